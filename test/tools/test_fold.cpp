// The fold scene (config/fold.yaml for the node, config/compare/fold.yaml for modal_compare): the same
// towel, table and self-collision in both; in `full`, carried by the compare config's two handles, the
// towel is folded in half: no sampled step has two particles more than two springs apart closer than
// the thickness less 1 mm, and at the end the folded half lies at rest on the lower one.
#include "handle_scenarios.h"
#include "yaml_colliders.h"
#include "yaml_parameter_source.h"

#include "modal_mass_spring/parameters.h"
#include "modal_mass_spring/simulation.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>
#include <utility>

using namespace modal_mass_spring;

namespace
{

struct Scene
{
  GridParams grid;
  SimulationParams sim;
  YamlParameterSource source;
};

Scene load(const std::string& relative)
{
  YamlParameterSource source = YamlParameterSource::fromFile(std::string(MODAL_SOURCE_DIR) + "/" + relative);
  Scene scene{loadGridParams(source), loadSimulationParams(source), std::move(source)};
  scene.sim.colliders = parseColliders(source.getNode("colliders"), "colliders");
  return scene;
}

}  // namespace

TEST(Fold, NodeAndCompareConfigsHoldTheSameScene)
{
  const Scene node = load("config/fold.yaml"), compare = load("config/compare/fold.yaml");
  EXPECT_EQ(node.grid.rows, compare.grid.rows);
  EXPECT_EQ(node.grid.cols, compare.grid.cols);
  EXPECT_EQ(node.grid.spacing, compare.grid.spacing);
  EXPECT_EQ(node.grid.mass, compare.grid.mass);
  EXPECT_EQ(node.grid.rotation_deg, compare.grid.rotation_deg);
  EXPECT_EQ(node.sim.time_step, compare.sim.time_step);
  EXPECT_TRUE(node.sim.self_collision);
  EXPECT_TRUE(compare.sim.self_collision);
  EXPECT_EQ(node.sim.self_collision_thickness, compare.sim.self_collision_thickness);
  EXPECT_EQ(node.sim.self_friction, compare.sim.self_friction);
  ASSERT_EQ(node.sim.colliders.size(), compare.sim.colliders.size());
  for (size_t i = 0; i < node.sim.colliders.size(); ++i)
  {
    EXPECT_EQ(node.sim.colliders[i].center, compare.sim.colliders[i].center) << i;
    EXPECT_EQ(node.sim.colliders[i].half_extents, compare.sim.colliders[i].half_extents) << i;
  }
}

TEST(Fold, FullFoldsTheTowelInHalfWithItsLayersApart)
{
  const Scene scene = load("config/compare/fold.yaml");
  const std::vector<HandleScenario> scenarios =
      parseHandleScenarios(scene.source.getNode("handle_scenarios"), "handle_scenarios");
  ASSERT_EQ(scenarios.size(), 1u);
  const HandleScenario& fold = scenarios[0];
  SimulationParams params = scene.sim;
  params.method = Method::Full;
  Simulation sim(gridWithHandles(scene.grid, fold), params);
  const HandleDriver driver(fold, sim);
  const double thickness = params.self_collision_thickness;
  const int rows = scene.grid.rows, cols = scene.grid.cols;
  double closest = std::numeric_limits<double>::infinity();
  const long steps = std::lround(fold.duration() / params.time_step);
  for (long k = 0; k < steps; ++k)
  {
    driver.drive(sim);
    const StepResult r = sim.step();
    ASSERT_FALSE(r.diverged) << r.message;
    // The held corners take no part in self-collision: measured among the free particles.
    Eigen::VectorXd x = sim.positions();
    for (const std::vector<int>& handle : sim.grid().handles())
      for (int p : handle)
        x.segment<3>(3 * p) += Eigen::Vector3d(0.0, 0.0, 100.0 + p);
    closest = std::min(closest, closestSeparatedDistance(sim.grid(), x, thickness));
  }
  EXPECT_GT(closest, thickness - 1e-3);
  // At the end the far half (rows 10 to 19) lies over the near half, a thickness above it, at rest.
  const Eigen::Matrix3Xd points = sim.points();
  double lower = 0.0, upper = 0.0, upper_y = 0.0;
  for (int r = 0; r < rows / 2 - 1; ++r)
    for (int c = 0; c < cols; ++c)
      lower += points(2, r * cols + c);
  for (int r = rows / 2 + 1; r < rows; ++r)
    for (int c = 0; c < cols; ++c)
    {
      upper += points(2, r * cols + c);
      upper_y = std::max(upper_y, points(1, r * cols + c));
    }
  lower /= (rows / 2 - 1) * cols;
  upper /= (rows / 2 - 1) * cols;
  EXPECT_GT(upper - lower, thickness - 1e-3);
  EXPECT_LT(upper - lower, 3.0 * thickness);
  EXPECT_LT(upper_y, 0.5 * (rows - 1) * scene.grid.spacing + 0.03) << "the far half is over the near half";
  EXPECT_LT(sim.velocity().cwiseAbs().maxCoeff(), 0.05);
}
