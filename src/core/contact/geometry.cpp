// The geometric pieces the colliders and self-collision share (geometry.h).
#include "contact/geometry.h"

#include <cmath>
#include <limits>

namespace modal_mass_spring
{

Eigen::Vector3d closestOnTriangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                                  const Eigen::Vector3d& c, double w[3])
{
  const Eigen::Vector3d ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0.0 && d2 <= 0.0)
  {
    w[0] = 1.0, w[1] = w[2] = 0.0;
    return a;
  }
  const Eigen::Vector3d bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0.0 && d4 <= d3)
  {
    w[1] = 1.0, w[0] = w[2] = 0.0;
    return b;
  }
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0)
  {
    const double t = d1 / (d1 - d3);
    w[0] = 1.0 - t, w[1] = t, w[2] = 0.0;
    return a + t * ab;
  }
  const Eigen::Vector3d cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0.0 && d5 <= d6)
  {
    w[2] = 1.0, w[0] = w[1] = 0.0;
    return c;
  }
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0)
  {
    const double t = d2 / (d2 - d6);
    w[0] = 1.0 - t, w[2] = t, w[1] = 0.0;
    return a + t * ac;
  }
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0)
  {
    const double t = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    w[1] = 1.0 - t, w[2] = t, w[0] = 0.0;
    return b + t * (c - b);
  }
  const double denominator = 1.0 / (va + vb + vc);
  const double v = vb * denominator, u = vc * denominator;
  w[0] = 1.0 - v - u, w[1] = v, w[2] = u;
  return a + v * ab + u * ac;
}

Cells sortIntoCells(const double* x, int count, double reach, std::vector<int>& cell_of, std::vector<int>& start,
                    std::vector<int>& sorted, const std::vector<char>* only)
{
  Cells cells;
  Eigen::Vector3d low = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity()), high = -low;
  for (int p = 0; p < count; ++p)
  {
    const Eigen::Map<const Eigen::Vector3d> at(x + 3 * p);
    low = low.cwiseMin(at);
    high = high.cwiseMax(at);
  }
  if (count == 0)
    low = high = Eigen::Vector3d::Zero();
  cells.origin = low;
  cells.size = reach;
  const double limit = 4.0 * count + 64.0;  // cells
  for (;;)
  {
    double total = 1.0;
    for (int a = 0; a < 3; ++a)
    {
      cells.dims[a] = static_cast<int>(std::floor((high[a] - low[a]) / cells.size)) + 1;
      total *= cells.dims[a];
    }
    if (total <= limit)
      break;
    cells.size *= std::max(1.01, std::cbrt(total / limit));
  }
  const int total = cells.dims[0] * cells.dims[1] * cells.dims[2];
  cell_of.resize(count);
  start.assign(total + 1, 0);
  for (int p = 0; p < count; ++p)
  {
    if (only && !(*only)[p])
    {
      cell_of[p] = -1;
      continue;
    }
    int c[3];
    cells.cellOf(x + 3 * p, c);
    cell_of[p] = cells.index(c[0], c[1], c[2]);
    ++start[cell_of[p] + 1];
  }
  for (int c = 0; c < total; ++c)
    start[c + 1] += start[c];
  sorted.resize(start[total]);
  std::vector<int> fill(start.begin(), start.end() - 1);
  for (int p = 0; p < count; ++p)
    if (cell_of[p] >= 0)
      sorted[fill[cell_of[p]]++] = p;
  cells.start = &start;
  cells.sorted = &sorted;
  return cells;
}

}  // namespace modal_mass_spring
