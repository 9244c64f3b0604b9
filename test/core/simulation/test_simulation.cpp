// The three methods against closed forms, against each other, and their error handling.
#include "modal_mass_spring/simulation.h"

#include "modal_mass_spring/spring_forces.h"

#include "test_support.h"

#include <gtest/gtest.h>

#include <cmath>
#include <type_traits>

using namespace modal_mass_spring;

// The force models and integrators refer to the Simulation's members: it must stay where it was built.
static_assert(!std::is_copy_constructible_v<Simulation> && !std::is_copy_assignable_v<Simulation>);
static_assert(!std::is_move_constructible_v<Simulation> && !std::is_move_assignable_v<Simulation>);

namespace
{

GridParams weightless(int rows = 5, int cols = 5)
{
  GridParams p;
  p.rows = rows;
  p.cols = cols;
  p.gravity.setZero();
  return p;
}

SimulationParams withMethod(Method method, int r, double dt = 1e-3)
{
  SimulationParams s;
  s.method = method;
  s.num_modes = r;
  s.time_step = dt;
  return s;
}

double maxDistance(const Eigen::VectorXd& a, const Eigen::VectorXd& b)
{
  return (a - b).cwiseAbs().maxCoeff();
}

}  // namespace

TEST(Simulation, SingleDampedModeUnderLinearFollowsClosedForm)
{
  SimulationParams s = withMethod(Method::Linear, 4);
  s.alpha = 0.8;
  s.beta = 2e-3;
  Simulation sim(weightless(), s);
  const double amplitude = 0.01;
  const int mode = 1;
  const Eigen::VectorXd shape = sim.basis().phi.col(mode);
  sim.setPhysicalState(amplitude * shape, Eigen::VectorXd::Zero(shape.size()));

  const double omega = sim.basis().frequencies[mode];
  const double c = s.alpha + s.beta * omega * omega;  // X'' + c X' + omega^2 X = 0
  const double omega_d = std::sqrt(omega * omega - 0.25 * c * c);
  double worst = 0.0;
  for (int k = 1; k <= 3000; ++k)
  {
    const StepResult result = sim.step();
    ASSERT_FALSE(result.diverged) << result.message;
    const double t = sim.time();
    const double expected =
        amplitude * std::exp(-0.5 * c * t) * (std::cos(omega_d * t) + 0.5 * c / omega_d * std::sin(omega_d * t));
    worst = std::max(worst, std::abs(sim.state().q[mode] - expected));
    for (int other = 0; other < 4; ++other)
    {
      if (other != mode)
      {
        ASSERT_NEAR(sim.state().q[other], 0.0, 1e-14);
      }
    }
  }
  // Newmark's phase error is O((omega dt)^2) per radian; here that is below 1e-4 of the amplitude.
  EXPECT_LT(worst, 1e-4 * amplitude);
  EXPECT_LT(std::abs(sim.state().q[mode]), 0.5 * amplitude);  // and it did decay
}

TEST(Simulation, PhysicalWithEveryModeMatchesFull)
{
  GridParams g;
  g.rows = 4;
  g.cols = 3;
  g.mass = 0.02;
  SimulationParams s = withMethod(Method::Full, 2 * 9);
  s.alpha = 0.3;
  s.beta = 1e-3;
  Simulation full(g, s);
  s.method = Method::Physical;
  Simulation physical(g, s);
  double largest_motion = 0.0;
  for (int k = 0; k < 3000; ++k)
  {
    ASSERT_FALSE(full.step().diverged);
    ASSERT_FALSE(physical.step().diverged);
    largest_motion = std::max(largest_motion, maxDistance(full.positions(), full.grid().initialPositions()));
    ASSERT_LT(maxDistance(full.positions(), physical.positions()), 1e-10) << "step " << k;
  }
  EXPECT_GT(largest_motion, 0.01);  // gravity really moved it
}

TEST(Simulation, LinearAndPhysicalAgreeAtSmallAmplitudeOnly)
{
  const GridParams g = weightless();
  auto relativeGap = [&](double amplitude) {
    Simulation linear(g, withMethod(Method::Linear, 6));
    Simulation physical(g, withMethod(Method::Physical, 6));
    const Eigen::VectorXd shape = linear.basis().phi.col(0) + linear.basis().phi.col(2);
    const Eigen::VectorXd u = amplitude / shape.cwiseAbs().maxCoeff() * shape;  // largest particle offset
    const Eigen::VectorXd v = Eigen::VectorXd::Zero(u.size());
    linear.setPhysicalState(u, v);
    physical.setPhysicalState(u, v);
    double gap = 0.0;
    for (int k = 0; k < 2000; ++k)
    {
      linear.step();
      physical.step();
      gap = std::max(gap, maxDistance(linear.positions(), physical.positions()));
    }
    return gap / amplitude;
  };
  const double spacing = g.spacing;
  EXPECT_LT(relativeGap(1e-5 * spacing), 1e-3);
  EXPECT_GT(relativeGap(0.5 * spacing), 5e-2);
}

TEST(Simulation, UndampedFullKeepsEnergyBounded)
{
  Simulation sim(weightless(), withMethod(Method::Full, 4, 2e-4));
  std::srand(11);
  const int n = sim.grid().numFreeDofs();
  sim.setPhysicalState(0.2 * sim.grid().params().spacing * Eigen::VectorXd::Random(n), Eigen::VectorXd::Zero(n));
  const double initial = sim.totalEnergy();
  double worst = 0.0;
  for (int k = 0; k < 100; ++k)
  {
    ASSERT_FALSE(sim.step(1000).diverged);
    worst = std::max(worst, std::abs(sim.totalEnergy() - initial));
  }
  EXPECT_GT(initial, 0.0);
  EXPECT_LT(worst, 1e-2 * initial);
}

TEST(Simulation, MethodSwitchKeepsPositionsAndResetRestores)
{
  Simulation sim(GridParams{}, withMethod(Method::Physical, 8));
  sim.step(400);
  const Eigen::VectorXd before = sim.positions();
  ASSERT_GT(maxDistance(before, sim.grid().initialPositions()), 1e-3);

  sim.setMethod(Method::Linear);  // modal to modal: the same X
  EXPECT_LT(maxDistance(sim.positions(), before), 1e-14);
  sim.setMethod(Method::Full);  // u = Phi X
  EXPECT_LT(maxDistance(sim.positions(), before), 1e-14);
  EXPECT_EQ(sim.method(), Method::Full);

  sim.step(100);
  const Eigen::VectorXd u = sim.displacement();
  const Eigen::VectorXd full_positions = sim.positions();
  sim.setMethod(Method::Physical);  // X: the M-orthogonal projection of u; the rest stays frozen
  const ModalBasis& b = sim.basis();
  const Eigen::VectorXd modal = b.phi.transpose() * (sim.grid().particleMass() * u);
  EXPECT_LT(maxDistance(sim.state().q, modal), 1e-14);
  EXPECT_GT(maxDistance(b.phi * modal, u), 1e-4);  // the modes alone would have moved particles
  EXPECT_LT(maxDistance(sim.positions(), full_positions), 1e-14);
  // Stepping on from there moves the particles by about a step's motion, not by the residual.
  const Eigen::VectorXd before_step = sim.positions();
  sim.step(1);
  EXPECT_LT(maxDistance(sim.positions(), before_step), 1e-3);
  const Eigen::VectorXd after_step = sim.positions();
  sim.setMethod(Method::Full);  // u = offset + Phi X, exactly
  EXPECT_LT(maxDistance(sim.positions(), after_step), 1e-14);
  sim.setMethod(Method::Linear);
  sim.setMethod(Method::Physical);

  const long steps = sim.stepCount();
  sim.step(10);
  EXPECT_EQ(sim.stepCount(), steps + 10);
  sim.reset();
  EXPECT_EQ(sim.stepCount(), 0);
  EXPECT_EQ(sim.positions(), sim.grid().initialPositions());
  EXPECT_EQ(sim.kineticEnergy(), 0.0);
}

TEST(Simulation, SwitchWithEveryModeIsExact)
{
  GridParams g;
  g.rows = 3;
  g.cols = 3;
  Simulation sim(g, withMethod(Method::Full, 12));
  sim.step(300);
  const Eigen::VectorXd before = sim.positions();
  sim.setMethod(Method::Physical);
  EXPECT_LT(maxDistance(sim.positions(), before), 1e-12);
}

TEST(Simulation, TooLargeStepDivergesAndKeepsLastGoodState)
{
  for (Method method : {Method::Full, Method::Linear, Method::Physical})
  {
    // Past 2 / omega_max of each method: the reduced ones only see their 6 modes.
    const SimulationParams s = withMethod(method, 6, method == Method::Full ? 0.05 : 0.5);
    Simulation sim(GridParams{}, s);
    const StepResult result = sim.step(5000);
    ASSERT_TRUE(result.diverged) << toString(method);
    EXPECT_LT(result.steps_taken, 5000);
    EXPECT_NE(result.message.find(toString(method)), std::string::npos) << result.message;
    EXPECT_NE(result.message.find("time_step"), std::string::npos) << result.message;
    EXPECT_TRUE(sim.positions().allFinite());
    EXPECT_EQ(sim.stepCount(), result.steps_taken);

    // The kept state is exactly the one after the last good step.
    Simulation replay(GridParams{}, s);
    replay.step(result.steps_taken);
    EXPECT_EQ(replay.positions(), sim.positions());

    // Stepping a diverged simulation changes nothing until reset or a method switch.
    const StepResult again = sim.step(10);
    EXPECT_TRUE(again.diverged);
    EXPECT_EQ(again.steps_taken, 0);
    EXPECT_EQ(replay.positions(), sim.positions());
    sim.reset();
    EXPECT_FALSE(sim.diverged());
  }
}

TEST(Simulation, SmallerTimeStepRecoversAfterSetTimeStep)
{
  Simulation sim(GridParams{}, withMethod(Method::Physical, 4, 1.0));
  EXPECT_TRUE(sim.step(100).diverged);
  sim.setTimeStep(1e-3);
  sim.reset();
  EXPECT_FALSE(sim.step(1000).diverged);
  EXPECT_THROW(sim.setTimeStep(-1.0), std::invalid_argument);
}

TEST(Simulation, SetTimeStepKeepsTheStateAndTheNewStepIsUsed)
{
  Simulation sim(GridParams{}, withMethod(Method::Physical, 4, 1e-3));
  sim.step(300);
  const Eigen::VectorXd x = sim.positions(), v = sim.velocity();
  sim.setTimeStep(2e-3);
  EXPECT_EQ(sim.positions(), x);
  EXPECT_EQ(sim.velocity(), v);
  EXPECT_EQ(sim.params().time_step, 2e-3);
  // Two steps of 2 ms land close to four of 1 ms, far from where two of 1 ms would.
  Simulation reference(GridParams{}, withMethod(Method::Physical, 4, 1e-3));
  reference.step(304);
  sim.step(2);
  EXPECT_LT((sim.positions() - reference.positions()).cwiseAbs().maxCoeff(), 1e-4);
  EXPECT_TRUE(contains(refusal([&] { sim.setTimeStep(0.0); }), "'time_step' = 0"));
  EXPECT_EQ(sim.params().time_step, 2e-3);
}

// A step spanning several time steps is one step of their sum, on the same clock: stepCount() and
// time() count time steps.
TEST(Simulation, AStepSpanningSeveralTimeStepsIsOneStepOfTheirSum)
{
  Simulation spanned(GridParams{}, withMethod(Method::Full, 4, 1e-3));
  Simulation longer(GridParams{}, withMethod(Method::Full, 4, 3e-3));
  spanned.setStepSpan(3);
  EXPECT_EQ(spanned.stepSpan(), 3);
  spanned.step(50);
  longer.step(50);
  EXPECT_LT((spanned.positions() - longer.positions()).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_EQ(spanned.stepCount(), 150);
  EXPECT_DOUBLE_EQ(spanned.time(), 0.15);
  EXPECT_DOUBLE_EQ(spanned.timeSinceStateSet(), 0.15);
  EXPECT_DOUBLE_EQ(spanned.nextStepTime(), 0.153);
  EXPECT_EQ(spanned.params().time_step, 1e-3);
  // The span is part of the state: restored elsewhere, the next steps are the same.
  Simulation other(GridParams{}, withMethod(Method::Full, 4, 1e-3));
  other.restoreState(spanned.saveState());
  EXPECT_EQ(other.stepSpan(), 3);
  other.step(5);
  spanned.step(5);
  EXPECT_EQ(other.positions(), spanned.positions());
  // Back to one: the next step is a millisecond's, as at 1 ms from the same state.
  Simulation one(GridParams{}, withMethod(Method::Full, 4, 1e-3));
  spanned.setStepSpan(1);
  one.restoreState(spanned.saveState());
  spanned.step();
  EXPECT_EQ(spanned.stepCount(), 166);
  EXPECT_DOUBLE_EQ(spanned.time(), 0.166);
  one.step();
  EXPECT_EQ(spanned.positions(), one.positions());
  EXPECT_TRUE(contains(refusal([&] { spanned.setStepSpan(0); }), "'step_span' = 0"));
  EXPECT_EQ(spanned.stepSpan(), 1);
  // A reset starts again a time step a step.
  other.reset();
  EXPECT_EQ(other.stepSpan(), 1);
}

// A cubature on the linear modes of a sheet held by two single-particle grips, linearized at rest,
// has no constraint modes (K_ii is singular: no out-of-plane stiffness): it is refused before its
// training starts, not after it. Held by the whole top row, the same cubature trains.
TEST(Simulation, ACubatureThatCannotFollowItsHandlesIsRefusedBeforeItsTraining)
{
  SimulationParams params = methodParams(Method::Cubature, 6, 1e-3);
  params.linearization = Linearization::Rest;
  params.initial_state = InitialState::Initial;
  int iterations = 0;
  const IterationFn count = [&](const std::string& stage, int, double, double) { iterations += stage == "cubature"; };
  try
  {
    Simulation(heldCloth({{0}, {5}}, 6), params, {}, {}, count);
    ADD_FAILURE() << "two point grips on the linear modes were accepted";
  }
  catch (const std::runtime_error& error)
  {
    EXPECT_NE(std::string(error.what()).find("constraint modes"), std::string::npos) << error.what();
  }
  EXPECT_EQ(iterations, 0) << "the training ran before the refusal";

  params.linearization = Linearization::Equilibrium;
  params.initial_state = InitialState::Equilibrium;
  Simulation held(heldCloth({{0, 1, 2, 3, 4, 5}}, 6), params, {}, {}, count);
  EXPECT_GT(iterations, 0) << "a training reports its iterations";
}
