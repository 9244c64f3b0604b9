// Wires grid, basis, force models and integrators into the three methods.
#include "modal_mass_spring/simulation.h"

#include "modal_mass_spring/spring_forces.h"

#include <cmath>
#include <sstream>
#include <stdexcept>

namespace modal_mass_spring
{
namespace
{

void requireNonNegative(const std::string& name, double value)
{
  if (!std::isfinite(value) || value < 0.0)
  {
    std::ostringstream msg;
    msg << "invalid parameter '" << name << "' = " << value << ": must be a finite number >= 0";
    throw std::invalid_argument(msg.str());
  }
}

void validateTimeStep(double dt)
{
  if (!std::isfinite(dt) || dt <= 0.0)
  {
    std::ostringstream msg;
    msg << "invalid parameter 'time_step' = " << dt << ": must be a finite number of seconds > 0";
    throw std::invalid_argument(msg.str());
  }
}

SparseMatrix diagonalMatrix(const Eigen::VectorXd& d)
{
  SparseMatrix m(d.size(), d.size());
  m.reserve(Eigen::VectorXi::Ones(d.size()));
  for (int k = 0; k < d.size(); ++k)
    m.insert(k, k) = d[k];
  return m;
}

}  // namespace

const std::vector<std::string>& methodNames()
{
  static const std::vector<std::string> names{"full", "linear", "physical"};
  return names;
}

std::string toString(Method method)
{
  return methodNames()[static_cast<int>(method)];
}

Method parseMethod(const std::string& name)
{
  const auto& names = methodNames();
  for (size_t k = 0; k < names.size(); ++k)
    if (names[k] == name)
      return static_cast<Method>(k);
  throw std::invalid_argument("invalid parameter 'method' = '" + name + "': must be one of full, linear, physical");
}

Simulation::Simulation(const GridParams& grid_params, const SimulationParams& params)
  : grid_(grid_params), params_(params)
{
  requireNonNegative("alpha", params_.alpha);
  requireNonNegative("beta", params_.beta);
  validateTimeStep(params_.time_step);
  requireNonNegative("divergence_limit", params_.divergence_limit);
  const int n = grid_.numFreeDofs();
  if (params_.num_modes < 1 || params_.num_modes > n)
    throw std::invalid_argument("invalid parameter 'num_modes' = " + std::to_string(params_.num_modes) +
                                ": must be in [1, " + std::to_string(n) + "], the number of free degrees of freedom");

  const GridParams& g = grid_.params();
  limit_ = params_.divergence_limit > 0.0 ? params_.divergence_limit
                                          : 100.0 * g.spacing * std::max(g.rows, g.cols);

  const Eigen::VectorXd& x0 = grid_.initialPositions();
  stiffness_ = tangentStiffness(grid_, x0);
  mass_ = Eigen::VectorXd::Constant(n, grid_.particleMass());
  basis_ = computeModalBasis(stiffness_, mass_, params_.num_modes);

  full_force_ = std::make_unique<FullForceModel>(grid_, x0);
  linear_force_ = std::make_unique<LinearModalForceModel>(grid_, basis_, x0);
  physical_force_ = std::make_unique<PhysicalModalForceModel>(grid_, basis_, x0);
  buildIntegrators();
  reset();
}

void Simulation::buildIntegrators()
{
  // Rayleigh damping: alpha M + beta K(x0); in modal coordinates diag(alpha + beta lambda^2).
  SparseMatrix full_damping = params_.alpha * diagonalMatrix(mass_) + params_.beta * stiffness_;
  full_integrator_ = std::make_unique<ExplicitNewmark>(MassDamping{mass_, full_damping}, params_.time_step);
  const Eigen::VectorXd modal_damping =
      (params_.alpha + params_.beta * basis_.eigenvalues.array()).matrix();
  modal_integrator_ = std::make_unique<ExplicitNewmark>(
      MassDamping{Eigen::VectorXd::Ones(basis_.eigenvalues.size()), diagonalMatrix(modal_damping)},
      params_.time_step);
}

ForceModel& Simulation::forceModel()
{
  switch (params_.method)
  {
    case Method::Full:
      return *full_force_;
    case Method::Linear:
      return *linear_force_;
    default:
      return *physical_force_;
  }
}

Integrator& Simulation::integrator()
{
  return isModal() ? *modal_integrator_ : *full_integrator_;
}

void Simulation::initializeAcceleration()
{
  integrator().initialize(forceModel(), state_);
}

void Simulation::setMethod(Method method)
{
  const Eigen::VectorXd u = displacement();
  const Eigen::VectorXd v = velocity();
  params_.method = method;
  setPhysicalState(u, v);
}

void Simulation::setPhysicalState(const Eigen::VectorXd& u, const Eigen::VectorXd& v)
{
  if (isModal())
  {
    // Mass-orthonormal basis: the M-orthogonal projection onto span(Phi) is X = Phi^T M u.
    state_.q = basis_.phi.transpose() * mass_.cwiseProduct(u);
    state_.v = basis_.phi.transpose() * mass_.cwiseProduct(v);
  }
  else
  {
    state_.q = u;
    state_.v = v;
  }
  initializeAcceleration();
  diverged_ = false;
}

void Simulation::setTimeStep(double dt)
{
  validateTimeStep(dt);
  params_.time_step = dt;
  buildIntegrators();
  initializeAcceleration();
}

void Simulation::reset()
{
  const int n = grid_.numFreeDofs();
  setPhysicalState(Eigen::VectorXd::Zero(n), Eigen::VectorXd::Zero(n));
  step_count_ = 0;
}

StepResult Simulation::step(int steps)
{
  StepResult result;
  if (diverged_)
  {
    result.diverged = true;
    result.message = "the simulation diverged at step " + std::to_string(step_count_) +
                     "; reset or switch method to go on";
    return result;
  }
  // Weights so that the check reads as an RMS displacement in metres, in both kinds of coordinates.
  const double total_mass = mass_.sum();
  for (int k = 0; k < steps; ++k)
  {
    const bool ok = integrator().step(forceModel(), state_, next_);
    const double norm2 = isModal() ? next_.q.squaredNorm() : next_.q.cwiseAbs2().dot(mass_);
    const bool finite = next_.q.allFinite() && next_.v.allFinite() && next_.a.allFinite();
    if (!ok || !finite || std::sqrt(norm2 / total_mass) > limit_)
    {
      diverged_ = true;
      result.diverged = true;
      std::ostringstream msg;
      msg << "method '" << toString(params_.method) << "' diverged at step " << step_count_ + 1
          << " with time_step " << params_.time_step << " s ("
          << (!ok ? "the step failed" : !finite ? "non-finite state" : "displacement beyond divergence_limit")
          << "); the last good state is kept; a smaller time_step or more damping may help";
      result.message = msg.str();
      return result;
    }
    std::swap(state_, next_);
    ++step_count_;
    ++result.steps_taken;
  }
  return result;
}

Eigen::VectorXd Simulation::displacement() const
{
  return isModal() ? Eigen::VectorXd(basis_.phi * state_.q) : state_.q;
}

Eigen::VectorXd Simulation::velocity() const
{
  return isModal() ? Eigen::VectorXd(basis_.phi * state_.v) : state_.v;
}

Eigen::VectorXd Simulation::positions() const
{
  Eigen::VectorXd x = grid_.initialPositions();
  grid_.addFree(displacement(), x);
  return x;
}

double Simulation::kineticEnergy() const
{
  // Phi is mass-orthonormal, so 1/2 V^T V is the physical kinetic energy of u' = Phi V.
  return isModal() ? 0.5 * state_.v.squaredNorm() : 0.5 * state_.v.cwiseAbs2().dot(mass_);
}

double Simulation::totalEnergy() const
{
  const Eigen::VectorXd x = positions();
  return kineticEnergy() + springEnergy(grid_, x) + gravityEnergy(grid_, x);
}

}  // namespace modal_mass_spring
