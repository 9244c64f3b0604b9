// Self-collision's broad phase: the particles more than two springs apart, and the candidate pairs
// within the thickness plus the skin, listed anew for the particles that moved (self_collision.h).
#include "modal_mass_spring/self_collision.h"

#include "contact/geometry.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

namespace modal_mass_spring
{
namespace
{

// More than two springs apart: the Chebyshev distance of the grid indices.
bool separatedIndices(int row_p, int col_p, int row_q, int col_q)
{
  return std::max(std::abs(row_p - row_q), std::abs(col_p - col_q)) > 2;
}

// Every corner of the cell anchored at (row_q, col_q) more than two springs from (row_p, col_p):
// checked before listTriangles, which most neighbours in a flat cloth fail (inline, it is cheaper
// than the call).
bool cellSeparated(int row_p, int col_p, int row_q, int col_q)
{
  const int dr = row_p < row_q ? row_q - row_p : std::max(0, row_p - row_q - 1);
  const int dc = col_p < col_q ? col_q - col_p : std::max(0, col_p - col_q - 1);
  return std::max(dr, dc) > 2;
}

}  // namespace

bool selfSeparated(const Grid& grid, int p, int q)
{
  const int cols = grid.params().cols;
  return separatedIndices(p / cols, p % cols, q / cols, q % cols);
}

double closestSeparatedDistance(const Grid& grid, const Eigen::VectorXd& positions, double cutoff)
{
  const int count = grid.numParticles();
  std::vector<int> cell_of, start, sorted;
  const Cells cells = sortIntoCells(positions.data(), count, cutoff, cell_of, start, sorted);
  double closest = std::numeric_limits<double>::infinity();
  for (int p = 0; p < count; ++p)
  {
    const Eigen::Map<const Eigen::Vector3d> at(positions.data() + 3 * p);
    forNeighbours(cells, positions.data() + 3 * p, [&](int q) {
      if (q <= p || !selfSeparated(grid, p, q))
        return;
      const double d = (Eigen::Map<const Eigen::Vector3d>(positions.data() + 3 * q) - at).norm();
      if (d < cutoff)
        closest = std::min(closest, d);
    });
  }
  return closest;
}

void SelfCollision::listCandidates(const Eigen::VectorXd& x, const std::vector<int>& moved)
{
  const int count = static_cast<int>(particle_of_.size());
  const bool all = moved.empty();
  candidates_.resize(count);
  group_changed_.resize(count);
  group_bound_.resize(count);
  group_summary_.resize(count);
  is_moved_.assign(count, all ? 1 : 0);
  for (int p : moved)
    is_moved_[p] = 1;
  const double* xs = x.data();
  const bool triangles = primitive_ == SelfPrimitive::Triangles;
  // The pairs with a moved particle go; they are listed anew below (moved to the end of their group,
  // [gone_from, gone_end), until those listed again have taken what was found of them).
  named_by_.resize(count);
  gone_from_.resize(count);
  gone_end_.resize(count);
  dropMovedPairs(all, moved);
  const double listed = (1.0 + 2.0 * kSkin) * thickness_;
  // A triangle within `listed` of a particle has its first corner within `listed` plus its longest
  // edge (cellSphere: the cheap test before the exact one). At a listing of some particles, a bound
  // on it instead of a pass over every cell: the longest edge between the positions the particles
  // were listed at (those moved now are listed where they are), plus half the skin at each end.
  double longest = 0.0;
  if (!all)
    for (int p : moved)
      built_at_.segment<3>(3 * p) = pointAt(xs, p);
  if (triangles)
  {
    cell_sphere_.assign(count, Eigen::Vector4d::Constant(-1.0));
    if (all)
      longest = longest_listed_ = std::sqrt(longestCellEdge(xs));
    else
    {
      for (int m : moved)
        for (int q : fan_[m])
          if (q >= 0)
            longest_listed_ = std::max(longest_listed_, (pointAt(built_at_.data(), m) - pointAt(built_at_.data(), q)).norm());
      longest = longest_listed_ + kSkin * thickness_;
    }
  }
  if (triangles && all)
    for (int s = 0; s < count; ++s)
      if (anchor_[s])
        cellSphere(s, xs, listed);
  const double reach = listed + longest;
  if (!all)
    markNearMoved(moved, xs, reach);
  const Cells cells = sortIntoCells(xs, count, reach, cell_of_, cell_start_, sorted_, all ? nullptr : &is_near_moved_);
  naming_ = !all;  // a full listing names them all at the end
  listAroundMoved(cells, xs, reach, listed);
  built_at_.resize(x.size());
  if (all)
  {
    built_at_ = x;
    nameAll();
    return;
  }
  if (triangles)
    listMovedTriangles(moved, cells, xs, reach, listed);
  takeBackFound();
}

void SelfCollision::markNearMoved(const std::vector<int>& moved, const double* xs, double reach)
{
  Eigen::Vector3d low = pointAt(xs, moved.front()), high = low;
  for (int m : moved)
  {
    low = low.cwiseMin(pointAt(xs, m));
    high = high.cwiseMax(pointAt(xs, m));
  }
  low.array() -= reach;
  high.array() += reach;
  const int count = static_cast<int>(candidates_.size());
  is_near_moved_.resize(count);
  for (int p = 0; p < count; ++p)
  {
    const double* at = xs + 3 * p;
    is_near_moved_[p] = at[0] >= low[0] && at[0] <= high[0] && at[1] >= low[1] && at[1] <= high[1] &&
                        at[2] >= low[2] && at[2] <= high[2];
  }
}

void SelfCollision::dropMovedPairs(bool all, const std::vector<int>& moved)
{
  const int count = static_cast<int>(candidates_.size());
  dropped_from_.clear();
  if (all)
  {
    for (int p = 0; p < count; ++p)
    {
      candidates_[p].clear();
      group_changed_[p] = 1;
      group_summary_[p].found = false;
    }
    return;
  }
  // The groups with a pair naming a moved particle: its own, and those named_by_ it.
  for (int m : moved)
  {
    dropped_from_.push_back(m);
    dropped_from_.insert(dropped_from_.end(), named_by_[m].begin(), named_by_[m].end());
    named_by_[m].clear();  // every pair naming it goes
  }
  std::sort(dropped_from_.begin(), dropped_from_.end());
  dropped_from_.erase(std::unique(dropped_from_.begin(), dropped_from_.end()), dropped_from_.end());
  for (int p : dropped_from_)
  {
    std::vector<Pair>& group = candidates_[p];
    group_summary_[p].found = false;  // its pairs are reordered
    gone_end_[p] = static_cast<int>(group.size());
    gone_from_[p] = static_cast<int>(std::partition(group.begin(), group.end(),
                                                    [&](const Pair& pair) {
                                                      return !(is_moved_[pair.p] || is_moved_[pair.c[0]] ||
                                                               (pair.c[1] >= 0 && (is_moved_[pair.c[1]] ||
                                                                                   is_moved_[pair.c[2]])));
                                                    }) -
                                     group.begin());
    group_changed_[p] = gone_from_[p] != gone_end_[p];
  }
}

void SelfCollision::addPair(const Pair& pair)
{
  candidates_[pair.p].push_back(pair);
  group_changed_[pair.p] = 1;
  group_summary_[pair.p].found = false;
  for (int k = 0; k < 3 && pair.c[k] >= 0; ++k)
  {
    std::vector<int>& named = named_by_[pair.c[k]];
    if (std::find(named.begin(), named.end(), pair.p) == named.end())
      named.push_back(pair.p);
  }
}

void SelfCollision::nameAll()
{
  const int count = static_cast<int>(candidates_.size());
  for (std::vector<int>& named : named_by_)
    named.clear();
  std::vector<int> last(count, -1);  // the last group that named each particle
  for (int p = 0; p < count; ++p)
    for (const Pair& pair : candidates_[p])
      for (int k = 0; k < 3 && pair.c[k] >= 0; ++k)
        if (last[pair.c[k]] != p)
        {
          last[pair.c[k]] = p;
          named_by_[pair.c[k]].push_back(p);
        }
}

double SelfCollision::longestCellEdge(const double* xs) const
{
  double longest = 0.0;
  for (size_t s = 0; s < anchor_.size(); ++s)
    if (anchor_[s])
    {
      const int b = slotAt(row_[s], col_[s] + 1), c = slotAt(row_[s] + 1, col_[s]), d = slotAt(row_[s] + 1, col_[s] + 1);
      const int a = static_cast<int>(s);
      longest = std::max({longest, (pointAt(xs, b) - pointAt(xs, a)).squaredNorm(), (pointAt(xs, c) - pointAt(xs, a)).squaredNorm(),
                          (pointAt(xs, d) - pointAt(xs, a)).squaredNorm(), (pointAt(xs, d) - pointAt(xs, b)).squaredNorm(),
                          (pointAt(xs, d) - pointAt(xs, c)).squaredNorm()});
    }
  return longest;
}

const Eigen::Vector4d& SelfCollision::cellSphere(int s, const double* xs, double listed)
{
  // Around the cell, a sphere through its farthest corner from the corners' mean: a particle farther
  // than `listed` from it is that far from both triangles. At a listing of some particles, found for
  // the cells it meets: a negative radius marks one not found yet.
  Eigen::Vector4d& sphere = cell_sphere_[s];
  if (sphere[3] < 0.0)
  {
    const int b = slotAt(row_[s], col_[s] + 1), c = slotAt(row_[s] + 1, col_[s]), d = slotAt(row_[s] + 1, col_[s] + 1);
    const Eigen::Vector3d centre = 0.25 * (pointAt(xs, s) + pointAt(xs, b) + pointAt(xs, c) + pointAt(xs, d));
    const double radius = std::sqrt(std::max({(pointAt(xs, s) - centre).squaredNorm(), (pointAt(xs, b) - centre).squaredNorm(),
                                              (pointAt(xs, c) - centre).squaredNorm(), (pointAt(xs, d) - centre).squaredNorm()})) +
                          listed;
    sphere << centre, radius * radius;
  }
  return sphere;
}

void SelfCollision::listTriangles(int p, int q, bool moved_only, const double* xs, double listed)
{
  const double listed2 = listed * listed;
  const Eigen::Vector3d xp = pointAt(xs, p);
  const int rq = row_[q], cq = col_[q];
  const Eigen::Vector4d& sphere = cellSphere(q, xs, listed);
  if ((sphere.head<3>() - xp).squaredNorm() >= sphere[3])
    return;
  const int b = slotAt(rq, cq + 1), c = slotAt(rq + 1, cq), d = slotAt(rq + 1, cq + 1);
  int half = 0;
  for (const auto& corners : {std::array<int, 3>{q, b, d}, std::array<int, 3>{q, d, c}})
  {
    double w[3];
    if (!moved_only || is_moved_[corners[0]] || is_moved_[corners[1]] || is_moved_[corners[2]])
    {
      const Eigen::Vector3d y = closestOnTriangle(xp, pointAt(xs, corners[0]), pointAt(xs, corners[1]), pointAt(xs, corners[2]), w);
      if ((xp - y).squaredNorm() < listed2)
      {
        const Pair pair(p, corners[0], corners[1], corners[2], half);
        if (naming_)
          addPair(pair);
        else
          candidates_[p].push_back(pair);
      }
    }
    ++half;
  }
}

void SelfCollision::listAroundMoved(const Cells& cells, const double* xs, double reach, double listed)
{
  const int count = static_cast<int>(candidates_.size());
  const bool triangles = primitive_ == SelfPrimitive::Triangles;
  const double reach2 = reach * reach, listed2 = listed * listed;
  for (int p = 0; p < count; ++p)
  {
    if (!is_moved_[p])
      continue;
    const Eigen::Vector3d xp = pointAt(xs, p);
    forNeighbours(cells, xs + 3 * p, [&](int q) {
      const double d2 = (pointAt(xs, q) - xp).squaredNorm();
      if (q == p || d2 >= reach2)
        return;
      if (d2 < listed2 && (q > p || !is_moved_[q]) && separatedIndices(row_[p], col_[p], row_[q], col_[q]))
      {
        const Pair pq(p, q, -1, -1, -1), qp(q, p, -1, -1, -1);
        if (naming_)
          addPair(pq), addPair(qp);
        else
          candidates_[p].push_back(pq), candidates_[q].push_back(qp);
      }
      if (triangles && anchor_[q] && cellSeparated(row_[p], col_[p], row_[q], col_[q]))
        listTriangles(p, q, false, xs, listed);
    });
  }
}

void SelfCollision::listMovedTriangles(const std::vector<int>& moved, const Cells& cells, const double* xs, double reach,
                                       double listed)
{
  const double reach2 = reach * reach;
  is_anchor_listed_.assign(candidates_.size(), 0);
  for (int m : moved)
  {
    // The cells at m not listed yet (a cell at several moved particles is listed once), against the
    // particles that have not moved within reach of m: every point of a triangle at m is within its
    // longest edge of m, so one search around m finds them for its cells.
    int anchors[4], cells_at_m = 0;
    for (int r = std::max(0, row_[m] - 1); r <= row_[m]; ++r)
      for (int c = std::max(0, col_[m] - 1); c <= col_[m]; ++c)
      {
        const int q = slotAt(r, c);
        if (q < 0 || !anchor_[q] || is_anchor_listed_[q])
          continue;
        is_anchor_listed_[q] = 1;
        anchors[cells_at_m++] = q;
      }
    if (cells_at_m == 0)
      continue;
    const Eigen::Vector3d xm = pointAt(xs, m);
    forNeighbours(cells, xs + 3 * m, [&](int p) {
      if (is_moved_[p] || (pointAt(xs, p) - xm).squaredNorm() >= reach2)
        return;
      for (int k = 0; k < cells_at_m; ++k)
        if (cellSeparated(row_[p], col_[p], row_[anchors[k]], col_[anchors[k]]))
          listTriangles(p, anchors[k], true, xs, listed);  // the other half kept its pairs
    });
  }
}

void SelfCollision::takeBackFound()
{
  for (int p : dropped_from_)
  {
    std::vector<Pair>& group = candidates_[p];
    const int gone = gone_end_[p] - gone_from_[p];
    if (gone == 0)
      continue;
    int found = 0;
    for (size_t k = gone_end_[p]; k < group.size(); ++k)
      for (int j = gone_from_[p]; j < gone_end_[p]; ++j)
        if (group[j].c[0] == group[k].c[0] && group[j].c[1] == group[k].c[1] && group[j].half == group[k].half)
        {
          group[k] = group[j];
          ++found;
          break;
        }
    // The same pairs as before: the group is as it was looked at.
    group_changed_[p] = found != gone || static_cast<int>(group.size()) - gone_end_[p] != gone;
    group.erase(group.begin() + gone_from_[p], group.begin() + gone_end_[p]);
  }
}

}  // namespace modal_mass_spring
