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
    loaded_.setLoad(Eigen::VectorXd());
  else
    loaded_.setLoad(generalizedForce(f_free));
  if (state_.q.size() > 0)
    integrator_->initialize(loaded_, state_);
}

void MethodModel::configure(const IntegratorSettings& settings)
{
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
  setOffset(Eigen::VectorXd::Zero(lin_.grid.numFreeDofs()));
  configure(settings);
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
  Eigen::VectorXd reference = lin_.x_ref;
  lin_.grid.addFree(offset_, reference);
  modal_force_->setReference(reference);
  if (anchor_.size() > 0)
    setAnchor(anchor_);
}

double ModalMethod::assign(const Eigen::VectorXd& u, const Eigen::VectorXd& v, Remainder remainder)
{
  const Eigen::MatrixXd& phi = lin_.basis.phi;
  // The M-orthogonal projection onto span(Phi) (Phi^T M Phi = I): X = Phi^T M u.
  const Eigen::VectorXd modal = phi.transpose() * lin_.mass.cwiseProduct(u);
  const Eigen::VectorXd remainder_u = u - phi * modal;
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
  setState(modal, phi.transpose() * lin_.mass.cwiseProduct(v));
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
  return offset_ + lin_.basis.phi * s.q;
}

Eigen::VectorXd ModalMethod::velocity(const State& s) const { return lin_.basis.phi * s.v; }

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
