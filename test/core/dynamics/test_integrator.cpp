// The implicit integrator (Newmark, HHT alpha): each mode's energy, implicit full against physical and
// against the explicit scheme as the step shrinks, stability far past the explicit bound, and what it
// does when Newton fails or has nothing to measure against.
#include "modal_mass_spring/simulation.h"

#include "test_support.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>

using namespace modal_mass_spring;

namespace
{

GridParams paper2D() { return GridParams{}; }  // 5 x 5, top row fixed

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

TEST(Implicit, UndampedLinearConservesEachModesEnergyFarPastTheExplicitBound)
{
  GridParams g = paper2D();
  g.gravity.setZero();
  const int r = 6;
  SimulationParams s = methodParams(Method::Linear, r, 1.0, IntegratorKind::Implicit);
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
  SimulationParams s = methodParams(Method::Full, 18, 5e-3, IntegratorKind::Implicit);
  s.alpha = 0.2;
  s.beta = 1e-3;
  NewtonIterations newton;
  ASSERT_NO_FATAL_FAILURE(expectPhysicalMatchesFull(g, s, 500, newton));
  EXPECT_GT(newton.full, 1);
}

TEST(Implicit, FullConvergesToTheExplicitReferenceAsTheStepShrinks)
{
  // Both schemes are second order: the implicit error at dt and dt/2 against a fine explicit run
  // shrinks about four times.
  const GridParams g = paper2D();
  Simulation reference(g, methodParams(Method::Full, 4, 1e-5));
  reference.step(50000);  // 0.5 s
  auto error = [&](double dt) {
    Simulation sim(g, methodParams(Method::Full, 4, dt, IntegratorKind::Implicit));
    sim.step(static_cast<int>(std::lround(0.5 / dt)));
    return (sim.positions() - reference.positions()).cwiseAbs().maxCoeff();
  };
  const double coarse = error(4e-3), fine = error(2e-3);
  EXPECT_GT(coarse / fine, 3.0);
  EXPECT_LT(coarse / fine, 5.0);
}

TEST(Implicit, PhysicalStaysStableAtTenTimesTheExplicitBound)
{
  for (const GridParams& g : {paper2D(), turnedSheet()})
  {
    const int r = g.dimension == 2 ? 4 : 30;
    const int steps = 2000;
    const double bound = stabilityBound(g, methodParams(Method::Physical, r, 1e-3), steps);
    EXPECT_FALSE(stable(g, methodParams(Method::Physical, r, 10.0 * bound), steps));
    Simulation sim(g, methodParams(Method::Physical, r, 10.0 * bound, IntegratorKind::Implicit));
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
  EXPECT_EQ(parseImplicitSolver(toString(ImplicitSolver::ConstantMatrix)), ImplicitSolver::ConstantMatrix);
  EXPECT_EQ(parseImplicitSolver("lagged_tangent"), ImplicitSolver::LaggedTangent);
  EXPECT_THROW(parseImplicitSolver("projective"), std::invalid_argument);
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

TEST(Implicit, NewtonFailureSplitsTheStepAndRefusesItWhenSplittingDoesNotHelp)
{
  // At 0.1 s on the paper's grid, 3 Newton iterations are not enough for a whole step but are for
  // its halves; 1 is not enough even in 1/16 of it.
  SimulationParams s = methodParams(Method::Full, 4, 0.1, IntegratorKind::Implicit);
  s.newton_max_iterations = 3;
  Simulation split(paper2D(), s);
  int most_substeps = 0;
  for (int k = 0; k < 300; ++k)
  {
    ASSERT_FALSE(split.step().diverged) << "step " << k;
    most_substeps = std::max(most_substeps, split.lastImplicitSubsteps());
  }
  EXPECT_GT(most_substeps, 1);

  s.newton_max_iterations = 1;
  Simulation refused(paper2D(), s);
  const Eigen::VectorXd start = refused.positions();
  const StepResult result = refused.step();
  ASSERT_TRUE(result.diverged);
  EXPECT_TRUE(contains(result.message, "newton_max_iterations = 1, even in 1/16 of the step")) << result.message;
  EXPECT_EQ(refused.stepCount(), 0);
  EXPECT_EQ(refused.positions(), start);
}

TEST(Implicit, LargeStepsConvergeWhereTheGridRestsAtTheLinearizationPoint)
{
  // At the equilibrium basis's own linearization point the forces balance to the round-off of the
  // spring forces, and q = 0: a convergence test relative to the forces or to q has nothing to
  // measure against. The grid starts there at rest; at a step far past the explicit bound every
  // method must go on standing still, not be refused.
  for (Method method : {Method::Full, Method::Linear, Method::Physical})
    for (const double dt : {1e-3, 0.5})
    {
      SimulationParams s = methodParams(method, 4, dt, IntegratorKind::Implicit);
      s.linearization = Linearization::Equilibrium;
      s.initial_state = InitialState::Equilibrium;
      Simulation sim(paper2D(), s);
      const StepResult result = sim.step(200);
      EXPECT_FALSE(result.diverged) << toString(method) << " at " << dt << " s: " << result.message;
      EXPECT_LT(largestParticleDistance(sim, sim.startPositions()), 1e-9) << toString(method) << " at " << dt;
    }
}

TEST(Implicit, ConstantMatrixAndLaggedTangentReachNewtonsSteps)
{
  // The three solvers converge each step to the same tolerance: their runs agree to far below the
  // motion. The constant matrix takes more iterations than Newton (no tangent), and the lagged
  // tangent fewer than the constant matrix (a tangent, a few steps old), which shows each was used.
  for (Method method : {Method::Full, Method::Physical, Method::Cubature})
  {
    SimulationParams s = methodParams(method, 30, 5e-3, IntegratorKind::Implicit);
    s.alpha = 0.5;
    Simulation newton(turnedSheet(), s);
    s.implicit_solver = ImplicitSolver::ConstantMatrix;
    Simulation constant(turnedSheet(), s);
    s.implicit_solver = ImplicitSolver::LaggedTangent;
    s.tangent_refresh_steps = 10;
    Simulation lagged(turnedSheet(), s);
    int newton_iterations = 0, constant_iterations = 0, lagged_iterations = 0;
    for (int k = 0; k < 100; ++k)
    {
      ASSERT_FALSE(newton.step().diverged) << toString(method);
      ASSERT_FALSE(constant.step().diverged) << toString(method);
      ASSERT_FALSE(lagged.step().diverged) << toString(method);
      newton_iterations += newton.lastNewtonIterations();
      constant_iterations += constant.lastNewtonIterations();
      lagged_iterations += lagged.lastNewtonIterations();
    }
    const double motion = largestParticleDistance(newton, newton.grid().initialPositions());
    EXPECT_GT(motion, 0.05) << toString(method);
    EXPECT_LT(largestParticleDistance(constant, newton.positions()), 1e-6 * motion) << toString(method);
    EXPECT_LT(largestParticleDistance(lagged, newton.positions()), 1e-6 * motion) << toString(method);
    EXPECT_GT(constant_iterations, newton_iterations) << toString(method);
    EXPECT_LT(lagged_iterations, constant_iterations) << toString(method);
    EXPECT_NE(lagged_iterations, newton_iterations) << toString(method);
  }
}
