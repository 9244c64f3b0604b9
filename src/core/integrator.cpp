// The explicit Newmark scheme of the paper.
#include "modal_mass_spring/integrator.h"

#include <algorithm>
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
  state.a = (f - system_.damping * state.v).cwiseQuotient(system_.mass);
}

ExplicitNewmark::ExplicitNewmark(MassDamping system, double dt) : Integrator(std::move(system), dt)
{
  SparseMatrix mass(system_.mass.size(), system_.mass.size());
  mass.setIdentity();
  mass = system_.mass.asDiagonal() * mass;
  const SparseMatrix lhs = mass + (0.5 * dt_) * system_.damping;
  diagonal_ = isDiagonal(lhs);
  if (diagonal_)
  {
    inverse_diagonal_ = lhs.diagonal().cwiseInverse();
  }
  else
  {
    ldlt_.compute(lhs);
    if (ldlt_.info() != Eigen::Success)
      throw std::runtime_error("explicit Newmark: M + dt/2 C is not positive definite");
  }
}

bool ExplicitNewmark::step(ForceModel& model, const State& s, State& next)
{
  const Eigen::VectorXd& m = system_.mass;
  next.q = s.q + dt_ * s.v + (0.5 * dt_ * dt_) * s.a;
  model.force(next.q, force_);
  rhs_ = m.cwiseProduct(s.v) + (0.5 * dt_) * (m.cwiseProduct(s.a) + force_);
  if (diagonal_)
    next.v = inverse_diagonal_.cwiseProduct(rhs_);
  else
    next.v = ldlt_.solve(rhs_);
  next.a = (force_ - system_.damping * next.v).cwiseQuotient(m);
  return true;
}

}  // namespace modal_mass_spring

namespace modal_mass_spring
{

ImplicitNewmark::ImplicitNewmark(MassDamping system, double dt, int max_iterations, double tolerance)
  : Integrator(std::move(system), dt), max_iterations_(max_iterations), tolerance_(tolerance)
{
  SparseMatrix mass(system_.mass.size(), system_.mass.size());
  mass.setIdentity();
  mass = system_.mass.asDiagonal() * mass;
  inertia_ = (4.0 / (dt_ * dt_)) * mass + (2.0 / dt_) * system_.damping;
}

void ImplicitNewmark::analyzeIfNewPattern(const SparseMatrix& jacobian)
{
  // The symbolic analysis (fill-reducing ordering) is the costly part for the full model, whose
  // pattern never changes; a reduced tangent can gain or lose exact zeros from step to step.
  const int* outer = jacobian.outerIndexPtr();
  const int* inner = jacobian.innerIndexPtr();
  const size_t num_outer = jacobian.outerSize() + 1;
  const size_t num_inner = jacobian.nonZeros();
  const bool same = pattern_outer_.size() == num_outer && pattern_inner_.size() == num_inner &&
                    std::equal(outer, outer + num_outer, pattern_outer_.begin()) &&
                    std::equal(inner, inner + num_inner, pattern_inner_.begin());
  if (!same)
  {
    ldlt_.analyzePattern(jacobian);
    pattern_outer_.assign(outer, outer + num_outer);
    pattern_inner_.assign(inner, inner + num_inner);
  }
}

void ImplicitNewmark::kinematics(const State& s, State& next) const
{
  next.a = (4.0 / (dt_ * dt_)) * (next.q - s.q - dt_ * s.v) - s.a;
  next.v = (2.0 / dt_) * (next.q - s.q) - s.v;
}

bool ImplicitNewmark::step(ForceModel& model, const State& s, State& next)
{
  // The explicit step is the predictor.
  next.q = s.q + dt_ * s.v + (0.5 * dt_ * dt_) * s.a;
  const int iterations = model.isLinear() ? 1 : max_iterations_;
  for (last_iterations_ = 1; last_iterations_ <= iterations; ++last_iterations_)
  {
    kinematics(s, next);
    model.force(next.q, force_);
    const Eigen::VectorXd inertial = system_.mass.cwiseProduct(next.a) + system_.damping * next.v;
    residual_ = inertial - force_;
    // Converged when the unbalanced force is small against the forces at play.
    if (!model.isLinear() && last_iterations_ > 1 &&
        residual_.norm() <= tolerance_ * (force_.norm() + inertial.norm() + 1e-300))
      break;
    model.tangentStiffness(next.q, tangent_);
    SparseMatrix jacobian = inertia_ + tangent_;
    jacobian.makeCompressed();
    analyzeIfNewPattern(jacobian);
    ldlt_.factorize(jacobian);
    if (ldlt_.info() != Eigen::Success)
      return false;
    next.q -= ldlt_.solve(residual_);
    if (!next.q.allFinite())
      return false;
    if (model.isLinear())
    {
      kinematics(s, next);
      return true;
    }
  }
  if (last_iterations_ > iterations)
    return false;
  kinematics(s, next);
  return true;
}

}  // namespace modal_mass_spring
