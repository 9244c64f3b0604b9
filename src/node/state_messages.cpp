// SimulationState <-> SavedState.
#include "state_messages.h"

#include "grid_messages.h"

#include "modal_mass_spring/parameter_error.h"

#include <string>
#include <vector>

namespace modal_mass_spring
{
namespace
{

std::vector<double> values(const Eigen::VectorXd& v) { return std::vector<double>(v.data(), v.data() + v.size()); }

Eigen::VectorXd vector(const std::vector<double>& v)
{
  return Eigen::Map<const Eigen::VectorXd>(v.data(), static_cast<Eigen::Index>(v.size()));
}

Eigen::Isometry3d isometry(const geometry_msgs::Pose& pose)
{
  const FramePose p = framePose(pose);
  Eigen::Isometry3d result = Eigen::Isometry3d::Identity();
  result.linear() = p.rotation.toRotationMatrix();
  result.translation() = p.translation;
  return result;
}

}  // namespace

geometry_msgs::Pose poseMessage(const FramePose& pose)
{
  geometry_msgs::Pose m;
  m.position.x = pose.translation.x(), m.position.y = pose.translation.y(), m.position.z = pose.translation.z();
  m.orientation.x = pose.rotation.x(), m.orientation.y = pose.rotation.y(), m.orientation.z = pose.rotation.z();
  m.orientation.w = pose.rotation.w();
  return m;
}

FramePose framePose(const geometry_msgs::Pose& pose)
{
  FramePose p;
  p.translation = Eigen::Vector3d(pose.position.x, pose.position.y, pose.position.z);
  p.rotation = Eigen::Quaterniond(pose.orientation.w, pose.orientation.x, pose.orientation.y, pose.orientation.z);
  if (p.rotation.coeffs().allFinite() && p.rotation.norm() > 0.0)
    p.rotation.normalize();
  return p;
}

SavedState stateMessage(const SimulationState& state, const HandleFrames& frames, const Eigen::Matrix3Xd& points,
                        const Eigen::Vector3d& offset)
{
  SavedState m;
  m.method = toString(state.method);
  m.time_step = state.time_step;
  m.step_count = state.step_count;
  m.time = state.step_count * state.time_step;
  m.coordinates = values(state.coordinates.q);
  m.velocities = values(state.coordinates.v);
  m.accelerations = values(state.coordinates.a);
  m.offset = values(state.offset);
  m.handle_displacement = values(state.handles.displacement);
  m.handle_velocity = values(state.handles.velocity);
  m.handle_acceleration = values(state.handles.acceleration);
  // B's motion in the order of msg/SavedState.msg: translation, rotation row by row, the rest.
  const FrameMotion& f = state.frame;
  m.frame_motion.assign(f.translation.data(), f.translation.data() + 3);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      m.frame_motion.push_back(f.rotation(r, c));
  for (const Eigen::Vector3d* v : {&f.velocity, &f.acceleration, &f.angular_velocity, &f.angular_acceleration})
    m.frame_motion.insert(m.frame_motion.end(), v->data(), v->data() + 3);
  for (const Eigen::Isometry3d& pose : state.collider_poses)
  {
    FramePose p;
    p.translation = pose.translation();
    p.rotation = Eigen::Quaterniond(pose.linear());
    m.collider_poses.push_back(poseMessage(p));
  }
  m.colliders_active.assign(state.colliders_active.begin(), state.colliders_active.end());
  m.colliders_moved = state.colliders_moved;
  m.external_force = values(state.external_force);
  m.anchor = values(state.anchor);
  m.anchor_handles = values(state.anchor_handles);
  m.start_energy = state.start_energy;
  m.energy_scale = state.energy_scale;
  m.handles_moved = state.handles_moved;
  m.diverged = state.diverged;
  m.divergence_message = state.divergence_message;
  for (size_t h = 0; h < frames.size(); ++h)
  {
    m.handle_frames.push_back(frames.frame(h));
    m.handle_frame_poses.push_back(poseMessage(frames.current(h)));
  }
  for (Eigen::Index p = 0; p < points.cols(); ++p)
    m.positions.push_back(point(points.col(p) + offset));
  return m;
}

SimulationState simulationState(const SavedState& m, const HandleFrames& frames)
{
  SimulationState s;
  try
  {
    s.method = parseMethod(m.method);
  }
  catch (const std::invalid_argument&)
  {
    rejectParameter("state.method", "'" + m.method + "'", "must be one of " + methodList());
  }
  s.time_step = m.time_step;
  s.step_count = m.step_count;
  s.coordinates.q = vector(m.coordinates);
  s.coordinates.v = vector(m.velocities);
  s.coordinates.a = vector(m.accelerations);
  s.offset = vector(m.offset);
  s.handles.displacement = vector(m.handle_displacement);
  s.handles.velocity = vector(m.handle_velocity);
  s.handles.acceleration = vector(m.handle_acceleration);
  if (m.frame_motion.size() != 24)
    rejectParameter("state.frame_motion", std::to_string(m.frame_motion.size()) + " values",
                    "must have 24: translation (3), rotation (9), velocity, acceleration, angular velocity and "
                    "angular acceleration (3 each)");
  const Eigen::VectorXd f = vector(m.frame_motion);
  if (!f.allFinite())
    rejectParameter("state.frame_motion", "a non-finite value", "must be finite");
  s.frame.translation = f.segment<3>(0);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      s.frame.rotation(r, c) = f[3 + 3 * r + c];
  s.frame.velocity = f.segment<3>(12);
  s.frame.acceleration = f.segment<3>(15);
  s.frame.angular_velocity = f.segment<3>(18);
  s.frame.angular_acceleration = f.segment<3>(21);
  for (const geometry_msgs::Pose& pose : m.collider_poses)
    s.collider_poses.push_back(isometry(pose));
  s.colliders_active.assign(m.colliders_active.begin(), m.colliders_active.end());
  s.colliders_moved = m.colliders_moved;
  s.external_force = vector(m.external_force);
  s.anchor = vector(m.anchor);
  s.anchor_handles = vector(m.anchor_handles);
  s.start_energy = m.start_energy;
  s.energy_scale = m.energy_scale;
  s.handles_moved = m.handles_moved;
  s.diverged = m.diverged;
  s.divergence_message = m.divergence_message;
  // The handle frames must be the node's, in its order (empty: where the node's frames are now).
  if (!m.handle_frames.empty() || !m.handle_frame_poses.empty())
  {
    bool same = m.handle_frames.size() == frames.size() && m.handle_frame_poses.size() == frames.size();
    for (size_t h = 0; same && h < frames.size(); ++h)
      same = m.handle_frames[h] == frames.frame(h);
    if (!same)
      rejectParameter("state.handle_frames", std::to_string(m.handle_frames.size()) + " frames",
                      "must be the node's handle frames in the order of parameter handles, one pose each (or none)");
    for (size_t h = 0; h < frames.size(); ++h)
    {
      const FramePose p = framePose(m.handle_frame_poses[h]);
      if (!p.translation.allFinite() || !p.rotation.coeffs().allFinite())
        rejectParameter("state.handle_frame_poses[" + std::to_string(h) + "]", "a non-finite value", "must be finite");
    }
  }
  return s;
}

void placeHandleFrames(const SavedState& m, HandleFrames& frames)
{
  for (size_t h = 0; h < m.handle_frame_poses.size() && h < frames.size(); ++h)
    frames.place(h, framePose(m.handle_frame_poses[h]));
}

}  // namespace modal_mass_spring
