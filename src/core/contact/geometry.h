// The geometric pieces the colliders and self-collision share (internal): Coulomb's correction of a
// tangential quantity, the closest point on a triangle, and points sorted into cells (the broad phase).
#pragma once

#include <Eigen/Core>

#include <algorithm>
#include <cmath>
#include <vector>

namespace modal_mass_spring
{

// The correction that Coulomb friction with the bound `limit` (>= 0) makes to a tangential quantity
// t: cancel it where the bound covers it (stick), else shorten it by the bound (slip). Compared
// squared: a resting particle sticks, and needs no square root.
inline Eigen::Vector3d coulomb(const Eigen::Vector3d& t, double limit)
{
  const double squared = t.squaredNorm();
  if (squared <= limit * limit)
    return -t;
  return -limit / std::sqrt(squared) * t;
}

// Point i of packed 3D points x (three doubles a point).
inline Eigen::Map<const Eigen::Vector3d> pointAt(const double* x, int i)
{
  return Eigen::Map<const Eigen::Vector3d>(x + 3 * i);
}

// The point of triangle (a, b, c) closest to p and its barycentric weights w (Ericson, Real-Time
// Collision Detection, 5.1.5).
Eigen::Vector3d closestOnTriangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                                  const Eigen::Vector3d& c, double w[3]);

// Points sorted into a uniform grid of cubic cells at least `reach` wide over their bounding box
// (wider when that would make more than a few cells per point), by a counting sort.
struct Cells
{
  Eigen::Vector3d origin;
  double size = 0.0;
  int dims[3] = {1, 1, 1};
  std::vector<int>* start = nullptr;   // cell c holds sorted[start[c] .. start[c + 1])
  std::vector<int>* sorted = nullptr;

  void cellOf(const double* point, int out[3]) const
  {
    for (int a = 0; a < 3; ++a)
      out[a] = std::min(dims[a] - 1, std::max(0, static_cast<int>((point[a] - origin[a]) / size)));
  }
  int index(int i, int j, int k) const { return i + dims[0] * (j + dims[1] * k); }
};

// Sorts the `count` points x (3 each) into cells at least `reach` wide; cell_of, start and sorted
// are the caller's storage (kept between calls, no allocation once grown), which the cells point to.
// With `only`, only the points it marks are filed, in the cells that all the points would have (so
// that they are visited in the same order as when all are filed).
Cells sortIntoCells(const double* x, int count, double reach, std::vector<int>& cell_of, std::vector<int>& start,
                    std::vector<int>& sorted, const std::vector<char>* only = nullptr);

// Calls visit(q) for every point in the 27 cells around `point`.
template <typename Visit>
void forNeighbours(const Cells& cells, const double* point, Visit&& visit)
{
  int c[3];
  cells.cellOf(point, c);
  const std::vector<int>& start = *cells.start;
  const std::vector<int>& sorted = *cells.sorted;
  for (int k = std::max(0, c[2] - 1); k <= std::min(cells.dims[2] - 1, c[2] + 1); ++k)
    for (int j = std::max(0, c[1] - 1); j <= std::min(cells.dims[1] - 1, c[1] + 1); ++j)
    {
      const int i0 = std::max(0, c[0] - 1), i1 = std::min(cells.dims[0] - 1, c[0] + 1);
      // Cells along x are consecutive: one range.
      for (int s = start[cells.index(i0, j, k)]; s < start[cells.index(i1, j, k) + 1]; ++s)
        visit(sorted[s]);
    }
}

}  // namespace modal_mass_spring
