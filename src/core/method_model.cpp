// The methods' coordinates and the maps between them and physical displacements.
#include "modal_mass_spring/method_model.h"

#include <algorithm>
#include <stdexcept>

namespace modal_mass_spring
{
namespace
{

SparseMatrix diagonalMatrix(const Eigen::VectorXd& d)
{
  SparseMatrix m(d.size(), d.size());
  m.reserve(Eigen::VectorXi::Ones(d.size()));
  for (int k = 0; k < d.size(); ++k)
    m.insert(k, k) = d[k];
  return m;
}

}  // namespace

MethodModel::MethodModel(Method method, const LinearizedGrid& linearized, std::unique_ptr<ForceModel> force)
  : lin_(linearized), method_(method), force_(std::move(force)), loaded_(*force_)
{
}

void MethodModel::setExternalForce(const Eigen::VectorXd& f_free)
{
  if (f_free.size() == 0 || f_free.isZero(0.0))
    external_load_.resize(0);
  else
    external_load_ = generalizedForce(f_free);
  updateLoad();
  if (state_.q.size() > 0)
    integrator_->initialize(loaded_, state_);
}

void MethodModel::setHandleLoad(const Eigen::VectorXd& load)
{
  handle_load_ = load;
  updateLoad();
}

void MethodModel::updateLoad()
{
  if (handle_load_.size() == 0)
    loaded_.setLoad(external_load_);
  else if (external_load_.size() == 0)
    loaded_.setLoad(handle_load_);
  else
    loaded_.setLoad(external_load_ + handle_load_);
}

void MethodModel::configure(const IntegratorSettings& settings)
{
  settings_ = settings;
  MassDamping system = massDamping(settings.alpha, settings.beta);
  if (settings.kind == IntegratorKind::Implicit)
    integrator_ = std::make_unique<ImplicitNewmark>(std::move(system), settings.time_step, settings.newton_max_iterations,
                                                    settings.hht_alpha);
  else
    integrator_ = std::make_unique<ExplicitNewmark>(std::move(system), settings.time_step);
  if (state_.q.size() > 0)
    integrator_->initialize(loaded_, state_);
}

void MethodModel::setState(const Eigen::VectorXd& q, const Eigen::VectorXd& v)
{
  state_.q = q;
  state_.v = v;
  integrator_->initialize(loaded_, state_);
}

FullMethod::FullMethod(const LinearizedGrid& linearized, const IntegratorSettings& settings)
  : MethodModel(Method::Full, linearized, std::make_unique<FullForceModel>(linearized.grid, linearized.x_ref))
{
  configure(settings);
}

MassDamping FullMethod::massDamping(double alpha, double beta) const
{
  // Rayleigh damping with the constant K of the linearization point.
  return MassDamping{lin_.mass, alpha * diagonalMatrix(lin_.mass) + beta * lin_.stiffness};
}

double FullMethod::assign(const Eigen::VectorXd& u, const Eigen::VectorXd& v, Remainder)
{
  setState(u, v);
  return 0.0;
}

void FullMethod::setHandleMotion(const HandleMotion& motion)
{
  Eigen::VectorXd reference = lin_.x_ref;
  const std::vector<int>& dofs = lin_.grid.handleDofs();
  if (motion.displacement.size() > 0)
    for (size_t k = 0; k < dofs.size(); ++k)
      reference[dofs[k]] += motion.displacement[static_cast<Eigen::Index>(k)];
  static_cast<FullForceModel&>(forceModel()).setReference(reference);
  if (settings_.beta != 0.0 && motion.velocity.size() > 0 && lin_.handle_coupling)
    setHandleLoad(-settings_.beta * (*lin_.handle_coupling * motion.velocity));
  else
    setHandleLoad(Eigen::VectorXd());
}

double FullMethod::kineticEnergy(const State& s) const { return 0.5 * s.v.cwiseAbs2().dot(lin_.mass); }

double FullMethod::anchorDistanceSquared(const Eigen::VectorXd& q) const
{
  return (q - anchor_).cwiseAbs2().dot(lin_.mass);
}

namespace
{

std::unique_ptr<ModalForceModel> makeModalForce(Method method, const LinearizedGrid& lin)
{
  if (method == Method::Linear)
    return std::make_unique<LinearModalForceModel>(lin.grid, lin.basis, lin.x_ref);
  if (method == Method::Cubature)
  {
    if (!lin.cubature)
      throw std::logic_error("the cubature method needs a trained cubature");
    return std::make_unique<CubatureForceModel>(lin.grid, lin.basis, lin.x_ref, *lin.cubature);
  }
  return std::make_unique<PhysicalModalForceModel>(lin.grid, lin.basis, lin.x_ref);
}

}  // namespace

ModalMethod::ModalMethod(Method method, const LinearizedGrid& linearized, const IntegratorSettings& settings)
  : MethodModel(method, linearized, makeModalForce(method, linearized))
{
  // The base owns the force model makeModalForce built; keep its modal interface to move the reference.
  modal_force_ = static_cast<ModalForceModel*>(&forceModel());
  if (lin_.constraint_modes)
  {
    interface_mass_ = lin_.basis.phi.transpose() * (lin_.mass.asDiagonal() * *lin_.constraint_modes);
    const Eigen::VectorXd rest = Eigen::VectorXd::Zero(lin_.constraint_modes->cols());
    handle_motion_ = HandleMotion{rest, rest, rest};
  }
  configure(settings);
  setOffset(Eigen::VectorXd::Zero(lin_.grid.numFreeDofs()));
}

MassDamping ModalMethod::massDamping(double alpha, double beta) const
{
  const Eigen::Index r = lin_.basis.phi.cols();
  if (lin_.basis.reduced_stiffness.size() > 0)
  {
    // Not an eigenbasis (modal derivatives): Phi^T C Phi = alpha I + beta Phi^T K Phi is dense.
    const Eigen::MatrixXd damping = alpha * Eigen::MatrixXd::Identity(r, r) + beta * lin_.basis.reduced_stiffness;
    return MassDamping{Eigen::VectorXd::Ones(r), damping.sparseView()};
  }
  // Phi^T M Phi = I and Phi^T K Phi = Lambda: Rayleigh damping is diagonal, alpha + beta lambda^2.
  const Eigen::VectorXd damping = (alpha + beta * lin_.basis.eigenvalues.array()).matrix();
  return MassDamping{Eigen::VectorXd::Ones(damping.size()), diagonalMatrix(damping)};
}

void ModalMethod::setOffset(const Eigen::VectorXd& offset)
{
  offset_ = offset;
  updateReference();
  if (anchor_.size() > 0)
    setAnchor(anchor_);
}

void ModalMethod::updateReference()
{
  Eigen::VectorXd reference = lin_.x_ref;
  if (lin_.constraint_modes && method() != Method::Linear)
  {
    const std::vector<int>& dofs = lin_.grid.handleDofs();
    for (size_t k = 0; k < dofs.size(); ++k)
      reference[dofs[k]] += handle_motion_.displacement[static_cast<Eigen::Index>(k)];
    lin_.grid.addFree(offset_ + psiDx(), reference);
  }
  else
  {
    lin_.grid.addFree(offset_, reference);
  }
  modal_force_->setReference(reference);
}

void ModalMethod::setHandleMotion(const HandleMotion& motion)
{
  if (!lin_.constraint_modes)
  {
    if (!motion.atRest())
      throw std::logic_error("a modal method with handles needs their constraint modes");
    return;
  }
  const Eigen::Index nb = lin_.constraint_modes->cols();
  handle_motion_ = motion;
  auto orZero = [nb](const Eigen::VectorXd& v) { return v.size() > 0 ? v : Eigen::VectorXd::Zero(nb); };
  handle_motion_.displacement = orZero(motion.displacement);
  handle_motion_.velocity = orZero(motion.velocity);
  handle_motion_.acceleration = orZero(motion.acceleration);
  psi_dx_stale_ = psi_v_stale_ = true;
  // `linear`'s force, linearized at x_ref, is unchanged by the interface: K_ii Psi + K_ib = 0.
  if (method() != Method::Linear)
    updateReference();
  // The interior's acceleration Psi a_b and the mass-proportional damping of its velocity Psi v_b
  // (the stiffness-proportional part cancels with the coupling: beta (K_ii Psi + K_ib) v_b = 0).
  setHandleLoad(-interface_mass_ * (handle_motion_.acceleration + settings_.alpha * handle_motion_.velocity));
}

double ModalMethod::assign(const Eigen::VectorXd& u, const Eigen::VectorXd& v, Remainder remainder)
{
  const Eigen::MatrixXd& phi = lin_.basis.phi;
  // The handles carry Psi dx_b; the M-orthogonal projection onto span(Phi) (Phi^T M Phi = I) of the
  // rest: X = Phi^T M u.
  const Eigen::VectorXd u_modes = lin_.constraint_modes ? Eigen::VectorXd(u - psiDx()) : u;
  const Eigen::VectorXd v_modes = lin_.constraint_modes ? Eigen::VectorXd(v - psiV()) : v;
  const Eigen::VectorXd modal = phi.transpose() * lin_.mass.cwiseProduct(u_modes);
  const Eigen::VectorXd remainder_u = u_modes - phi * modal;
  double dropped = 0.0;
  if (remainder == Remainder::Keep)
  {
    setOffset(remainder_u);
  }
  else
  {
    setOffset(Eigen::VectorXd::Zero(u.size()));
    const int dim = lin_.grid.dimension();
    for (int k = 0; k + dim <= remainder_u.size(); k += dim)
      dropped = std::max(dropped, remainder_u.segment(k, dim).norm());
  }
  setState(modal, phi.transpose() * lin_.mass.cwiseProduct(v_modes));
  return dropped;
}

Eigen::VectorXd ModalMethod::generalizedForce(const Eigen::VectorXd& f_free) const
{
  // A force on a few particles touches a few rows of Phi: O(touched dofs x r), not O(n r).
  Eigen::VectorXd load = Eigen::VectorXd::Zero(lin_.basis.phi.cols());
  for (int k = 0; k < f_free.size(); ++k)
    if (f_free[k] != 0.0)
      load += f_free[k] * lin_.basis.phi.row(k).transpose();
  return load;
}

Eigen::VectorXd ModalMethod::displacement(const State& s) const
{
  if (lin_.constraint_modes)
    return offset_ + psiDx() + lin_.basis.phi * s.q;
  return offset_ + lin_.basis.phi * s.q;
}

Eigen::VectorXd ModalMethod::velocity(const State& s) const
{
  if (lin_.constraint_modes)
    return psiV() + lin_.basis.phi * s.v;
  return lin_.basis.phi * s.v;
}

const Eigen::VectorXd& ModalMethod::psiDx() const
{
  if (psi_dx_stale_ || psi_dx_.size() == 0)
    psi_dx_ = *lin_.constraint_modes * handle_motion_.displacement;
  psi_dx_stale_ = false;
  return psi_dx_;
}

const Eigen::VectorXd& ModalMethod::psiV() const
{
  if (psi_v_stale_ || psi_v_.size() == 0)
    psi_v_ = *lin_.constraint_modes * handle_motion_.velocity;
  psi_v_stale_ = false;
  return psi_v_;
}

void ModalMethod::setAnchor(const Eigen::VectorXd& u_anchor)
{
  anchor_ = u_anchor;
  const Eigen::VectorXd from_anchor = offset_ - anchor_;
  anchor_b_ = lin_.basis.phi.transpose() * lin_.mass.cwiseProduct(from_anchor);
  anchor_c_ = from_anchor.cwiseAbs2().dot(lin_.mass);
}

double ModalMethod::anchorDistanceSquared(const Eigen::VectorXd& q) const
{
  // Round-off can make the sum of nearly cancelling terms slightly negative.
  return std::max(0.0, anchor_c_ + 2.0 * anchor_b_.dot(q) + q.squaredNorm());
}

std::unique_ptr<MethodModel> makeMethod(Method method, const LinearizedGrid& linearized,
                                        const IntegratorSettings& settings)
{
  if (method == Method::Full)
    return std::make_unique<FullMethod>(linearized, settings);
  return std::make_unique<ModalMethod>(method, linearized, settings);
}

}  // namespace modal_mass_spring
