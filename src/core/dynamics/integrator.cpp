// The paper's explicit Newmark scheme and the implicit Newmark (HHT alpha) with its Newton solve.
#include "dynamics/integrator.h"

#include <Eigen/QR>

#include <algorithm>
#include <limits>
#include <stdexcept>

namespace modal_mass_spring
{
namespace
{

bool isDiagonal(const SparseMatrix& m)
{
  for (int col = 0; col < m.outerSize(); ++col)
    for (SparseMatrix::InnerIterator it(m, col); it; ++it)
      if (it.row() != it.col() && it.value() != 0.0)
        return false;
  return true;
}

}  // namespace

void Integrator::initialize(ForceModel& model, State& state) const
{
  Eigen::VectorXd f;
  model.force(state.q, f);
  state.a = (f - dampingForce(state.v)).cwiseQuotient(system_.mass);
}

void Integrator::setGyroscopic(const SparseMatrix* g)
{
  gyroscopic_ = g && g->size() > 0 ? g : nullptr;
  gyroscopicChanged();
}

Eigen::VectorXd Integrator::dampingForce(const Eigen::VectorXd& v) const
{
  Eigen::VectorXd f = system_.damping * v;
  if (gyroscopic_)
    f.noalias() += *gyroscopic_ * v;
  return f;
}

ExplicitNewmark::ExplicitNewmark(MassDamping system, double dt) : Integrator(std::move(system), dt)
{
  // M is diagonal, so M + dt/2 C is diagonal where C is (Rayleigh's alpha alone): inverted entrywise,
  // without forming the sum.
  diagonal_ = isDiagonal(system_.damping);
  if (diagonal_)
  {
    inverse_diagonal_ = (system_.mass + (0.5 * dt_) * Eigen::VectorXd(system_.damping.diagonal())).cwiseInverse();
  }
  else
  {
    SparseMatrix mass(system_.mass.size(), system_.mass.size());
    mass.setIdentity();
    mass = system_.mass.asDiagonal() * mass;
    ldlt_.compute(SparseMatrix(mass + (0.5 * dt_) * system_.damping));
    if (ldlt_.info() != Eigen::Success)
      throw std::runtime_error("explicit Newmark: M + dt/2 C is not positive definite");
  }
}

Eigen::VectorXd ExplicitNewmark::solve(const Eigen::VectorXd& rhs) const
{
  if (diagonal_)
    return inverse_diagonal_.cwiseProduct(rhs);
  return ldlt_.solve(rhs);
}

bool ExplicitNewmark::step(ForceModel& model, const State& s, State& next)
{
  const Eigen::VectorXd& m = system_.mass;
  next.q = s.q + dt_ * s.v + (0.5 * dt_ * dt_) * s.a;
  model.force(next.q, force_);
  rhs_ = m.cwiseProduct(s.v) + (0.5 * dt_) * (m.cwiseProduct(s.a) + force_);
  if (!gyroscopic_)
  {
    next.v = solve(rhs_);
  }
  else
  {
    // From the velocity the start's acceleration predicts, O(dt^2) off, until it stops changing at
    // round-off; a frame turning so fast that this does not contract (dt |omega| near 1) refuses the
    // step.
    next.v = s.v + dt_ * s.a;
    bool converged = false;
    for (int iteration = 0; !converged && iteration < kMaxIterations; ++iteration)
    {
      gyroscopic_force_.noalias() = *gyroscopic_ * next.v;
      gyroscopic_force_ = rhs_ - (0.5 * dt_) * gyroscopic_force_;
      velocity_ = solve(gyroscopic_force_);
      const double change = (velocity_ - next.v).norm();
      converged = change <= 1e-14 * velocity_.norm() || change == 0.0;
      next.v.swap(velocity_);
    }
    if (!converged || !next.v.allFinite())
      return false;
  }
  next.a = (force_ - dampingForce(next.v)).cwiseQuotient(m);
  return true;
}

}  // namespace modal_mass_spring

namespace modal_mass_spring
{

ImplicitNewmark::ImplicitNewmark(MassDamping system, double dt, int max_iterations, double hht_alpha,
                                 double tolerance, TangentSolverKind linear_solver)
  : Integrator(std::move(system), dt),
    alpha_(hht_alpha),
    beta_(0.25 * (1.0 - hht_alpha) * (1.0 - hht_alpha)),
    gamma_(0.5 - hht_alpha),
    max_iterations_(max_iterations),
    tolerance_(tolerance),
    linear_solver_(std::make_unique<TangentSolver>(linear_solver))
{
  mass_matrix_.resize(system_.mass.size(), system_.mass.size());
  mass_matrix_.setIdentity();
  mass_matrix_ = system_.mass.asDiagonal() * mass_matrix_;
  damping_ = system_.damping;
  setStepSize(dt_);
}

void ImplicitNewmark::gyroscopicChanged()
{
  damping_ = gyroscopic_ ? SparseMatrix(system_.damping + *gyroscopic_) : system_.damping;
  h_ = 0.0;  // the inertia term holds C + G: built again at the next step
  factor_h_ = 0.0;
  inertia_mapped_ = false;
}

void ImplicitNewmark::setStepSize(double h)
{
  if (h == h_)
    return;
  h_ = h;
  inertia_mapped_ = false;
  linear_solver_->forgetFactor();
  inertia_ = (1.0 / (beta_ * h * h)) * mass_matrix_ + ((1.0 + alpha_) * gamma_ / (beta_ * h)) * damping_;
  inertia_diagonal_.resize(0);
  if (isDiagonal(inertia_))
    inertia_diagonal_ = inertia_.diagonal();
}

bool ImplicitNewmark::step(ForceModel& model, const State& s, State& next)
{
  substeps_ = 0;
  return advance(model, s, next, dt_, 0);
}

// Where Newton does not converge, the step is taken as two implicit half steps, down to 1/16 of it:
// still converged solutions of the same scheme, only finer.
bool ImplicitNewmark::advance(ForceModel& model, const State& s, State& next, double h, int depth)
{
  setStepSize(h);
  if (solve(model, s, next))
  {
    ++substeps_;
    return true;
  }
  if (depth == kMaxHalvings)
    return false;
  State middle;
  return advance(model, s, middle, 0.5 * h, depth + 1) && advance(model, middle, next, 0.5 * h, depth + 1);
}

void ImplicitNewmark::kinematics(const State& s, State& next) const
{
  next.a = (next.q - predicted_) / (beta_ * h_ * h_);
  next.v = s.v + h_ * ((1.0 - gamma_) * s.a + gamma_ * next.a);
}

void ImplicitNewmark::predict(ForceModel& model, const State& s, State& next)
{
  predicted_ = s.q + h_ * s.v + ((0.5 - beta_) * h_ * h_) * s.a;
  old_terms_.setZero(s.q.size());
  if (alpha_ != 0.0)
  {
    model.force(s.q, force_);
    old_terms_ = alpha_ * (damping_ * s.v - force_);
  }
  // Predictor: constant velocity, or the start's acceleration kept over the step (the converged
  // acceleration of the previous implicit step is smooth in time: one Newton iteration or so closer).
  next.q = s.q + h_ * s.v;
  if (start_ == NewtonStart::ConstantAcceleration)
    next.q += (0.5 * h_ * h_) * s.a;
}

bool ImplicitNewmark::solve(ForceModel& model, const State& s, State& next)
{
  predict(model, s, next);
  // R(q') is the gradient of the incremental potential
  //   G(q') = |q' - y|_M^2 / (2 beta h^2) + (1 + alpha) gamma / (2 beta h) |q' - y|_C^2
  //           + (1 + alpha) (E(q') + (C (v + h (1 - gamma) a)) . q') - alpha (C v - F(q)) . q',
  // so a Newton direction that descends G, found with a line search on G, converges from far away.
  const Eigen::VectorXd linear_term =
      (1.0 + alpha_) * (damping_ * (s.v + (h_ * (1.0 - gamma_)) * s.a)) - old_terms_;
  auto incremental = [&](const Eigen::VectorXd& q) {
    const Eigen::VectorXd dy = q - predicted_;
    return (dy.dot(system_.mass.cwiseProduct(dy)) + (1.0 + alpha_) * gamma_ * h_ * dy.dot(damping_ * dy)) /
               (2.0 * beta_ * h_ * h_) +
           (1.0 + alpha_) * model.energy(q) + linear_term.dot(q);
  };

  const bool symmetric = !gyroscopic_ && model.isSymmetric();
  if (solver_ != ImplicitSolver::Newton && symmetric && !model.isLinear() && prepareFactor(model, next.q, false))
    return solveWithFactor(model, s, next, incremental);
  linear_solver_->setBlockSize(model.blockSize());
  for (last_iterations_ = 1; last_iterations_ <= max_iterations_; ++last_iterations_)
  {
    const double residual_norm = residual(model, s, next);
    // Converged when the unbalanced force is small against the forces at play, or at the
    // round-off of the forces: where they balance (a grid resting at its equilibrium) there is no
    // other scale.
    const double target = tolerance_ * (force_.norm() + inertial_norm_) + roundoff(model, next);
    if (residual_norm <= target)
      return true;

    // An inexact Newton direction (Eisenstat and Walker): a linear residual below |R| times R's own
    // relative size keeps Newton's quadratic convergence, and one below a tenth of the target is as
    // good as exact.
    const double relative = residual_norm / (force_.norm() + inertial_norm_);
    const double slack = std::max(std::min(max_forcing_, relative) * residual_norm, 0.1 * target);
    Eigen::VectorXd delta = direction(model, next, symmetric, slack);
    if (delta.size() == 0)
      return false;
    // Also converged when the Newton correction is negligible against the step's own motion: with
    // tiny motions the residual cannot fall below the round-off of the spring forces.
    if (model.isLinear() || delta.norm() <= 1e-10 * (next.q - s.q).norm())
    {
      next.q += delta;
      residual(model, s, next);
      return true;
    }

    if (!lineSearch(model, s, next, delta, residual_norm, symmetric, incremental))
    {
      // No further decrease: the residual has reached the round-off of the forces. Accept it when
      // it is small anyway (the square root of the tolerance), refuse the step otherwise.
      return residual_norm <= std::sqrt(tolerance_) * (force_.norm() + inertial_norm_) + roundoff(model, next);
    }
  }
  return false;
}

bool ImplicitNewmark::lineSearch(ForceModel& model, const State& s, State& next, const Eigen::VectorXd& delta,
                                 double residual_norm, bool symmetric,
                                 const std::function<double(const Eigen::VectorXd&)>& incremental)
{
  const Eigen::VectorXd start = next.q;
  const double g0 = symmetric ? incremental(start) : 0.0;
  const double slope = residual_.dot(delta);
  bool accepted = false;
  for (double fraction = 1.0; fraction > 1e-6 && !accepted; fraction *= 0.5)
  {
    next.q = start + fraction * delta;
    if (!symmetric)
    {
      // No potential: a residual smaller in proportion to the step.
      accepted = residual(model, s, next) <= (1.0 - 1e-4 * fraction) * residual_norm;
      continue;
    }
    // Armijo on G; only where the expected decrease drowns in G's round-off, a smaller residual.
    const double expected = fraction * slope;
    const bool roundoff = std::abs(expected) < 1e-12 * (std::abs(g0) + 1e-300);
    accepted = roundoff ? residual(model, s, next) < residual_norm
                        : incremental(next.q) <= g0 + 1e-4 * expected;
  }
  if (!accepted)
  {
    next.q = start;
    residual(model, s, next);
  }
  return accepted;
}

void ImplicitNewmark::setSolver(ImplicitSolver solver, int refresh_steps)
{
  solver_ = solver;
  refresh_steps_ = refresh_steps;
  factor_h_ = 0.0;
}

bool ImplicitNewmark::prepareFactor(ForceModel& model, const Eigen::VectorXd& q, bool refresh)
{
  const bool lagged = solver_ == ImplicitSolver::LaggedTangent;
  refresh = refresh || factor_h_ != h_ || (lagged && solves_since_factor_ >= refresh_steps_);
  if (!refresh)
    return true;
  solves_since_factor_ = 0;
  if (lagged)
  {
    model.tangentStiffness(q, tangent_);
    if (factorize(model, tangent_))
      return true;
  }
  if (constant_stiffness_.rows() != model.size() && !model.constantStiffness(constant_stiffness_))
    return false;
  return factorize(model, constant_stiffness_);
}

bool ImplicitNewmark::factorize(const ForceModel& model, const SparseMatrix& stiffness)
{
  const SparseMatrix matrix = inertia_ + (1.0 + alpha_) * stiffness;
  factor_dense_ = model.blockSize() == 1;  // modal coordinates: small and dense
  bool ok;
  if (factor_dense_)
  {
    dense_factor_.compute(Eigen::MatrixXd(matrix));
    ok = dense_factor_.info() == Eigen::Success;
  }
  else
  {
    sparse_factor_.compute(matrix);
    ok = sparse_factor_.info() == Eigen::Success;
  }
  factor_h_ = ok ? h_ : 0.0;
  return ok;
}

Eigen::VectorXd ImplicitNewmark::applyFactor(const Eigen::VectorXd& rhs) const
{
  return factor_dense_ ? Eigen::VectorXd(dense_factor_.solve(rhs)) : Eigen::VectorXd(sparse_factor_.solve(rhs));
}

namespace
{

// Anderson mixing's history: the differences of the last `depth` iterates' f and g = q + f.
struct AndersonHistory
{
  AndersonHistory(Eigen::Index n, int depth_) : delta_f(n, depth_), delta_g(n, depth_), depth(depth_) {}

  void forget()
  {
    stored = 0;
    oldest = 0;
    previous_f.resize(0);
  }
  // Records an iterate's f and g; false while there is no difference to mix (a plain step).
  bool add(const Eigen::VectorXd& f, const Eigen::VectorXd& g)
  {
    if (previous_f.size() > 0)
    {
      delta_f.col(oldest) = f - previous_f;
      delta_g.col(oldest) = g - previous_g;
      oldest = (oldest + 1) % depth;
      stored = std::min(stored + 1, depth);
    }
    previous_f = f;
    previous_g = g;
    return stored > 0;
  }
  // q <- the g of the combination of the stored iterates whose f is smallest (least squares over
  // their differences).
  void mix(const Eigen::VectorXd& f, const Eigen::VectorXd& g, Eigen::VectorXd& q) const
  {
    const Eigen::VectorXd gamma = delta_f.leftCols(stored).colPivHouseholderQr().solve(f);
    q = g - delta_g.leftCols(stored) * gamma;
  }

  Eigen::MatrixXd delta_f, delta_g;
  int depth, stored = 0, oldest = 0;
  Eigen::VectorXd previous_f, previous_g;
};

}  // namespace

bool ImplicitNewmark::solveWithFactor(ForceModel& model, const State& s, State& next,
                                      const std::function<double(const Eigen::VectorXd&)>& incremental)
{
  // The fixed-point map q -> g(q) = q + f(q), f = -J_c^-1 R(q). Anderson mixing takes the g of the
  // combination of the last iterates whose f is smallest (least squares over their differences).
  ++solves_since_factor_;
  AndersonHistory history(next.q.size(), kAndersonDepth);
  Eigen::VectorXd f, base_q, base_f;
  double base_potential = 0.0, base_slope = 0.0;
  bool plain = true;  // next.q is base_q + base_f, not a mixed iterate
  for (last_iterations_ = 1; last_iterations_ <= kConstantMatrixIterations * max_iterations_; ++last_iterations_)
  {
    double residual_norm = residual(model, s, next);
    double potential = incremental(next.q);
    if (base_q.size() > 0 && potential > base_potential + 1e-12 * std::abs(base_potential))
    {
      // Uphill from the last accepted iterate: a mixed iterate, or a plain step of a lagged tangent,
      // which does not bound the springs' stiffness. Back along the plain direction, which descends
      // for any positive definite matrix, until G has decreased enough (Armijo).
      double t = plain ? 0.5 : 1.0;
      for (;; t *= 0.5)
      {
        if (t < 1e-6)
          return false;
        next.q = base_q + t * base_f;
        residual_norm = residual(model, s, next);
        potential = incremental(next.q);
        if (potential <= base_potential + 1e-4 * t * base_slope + 1e-12 * std::abs(base_potential))
          break;
      }
      history.forget();
    }
    const double target = tolerance_ * (force_.norm() + inertial_norm_) + roundoff(model, next);
    if (residual_norm <= target)
      return true;
    if (solver_ == ImplicitSolver::LaggedTangent && last_iterations_ % kRefreshIterations == 0)
    {
      // Slow to converge: the lagged tangent is too far from this state's.
      if (!prepareFactor(model, next.q, true))
        return false;
      history.forget();
    }
    f = -applyFactor(residual_);
    if (!f.allFinite())
      return false;
    if (f.norm() <= 1e-10 * (next.q - s.q).norm())
    {
      next.q += f;
      residual(model, s, next);
      return true;
    }
    const Eigen::VectorXd g = next.q + f;
    base_q = next.q;
    base_f = f;
    base_potential = potential;
    base_slope = residual_.dot(f);
    plain = !history.add(f, g);
    if (plain)
    {
      next.q = g;
      continue;
    }
    history.mix(f, g, next.q);
    if (!next.q.allFinite())
    {
      next.q = g;
      plain = true;
    }
  }
  return false;
}

Eigen::VectorXd ImplicitNewmark::direction(ForceModel& model, const State& next, bool symmetric, double slack)
{
  Eigen::VectorXd delta;
  if (symmetric && linear_solver_->kind() == TangentSolverKind::BlockJacobiCg)
    if (const SpringTangent* k = model.springTangent(next.q))
    {
      // J p = inertia p + (1 + alpha) K p from the springs, J never assembled; where CG does not
      // get there, J is assembled below and solved as before (more inertia, a factorisation).
      const int block_size = model.blockSize();
      inertiaBlocks(block_size, jacobian_blocks_);
      k->addDiagonalBlocks(1.0 + alpha_, jacobian_blocks_);
      auto multiply = [&](const Eigen::VectorXd& p, Eigen::VectorXd& jp) {
        if (inertia_diagonal_.size() == p.size())
          jp.noalias() = inertia_diagonal_.cwiseProduct(p);
        else
          jp.noalias() = inertia_ * p;
        k->multiplyAdd(p, 1.0 + alpha_, jp);
      };
      if (linear_solver_->solveMatrixFree(multiply, jacobian_blocks_, residual_, delta, slack) &&
          residual_.dot(delta) > 0.0)
        return -delta;
    }
  model.tangentStiffness(next.q, tangent_);
  if (!symmetric)
  {
    SparseMatrix jacobian = inertia_ + (1.0 + alpha_) * tangent_;
    jacobian.makeCompressed();
    if (lu_pattern_.changedTo(jacobian))
      lu_.analyzePattern(jacobian);
    lu_.factorize(jacobian);
    if (lu_.info() == Eigen::Success)
      delta = -lu_.solve(residual_);
    if (delta.size() > 0 && !delta.allFinite())
      delta.resize(0);
    return delta;
  }
  // The exact tangent; where compressed springs make the Jacobian indefinite, more of the
  // (positive) inertia is added until it is positive definite, so the direction descends G.
  for (double extra = 0.0; extra < 1e8; extra = std::max(1e-3, 10.0 * extra))
  {
    assembleJacobian(1.0 + extra, 1.0 + alpha_);
    if (linear_solver_->solve(jacobian_, residual_, delta, slack))
    {
      delta = -delta;
      break;
    }
    delta.resize(0);
  }
  if (delta.size() > 0 && (!delta.allFinite() || residual_.dot(delta) >= 0.0))
    delta.resize(0);
  return delta;
}

void ImplicitNewmark::inertiaBlocks(int block_size, Eigen::VectorXd& blocks) const
{
  blocks.setZero(inertia_.rows() * block_size);
  for (int col = 0; col < inertia_.outerSize(); ++col)
    for (SparseMatrix::InnerIterator it(inertia_, col); it; ++it)
      if (it.row() / block_size == col / block_size)
        blocks[(col / block_size) * block_size * block_size + (col % block_size) * block_size + it.row() % block_size] +=
            it.value();
}

void ImplicitNewmark::assembleJacobian(double inertia_factor, double tangent_factor)
{
  if (tangent_.isCompressed() && (tangent_pattern_.changedTo(tangent_) || !inertia_mapped_))
  {
    // The inertia's entries in the tangent's values, when the tangent's pattern holds them all.
    inertia_mapped_ = true;
    inertia_fits_ = true;
    jacobian_.resize(0, 0);  // of another pattern
    inertia_on_tangent_.setZero(tangent_.nonZeros());
    for (int col = 0; col < inertia_.outerSize() && inertia_fits_; ++col)
      for (SparseMatrix::InnerIterator it(inertia_, col); it; ++it)
      {
        const int* begin = tangent_.innerIndexPtr() + tangent_.outerIndexPtr()[col];
        const int* end = tangent_.innerIndexPtr() + tangent_.outerIndexPtr()[col + 1];
        const int* found = std::lower_bound(begin, end, static_cast<int>(it.row()));
        if (found == end || *found != it.row())
        {
          inertia_fits_ = false;
          break;
        }
        inertia_on_tangent_[found - tangent_.innerIndexPtr()] = it.value();
      }
  }
  if (tangent_.isCompressed() && inertia_fits_)
  {
    // J has the tangent's pattern: only its values are computed.
    if (jacobian_.rows() == 0)
      jacobian_ = tangent_;
    Eigen::Map<Eigen::VectorXd>(jacobian_.valuePtr(), jacobian_.nonZeros()) =
        inertia_factor * inertia_on_tangent_ +
        tangent_factor * Eigen::Map<const Eigen::VectorXd>(tangent_.valuePtr(), tangent_.nonZeros());
    return;
  }
  jacobian_ = inertia_factor * inertia_ + tangent_factor * tangent_;
  jacobian_.makeCompressed();
  inertia_mapped_ = false;  // jacobian_ no longer has the tangent's pattern
}

double ImplicitNewmark::roundoff(const ForceModel& model, const State& next) const
{
  // a' = (q' - y) / (beta h^2) differences nearly equal numbers: its round-off is about
  // eps |q'| / (beta h^2), which no Newton iteration removes when the motion is tiny; F(q') carries
  // the round-off of the spring forces.
  return 100.0 * std::numeric_limits<double>::epsilon() / (beta_ * h_ * h_) * system_.mass.cwiseProduct(next.q).norm() +
         10.0 * model.roundoff();
}

double ImplicitNewmark::residual(ForceModel& model, const State& s, State& next)
{
  kinematics(s, next);
  model.force(next.q, force_);
  force_ *= 1.0 + alpha_;
  residual_ = system_.mass.cwiseProduct(next.a) + (1.0 + alpha_) * (damping_ * next.v);
  inertial_norm_ = residual_.norm();
  residual_ -= force_ + old_terms_;
  return residual_.norm();
}

}  // namespace modal_mass_spring
