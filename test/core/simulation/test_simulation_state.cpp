// saveState / restoreState: a state put back, in the same simulation or in another one built with the
// same parameters, replays the trajectory that followed it.
#include "modal_mass_spring/simulation.h"

#include "test_support.h"

#include <gtest/gtest.h>

#include <vector>

using namespace modal_mass_spring;

namespace
{

// Positions after each of `steps` steps from the simulation's current state.
std::vector<Eigen::VectorXd> trajectory(Simulation& sim, int steps, const Eigen::VectorXd& handle_start)
{
  std::vector<Eigen::VectorXd> path;
  for (int k = 0; k < steps; ++k)
  {
    if (handle_start.size() > 0)
      slideHandles(sim, handle_start, sim.stepCount(), 0.1);
    EXPECT_FALSE(sim.step().diverged);
    path.push_back(sim.positions());
  }
  return path;
}

double largestDifference(const std::vector<Eigen::VectorXd>& a, const std::vector<Eigen::VectorXd>& b)
{
  double d = 0.0;
  for (size_t k = 0; k < a.size(); ++k)
    d = std::max(d, (a[k] - b[k]).cwiseAbs().maxCoeff());
  return d;
}

}  // namespace

// `full` holding a cloth by two moving handles over a table it lands on: the saved state restored
// into the same simulation and into a fresh one replays the steps bit for bit (the acceleration a
// contact correction left, the handles and the collider come back with it).
TEST(SimulationState, RestoredStateReplaysHeldClothOnTable)
{
  const GridParams g = heldCloth({{0}, {5}}, 6);
  SimulationParams s = methodParams(Method::Full, 4, 1e-3);
  s.alpha = 0.5;
  s.colliders = {tableBelow(g, 0.02)};
  Simulation live(g, s);
  const Eigen::VectorXd handle_start = live.handlePositions();
  trajectory(live, 150, handle_start);
  const SimulationState saved = live.saveState();
  const std::vector<Eigen::VectorXd> original = trajectory(live, 150, handle_start);
  ASSERT_GT(live.contact()->report().touching[0], 0) << "the cloth must reach the table for the test to mean anything";
  EXPECT_GT((original.back() - original.front()).cwiseAbs().maxCoeff(), 1e-3);

  live.restoreState(saved);
  EXPECT_EQ(live.stepCount(), 150);
  EXPECT_EQ(largestDifference(trajectory(live, 150, handle_start), original), 0.0);

  Simulation copy(g, s);
  copy.restoreState(saved);
  EXPECT_EQ(largestDifference(trajectory(copy, 150, handle_start), original), 0.0);
}

// `physical` after a switch from `full`, which froze an offset the modes cannot hold: a simulation
// still on `full` takes the state, switches to its method and replays it.
TEST(SimulationState, RestoredModalStateKeepsItsOffset)
{
  const SimulationParams s = methodParams(Method::Full, 6, 1e-3);
  Simulation live(turnedSheet(), s);
  trajectory(live, 60, {});
  live.setMethod(Method::Physical);
  trajectory(live, 20, {});
  const SimulationState saved = live.saveState();
  ASSERT_GT(saved.offset.cwiseAbs().maxCoeff(), 1e-6);
  const std::vector<Eigen::VectorXd> original = trajectory(live, 100, {});

  Simulation copy(turnedSheet(), s);
  copy.restoreState(saved);
  EXPECT_EQ(copy.method(), Method::Physical);
  EXPECT_LT(largestDifference(trajectory(copy, 100, {}), original), 1e-12);
}

TEST(SimulationState, BadStateRefusedByNameChangingNothing)
{
  Simulation sim(turnedSheet(), methodParams(Method::Full, 4, 1e-3));
  sim.step(10);
  SimulationState bad = sim.saveState();
  const Eigen::VectorXd before = sim.positions();
  bad.coordinates.q.conservativeResize(bad.coordinates.q.size() - 1);
  const std::string wrong_size = refusal([&] { sim.restoreState(bad); });
  EXPECT_TRUE(contains(wrong_size, "state.coordinates")) << wrong_size;
  EXPECT_TRUE(contains(wrong_size, "must have " + std::to_string(sim.state().q.size()))) << wrong_size;
  bad = sim.saveState();
  bad.coordinates.v[0] = std::nan("");
  EXPECT_TRUE(contains(refusal([&] { sim.restoreState(bad); }), "state.velocities"));
  bad = sim.saveState();
  bad.anchor.resize(0);
  EXPECT_TRUE(contains(refusal([&] { sim.restoreState(bad); }), "state.anchor"));
  bad = sim.saveState();
  bad.time_step = -1.0;
  EXPECT_TRUE(contains(refusal([&] { sim.restoreState(bad); }), "time_step"));
  EXPECT_EQ(sim.positions(), before);
  EXPECT_EQ(sim.stepCount(), 10);
}
