// Self-collision: the broad phase's cells, the pairs within the thickness and their correction
// (self_collision.h).
#include "modal_mass_spring/self_collision.h"

#include "modal_mass_spring/parameter_error.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

namespace modal_mass_spring
{
namespace
{

// The correction Coulomb friction with the bound `limit` makes to a tangential quantity t (as the
// colliders': cancel it where the bound covers it, else shorten it by the bound).
Eigen::Vector3d coulomb(const Eigen::Vector3d& t, double limit)
{
  const double squared = t.squaredNorm();
  if (squared <= limit * limit)
    return -t;
  return -limit / std::sqrt(squared) * t;
}

// The point of triangle (a, b, c) closest to p and its barycentric weights (Ericson, Real-Time
// Collision Detection, 5.1.5).
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

Cells sortIntoCells(const double* x, int count, double reach, std::vector<int>& cell_of, std::vector<int>& start,
                    std::vector<int>& sorted)
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
    int c[3];
    cells.cellOf(x + 3 * p, c);
    cell_of[p] = cells.index(c[0], c[1], c[2]);
    ++start[cell_of[p] + 1];
  }
  for (int c = 0; c < total; ++c)
    start[c + 1] += start[c];
  sorted.resize(count);
  std::vector<int> fill(start.begin(), start.end() - 1);
  for (int p = 0; p < count; ++p)
    sorted[fill[cell_of[p]]++] = p;
  cells.start = &start;
  cells.sorted = &sorted;
  return cells;
}

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

// More than two springs apart: the Chebyshev distance of the grid indices.
bool separatedIndices(int row_p, int col_p, int row_q, int col_q)
{
  return std::max(std::abs(row_p - row_q), std::abs(col_p - col_q)) > 2;
}

}  // namespace

void validateSelfCollision(const GridParams& grid, bool enabled, double thickness, double friction)
{
  if (!enabled)
    return;
  if (grid.dimension != 3)
    rejectParameter("self_collision", "true",
                    "needs a 3D grid (dimension: 3): a 2D grid lies in its plane and cannot fold over itself; use "
                    "self_collision: false with dimension: 2");
  if (!std::isfinite(thickness) || thickness <= 0.0 || thickness > grid.spacing)
    rejectParameter("self_collision_thickness", thickness,
                    "must be a finite number of metres > 0 and at most the grid's spacing (" +
                        std::to_string(grid.spacing) + " m): particles one spring apart are that far apart at rest");
  if (!std::isfinite(friction) || friction < 0.0)
    rejectParameter("self_friction", friction, "must be a finite Coulomb coefficient >= 0");
}

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

SelfCollision::SelfCollision(const Grid& grid, double thickness, double friction, SelfPrimitive primitive)
  : grid_(grid), thickness_(thickness), friction_(friction), primitive_(primitive)
{
  const int rows = grid.params().rows, cols = grid.params().cols;
  slot_of_.assign(grid.numParticles(), -1);
  for (int p = 0; p < grid.numParticles(); ++p)
    if (!grid.isFixed(p) && !grid.isHandle(p))
    {
      // The free dofs keep the particles' order, three each.
      slot_of_[p] = grid.freeIndex(3 * p) / 3;
      particle_of_.push_back(p);
      row_.push_back(p / cols);
      col_.push_back(p % cols);
    }
  anchor_.assign(particle_of_.size(), 0);
  for (size_t s = 0; s < particle_of_.size(); ++s)
  {
    const int r = row_[s], c = col_[s];
    if (r + 1 < rows && c + 1 < cols && slot_of_[grid.particleIndex(r, c + 1)] >= 0 &&
        slot_of_[grid.particleIndex(r + 1, c)] >= 0 && slot_of_[grid.particleIndex(r + 1, c + 1)] >= 0)
      anchor_[s] = 1;
  }
  // The free ends of the triangles' edges at each particle: the sides and the diagonal (r, c)-(r+1, c+1).
  fan_.assign(particle_of_.size(), {-1, -1, -1, -1, -1, -1});
  static constexpr int kEdges[6][2] = {{0, 1}, {0, -1}, {1, 0}, {-1, 0}, {1, 1}, {-1, -1}};
  for (size_t s = 0; s < particle_of_.size(); ++s)
    for (int e = 0; e < 6; ++e)
    {
      const int r = row_[s] + kEdges[e][0], c = col_[s] + kEdges[e][1];
      if (r >= 0 && c >= 0 && r < rows && c < cols)
        fan_[s][e] = slot_of_[grid.particleIndex(r, c)];
    }
}

SelfCollision::Geometry SelfCollision::geometry(const Pair& pair, const double* x, const double* x_start) const
{
  Geometry g;
  auto at = [](const double* v, int slot) { return Eigen::Map<const Eigen::Vector3d>(v + 3 * slot); };
  const Eigen::Vector3d p = at(x, pair.p);
  if (pair.c[1] < 0)
  {
    g.w[0] = 1.0, g.w[1] = g.w[2] = 0.0;
    Eigen::Vector3d d = p - at(x, pair.c[0]);
    g.gap = d.norm();
    if (g.gap < 1e-12 * thickness_)
      d = at(x_start, pair.p) - at(x_start, pair.c[0]);  // on top of each other: apart the way they came
    g.normal = d.norm() > 0.0 ? Eigen::Vector3d(d.normalized()) : Eigen::Vector3d::UnitZ();
    return g;
  }
  const Eigen::Vector3d a = at(x, pair.c[0]), b = at(x, pair.c[1]), c = at(x, pair.c[2]);
  const Eigen::Vector3d y = closestOnTriangle(p, a, b, c, g.w);
  const Eigen::Vector3d d = p - y;
  const double distance = d.norm();
  const bool inside = g.w[0] > 1e-9 && g.w[1] > 1e-9 && g.w[2] > 1e-9;
  if (!inside && distance > 1e-12 * thickness_)
  {
    g.normal = d / distance;
    g.gap = distance;
    return g;
  }
  // Over the face: the side the particle was on at the step's start, so that a particle the step
  // carried through the face is pushed back, not on through.
  Eigen::Vector3d n = (b - a).cross(c - a);
  if (!(n.norm() > 0.0))
    n = Eigen::Vector3d::UnitZ();
  n.normalize();
  const Eigen::Vector3d a0 = at(x_start, pair.c[0]), b0 = at(x_start, pair.c[1]), c0 = at(x_start, pair.c[2]);
  const double side = (at(x_start, pair.p) - (g.w[0] * a0 + g.w[1] * b0 + g.w[2] * c0)).dot((b0 - a0).cross(c0 - a0));
  g.normal = side < 0.0 ? Eigen::Vector3d(-n) : n;
  g.gap = d.dot(g.normal);
  return g;
}

void SelfCollision::listCandidates(const Eigen::VectorXd& x, const std::vector<int>& moved)
{
  const int count = static_cast<int>(particle_of_.size());
  const bool all = moved.empty();
  candidates_.resize(count);
  group_changed_.resize(count);
  is_moved_.assign(count, all ? 1 : 0);
  for (int p : moved)
    is_moved_[p] = 1;
  const int cols = grid_.params().cols;
  const double* xs = x.data();
  auto at = [xs](int slot) { return Eigen::Map<const Eigen::Vector3d>(xs + 3 * slot); };
  auto slotAt = [&](int row, int col) { return slot_of_[row * cols + col]; };
  const bool triangles = primitive_ == SelfPrimitive::Triangles;
  // The pairs with a moved particle go; they are listed anew below (moved to the end of their group,
  // [gone_from, gone_end), until those listed again have taken what was found of them).
  std::vector<int> gone_from(all ? 0 : count), gone_end(all ? 0 : count);
  for (int p = 0; p < count; ++p)
  {
    std::vector<Pair>& group = candidates_[p];
    group_changed_[p] = all;
    if (all)
    {
      group.clear();
      continue;
    }
    gone_end[p] = static_cast<int>(group.size());
    gone_from[p] = static_cast<int>(std::partition(group.begin(), group.end(),
                                                   [&](const Pair& pair) {
                                                     return !(is_moved_[pair.p] || is_moved_[pair.c[0]] ||
                                                              (pair.c[1] >= 0 && (is_moved_[pair.c[1]] ||
                                                                                  is_moved_[pair.c[2]])));
                                                   }) -
                                    group.begin());
    group_changed_[p] = gone_from[p] != gone_end[p];
  }
  const double listed = (1.0 + 2.0 * kSkin) * thickness_;
  // A triangle within `listed` of a particle has its first corner within `listed` plus its longest
  // edge. Around each cell, a sphere through its farthest corner from the corners' mean: a particle
  // farther than `listed` from it is that far from both triangles (the cheap test before the exact
  // one; at a listing of some particles, found for the cells it meets: a negative radius marks one
  // not found yet).
  double longest = 0.0;
  if (triangles)
  {
    cell_sphere_.assign(count, Eigen::Vector4d::Constant(-1.0));
    for (int s = 0; s < count; ++s)
      if (anchor_[s])
      {
        const int b = slotAt(row_[s], col_[s] + 1), c = slotAt(row_[s] + 1, col_[s]), d = slotAt(row_[s] + 1, col_[s] + 1);
        longest = std::max({longest, (at(b) - at(s)).squaredNorm(), (at(c) - at(s)).squaredNorm(),
                            (at(d) - at(s)).squaredNorm(), (at(d) - at(b)).squaredNorm(), (at(d) - at(c)).squaredNorm()});
      }
  }
  auto cellSphere = [&](int s) -> const Eigen::Vector4d& {
    Eigen::Vector4d& sphere = cell_sphere_[s];
    if (sphere[3] < 0.0)
    {
      const int b = slotAt(row_[s], col_[s] + 1), c = slotAt(row_[s] + 1, col_[s]), d = slotAt(row_[s] + 1, col_[s] + 1);
      const Eigen::Vector3d centre = 0.25 * (at(s) + at(b) + at(c) + at(d));
      const double radius = std::sqrt(std::max({(at(s) - centre).squaredNorm(), (at(b) - centre).squaredNorm(),
                                                (at(c) - centre).squaredNorm(), (at(d) - centre).squaredNorm()})) +
                            listed;
      sphere << centre, radius * radius;
    }
    return sphere;
  };
  if (triangles && all)
    for (int s = 0; s < count; ++s)
      if (anchor_[s])
        cellSphere(s);
  const double reach = listed + std::sqrt(longest);
  const double reach2 = reach * reach, listed2 = listed * listed;
  const Cells cells = sortIntoCells(xs, count, reach, cell_of_, cell_start_, sorted_);
  // Particle p against the cell anchored at q (both its triangles, or only those with a moved corner
  // when `moved_only`), when every corner of the cell is more than two springs from p and a triangle
  // is within `listed`.
  auto listTriangles = [&](int p, int q, bool moved_only) {
    const Eigen::Vector3d xp = at(p);
    const int rp = row_[p], cp = col_[p], rq = row_[q], cq = col_[q];
    const int dr = rp < rq ? rq - rp : std::max(0, rp - rq - 1);
    const int dc = cp < cq ? cq - cp : std::max(0, cp - cq - 1);
    if (std::max(dr, dc) <= 2)
      return;
    const Eigen::Vector4d& sphere = cellSphere(q);
    if ((sphere.head<3>() - xp).squaredNorm() >= sphere[3])
      return;
    const int b = slotAt(rq, cq + 1), c = slotAt(rq + 1, cq), d = slotAt(rq + 1, cq + 1);
    int half = 0;
    for (const auto& corners : {std::array<int, 3>{q, b, d}, std::array<int, 3>{q, d, c}})
    {
      double w[3];
      if (!moved_only || is_moved_[corners[0]] || is_moved_[corners[1]] || is_moved_[corners[2]])
      {
        const Eigen::Vector3d y = closestOnTriangle(xp, at(corners[0]), at(corners[1]), at(corners[2]), w);
        if ((xp - y).squaredNorm() < listed2)
        {
          candidates_[p].push_back(Pair{p, {corners[0], corners[1], corners[2]}, half, -1.0, 0.0, 0, Geometry{}});
          group_changed_[p] = 1;
        }
      }
      ++half;
    }
  };
  // The moved particles against everything (a particle pair in both particles' lists).
  for (int p = 0; p < count; ++p)
  {
    if (!is_moved_[p])
      continue;
    const Eigen::Vector3d xp = at(p);
    forNeighbours(cells, xs + 3 * p, [&](int q) {
      const double d2 = (at(q) - xp).squaredNorm();
      if (q == p || d2 >= reach2)
        return;
      if (d2 < listed2 && (q > p || !is_moved_[q]) && separatedIndices(row_[p], col_[p], row_[q], col_[q]))
      {
        candidates_[p].push_back(Pair{p, {q, -1, -1}, -1, -1.0, 0.0, 0, Geometry{}});
        candidates_[q].push_back(Pair{q, {p, -1, -1}, -1, -1.0, 0.0, 0, Geometry{}});
        group_changed_[p] = group_changed_[q] = 1;
      }
      if (triangles && anchor_[q])
        listTriangles(p, q, false);
    });
  }
  built_at_.resize(x.size());
  if (all)
  {
    built_at_ = x;
    return;
  }
  for (int p : moved)
    built_at_.segment<3>(3 * p) = at(p);
  // The triangles with a moved corner against the particles that have not moved.
  if (triangles)
  {
    is_anchor_listed_.assign(count, 0);
    for (int m : moved)
      for (int r = std::max(0, row_[m] - 1); r <= row_[m]; ++r)
        for (int c = std::max(0, col_[m] - 1); c <= col_[m]; ++c)
        {
          const int q = slotAt(r, c);
          if (q < 0 || !anchor_[q] || is_anchor_listed_[q])
            continue;
          is_anchor_listed_[q] = 1;
          forNeighbours(cells, xs + 3 * q, [&](int p) {
            if (!is_moved_[p] && (at(q) - at(p)).squaredNorm() < reach2)
              listTriangles(p, q, true);  // the other half kept its pairs
          });
        }
  }
  // A pair listed again takes what was found of it before (its margin, its kept closest point: they
  // hold for the pair whatever the listing), so that a listing does not send it to the narrow phase.
  for (int p = 0; p < count; ++p)
  {
    std::vector<Pair>& group = candidates_[p];
    const int gone = gone_end[p] - gone_from[p];
    if (gone == 0)
      continue;
    int found = 0;
    for (size_t k = gone_end[p]; k < group.size(); ++k)
      for (int j = gone_from[p]; j < gone_end[p]; ++j)
        if (group[j].c[0] == group[k].c[0] && group[j].c[1] == group[k].c[1] && group[j].half == group[k].half)
        {
          group[k] = group[j];
          ++found;
          break;
        }
    // The same pairs as before: the group is as it was looked at.
    group_changed_[p] = found != gone || static_cast<int>(group.size()) - gone_end[p] != gone;
    group.erase(group.begin() + gone_from[p], group.begin() + gone_end[p]);
  }
}

bool SelfCollision::edgeHeldByNeighbour(const std::vector<Pair>& group, const std::vector<Geometry>& geometry, int k,
                                        int opposite) const
{
  const Pair& pair = group[k];
  const int r = row_[pair.c[0]], c = col_[pair.c[0]];
  // The triangle across the edge opposite corner `opposite` (self_collision.h names the halves).
  static constexpr int kAcross[2][3][3] = {
      {{0, 1, 1}, {0, 0, 1}, {-1, 0, 1}},  // half 0: right edge, diagonal, top edge -> (row, col, half)
      {{1, 0, 0}, {0, -1, 0}, {0, 0, 0}},  // half 1: bottom edge, left edge, diagonal
  };
  const int* across = kAcross[pair.half][opposite];
  const int row = r + across[0], col = c + across[1], half = across[2];
  const GridParams& g = grid_.params();
  if (row < 0 || col < 0 || row >= g.rows || col >= g.cols)
    return false;
  const int anchor = slot_of_[row * g.cols + col];
  if (anchor < 0 || 2 * anchor + half > 2 * pair.c[0] + pair.half)
    return false;  // none there, or it leaves the point to this one
  const int a = pair.c[(opposite + 1) % 3], b = pair.c[(opposite + 2) % 3];
  for (size_t j = 0; j < group.size(); ++j)
  {
    const Pair& other = group[j];
    if (other.half != half || other.c[0] != anchor || !(geometry[j].gap < (1.0 + kReuse) * thickness_))
      continue;
    // Its closest point on the same edge: its weight on the corner off the edge is zero.
    for (int i = 0; i < 3; ++i)
      if (other.c[i] != a && other.c[i] != b)
        return geometry[j].w[i] == 0.0;
  }
  return false;
}

namespace
{

// A kept pair's gap at positions x: along its kept normal, with its kept weights.
template <typename KeptPair>
double keptGap(const KeptPair& pair, const double* x)
{
  Eigen::Vector3d r = Eigen::Map<const Eigen::Vector3d>(x + 3 * pair.p);
  for (int k = 0; k < 3 && pair.c[k] >= 0; ++k)
    r -= pair.kept_geometry.w[k] * Eigen::Map<const Eigen::Vector3d>(x + 3 * pair.c[k]);
  return r.dot(pair.kept_geometry.normal);
}

}  // namespace

bool SelfCollision::groupSettled(int p) const
{
  if (group_changed_[p])
    return false;
  const double reuse = kReuse * thickness_;
  for (const Pair& pair : candidates_[p])
    if (!(travelOf(pair) - pair.travel < (pair.kept ? reuse : pair.margin)))
      return false;
  return true;
}

void SelfCollision::lookAtGroup(int p, const double* xs, const double* starts)
{
  auto at = [xs](int slot) { return Eigen::Map<const Eigen::Vector3d>(xs + 3 * slot); };
  // Pairs within this of the thickness are kept (their closest points found below as within it); a
  // triangle pair kept keeps its closest point while its particles have travelled less than `reuse`.
  const double reach = (1.0 + kReuse) * thickness_, reuse = kReuse * thickness_;
  std::vector<Pair>& group = candidates_[p];
  const int size = static_cast<int>(group.size());
  group_geometry_.resize(size);
  // A pair whose particles have travelled less than its margin since it was last looked at is still
  // apart (a point's distance to a triangle changes by at most its own and the farthest corner's
  // displacements); a kept pair is looked at whenever its group is.
  auto apart = [&](Pair& pair) {
    const double travel = travelOf(pair);
    if (!pair.kept && travel - pair.travel < pair.margin)
      return true;
    pair.travel = travel;
    pair.kept = 0;
    return false;
  };
  // The particles within reach of p whose every triangle has its closest point to p at them (p is
  // in their corner's Voronoi region: Ericson 5.1.5's first test): the particle pair holds that
  // point, so their triangles are not looked at.
  int covered[8], covering = 0;
  const Eigen::Vector3d xp = at(p);
  for (int k = 0; k < size; ++k)
  {
    Pair& pair = group[k];
    group_geometry_[k].gap = std::numeric_limits<double>::infinity();
    if (pair.c[1] >= 0 || apart(pair))
      continue;
    const int q = pair.c[0];
    const Eigen::Vector3d d = xp - at(q);
    pair.margin = d.norm() - thickness_;
    if (!(d.squaredNorm() < reach * reach))
      continue;
    bool corner = true;
    for (int e = 0; e < 6 && corner; ++e)
      corner = fan_[q][e] < 0 || d.dot(at(fan_[q][e]) - at(q)) <= 0.0;
    if (corner && covering < 8)
      covered[covering++] = q;
    // The pair is p's when p comes first (it is in q's list too).
    pair.kept = p < q ? 1 : 2;
    if (p < q)
    {
      pair.kept_geometry = geometry(pair, xs, starts);
      if (pair.kept_geometry.gap < thickness_)
        touches_.push_back(Touch{pair, pair.kept_geometry, {}, 0.0, Eigen::Vector3d::Zero()});
    }
  }
  for (int k = 0; k < size; ++k)
  {
    Pair& pair = group[k];
    if (pair.c[1] < 0)
      continue;
    if (std::any_of(covered, covered + covering,
                    [&](int q) { return pair.c[0] == q || pair.c[1] == q || pair.c[2] == q; }))
    {
      pair.travel = travelOf(pair);
      pair.kept = 3;
      continue;
    }
    if ((pair.kept == 1 || pair.kept == 2) && travelOf(pair) - pair.travel < reuse)
    {
      group_geometry_[k] = pair.kept_geometry;
      group_geometry_[k].gap = keptGap(pair, xs);
      continue;
    }
    if (apart(pair))
      continue;
    group_geometry_[k] = geometry(pair, xs, starts);
    pair.margin = group_geometry_[k].gap - thickness_;
  }
  for (int k = 0; k < size; ++k)
  {
    const Geometry& g = group_geometry_[k];
    if (!(g.gap < reach))
      continue;
    // A corner is held by the particle pair with it (listed: it is as close), an edge by the
    // triangle across it when that one finds the same point.
    const int zeros = (g.w[0] == 0.0) + (g.w[1] == 0.0) + (g.w[2] == 0.0);
    const bool held = zeros == 2 || (zeros == 1 && edgeHeldByNeighbour(group, group_geometry_, k,
                                                                         g.w[0] == 0.0 ? 0 : g.w[1] == 0.0 ? 1 : 2));
    const bool reused = group[k].kept != 0;  // a pair looked at anew was marked not kept
    group[k].kept = held ? 2 : 1;
    group[k].kept_geometry = g;
    if (!held && g.gap < thickness_)
    {
      touches_.push_back(Touch{group[k], g, {}, 0.0, Eigen::Vector3d::Zero()});
      report_.reused += reused;
    }
  }
}

void SelfCollision::findTouches(const Eigen::VectorXd& x_start, const Eigen::VectorXd& x)
{
  touches_.clear();
  const double* xs = x.data();
  const int count = static_cast<int>(candidates_.size());
  for (int p = 0; p < count; ++p)
  {
    if (!groupSettled(p))
    {
      lookAtGroup(p, xs, x_start.data());
      group_changed_[p] = 0;
      continue;
    }
    // Every pair as it was: the kept ones' gaps along their kept normals, with their kept weights.
    for (const Pair& pair : candidates_[p])
    {
      if (pair.kept != 1)
        continue;
      Geometry g = pair.kept_geometry;
      g.gap = keptGap(pair, xs);
      if (g.gap < thickness_)
      {
        touches_.push_back(Touch{pair, g, {}, 0.0, Eigen::Vector3d::Zero()});
        ++report_.reused;
      }
    }
  }
}

void SelfCollision::correct(const Eigen::VectorXd& x_start, Eigen::VectorXd& x, Eigen::VectorXd& v, double dt,
                            const Contact* contact)
{
  report_ = SelfCollisionReport{};
  report_.closest_before = report_.closest_after = thickness_;
  // A particle's pairs are listed anew once it has moved half the skin since they were (the bound:
  // docs/design.md, "Self-collision"); all of them when more than an eighth of the particles have
  // (the listing searches every particle's cells anyway), or at the first step. NaN lists anew.
  const int particles = static_cast<int>(particle_of_.size());
  const double moved2 = 0.25 * kSkin * kSkin * thickness_ * thickness_;
  moved_.clear();
  bool all = built_at_.size() != x.size();
  for (int p = 0; p < particles && !all; ++p)
  {
    const int i = 3 * p;
    const double dx = x[i] - built_at_[i], dy = x[i + 1] - built_at_[i + 1], dz = x[i + 2] - built_at_[i + 2];
    if (!(dx * dx + dy * dy + dz * dz <= moved2))
    {
      moved_.push_back(p);
      all = 8 * static_cast<int>(moved_.size()) > particles;
    }
  }
  if (all)
    moved_.clear();
  // Each particle's path length over the steps' end positions (the candidates' margins count it).
  if (last_x_.size() != x.size())
  {
    last_x_ = x;
    travel_.assign(particles, 0.0);
  }
  bool finite = true;
  for (int p = 0; p < particles; ++p)
  {
    travel_[p] += (x.segment<3>(3 * p) - last_x_.segment<3>(3 * p)).norm();
    last_x_.segment<3>(3 * p) = x.segment<3>(3 * p);
    finite = finite && std::isfinite(travel_[p]);
  }
  if (!finite)
  {
    // After positions that were not finite (a step that diverged, its state then put back): every
    // margin is forgotten with a listing anew.
    travel_.assign(particles, 0.0);
    surface_travel_.clear();
    all = true;
    moved_.clear();
  }
  report_.relisted = all ? particles : static_cast<int>(moved_.size());
  if (report_.relisted > 0)
    listCandidates(x, moved_);
  findTouches(x_start, x);
  if (touches_.empty())
    return;
  // The particles of the pairs that lie on a collider, and the surface's normal there: found anew
  // for a particle that has travelled the reuse fraction since it was last, and for every particle
  // once a collider has moved (or none is given).
  const int colliders = contact ? static_cast<int>(contact->colliders().size()) : 0;
  bool same_colliders = surface_travel_.size() == particle_of_.size() && surface_poses_.size() == static_cast<size_t>(colliders) &&
                        (contact != nullptr) == surface_contact_;
  for (int i = 0; i < colliders && same_colliders; ++i)
    same_colliders = surface_active_[i] == contact->active(i) && surface_poses_[i].matrix() == contact->pose(i).matrix();
  if (!same_colliders)
  {
    surface_normal_.assign(particle_of_.size(), Eigen::Vector3d::Zero());
    surface_travel_.assign(particle_of_.size(), std::numeric_limits<double>::quiet_NaN());
    surface_contact_ = contact != nullptr;
    surface_poses_.clear();
    surface_active_.clear();
    for (int i = 0; i < colliders; ++i)
    {
      surface_poses_.push_back(contact->pose(i));
      surface_active_.push_back(contact->active(i));
    }
  }
  const double reuse = kReuse * thickness_;
  for (const Touch& touch : touches_)
    for (int slot : {touch.pair.p, touch.pair.c[0], touch.pair.c[1], touch.pair.c[2]})
    {
      if (slot < 0 || travel_[slot] - surface_travel_[slot] < reuse)
        continue;
      surface_travel_[slot] = travel_[slot];
      surface_normal_[slot].setZero();
      const Eigen::Vector3d at = x.segment<3>(3 * slot);
      for (int i = 0; i < colliders; ++i)
      {
        Eigen::Vector3d normal;
        if (contact->active(i) &&
            signedDistance(contact->colliders()[i], contact->pose(i), at, normal) <= 1.001 * contact->thickness())
        {
          surface_normal_[slot] = normal;
          break;
        }
      }
    }
  report_.contacts = static_cast<int>(touches_.size());
  double* const xs = x.data();
  double* const vs = v.data();
  const double* const starts = x_start.data();
  auto ref = [](double* values, int slot) { return Eigen::Map<Eigen::Vector3d>(values + 3 * slot); };
  auto cref = [](const double* values, int slot) { return Eigen::Map<const Eigen::Vector3d>(values + 3 * slot); };
  auto relative = [&](const double* values, const Touch& t) {
    Eigen::Vector3d r = cref(values, t.pair.p);
    for (int k = 0; k < 3 && t.pair.c[k] >= 0; ++k)
      r -= t.g.w[k] * cref(values, t.pair.c[k]);
    return r;
  };
  // A particle's inverse mass in a pair pushing along its normal, relative to a free particle's: 0 on
  // a collider when the push is along the surface's normal (more than 60 degrees from the surface).
  for (Touch& t : touches_)
  {
    const int slots[4] = {t.pair.p, t.pair.c[0], t.pair.c[1], t.pair.c[2]};
    const double weights[4] = {1.0, t.g.w[0], t.g.w[1], t.g.w[2]};
    for (int k = 0; k < 4; ++k)
    {
      t.m[k] = slots[k] >= 0 && std::abs(surface_normal_[slots[k]].dot(t.g.normal)) <= 0.5 ? 1.0 : 0.0;
      t.sum += slots[k] >= 0 ? weights[k] * weights[k] * t.m[k] : 0.0;
    }
    t.start = relative(starts, t);
    report_.closest_before = std::min(report_.closest_before, t.g.gap);
  }
  // Moves p by delta / (1 + sum w^2) and the corners against it by their weights (each times its
  // inverse mass): the pair's relative displacement changes by delta and, between free particles, its
  // momentum not at all.
  auto apply = [&](double* values, const Touch& t, const Eigen::Vector3d& delta) {
    const Eigen::Vector3d share = delta / t.sum;
    ref(values, t.pair.p) += t.m[0] * share;
    for (int k = 0; k < 3 && t.pair.c[k] >= 0; ++k)
      ref(values, t.pair.c[k]) -= t.m[k + 1] * t.g.w[k] * share;
  };
  const int count = static_cast<int>(touches_.size());
  touched_.assign(count, 0);
  // The sweeps end after one that moved nothing by more than this (m, and m over the step for
  // velocities): what it leaves is smaller still, and the next step pushes out what is left.
  const double settled = 1e-3 * thickness_;
  // After the first sweep, a pair is swept again only when a push of more than that moved one of its
  // particles in the last sweep or this one: the rule that ends the sweeps, pair by pair.
  const double stir = settled;
  auto stirred = [&](const Touch& t, int sweep) {
    for (int slot : {t.pair.p, t.pair.c[0], t.pair.c[1], t.pair.c[2]})
      if (slot >= 0 && stirred_[slot] >= sweep - 1)
        return true;
    return false;
  };
  auto stirring = [&](const Touch& t, int sweep) {
    for (int slot : {t.pair.p, t.pair.c[0], t.pair.c[1], t.pair.c[2]})
      if (slot >= 0)
        stirred_[slot] = sweep;
  };
  stirred_.assign(particle_of_.size(), -1);
  for (int sweep = 0; sweep < kSweeps; ++sweep)
  {
    ++report_.position_sweeps;
    double largest = 0.0;
    report_.closest_after = thickness_;
    for (int k = 0; k < count; ++k)
    {
      const Touch& t = touches_[k];
      if (sweep > 0 && !stirred(t, sweep))
        continue;
      // The gap along the pair's normal at the step's end: it moves by micrometres over the sweeps.
      const Eigen::Vector3d r = relative(xs, t);
      const double gap = r.dot(t.g.normal);
      if (gap >= thickness_ || t.sum <= 0.0)  // apart, or every particle of the pair held by a collider
      {
        report_.closest_after = std::min(report_.closest_after, gap);
        continue;
      }
      touched_[k] = 1;
      // Positions: push apart to the thickness, Coulomb on the pair's relative slip over the step with
      // the push as the normal bound (as the colliders).
      const double push = thickness_ - gap;
      largest = std::max(largest, push);
      const Eigen::Vector3d slip = r - t.start;
      apply(xs, t, push * t.g.normal + coulomb(slip - slip.dot(t.g.normal) * t.g.normal, friction_ * push));
      if (push > stir)
        stirring(t, sweep);
    }
    if (largest <= settled)
      break;
  }
  stirred_.assign(particle_of_.size(), -1);
  for (int sweep = 0; sweep < kSweeps; ++sweep)
  {
    ++report_.velocity_sweeps;
    double largest = 0.0;
    for (int k = 0; k < count; ++k)
    {
      if (!touched_[k])
        continue;
      const Touch& t = touches_[k];
      if (sweep > 0 && !stirred(t, sweep))
        continue;
      // Velocities: remove the approach, Coulomb on the relative tangential velocity.
      const Eigen::Vector3d velocity = relative(vs, t);
      const double approach = -velocity.dot(t.g.normal);
      if (approach <= 0.0)
        continue;
      largest = std::max(largest, approach);
      const Eigen::Vector3d tangential = velocity + approach * t.g.normal;
      apply(vs, t, approach * t.g.normal + coulomb(tangential, friction_ * approach));
      if (approach * dt > stir)
        stirring(t, sweep);
    }
    if (largest * dt <= settled)
      break;
  }
}

}  // namespace modal_mass_spring
