// The cloth-on-a-table scene (config/cloth_table.yaml for the node, config/compare/cloth_table.yaml
// for modal_compare): the same grid and colliders in both, and in `full` the cloth drops onto the
// table, rests on it and drapes over its edge without entering it.
#include "yaml_colliders.h"
#include "yaml_parameter_source.h"

#include "modal_mass_spring/parameters.h"
#include "modal_mass_spring/simulation.h"

#include <gtest/gtest.h>

#include <cmath>
#include <string>

using namespace modal_mass_spring;

namespace
{

struct Scene
{
  GridParams grid;
  SimulationParams sim;
};

Scene load(const std::string& relative)
{
  const YamlParameterSource source = YamlParameterSource::fromFile(std::string(MODAL_SOURCE_DIR) + "/" + relative);
  Scene scene{loadGridParams(source), loadSimulationParams(source)};
  scene.sim.colliders = parseColliders(source.getNode("colliders"), "colliders");
  return scene;
}

}  // namespace

TEST(ClothTable, NodeAndCompareConfigsHoldTheSameScene)
{
  const Scene node = load("config/cloth_table.yaml"), compare = load("config/compare/cloth_table.yaml");
  EXPECT_EQ(node.grid.rows, compare.grid.rows);
  EXPECT_EQ(node.grid.cols, compare.grid.cols);
  EXPECT_EQ(node.grid.spacing, compare.grid.spacing);
  EXPECT_EQ(node.grid.rotation_deg, compare.grid.rotation_deg);
  ASSERT_EQ(node.sim.colliders.size(), compare.sim.colliders.size());
  for (size_t i = 0; i < node.sim.colliders.size(); ++i)
  {
    const Collider &a = node.sim.colliders[i], &b = compare.sim.colliders[i];
    EXPECT_EQ(a.type, b.type) << i;
    EXPECT_EQ(a.center, b.center) << i;
    EXPECT_EQ(a.half_extents, b.half_extents) << i;
    EXPECT_EQ(a.point, b.point) << i;
    EXPECT_EQ(a.normal, b.normal) << i;
    EXPECT_EQ(a.friction, b.friction) << i;
  }
}

// 2 s of `full` (the config's implicit 5 ms steps): no free particle ever deeper than 1 mm in the
// table or the floor; at the end some particles lie on the table top (within its footprint, at most
// 2 thicknesses above it) and some hang below the top beyond its edge (the drape), none has reached
// the floor.
TEST(ClothTable, FullDropsOntoTheTableAndDrapesOverItsEdge)
{
  const Scene scene = load("config/cloth_table.yaml");
  ASSERT_EQ(scene.sim.colliders.size(), 2u);
  const Collider& table = scene.sim.colliders[0];
  ASSERT_EQ(table.type, ColliderType::Box);
  SimulationParams params = scene.sim;
  params.method = Method::Full;
  Simulation sim(scene.grid, params);
  const double thickness = sim.contact()->thickness();
  const Eigen::Vector3d low = table.center - table.half_extents, high = table.center + table.half_extents;
  const double top = high.z();
  {
    // It starts above the table, partly beyond its edge (+y).
    const Eigen::Matrix3Xd start = sim.points();
    EXPECT_GT(start.row(2).minCoeff(), top + 0.05);
    EXPECT_GT(start.row(1).maxCoeff(), high.y() + 0.2);
  }
  double deepest = 0.0;
  const int steps = static_cast<int>(std::lround(2.0 / params.time_step));
  for (int k = 0; k < steps; ++k)
  {
    const StepResult r = sim.step();
    ASSERT_FALSE(r.diverged) << r.message;
    const Eigen::Matrix3Xd points = sim.points();
    for (int p = 0; p < points.cols(); ++p)
    {
      if (sim.grid().isFixed(p))
        continue;
      for (const Collider& c : scene.sim.colliders)
      {
        Eigen::Vector3d n;
        deepest = std::max(deepest, -signedDistance(c, Eigen::Isometry3d::Identity(), points.col(p), n));
      }
    }
  }
  EXPECT_LT(deepest, 1e-3);
  const Eigen::Matrix3Xd end = sim.points();
  int on_table = 0, draped = 0;
  for (int p = 0; p < end.cols(); ++p)
  {
    const Eigen::Vector3d x = end.col(p);
    const bool over = x.x() > low.x() && x.x() < high.x() && x.y() > low.y() && x.y() < high.y();
    on_table += over && x.z() < top + 2.0 * thickness;
    draped += !over && x.y() > high.y() && x.z() < top - 0.1;
  }
  EXPECT_GE(on_table, end.cols() / 4) << "particles resting on the table";
  EXPECT_GE(draped, end.cols() / 5) << "particles hanging more than 0.1 m below the top beyond the edge";
  EXPECT_GT(end.row(2).minCoeff(), scene.sim.colliders[1].point.z() + 0.1) << "the drape reaches the floor";
}
