// The colliders as rviz markers and contact forces as wrenches, and ~set_colliders's colliders as the core's.
#include "contact_messages.h"

#include "modal_mass_spring/parameter_error.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace modal_mass_spring
{
namespace
{

// The plane drawn as a square this wide (m) and this thick.
constexpr double kPlaneSide = 4.0, kPlaneThickness = 0.002;

void place(visualization_msgs::Marker& m, const Eigen::Isometry3d& pose)
{
  const Eigen::Quaterniond q(pose.linear());
  m.pose.position.x = pose.translation().x();
  m.pose.position.y = pose.translation().y();
  m.pose.position.z = pose.translation().z();
  m.pose.orientation.w = q.w();
  m.pose.orientation.x = q.x();
  m.pose.orientation.y = q.y();
  m.pose.orientation.z = q.z();
}

}  // namespace

visualization_msgs::MarkerArray colliderMarkers(const Contact& contact, const std::string& frame_id,
                                                const Eigen::Vector3d& offset, const std::string& ns,
                                                const ros::Time& stamp)
{
  visualization_msgs::MarkerArray array;
  int id = 0;
  for (size_t i = 0; i < contact.colliders().size(); ++i)
  {
    const Collider& c = contact.colliders()[i];
    const Eigen::Isometry3d pose = Eigen::Translation3d(offset) * contact.pose(static_cast<int>(i));
    visualization_msgs::Marker m;
    m.header.frame_id = frame_id;
    m.header.stamp = stamp;
    m.ns = ns;
    // A collider on a TF frame not yet found touches nothing: its marker is taken away until it is.
    m.action = contact.active(static_cast<int>(i)) ? visualization_msgs::Marker::ADD : visualization_msgs::Marker::DELETE;
    m.color.r = m.color.g = m.color.b = 0.6f;
    m.color.a = 0.8f;
    auto add = [&](int type, const Eigen::Isometry3d& local, const Eigen::Vector3d& scale) {
      m.id = id++;
      m.type = type;
      place(m, pose * local);
      m.scale.x = scale.x();
      m.scale.y = scale.y();
      m.scale.z = scale.z();
      array.markers.push_back(m);
    };
    switch (c.type)
    {
      case ColliderType::Plane:
      {
        // The square's top face on the plane: its centre half a thickness below, along the normal.
        const Eigen::Vector3d n = c.normal.normalized();
        const Eigen::Isometry3d local = Eigen::Translation3d(c.point - 0.5 * kPlaneThickness * n) *
                                        Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), n);
        add(visualization_msgs::Marker::CUBE, local, Eigen::Vector3d(kPlaneSide, kPlaneSide, kPlaneThickness));
        break;
      }
      case ColliderType::Box:
        add(visualization_msgs::Marker::CUBE, Eigen::Isometry3d(Eigen::Translation3d(c.center)), 2.0 * c.half_extents);
        break;
      case ColliderType::Sphere:
        add(visualization_msgs::Marker::SPHERE, Eigen::Isometry3d(Eigen::Translation3d(c.center)),
            Eigen::Vector3d::Constant(2.0 * c.radius));
        break;
      case ColliderType::Capsule:
      {
        const Eigen::Vector3d axis = c.b - c.a;
        const Eigen::Isometry3d middle = Eigen::Translation3d(0.5 * (c.a + c.b)) *
                                         Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), axis);
        add(visualization_msgs::Marker::CYLINDER, middle, Eigen::Vector3d(2.0 * c.radius, 2.0 * c.radius, axis.norm()));
        for (const Eigen::Vector3d& end : {c.a, c.b})
          add(visualization_msgs::Marker::SPHERE, Eigen::Isometry3d(Eigen::Translation3d(end)),
              Eigen::Vector3d::Constant(2.0 * c.radius));
        break;
      }
    }
  }
  return array;
}

geometry_msgs::WrenchStamped forceWrench(const Eigen::Vector3d& force, const std::string& frame_id,
                                         const ros::Time& stamp, const Eigen::Vector3d& torque)
{
  geometry_msgs::WrenchStamped w;
  w.header.frame_id = frame_id;
  w.header.stamp = stamp;
  w.wrench.force.x = force.x();
  w.wrench.force.y = force.y();
  w.wrench.force.z = force.z();
  w.wrench.torque.x = torque.x();
  w.wrench.torque.y = torque.y();
  w.wrench.torque.z = torque.z();
  return w;
}

}  // namespace modal_mass_spring

namespace modal_mass_spring
{
namespace
{

template <typename T>
[[noreturn]] void refuse(const std::string& field, const T& value, const std::string& allowed)
{
  std::ostringstream message;
  message << field << " = " << value << ": " << allowed;
  throw std::invalid_argument(message.str());
}

std::string listText(const std::vector<double>& values)
{
  std::ostringstream s;
  s << "[";
  for (size_t k = 0; k < values.size(); ++k)
    s << (k ? ", " : "") << values[k];
  s << "]";
  return s.str();
}

constexpr char kShapes[] =
    "BOX (1, dimensions [x, y, z]), SPHERE (2, [radius]), CYLINDER (3, [height, radius]: the capsule around it), "
    "or 0 with `plane` (a x + b y + c z + d = 0); CONE is refused";

}  // namespace

Collider colliderFromMessage(const PlacedCollider& message, const std::string& name,
                             const Eigen::Vector3d& grid_offset, int dimension)
{
  if (message.id.empty())
    refuse(name + ".id", "''", "must be a non-empty name, unique among the colliders");
  const std::string field = name + " ('" + message.id + "')";
  Collider c;
  c.id = message.id;
  if (!std::isfinite(message.friction) || message.friction < 0.0)
    refuse(field + ".friction", message.friction, "must be a finite Coulomb coefficient >= 0");
  c.friction = message.friction;
  const std::vector<double>& dims = message.shape.dimensions;
  auto requireSizes = [&](size_t count, const std::string& what) {
    if (dims.size() != count)
      refuse(field + ".shape.dimensions", listText(dims), "a " + what + " needs " + std::to_string(count) + " number" +
                                                              (count > 1 ? "s" : ""));
    for (double d : dims)
      if (!std::isfinite(d) || d <= 0.0 || d > kMaxColliderCoordinate)
        refuse(field + ".shape.dimensions", listText(dims), "each must be a number > 0 and <= 1e6 (m)");
  };
  switch (message.shape.type)
  {
    case shape_msgs::SolidPrimitive::BOX:
      requireSizes(3, "BOX ([x, y, z], its full sizes)");
      c.type = ColliderType::Box;
      c.center = Eigen::Vector3d::Zero();
      c.half_extents = 0.5 * Eigen::Vector3d(dims[0], dims[1], dims[2]);
      break;
    case shape_msgs::SolidPrimitive::SPHERE:
      requireSizes(1, "SPHERE ([radius])");
      c.type = ColliderType::Sphere;
      c.center = Eigen::Vector3d::Zero();
      c.radius = dims[0];
      break;
    case shape_msgs::SolidPrimitive::CYLINDER:
    {
      // No collider here has flat ends: the capsule on the same axis and radius encloses it, its
      // round ends reaching `radius` beyond the flat ones (a robot's obstacle grown, never shrunk).
      requireSizes(2, "CYLINDER ([height, radius], its axis along the pose's z)");
      const double height = dims[shape_msgs::SolidPrimitive::CYLINDER_HEIGHT];
      c.type = ColliderType::Capsule;
      c.a = Eigen::Vector3d(0.0, 0.0, -0.5 * height);
      c.b = Eigen::Vector3d(0.0, 0.0, 0.5 * height);
      c.radius = dims[shape_msgs::SolidPrimitive::CYLINDER_RADIUS];
      break;
    }
    case 0:
    {
      if (!dims.empty())
        refuse(field + ".shape.dimensions", listText(dims), "a plane (shape.type 0) takes none: its `plane` gives it");
      const auto& k = message.plane.coef;
      const Eigen::Vector3d normal(k[0], k[1], k[2]);
      const std::vector<double> coef(k.begin(), k.end());
      if (!normal.allFinite() || !std::isfinite(k[3]) || !(normal.norm() > 1e-12))
        refuse(field + ".plane.coef", listText(coef),
               "must be finite with (a, b, c) non-zero: the plane a x + b y + c z + d = 0, the cloth on the side (a, b, c) points to");
      // Its distance from the pose's origin, |d| / |(a, b, c)|, within the colliders' coordinates.
      if (std::abs(k[3]) / normal.norm() > kMaxColliderCoordinate)
        refuse(field + ".plane.coef", listText(coef), "must put the plane within 1e6 m of the pose's origin (|d| / |(a, b, c)|)");
      c.type = ColliderType::Plane;
      c.normal = normal / normal.norm();
      c.point = -k[3] * c.normal / normal.norm();
      break;
    }
    default:
      refuse(field + ".shape.type", static_cast<int>(message.shape.type), std::string("must be ") + kShapes);
  }
  const auto& p = message.pose.position;
  const Eigen::Vector3d position(p.x, p.y, p.z);
  if (!position.allFinite() || position.cwiseAbs().maxCoeff() > kMaxColliderCoordinate)
    refuse(field + ".pose.position", listText({p.x, p.y, p.z}), "must be three finite numbers in [-1e6, 1e6] (m)");
  const auto& o = message.pose.orientation;
  const Eigen::Quaterniond q(o.w, o.x, o.y, o.z);
  // A quaternion written with a few digits is accepted and normalised; a zero or garbled one is a mistake.
  if (!q.coeffs().allFinite() || std::abs(q.norm() - 1.0) > 1e-3)
    refuse(field + ".pose.orientation", listText({o.x, o.y, o.z, o.w}),
           "must be a unit quaternion [x, y, z, w] (its norm within 1e-3 of 1; no rotation: w 1)");
  c.pose = Eigen::Translation3d(position - grid_offset) * q.normalized();
  try
  {
    validateCollider(c, field, dimension);
  }
  catch (const std::invalid_argument& error)
  {
    throw std::invalid_argument(std::string(error.what()) + " (of the shape at its pose, in the grid's coordinates)");
  }
  return c;
}

void nameColliders(std::vector<Collider>& colliders)
{
  for (size_t i = 0; i < colliders.size(); ++i)
    if (colliders[i].id.empty())
      colliders[i].id = "collider_" + std::to_string(i);
  for (size_t i = 0; i < colliders.size(); ++i)
    for (size_t j = 0; j < i; ++j)
      if (colliders[i].id == colliders[j].id)
        rejectParameter("colliders[" + std::to_string(i) + "].id", "'" + colliders[i].id + "'",
                        "is the id of colliders[" + std::to_string(j) +
                            "] too: each collider needs its own (a collider without one is collider_<index>)");
}

ColliderChange changeColliders(const std::vector<Collider>& current, const SetColliders::Request& request,
                               const Eigen::Vector3d& grid_offset, int dimension)
{
  const auto indexOf = [](const std::vector<Collider>& colliders, const std::string& id) {
    for (size_t i = 0; i < colliders.size(); ++i)
      if (colliders[i].id == id)
        return static_cast<int>(i);
    return -1;
  };
  if (request.operation != SetColliders::Request::SET && request.operation != SetColliders::Request::UPDATE)
    refuse("operation", static_cast<int>(request.operation), "must be SET (0: the colliders become those given) or UPDATE "
                                                             "(1: those given added or replaced by id, those in `remove` removed)");
  if (request.operation == SetColliders::Request::SET && !request.remove.empty())
    refuse("remove", "'" + request.remove.front() + "'", "must be empty with SET (the colliders given are the whole set)");
  std::vector<Collider> given;
  for (size_t i = 0; i < request.colliders.size(); ++i)
  {
    given.push_back(colliderFromMessage(request.colliders[i], "colliders[" + std::to_string(i) + "]", grid_offset, dimension));
    const int twice = indexOf(given, given.back().id);
    if (twice < static_cast<int>(i))
      refuse("colliders[" + std::to_string(i) + "].id", "'" + given.back().id + "'",
             "is also the id of colliders[" + std::to_string(twice) + "]: each id once");
  }
  ColliderChange change;
  if (request.operation == SetColliders::Request::SET)
  {
    change.colliders = given;
    change.keep.assign(given.size(), -1);
    return change;
  }
  std::vector<std::string> ids;
  for (const Collider& c : current)
    ids.push_back(c.id);
  for (size_t r = 0; r < request.remove.size(); ++r)
  {
    const std::string& id = request.remove[r];
    const std::string field = "remove[" + std::to_string(r) + "]";
    if (std::find(request.remove.begin(), request.remove.begin() + r, id) != request.remove.begin() + r)
      refuse(field, "'" + id + "'", "is listed twice: each id once");
    if (indexOf(given, id) >= 0)
      refuse(field, "'" + id + "'", "is also among the colliders given: replace or remove it, not both");
    if (indexOf(current, id) < 0)
    {
      std::string known;
      for (const std::string& k : ids)
        known += (known.empty() ? "'" : ", '") + k + "'";
      refuse(field, "'" + id + "'", "is not a collider's id (the colliders: " + (known.empty() ? "none" : known) + ")");
    }
  }
  for (size_t i = 0; i < current.size(); ++i)
    if (std::find(request.remove.begin(), request.remove.end(), current[i].id) == request.remove.end())
    {
      const int replaced = indexOf(given, current[i].id);
      change.colliders.push_back(replaced >= 0 ? given[replaced] : current[i]);
      change.keep.push_back(replaced >= 0 ? -1 : static_cast<int>(i));
    }
  for (const Collider& c : given)
    if (indexOf(current, c.id) < 0)
    {
      change.colliders.push_back(c);
      change.keep.push_back(-1);
    }
  return change;
}

}  // namespace modal_mass_spring
