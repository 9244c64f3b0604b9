// Colliders as parameters: their names, their checks, reading them from a parameter source's fields,
// and the check that the cloth starts outside them (contact.h).
#include "modal_mass_spring/contact.h"

#include "modal_mass_spring/parameter_error.h"
#include "contact/collider_shapes.h"

#include <algorithm>
#include <cmath>
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
  const Eigen::Matrix3d turn = c.pose.linear();
  if (!c.pose.matrix().allFinite() || c.pose.translation().cwiseAbs().maxCoeff() > kMaxColliderCoordinate ||
      !(turn.transpose() * turn).isApprox(Eigen::Matrix3d::Identity(), 1e-9) || !(turn.determinant() > 0.0))
    rejectParameter(name + ".pose", text(c.pose.translation()),
                    "must be a finite rigid pose (a rotation and a translation in [-" + bound() + ", " + bound() + "] m)");
  if (planar && (c.pose.translation().y() != 0.0 || !(turn.col(1) - Eigen::Vector3d::UnitY()).isZero(1e-12)))
    rejectParameter(name + ".pose", text(c.pose.translation()),
                    "must keep the x-z plane on a 2D grid: its origin's y 0 and a turn about y only");
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
  if (key == "id")
    return "a string (the collider's name for ~set_colliders)";
  if (key == "friction")
    return "a number (the Coulomb coefficient, >= 0)";
  if (key == "radius")
    return "a number (m, > 0)";
  if (key == "point" || key == "normal" || key == "center" || key == "half_extents" || key == "a" || key == "b")
    return "a list of three numbers [x, y, z] (m)";
  return "not a key of a collider (the keys: type, frame, id, friction; point, normal (plane); center, half_extents "
         "(box); center, radius (sphere); a, b, radius (capsule))";
}

namespace
{

bool known(const std::vector<std::string>& keys, const std::string& key)
{
  return std::find(keys.begin(), keys.end(), key) != keys.end();
}

// The type named by the fields' `type` (refused when a number or absent).
ColliderType colliderTypeOf(const ColliderFields& f, const std::string& name)
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
  return parseColliderType(type_text->second, name + ".type");
}

// Refuses a field that is not a key of a collider of `type` (its vectors and scalars beside type and
// frame; `allowed` lists them), or of the wrong kind or size, and a key it needs that is absent.
void checkColliderFields(const ColliderFields& f, const std::string& name, ColliderType type,
                         const std::vector<std::string>& vectors, const std::vector<std::string>& scalars,
                         const std::string& allowed)
{
  for (const auto& [key, value] : f.text)
    if (key != "type" && key != "frame" && key != "id")
      rejectParameter(name + "." + key, "'" + value + "'",
                      known(vectors, key) || known(scalars, key) ? "must be " + colliderFieldExpected(key)
                                                                 : "is not a key of a " + toString(type) + " (its keys: " + allowed + ")");
  for (const auto& [key, value] : f.numbers)
  {
    const std::string field = name + "." + key;
    if (key == "type" || key == "frame" || key == "id")
      rejectParameter(field, value.empty() ? 0.0 : value[0], "must be " + colliderFieldExpected(key));
    if (known(vectors, key))
    {
      if (value.size() != 3)
        rejectParameter(field, std::to_string(value.size()) + " numbers", "must be a list of three numbers [x, y, z]");
      continue;
    }
    if (!known(scalars, key))
      rejectParameter(field, "(given)", "is not a key of a " + toString(type) + " (its keys: " + allowed + ")");
    if (value.size() != 1)
      rejectParameter(field, std::to_string(value.size()) + " numbers", "must be one number");
  }
  for (const std::string& key : vectors)
    if (!f.numbers.count(key))
      rejectParameter(name + "." + key, "(absent)", "a " + toString(type) + " needs it (its keys: " + allowed + ")");
  if (known(scalars, "radius") && !f.numbers.count("radius"))
    rejectParameter(name + ".radius", "(absent)", "a " + toString(type) + " needs a radius");
}

}  // namespace

Collider colliderFromFields(const ColliderFields& f, const std::string& name)
{
  Collider c;
  c.type = colliderTypeOf(f, name);
  std::vector<std::string> vectors, scalars{"friction"};
  switch (c.type)
  {
    case ColliderType::Plane: vectors = {"point", "normal"}; break;
    case ColliderType::Box: vectors = {"center", "half_extents"}; break;
    case ColliderType::Sphere: vectors = {"center"}; scalars.push_back("radius"); break;
    case ColliderType::Capsule: vectors = {"a", "b"}; scalars.push_back("radius"); break;
  }
  std::string allowed = "type, frame, id, friction";
  for (const std::string& key : vectors)
    allowed += ", " + key;
  for (size_t k = 1; k < scalars.size(); ++k)
    allowed += ", " + scalars[k];
  checkColliderFields(f, name, c.type, vectors, scalars, allowed);
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
  if (f.text.count("id"))
  {
    c.id = f.text.at("id");
    if (c.id.empty())
      rejectParameter(name + ".id", "''", "must be a non-empty string (the collider's name for ~set_colliders)");
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

DeepestParticle deepestFreeParticle(const Grid& grid, const Eigen::Matrix3Xd& points, const Collider& collider,
                                    const Eigen::Isometry3d& pose)
{
  DeepestParticle deepest;
  for (int p = 0; p < grid.numParticles(); ++p)
  {
    if (grid.isFixed(p) || grid.isHandle(p))
      continue;
    Eigen::Vector3d unused;
    const double depth = -signedDistance(collider, pose, points.col(p), unused);
    if (depth > deepest.depth)
      deepest = {p, depth};
  }
  return deepest;
}

double deepestInside(const Grid& grid, const Eigen::Matrix3Xd& points, const Contact& contact)
{
  double deepest = 0.0;
  for (int i = 0; i < static_cast<int>(contact.colliders().size()); ++i)
    if (contact.active(i))
      deepest = std::max(deepest, deepestFreeParticle(grid, points, contact.colliders()[i], contact.pose(i)).depth);
  return deepest;
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
    const auto [particle, deepest] = deepestFreeParticle(grid, points, collider, collider.pose);
    if (particle < 0 || deepest <= kSurfaceRoundOffFraction * thickness)
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

}  // namespace modal_mass_spring
