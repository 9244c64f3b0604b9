// Colliders, their signed distances, and the Coulomb correction of a step's end state (contact.h).
#include "modal_mass_spring/contact.h"

#include "modal_mass_spring/parameter_error.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

namespace modal_mass_spring
{
namespace
{

std::string text(const Eigen::Vector3d& v)
{
  std::ostringstream s;
  s << "[" << v.x() << ", " << v.y() << ", " << v.z() << "]";
  return s.str();
}

std::string bound()
{
  std::ostringstream s;
  s << kMaxColliderCoordinate;
  return s.str();
}

void requireFinite(const std::string& name, const Eigen::Vector3d& v)
{
  if (!v.allFinite() || v.cwiseAbs().maxCoeff() > kMaxColliderCoordinate)
    rejectParameter(name, text(v), "must be three finite numbers in [-" + bound() + ", " + bound() + "] (m)");
}

void requirePositive(const std::string& name, double value)
{
  if (!std::isfinite(value) || value <= 0.0 || value > kMaxColliderCoordinate)
    rejectParameter(name, value, "must be a number > 0 and <= " + bound() + " (m)");
}

// On a 2D grid a collider's surface must push the particles only within the x-z plane: the y of `v`
// (a point's, or a direction's) must be 0.
void requireInPlane(const std::string& name, const Eigen::Vector3d& v, const std::string& what)
{
  if (v.y() != 0.0)
    rejectParameter(name, text(v), "its y must be 0 on a 2D grid (" + what +
                                       " would push the particles along y, which a 2D grid in the x-z plane does not have)");
}

// The correction that Coulomb friction with the bound `limit` (>= 0) makes to a tangential quantity
// t: cancel it where the bound covers it (stick), else shorten it by the bound (slip). Compared
// squared: a resting particle sticks, and needs no square root.
Eigen::Vector3d coulomb(const Eigen::Vector3d& t, double limit)
{
  const double squared = t.squaredNorm();
  if (squared <= limit * limit)
    return -t;
  return -limit / std::sqrt(squared) * t;
}

// Two unit vectors completing n to an orthonormal basis.
void tangents(const Eigen::Vector3d& n, Eigen::Vector3d& t1, Eigen::Vector3d& t2)
{
  t1 = (std::abs(n.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY()).cross(n).normalized();
  t2 = n.cross(t1);
}

}  // namespace

std::string toString(ColliderType type)
{
  switch (type)
  {
    case ColliderType::Plane: return "plane";
    case ColliderType::Box: return "box";
    case ColliderType::Sphere: return "sphere";
    case ColliderType::Capsule: return "capsule";
  }
  return "?";
}

ColliderType parseColliderType(const std::string& text, const std::string& name)
{
  for (ColliderType t : {ColliderType::Plane, ColliderType::Box, ColliderType::Sphere, ColliderType::Capsule})
    if (text == toString(t))
      return t;
  rejectParameter(name, "'" + text + "'", "must be one of plane, box, sphere, capsule");
}

void validateCollider(const Collider& c, const std::string& name, int dimension)
{
  if (!std::isfinite(c.friction) || c.friction < 0.0)
    rejectParameter(name + ".friction", c.friction, "must be a finite Coulomb coefficient >= 0");
  const bool planar = dimension == 2;
  switch (c.type)
  {
    case ColliderType::Plane:
      requireFinite(name + ".point", c.point);
      requireFinite(name + ".normal", c.normal);
      if (!(c.normal.norm() > 1e-12))
        rejectParameter(name + ".normal", text(c.normal), "must be a non-zero vector (the side the cloth stays on)");
      if (planar)
        requireInPlane(name + ".normal", c.normal, "a plane whose normal has a y part");
      break;
    case ColliderType::Box:
      requireFinite(name + ".center", c.center);
      requireFinite(name + ".half_extents", c.half_extents);
      if (!(c.half_extents.minCoeff() > 0.0) || c.half_extents.maxCoeff() > kMaxColliderCoordinate)
        rejectParameter(name + ".half_extents", text(c.half_extents), "must be three numbers > 0 and <= " + bound() + " (m)");
      if (planar)
      {
        requireInPlane(name + ".center", c.center, "a box off the plane");
        // A particle inside is pushed out through the nearest face: a y face where the box is thinner
        // along y than its depth in the plane (at most the smaller in-plane half extent).
        if (c.half_extents.y() < std::min(c.half_extents.x(), c.half_extents.z()))
          rejectParameter(name + ".half_extents", text(c.half_extents),
                          "its y must be at least the smaller of its x and z on a 2D grid (a thinner box would push the "
                          "particles inside it out along y, which a 2D grid in the x-z plane does not have)");
      }
      break;
    case ColliderType::Sphere:
      requireFinite(name + ".center", c.center);
      requirePositive(name + ".radius", c.radius);
      if (planar)
        requireInPlane(name + ".center", c.center, "a sphere centred off the plane");
      break;
    case ColliderType::Capsule:
      requireFinite(name + ".a", c.a);
      requireFinite(name + ".b", c.b);
      requirePositive(name + ".radius", c.radius);
      if (!((c.b - c.a).norm() > 0.0))
        rejectParameter(name + ".b", text(c.b), "must differ from a (a capsule's segment; use a sphere for a point)");
      if (planar)
      {
        requireInPlane(name + ".a", c.a, "a capsule off the plane");
        requireInPlane(name + ".b", c.b, "a capsule off the plane");
      }
      break;
  }
}

std::string colliderFieldExpected(const std::string& key)
{
  if (key == "type")
    return "a string: plane, box, sphere or capsule";
  if (key == "frame")
    return "a string (a TF frame id)";
  if (key == "friction")
    return "a number (the Coulomb coefficient, >= 0)";
  if (key == "radius")
    return "a number (m, > 0)";
  if (key == "point" || key == "normal" || key == "center" || key == "half_extents" || key == "a" || key == "b")
    return "a list of three numbers [x, y, z] (m)";
  return "not a key of a collider (the keys: type, frame, friction; point, normal (plane); center, half_extents "
         "(box); center, radius (sphere); a, b, radius (capsule))";
}

Collider colliderFromFields(const ColliderFields& f, const std::string& name)
{
  if (f.numbers.count("type"))
  {
    const std::vector<double>& value = f.numbers.at("type");
    std::ostringstream given;
    if (value.size() == 1)
      given << value[0];
    else
      given << "a list of " << value.size() << " numbers";
    rejectParameter(name + ".type", given.str(), "must be " + colliderFieldExpected("type"));
  }
  const auto type_text = f.text.find("type");
  if (type_text == f.text.end())
    rejectParameter(name + ".type", "(absent)", "every collider needs a type: plane, box, sphere or capsule");
  Collider c;
  c.type = parseColliderType(type_text->second, name + ".type");
  std::vector<std::string> vectors, scalars{"friction"};
  switch (c.type)
  {
    case ColliderType::Plane: vectors = {"point", "normal"}; break;
    case ColliderType::Box: vectors = {"center", "half_extents"}; break;
    case ColliderType::Sphere: vectors = {"center"}; scalars.push_back("radius"); break;
    case ColliderType::Capsule: vectors = {"a", "b"}; scalars.push_back("radius"); break;
  }
  std::string allowed = "type, frame, friction";
  for (const std::string& key : vectors)
    allowed += ", " + key;
  for (size_t k = 1; k < scalars.size(); ++k)
    allowed += ", " + scalars[k];
  auto known = [](const std::vector<std::string>& keys, const std::string& key) {
    return std::find(keys.begin(), keys.end(), key) != keys.end();
  };
  for (const auto& [key, value] : f.text)
    if (key != "type" && key != "frame")
      rejectParameter(name + "." + key, "'" + value + "'",
                      known(vectors, key) || known(scalars, key) ? "must be " + colliderFieldExpected(key)
                                                                 : "is not a key of a " + toString(c.type) + " (its keys: " + allowed + ")");
  for (const auto& [key, value] : f.numbers)
  {
    const std::string field = name + "." + key;
    if (key == "type" || key == "frame")
      rejectParameter(field, value.empty() ? 0.0 : value[0], "must be " + colliderFieldExpected(key));
    if (known(vectors, key))
    {
      if (value.size() != 3)
        rejectParameter(field, std::to_string(value.size()) + " numbers", "must be a list of three numbers [x, y, z]");
      continue;
    }
    if (!known(scalars, key))
      rejectParameter(field, "(given)", "is not a key of a " + toString(c.type) + " (its keys: " + allowed + ")");
    if (value.size() != 1)
      rejectParameter(field, std::to_string(value.size()) + " numbers", "must be one number");
  }
  for (const std::string& key : vectors)
    if (!f.numbers.count(key))
      rejectParameter(name + "." + key, "(absent)", "a " + toString(c.type) + " needs it (its keys: " + allowed + ")");
  if (known(scalars, "radius") && !f.numbers.count("radius"))
    rejectParameter(name + ".radius", "(absent)", "a " + toString(c.type) + " needs a radius");
  auto vector = [&](const std::string& key) {
    const std::vector<double>& v = f.numbers.at(key);
    return Eigen::Vector3d(v[0], v[1], v[2]);
  };
  switch (c.type)
  {
    case ColliderType::Plane: c.point = vector("point"); c.normal = vector("normal"); break;
    case ColliderType::Box: c.center = vector("center"); c.half_extents = vector("half_extents"); break;
    case ColliderType::Sphere: c.center = vector("center"); break;
    case ColliderType::Capsule: c.a = vector("a"); c.b = vector("b"); break;
  }
  if (f.numbers.count("radius"))
    c.radius = f.numbers.at("radius")[0];
  if (f.numbers.count("friction"))
    c.friction = f.numbers.at("friction")[0];
  if (f.text.count("frame"))
  {
    c.frame = f.text.at("frame");
    if (c.frame.empty() || c.frame.front() == '/' || c.frame.find_first_of(" \t\n\r") != std::string::npos)
      rejectParameter(name + ".frame", "'" + c.frame + "'",
                      "must be a non-empty TF frame id without a leading '/' or spaces (the frame the collider follows)");
  }
  validateCollider(c, name);
  return c;
}

void validateContactThickness(double thickness, double spacing)
{
  if (!std::isfinite(thickness) || thickness < 0.0 || thickness > kMaxThicknessFraction * spacing)
  {
    std::ostringstream allowed;
    allowed << "must be a number of metres >= 0 (0: a tenth of the spacing) and at most " << kMaxThicknessFraction
            << " x spacing = " << kMaxThicknessFraction * spacing
            << " m (a touching particle is pushed out by up to the thickness in one step; further than a spring's "
               "length folds the cloth)";
    rejectParameter("contact_thickness", thickness, allowed.str());
  }
}

namespace
{

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

// Where the segment from a0 (outside the shape) to a1, both in the collider's frame, first enters the
// shape: the entry's outward normal n and n . (a1 - entry) (<= 0: how far beyond the surface the
// segment ends, on the side it came from). False when it does not enter it or a0 is inside. A
// plane's half-space is never passed through (a particle beyond it is inside at any depth).
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
    {
      // Slabs: the latest entry into the three slabs before the earliest exit.
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
    case ColliderType::Sphere:
    {
      if (!sphereEntry(a0 - c.center, a1 - c.center, c.radius, t))
        return false;
      n = (a0 + t * dir - c.center).normalized();
      distance = n.dot(dir) * (1.0 - t);
      return true;
    }
    case ColliderType::Capsule:
    {
      // The union of the two end spheres and the side of the cylinder between them: the first entry
      // into any (an entry through a flat end of the cylinder is inside an end sphere, entered earlier).
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
  }
  return false;
}

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

  Placed(const Collider& c, const Eigen::Isometry3d& at, const Eigen::Isometry3d& start, double thickness)
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

}  // namespace

double signedDistance(const Collider& c, const Eigen::Isometry3d& pose, const Eigen::Vector3d& x,
                      Eigen::Vector3d& normal)
{
  Eigen::Vector3d n;
  const double d = localDistance(c, c.normal.normalized(), pose.inverse() * x,
                                 std::numeric_limits<double>::infinity(), n);
  normal = pose.linear() * n;
  return d;
}

void checkStartOutsideColliders(const Grid& grid, const Eigen::VectorXd& positions,
                                const std::vector<Collider>& colliders, double thickness, const std::string& start)
{
  const Eigen::Matrix3Xd points = grid.toPoints(positions);
  for (size_t c = 0; c < colliders.size(); ++c)
  {
    const Collider& collider = colliders[c];
    if (!collider.frame.empty())
      continue;  // placed at its frame's first pose, later
    double deepest = 0.0;
    int particle = -1;
    for (int p = 0; p < grid.numParticles(); ++p)
    {
      if (grid.isFixed(p) || grid.isHandle(p))
        continue;
      Eigen::Vector3d unused;
      const double depth = -signedDistance(collider, Eigen::Isometry3d::Identity(), points.col(p), unused);
      if (depth > deepest)
      {
        deepest = depth;
        particle = p;
      }
    }
    // Round-off in placing a sheet on a surface stays far below a hundredth of the thickness.
    if (particle < 0 || deepest <= 0.01 * thickness)
      continue;
    std::ostringstream value, allowed;
    value << "a " << toString(collider.type);
    switch (collider.type)
    {
      case ColliderType::Plane: value << " through " << text(collider.point) << ", normal " << text(collider.normal); break;
      case ColliderType::Box: value << " at " << text(collider.center) << ", half_extents " << text(collider.half_extents); break;
      case ColliderType::Sphere: value << " at " << text(collider.center) << ", radius " << collider.radius; break;
      case ColliderType::Capsule: value << " from " << text(collider.a) << " to " << text(collider.b) << ", radius " << collider.radius; break;
    }
    allowed << "free particle " << particle << " starts " << deepest << " m inside it (" << start
            << " places it at " << text(points.col(particle)) << " m; the start ignores colliders); the cloth must start "
            << "outside every collider (the first step would throw it out): move the collider or the grid, or start "
            << "from another state (initial_state)";
    rejectParameter("colliders[" + std::to_string(c) + "]", value.str(), allowed.str());
  }
}

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
    active_[i] = colliders_[i].frame.empty();
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

// The pass of correctParticles below with one active collider on a 3D grid (a table, a floor): the
// same arithmetic in the same order, so the same results to the bit, but on local copies of the
// collider and the sums, which the stores to x and v cannot alias (the general pass reloads them
// after every store), and with no per-collider bookkeeping.
struct OnePassResult
{
  int touching = 0;
  double before = 0.0, after = 0.0;
  Eigen::Vector3d force = Eigen::Vector3d::Zero();
};

OnePassResult onePass(const Placed& placed, double thickness, const Eigen::VectorXd& x_start, Eigen::VectorXd& x,
                      Eigen::VectorXd& v, const Eigen::VectorXd& mass, double dt)
{
  const Collider shape = *placed.collider;
  Placed one = placed;
  one.collider = &shape;
  const double mu = shape.friction;
  int touching = 0;
  double before = 0.0, after = 0.0;
  Eigen::Vector3d impulse = Eigen::Vector3d::Zero();
  double* const xs = x.data();
  double* const vs = v.data();
  const double* const starts = x_start.data();
  const int particles = static_cast<int>(x.size()) / 3;
  for (int p = 0; p < particles; ++p)
  {
    const Eigen::Vector3d at = Eigen::Map<const Eigen::Vector3d>(xs + 3 * p);
    Eigen::Vector3d local_n;
    double d = 0.0;
    if (!one.touches(Eigen::Map<const Eigen::Vector3d>(starts + 3 * p), at, thickness, d, local_n))
      continue;
    const Eigen::Vector3d n = one.normal(local_n);
    before = std::max(before, -d);
    ++touching;
    const Eigen::Vector3d surface_step = one.still ? Eigen::Vector3d::Zero() : Eigen::Vector3d(at - one.step_back * at);
    const double push = thickness - d;
    const Eigen::Vector3d slip = at - Eigen::Map<const Eigen::Vector3d>(starts + 3 * p) - surface_step;
    const Eigen::Vector3d corrected = at + (push * n + coulomb(slip - slip.dot(n) * n, mu * push));
    Eigen::Map<Eigen::Vector3d>(xs + 3 * p) = corrected;
    const Eigen::Vector3d velocity = Eigen::Map<const Eigen::Vector3d>(vs + 3 * p);
    const Eigen::Vector3d relative = one.still ? velocity : Eigen::Vector3d(velocity - surface_step / dt);
    const double approach = -relative.dot(n);
    if (approach > 0.0)
    {
      const Eigen::Vector3d tangential = relative + approach * n;
      const Eigen::Vector3d dv = approach * n + coulomb(tangential, mu * approach);
      Eigen::Map<Eigen::Vector3d>(vs + 3 * p) = velocity + dv;
      impulse += mass[3 * p] * dv;
    }
    // The depth after: measured only where the proof below (correctParticles) does not cover it.
    if (d > one.centre_distance && thickness > 1e-6 * (one.scale + corrected.cwiseAbs().maxCoeff()))
      continue;
    Eigen::Vector3d unused;
    after = std::max(after, -one.distance(corrected, -std::numeric_limits<double>::infinity(), unused));
  }
  OnePassResult result;
  result.touching = touching;
  result.before = before;
  result.after = after;
  result.force = -impulse / dt;
  return result;
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
  const int dim = grid_.dimension();
  report_.force.assign(colliders_.size(), Eigen::Vector3d::Zero());
  report_.touching.assign(colliders_.size(), 0);
  report_.penetration_before = report_.penetration_after = 0.0;
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
  std::vector<int> touched(count);  // the colliders the current particle touches
  // Per collider: the sum of the touching particles' m dv (its force is minus that over dt, once).
  std::vector<Eigen::Vector3d> impulse(count, Eigen::Vector3d::Zero());
  auto add = [&](Eigen::VectorXd& target, int p, const Eigen::Vector3d& delta) {
    if (dim == 3)
      target.segment<3>(3 * p) += delta;
    else
    {
      target[2 * p] += delta.x();
      target[2 * p + 1] += delta.z();
    }
  };
  // One pass, particle by particle: a touch corrects only its own particle, so this is the same as
  // finding every collider's touches at the uncorrected positions and then correcting them collider
  // by collider, with no list of touches kept.
  const int particles = static_cast<int>(x.size()) / dim;
  if (count == 1 && dim == 3)
  {
    const OnePassResult one = onePass(placed[0], thickness_, x_start, x, v, mass, dt);
    report_.touching[index[0]] = one.touching;
    report_.penetration_before = one.before;
    report_.penetration_after = one.after;
    report_.force[index[0]] = one.force;
    return;
  }
  for (int p = 0; p < particles; ++p)
  {
    const Eigen::Vector3d at = pointOf(x, p, dim);  // touches are found where the step left the particle
    const Eigen::Vector3d from = pointOf(x_start, p, dim);  // and along its path there
    int touching = 0;
    bool corrected = false;  // an earlier collider's correction moved the particle
    double first_distance = 0.0;
    for (int k = 0; k < count; ++k)
    {
      const Placed& placed_k = placed[k];
      Eigen::Vector3d local_n;
      double d = 0.0;
      if (!placed_k.touches(from, at, thickness_, d, local_n))
        continue;
      Eigen::Vector3d n = placed_k.normal(local_n);
      const int c = index[k];
      report_.penetration_before = std::max(report_.penetration_before, -d);
      ++report_.touching[c];
      touched[touching++] = k;
      if (touching == 1)
        first_distance = d;
      // The surface point under the particle at the step's start went to `at` (rigid motion).
      const Eigen::Vector3d surface_step =
          placed_k.still ? Eigen::Vector3d::Zero() : Eigen::Vector3d(at - placed_k.step_back * at);
      if (corrected)
      {
        d = placed_k.distance(pointOf(x, p, dim), thickness_, local_n);  // after the earlier collider's correction
        if (d >= thickness_)
          continue;
        n = placed_k.normal(local_n);
      }
      const double mu = colliders_[c].friction;
      // Positions: push out, and Coulomb on the slip over the step with the push as the normal bound.
      const double push = thickness_ - d;
      const Eigen::Vector3d slip = pointOf(x, p, dim) - pointOf(x_start, p, dim) - surface_step;
      add(x, p, push * n + coulomb(slip - slip.dot(n) * n, mu * push));
      corrected = true;
      // Velocities: remove the approach, Coulomb on the tangential velocity relative to the surface.
      const Eigen::Vector3d relative =
          placed_k.still ? pointOf(v, p, dim) : Eigen::Vector3d(pointOf(v, p, dim) - surface_step / dt);
      const double approach = -relative.dot(n);
      if (approach <= 0.0)
        continue;
      const Eigen::Vector3d tangential = relative + approach * n;
      const Eigen::Vector3d dv = approach * n + coulomb(tangential, mu * approach);
      add(v, p, dv);
      impulse[k] += mass[dim * p] * dv;
    }
    // Its depth below each surface it touched, once all of them corrected it. A particle that one
    // collider alone touched and corrected, in 3D, ends at least the thickness out, so it cannot
    // deepen the report and is not measured: every shape is convex, so its signed distance is a
    // convex function whose gradient (a subgradient inside a box) is the normal n the correction
    // used, and the correction moved the particle by the push along n plus a part normal to n:
    // d(after) >= d + n . move = d + push = the thickness. This holds to round-off (far below the
    // thickness, which the test asks) except at a round shape's centre or axis, where n is a fixed
    // direction, and in 2D, where the move loses its out-of-plane part.
    if (dim == 3 && touching == 1 && corrected && first_distance > placed[touched[0]].centre_distance &&
        thickness_ > 1e-6 * (placed[touched[0]].scale + pointOf(x, p, dim).cwiseAbs().maxCoeff()))
      continue;
    for (int j = 0; j < touching; ++j)
    {
      Eigen::Vector3d unused;
      const double d = placed[touched[j]].distance(pointOf(x, p, dim), -std::numeric_limits<double>::infinity(), unused);
      report_.penetration_after = std::max(report_.penetration_after, -d);
    }
  }
  for (int k = 0; k < count; ++k)
    report_.force[index[k]] = -impulse[k] / dt;
}

void Contact::correctModal(const Eigen::VectorXd& x_start, const Eigen::VectorXd& x, const Eigen::VectorXd& v,
                           const Eigen::VectorXd& mass, const Eigen::MatrixXd& phi, Eigen::VectorXd& q, Eigen::VectorXd& qv, double dt)
{
  const int dim = grid_.dimension();
  const std::vector<Touch> touches = detect(x_start, x);
  if (touches.empty())
    return;
  const int r = static_cast<int>(phi.cols());
  const int count = static_cast<int>(touches.size());
  // Per touch: Phi_p^T e for e = n, t1, t2 (what an impulse along e does to the modal coordinates),
  // and the starting normal gap, slip and relative velocity.
  struct Row
  {
    Eigen::Vector3d e[3];
    Eigen::VectorXd g[3];
    double inverse[3];  // 1 / |g|^2, 0 where the basis cannot move the particle that way
    double gap;
    Eigen::Vector3d slip, velocity;
    double mu;
  };
  std::vector<Row> rows(count);
  for (int k = 0; k < count; ++k)
  {
    const Touch& t = touches[k];
    Row& row = rows[k];
    row.e[0] = t.normal;
    tangents(t.normal, row.e[1], row.e[2]);
    for (int j = 0; j < 3; ++j)
    {
      row.g[j] = Eigen::VectorXd::Zero(r);
      for (int a = 0; a < dim; ++a)
      {
        const double component = dim == 3 ? row.e[j][a] : row.e[j][a == 0 ? 0 : 2];
        row.g[j] += component * phi.row(dim * t.particle + a).transpose();
      }
      // |g|^2 <= 1 / m (the basis moves a particle at most as freely as its own dofs would): where
      // it is far smaller, the particle barely moves in the basis and a full correction would throw
      // the whole grid; the compliance kCompliance / m bounds the modal step a touch can ask for.
      const double size = row.g[j].squaredNorm() + kCompliance / mass[dim * t.particle];
      row.inverse[j] = 1.0 / size;
    }
    row.gap = t.distance - thickness_;
    row.slip = point(x, t.particle) - point(x_start, t.particle) - t.surface_step;
    row.velocity = point(v, t.particle) - t.surface_step / dt;
    row.mu = colliders_[t.collider].friction;
  }
  // One projected Gauss-Seidel solve: the normal part of (start + Phi_p delta) kept >= bound (gap:
  // -gap; velocity: 0), the tangential part cancelled within mu times the normal multiplier.
  auto solve = [&](bool positions) {
    Eigen::VectorXd delta = Eigen::VectorXd::Zero(r);
    std::vector<Eigen::Vector3d> lambda(count, Eigen::Vector3d::Zero());
    for (int sweep = 0; sweep < kSweeps; ++sweep)
    {
      for (int k = 0; k < count; ++k)
      {
        Row& row = rows[k];
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
    if (!positions)
      for (int k = 0; k < count; ++k)
        report_.force[touches[k].collider] -=
            (lambda[k][0] * rows[k].e[0] + lambda[k][1] * rows[k].e[1] + lambda[k][2] * rows[k].e[2]) / dt;
    return delta;
  };
  const Eigen::VectorXd dq = solve(true);
  q += dq;
  qv += solve(false);
  for (int k = 0; k < count; ++k)
  {
    const Row& row = rows[k];
    report_.penetration_after = std::max(report_.penetration_after, -(row.gap + thickness_ + row.g[0].dot(dq)));
  }
}

}  // namespace modal_mass_spring
