// The frames' motion as the core's handle motion: rigid offsets, interpolated poses.
#include "handle_frames.h"

#include <cmath>
#include <cstdio>

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

namespace
{

constexpr double kPi = 3.14159265358979323846;

FramePose compose(const FramePose& a, const FramePose& b)
{
  FramePose c;
  c.rotation = a.rotation * b.rotation;
  c.translation = a.rotation * b.translation + a.translation;
  return c;
}

FramePose inverse(const FramePose& a)
{
  FramePose i;
  i.rotation = a.rotation.conjugate();
  i.translation = -(i.rotation * a.translation);
  return i;
}

// `b` is within one tick's motion of `a`: a frame that jumped and stays there moves on from it.
bool withinATick(const FramePose& a, const FramePose& b)
{
  return (a.translation - b.translation).norm() <= HandleFrames::kMaxJumpPerTick &&
         a.rotation.angularDistance(b.rotation) <= HandleFrames::kMaxTurnPerTick;
}

}  // namespace

std::string HandleFrames::refusal(const Handle& handle, const FramePose& pose) const
{
  char text[200];
  if (dimension_ == 2)
  {
    // The particles turn with the frame relative to its first pose: only a turn about y (the normal
    // of the grid's x-z plane) keeps them in the plane; the rest would be projected onto it.
    const Eigen::Matrix3d r = (pose.rotation * handle.start_pose.rotation.conjugate()).toRotationMatrix();
    const double off_plane = std::abs(r(0, 1)) + std::abs(r(1, 0)) + std::abs(r(1, 2)) + std::abs(r(2, 1));
    if (off_plane > 1e-6)
      return "refused: it turns out of the 2D grid's x-z plane (a 2D grid's frame may only turn about y)";
  }
  const double jump = (pose.translation - handle.current.translation).norm();
  if (!(jump <= kMaxJumpPerTick))
  {
    std::snprintf(text, sizeof text,
                  "refused: it jumped %.3g m since the last tick, above %.3g m (a glitching frame; kept near that pose "
                  "for a tick, it is gripped anew)",
                  jump, kMaxJumpPerTick);
    return text;
  }
  const double turn = handle.current.rotation.angularDistance(pose.rotation);
  if (turn > kMaxTurnPerTick)
  {
    std::snprintf(text, sizeof text,
                  "refused: it turned %.0f degrees since the last tick, above %.0f (a flipping or glitching frame; "
                  "kept near that pose for a tick, it is gripped anew)",
                  turn * 180.0 / kPi, kMaxTurnPerTick * 180.0 / kPi);
    return text;
  }
  return "";
}

void HandleFrames::regrip(Handle& handle, const FramePose& pose)
{
  // The particles where they are now, in the new pose; the motion relative to the start pose
  // continues from where it is (start' = start current^-1 pose).
  const Eigen::Matrix3Xd now = (handle.current.rotation.toRotationMatrix() * handle.offsets).colwise() +
                               handle.current.translation;
  handle.offsets = pose.rotation.conjugate().toRotationMatrix() * (now.colwise() - pose.translation);
  handle.start_pose = compose(compose(handle.start_pose, inverse(handle.current)), pose);
  handle.current = pose;
  handle.last = FrameVelocity{};
}

void HandleFrames::setTargets(const std::vector<std::optional<FramePose>>& poses, const std::vector<std::string>& problems)
{
  for (size_t h = 0; h < handles_.size(); ++h)
  {
    Handle& handle = handles_[h];
    handle.missing = !poses[h];
    handle.refused = false;
    handle.problem = h < problems.size() && !problems[h].empty() ? problems[h] : "not available";
    if (!poses[h])
    {
      handle.target = handle.current;  // held
      handle.refused_pose.reset();
      continue;
    }
    const FramePose& pose = *poses[h];
    if (!handle.found)
    {
      // The particles' start positions in the frame's first pose.
      handle.offsets = pose.rotation.conjugate().toRotationMatrix() * (handle.start.colwise() - pose.translation);
      handle.start_pose = handle.current = pose;
      handle.last = FrameVelocity{};
      handle.found = true;
    }
    std::string why = refusal(handle, pose);
    const bool in_plane = why.empty() || why.find("x-z plane") == std::string::npos;
    if (!why.empty() && in_plane && handle.refused_pose && withinATick(*handle.refused_pose, pose))
    {
      regrip(handle, pose);  // not a flip or a glitch: the frame stays at its new pose
      why.clear();
    }
    handle.refused_pose.reset();
    if (!why.empty())
    {
      if (in_plane)
        handle.refused_pose = pose;
      handle.missing = handle.refused = true;
      handle.problem = why;
      handle.target = handle.current;  // held
      continue;
    }
    handle.target = pose;
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
      const FrameVelocity change = tickAcceleration(handle, duration);
      const Eigen::Vector3d origin = handle.current.translation + s * (handle.target.translation - handle.current.translation);
      for (Eigen::Index p = 0; p < m.position.cols(); ++p)
        m.acceleration.col(p) += change.linear + change.angular.cross(m.position.col(p) - origin);
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
  const FramePose start = inGrid(handle.start_pose);
  FrameMotion m = interpolateFrameMotion(start, inGrid(handle.current), inGrid(handle.target), duration, s);
  // The frame's origin accelerates at the tick's change of velocity, and the frame turns about it.
  const FrameVelocity change = tickAcceleration(handle, duration);
  m.angular_acceleration = change.angular;
  m.acceleration += change.linear - change.angular.cross(m.rotation * start.translation);
  return m;
}

FrameVelocity HandleFrames::tickAcceleration(const Handle& handle, double duration)
{
  // A tick moves the frame at a constant velocity: the change from the last tick's, spread over this one.
  const FrameVelocity now = interpolationVelocity(handle.current, handle.target, duration);
  return {(now.linear - handle.last.linear) / duration, (now.angular - handle.last.angular) / duration};
}

void HandleFrames::drive(Simulation& simulation, double duration, double s) const
{
  if (handles_.empty())
    return;
  if (simulation.handleFormulation() == HandleFormulation::MovingFrame)
  {
    simulation.setHandleFrameMotion(frameMotion(duration, s));
    return;
  }
  Eigen::VectorXd x, v, a;
  motion(duration, s, x, v, a);
  simulation.setHandleMotion(x, v, a);
}

void HandleFrames::finishTick(double duration, double s)
{
  for (auto& handle : handles_)
  {
    if (s > 0.0)  // a tick with no step moved nothing
      handle.last = interpolationVelocity(handle.current, handle.target, duration);
    handle.current.translation = (1.0 - s) * handle.current.translation + s * handle.target.translation;
    handle.current.rotation = handle.current.rotation.slerp(s, handle.target.rotation);
  }
}

void HandleFrames::hold()
{
  for (auto& handle : handles_)
  {
    handle.target = handle.current;
    handle.last = FrameVelocity{};
  }
}

void HandleFrames::place(size_t h, const FramePose& pose)
{
  if (handles_[h].found)
  {
    handles_[h].current = handles_[h].target = pose;
    handles_[h].last = FrameVelocity{};
  }
}

void HandleFrames::grip(size_t h, const FramePose& pose, const Eigen::Matrix3Xd& points, bool snap)
{
  Handle& handle = handles_[h];
  handle.offsets = pose.rotation.conjugate().toRotationMatrix() * (points.colwise() - pose.translation);
  handle.start_pose = handle.current = pose;
  handle.last = FrameVelocity{};
  if (snap)
  {
    // The frame is taken to be where their centre is now; the tick moves it to the frame's pose.
    const Eigen::Vector3d centre = handle.offsets.rowwise().mean();
    handle.offsets.colwise() -= centre;
    handle.current.translation += pose.rotation * centre;
  }
  handle.target = handle.current;
  handle.found = handle.gripped_live = true;
  handle.missing = handle.refused = false;
  handle.refused_pose.reset();
}

void HandleFrames::reset()
{
  for (auto& handle : handles_)
  {
    handle.current = handle.target = handle.start_pose;
    handle.last = FrameVelocity{};
    if (handle.gripped_live)
      handle.found = handle.gripped_live = false;  // its particles are back at x_ref: gripped there anew
  }
}

std::string HandleFrames::status() const
{
  std::string held;
  for (const auto& handle : handles_)
    if (handle.missing)
      held += (held.empty() ? "held: frame '" : ", frame '") + handle.frame + "' " + handle.problem;
  return held;
}

std::vector<std::string> HandleFrames::refusals() const
{
  std::vector<std::string> lines;
  for (const auto& handle : handles_)
    if (handle.refused)
      lines.push_back("handle frame '" + handle.frame + "' " + handle.problem + "; its particles hold where they are");
  return lines;
}

}  // namespace modal_mass_spring
