// The installed API alone, as a user of the library compiles it: this file is built without the
// core's internal include folder, so it fails to build when an installed header needs an internal one.
#include <modal_mass_spring/modal_mass_spring.h>

#include <gtest/gtest.h>

namespace modal_mass_spring
{
namespace
{

// The README's example: the paper's 2D grid with `physical`, then the same state under `full`.
TEST(PublicApi, ReadmeExampleStepsPhysicalThenFullFromTheSameState)
{
  GridParams grid;
  SimulationParams params;
  params.method = Method::Physical;
  params.num_modes = 4;
  params.time_step = 1e-3;
  Simulation sim(grid, params);
  const StepResult result = sim.step(1000);
  ASSERT_FALSE(result.diverged) << result.message;
  const Eigen::Matrix3Xd start = sim.grid().toPoints(sim.startPositions());
  const Eigen::Matrix3Xd x = sim.points();
  ASSERT_TRUE(x.allFinite());
  EXPECT_LT(x(2, 24), start(2, 24));  // the free corner has fallen under gravity
  sim.setMethod(Method::Full);
  EXPECT_TRUE(sim.points().isApprox(x, 1e-12));  // a switch moves no particle
  EXPECT_EQ(sim.step(1000).steps_taken, 1000);
  EXPECT_EQ(sim.method(), Method::Full);
}

TEST(PublicApi, BadParameterIsRefusedByName)
{
  GridParams grid;
  SimulationParams params;
  params.time_step = -1.0;
  try
  {
    Simulation sim(grid, params);
    FAIL() << "a negative time_step was accepted";
  }
  catch (const std::invalid_argument& error)
  {
    EXPECT_NE(std::string(error.what()).find("time_step"), std::string::npos) << error.what();
  }
}

}  // namespace
}  // namespace modal_mass_spring
