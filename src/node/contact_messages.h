// The colliders as rviz markers and contact forces as wrenches (contact.h's ROS face).
#pragma once

#include "modal_mass_spring/contact.h"

#include <geometry_msgs/WrenchStamped.h>
#include <ros/time.h>
#include <visualization_msgs/MarkerArray.h>

#include <string>

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

}  // namespace modal_mass_spring
