// The colliders as rviz markers and contact forces as wrenches.
#include "contact_messages.h"

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
