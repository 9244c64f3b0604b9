// Self-collision: the pairs within the thickness and their correction (self_collision.h); the
// candidate pairs are listed in self_collision_candidates.cpp.
#include "modal_mass_spring/self_collision.h"

#include "modal_mass_spring/parameter_error.h"

#include "contact/geometry.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

namespace modal_mass_spring
{
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

SelfCollision::SelfCollision(const Grid& grid, double thickness, double friction, SelfPrimitive primitive, double lapse)
  : grid_(grid), thickness_(thickness), friction_(friction), primitive_(primitive), lapse_(lapse)
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
  const int block_cols = (cols + kBlock - 1) / kBlock;
  for (size_t s = 0; s < particle_of_.size(); ++s)
    block_.push_back(row_[s] / kBlock * block_cols + col_[s] / kBlock);
  block_travel_.assign(block_cols * ((rows + kBlock - 1) / kBlock), 0.0);
  block_step_ = block_travel_;
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

// Inline: the narrow phase and the sweeps call them for every touching pair (this file only).
template <typename Weight>
inline Eigen::Vector3d SelfCollision::relative(const double* values, int p, const int c[3], const Weight w[3])
{
  // Relative to corner 0 (w[0] = 1 - w[1] - w[2]): the weights' rounding then scales the cell's
  // size, not the positions' distance from the origin.
  const Eigen::Vector3d c0 = pointAt(values, c[0]);
  Eigen::Vector3d r = pointAt(values, p) - c0;
  if (c[1] >= 0)
    r -= w[1] * (pointAt(values, c[1]) - c0) + w[2] * (pointAt(values, c[2]) - c0);
  return r;
}

inline void SelfCollision::apply(double* values, const Touch& touch, const Eigen::Vector3d& delta)
{
  auto ref = [](double* v, int slot) { return Eigen::Map<Eigen::Vector3d>(v + 3 * slot); };
  const Eigen::Vector3d share = touch.scale * delta;
  if (touch.shares & 1)
    ref(values, touch.p) += share;
  for (int k = 0; k < 3 && touch.c[k] >= 0; ++k)
    if (touch.shares & (2 << k))
      ref(values, touch.c[k]) -= touch.w[k] * share;
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


double SelfCollision::blockTravel(const GroupBound& bound) const
{
  double travel = 0.0;
  for (int k = 0; k < 4 && bound.blocks[k] >= 0; ++k)
    travel += block_travel_[bound.blocks[k]];
  return travel;
}

void SelfCollision::findBlocks(int p)
{
  GroupBound& bound = group_bound_[p];
  std::fill(bound.blocks, bound.blocks + 4, -1);
  int blocks = 0;
  for (const Pair& pair : candidates_[p])
    for (int slot : {pair.p, pair.c[0], pair.c[1], pair.c[2]})
      if (slot >= 0 && std::find(bound.blocks, bound.blocks + blocks, block_[slot]) == bound.blocks + blocks)
      {
        if (blocks == 4)
        {
          bound.blocks[0] = -3;  // too many: no bound
          return;
        }
        bound.blocks[blocks++] = block_[slot];
      }
}

SelfCollision::GroupSummary& SelfCollision::summaryOf(int p)
{
  GroupSummary& summary = group_summary_[p];
  if (summary.found)
    return summary;
  const double reuse = kReuse * thickness_;
  const std::vector<Pair>& group = candidates_[p];
  summary.allowances.clear();
  for (const Pair& pair : group)
    summary.allowances.push_back(
        Allowance{{pair.c[0], pair.c[1], pair.c[2]}, pair.travel, pair.kept ? reuse : pair.margin});
  summary.found = true;
  return summary;
}

bool SelfCollision::groupSettled(int p)
{
  if (group_changed_[p])
    return false;
  GroupBound& bound = group_bound_[p];
  if (bound.slack >= 0.0 && blockTravel(bound) - bound.at < bound.slack)
    return true;
  double slack = std::numeric_limits<double>::infinity();
  for (const Allowance& pair : summaryOf(p).allowances)
  {
    const double left = pair.allowance - (travelOf(p, pair.c) - pair.travel);
    if (!(left > 0.0))
    {
      bound.slack = -1.0;
      return false;
    }
    slack = std::min(slack, left);
  }
  // Each of a pair's (at most four) particles travels no farther than its block. No bound when p's
  // own block went farther than it allows since the last narrow phase: it would not hold to the next
  // (a falling cloth's groups), and finding the blocks costs more than it saves.
  bound.slack = -1.0;
  if (0.25 * slack <= block_step_[block_[p]])
    return true;
  if (bound.blocks[0] == -2)
    findBlocks(p);
  bound.slack = bound.blocks[0] == -3 ? -1.0 : 0.25 * slack;
  bound.at = blockTravel(bound);
  return true;
}


bool SelfCollision::apart(Pair& pair) const
{
  const double travel = travelOf(pair);
  if (!pair.kept && travel - pair.travel < pair.margin)
    return true;
  pair.travel = travel;
  pair.kept = 0;
  return false;
}

void SelfCollision::lookAtGroup(int p, const double* xs, const double* starts)
{
  group_geometry_.resize(candidates_[p].size());
  // The particles within reach of p whose every triangle has its closest point to p at them (p is
  // in their corner's Voronoi region: Ericson 5.1.5's first test): the particle pair holds that
  // point, so their triangles are not looked at.
  int covered[8];
  const int covering = lookAtParticlePairs(p, xs, starts, covered);
  lookAtTrianglePairs(p, xs, starts, covered, covering);
  keepWithinReach(p, xs);
}

int SelfCollision::lookAtParticlePairs(int p, const double* xs, const double* starts, int covered[8])
{
  const double reach = (1.0 + kReuse) * thickness_;
  std::vector<Pair>& group = candidates_[p];
  const int size = static_cast<int>(group.size());
  int covering = 0;
  const Eigen::Vector3d xp = pointAt(xs, p);
  for (int k = 0; k < size; ++k)
  {
    Pair& pair = group[k];
    group_geometry_[k].gap = std::numeric_limits<double>::infinity();
    if (pair.c[1] >= 0 || apart(pair))
      continue;
    const int q = pair.c[0];
    const Eigen::Vector3d d = xp - pointAt(xs, q);
    pair.margin = d.norm() - thickness_;
    if (!(d.squaredNorm() < reach * reach))
      continue;
    bool corner = true;
    for (int e = 0; e < 6 && corner; ++e)
      corner = fan_[q][e] < 0 || d.dot(pointAt(xs, fan_[q][e]) - pointAt(xs, q)) <= 0.0;
    if (corner && covering < 8)
      covered[covering++] = q;
    // The pair is p's when p comes first (it is in q's list too).
    pair.kept = p < q ? 1 : 2;
    if (p < q)
    {
      pair.kept_geometry = geometry(pair, xs, starts);
      addTouch(pair, xs);
    }
  }
  return covering;
}

void SelfCollision::lookAtTrianglePairs(int p, const double* xs, const double* starts, const int covered[8],
                                        int covering)
{
  const double reuse = kReuse * thickness_;
  std::vector<Pair>& group = candidates_[p];
  const int size = static_cast<int>(group.size());
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
      group_geometry_[k].gap = relative(xs, pair).dot(pair.kept_geometry.normal);
      continue;
    }
    if (apart(pair))
      continue;
    group_geometry_[k] = geometry(pair, xs, starts);
    pair.margin = group_geometry_[k].gap - thickness_;
  }
}

void SelfCollision::keepWithinReach(int p, const double* xs)
{
  const double reach = (1.0 + kReuse) * thickness_;
  std::vector<Pair>& group = candidates_[p];
  const int size = static_cast<int>(group.size());
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
    if (!held)
    {
      addTouch(group[k], xs);
      report_.reused += reused && g.gap < thickness_;
    }
  }
}

void SelfCollision::findTouches(const Eigen::VectorXd& x_start, const Eigen::VectorXd& x)
{
  const double* xs = x.data();
  const int count = static_cast<int>(candidates_.size());
  looking_.resize(count);
  for (int p = 0; p < count; ++p)
    looking_[p] = !groupSettled(p);
  // A settled group's touches stay as they were found; the others' are found anew.
  touches_.erase(std::remove_if(touches_.begin(), touches_.end(), [&](const Touch& t) { return looking_[t.p]; }),
                 touches_.end());
  const std::ptrdiff_t kept = static_cast<std::ptrdiff_t>(touches_.size());
  for (int p = 0; p < count; ++p)
  {
    if (!looking_[p])
      continue;
    lookAtGroup(p, xs, x_start.data());
    group_summary_[p].found = false;
    summaryOf(p);  // while its pairs are at hand
    if (group_changed_[p])
      group_bound_[p].blocks[0] = -2;  // other pairs: their blocks are found again
    group_changed_[p] = 0;
    group_bound_[p].slack = -1.0;
  }
  // In the groups' order, as the sweeps gather and scatter the particles.
  std::inplace_merge(touches_.begin(), touches_.begin() + kept, touches_.end(),
                     [](const Touch& a, const Touch& b) { return a.p < b.p; });
}

void SelfCollision::measureTouches(const Eigen::VectorXd& x)
{
  swept_.clear();
  for (const Touch& t : touches_)
  {
    const double gap = relative(x.data(), t).dot(t.normalVector());
    if (!(gap < thickness_))
      continue;
    swept_.push_back(t);
    ++report_.contacts;
    report_.closest_before = std::min(report_.closest_before, gap);
    report_.reused += !looking_[t.p];
  }
}


void SelfCollision::correct(const Eigen::VectorXd& x_start, Eigen::VectorXd& x, Eigen::VectorXd& v, double dt,
                            const Contact* contact)
{
  report_ = SelfCollisionReport{};
  report_.closest_before = report_.closest_after = thickness_;
  // A moved collider weighs the touches swept now, and the others at the next narrow phase.
  const bool colliders_moved = checkSurfaces(contact);
  weights_stale_ = weights_stale_ || colliders_moved;
  if (!lookDue(x))
  {
    if (colliders_moved)
      for (Touch& touch : swept_)
        weigh(touch, x.data());
    report_.looked = false;
    sweep(x_start, x, v, dt);
    report_.reused = report_.contacts;
    return;
  }
  const int particles = static_cast<int>(particle_of_.size());
  bool all = findMoved(x);
  if (!addTravel(x))
  {
    // After positions that were not finite (a step that diverged, its state then put back): every
    // margin is forgotten with a listing anew.
    travel_.assign(particles, 0.0);
    surface_travel_.assign(particles, std::numeric_limits<double>::quiet_NaN());  // every surface found again
    all = true;
    moved_.clear();
  }
  report_.relisted = all ? particles : static_cast<int>(moved_.size());
  if (report_.relisted > 0)
    listCandidates(x, moved_);
  findTouches(x_start, x);
  if (weights_stale_)
    for (Touch& touch : touches_)
      weigh(touch, x.data());
  weights_stale_ = false;
  measureTouches(x);
  sweep(x_start, x, v, dt);
}

bool SelfCollision::lookDue(const Eigen::VectorXd& x) const
{
  // last_x_: where the narrow phase last ran; no listing yet (or a new thickness): due.
  if (!(lapse_ > 0.0) || last_x_.size() != x.size() || built_at_.size() != x.size())
    return true;
  const double limit2 = lapse_ * lapse_ * thickness_ * thickness_;
  for (Eigen::Index i = 0; i < x.size(); i += 3)
  {
    const double dx = x[i] - last_x_[i], dy = x[i + 1] - last_x_[i + 1], dz = x[i + 2] - last_x_[i + 2];
    if (!(dx * dx + dy * dy + dz * dz <= limit2))  // NaN too
      return true;
  }
  return false;
}

bool SelfCollision::findMoved(const Eigen::VectorXd& x)
{
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
  return all;
}

bool SelfCollision::addTravel(const Eigen::VectorXd& x)
{
  const int particles = static_cast<int>(particle_of_.size());
  if (last_x_.size() != x.size())
  {
    last_x_ = x;
    travel_.assign(particles, 0.0);
  }
  bool finite = true;
  std::fill(block_step_.begin(), block_step_.end(), 0.0);
  for (int p = 0; p < particles; ++p)
  {
    const double step = (x.segment<3>(3 * p) - last_x_.segment<3>(3 * p)).norm();
    travel_[p] += step;
    last_x_.segment<3>(3 * p) = x.segment<3>(3 * p);
    finite = finite && std::isfinite(travel_[p]);
    block_step_[block_[p]] = std::max(block_step_[block_[p]], step);
  }
  if (!finite)
    std::fill(block_travel_.begin(), block_travel_.end(), 0.0);
  else
    for (size_t b = 0; b < block_travel_.size(); ++b)
      block_travel_[b] += block_step_[b];
  return finite;
}

bool SelfCollision::checkSurfaces(const Contact* contact)
{
  contact_ = contact;
  const int colliders = contact ? static_cast<int>(contact->colliders().size()) : 0;
  bool same_colliders = surface_travel_.size() == particle_of_.size() && surface_poses_.size() == static_cast<size_t>(colliders) &&
                        (contact != nullptr) == surface_contact_;
  for (int i = 0; i < colliders && same_colliders; ++i)
    same_colliders = surface_active_[i] == contact->active(i) && surface_poses_[i].matrix() == contact->pose(i).matrix();
  if (same_colliders)
    return false;
  // The touches are weighed anew (correct).
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
  return true;
}

const Eigen::Vector3d& SelfCollision::surfaceOf(int slot, const double* x)
{
  Eigen::Vector3d& surface = surface_normal_[slot];
  if (travel_[slot] - surface_travel_[slot] < kReuse * thickness_)
    return surface;
  surface_travel_[slot] = travel_[slot];
  surface.setZero();
  const int colliders = contact_ ? static_cast<int>(contact_->colliders().size()) : 0;
  for (int i = 0; i < colliders; ++i)
  {
    Eigen::Vector3d normal;
    if (contact_->active(i) &&
        signedDistance(contact_->colliders()[i], contact_->pose(i), pointAt(x, slot), normal) <= 1.001 * contact_->thickness())
    {
      surface = normal;
      break;
    }
  }
  return surface;
}

void SelfCollision::weigh(Touch& touch, const double* x)
{
  const int slots[4] = {touch.p, touch.c[0], touch.c[1], touch.c[2]};
  const double weights[4] = {1.0, touch.w[0], touch.w[1], touch.w[2]};
  const Eigen::Vector3d normal = touch.normalVector();
  double sum = 0.0;
  touch.shares = 0;
  for (int k = 0; k < 4; ++k)
    if (slots[k] >= 0 && weights[k] > kLeastShare && std::abs(surfaceOf(slots[k], x).dot(normal)) <= 0.5)
    {
      touch.shares |= 1 << k;
      sum += weights[k] * weights[k];
    }
  touch.scale = sum > 0.0 ? static_cast<float>(1.0 / sum) : 0.0f;
}

inline void SelfCollision::addTouch(const Pair& pair, const double* x)
{
  const Geometry& g = pair.kept_geometry;
  Touch touch{pair.p,
              {pair.c[0], pair.c[1], pair.c[2]},
              {float(g.w[0]), float(g.w[1]), float(g.w[2])},
              {float(g.normal.x()), float(g.normal.y()), float(g.normal.z())},
              0.0f,
              0};
  weigh(touch, x);
  touches_.push_back(touch);
}

inline bool SelfCollision::stirred(const int* stirred, const Touch& touch, int sweep)
{
  return stirred[touch.p] >= sweep - 1 || stirred[touch.c[0]] >= sweep - 1 ||
         (touch.c[1] >= 0 && (stirred[touch.c[1]] >= sweep - 1 || stirred[touch.c[2]] >= sweep - 1));
}

inline void SelfCollision::stir(int* stirred, const Touch& touch, int sweep)
{
  stirred[touch.p] = stirred[touch.c[0]] = sweep;
  if (touch.c[1] >= 0)
    stirred[touch.c[1]] = stirred[touch.c[2]] = sweep;
}

inline double SelfCollision::pushVelocity(double* vs, const Touch& t, double friction)
{
  // Remove the approach, Coulomb on the relative tangential velocity.
  const Eigen::Vector3d n = t.normalVector();
  const Eigen::Vector3d velocity = relative(vs, t);
  const double approach = -velocity.dot(n);
  if (approach <= 0.0)
    return 0.0;
  const Eigen::Vector3d tangential = velocity + approach * n;
  apply(vs, t, approach * n + coulomb(tangential, friction * approach));
  return approach;
}

// The sweeps read the members they need into locals first: the pushes write through a double
// pointer, which the compiler must otherwise assume may change them, and reload them every pair.
// The first velocity sweep is folded into the first position sweep: a touch's velocities are pushed
// as soon as its position is (they do not depend on the positions), while the touch is at hand.
// The sweep is most of self-collision's cost on a cloth at rest, and fused multiply-adds take a sixth
// off it (docs/benchmarks.md, "Self-collision"): built for any x86-64, the package has GCC compile it
// twice and pick the version with them at load time, where the processor has them.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
__attribute__((target_clones("fma", "default")))
#endif
void SelfCollision::sweep(const Eigen::VectorXd& x_start, Eigen::VectorXd& x, Eigen::VectorXd& v, double dt)
{
  if (swept_.empty())
    return;
  double* const xs = x.data();
  double* const vs = v.data();
  const double* const starts = x_start.data();
  const Touch* const touches = swept_.data();
  const int count = static_cast<int>(swept_.size());
  touched_.assign(count, 0);
  char* const touched = touched_.data();
  stirred_.assign(particle_of_.size(), -1);
  velocity_stirred_.assign(particle_of_.size(), -1);
  int* const stirred_at = stirred_.data();
  int* const velocity_stirred_at = velocity_stirred_.data();
  const double thickness = thickness_, friction = friction_, settled = settledDistance();
  // Measured by the first sweep when the narrow phase did not run (measureTouches did when it did).
  const bool measure = !report_.looked;
  int contacts = 0;
  double closest_before = report_.closest_before, closest_after = thickness, fastest = 0.0;
  for (int sweep = 0; sweep < kSweeps; ++sweep)
  {
    ++report_.position_sweeps;
    double largest = 0.0;
    closest_after = thickness;
    for (int k = 0; k < count; ++k)
    {
      const Touch& t = touches[k];
      if (sweep > 0 && !stirred(stirred_at, t, sweep))
        continue;
      // The gap along the pair's normal at the step's end: it moves by micrometres over the sweeps.
      const Eigen::Vector3d n = t.normalVector();
      const Eigen::Vector3d r = relative(xs, t);
      const double gap = r.dot(n);
      if (sweep == 0 && measure && gap < thickness)
      {
        ++contacts;
        closest_before = std::min(closest_before, gap);
      }
      if (gap >= thickness || t.scale == 0.0f)  // apart, or every particle of the pair held by a collider
      {
        closest_after = std::min(closest_after, gap);
        continue;
      }
      // Positions: push apart to the thickness, Coulomb on the pair's relative slip over the step with
      // the push as the normal bound (as the colliders).
      const double push = thickness - gap;
      largest = std::max(largest, push);
      const Eigen::Vector3d slip = r - relative(starts, t);
      apply(xs, t, push * n + coulomb(slip - slip.dot(n) * n, friction * push));
      if (push > settled)
        stir(stirred_at, t, sweep);
      if (sweep > 0)
      {
        touched[k] = std::max<char>(touched[k], 1);  // its first velocity push still to come
        continue;
      }
      touched[k] = 2;
      const double approach = pushVelocity(vs, t, friction);
      fastest = std::max(fastest, approach);
      if (approach * dt > settled)
        stir(velocity_stirred_at, t, 0);
    }
    if (largest <= settled)
      break;
  }
  report_.contacts += contacts;
  report_.closest_before = closest_before;
  report_.closest_after = closest_after;
  sweepVelocities(v, dt, fastest);
}

void SelfCollision::sweepVelocities(Eigen::VectorXd& v, double dt, double fastest)
{
  double* const vs = v.data();
  const Touch* const touches = swept_.data();
  const char* const touched = touched_.data();
  const int count = static_cast<int>(swept_.size());
  int* const stirred_at = velocity_stirred_.data();
  const double friction = friction_, settled = settledDistance();
  for (int sweep = 0; sweep < kSweeps; ++sweep)
  {
    ++report_.velocity_sweeps;
    double largest = sweep == 0 ? fastest : 0.0;
    for (int k = 0; k < count; ++k)
    {
      // The first sweep: the touches a later position sweep touched first.
      if (touched[k] == 0 || (sweep == 0 && touched[k] == 2))
        continue;
      const Touch& t = touches[k];
      if (sweep > 0 && !stirred(stirred_at, t, sweep))
        continue;
      const double approach = pushVelocity(vs, t, friction);
      largest = std::max(largest, approach);
      if (approach * dt > settled)
        stir(stirred_at, t, sweep);
    }
    if (largest * dt <= settled)
      break;
  }
}

}  // namespace modal_mass_spring
