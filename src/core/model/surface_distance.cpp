// The surface distance between two configurations of a grid (surface_distance.h): each particle's
// nearest point on the other surface, found in a tree of bounding boxes over the grid's quads.
#include "modal_mass_spring/surface_distance.h"

#include "contact/geometry.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

namespace modal_mass_spring
{
namespace
{

double squaredToSegment(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b)
{
  const Eigen::Vector3d ab = b - a;
  const double length2 = ab.squaredNorm();
  const double t = length2 > 0.0 ? std::clamp((p - a).dot(ab) / length2, 0.0, 1.0) : 0.0;
  return (p - a - t * ab).squaredNorm();
}

// The grid's cells (a quad split along its diagonal (r, c)-(r + 1, c + 1), as the self-collision's
// triangles; a segment where the grid is one row or column), their boxes in a binary tree that halves
// the longer side of a block of cells. Rebuilt for every configuration: it takes one pass over the grid.
class CellTree
{
public:
  CellTree(const GridParams& grid, const Eigen::Matrix3Xd& points)
    : points_(points)
    , cols_(grid.cols)
    , cell_rows_(std::max(1, grid.rows - 1))
    , cell_cols_(std::max(1, grid.cols - 1))
    , last_row_(grid.rows - 1)
    , last_col_(grid.cols - 1)
  {
    nodes_.reserve(2 * static_cast<size_t>(cell_rows_) * cell_cols_);
    build(0, cell_rows_, 0, cell_cols_);
  }

  double squaredDistance(const Eigen::Vector3d& p) const
  {
    double best = std::numeric_limits<double>::infinity();
    search(0, p, best);
    return best;
  }

private:
  struct Node
  {
    Eigen::AlignedBox3d box;
    int r0, r1, c0, c1;  // the cells [r0, r1) x [c0, c1)
    int children[2] = {-1, -1};
  };

  Eigen::Vector3d at(int r, int c) const { return points_.col(std::min(r, last_row_) * cols_ + std::min(c, last_col_)); }

  int build(int r0, int r1, int c0, int c1)
  {
    const int index = static_cast<int>(nodes_.size());
    nodes_.push_back({Eigen::AlignedBox3d(), r0, r1, c0, c1});
    if (r1 - r0 == 1 && c1 - c0 == 1)
    {
      for (int r = r0; r <= r0 + 1; ++r)
        for (int c = c0; c <= c0 + 1; ++c)
          nodes_[index].box.extend(at(r, c));
      return index;
    }
    int children[2];
    if (r1 - r0 >= c1 - c0)
    {
      const int middle = (r0 + r1) / 2;
      children[0] = build(r0, middle, c0, c1);
      children[1] = build(middle, r1, c0, c1);
    }
    else
    {
      const int middle = (c0 + c1) / 2;
      children[0] = build(r0, r1, c0, middle);
      children[1] = build(r0, r1, middle, c1);
    }
    Node& node = nodes_[index];
    node.children[0] = children[0], node.children[1] = children[1];
    node.box = nodes_[children[0]].box.merged(nodes_[children[1]].box);
    return index;
  }

  void search(int index, const Eigen::Vector3d& p, double& best) const
  {
    const Node& node = nodes_[index];
    if (node.children[0] < 0)
    {
      const int r = node.r0, c = node.c0;
      if (last_row_ == 0 || last_col_ == 0)
      {
        best = std::min(best, squaredToSegment(p, at(r, c), at(r + 1, c + 1)));
        return;
      }
      double w[3];
      best = std::min(best, (p - closestOnTriangle(p, at(r, c), at(r, c + 1), at(r + 1, c + 1), w)).squaredNorm());
      best = std::min(best, (p - closestOnTriangle(p, at(r, c), at(r + 1, c + 1), at(r + 1, c), w)).squaredNorm());
      return;
    }
    // The nearer child first, so that the other is more often beyond the best already found.
    double d[2];
    for (int k = 0; k < 2; ++k)
      d[k] = nodes_[node.children[k]].box.squaredExteriorDistance(p);
    const int first = d[1] < d[0] ? 1 : 0;
    for (int k : {first, 1 - first})
      if (d[k] < best)
        search(node.children[k], p, best);
  }

  const Eigen::Matrix3Xd& points_;
  int cols_, cell_rows_, cell_cols_, last_row_, last_col_;
  std::vector<Node> nodes_;
};

// The sum over the free particles of `from` of their squared distance to `to`'s surface.
double sumSquaredToSurface(const Grid& grid, const Eigen::Matrix3Xd& from, const Eigen::Matrix3Xd& to, int& count)
{
  const CellTree surface(grid.params(), to);
  double sum = 0.0;
  for (int p = 0; p < grid.numParticles(); ++p)
  {
    if (grid.isFixed(p) || grid.isHandle(p))
      continue;
    sum += surface.squaredDistance(from.col(p));
    ++count;
  }
  return sum;
}

}  // namespace

double surfaceDistance(const Grid& grid, const Eigen::Matrix3Xd& a, const Eigen::Matrix3Xd& b)
{
  int count = 0;
  const double sum = sumSquaredToSurface(grid, a, b, count) + sumSquaredToSurface(grid, b, a, count);
  return count ? std::sqrt(sum / count) : 0.0;
}

}  // namespace modal_mass_spring
