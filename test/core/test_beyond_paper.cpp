// Linearization at the hanging equilibrium and implicit Newmark: checks against closed forms.
#include "modal_mass_spring/equilibrium.h"
#include "modal_mass_spring/simulation.h"
#include "modal_mass_spring/spring_forces.h"

#include <gtest/gtest.h>

#include <cmath>

using namespace modal_mass_spring;

namespace
{

GridParams paper2D()
{
  return GridParams{};  // 5 x 5, top row fixed
}

GridParams paper3D()
{
  GridParams p;
  p.dimension = 3;
  p.rotation_deg = 45.0;
  return p;
}

SimulationParams params(Method method, int r, double dt, IntegratorKind integrator = IntegratorKind::Explicit)
{
  SimulationParams s;
  s.method = method;
  s.num_modes = r;
  s.time_step = dt;
  s.integrator = integrator;
  return s;
}

bool stable(const GridParams& g, SimulationParams s, int steps)
{
  Simulation sim(g, s);
  return !sim.step(steps).diverged;
}

// Largest stable time step by bisection between a stable and an unstable one.
double stabilityBound(const GridParams& g, const SimulationParams& s, int steps)
{
  double lo = 1e-5, hi = 1.0;
  while (hi / lo > 1.02)
  {
    const double mid = std::sqrt(lo * hi);
    SimulationParams trial = s;
    trial.time_step = mid;
    (stable(g, trial, steps) ? lo : hi) = mid;
  }
  return lo;
}

}  // namespace

TEST(Equilibrium, BalancesGravityFromARotatedSheet)
{
  const Grid grid(paper3D());
  const Equilibrium eq = solveEquilibrium(grid, grid.initialPositions());
  Eigen::VectorXd f;
  springForces(grid, eq.positions, f);
  const Eigen::VectorXd net = grid.gatherFree(f + grid.gravityForce());
  EXPECT_LT(net.cwiseAbs().maxCoeff(), 1e-8 * grid.particleMass() * 9.81);
  // The sheet swung down from 45 degrees (bottom row at y = 0.28) to hang nearly vertically;
  // compressed springs near the bottom let it bulge a little out of its plane.
  const Eigen::Matrix3Xd points = grid.toPoints(eq.positions);
  EXPECT_LT(std::abs(points(1, grid.particleIndex(4, 2))), 0.05);
  EXPECT_LT(points(2, grid.particleIndex(4, 2)), -0.4);
}

TEST(Equilibrium, HangingChainSidewaysModesMatchTheContinuum)
{
  // A stiff chain of many particles: the sideways modes about the hanging equilibrium tend to the
  // continuum chain's omega_n = (z_n / 2) sqrt(g / L), z_n the zeros of J0.
  GridParams g;
  g.rows = 201;
  g.cols = 1;
  g.spacing = 0.01;
  g.mass = 0.001;
  g.structural_stiffness = 1e4;
  SimulationParams s = params(Method::Linear, 3, 1e-4);
  s.linearization = Linearization::Equilibrium;
  const Simulation sim(g, s);
  ASSERT_TRUE(sim.linearization().equilibrium_solved);
  const Eigen::Matrix3Xd points = sim.grid().toPoints(sim.linearizationPositions());
  const double length = -points(2, g.rows - 1);
  EXPECT_GT(length, 2.0);  // stretched under its own weight
  const double zeros[] = {2.404826, 5.520078, 8.653728};
  for (int n = 0; n < 3; ++n)
  {
    const double expected = 0.5 * zeros[n] * std::sqrt(9.81 / length);
    EXPECT_NEAR(sim.basis().frequencies[n] / expected, 1.0, 0.03) << "mode " << n;
  }
}

TEST(Equilibrium, Paper3DSheetHasNoZeroModesThere)
{
  GridParams g = paper3D();
  g.rotation_deg = 0.0;  // no rotation needed at the equilibrium
  SimulationParams s = params(Method::Physical, 30, 1e-3);
  s.linearization = Linearization::Equilibrium;
  const Simulation sim(g, s);
  EXPECT_EQ(sim.basis().num_zero_modes, 0);
  EXPECT_GT(sim.basis().eigenvalues.minCoeff(), 1e-6 * sim.basis().eigenvalues.maxCoeff());

  // The same sheet linearised at rest has one zero mode per free particle.
  s.linearization = Linearization::Rest;
  EXPECT_EQ(Simulation(g, s).basis().num_zero_modes, 20);
}

TEST(Equilibrium, LinearIsExactAtRestThere)
{
  SimulationParams s = params(Method::Linear, 8, 1e-3);
  s.linearization = Linearization::Equilibrium;
  s.initial_state = InitialState::Equilibrium;
  Simulation sim(paper2D(), s);
  const Eigen::VectorXd start = sim.positions();
  EXPECT_LT((start - sim.linearizationPositions()).cwiseAbs().maxCoeff(), 1e-15);
  sim.step(2000);
  EXPECT_LT((sim.positions() - start).cwiseAbs().maxCoeff(), 1e-9);

  // Starting from the unloaded grid instead, the modal state is a projection, and its error is told.
  s.initial_state = InitialState::Initial;
  const Simulation from_initial(paper2D(), s);
  EXPECT_GT(from_initial.projectionError(), 0.0);
  // The projection error is the largest particle distance between the projected and requested grids.
  const Grid& grid = from_initial.grid();
  EXPECT_NEAR((grid.toPoints(from_initial.positions()) - grid.toPoints(grid.initialPositions())).colwise().norm().maxCoeff(),
              from_initial.projectionError(), 1e-12);
}

TEST(Implicit, UndampedLinearConservesEachModesEnergyFarPastTheExplicitBound)
{
  GridParams g = paper2D();
  g.gravity.setZero();
  const int r = 6;
  SimulationParams s = params(Method::Linear, r, 1.0, IntegratorKind::Implicit);
  s.hht_alpha = 0.0;  // average acceleration: what conserves a linear system's energy
  Simulation sim(g, s);
  const Eigen::VectorXd lambda = sim.basis().eigenvalues;
  const double explicit_bound = 2.0 / std::sqrt(lambda.maxCoeff());
  sim.setTimeStep(20.0 * explicit_bound);
  const Eigen::VectorXd shape = sim.basis().phi.rowwise().sum();
  sim.setPhysicalState(0.01 * shape, Eigen::VectorXd::Zero(shape.size()));
  auto modeEnergy = [&]() {
    return (0.5 * sim.state().v.cwiseAbs2() + 0.5 * lambda.cwiseProduct(sim.state().q.cwiseAbs2())).eval();
  };
  const Eigen::VectorXd initial = modeEnergy();
  ASSERT_GT(initial.minCoeff(), 0.0);
  const StepResult result = sim.step(100000);
  ASSERT_FALSE(result.diverged) << result.message;
  const Eigen::VectorXd drift = (modeEnergy() - initial).cwiseQuotient(initial).cwiseAbs();
  EXPECT_LT(drift.maxCoeff(), 1e-9);

  // The explicit scheme at the same step blows up.
  s.integrator = IntegratorKind::Explicit;
  s.time_step = 20.0 * explicit_bound;
  Simulation explicit_sim(g, s);
  explicit_sim.setPhysicalState(0.01 * shape, Eigen::VectorXd::Zero(shape.size()));
  EXPECT_TRUE(explicit_sim.step(1000).diverged);
}

TEST(Implicit, PhysicalWithEveryModeMatchesImplicitFull)
{
  GridParams g;
  g.rows = 4;
  g.cols = 3;
  SimulationParams s = params(Method::Full, 18, 5e-3, IntegratorKind::Implicit);
  s.alpha = 0.2;
  s.beta = 1e-3;
  Simulation full(g, s);
  s.method = Method::Physical;
  Simulation physical(g, s);
  for (int k = 0; k < 500; ++k)
  {
    ASSERT_FALSE(full.step().diverged);
    ASSERT_FALSE(physical.step().diverged);
  }
  EXPECT_GT(full.lastNewtonIterations(), 1);
  EXPECT_LT((full.positions() - physical.positions()).cwiseAbs().maxCoeff(), 1e-7);
  EXPECT_GT((full.positions() - full.grid().initialPositions()).cwiseAbs().maxCoeff(), 1e-2);
}

TEST(Implicit, FullConvergesToTheExplicitReferenceAsTheStepShrinks)
{
  // Both schemes are second order: the implicit error at dt and dt/2 against a fine explicit run
  // shrinks about four times.
  const GridParams g = paper2D();
  Simulation reference(g, params(Method::Full, 4, 1e-5));
  reference.step(50000);  // 0.5 s
  auto error = [&](double dt) {
    Simulation sim(g, params(Method::Full, 4, dt, IntegratorKind::Implicit));
    sim.step(static_cast<int>(std::lround(0.5 / dt)));
    return (sim.positions() - reference.positions()).cwiseAbs().maxCoeff();
  };
  const double coarse = error(4e-3), fine = error(2e-3);
  EXPECT_GT(coarse / fine, 3.0);
  EXPECT_LT(coarse / fine, 5.0);
}

TEST(Implicit, PhysicalStaysStableAtTenTimesTheExplicitBound)
{
  for (const GridParams& g : {paper2D(), paper3D()})
  {
    const int r = g.dimension == 2 ? 4 : 30;
    const int steps = 2000;
    const double bound = stabilityBound(g, params(Method::Physical, r, 1e-3), steps);
    EXPECT_FALSE(stable(g, params(Method::Physical, r, 10.0 * bound), steps));
    Simulation sim(g, params(Method::Physical, r, 10.0 * bound, IntegratorKind::Implicit));
    const StepResult result = sim.step(steps);
    EXPECT_FALSE(result.diverged) << "dimension " << g.dimension << ": " << result.message;
    EXPECT_TRUE(sim.positions().allFinite());
  }
}

TEST(Implicit, NamesRoundTrip)
{
  EXPECT_EQ(parseIntegrator("implicit"), IntegratorKind::Implicit);
  EXPECT_EQ(toString(Linearization::Equilibrium), "equilibrium");
  EXPECT_EQ(parseInitialState("initial"), InitialState::Initial);
  try
  {
    parseLinearization("hanging");
    FAIL();
  }
  catch (const std::invalid_argument& e)
  {
    EXPECT_NE(std::string(e.what()).find("'linearization' = 'hanging': must be one of rest, equilibrium"),
              std::string::npos)
        << e.what();
  }
}
