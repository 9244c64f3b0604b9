// Google Benchmark of the core: basis construction (with and without modal derivatives), one step of each method, the
// extra cost of moving handles, position reconstruction and one evaluation of all spring forces.
#include "modal_mass_spring/adaptive.h"
#include "modal_mass_spring/cpu_time.h"
#include "modal_mass_spring/force_model.h"
#include "modal_mass_spring/modal_derivatives.h"
#include "modal_mass_spring/simulation.h"
#include "modal_mass_spring/spring_forces.h"
#include "dynamics/integrator.h"
#include "solvers/equilibrium.h"
#include "supernodal_cholesky.h"
#include "swinging_cloth.h"

#include <Eigen/Geometry>
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <map>
#include <memory>
#include <numeric>
#include <stdexcept>
#include <string>
#include <tuple>

#include <time.h>

using namespace modal_mass_spring;

namespace
{

GridParams square(int size, int dimension)
{
  GridParams p;
  p.rows = size;
  p.cols = size;
  p.dimension = dimension;
  return p;
}

// A 3D sheet disturbed out of its plane, gravity off, so no method drifts away during a long loop.
std::unique_ptr<Simulation> disturbedSheet(int size, int r, Method method,
                                           IntegratorKind integrator = IntegratorKind::Explicit)
{
  GridParams g = square(size, 3);
  g.gravity.setZero();
  SimulationParams s;
  s.method = method;
  s.num_modes = r;
  s.time_step = 1e-4;
  s.integrator = integrator;
  auto sim = std::make_unique<Simulation>(g, s);
  std::srand(1);
  const int n = sim->grid().numFreeDofs();
  sim->setPhysicalState(1e-3 * g.spacing * Eigen::VectorXd::Random(n), Eigen::VectorXd::Zero(n));
  return sim;
}

// One sheet per (size, r, method, integrator), built on first use and kept: Google Benchmark calls a
// benchmark several times (to size its iterations, and per repetition), and a 200 x 200 basis and
// cubature take seconds to build.
Simulation& sharedSheet(int size, int r, Method method, IntegratorKind integrator = IntegratorKind::Explicit)
{
  static std::map<std::tuple<int, int, Method, IntegratorKind>, std::unique_ptr<Simulation>> built;
  auto& sim = built[{size, r, method, integrator}];
  if (!sim)
    sim = disturbedSheet(size, r, method, integrator);
  return *sim;
}

const std::vector<int64_t> kSizes{5, 10, 20, 50, 100};

// The basis is timed on 2D grids: a flat 3D sheet at rest has only zero out-of-plane modes.
void BM_Basis2D(benchmark::State& state)
{
  const Grid grid(square(static_cast<int>(state.range(0)), 2));
  const SparseMatrix k = tangentStiffness(grid, grid.initialPositions());
  const Eigen::VectorXd mass = Eigen::VectorXd::Constant(grid.numFreeDofs(), grid.particleMass());
  for (auto _ : state)
    benchmark::DoNotOptimize(computeModalBasis(k, mass, static_cast<int>(state.range(1))));
  state.counters["free_dofs"] = grid.numFreeDofs();
}
BENCHMARK(BM_Basis2D)->ArgsProduct({kSizes, {4, 30}})->Unit(benchmark::kMillisecond);

// A 3D sheet hanging at its equilibrium under gravity, with K there: solved once per size (the
// equilibrium is not what these benchmarks time).
struct HangingSheet
{
  explicit HangingSheet(int size)
    : grid(square(size, 3)), x_eq(solveEquilibrium(grid, grid.initialPositions()).positions),
      stiffness(tangentStiffness(grid, x_eq, CompressedSprings::Drop)),
      mass(Eigen::VectorXd::Constant(grid.numFreeDofs(), grid.particleMass()))
  {
  }
  Grid grid;
  Eigen::VectorXd x_eq;
  SparseMatrix stiffness;
  Eigen::VectorXd mass;
};

const HangingSheet& hangingSheet(int size)
{
  static std::map<int, std::unique_ptr<HangingSheet>> sheets;
  auto& sheet = sheets[size];
  if (!sheet)
    sheet = std::make_unique<HangingSheet>(size);
  return *sheet;
}

const std::vector<int64_t> kDerivativeSizes{20, 50, 100};

// The r lowest modes of a hanging 3D sheet, and the same plus r directions from their modal
// derivatives (r (r + 1) / 2 solves with one factorisation of K, and the mass-PCA): the difference is
// what the derivatives add to a start-up.
void BM_BasisHanging3D(benchmark::State& state)
{
  const HangingSheet& sheet = hangingSheet(static_cast<int>(state.range(0)));
  for (auto _ : state)
    benchmark::DoNotOptimize(computeModalBasis(sheet.stiffness, sheet.mass, static_cast<int>(state.range(1))));
  state.counters["free_dofs"] = sheet.grid.numFreeDofs();
}
BENCHMARK(BM_BasisHanging3D)->ArgsProduct({kDerivativeSizes, {10, 20}})->Unit(benchmark::kMillisecond);

void BM_BasisWithDerivativesHanging3D(benchmark::State& state)
{
  const HangingSheet& sheet = hangingSheet(static_cast<int>(state.range(0)));
  const int r = static_cast<int>(state.range(1));
  for (auto _ : state)
  {
    const ModalBasis modes = computeModalBasis(sheet.stiffness, sheet.mass, r);
    benchmark::DoNotOptimize(buildDerivativeBasis(sheet.grid, sheet.x_eq, sheet.stiffness, sheet.mass, modes, r));
  }
  state.counters["free_dofs"] = sheet.grid.numFreeDofs();
}
BENCHMARK(BM_BasisWithDerivativesHanging3D)->ArgsProduct({kDerivativeSizes, {10, 20}})->Unit(benchmark::kMillisecond);

void stepBenchmark(benchmark::State& state, Method method)
{
  Simulation* sim = &sharedSheet(static_cast<int>(state.range(0)), static_cast<int>(state.range(1)), method);
  for (auto _ : state)
    benchmark::DoNotOptimize(sim->step(1));
  if (sim->diverged())
    state.SkipWithError("diverged");
}
void BM_StepFull(benchmark::State& state) { stepBenchmark(state, Method::Full); }
void BM_StepLinear(benchmark::State& state) { stepBenchmark(state, Method::Linear); }
void BM_StepPhysical(benchmark::State& state) { stepBenchmark(state, Method::Physical); }
BENCHMARK(BM_StepFull)->ArgsProduct({kSizes, {30}})->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_StepLinear)->ArgsProduct({kSizes, {4, 30}})->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_StepPhysical)->ArgsProduct({kSizes, {4, 30}})->Unit(benchmark::kMicrosecond);

// Cubature beside physical on the larger sheets: its step should not grow with the grid.
const std::vector<int64_t> kCubatureSizes{20, 50, 100, 200};
void BM_StepCubature(benchmark::State& state) { stepBenchmark(state, Method::Cubature); }
BENCHMARK(BM_StepPhysical)->Args({200, 30})->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_StepCubature)->ArgsProduct({kCubatureSizes, {4, 30}})->Unit(benchmark::kMicrosecond);

// Moving handles: a 2D sheet (top row fixed, gravity off) with 1 or 4 single-particle handles on
// its bottom row, moved along a 1 cm, 1 Hz sine every step (setHandleMotion, then step), against the
// same sheet with those particles fixed (handles = 0 holds the corner fixed, -4 the four): the
// difference is the handles' cost per step (the moving references, Psi dx_b, the interface load).
void handleBenchmark(benchmark::State& state, Method method)
{
  const int size = static_cast<int>(state.range(0));
  const int count = static_cast<int>(std::abs(state.range(1)));
  const bool moving = state.range(1) > 0;
  GridParams g = square(size, 2);
  g.gravity.setZero();
  for (int c = 0; c < size; ++c)
    g.fixed.push_back(c);
  std::vector<int> held;
  for (int k = 0; k < count; ++k)
    held.push_back((size - 1) * size + k * (size - 1) / std::max(count - 1, 1));
  if (moving)
    for (int particle : held)
      g.handles.push_back({particle});
  else
    g.fixed.insert(g.fixed.end(), held.begin(), held.end());
  SimulationParams s;
  s.method = method;
  s.num_modes = 30;
  Simulation sim(g, s);
  const int nb = sim.grid().numHandleDofs();
  Eigen::VectorXd x0(nb);
  for (int k = 0; k < nb; ++k)
    x0[k] = sim.linearizationPositions()[sim.grid().handleDofs()[k]];
  const Eigen::VectorXd ones = Eigen::VectorXd::Ones(nb);
  const double w = 2.0 * M_PI, amplitude = 0.01;
  for (auto _ : state)
  {
    if (moving)
    {
      const double t = sim.time() + s.time_step;
      sim.setHandleMotion(x0 + amplitude * std::sin(w * t) * ones, amplitude * w * std::cos(w * t) * ones,
                          -amplitude * w * w * std::sin(w * t) * ones);
    }
    benchmark::DoNotOptimize(sim.step(1));
  }
  if (sim.diverged())
    state.SkipWithError("diverged");
}
void BM_HandlesFull(benchmark::State& state) { handleBenchmark(state, Method::Full); }
void BM_HandlesLinear(benchmark::State& state) { handleBenchmark(state, Method::Linear); }
void BM_HandlesPhysical(benchmark::State& state) { handleBenchmark(state, Method::Physical); }
BENCHMARK(BM_HandlesFull)->ArgsProduct({{20, 100}, {-1, 1, -4, 4}})->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_HandlesLinear)->ArgsProduct({{20, 100}, {-1, 1, -4, 4}})->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_HandlesPhysical)->ArgsProduct({{20, 100}, {-1, 1, -4, 4}})->Unit(benchmark::kMicrosecond);

// A frame turned about a fixed pivot by `angle` about `axis` (rad, rad/s, rad/s^2): the pivot stays put.
FrameMotion turnAbout(const Eigen::Vector3d& pivot, const Eigen::Vector3d& axis, double angle, double rate,
                      double spin)
{
  FrameMotion m;
  m.rotation = Eigen::AngleAxisd(angle, axis).toRotationMatrix();
  m.angular_velocity = rate * axis;
  m.angular_acceleration = spin * axis;
  const Eigen::Vector3d turned = m.rotation * pivot;
  m.translation = pivot - turned;
  m.velocity = -m.angular_velocity.cross(turned);
  m.acceleration = -m.angular_acceleration.cross(turned) - m.angular_velocity.cross(m.angular_velocity.cross(turned));
  return m;
}

// The moving frame: a 2D sheet hanging from one handle that holds its top row (nothing fixed),
// simulated in the handle's frame while it sways about y through the top row's middle, 0.1 rad at
// 1 Hz (setHandleFrameMotion, then step): every frame term acts, the Coriolis one through the
// integrator. Against the same sheet with its top row fixed (frame = 0): the difference is the
// moving frame's cost per step.
void frameBenchmark(benchmark::State& state, Method method, IntegratorKind integrator)
{
  const int size = static_cast<int>(state.range(0));
  const bool moving = state.range(1) > 0;
  GridParams g = square(size, 2);
  std::vector<int> top;
  for (int c = 0; c < size; ++c)
    top.push_back(c);
  g.fixed = top;
  if (moving)
  {
    g.fixed.clear();
    g.handles = {top};
  }
  SimulationParams s;
  s.method = method;
  s.num_modes = 30;
  s.integrator = integrator;
  s.alpha = 0.5;
  s.handle_formulation = moving ? HandleFormulation::MovingFrame : HandleFormulation::Auto;
  s.handles_one_body = moving;
  Simulation sim(g, s);
  const Eigen::Vector3d pivot(0.5 * (size - 1) * g.spacing, 0.0, 0.0), axis = Eigen::Vector3d::UnitY();
  const double w = 2.0 * M_PI, amplitude = 0.1;
  for (auto _ : state)
  {
    if (moving)
    {
      const double t = sim.time() + s.time_step;
      sim.setHandleFrameMotion(turnAbout(pivot, axis, amplitude * std::sin(w * t), amplitude * w * std::cos(w * t),
                                         -amplitude * w * w * std::sin(w * t)));
    }
    benchmark::DoNotOptimize(sim.step(1));
  }
  if (sim.diverged())
    state.SkipWithError("diverged");
}
void BM_FrameFull(benchmark::State& state) { frameBenchmark(state, Method::Full, IntegratorKind::Explicit); }
void BM_FrameLinear(benchmark::State& state) { frameBenchmark(state, Method::Linear, IntegratorKind::Explicit); }
void BM_FramePhysical(benchmark::State& state) { frameBenchmark(state, Method::Physical, IntegratorKind::Explicit); }
void BM_FrameImplicitPhysical(benchmark::State& state)
{
  frameBenchmark(state, Method::Physical, IntegratorKind::Implicit);
}
BENCHMARK(BM_FrameFull)->ArgsProduct({{20, 100}, {0, 1}})->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_FrameLinear)->ArgsProduct({{20, 100}, {0, 1}})->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_FramePhysical)->ArgsProduct({{20, 100}, {0, 1}})->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_FrameImplicitPhysical)->ArgsProduct({{20, 100}, {0, 1}})->Unit(benchmark::kMicrosecond);

// Implicit Newmark: Newton iterations with the sparse (full) or r x r (physical) tangent.
void implicitBenchmark(benchmark::State& state, Method method)
{
  Simulation* sim = &sharedSheet(static_cast<int>(state.range(0)), static_cast<int>(state.range(1)), method,
                                 IntegratorKind::Implicit);
  for (auto _ : state)
    benchmark::DoNotOptimize(sim->step(1));
  if (sim->diverged())
    state.SkipWithError("diverged");
  state.counters["newton_iterations"] = sim->lastNewtonIterations();
}
void BM_ImplicitFull(benchmark::State& state) { implicitBenchmark(state, Method::Full); }
void BM_ImplicitLinear(benchmark::State& state) { implicitBenchmark(state, Method::Linear); }
void BM_ImplicitPhysical(benchmark::State& state) { implicitBenchmark(state, Method::Physical); }
BENCHMARK(BM_ImplicitFull)->ArgsProduct({{5, 20, 50}, {30}})->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_ImplicitLinear)->ArgsProduct({{5, 20, 100}, {30}})->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_ImplicitPhysical)->ArgsProduct({{5, 20, 50, 100, 200}, {30}})->Unit(benchmark::kMicrosecond);
void BM_ImplicitCubature(benchmark::State& state) { implicitBenchmark(state, Method::Cubature); }
BENCHMARK(BM_ImplicitCubature)->ArgsProduct({kCubatureSizes, {30}})->Unit(benchmark::kMicrosecond);

// Implicit `full` on a swinging cloth, each linear solver of Newton's tangents side by side: the cloth
// of config/cloth_large.yaml (0.99 m wide, 2 kg, 200/80/20 N/m structural/shear/bending springs, top
// row fixed, alpha = 0.5 /s, HHT alpha -0.1) at n x n particles, released 60 degrees out of the
// vertical, 5 ms steps. Every solver steps the same cloth from the same start for the same number of
// steps (fixed iterations), each converged to the default Newton tolerance.
MassDamping massDamping(const Grid& grid, double alpha)
{
  const Eigen::VectorXd mass = Eigen::VectorXd::Constant(grid.numFreeDofs(), grid.particleMass());
  SparseMatrix damping(mass.size(), mass.size());
  damping.setIdentity();
  damping = (alpha * mass).asDiagonal() * damping;
  return MassDamping{mass, damping};
}

// Newton's linear solvers measured side by side (range(1) of BM_ImplicitFullSolver): the core's kinds
// and three of this benchmark's own, which the core left for being slower (docs/benchmarks.md).
enum class LinearSolver
{
  SimplicialLdlt,  // the core's
  Cholmod,         // the core's
  Supernodal,      // the package's former supernodal Cholesky (supernodal_cholesky.h), built for every J
  JacobiCg,        // conjugate gradients preconditioned by J's diagonal
  CholmodCg,       // conjugate gradients preconditioned by the CHOLMOD factor of an earlier J
  BlockJacobiCg,   // the core's
};

// The benchmark's own kinds over the core's CHOLMOD one, which factorises J where they give up.
class BenchmarkTangentSolver : public TangentSolver
{
public:
  explicit BenchmarkTangentSolver(LinearSolver kind) : TangentSolver(TangentSolverKind::Cholmod), kind_(kind) {}

  bool solve(const SparseMatrix& j, const Eigen::VectorXd& b, Eigen::VectorXd& x, double tolerance) override
  {
    auto product = [&](const Eigen::VectorXd& p, Eigen::VectorXd& jp) { jp.noalias() = j * p; };
    if (kind_ == LinearSolver::Supernodal)
    {
      ++factorisations_;
      const SupernodalCholesky llt(j);
      if (llt.info() != Eigen::Success)
        return false;
      x = b;
      llt.solveInPlace(x);
      return x.allFinite();
    }
    if (kind_ == LinearSolver::JacobiCg && diagonalJacobi(j, b, x, tolerance))
      return true;
    // Within a few iterations while J changes little; past this many, factorising the new J costs less.
    constexpr int kMaxReusedFactorIterations = 8;
    if (kind_ == LinearSolver::CholmodCg && hasFactor())
    {
      // CG from zero is a descent direction of the quadratic whatever the preconditioner.
      if (conjugateGradients(product, b, x, tolerance, kMaxReusedFactorIterations,
                             [&](Eigen::VectorXd& v) {
                               solveWithFactor(v, preconditioned_);
                               v = preconditioned_;
                             }) &&
          x.allFinite())
        return true;
    }
    return TangentSolver::solve(j, b, x, tolerance);
  }

private:
  LinearSolver kind_;
  Eigen::VectorXd preconditioned_;
};

TangentSolverKind coreKind(LinearSolver solver)
{
  if (solver == LinearSolver::SimplicialLdlt)
    return TangentSolverKind::SimplicialLdlt;
  return solver == LinearSolver::BlockJacobiCg ? TangentSolverKind::BlockJacobiCg : TangentSolverKind::Cholmod;
}

struct SwingingCloth
{
  SwingingCloth(int size, LinearSolver solver)
    : grid(swingingCloth(size)), model(grid, grid.initialPositions()),
      integrator(massDamping(grid, 0.5), 0.005, 50, -0.1, 1e-9, coreKind(solver))
  {
    if (solver == LinearSolver::Supernodal || solver == LinearSolver::JacobiCg || solver == LinearSolver::CholmodCg)
      integrator.setLinearSolver(std::make_unique<BenchmarkTangentSolver>(solver));
    state.q.setZero(grid.numFreeDofs());
    state.v.setZero(grid.numFreeDofs());
    integrator.initialize(model, state);
  }
  Grid grid;
  FullForceModel model;
  ImplicitNewmark integrator;
  State state;
};

void BM_ImplicitFullSolver(benchmark::State& state)
{
  const int size = static_cast<int>(state.range(0));
  const auto solver = static_cast<LinearSolver>(state.range(1));
  auto cloth = std::make_unique<SwingingCloth>(size, solver);
  if (state.range(2) != 0)
    cloth->integrator.setNewtonStart(NewtonStart::ConstantAcceleration);
  cloth->integrator.setMaxForcing(std::pow(10.0, -static_cast<double>(state.range(3))));
  long newton = 0, substeps = 0, steps = 0;
  State next;
  for (auto _ : state)
  {
    if (!cloth->integrator.step(cloth->model, cloth->state, next))
    {
      state.SkipWithError("step refused");
      break;
    }
    std::swap(cloth->state, next);
    newton += cloth->integrator.lastIterations();
    substeps += cloth->integrator.lastSubsteps();
    ++steps;
  }
  const double per_step = 1.0 / std::max(steps, 1L);
  state.counters["newton_per_step"] = newton * per_step;
  state.counters["substeps_per_step"] = substeps * per_step;
  state.counters["factorisations_per_step"] = cloth->integrator.linearSolver().factorisations() * per_step;
  state.counters["cg_per_step"] = cloth->integrator.linearSolver().cgIterations() * per_step;
  state.counters["free_dofs"] = cloth->grid.numFreeDofs();
}
// range(1): LinearSolver (0 simplicial LDL^T, 1 CHOLMOD, 2 the former own supernodal, 3 Jacobi CG,
// 4 CG preconditioned by an earlier CHOLMOD factor, 5 CG preconditioned by J's 3 x 3 particle blocks);
// range(2): Newton's start (0 constant velocity, 1 constant acceleration); range(3): the inexact
// Newton's largest forcing term, 10^-range(3). 200 steps (1 s) on 50 x 50, 100 (0.5 s) on 100 x 100,
// 20 (0.1 s) on 200 x 200.
BENCHMARK(BM_ImplicitFullSolver)->ArgsProduct({{50}, {0, 1, 2, 3, 4, 5}, {0, 1}, {1, 2, 3}})->Iterations(200)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ImplicitFullSolver)->ArgsProduct({{100}, {0, 1, 2, 3, 4, 5}, {0, 1}, {1, 2, 3}})->Iterations(100)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ImplicitFullSolver)->ArgsProduct({{200}, {0, 1, 2, 3, 4, 5}, {0, 1}, {1, 2, 3}})->Iterations(20)->Unit(benchmark::kMillisecond);

// What a start with linearization 'equilibrium' builds before its first step on a 100 x 100 cloth (0.99 m,
// top row fixed, shear springs of 0.4 and bending springs of 0.1 of the structural stiffness) of
// range(0) grams in all with range(1) N/m structural springs, released range(2) degrees out of the
// vertical: the hanging equilibrium from there and the basis of the default 4 modes at it. range(3):
// the equilibrium's Newton solves on CHOLMOD (1) or only on the simplicial LDL^T (0, as before).
// Counters: the two parts' CPU seconds, Newton iterations, the largest unbalanced force left (where
// the equilibrium is refused, at the iteration limit: the time until then).
void BM_Equilibrium100(benchmark::State& state)
{
  GridParams g = swingingCloth(100);
  g.rotation_deg = static_cast<double>(state.range(2));
  g.mass = 1e-3 * static_cast<double>(state.range(0)) / (100 * 100);
  g.structural_stiffness = static_cast<double>(state.range(1));
  g.shear_stiffness = 0.4 * g.structural_stiffness;
  g.bending_stiffness = 0.1 * g.structural_stiffness;
  const Grid grid(g);
  const EquilibriumSolver solver = state.range(3) ? EquilibriumSolver::Cholmod : EquilibriumSolver::SimplicialLdlt;
  Equilibrium found;
  double equilibrium_cpu = 0.0, basis_cpu = 0.0;
  for (auto _ : state)
  {
    const double start = processCpuSeconds();
    try
    {
      found = solveEquilibrium(grid, grid.initialPositions(), kDefaultEquilibriumMaxIterations, kEquilibriumTolerance,
                               [&](int iteration, double residual, double) {
                                 found.iterations = iteration;
                                 found.residual = residual;
                               },
                               solver);
    }
    catch (const std::runtime_error&)
    {
      // What a start is told, after how long (an error ends the benchmark's loop: the figures go in
      // its message).
      static std::string refused;
      refused = "refused after " + std::to_string(processCpuSeconds() - start) + " s of CPU at Newton iteration " +
                std::to_string(found.iterations) + ", largest unbalanced force " + std::to_string(found.residual) + " N";
      state.SkipWithError(refused.c_str());
      break;
    }
    const double solved = processCpuSeconds();
    const SparseMatrix k = tangentStiffness(grid, found.positions, CompressedSprings::Drop);
    benchmark::DoNotOptimize(
        computeModalBasis(k, Eigen::VectorXd::Constant(grid.numFreeDofs(), grid.particleMass()), SimulationParams{}.num_modes));
    equilibrium_cpu = solved - start;
    basis_cpu = processCpuSeconds() - solved;
  }
  state.counters["equilibrium_cpu_s"] = equilibrium_cpu;
  state.counters["basis_cpu_s"] = basis_cpu;
  state.counters["newton_iterations"] = found.iterations;
  state.counters["residual_N"] = found.residual;
}
BENCHMARK(BM_Equilibrium100)
    ->ArgsProduct({{200, 1000, 2000, 5000}, {50, 300, 1000}, {0}, {0, 1}})
    ->Args({2000, 200, 60, 1})
    ->Iterations(1)
    ->Unit(benchmark::kSecond);

// The cubature's training alone, on the basis of a sheet (built once, outside the timing), with the
// size of T and the errors it reached as counters.
void BM_TrainCubature(benchmark::State& state)
{
  const auto sim = disturbedSheet(static_cast<int>(state.range(0)), static_cast<int>(state.range(1)), Method::Linear);
  const CubatureParams params = cubatureParams(sim->params());
  Cubature cubature;
  for (auto _ : state)
    cubature = trainCubature(sim->grid(), sim->basis(), sim->linearizationPositions(), params);
  state.counters["springs"] = static_cast<double>(cubature.springs.size());
  state.counters["training_error"] = cubature.training_error;
  state.counters["heldout_error"] = cubature.heldout_error;
}
BENCHMARK(BM_TrainCubature)->ArgsProduct({{20, 50, 100}, {30}})->Unit(benchmark::kMillisecond)->Iterations(1);

// x = x0 + Phi X for every particle: what a modal method pays only when positions are wanted.
void BM_Reconstruct(benchmark::State& state)
{
  const auto sim = disturbedSheet(static_cast<int>(state.range(0)), static_cast<int>(state.range(1)), Method::Linear);
  for (auto _ : state)
    benchmark::DoNotOptimize(sim->positions());
}
BENCHMARK(BM_Reconstruct)->ArgsProduct({kSizes, {4, 30}})->Unit(benchmark::kMicrosecond);

void BM_SpringForces(benchmark::State& state)
{
  const Grid grid(square(static_cast<int>(state.range(0)), 3));
  std::srand(1);
  const Eigen::VectorXd x = grid.initialPositions() + 1e-3 * Eigen::VectorXd::Random(grid.numDofs());
  Eigen::VectorXd f;
  for (auto _ : state)
  {
    springForces(grid, x, f);
    benchmark::DoNotOptimize(f.data());
  }
  state.counters["springs"] = static_cast<double>(grid.springs().size());
}
BENCHMARK(BM_SpringForces)->ArgsProduct({kSizes})->Unit(benchmark::kMicrosecond);

// `coarse` with the scenes' damping, from the held cloth hanging at rest.
SimulationParams coarseAtRest()
{
  SimulationParams s;
  s.method = Method::Coarse;
  s.alpha = 0.5;
  s.linearization = Linearization::Equilibrium;
  s.initial_state = InitialState::Equilibrium;
  return s;
}

// The cloth of config/cloth_large.yaml on N x N, held by a clamp of its top two rows, nothing fixed.
GridParams clampedCloth(int size)
{
  GridParams g = swingingCloth(size);
  g.rotation_deg = 0.0;
  std::vector<int> clamp(2 * size);
  std::iota(clamp.begin(), clamp.end(), 0);
  g.handles = {clamp};
  return g;
}

// `coarse` on the held cloth turned 60 degrees about the vertical in 1 s and back
// (config/compare/large_motion_100.yaml on N x N: the cloth of config/cloth_large.yaml held by a clamp
// of its top two rows, nothing fixed), explicit, the clamp's motion handed over every step as the node
// and modal_compare hand it: every clamp particle's motion (setHandleMotion), or the clamp's frame
// (setHandleFrameMotion). At `full`'s largest stable step (0.8 ms x 100 / N) or at coarse's own
// (coarseStepMultiple times it), alone or through the adaptive stepper: at `full`'s step it is
// handed each step's motion and records it, as the node does; at coarse's own it drives each reduced
// step (reduced_step_span), as modal_compare does. Counter: CPU seconds per simulated second, which
// compares different steps.
void turnCoarse(benchmark::State& state, int size, bool frame, bool own_step, bool adaptive)
{
  const GridParams g = clampedCloth(size);
  SimulationParams s = coarseAtRest();
  s.handle_formulation = HandleFormulation::ConstraintModes;
  s.time_step = 0.0008 * 100.0 / size;
  const int multiple = own_step ? coarseStepMultiple(g, s) : 1;
  if (!adaptive)
    s.time_step *= multiple;
  Simulation sim(g, s);
  const std::vector<int>& dofs = sim.grid().handleDofs();
  Eigen::Matrix3Xd points(3, static_cast<Eigen::Index>(dofs.size()) / 3);
  for (Eigen::Index p = 0; p < points.cols(); ++p)
    points.col(p) = sim.linearizationPositions().segment<3>(dofs[3 * p]);
  const Eigen::Vector3d pivot = points.rowwise().mean(), axis = Eigen::Vector3d::UnitZ();
  const double duration = 1.0, angle = EIGEN_PI / 3.0;
  // Turned to 60 degrees and back, smoothly, every 2 s: angle (1 - cos(pi t / duration)) / 2, where
  // the next step ends.
  const Drive drive = [&](Simulation& sim) {
    const double t = sim.nextStepTime(), w = EIGEN_PI / duration;
    const double turn = 0.5 * angle * (1.0 - std::cos(w * t)), rate = 0.5 * angle * w * std::sin(w * t);
    const double spin = 0.5 * angle * w * w * std::cos(w * t);
    const FrameMotion m = turnAbout(pivot, axis, turn, rate, spin);
    if (frame)
      sim.setHandleFrameMotion(m);
    else
    {
      const RigidPointMotion motion = pointMotion(m, points);
      sim.setHandleMotion(motion.position.reshaped(), motion.velocity.reshaped(), motion.acceleration.reshaped());
    }
  };
  std::unique_ptr<AdaptiveStepper> stepper;
  if (adaptive)
  {
    AdaptiveSettings settings = adaptiveSettings(s);
    settings.reduced = Method::Coarse;
    // What the checks cost on a run that stays reduced: turned back and forth without end, the
    // swing's drift reaches the default tolerance within a few turns, and the run would time `full`.
    settings.tolerance = 1.0;
    settings.reduced_step_span = multiple;
    stepper = own_step ? std::make_unique<AdaptiveStepper>(sim, settings, drive)
                       : std::make_unique<AdaptiveStepper>(sim, settings);
  }
  const double start_cpu = threadCpuSeconds();
  const double start_time = sim.time();
  for (auto _ : state)
  {
    if (!(stepper && own_step))
      drive(sim);
    const StepResult r = stepper ? stepper->step() : sim.step(1);
    if (r.diverged)
    {
      static std::string message;
      message = r.message;
      state.SkipWithError(message.c_str());
      break;
    }
  }
  if (sim.time() > start_time)
    state.counters["cpu_per_simulated_s"] = (threadCpuSeconds() - start_cpu) / (sim.time() - start_time);
  state.counters["time_step_ms"] = 1e3 * s.time_step;
  if (stepper)
    state.counters["reduced_share"] = stepper->reducedShare();
}

// range(1) = 0: every clamp particle's motion; 1: the clamp's frame. At coarse's own step.
void BM_CoarseTurn(benchmark::State& state)
{
  turnCoarse(state, static_cast<int>(state.range(0)), state.range(1) == 1, true, false);
}
BENCHMARK(BM_CoarseTurn)->ArgsProduct({{50, 100, 200}, {0, 1}})->Unit(benchmark::kMicrosecond);

// The same turn at `full`'s step, every clamp particle's motion: range(1) = 0, `coarse` alone; 1,
// through the adaptive stepper (its check every 0.1 s, stretched up to 0.4 s while safely within the
// tolerance, and the motions it keeps for a fallback).
void BM_AdaptiveCoarseTurn(benchmark::State& state)
{
  turnCoarse(state, static_cast<int>(state.range(0)), false, false, state.range(1) == 1);
}
BENCHMARK(BM_AdaptiveCoarseTurn)->ArgsProduct({{50, 100}, {0, 1}})->Unit(benchmark::kMicrosecond);

// The same at coarse's own step: range(1) = 0, `coarse` alone (BM_CoarseTurn); 1, through the
// adaptive stepper, each reduced step spanning that many of `full`'s steps and driven by it. Compare
// the CPU per simulated second: its iterations are steps of different lengths.
void BM_AdaptiveCoarseTurnOwnStep(benchmark::State& state)
{
  turnCoarse(state, static_cast<int>(state.range(0)), false, true, state.range(1) == 1);
}
BENCHMARK(BM_AdaptiveCoarseTurnOwnStep)->ArgsProduct({{50, 100}, {0, 1}})->Unit(benchmark::kMicrosecond);

// One whole scene from `start` (restored untimed): through a new adaptive stepper with `drive` (kept
// in `stepper` for its counters) where `settings` is given, else `sim` alone driven every step; until
// `done`. Returns the CPU seconds of its steps; -1, and the benchmark skipped, where a step diverged.
double runScene(benchmark::State& state, Simulation& sim, const SimulationState& start,
                const AdaptiveSettings* settings, const Drive& drive, const std::function<bool()>& done,
                std::unique_ptr<AdaptiveStepper>& stepper)
{
  state.PauseTiming();
  sim.restoreState(start);
  stepper = settings ? std::make_unique<AdaptiveStepper>(sim, *settings, drive) : nullptr;
  state.ResumeTiming();
  const double start_cpu = threadCpuSeconds();
  while (!done())
  {
    if (!stepper)
      drive(sim);
    if ((stepper ? stepper->step() : sim.step()).diverged)
    {
      state.SkipWithError("diverged");
      return -1.0;
    }
  }
  return threadCpuSeconds() - start_cpu;
}

// modal_compare's ramp for a handle scenario's move over 1 s (s = 10 tau^3 - 15 tau^4 + 6 tau^5, its
// velocity and acceleration zero at both ends): where it is at time t, and its two rates.
struct Ramp
{
  double s, ds, dds;
};
Ramp moveRamp(double t)
{
  const double tau = std::clamp(t, 0.0, 1.0), rest = 1.0 - tau;
  return {tau * tau * tau * (10.0 - 15.0 * tau + 6.0 * tau * tau), 30.0 * tau * tau * rest * rest,
          60.0 * tau * rest * (1.0 - 2.0 * tau)};
}

// config/compare/large_motion_100.yaml's turn_60 as `benchmark/size_sweep.py --scene turn` runs it: the
// held cloth of BM_CoarseTurn on N x N turned 60 degrees about the vertical over 1 s and held 0.5 s,
// explicit at `full`'s step (0.8 ms x 100 / N). range(1) = 0: `coarse` alone at its own step; 1:
// `adaptive` on `coarse` with its defaults (the tolerance 1.5 cm), each reduced step at coarse's own
// step; 2: the same with one check only, at the end (what the stepper costs besides them). Each
// iteration is the whole scene from the hanging start (restored untimed), so the checks come where
// they come in the scene; counter: CPU seconds per simulated second of the stepping.
void BM_AdaptiveCoarseTurnScene(benchmark::State& state)
{
  const int size = static_cast<int>(state.range(0));
  const bool adaptive = state.range(1) >= 1;
  const GridParams g = clampedCloth(size);
  SimulationParams s = coarseAtRest();
  s.handle_formulation = HandleFormulation::ConstraintModes;
  s.time_step = 0.0008 * 100.0 / size;
  s.adaptive_method = Method::Coarse;
  const long fine_steps = std::lround(1.5 / s.time_step);
  const int multiple = coarseStepMultiple(g, s);
  if (!adaptive)
    s.time_step *= multiple;
  Simulation sim(g, s);
  const SimulationState start = sim.saveState();
  const std::vector<int>& dofs = sim.grid().handleDofs();
  Eigen::Matrix3Xd points(3, static_cast<Eigen::Index>(dofs.size()) / 3);
  for (Eigen::Index p = 0; p < points.cols(); ++p)
    points.col(p) = sim.linearizationPositions().segment<3>(dofs[3 * p]);
  const Eigen::Vector3d pivot = points.rowwise().mean(), axis = Eigen::Vector3d::UnitZ();
  const Drive drive = [&](Simulation& sim) {
    const Ramp r = moveRamp(sim.nextStepTime());
    const double angle = EIGEN_PI / 3.0;
    const RigidPointMotion motion =
        pointMotion(turnAbout(pivot, axis, angle * r.s, angle * r.ds, angle * r.dds), points);
    sim.setHandleMotion(motion.position.reshaped(), motion.velocity.reshaped(), motion.acceleration.reshaped());
  };
  AdaptiveSettings settings = adaptiveSettings(s);
  settings.reduced_step_span = multiple;
  if (state.range(1) == 2)
    settings.check_steps = static_cast<int>(fine_steps);
  const double end = fine_steps * (adaptive ? s.time_step : s.time_step / multiple) - 1e-9;
  double cpu = 0.0, simulated = 0.0, reduced_share = 0.0;
  int checks = 0;
  std::unique_ptr<AdaptiveStepper> stepper;
  for (auto _ : state)
  {
    const double scene = runScene(state, sim, start, adaptive ? &settings : nullptr, drive,
                                  [&] { return sim.time() >= end; }, stepper);
    if (scene < 0.0)
      return;
    cpu += scene;
    simulated += sim.time();
    reduced_share = stepper ? stepper->reducedShare() : 1.0;
    checks = stepper ? stepper->checks() : 0;
  }
  state.counters["cpu_per_simulated_s"] = simulated > 0.0 ? cpu / simulated : 0.0;
  state.counters["reduced_share"] = reduced_share;
  state.counters["checks"] = checks;
}
BENCHMARK(BM_AdaptiveCoarseTurnScene)->ArgsProduct({{50, 100}, {0, 1, 2}})->Unit(benchmark::kMillisecond);

// config/compare/large_motion_grips.yaml's corners_together, the scene where the coarse grid's span
// is right only at the start: the 20 x 20 cloth hanging from two 2 x 2 grips at its top corners,
// brought 0.35 m towards each other over 1 s (moveRamp) and held 2 s,
// explicit at 5 ms. range(0) = 0: `full`; 1: `adaptive` on `coarse` (its defaults, at coarse's own
// step). Each iteration is the whole scene from the hanging start (restored untimed): compare the
// two by their time per iteration.
void BM_AdaptiveCornersTogether(benchmark::State& state)
{
  const bool adaptive = state.range(0) == 1;
  GridParams g;
  g.rows = g.cols = 20;
  g.spacing = 0.05;
  g.dimension = 3;
  g.mass = 0.005;
  g.structural_stiffness = 50.0;
  g.shear_stiffness = 20.0;
  g.bending = true;
  g.bending_stiffness = 5.0;
  g.fixed = {};
  g.handles = {{0, 1, 20, 21}, {18, 19, 38, 39}};
  SimulationParams s;
  s.method = adaptive ? Method::Coarse : Method::Full;
  s.num_modes = 30;
  s.linearization = Linearization::Equilibrium;
  s.initial_state = InitialState::Equilibrium;
  s.handle_formulation = HandleFormulation::ConstraintModes;
  s.integrator = IntegratorKind::Explicit;
  s.alpha = 0.5;
  s.time_step = 0.005;
  s.adaptive_method = Method::Coarse;
  Simulation sim(g, s);
  const SimulationState start = sim.saveState();
  const Eigen::VectorXd rest = sim.handlePositions();
  const long steps = 600;
  const Drive drive = [&](Simulation& sim) {
    const Ramp r = moveRamp(sim.nextStepTime());
    Eigen::VectorXd x = rest, v = Eigen::VectorXd::Zero(rest.size()), a = v;
    for (Eigen::Index d = 0; d < x.size(); d += 3)
    {
      const double towards = d < x.size() / 2 ? 0.35 : -0.35;  // the first grip's four particles, then the second's
      x[d] += towards * r.s;
      v[d] = towards * r.ds;
      a[d] = towards * r.dds;
    }
    sim.setHandleMotion(x, v, a);
  };
  AdaptiveSettings settings = adaptiveSettings(s);
  settings.reduced_step_span = coarseStepMultiple(g, s, steps);
  double reduced_share = 0.0;
  std::unique_ptr<AdaptiveStepper> stepper;
  for (auto _ : state)
  {
    if (runScene(state, sim, start, adaptive ? &settings : nullptr, drive, [&] { return sim.stepCount() >= steps; },
                 stepper) < 0.0)
      return;
    reduced_share = stepper ? stepper->reducedShare() : 0.0;
  }
  state.counters["reduced_share"] = reduced_share;
}
BENCHMARK(BM_AdaptiveCornersTogether)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

// The error indicator of `coarse` (what the adaptive method's check costs while reduced), on the held
// cloth of BM_CoarseTurn hanging at rest, against one step of `coarse` at its own step.
void BM_CoarseErrorIndicator(benchmark::State& state)
{
  const int size = static_cast<int>(state.range(0));
  const GridParams g = clampedCloth(size);
  SimulationParams s = coarseAtRest();
  s.time_step = 0.0008 * 100.0 / size;
  s.time_step *= coarseStepMultiple(g, s);
  Simulation sim(g, s);
  sim.errorIndicator();  // the Laplacian factorised once
  for (auto _ : state)
    benchmark::DoNotOptimize(sim.errorIndicator());
  const double start = threadCpuSeconds();
  sim.step(20);
  state.counters["coarse_step_us"] = 1e6 * (threadCpuSeconds() - start) / 20;
}
BENCHMARK(BM_CoarseErrorIndicator)->Arg(50)->Arg(100)->Unit(benchmark::kMicrosecond);

// The drag's 9 s (config/compare/cloth_drag_50.yaml on N x N, as benchmark/size_sweep.py makes it):
// the top row lowered 0.35 m in 4 s onto the table, dragged 0.5 m along y in 4 s, held 1 s, each leg
// from rest to rest.
void driveDrag(Simulation& sim, double time_step)
{
  const long steps = std::lround(9.0 / time_step);
  for (long k = 1; k <= steps && !sim.diverged(); ++k)
  {
    const double t = k * time_step, w = EIGEN_PI / 4.0;
    FrameMotion m;
    // (1 - cos(w t)) / 2 of each leg, and its rates.
    auto leg = [&](double start, double length, int axis) {
      const double s = std::clamp(t - start, 0.0, 4.0);
      m.translation[axis] += 0.5 * length * (1.0 - std::cos(w * s));
      if (t - start > 0.0 && t - start < 4.0)
      {
        m.velocity[axis] += 0.5 * length * w * std::sin(w * s);
        m.acceleration[axis] += 0.5 * length * w * w * std::cos(w * s);
      }
    };
    leg(0.0, -0.35, 2);
    leg(4.0, 0.5, 1);
    sim.setHandleFrameMotion(m);
    sim.step(1);
  }
}

// `coarse` on the drag at its own step, the whole scene once a repeat (the landing is in it): CPU
// seconds per simulated second, the counter that compares the sizes' different steps, with the table.
void BM_CoarseDrag(benchmark::State& state)
{
  const int size = static_cast<int>(state.range(0));
  GridParams g;
  g.rows = g.cols = size;
  g.dimension = 3;
  g.spacing = 0.98 / (size - 1);
  g.mass = 2.0 / (size * size);
  g.structural_stiffness = 50.0;
  g.shear_stiffness = 20.0;
  g.bending = true;
  g.bending_stiffness = 5.0;
  std::vector<int> top(size);
  std::iota(top.begin(), top.end(), 0);
  g.handles = {top};
  SimulationParams s = coarseAtRest();
  Collider table;
  table.type = ColliderType::Box;
  table.center = Eigen::Vector3d(0.475, 0.5, -1.4);
  table.half_extents = Eigen::Vector3d(0.8, 1.0, 0.25);
  s.colliders = {table};
  s.time_step = 0.0025 * 50.0 / size;
  s.time_step *= coarseStepMultiple(g, s);
  double cpu = 0.0, simulated = 0.0;
  long touching = 0;
  for (auto _ : state)
  {
    state.PauseTiming();
    Simulation sim(g, s);
    state.ResumeTiming();
    const double start = threadCpuSeconds();
    driveDrag(sim, s.time_step);
    cpu += threadCpuSeconds() - start;
    simulated += sim.time();
    if (sim.diverged())
    {
      state.SkipWithError("diverged");
      break;
    }
    const std::vector<int> contacts = sim.particleContacts();
    touching = std::count_if(contacts.begin(), contacts.end(), [](int c) { return c >= 0; });
  }
  state.counters["cpu_per_simulated_s"] = simulated > 0.0 ? cpu / simulated : 0.0;
  state.counters["on_the_table_at_the_end"] = static_cast<double>(touching);
  state.counters["time_step_ms"] = 1e3 * s.time_step;
}
BENCHMARK(BM_CoarseDrag)->Arg(50)->Arg(100)->Arg(200)->Unit(benchmark::kMillisecond)->Iterations(1);

}  // namespace

BENCHMARK_MAIN();
