// The Coulomb correction of a step's end state against the colliders (contact.h): particle by particle
// (correctParticles), or in a modal basis (correctModal).
#include "modal_mass_spring/contact.h"

#include "contact/collider_shapes.h"
#include "contact/geometry.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

namespace modal_mass_spring
{
namespace
{

// Two unit vectors completing n to an orthonormal basis.
void tangents(const Eigen::Vector3d& n, Eigen::Vector3d& t1, Eigen::Vector3d& t2)
{
  t1 = (std::abs(n.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY()).cross(n).normalized();
  t2 = n.cross(t1);
}

}  // namespace

struct Contact::Touch
{
  int particle;  // free particle: free dofs [dim particle, dim particle + dim)
  int collider;
  double distance;
  Eigen::Vector3d normal;
  Eigen::Vector3d surface_step;  // how far the collider's surface at the particle moved over the step
};

Contact::Contact(const Grid& grid, std::vector<Collider> colliders, double thickness)
  : grid_(grid), colliders_(std::move(colliders)), thickness_(thickness),
    poses_(colliders_.size(), Eigen::Isometry3d::Identity()), start_poses_(poses_), active_(colliders_.size(), true)
{
  for (size_t i = 0; i < colliders_.size(); ++i)
  {
    active_[i] = colliders_[i].frame.empty();
    if (active_[i])
      poses_[i] = start_poses_[i] = colliders_[i].pose;
  }
  report_.force.assign(colliders_.size(), Eigen::Vector3d::Zero());
  report_.touching.assign(colliders_.size(), 0);
}

void Contact::setPose(int i, const Eigen::Isometry3d& pose)
{
  if (!active_[i])
  {
    place(i, pose);  // it appears where its frame is: no sweep from the identity
    return;
  }
  if (!pose.isApprox(poses_[i], 0.0))
    moved_ = true;
  poses_[i] = pose;
}

void Contact::place(int i, const Eigen::Isometry3d& pose)
{
  // Appearing on the cloth pushes it out (work done on the grid), so it counts as a move.
  poses_[i] = start_poses_[i] = pose;
  active_[i] = true;
  moved_ = true;
}

void Contact::commit() { start_poses_ = poses_; }

void Contact::restore(const std::vector<Eigen::Isometry3d>& poses, const std::vector<bool>& active, bool moved)
{
  poses_ = start_poses_ = poses;
  active_ = active;
  moved_ = moved;
}

void Contact::follow(const Contact& other)
{
  colliders_ = other.colliders_;
  thickness_ = other.thickness_;
  poses_ = other.poses_;
  start_poses_ = other.start_poses_;
  active_ = other.active_;
  moved_ = other.moved_;
}

namespace
{

// A particle's position (or velocity) in 3D; a 2D grid's x-z plane is y = 0. Here, not a member, so
// that the contact pass inlines it (a member of a shared library is called through its PLT).
inline Eigen::Vector3d pointOf(const Eigen::VectorXd& x, int particle, int dim)
{
  if (dim == 3)
    return x.segment<3>(3 * particle);
  return Eigen::Vector3d(x[2 * particle], 0.0, x[2 * particle + 1]);
}

inline void addTo(Eigen::VectorXd& target, int p, int dim, const Eigen::Vector3d& delta)
{
  if (dim == 3)
    target.segment<3>(3 * p) += delta;
  else
  {
    target[2 * p] += delta.x();
    target[2 * p + 1] += delta.z();
  }
}

// What a pass sums, per placed collider (Count of them, or any number for 0): the particles touching
// it and their m dv (its force is minus that over dt, once); the deepest penetration before and
// after. Kept in the pass's own storage, which with one collider the stores to x and v cannot alias
// (the report's members would be reloaded after every store).
template <int Count>
struct PassSums
{
  explicit PassSums(int) { impulse.fill(Eigen::Vector3d::Zero()); }
  std::array<int, Count> touching{};
  std::array<Eigen::Vector3d, Count> impulse;
  std::array<int, Count> touched{};  // the colliders the current particle touches
  double before = 0.0, after = 0.0;
};

template <>
struct PassSums<0>
{
  explicit PassSums(int count) : touching(count, 0), impulse(count, Eigen::Vector3d::Zero()), touched(count) {}
  std::vector<int> touching;
  std::vector<Eigen::Vector3d> impulse;
  std::vector<int> touched;
  double before = 0.0, after = 0.0;
};

// The depth of a corrected particle at x below each surface it touched (placed[touched[0 .. touching)],
// the first at first_distance before), once all of them corrected it, into `after`. A particle that
// one collider alone touched and corrected, in 3D, ends at least the thickness out, so it cannot
// deepen the report and is not measured: every shape is convex, so its signed distance is a convex
// function whose gradient (a subgradient inside a box) is the normal n the correction used, and the
// correction moved the particle by the push along n plus a part normal to n: d(after) >= d + n .
// move = d + push = the thickness. This holds to round-off (far below the thickness, which the test
// asks) except at a round shape's centre or axis, where n is a fixed direction, and in 2D, where the
// move loses its out-of-plane part.
template <int Dim, typename Touched>
inline void measureDepth(const Placed* placed, const Touched& touched, int touching, bool corrected,
                         double first_distance, double thickness, const Eigen::Vector3d& x, double& after)
{
  if (Dim == 3 && touching == 1 && corrected && first_distance > placed[touched[0]].centre_distance &&
      thickness > 1e-6 * (placed[touched[0]].scale + x.cwiseAbs().maxCoeff()))
    return;
  for (int j = 0; j < touching; ++j)
  {
    Eigen::Vector3d unused;
    const double d = placed[touched[j]].distance(x, -std::numeric_limits<double>::infinity(), unused);
    after = std::max(after, -d);
  }
}

// The contact pass of correctParticles over the `count` placed colliders (Count of them when not 0)
// on a grid of dimension Dim, particle by particle: a touch corrects only its own particle, so this
// is the same as finding every collider's touches at the uncorrected positions and then correcting
// them collider by collider, with no list of touches kept. With one collider (a table, a floor), on
// a local copy of it, which the stores to x and v cannot alias.
template <int Dim, int Count>
PassSums<Count> contactPass(const Placed* placed_all, int count, double thickness, const Eigen::VectorXd& x_start,
                            Eigen::VectorXd& x, Eigen::VectorXd& v, const Eigen::VectorXd& mass, double dt,
                            int* first_touched)
{
  PassSums<Count> sums(count);
  const Placed* placed = placed_all;
  Collider shape;
  Placed one;
  if constexpr (Count == 1)
  {
    shape = *placed_all[0].collider;
    one = placed_all[0];
    one.collider = &shape;
    placed = &one;
  }
  const int particles = static_cast<int>(x.size()) / Dim;
  for (int p = 0; p < particles; ++p)
  {
    const Eigen::Vector3d at = pointOf(x, p, Dim);  // touches are found where the step left the particle
    const Eigen::Vector3d from = pointOf(x_start, p, Dim);  // and along its path there
    int touching = 0;
    bool corrected = false;  // an earlier collider's correction moved the particle
    double first_distance = 0.0;
    for (int k = 0; k < (Count == 0 ? count : Count); ++k)
    {
      const Placed& placed_k = placed[k];
      Eigen::Vector3d local_n;
      double d = 0.0;
      if (!placed_k.touches(from, at, thickness, d, local_n))
        continue;
      Eigen::Vector3d n = placed_k.normal(local_n);
      sums.before = std::max(sums.before, -d);
      ++sums.touching[k];
      sums.touched[touching++] = k;
      if (touching == 1)
      {
        first_distance = d;
        first_touched[p] = k;
      }
      // The surface point under the particle at the step's start went to `at` (rigid motion).
      const Eigen::Vector3d surface_step =
          placed_k.still ? Eigen::Vector3d::Zero() : Eigen::Vector3d(at - placed_k.step_back * at);
      if (corrected)
      {
        d = placed_k.distance(pointOf(x, p, Dim), thickness, local_n);  // after the earlier collider's correction
        if (d >= thickness)
          continue;
        n = placed_k.normal(local_n);
      }
      const double mu = placed_k.collider->friction;
      // Positions: push out, and Coulomb on the slip over the step with the push as the normal bound.
      const double push = thickness - d;
      const Eigen::Vector3d slip = pointOf(x, p, Dim) - pointOf(x_start, p, Dim) - surface_step;
      addTo(x, p, Dim, push * n + coulomb(slip - slip.dot(n) * n, mu * push));
      corrected = true;
      // Velocities: remove the approach, Coulomb on the tangential velocity relative to the surface.
      const Eigen::Vector3d relative =
          placed_k.still ? pointOf(v, p, Dim) : Eigen::Vector3d(pointOf(v, p, Dim) - surface_step / dt);
      const double approach = -relative.dot(n);
      if (approach <= 0.0)
        continue;
      const Eigen::Vector3d tangential = relative + approach * n;
      const Eigen::Vector3d dv = approach * n + coulomb(tangential, mu * approach);
      addTo(v, p, Dim, dv);
      sums.impulse[k] += mass[Dim * p] * dv;
    }
    measureDepth<Dim>(placed, sums.touched, touching, corrected, first_distance, thickness, pointOf(x, p, Dim),
                      sums.after);
  }
  return sums;
}

// The pass's sums into the report (`index`: the placed colliders' indices).
template <int Count>
void recordPass(const PassSums<Count>& sums, const std::vector<int>& index, double dt, ContactReport& out)
{
  for (size_t k = 0; k < index.size(); ++k)
  {
    out.touching[index[k]] = sums.touching[k];
    out.force[index[k]] = -sums.impulse[k] / dt;
  }
  for (int& c : out.touched_by)
    if (c >= 0)
      c = index[c];  // the placed collider's index among all
  out.penetration_before = sums.before;
  out.penetration_after = sums.after;
}

}  // namespace


Eigen::Vector3d Contact::point(const Eigen::VectorXd& x, int particle) const
{
  return pointOf(x, particle, grid_.dimension());
}

std::vector<Contact::Touch> Contact::detect(const Eigen::VectorXd& x_start, const Eigen::VectorXd& x)
{
  std::vector<Touch> touches;
  report_ = ContactReport{};
  report_.force.assign(colliders_.size(), Eigen::Vector3d::Zero());
  report_.touching.assign(colliders_.size(), 0);
  const int particles = static_cast<int>(x.size()) / grid_.dimension();
  report_.touched_by.assign(particles, -1);
  for (int c = 0; c < static_cast<int>(colliders_.size()); ++c)
  {
    if (!active_[c])
      continue;
    const Placed placed(colliders_[c], poses_[c], start_poses_[c], thickness_);
    for (int p = 0; p < particles; ++p)
    {
      const Eigen::Vector3d at = point(x, p);
      Eigen::Vector3d local_n;
      double d = 0.0;
      if (!placed.touches(point(x_start, p), at, thickness_, d, local_n))
        continue;
      report_.penetration_before = std::max(report_.penetration_before, -d);
      ++report_.touching[c];
      if (report_.touched_by[p] < 0)
        report_.touched_by[p] = c;
      // The surface point under the particle at the step's start went to `at` (rigid motion).
      const Eigen::Vector3d moved = placed.still ? Eigen::Vector3d::Zero() : Eigen::Vector3d(at - placed.step_back * at);
      touches.push_back(Touch{p, c, d, placed.normal(local_n), moved});
    }
  }
  return touches;
}

void Contact::correctParticles(const Eigen::VectorXd& x_start, Eigen::VectorXd& x, Eigen::VectorXd& v,
                               const Eigen::VectorXd& mass, double dt)
{
  report_.force.assign(colliders_.size(), Eigen::Vector3d::Zero());
  report_.touching.assign(colliders_.size(), 0);
  std::vector<Placed> placed;  // the active colliders, in order
  placed.reserve(colliders_.size());
  std::vector<int> index;      // their indices
  for (int c = 0; c < static_cast<int>(colliders_.size()); ++c)
    if (active_[c])
    {
      placed.emplace_back(colliders_[c], poses_[c], start_poses_[c], thickness_);
      index.push_back(c);
    }
  const int count = static_cast<int>(placed.size());
  const int dim = grid_.dimension();
  report_.touched_by.assign(x.size() / dim, -1);
  int* first = report_.touched_by.data();
  if (dim == 2)
    recordPass(contactPass<2, 0>(placed.data(), count, thickness_, x_start, x, v, mass, dt, first), index, dt, report_);
  else if (count == 1)
    recordPass(contactPass<3, 1>(placed.data(), count, thickness_, x_start, x, v, mass, dt, first), index, dt, report_);
  else
    recordPass(contactPass<3, 0>(placed.data(), count, thickness_, x_start, x, v, mass, dt, first), index, dt, report_);
}


namespace
{

// Per touch of correctModal: Phi_p^T e for e = n, t1, t2 (what an impulse along e does to the modal
// coordinates), and the starting normal gap, slip and relative velocity.
struct ModalRow
{
  Eigen::Vector3d e[3];
  Eigen::VectorXd g[3];
  double inverse[3];  // 1 / |g|^2, 0 where the basis cannot move the particle that way
  double gap;
  Eigen::Vector3d slip, velocity;
  double mu;
};

// The row's directions e (the normal and two tangents), g and inverse for the free particle of a
// grid of dimension dim in basis phi.
void modalDirections(const Eigen::Vector3d& normal, int particle, int dim, const Eigen::MatrixXd& phi,
                     const Eigen::VectorXd& mass, double compliance, ModalRow& row)
{
  const int r = static_cast<int>(phi.cols());
  row.e[0] = normal;
  tangents(normal, row.e[1], row.e[2]);
  for (int j = 0; j < 3; ++j)
  {
    row.g[j] = Eigen::VectorXd::Zero(r);
    for (int a = 0; a < dim; ++a)
    {
      const double component = dim == 3 ? row.e[j][a] : row.e[j][a == 0 ? 0 : 2];
      row.g[j] += component * phi.row(dim * particle + a).transpose();
    }
    // |g|^2 <= 1 / m (the basis moves a particle at most as freely as its own dofs would): where
    // it is far smaller, the particle barely moves in the basis and a full correction would throw
    // the whole grid; the compliance kCompliance / m bounds the modal step a touch can ask for.
    const double size = row.g[j].squaredNorm() + compliance / mass[dim * particle];
    row.inverse[j] = 1.0 / size;
  }
}

// One projected Gauss-Seidel solve of `sweeps` sweeps: the normal part of (start + Phi_p delta)
// kept >= bound (gap: -gap; velocity: 0), the tangential part cancelled within mu times the normal
// multiplier. Returns delta (r modal coordinates) and each row's multipliers in lambda.
Eigen::VectorXd solveModal(const std::vector<ModalRow>& rows, bool positions, int r, int sweeps,
                           std::vector<Eigen::Vector3d>& lambda)
{
  const int count = static_cast<int>(rows.size());
  Eigen::VectorXd delta = Eigen::VectorXd::Zero(r);
  lambda.assign(count, Eigen::Vector3d::Zero());
  for (int sweep = 0; sweep < sweeps; ++sweep)
  {
    for (int k = 0; k < count; ++k)
    {
      const ModalRow& row = rows[k];
      Eigen::Vector3d& l = lambda[k];
      const Eigen::Vector3d& start = positions ? row.slip : row.velocity;
      const double violation = positions ? row.gap + row.g[0].dot(delta) : row.e[0].dot(start) + row.g[0].dot(delta);
      const double normal = std::max(0.0, l[0] - violation * row.inverse[0]);
      delta += (normal - l[0]) * row.g[0];
      l[0] = normal;
      Eigen::Vector2d tangential(l[1], l[2]);
      for (int j = 1; j < 3; ++j)
        tangential[j - 1] -= (row.e[j].dot(start) + row.g[j].dot(delta)) * row.inverse[j];
      const double limit = row.mu * l[0];
      if (tangential.norm() > limit)
        tangential *= limit / tangential.norm();
      delta += (tangential[0] - l[1]) * row.g[1] + (tangential[1] - l[2]) * row.g[2];
      l[1] = tangential[0];
      l[2] = tangential[1];
    }
  }
  return delta;
}

}  // namespace

void Contact::correctModal(const Eigen::VectorXd& x_start, const Eigen::VectorXd& x, const Eigen::VectorXd& v,
                           const Eigen::VectorXd& mass, const Eigen::MatrixXd& phi, Eigen::VectorXd& q, Eigen::VectorXd& qv, double dt)
{
  const int dim = grid_.dimension();
  const std::vector<Touch> touches = detect(x_start, x);
  if (touches.empty())
    return;
  const int r = static_cast<int>(phi.cols());
  const int count = static_cast<int>(touches.size());
  std::vector<ModalRow> rows(count);
  for (int k = 0; k < count; ++k)
  {
    const Touch& t = touches[k];
    ModalRow& row = rows[k];
    modalDirections(t.normal, t.particle, dim, phi, mass, kCompliance, row);
    row.gap = t.distance - thickness_;
    row.slip = point(x, t.particle) - point(x_start, t.particle) - t.surface_step;
    row.velocity = point(v, t.particle) - t.surface_step / dt;
    row.mu = colliders_[t.collider].friction;
  }
  std::vector<Eigen::Vector3d> lambda;
  const Eigen::VectorXd dq = solveModal(rows, true, r, kSweeps, lambda);
  q += dq;
  qv += solveModal(rows, false, r, kSweeps, lambda);
  for (int k = 0; k < count; ++k)
    report_.force[touches[k].collider] -=
        (lambda[k][0] * rows[k].e[0] + lambda[k][1] * rows[k].e[1] + lambda[k][2] * rows[k].e[2]) / dt;
  for (int k = 0; k < count; ++k)
  {
    const ModalRow& row = rows[k];
    report_.penetration_after = std::max(report_.penetration_after, -(row.gap + thickness_ + row.g[0].dot(dq)));
  }
}

}  // namespace modal_mass_spring
