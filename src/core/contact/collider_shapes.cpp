// A collider's shape: where a path first enters it, a collider placed for one step, and the signed
// distance (collider_shapes.h, contact.h).
#include "contact/collider_shapes.h"

namespace modal_mass_spring
{
namespace
{

// The first t in [0, 1] where a0 + t (a1 - a0) reaches the sphere of `radius` about the origin, from
// a0 outside it; false when it does not.
bool sphereEntry(const Eigen::Vector3d& a0, const Eigen::Vector3d& a1, double radius, double& t)
{
  const Eigen::Vector3d dir = a1 - a0;
  const double a = dir.squaredNorm(), b = a0.dot(dir), c = a0.squaredNorm() - radius * radius;
  if (c <= 0.0 || a <= 0.0 || b >= 0.0)  // inside, still, or moving away
    return false;
  const double disc = b * b - a * c;
  if (disc < 0.0)
    return false;
  t = c / (-b + std::sqrt(disc));  // the smaller root, without cancellation
  return t <= 1.0;
}

// The box's entry (shapeEntry): slabs, the latest entry into the three slabs before the earliest exit.
bool boxEntry(const Collider& c, const Eigen::Vector3d& a0, const Eigen::Vector3d& dir, double& distance,
              Eigen::Vector3d& n)
{
  const Eigen::Vector3d q = a0 - c.center;
  if ((q.cwiseAbs() - c.half_extents).maxCoeff() <= 0.0)
    return false;
  double enter = -std::numeric_limits<double>::infinity(), exit = std::numeric_limits<double>::infinity();
  int axis = -1;
  for (int k = 0; k < 3; ++k)
  {
    if (dir[k] == 0.0)
    {
      if (std::abs(q[k]) > c.half_extents[k])
        return false;
      continue;
    }
    double t1 = (-c.half_extents[k] - q[k]) / dir[k], t2 = (c.half_extents[k] - q[k]) / dir[k];
    if (t1 > t2)
      std::swap(t1, t2);
    if (t1 > enter)
    {
      enter = t1;
      axis = k;
    }
    exit = std::min(exit, t2);
  }
  if (axis < 0 || enter > exit || enter < 0.0 || enter > 1.0)
    return false;
  n = Eigen::Vector3d::Zero();
  n[axis] = dir[axis] > 0.0 ? -1.0 : 1.0;
  distance = n.dot(dir) * (1.0 - enter);
  return true;
}

// The capsule's entry (shapeEntry): the union of the two end spheres and the side of the cylinder
// between them, the first entry into any (an entry through a flat end of the cylinder is inside an
// end sphere, entered earlier).
bool capsuleEntry(const Collider& c, const Eigen::Vector3d& a0, const Eigen::Vector3d& a1, double& distance,
                  Eigen::Vector3d& n)
{
  const Eigen::Vector3d dir = a1 - a0;
  double t = 0.0;
  const Eigen::Vector3d axis = c.b - c.a;
  const double length = axis.norm();
  const Eigen::Vector3d u = axis / length;
  const Eigen::Vector3d p = a0 - c.a;
  const double along = std::clamp(p.dot(u), 0.0, length);
  if ((p - along * u).norm() <= c.radius)
    return false;  // a0 inside
  double best = std::numeric_limits<double>::infinity();
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3d& end : {c.a, c.b})
    if (sphereEntry(a0 - end, a1 - end, c.radius, t) && t < best)
    {
      best = t;
      centre = end;
    }
  const Eigen::Vector3d p_perp = p - p.dot(u) * u, d_perp = dir - dir.dot(u) * u;
  if (sphereEntry(p_perp, p_perp + d_perp, c.radius, t) && t < best)
  {
    const double s = (p + t * dir).dot(u);
    if (s >= 0.0 && s <= length)
    {
      best = t;
      centre = c.a + s * u;
    }
  }
  if (!(best <= 1.0))
    return false;
  n = (a0 + best * dir - centre).normalized();
  distance = n.dot(dir) * (1.0 - best);
  return true;
}

}  // namespace

bool shapeEntry(const Collider& c, const Eigen::Vector3d& a0, const Eigen::Vector3d& a1, double& distance,
                Eigen::Vector3d& n)
{
  const Eigen::Vector3d dir = a1 - a0;
  double t = 0.0;
  switch (c.type)
  {
    case ColliderType::Plane:
      return false;
    case ColliderType::Box:
      return boxEntry(c, a0, dir, distance, n);
    case ColliderType::Sphere:
    {
      if (!sphereEntry(a0 - c.center, a1 - c.center, c.radius, t))
        return false;
      n = (a0 + t * dir - c.center).normalized();
      distance = n.dot(dir) * (1.0 - t);
      return true;
    }
    case ColliderType::Capsule:
      return capsuleEntry(c, a0, a1, distance, n);
  }
  return false;
}

Placed::Placed(const Collider& c, const Eigen::Isometry3d& at, const Eigen::Isometry3d& start, double thickness)
  : collider(&c), pose(at), to_local(at.inverse()), unit_normal(c.normal.normalized())
{
  step = at * start.inverse();
  still = step.isApprox(Eigen::Isometry3d::Identity(), 0.0);
  step_back = step.inverse();
  auto size = [](const Eigen::Vector3d& v) { return v.cwiseAbs().maxCoeff(); };
  scale = 1.0 + size(at.translation());
  switch (c.type)
  {
    case ColliderType::Plane: scale += size(c.point); break;
    case ColliderType::Box: scale += size(c.center) + size(c.half_extents); break;
    case ColliderType::Sphere: scale += size(c.center) + c.radius; break;
    case ColliderType::Capsule: scale += std::max(size(c.a), size(c.b)) + c.radius; break;
  }
  if (c.type == ColliderType::Sphere || c.type == ColliderType::Capsule)
    centre_distance = -c.radius;
  Eigen::Vector3d low = Eigen::Vector3d::Zero(), high = Eigen::Vector3d::Zero();
  double grow = thickness;
  switch (c.type)
  {
    case ColliderType::Plane:
      return;
    case ColliderType::Box:
    {
      const Eigen::Vector3d center = at * c.center;
      const Eigen::Vector3d half = at.linear().cwiseAbs() * c.half_extents;
      low = center - half;
      high = center + half;
      break;
    }
    case ColliderType::Sphere:
      low = high = at * c.center;
      grow += c.radius;
      break;
    case ColliderType::Capsule:
    {
      const Eigen::Vector3d a = at * c.a, b = at * c.b;
      low = a.cwiseMin(b);
      high = a.cwiseMax(b);
      grow += c.radius;
      break;
    }
  }
  // Round-off in the particle's distance must not reject one the distance would keep: a margin far
  // above it (1e-9 of the coordinates' size).
  grow += 1e-9 * (1.0 + low.cwiseAbs().cwiseMax(high.cwiseAbs()).maxCoeff() + grow);
  bounded = true;
  reach = Eigen::AlignedBox3d((low.array() - grow).matrix(), (high.array() + grow).matrix());
}

double signedDistance(const Collider& c, const Eigen::Isometry3d& pose, const Eigen::Vector3d& x,
                      Eigen::Vector3d& normal)
{
  Eigen::Vector3d n;
  const double d = localDistance(c, c.normal.normalized(), pose.inverse() * x,
                                 std::numeric_limits<double>::infinity(), n);
  normal = pose.linear() * n;
  return d;
}

}  // namespace modal_mass_spring
