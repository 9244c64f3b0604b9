// The colliders as rviz markers and contact forces as wrenches (contact.h's ROS face).
#pragma once

#include "modal_mass_spring/PlacedCollider.h"
#include "modal_mass_spring/SetColliders.h"
#include "modal_mass_spring/contact.h"

#include <geometry_msgs/WrenchStamped.h>
#include <ros/time.h>
#include <visualization_msgs/MarkerArray.h>

#include <string>
#include <vector>

namespace modal_mass_spring
{

// One marker per collider (a capsule: a cylinder and two spheres; a plane: a thin 4 m square), in
// namespace `ns`, at its pose in grid coordinates shifted by `offset`, in `frame_id`; a collider not
// active (a frame's, before the frame is found) as DELETE.
visualization_msgs::MarkerArray colliderMarkers(const Contact& contact, const std::string& frame_id,
                                                const Eigen::Vector3d& offset, const std::string& ns,
                                                const ros::Time& stamp);

// A force (N) and its torque about the frame's origin (N m; none: zero) as a wrench.
geometry_msgs::WrenchStamped forceWrench(const Eigen::Vector3d& force, const std::string& frame_id,
                                         const ros::Time& stamp, const Eigen::Vector3d& torque = Eigen::Vector3d::Zero());

// A collider of ~set_colliders as the core's: a BOX (dimensions [x, y, z], full sizes) as a box, a
// SPHERE ([radius]) as a sphere, a CYLINDER ([height, radius], along the pose's z) as the capsule around
// it, shape.type 0 as the plane `plane` of the pose's frame; the pose in the fixed frame, turned into
// the grid's coordinates (the grid's origin at `grid_offset` there). Throws std::invalid_argument
// naming `name`'s field (e.g. "colliders[1] ('table').shape.dimensions") and what is allowed: an
// empty id, an unknown type or CONE, a wrong number of dimensions, a
// dimension not in (0, 1e6] m, a plane whose normal (a, b, c) is zero, a non-finite number, a position
// beyond 1e6 m, an orientation not a unit quaternion, a friction < 0, and what validateCollider
// refuses on a grid of `dimension`.
Collider colliderFromMessage(const PlacedCollider& message, const std::string& name,
                             const Eigen::Vector3d& grid_offset, int dimension);

// Gives each collider without an id the id collider_<index>; throws std::invalid_argument naming
// colliders[i].id for an id given twice (the start-up parameter `colliders`).
void nameColliders(std::vector<Collider>& colliders);

// What a ~set_colliders request makes of the colliders `current`: the new set, and for each of them
// the collider of `current` it continues unchanged, or -1 (Simulation::setColliders's keep). Throws
// std::invalid_argument naming what is wrong, and what is allowed: an unknown operation, an id given
// twice in `colliders` or `remove`, an id both replaced and removed, an unknown id to remove, `remove`
// with SET, and whatever colliderFromMessage refuses.
struct ColliderChange
{
  std::vector<Collider> colliders;
  std::vector<int> keep;
};
ColliderChange changeColliders(const std::vector<Collider>& current, const SetColliders::Request& request,
                               const Eigen::Vector3d& grid_offset, int dimension);

}  // namespace modal_mass_spring
