// The surface distance between two configurations of a grid, against its closed forms and a search
// over every triangle.
#include "modal_mass_spring/surface_distance.h"

#include "contact/geometry.h"

#include <Eigen/Geometry>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

using namespace modal_mass_spring;

namespace
{

GridParams flatSheet(int rows, int cols)
{
  GridParams g;
  g.rows = rows;
  g.cols = cols;
  g.dimension = 3;
  g.spacing = 0.1;
  g.rotation_deg = 90.0;  // lying in a horizontal plane
  return g;
}

// The distance of every free particle of `from` to every triangle of `to`, taken the long way.
double bruteForce(const Grid& grid, const Eigen::Matrix3Xd& a, const Eigen::Matrix3Xd& b)
{
  const int rows = grid.params().rows, cols = grid.params().cols;
  auto toSurface = [&](const Eigen::Matrix3Xd& from, const Eigen::Matrix3Xd& to, int& count) {
    double sum = 0.0;
    for (int p = 0; p < grid.numParticles(); ++p)
    {
      if (grid.isFixed(p) || grid.isHandle(p))
        continue;
      double best = std::numeric_limits<double>::infinity(), w[3];
      for (int r = 0; r + 1 < rows; ++r)
        for (int c = 0; c + 1 < cols; ++c)
        {
          const auto v = [&](int i, int j) { return Eigen::Vector3d(to.col(grid.particleIndex(i, j))); };
          best = std::min(best, (from.col(p) - closestOnTriangle(from.col(p), v(r, c), v(r, c + 1), v(r + 1, c + 1), w))
                                    .squaredNorm());
          best = std::min(best, (from.col(p) - closestOnTriangle(from.col(p), v(r, c), v(r + 1, c + 1), v(r + 1, c), w))
                                    .squaredNorm());
        }
      sum += best;
      ++count;
    }
    return sum;
  };
  int count = 0;
  const double sum = toSurface(a, b, count) + toSurface(b, a, count);
  return std::sqrt(sum / count);
}

}  // namespace

TEST(SurfaceDistance, IsZeroForOneConfigurationAndTheOffsetForASheetMovedAlongItsNormal)
{
  const Grid grid(flatSheet(7, 9));
  const Eigen::Matrix3Xd a = grid.toPoints(grid.initialPositions());
  EXPECT_EQ(surfaceDistance(grid, a, a), 0.0);
  const Eigen::Vector3d normal = (a.col(grid.particleIndex(0, 1)) - a.col(0)).cross(a.col(grid.particleIndex(1, 0)) - a.col(0)).normalized();
  const Eigen::Matrix3Xd lifted = a.colwise() + 0.03 * normal;
  EXPECT_NEAR(surfaceDistance(grid, a, lifted), 0.03, 1e-12);
}

TEST(SurfaceDistance, ParticlesSlidAlongTheSheetAreNotApartButParticleByParticleThey)
{
  const Grid grid(flatSheet(9, 9));
  const Eigen::Matrix3Xd a = grid.toPoints(grid.initialPositions());
  // The inner particles slid 3 cm along the rows, in the sheet's plane; the border kept.
  Eigen::Matrix3Xd slid = a;
  const Eigen::Vector3d along_row = (a.col(1) - a.col(0)).normalized();
  double sum2 = 0.0;
  int free = 0;
  for (int r = 1; r < 8; ++r)
    for (int c = 1; c < 8; ++c)
      slid.col(grid.particleIndex(r, c)) += 0.03 * along_row;
  for (int p = 0; p < grid.numParticles(); ++p)
    if (!grid.isFixed(p))
      sum2 += (slid.col(p) - a.col(p)).squaredNorm(), ++free;
  EXPECT_GT(std::sqrt(sum2 / free), 0.02);
  EXPECT_LT(surfaceDistance(grid, a, slid), 1e-12);
}

TEST(SurfaceDistance, FindsTheNearestTriangleOfACrumpledSheet)
{
  std::mt19937 random(7);
  std::normal_distribution<double> noise(0.0, 0.05);  // half the spacing: folds and far points both
  for (auto [rows, cols] : {std::pair{12, 17}, std::pair{17, 12}, std::pair{2, 2}, std::pair{2, 9}})
  {
    const Grid grid(flatSheet(rows, cols));
    Eigen::Matrix3Xd a = grid.toPoints(grid.initialPositions()), b = a;
    for (int p = 0; p < grid.numParticles(); ++p)
      for (int k = 0; k < 3; ++k)
        a(k, p) += noise(random), b(k, p) += noise(random);
    b.row(2).array() -= 0.2;  // some particles far from the other surface
    EXPECT_NEAR(surfaceDistance(grid, a, b), bruteForce(grid, a, b), 1e-12) << rows << " x " << cols;
  }
}

TEST(SurfaceDistance, AGridOfOneColumnIsItsPolyline)
{
  const Grid grid(flatSheet(6, 1));
  const Eigen::Matrix3Xd a = grid.toPoints(grid.initialPositions());
  const Eigen::Matrix3Xd lifted = a.colwise() + Eigen::Vector3d(0.0, 0.0, 0.04);
  EXPECT_NEAR(surfaceDistance(grid, a, lifted), 0.04, 1e-12);
}
