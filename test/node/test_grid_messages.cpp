// The messages that show a grid, without a master: the surface's triangles and colours, the
// namespaces switched off, the size of a large sheet's markers, the point cloud.
#include "grid_messages.h"
#include "node_params.h"

#include <Eigen/Geometry>
#include <gtest/gtest.h>
#include <ros/serialization.h>
#include <sensor_msgs/point_cloud2_iterator.h>

#include <cmath>
#include <set>

namespace
{

using namespace modal_mass_spring;
using visualization_msgs::Marker;

GridParams sheet(int rows, int cols)
{
  GridParams params;
  params.rows = rows;
  params.cols = cols;
  params.dimension = 3;
  params.spacing = 0.05;
  return params;
}

const Marker* find(const visualization_msgs::MarkerArray& array, const std::string& ns)
{
  for (const auto& marker : array.markers)
    if (marker.ns == ns)
      return &marker;
  return nullptr;
}

// The normal of triangle t (vertices 3t..3t+2) of a TRIANGLE_LIST.
Eigen::Vector3d normal(const Marker& marker, size_t t)
{
  auto v = [&](size_t k) {
    const auto& p = marker.points[3 * t + k];
    return Eigen::Vector3d(p.x, p.y, p.z);
  };
  return (v(1) - v(0)).cross(v(2) - v(0));
}

TEST(GridMessages, SurfaceHasTwoTrianglesPerCellInBothWindings)
{
  const Grid grid(sheet(4, 5));
  const Eigen::Matrix3Xd points = grid.toPoints(grid.initialPositions());
  const auto array = makeMarkers(grid, MarkerOptions(), points, ros::Time(1.0));
  const Marker* surface = find(array, "surface");
  ASSERT_TRUE(surface);
  EXPECT_EQ(surface->type, Marker::TRIANGLE_LIST);
  EXPECT_EQ(surface->action, Marker::ADD);
  const size_t cells = 3 * 4;
  ASSERT_EQ(surface->points.size(), cells * 2 * 2 * 3);
  EXPECT_EQ(surface->colors.size(), surface->points.size()) << "a colour per vertex";
  // Each cell: two triangles facing one way, the same two facing the other way, each half the cell.
  int up = 0, down = 0;
  for (size_t t = 0; t < surface->points.size() / 3; ++t)
  {
    const Eigen::Vector3d n = normal(*surface, t);
    EXPECT_NEAR(n.norm(), 0.05 * 0.05, 1e-12) << "triangle " << t;  // twice the area of half a cell
    (n.y() > 0 ? up : down)++;
  }
  EXPECT_EQ(up, static_cast<int>(2 * cells));
  EXPECT_EQ(down, static_cast<int>(2 * cells));
  // Every particle is a vertex.
  std::set<std::tuple<double, double, double>> vertices;
  for (const auto& p : surface->points)
    vertices.emplace(p.x, p.y, p.z);
  EXPECT_EQ(vertices.size(), 20u);
}

TEST(GridMessages, StretchedParticlesAreColouredRedAndRestOnesNot)
{
  const Grid grid(sheet(3, 3));
  Eigen::Matrix3Xd points = grid.toPoints(grid.initialPositions());
  MarkerOptions options;
  const auto at_rest = makeMarkers(grid, options, points, ros::Time(1.0));
  const Marker* rest_surface = find(at_rest, "surface");
  ASSERT_TRUE(rest_surface);
  for (const auto& c : rest_surface->colors)
    EXPECT_EQ(c.r, rest_surface->colors[0].r);
  points.row(0) *= 1.2;  // stretched by 20% along x
  const Eigen::VectorXd strains = particleStrains(grid, points);
  for (int k = 0; k < strains.size(); ++k)
    EXPECT_GT(strains[k], 0.0);
  const auto stretched = makeMarkers(grid, options, points, ros::Time(1.0));
  const Marker* surface = find(stretched, "surface");
  ASSERT_TRUE(surface);
  for (const auto& c : surface->colors)
  {
    EXPECT_GT(c.r, c.b);
    EXPECT_LT(c.g, rest_surface->colors[0].g);
  }
  // The strains the caller already has give the same colours (the node computes them once a tick).
  const auto given = makeMarkers(grid, options, points, ros::Time(1.0), strains);
  EXPECT_EQ(find(given, "surface")->colors, surface->colors);
  EXPECT_EQ(find(given, "surface")->points, surface->points);
}

TEST(GridMessages, NamespacesCanBeSwitchedOffAndArePrefixed)
{
  const Grid grid(sheet(3, 4));
  const Eigen::Matrix3Xd points = grid.toPoints(grid.initialPositions());
  MarkerOptions options;
  options.ns_prefix = "linear/";
  options.particles = false;
  options.springs = false;
  options.label = "linear";
  const auto array = makeMarkers(grid, options, points, ros::Time(2.0));
  ASSERT_TRUE(find(array, "linear/surface"));
  EXPECT_EQ(find(array, "linear/surface")->action, Marker::ADD);
  ASSERT_TRUE(find(array, "linear/particles"));
  EXPECT_EQ(find(array, "linear/particles")->action, Marker::DELETE);
  EXPECT_TRUE(find(array, "linear/particles")->points.empty());
  ASSERT_TRUE(find(array, "linear/springs"));
  EXPECT_EQ(find(array, "linear/springs")->action, Marker::DELETE);
  const Marker* label = find(array, "linear/label");
  ASSERT_TRUE(label);
  EXPECT_EQ(label->type, Marker::TEXT_VIEW_FACING);
  EXPECT_EQ(label->text, "linear");
  for (const auto& marker : array.markers)
    EXPECT_EQ(marker.header.stamp, ros::Time(2.0));
}

TEST(GridMessages, ParticlesAndSpringsAreDrawnWhereThePointsAre)
{
  const Grid grid(sheet(3, 4));
  const Eigen::Matrix3Xd points = grid.toPoints(grid.initialPositions());
  MarkerOptions options;
  options.offset = Eigen::Vector3d(1.0, 2.0, 3.0);
  const auto array = makeMarkers(grid, options, points, ros::Time(1.0));
  const Marker* particles = find(array, "particles");
  const Marker* springs = find(array, "springs");
  ASSERT_TRUE(particles && springs);
  ASSERT_EQ(particles->points.size(), 12u);
  EXPECT_EQ(springs->points.size(), 2 * grid.springs().size());
  for (int k = 0; k < 12; ++k)
  {
    EXPECT_DOUBLE_EQ(particles->points[k].x, points(0, k) + 1.0);
    EXPECT_DOUBLE_EQ(particles->points[k].y, points(1, k) + 2.0);
    EXPECT_DOUBLE_EQ(particles->points[k].z, points(2, k) + 3.0);
  }
}

// A 100 x 100 sheet with the node's defaults: particles and springs off above detail_max_particles,
// the surface thinned to surface_max_cells. Without that, the springs alone would be 3.2 MB a message.
TEST(GridMessages, HundredByHundredSheetMarkersStayUnderOneMegabyte)
{
  const Grid grid(sheet(100, 100));
  const Eigen::Matrix3Xd points = grid.toPoints(grid.initialPositions());
  const NodeParams defaults;  // the defaults loadNodeParams starts from
  MarkerOptions options;
  options.particles = options.springs = grid.numParticles() <= defaults.detail_max_particles;
  options.surface_max_cells = defaults.surface_max_cells;
  const auto array = makeMarkers(grid, options, points, ros::Time(1.0));
  const uint32_t bytes = ros::serialization::serializationLength(array);
  EXPECT_LT(bytes, 1000000u);
  const Marker* surface = find(array, "surface");
  ASSERT_TRUE(surface);
  EXPECT_GT(surface->points.size(), 0u);
  EXPECT_LE(surface->points.size(), 12u * defaults.surface_max_cells);
  // It still spans the whole sheet: the corners are vertices.
  double max_x = -1e9, min_z = 1e9;
  for (const auto& p : surface->points)
  {
    max_x = std::max(max_x, p.x);
    min_z = std::min(min_z, p.z);
  }
  EXPECT_DOUBLE_EQ(max_x, points.row(0).maxCoeff());
  EXPECT_DOUBLE_EQ(min_z, points.row(2).minCoeff());
  std::printf("100 x 100 sheet, default markers: %u bytes, %zu surface vertices\n", bytes, surface->points.size());
}

TEST(GridMessages, SurfaceLinesKeepTheEdgesAndTheCellLimit)
{
  EXPECT_EQ(surfaceLines(5, 1), (std::vector<int>{0, 1, 2, 3, 4}));
  EXPECT_EQ(surfaceLines(5, 3), (std::vector<int>{0, 3, 4}));
  EXPECT_EQ(surfaceStride(20, 20, 1600), 1);
  for (int n : {50, 100, 333})
  {
    const int stride = surfaceStride(n, n, 1600);
    const size_t lines = surfaceLines(n, stride).size();
    EXPECT_LE((lines - 1) * (lines - 1), 1600u) << n;
    EXPECT_EQ(surfaceLines(n, stride).back(), n - 1);
  }
}

TEST(GridMessages, PointCloudHasOnePointPerParticleWithStrain)
{
  const Grid grid(sheet(3, 4));
  Eigen::Matrix3Xd points = grid.toPoints(grid.initialPositions());
  points.row(2) *= 1.1;
  const Eigen::VectorXd strains = particleStrains(grid, points);
  std::vector<int> contacts(12, -1);
  contacts[4] = 0;
  contacts[7] = 2;
  const auto cloud = makePointCloud(points, strains, contacts, Eigen::Vector3d(0.5, 0.0, 0.0), "world", ros::Time(3.0));
  EXPECT_EQ(cloud.header.frame_id, "world");
  EXPECT_EQ(cloud.header.stamp, ros::Time(3.0));
  EXPECT_EQ(cloud.width * cloud.height, 12u);
  ASSERT_EQ(cloud.fields.size(), 5u);
  EXPECT_EQ(cloud.fields[3].name, "strain");
  EXPECT_EQ(cloud.fields[4].name, "contact");
  EXPECT_EQ(cloud.fields[4].datatype, sensor_msgs::PointField::INT32);
  sensor_msgs::PointCloud2ConstIterator<float> x(cloud, "x"), z(cloud, "z"), strain(cloud, "strain");
  sensor_msgs::PointCloud2ConstIterator<int32_t> contact(cloud, "contact");
  for (int k = 0; k < 12; ++k, ++x, ++z, ++strain, ++contact)
  {
    EXPECT_FLOAT_EQ(*x, static_cast<float>(points(0, k) + 0.5));
    EXPECT_FLOAT_EQ(*z, static_cast<float>(points(2, k)));
    EXPECT_FLOAT_EQ(*strain, static_cast<float>(strains[k]));
    EXPECT_EQ(*contact, contacts[k]);
  }
  // Without contacts (no colliders), every particle says -1.
  const auto bare = makePointCloud(points, strains, {}, Eigen::Vector3d::Zero(), "world", ros::Time(3.0));
  sensor_msgs::PointCloud2ConstIterator<int32_t> none(bare, "contact");
  for (int k = 0; k < 12; ++k, ++none)
    EXPECT_EQ(*none, -1);
}

}  // namespace
