// The explicit Newmark scheme of the paper.
#include "modal_mass_spring/integrator.h"

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
