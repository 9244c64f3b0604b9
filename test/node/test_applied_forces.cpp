// The forces of ~apply_force, without a master: what is refused and why, the sum, the expiry.
#include "applied_forces.h"
#include "warning_throttle.h"

#include <gtest/gtest.h>

#include <limits>

using namespace modal_mass_spring;

namespace
{

Grid grid3D()
{
  GridParams g;
  g.dimension = 3;  // 5 x 5, top row (particles 0-4) fixed
  return Grid(g);
}

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

}  // namespace

TEST(AppliedForces, SumsForcesOnTheirParticlesAndDropsThemWhenTheirTimeIsUp)
{
  const Grid grid = grid3D();
  AppliedForces forces(grid);
  Eigen::VectorXd total;
  ASSERT_EQ(forces.add({24, 20}, {Eigen::Vector3d(1, 0, 0)}, 0.5, 1.0), "");
  ASSERT_EQ(forces.add({24}, {Eigen::Vector3d(0, 2, 0)}, 0.0, 1.0), "");
  ASSERT_TRUE(forces.update(1.0, total));
  EXPECT_EQ(total.segment<3>(3 * 24), Eigen::Vector3d(1, 2, 0));
  EXPECT_EQ(total.segment<3>(3 * 20), Eigen::Vector3d(1, 0, 0));
  EXPECT_EQ(total.sum(), 4.0);
  EXPECT_FALSE(forces.update(1.2, total));  // nothing changed
  ASSERT_TRUE(forces.update(1.5, total));   // the first one's 0.5 s are up
  EXPECT_EQ(total.segment<3>(3 * 24), Eigen::Vector3d(0, 2, 0));
  EXPECT_EQ(total.sum(), 2.0);
  EXPECT_FALSE(forces.update(1e9, total));  // duration 0: until cleared
  EXPECT_EQ(forces.clear(), 1u);
  ASSERT_TRUE(forces.update(1e9, total));
  EXPECT_EQ(total.cwiseAbs().sum(), 0.0);
}

TEST(AppliedForces, ATwoDimensionalGridTakesXAndZ)
{
  const Grid grid{GridParams{}};
  AppliedForces forces(grid);
  Eigen::VectorXd total;
  ASSERT_EQ(forces.add({7}, {Eigen::Vector3d(1, 0, -3)}, 0.0, 0.0), "");
  forces.update(0.0, total);
  EXPECT_EQ(total.size(), 50);
  EXPECT_EQ(total.segment<2>(14), Eigen::Vector2d(1, -3));
  EXPECT_TRUE(contains(forces.add({7}, {Eigen::Vector3d(0, 1, 0)}, 0.0, 0.0), "y component"));
}

TEST(AppliedForces, BadRequestsAreRefusedByNameAndAddNothing)
{
  const Grid grid = grid3D();
  AppliedForces forces(grid);
  const Eigen::Vector3d f(1, 0, 0);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  EXPECT_TRUE(contains(forces.add({25}, {f}, 0, 0), "particle 25 is out of range: indices are row * cols + col in [0, 24]"));
  EXPECT_TRUE(contains(forces.add({2}, {f}, 0, 0), "particle 2 is fixed"));
  EXPECT_TRUE(contains(forces.add({9, 9}, {f}, 0, 0), "particle 9 is listed twice"));
  EXPECT_TRUE(contains(forces.add({9, 10, 11}, {f, f}, 0, 0), "3 particles but 2 forces"));
  EXPECT_TRUE(contains(forces.add({9}, {}, 0, 0), "1 particle but 0 forces"));
  EXPECT_TRUE(contains(forces.add({}, {f}, 0, 0), "no particles"));
  EXPECT_TRUE(contains(forces.add({9}, {Eigen::Vector3d(nan, 0, 0)}, 0, 0), "the force on particle 9 is not finite"));
  EXPECT_TRUE(contains(forces.add({9}, {Eigen::Vector3d(-nan, 1.5, 0)}, 0, 0), "not finite: (nan, 1.5, 0) N"));
  EXPECT_TRUE(contains(forces.add({9}, {f}, -1.0, 0), "duration -1"));
  EXPECT_TRUE(contains(forces.add({9}, {f}, std::numeric_limits<double>::infinity(), 0), "duration inf"));
  EXPECT_EQ(forces.size(), 0u);

  GridParams held;
  held.dimension = 3;
  held.fixed = {0, 1, 2, 3, 4};
  held.handles = {{22}};
  const Grid with_handle(held);
  AppliedForces on_handle(with_handle);
  EXPECT_TRUE(contains(on_handle.add({22}, {f}, 0, 0), "particle 22 is held by a handle"));
}

TEST(WarningThrottle, EachDistinctWarningOncePerPeriodAndABurstAtMost)
{
  WarningThrottle throttle(1.0, 3);
  EXPECT_TRUE(throttle.allow("particle 25 is out of range", 0.0));
  EXPECT_FALSE(throttle.allow("particle 25 is out of range", 0.5)) << "the same mistake again: throttled";
  EXPECT_TRUE(throttle.allow("the force on particle 9 is not finite", 0.6)) << "a different one is told";
  EXPECT_TRUE(throttle.allow("duration -1", 0.7));
  EXPECT_FALSE(throttle.allow("particle 2 is fixed", 0.8)) << "a flood is cut at the burst";
  EXPECT_TRUE(throttle.allow("particle 25 is out of range", 1.2)) << "its period is over";
  EXPECT_TRUE(throttle.allow("particle 2 is fixed", 1.3));
}
