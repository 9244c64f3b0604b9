// A collider's shape (internal): its signed distance, where a path first enters it, and a collider
// placed at its pose for one step, with the test of a particle's path against it.
#pragma once

#include "modal_mass_spring/contact.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <limits>

namespace modal_mass_spring
{

// A free particle inside a collider by at most this fraction of the thickness is on its surface:
// round-off in placing a sheet on a surface stays far below it.
constexpr double kSurfaceRoundOffFraction = 0.01;

// The free particle (neither fixed nor held) of `points` (3 x particles, grid coordinates) deepest
// inside `collider` at `pose`, and its depth (> 0); particle -1 where none is inside.
struct DeepestParticle
{
  int particle = -1;
  double depth = 0.0;
};
DeepestParticle deepestFreeParticle(const Grid& grid, const Eigen::Matrix3Xd& points, const Collider& collider,
                                    const Eigen::Isometry3d& pose);

// The shape's signed distance at p (the collider's frame) and, where it is below `limit`, its outward
// unit normal there (that frame): the particles a pass rejects, and the depth checks, skip the
// normal's divisions. unit_normal: the plane's normal, normalized. Inlined into the contact pass,
// which calls it for every particle near a collider.
[[gnu::always_inline]] inline double localDistance(const Collider& c, const Eigen::Vector3d& unit_normal, const Eigen::Vector3d& p, double limit,
                     Eigen::Vector3d& n)
{
  n = Eigen::Vector3d::UnitZ();
  double d = 0.0;
  auto round = [&](const Eigen::Vector3d& closest, double radius) {
    const Eigen::Vector3d r = p - closest;
    const double length = r.norm();
    d = length - radius;
    if (d < limit)
      n = length > 0.0 ? Eigen::Vector3d(r / length) : Eigen::Vector3d::UnitZ();
  };
  switch (c.type)
  {
    case ColliderType::Plane:
      n = unit_normal;
      d = n.dot(p - c.point);
      break;
    case ColliderType::Sphere:
      round(c.center, c.radius);
      break;
    case ColliderType::Capsule:
    {
      const Eigen::Vector3d axis = c.b - c.a;
      const double s = std::clamp(axis.dot(p - c.a) / axis.squaredNorm(), 0.0, 1.0);
      round(c.a + s * axis, c.radius);
      break;
    }
    case ColliderType::Box:
    {
      const Eigen::Vector3d q = p - c.center;
      const Eigen::Vector3d excess = q.cwiseAbs() - c.half_extents;
      int outside = 0, face = 0;
      for (int k = 0; k < 3; ++k)
        if (excess[k] > 0.0)
        {
          ++outside;
          face = k;
        }
      if (outside == 1)
      {
        // Beyond one face only (a particle on a table top): the distance is that excess and the normal
        // the face's, what the general case below gives (sqrt(e^2) = e in floating point), without
        // its square root and divisions.
        d = excess[face];
        if (d < limit)
        {
          n = Eigen::Vector3d::Zero();
          n[face] = q[face] < 0.0 ? -1.0 : 1.0;
        }
        break;
      }
      const Eigen::Vector3d sign = q.unaryExpr([](double v) { return v < 0.0 ? -1.0 : 1.0; });
      if (outside > 1)
      {
        const Eigen::Vector3d out = excess.cwiseMax(0.0).cwiseProduct(sign);
        d = out.norm();
        if (d < limit)
          n = out / d;
      }
      else
      {
        int axis = 0;
        d = excess.maxCoeff(&axis);  // the nearest face, from inside
        n = Eigen::Vector3d::Zero();
        n[axis] = sign[axis];
      }
      break;
    }
  }
  return d;
}

// Where the segment from a0 (outside the shape) to a1, both in the collider's frame, first enters the
// shape: the entry's outward normal n and n . (a1 - entry) (<= 0: how far beyond the surface the
// segment ends, on the side it came from). False when it does not enter it or a0 is inside. A
// plane's half-space is never passed through (a particle beyond it is inside at any depth).
bool shapeEntry(const Collider& c, const Eigen::Vector3d& a0, const Eigen::Vector3d& a1, double& distance,
                Eigen::Vector3d& n);

// A collider at its pose for one step, in the forms every particle's test needs: computed once per
// step, not once per particle (the inverse pose, the plane's unit normal, the step's motion).
struct Placed
{
  const Collider* collider = nullptr;
  Eigen::Isometry3d pose, to_local;  // the pose and its inverse
  Eigen::Vector3d unit_normal;       // plane
  bool still = true;                 // the collider did not move over the step
  Eigen::Isometry3d step, step_back; // else its motion over the step, and that inverted
  // Every point closer to the surface than the thickness lies in `reach` (grid coordinates), so a
  // particle outside it is rejected with six comparisons; a plane is unbounded (no reach).
  bool bounded = false;
  Eigen::AlignedBox3d reach;
  // The size of the numbers its distance is computed from (m), for the round-off bound below.
  double scale = 0.0;
  // A sphere's or capsule's distance at or below this is at its centre or axis, where the normal is
  // a fixed direction rather than the distance's gradient.
  double centre_distance = -std::numeric_limits<double>::infinity();

  Placed() = default;
  // The collider c at pose `at`, at `start` at the step's start, for contacts within `thickness`.
  Placed(const Collider& c, const Eigen::Isometry3d& at, const Eigen::Isometry3d& start, double thickness);

  // Signed distance at x (grid coordinates) and, where it is below `limit`, the outward normal in the
  // collider's frame (turned into grid coordinates by normal(), for a touching particle only).
  double distance(const Eigen::Vector3d& x, double limit, Eigen::Vector3d& local_normal) const
  {
    return localDistance(*collider, unit_normal, to_local * x, limit, local_normal);
  }
  Eigen::Vector3d normal(const Eigen::Vector3d& local_normal) const { return pose.linear() * local_normal; }

  // Whether a particle that went from `from` to `at` over the step (grid coordinates) touches: its
  // distance d below the thickness at the end, or its path through the shape. Contact is continuous:
  // the path is the straight segment relative to the collider (the start carried by the collider's
  // motion over the step), and where it entered the shape from outside, d and the normal are the
  // entry's (d = n . (end - entry)), so a particle that passed through a thin plate or ended past the
  // middle of one is put back on the side it came from. Its distance at the end bounds how far it
  // can be from the shape on the way: a path shorter than that entered nothing (a resting particle
  // needs no sweep).
  [[gnu::always_inline]] inline bool touches(const Eigen::Vector3d& from, const Eigen::Vector3d& at, double thickness,
                                             double& d, Eigen::Vector3d& local_normal) const
  {
    const Eigen::Vector3d start = still ? from : Eigen::Vector3d(step * from);
    if (bounded && !reach.contains(at) && !reach.intersects(Eigen::AlignedBox3d(start.cwiseMin(at), start.cwiseMax(at))))
      return false;
    d = distance(at, thickness, local_normal);
    if (!bounded || (d >= 0.0 && (at - start).squaredNorm() <= d * d))
      return d < thickness;
    double entry_d = 0.0;
    Eigen::Vector3d entry_n;
    if (shapeEntry(*collider, to_local * start, to_local * at, entry_d, entry_n))
    {
      d = entry_d;
      local_normal = entry_n;
      return true;
    }
    return d < thickness;
  }
};

}  // namespace modal_mass_spring
