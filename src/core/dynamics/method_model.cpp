// The methods' coordinates and the maps between them and physical displacements.
#include "dynamics/method_model.h"

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
    external_free_.resize(0);
  else
    external_free_ = f_free;
  external_load_ = external_free_.size() > 0 ? generalizedForce(bodyExternalForce()) : Eigen::VectorXd();
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
  Eigen::VectorXd load;
  for (const Eigen::VectorXd* part : {&external_load_, &handle_load_, &frame_load_})
    if (part->size() > 0)
      load = load.size() > 0 ? Eigen::VectorXd(load + *part) : *part;
  loaded_.setLoad(load);
}

Eigen::VectorXd MethodModel::bodyExternalForce() const
{
  if (frame_.none || external_free_.size() == 0)
    return external_free_;
  // A particle's free dofs are consecutive: R^T per particle.
  const int dim = lin_.grid.dimension();
  Eigen::VectorXd f = external_free_;
  for (Eigen::Index k = 0; k + dim <= f.size(); k += dim)
    if (!f.segment(k, dim).isZero(0.0))
      f.segment(k, dim) = frame_.rotation.transpose() * external_free_.segment(k, dim);
  return f;
}

void MethodModel::setFrameForces(const FrameForces& frame)
{
  frame_ = frame;
  applyFrame();
}

void MethodModel::applyFrame()
{
  frame_load_.resize(0);
  // At rest B adds nothing: the results are those of a grid held still, to the last bit.
  if (!frame_.none)
    frameTerms(frame_, frame_load_, frame_linear_, frame_gyroscopic_);
  loaded_.setLinearTerm(frame_.none ? nullptr : &frame_linear_);
  integrator_->setGyroscopic(frame_.none ? nullptr : &frame_gyroscopic_);
  if (external_free_.size() > 0)
    external_load_ = generalizedForce(bodyExternalForce());
  updateLoad();
}

void MethodModel::configure(const IntegratorSettings& settings)
{
  settings_ = settings;
  MassDamping system = massDamping(settings.alpha, settings.beta);
  if (settings.kind == IntegratorKind::Implicit)
  {
    auto implicit = std::make_unique<ImplicitNewmark>(std::move(system), settings.time_step,
                                                      settings.newton_max_iterations, settings.hht_alpha);
    implicit->setSolver(settings.solver, settings.tangent_refresh_steps);
    integrator_ = std::move(implicit);
  }
  else
    integrator_ = std::make_unique<ExplicitNewmark>(std::move(system), settings.time_step);
  integrator_->setGyroscopic(frame_.none ? nullptr : &frame_gyroscopic_);
  if (state_.q.size() > 0)
    integrator_->initialize(loaded_, state_);
}

void MethodModel::setState(const Eigen::VectorXd& q, const Eigen::VectorXd& v)
{
  state_.q = q;
  state_.v = v;
  integrator_->initialize(loaded_, state_);
}

void MethodModel::restore(const State& state, const Eigen::VectorXd&) { state_ = state; }

FullMethod::FullMethod(const LinearizedGrid& linearized, const IntegratorSettings& settings)
  : FullMethod(Method::Full, linearized, settings)
{
}

FullMethod::FullMethod(Method method, const LinearizedGrid& linearized, const IntegratorSettings& settings)
  : MethodModel(method, linearized, std::make_unique<FullForceModel>(linearized.grid, linearized.x_ref))
{
  configure(settings);
}

MassDamping FullMethod::massDamping(double alpha, double beta) const
{
  // Rayleigh damping with the constant K of the linearization point. Without beta, K's pattern of
  // zeros would go into every product with C and into the implicit inertia (its blocks, J p); nor is
  // the sum formed (it was most of a switch to `full`: docs/results.md, "The adaptive method").
  SparseMatrix damping = alpha * diagonalMatrix(lin_.mass);
  if (beta != 0.0)
    damping = damping + beta * lin_.stiffness;
  damping.prune(0.0);
  return MassDamping{lin_.mass, damping};
}

double FullMethod::assign(const Eigen::VectorXd& u, const Eigen::VectorXd& v, Remainder)
{
  setState(u, v);
  return 0.0;
}

void FullMethod::setHandleMotion(const HandleMotion& motion)
{
  handle_displacement_ = motion.displacement;
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

void FullMethod::frameTerms(const FrameForces& frame, Eigen::VectorXd& load, SparseMatrix& linear,
                            SparseMatrix& gyroscopic)
{
  const int dim = lin_.grid.dimension();
  const Eigen::Index n = lin_.mass.size();
  // One dim x dim block per particle, every entry stored: built once, then only its values change.
  if (linear.rows() != n || gyroscopic.rows() != n)
  {
    y_ref_ = lin_.grid.gatherFree(lin_.x_ref);
    std::vector<Eigen::Triplet<double>> blocks;
    blocks.reserve(n * dim);
    for (Eigen::Index p = 0; p + dim <= n; p += dim)
      for (int c = 0; c < dim; ++c)
        for (int r = 0; r < dim; ++r)
          blocks.emplace_back(p + r, p + c, 1.0);
    linear.resize(n, n);
    linear.setFromTriplets(blocks.begin(), blocks.end());
    gyroscopic = linear;
  }
  load.resize(n);
  double* l = linear.valuePtr();
  double* g = gyroscopic.valuePtr();
  for (Eigen::Index p = 0; p + dim <= n; p += dim)
  {
    const double m = lin_.mass[p];
    load.segment(p, dim) = m * frame.uniform;
    // Column p + c holds rows p .. p + dim - 1, in order.
    for (int c = 0; c < dim; ++c)
      for (int r = 0; r < dim; ++r)
      {
        l[(p + c) * dim + r] = m * frame.position(r, c);
        g[(p + c) * dim + r] = 2.0 * m * frame.spin(r, c);
      }
  }
  load.noalias() -= linear * y_ref_;  // the linear force at q = 0: the positions of x_ref in B
}

double FullMethod::kineticEnergy(const State& s) const { return 0.5 * s.v.cwiseAbs2().dot(lin_.mass); }

Eigen::VectorXd FullMethod::handleTranslation(const Eigen::VectorXd& handle_displacement) const
{
  const int dim = lin_.grid.dimension();
  const Eigen::Index count = handle_displacement.size() / dim;
  if (count == 0)
    return Eigen::VectorXd();
  return handle_displacement.reshaped(dim, count).rowwise().mean();
}

void FullMethod::setAnchor(const Eigen::VectorXd& u_anchor, const Eigen::VectorXd& handles_anchor)
{
  anchor_ = u_anchor;
  anchor_translation_ = handleTranslation(handles_anchor);
}

double FullMethod::anchorDistanceSquared(const Eigen::VectorXd& q) const
{
  const int dim = lin_.grid.dimension();
  Eigen::VectorXd moved = handleTranslation(handle_displacement_);
  if (anchor_translation_.size() == dim)
    moved = moved.size() == dim ? Eigen::VectorXd(moved - anchor_translation_) : Eigen::VectorXd(-anchor_translation_);
  if (moved.size() == 0)
    return (q - anchor_).cwiseAbs2().dot(lin_.mass);
  double sum = 0.0;
  for (Eigen::Index p = 0; p + dim <= q.size(); p += dim)
    sum += (q.segment(p, dim) - anchor_.segment(p, dim) - moved).cwiseAbs2().dot(lin_.mass.segment(p, dim));
  return sum;
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
    if (!lin_.static_constraint_modes && lin_.handle_coupling)
      interface_stiffness_ =
          lin_.basis.phi.transpose() * (lin_.stiffness * *lin_.constraint_modes + Eigen::MatrixXd(*lin_.handle_coupling));
    const Eigen::VectorXd rest = Eigen::VectorXd::Zero(lin_.constraint_modes->cols());
    handle_motion_ = HandleMotion{rest, rest, rest};
    reference_handles_ = rest;
    if (lin_.constraint_modes->cols() > 0)
    {
      handle_fit_ = AffineHandleFit(lin_.grid, lin_.x_ref);
      psi_affine_ = *lin_.constraint_modes * handle_fit_.h;
      interface_mass_affine_ = interface_mass_ * handle_fit_.h;
      if (method == Method::Cubature)
      {
        cubature_force_ = static_cast<CubatureForceModel*>(modal_force_);
        cubature_force_->setHandleMap(*lin_.constraint_modes, handle_fit_);
      }
    }
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
    setAnchor(anchor_, Eigen::VectorXd());
  if (frame_projection_)
  {
    frame_projection_->w_stale = true;
    applyFrame();  // the frame's forces at q = 0 act at x_ref + offset
  }
}

void ModalMethod::restore(const State& state, const Eigen::VectorXd& offset)
{
  setOffset(offset.size() > 0 ? offset : Eigen::VectorXd::Zero(lin_.basis.phi.rows()));
  MethodModel::restore(state, offset);
}

void ModalMethod::projectFrame()
{
  const int dim = lin_.grid.dimension();
  const Eigen::MatrixXd& phi = lin_.basis.phi;
  const Eigen::Index particles = phi.rows() / dim;
  // A particle's free dofs are consecutive: component j is every dim-th row from j.
  auto component = [&](const auto& dense, int j) { return Eigen::MatrixXd(dense(Eigen::seqN(j, particles, dim), Eigen::all)); };
  if (!frame_projection_)
  {
    frame_projection_ = std::make_unique<FrameProjection>();
    FrameProjection& f = *frame_projection_;
    for (int j = 0; j < dim; ++j)
    {
      const Eigen::MatrixXd weighted = component(lin_.mass, j).asDiagonal() * component(phi, j);
      f.u.push_back(weighted.colwise().sum().transpose());
      for (int k = 0; k < dim; ++k)
        f.s.push_back(weighted.transpose() * component(phi, k));
    }
  }
  FrameProjection& f = *frame_projection_;
  if (!f.w_stale)
    return;
  const Eigen::VectorXd y = lin_.grid.gatherFree(lin_.x_ref) + offset_;
  f.w.clear();
  for (int j = 0; j < dim; ++j)
  {
    const Eigen::MatrixXd weighted = component(lin_.mass, j).asDiagonal() * component(phi, j);
    for (int k = 0; k < dim; ++k)
      f.w.push_back(weighted.transpose() * component(y, k));
  }
  f.w_stale = false;
}

void ModalMethod::frameTerms(const FrameForces& frame, Eigen::VectorXd& load, SparseMatrix& linear,
                             SparseMatrix& gyroscopic)
{
  projectFrame();
  const FrameProjection& f = *frame_projection_;
  const int dim = lin_.grid.dimension();
  const Eigen::Index r = lin_.basis.phi.cols();
  load.setZero(r);
  // Dense r x r, stored with every entry: the values of a full column-major pattern are the dense
  // matrix itself, written in place step after step.
  if (linear.rows() != r || gyroscopic.rows() != r)
  {
    linear = Eigen::MatrixXd::Ones(r, r).sparseView();
    gyroscopic = linear;
  }
  Eigen::Map<Eigen::MatrixXd> l(linear.valuePtr(), r, r), g(gyroscopic.valuePtr(), r, r);
  l.setZero();
  g.setZero();
  // Phi^T M (uniform - position y) = sum_j uniform_j U_j - sum_jk position_jk (W_jk + S_jk X).
  for (int j = 0; j < dim; ++j)
  {
    load += frame.uniform[j] * f.u[j];
    for (int k = 0; k < dim; ++k)
    {
      load -= frame.position(j, k) * f.w[j * dim + k];
      l += frame.position(j, k) * f.s[j * dim + k];
      g += (2.0 * frame.spin(j, k)) * f.s[j * dim + k];
    }
  }
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
    reference_handles_ = handle_motion_.displacement;
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
  if (cubature_force_)
    cubature_force_->moveHandles(handle_motion_.displacement - reference_handles_);
  else if (method() != Method::Linear)
    updateReference();
  // The interior's acceleration Psi a_b and the mass-proportional damping of its velocity Psi v_b
  // (the stiffness-proportional part cancels with the coupling: beta (K_ii Psi + K_ib) v_b = 0).
  // Through the handles' affine part when their motion is affine (a turned clamp): r x 12 instead of
  // r x handle dofs (a tenth of a cubature step with 1000 springs on the 100 x 100 clamp, more with fewer).
  const Eigen::VectorXd inertial = handle_motion_.acceleration + settings_.alpha * handle_motion_.velocity;
  Eigen::VectorXd load, affine, rest;
  if (interface_mass_affine_.size() > 0 && !handle_fit_.split(inertial, affine, rest))
    load = -interface_mass_affine_ * affine;
  else
    load = -interface_mass_ * inertial;
  if (interface_stiffness_.size() > 0 && settings_.beta != 0.0)
    load.noalias() -= settings_.beta * (interface_stiffness_ * handle_motion_.velocity);
  setHandleLoad(load);
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

void MethodModel::statesAt(const State& s, const std::vector<int>& k, Eigen::VectorXd& u, Eigen::VectorXd& v) const
{
  u.resize(static_cast<Eigen::Index>(k.size()));
  v.resize(u.size());
  for (size_t i = 0; i < k.size(); ++i)
  {
    u[static_cast<Eigen::Index>(i)] = displacementAt(s, k[i]);
    v[static_cast<Eigen::Index>(i)] = velocityAt(s, k[i]);
  }
}

// Row k of Psi dx_b and Psi v_b from Psi's row: O(handle dofs), where psiDx() and psiV() redo the whole
// product after every handle motion.
double ModalMethod::displacementAt(const State& s, int k) const
{
  const double handles = lin_.constraint_modes ? lin_.constraint_modes->row(k).dot(handle_motion_.displacement) : 0.0;
  return offset_[k] + handles + lin_.basis.phi.row(k).dot(s.q);
}

double ModalMethod::velocityAt(const State& s, int k) const
{
  const double handles = lin_.constraint_modes ? lin_.constraint_modes->row(k).dot(handle_motion_.velocity) : 0.0;
  return handles + lin_.basis.phi.row(k).dot(s.v);
}

void ModalMethod::applyPsi(const Eigen::VectorXd& dx, Eigen::VectorXd& out) const
{
  Eigen::VectorXd affine, rest;
  if (psi_affine_.size() > 0 && !handle_fit_.split(dx, affine, rest))
    out.noalias() = psi_affine_ * affine;  // Psi dx = Psi H H^+ dx: dx is affine to round-off
  else
    out.noalias() = *lin_.constraint_modes * dx;
}

const Eigen::VectorXd& ModalMethod::psiDx() const
{
  if (psi_dx_stale_ || psi_dx_.size() == 0)
    applyPsi(handle_motion_.displacement, psi_dx_);
  psi_dx_stale_ = false;
  return psi_dx_;
}

const Eigen::VectorXd& ModalMethod::psiV() const
{
  if (psi_v_stale_ || psi_v_.size() == 0)
    applyPsi(handle_motion_.velocity, psi_v_);
  psi_v_stale_ = false;
  return psi_v_;
}

void ModalMethod::setAnchor(const Eigen::VectorXd& u_anchor, const Eigen::VectorXd& /*handles_anchor*/)
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
  if (method == Method::Coarse)
    return std::make_unique<CoarseMethod>(linearized, settings);
  return std::make_unique<ModalMethod>(method, linearized, settings);
}

}  // namespace modal_mass_spring
