// Wires grid, basis, force models and integrators into the three methods.
#include "modal_mass_spring/simulation.h"

#include "modal_mass_spring/equilibrium.h"
#include "modal_mass_spring/spring_forces.h"
#include "modal_mass_spring/validation.h"

#include <chrono>
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
    rejectParameter(name, value, "must be a finite number >= 0");
}

void validateTimeStep(double dt)
{
  if (!std::isfinite(dt) || dt <= 0.0)
    rejectParameter("time_step", dt, "must be a finite number of seconds > 0");
}

// A derived scale must be a number the physics can square and sum without overflow or underflow.
bool representable(double value)
{
  return std::isfinite(value) && value > 0.0 && value >= 1e-100 && value <= 1e100;
}

// Refuses parameters whose combinations would give infinite or vanishing frequencies, forces or
// energies later on (for example mass 1e300: lambda^2 = k / m underflows; spacing 1e-300: lengths
// squared underflow), naming the parameters responsible.
void validateScales(const GridParams& g)
{
  const double side = g.spacing * std::max(g.rows, g.cols);
  if (!representable(g.spacing * g.spacing) || !representable(side * side))
    rejectParameter("spacing", g.spacing,
                    "must keep spacing^2 and the grid's side squared within [1e-100, 1e100] m^2 (lengths are squared)");
  std::vector<std::pair<std::string, double>> stiffnesses{{"structural_stiffness", g.structural_stiffness},
                                                          {"shear_stiffness", g.shear_stiffness}};
  if (g.bending)
    stiffnesses.emplace_back("bending_stiffness", g.bending_stiffness);
  for (const auto& [name, k] : stiffnesses)
  {
    std::ostringstream value;
    value << k << " with mass = " << g.mass << " and spacing = " << g.spacing;
    if (!representable(k / g.mass))
      rejectParameter(name + " / mass", value.str(),
                      "lambda^2 = stiffness / mass must be within [1e-100, 1e100] s^-2 (frequencies would overflow or vanish)");
    if (!representable(k * g.spacing * g.spacing * static_cast<double>(g.rows) * g.cols))
      rejectParameter(name + " * spacing^2", value.str(),
                      "spring energies (stiffness * spacing^2 per spring) must be within [1e-100, 1e100] J");
  }
  const double weight = g.mass * g.gravity.norm();
  if (weight > 0.0 && !representable(weight * side * static_cast<double>(g.rows) * g.cols))
  {
    std::ostringstream value;
    value << g.mass << " with gravity " << g.gravity.norm() << " m/s^2 and spacing = " << g.spacing;
    rejectParameter("mass", value.str(), "the grid's weight times its size must be within [1e-100, 1e100] J");
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

// Finds `name` among `names` (the enum's values in order) or throws naming the parameter.
int parseName(const std::string& parameter, const std::string& name, const std::vector<std::string>& names)
{
  for (size_t k = 0; k < names.size(); ++k)
    if (names[k] == name)
      return static_cast<int>(k);
  std::string allowed;
  for (size_t k = 0; k < names.size(); ++k)
    allowed += (k ? ", " : "") + names[k];
  throw std::invalid_argument("invalid parameter '" + parameter + "' = '" + name + "': must be one of " + allowed);
}

const std::vector<std::string> kLinearizations{"rest", "equilibrium"};
const std::vector<std::string> kIntegrators{"explicit", "implicit"};
const std::vector<std::string> kInitialStates{"initial", "equilibrium"};

}  // namespace

std::string toString(Linearization value) { return kLinearizations[static_cast<int>(value)]; }
Linearization parseLinearization(const std::string& name)
{
  return static_cast<Linearization>(parseName("linearization", name, kLinearizations));
}
std::string toString(IntegratorKind value) { return kIntegrators[static_cast<int>(value)]; }
IntegratorKind parseIntegrator(const std::string& name)
{
  return static_cast<IntegratorKind>(parseName("integrator", name, kIntegrators));
}
std::string toString(InitialState value) { return kInitialStates[static_cast<int>(value)]; }
InitialState parseInitialState(const std::string& name)
{
  return static_cast<InitialState>(parseName("initial_state", name, kInitialStates));
}

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
  return static_cast<Method>(parseName("method", name, methodNames()));
}

void validateParameters(const GridParams& grid, const SimulationParams& p)
{
  validateGridParams(grid);
  validateScales(grid);
  const long long n = countFreeDofs(grid);
  if (p.num_modes < 1 || p.num_modes > n)
    rejectParameter("num_modes", p.num_modes,
                    "must be in [1, " + std::to_string(n) + "], the number of free degrees of freedom");
  requireNonNegative("alpha", p.alpha);
  requireNonNegative("beta", p.beta);
  validateTimeStep(p.time_step);
  requireNonNegative("divergence_limit", p.divergence_limit);
  if (p.newton_max_iterations < 1)
    rejectParameter("newton_max_iterations", p.newton_max_iterations, "must be an integer >= 1");
  if (!std::isfinite(p.memory_limit_gb) || p.memory_limit_gb <= 0.0)
    rejectParameter("memory_limit_gb", p.memory_limit_gb, "must be a finite number of GB > 0");
  const double needed_gb = estimateMemoryBytes(grid, p) / 1e9;
  if (needed_gb > p.memory_limit_gb)
  {
    std::ostringstream value;
    value << grid.rows << " x " << grid.cols << " grid (" << grid.dimension << "D), num_modes = " << p.num_modes;
    std::ostringstream allowed;
    allowed.precision(3);
    allowed << "needs about " << needed_gb << " GB, above memory_limit_gb = " << p.memory_limit_gb
            << " GB; use a smaller grid or fewer modes, or raise memory_limit_gb if the machine has the memory";
    rejectParameter("rows, cols, num_modes", value.str(), allowed.str());
  }
}

double estimateMemoryBytes(const GridParams& g, const SimulationParams& p)
{
  const double particles = static_cast<double>(g.rows) * g.cols;
  const double dim = g.dimension;
  const double n = static_cast<double>(countFreeDofs(g));
  const double r = p.num_modes;
  // Stiffness: a dim x dim block per particle and neighbour (8 structural and shear, 4 bending),
  // 12 bytes an entry, held three times at once while the basis is built (K, M^-1/2 K M^-1/2,
  // and the shifted copy).
  const double blocks = 1.0 + 8.0 + (g.bending ? 4.0 : 0.0);
  double bytes = 3.0 * 12.0 * blocks * dim * dim * particles;
  // A sparse LDLT of a grid's stiffness with a fill-reducing ordering has about c n log2 n entries;
  // one is alive at a time (basis, equilibrium Newton, implicit full).
  const double fill = dim == 3 ? 8.0 : 5.0;
  bytes += 12.0 * fill * n * std::log2(std::max(n, 2.0));
  // The basis: Phi, the physical model's Phi^T and (K Phi)^T, the Lanczos vectors and the Ritz
  // vectors of deflated passes; a dense eigensolver when r is close to n.
  bytes += 8.0 * n * (3.0 * r + std::max(2.0 * r + 1.0, r + 20.0) + 2.0 * r);
  if (r + 1.0 >= n)
    bytes += 3.0 * 8.0 * n * n;
  // Positions, forces, states and scratch vectors over all dofs, and the springs.
  bytes += 8.0 * 40.0 * dim * particles + 24.0 * (blocks - 1.0) / 2.0 * particles;
  return bytes;
}

Simulation::Simulation(const GridParams& grid_params, const SimulationParams& params, const StageFn& on_stage)
  : grid_((validateParameters(grid_params, params), grid_params)), params_(params)
{
  auto stage = [&](const std::string& name) {
    if (on_stage)
      on_stage(name);
  };
  using Clock = std::chrono::steady_clock;
  auto since = [](Clock::time_point start) { return std::chrono::duration<double>(Clock::now() - start).count(); };
  const int n = grid_.numFreeDofs();
  const GridParams& g = grid_.params();
  limit_ = params_.divergence_limit > 0.0 ? params_.divergence_limit
                                          : 100.0 * g.spacing * std::max(g.rows, g.cols);

  x_ref_ = x_start_ = grid_.initialPositions();
  if (params_.linearization == Linearization::Equilibrium || params_.initial_state == InitialState::Equilibrium)
  {
    stage("equilibrium");
    const auto start = Clock::now();
    const Equilibrium equilibrium = solveEquilibrium(grid_, grid_.initialPositions());
    linearization_.equilibrium_seconds = since(start);
    linearization_.equilibrium_solved = true;
    linearization_.equilibrium_iterations = equilibrium.iterations;
    linearization_.equilibrium_residual = equilibrium.residual;
    if (params_.linearization == Linearization::Equilibrium)
      x_ref_ = equilibrium.positions;
    if (params_.initial_state == InitialState::Equilibrium)
      x_start_ = equilibrium.positions;
  }
  // At a hanging equilibrium compressed springs would make K indefinite: their geometric part is
  // dropped so that no mode has a negative lambda^2. At rest no spring is compressed.
  stage("stiffness");
  const auto stiffness_start = Clock::now();
  stiffness_ = tangentStiffness(grid_, x_ref_, CompressedSprings::Drop, &linearization_.dropped_compressed_springs);
  linearization_.stiffness_seconds = since(stiffness_start);
  mass_ = Eigen::VectorXd::Constant(n, grid_.particleMass());
  total_mass_ = mass_.sum();
  basis_ = computeModalBasis(stiffness_, mass_, params_.num_modes, on_stage);

  full_force_ = std::make_unique<FullForceModel>(grid_, x_ref_);
  linear_force_ = std::make_unique<LinearModalForceModel>(grid_, basis_, x_ref_);
  physical_force_ = std::make_unique<PhysicalModalForceModel>(grid_, basis_, x_ref_);
  buildIntegrators();
  reset();
}

void Simulation::buildIntegrators()
{
  auto make = [this](MassDamping system) -> std::unique_ptr<Integrator> {
    if (params_.integrator == IntegratorKind::Implicit)
      return std::make_unique<ImplicitNewmark>(std::move(system), params_.time_step, params_.newton_max_iterations);
    return std::make_unique<ExplicitNewmark>(std::move(system), params_.time_step);
  };
  // Rayleigh damping with the constant K of the linearization point: alpha M + beta K(x_ref); in
  // modal coordinates diag(alpha + beta lambda^2).
  full_integrator_ = make(MassDamping{mass_, params_.alpha * diagonalMatrix(mass_) + params_.beta * stiffness_});
  const Eigen::VectorXd modal_damping = (params_.alpha + params_.beta * basis_.eigenvalues.array()).matrix();
  modal_integrator_ =
      make(MassDamping{Eigen::VectorXd::Ones(basis_.eigenvalues.size()), diagonalMatrix(modal_damping)});
}

const ImplicitNewmark* Simulation::implicitIntegrator() const
{
  return dynamic_cast<const ImplicitNewmark*>(isModal() ? modal_integrator_.get() : full_integrator_.get());
}

int Simulation::lastNewtonIterations() const
{
  return implicitIntegrator() ? implicitIntegrator()->lastIterations() : 0;
}

int Simulation::lastImplicitSubsteps() const
{
  return implicitIntegrator() ? implicitIntegrator()->lastSubsteps() : 0;
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
  const bool was_modal = isModal();
  params_.method = method;
  if (!isModal())
  {
    setPhysicalState(u, v);
  }
  else if (was_modal)
  {
    assignState(u - offset_, v);  // the same X
  }
  else
  {
    const Eigen::VectorXd modal = basis_.phi.transpose() * mass_.cwiseProduct(u);
    setOffset(u - basis_.phi * modal);
    assignState(basis_.phi * modal, v);
  }
}

void Simulation::setOffset(const Eigen::VectorXd& offset)
{
  offset_ = offset;
  Eigen::VectorXd reference = x_ref_;
  grid_.addFree(offset_, reference);
  linear_force_->setReference(reference);
  physical_force_->setReference(reference);
}

void Simulation::setPhysicalState(const Eigen::VectorXd& u, const Eigen::VectorXd& v)
{
  setOffset(Eigen::VectorXd::Zero(u.size()));
  assignState(u, v);
}

void Simulation::assignState(const Eigen::VectorXd& u, const Eigen::VectorXd& v)
{
  projection_error_ = 0.0;
  if (isModal())
  {
    // Mass-orthonormal basis: the M-orthogonal projection onto span(Phi) is X = Phi^T M u.
    state_.q = basis_.phi.transpose() * mass_.cwiseProduct(u);
    state_.v = basis_.phi.transpose() * mass_.cwiseProduct(v);
    const Eigen::VectorXd residual = u - basis_.phi * state_.q;
    const int dim = grid_.dimension();
    for (int k = 0; k + dim <= residual.size(); k += dim)
      projection_error_ = std::max(projection_error_, residual.segment(k, dim).norm());
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
  const Eigen::VectorXd start = grid_.gatherFree(x_start_ - x_ref_);
  setPhysicalState(start, Eigen::VectorXd::Zero(start.size()));
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
  for (int k = 0; k < steps; ++k)
  {
    const bool ok = integrator().step(forceModel(), state_, next_);
    const double norm2 = isModal() ? next_.q.squaredNorm() : next_.q.cwiseAbs2().dot(mass_);
    const bool finite = next_.q.allFinite() && next_.v.allFinite() && next_.a.allFinite();
    if (!ok || !finite || std::sqrt(norm2 / total_mass_) > limit_)
    {
      diverged_ = true;
      result.diverged = true;
      std::ostringstream msg;
      msg << "method '" << toString(params_.method) << "' diverged at step " << step_count_ + 1
          << " with time_step " << params_.time_step << " s ("
          << (!ok ? "the implicit Newton iteration did not converge in newton_max_iterations = " +
                        std::to_string(params_.newton_max_iterations) + ", even in 1/16 of the step"
                  : !finite ? "non-finite state" : "displacement beyond divergence_limit")
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
  return isModal() ? Eigen::VectorXd(offset_ + basis_.phi * state_.q) : state_.q;
}

Eigen::VectorXd Simulation::velocity() const
{
  return isModal() ? Eigen::VectorXd(basis_.phi * state_.v) : state_.v;
}

Eigen::VectorXd Simulation::positions() const
{
  Eigen::VectorXd x = x_ref_;
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
