// The frames' motion as the core's handle motion: rigid offsets, interpolated poses.
#include "handle_frames.h"

namespace modal_mass_spring
{

HandleFrames::HandleFrames(const std::vector<HandleParam>& handles, const Grid& grid, const Eigen::VectorXd& x_ref,
                           const Eigen::Vector3d& grid_offset)
  : dimension_(grid.dimension()), grid_offset_(grid_offset)
{
  const Eigen::Matrix3Xd points = grid.toPoints(x_ref);
  for (const auto& param : handles)
  {
    Handle handle;
    handle.frame = param.frame;
    handle.start.resize(3, static_cast<Eigen::Index>(param.particles.size()));
    for (size_t k = 0; k < param.particles.size(); ++k)
      handle.start.col(static_cast<Eigen::Index>(k)) = points.col(param.particles[k]) + grid_offset;
    handles_.push_back(handle);
  }
}

void HandleFrames::setTargets(const std::vector<std::optional<FramePose>>& poses)
{
  for (size_t h = 0; h < handles_.size(); ++h)
  {
    Handle& handle = handles_[h];
    handle.missing = !poses[h];
    if (!poses[h])
    {
      handle.target = handle.current;  // held
      continue;
    }
    if (!handle.found)
    {
      // The particles' start positions in the frame's first pose.
      const FramePose& pose = *poses[h];
      handle.offsets = pose.rotation.conjugate().toRotationMatrix() * (handle.start.colwise() - pose.translation);
      handle.start_pose = handle.current = pose;
      handle.found = true;
    }
    handle.target = *poses[h];
  }
}

void HandleFrames::motion(double duration, double s, Eigen::VectorXd& x, Eigen::VectorXd& v, Eigen::VectorXd& a) const
{
  Eigen::Index count = 0;
  for (const auto& handle : handles_)
    count += handle.start.cols();
  x.resize(dimension_ * count);
  v.setZero(dimension_ * count);
  a.setZero(dimension_ * count);
  const std::vector<int> rows = gridAxes(dimension_);
  Eigen::Index dof = 0;
  for (const auto& handle : handles_)
  {
    RigidPointMotion m;
    if (handle.found)
    {
      m = interpolateRigidMotion(handle.offsets, handle.current, handle.target, duration, s);
    }
    else
    {
      m.position = handle.start;
      m.velocity = m.acceleration = Eigen::Matrix3Xd::Zero(3, handle.start.cols());
    }
    for (Eigen::Index p = 0; p < handle.start.cols(); ++p)
      for (int r : rows)
      {
        x[dof] = m.position(r, p) - grid_offset_[r];
        v[dof] = m.velocity(r, p);
        a[dof] = m.acceleration(r, p);
        ++dof;
      }
  }
}

FrameMotion HandleFrames::frameMotion(double duration, double s) const
{
  const Handle& handle = handles_.front();
  if (!handle.found)
    return FrameMotion{};
  // The poses in grid coordinates: the grid's origin sits at grid_offset_ in the fixed frame.
  auto inGrid = [this](FramePose pose) {
    pose.translation -= grid_offset_;
    return pose;
  };
  return interpolateFrameMotion(inGrid(handle.start_pose), inGrid(handle.current), inGrid(handle.target), duration, s);
}

void HandleFrames::finishTick(double s)
{
  for (auto& handle : handles_)
  {
    handle.current.translation = (1.0 - s) * handle.current.translation + s * handle.target.translation;
    handle.current.rotation = handle.current.rotation.slerp(s, handle.target.rotation);
  }
}

void HandleFrames::reset()
{
  for (auto& handle : handles_)
    handle.current = handle.target = handle.start_pose;
}

std::string HandleFrames::status() const
{
  std::string held;
  for (const auto& handle : handles_)
    if (handle.missing)
      held += (held.empty() ? "held: frame '" : ", frame '") + handle.frame + "'";
  return held.empty() ? "" : held + " not available";
}

}  // namespace modal_mass_spring
