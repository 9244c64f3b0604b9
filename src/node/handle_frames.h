// Handles that follow TF frames: each handle's particles keep the offsets they had in its frame at
// the frame's first lookup, and move with the frame, interpolated over the steps of a tick.
#pragma once

#include "modal_mass_spring/grid.h"
#include "modal_mass_spring/handles.h"
#include "modal_mass_spring/simulation.h"
#include "node_params.h"

#include <Eigen/Core>

#include <optional>
#include <string>
#include <vector>

namespace modal_mass_spring
{

// A handle's (or a collider's) frame whose latest pose is older than this (s, ROS time) is stale: its
// broadcaster has stopped, and its particles (its collider) hold where they are until it comes back.
constexpr double kStaleHandleFrameSeconds = 1.0;

class HandleFrames
{
public:
  // `x_ref`: the positions the handles rest at (grid coordinates); `grid_offset`: where the grid's
  // origin is in the fixed frame the poses are given in.
  HandleFrames(const std::vector<HandleParam>& handles, const Grid& grid, const Eigen::VectorXd& x_ref,
               const Eigen::Vector3d& grid_offset);
  HandleFrames() = default;  // no handles

  bool empty() const { return handles_.empty(); }
  const std::string& frame(size_t h) const { return handles_[h].frame; }
  size_t size() const { return handles_.size(); }

  // This tick's target pose of each frame in the fixed frame; nothing: not usable, held where it is,
  // for the reason in `problems` (empty or "": "not available"). A frame's first pose fixes its
  // particles' offsets (no motion on that tick). A pose the cloth cannot follow is refused and held:
  // on a 2D grid one that turns the frame out of the x-z plane; on any grid one that moves it more
  // than kMaxJumpPerTick or turns it more than kMaxTurnPerTick since the last tick (a flipping or
  // glitching frame: a TF sample 1e12 m away). A refused jump or turn that stays (the next tick's
  // pose within those limits of it) is a new grip: the particles keep where they are and follow the
  // frame from there, as at a first lookup.
  void setTargets(const std::vector<std::optional<FramePose>>& poses, const std::vector<std::string>& problems = {});
  static constexpr double kMaxJumpPerTick = kMaxFrameJumpPerTick;
  static constexpr double kMaxTurnPerTick = kMaxFrameTurnPerTick;
  // The handle dofs' positions (grid coordinates), velocities and accelerations at the fraction s of
  // a tick lasting `duration` seconds, in Grid::handleDofs() order.
  void motion(double duration, double s, Eigen::VectorXd& x, Eigen::VectorXd& v, Eigen::VectorXd& a) const;
  // When every handle names one frame (the moving-frame formulation): that frame's motion at the
  // fraction s of the tick relative to its pose at the first lookup, in grid coordinates, from the
  // same interpolation as motion(); at rest before the first lookup.
  FrameMotion frameMotion(double duration, double s) const;
  // Hands `simulation` its handles' motion at the fraction s of a tick lasting `duration` seconds, as
  // its handle formulation takes it: the frame's motion (frameMotion) in the moving frame, every
  // handle particle's (motion) with constraint modes. Throws what the simulation refuses.
  void drive(Simulation& simulation, double duration, double s) const;
  // The tick of `duration` seconds ended at the fraction s: the handles are there now, and moved at
  // this tick's velocities, which the next tick's accelerations start from.
  void finishTick(double duration, double s);
  // Every frame holds where it is now, at rest (stepping with no lookup: ~step while paused).
  void hold();
  // Back to the start (Simulation::reset puts the handles at rest at x_ref); offsets are kept.
  void reset();
  // Empty, or which frames are held and why (not available, stale, refused).
  std::string status() const;
  // The frames refused at the last tick (a turn out of the plane or too fast), one line each.
  std::vector<std::string> refusals() const;
  // Whether handle h follows its frame: it was looked up at the last tick.
  bool following(size_t h) const { return handles_[h].found && !handles_[h].missing; }
  // Whether handle h's frame was ever looked up.
  bool everFound(size_t h) const { return handles_[h].found; }
  size_t particles(size_t h) const { return static_cast<size_t>(handles_[h].start.cols()); }
  // Where handle h's frame is now (the fixed frame; the pose its particles follow, held while the frame
  // is missing); meaningful once everFound(h).
  const FramePose& current(size_t h) const { return handles_[h].current; }
  // Handle h's frame origin now, in grid coordinates.
  Eigen::Vector3d originInGrid(size_t h) const { return handles_[h].current.translation - grid_offset_; }
  // Puts handle h's frame at `pose` now, with no motion over the next tick (a state restored with
  // its frames' poses); offsets are kept. A frame never looked up is left as it is.
  void place(size_t h, const FramePose& pose);
  // Handle h grips its particles where they are now (`points`, the fixed frame, a column each) with
  // its frame at `pose` (a grasp while the simulation runs). With `snap` their centre moves onto the
  // frame's origin over the next tick, their arrangement kept; else they keep their offsets. A reset
  // puts them back at x_ref, gripped anew at the frame's next lookup.
  void grip(size_t h, const FramePose& pose, const Eigen::Matrix3Xd& points, bool snap);
  // Handle h takes over handle k of `from` as it is (the other grips when the held set changes).
  void adopt(size_t h, const HandleFrames& from, size_t k) { handles_[h] = from.handles_[k]; }

private:
  struct Handle
  {
    std::string frame;
    Eigen::Matrix3Xd start;    // the particles at x_ref, in the fixed frame
    Eigen::Matrix3Xd offsets;  // in the frame, from its first pose
    bool found = false;        // the frame was looked up at least once
    bool missing = false;      // it could not be used this tick
    std::string problem;       // why, when missing
    bool refused = false;      // its pose this tick was refused (problem says why)
    std::optional<FramePose> refused_pose;  // a large turn refused at the last tick
    bool gripped_live = false;  // by grip(): its offsets are not the first lookup's
    FramePose start_pose, current, target;
    // The frame's velocity and angular velocity (world) over the last tick: a tick moves the frame at
    // a constant velocity, so its change from tick to tick is an acceleration over the next tick, the
    // inertial load a cloth carried by the gripper feels (zero after a jump to a new pose).
    FrameVelocity last;
  };
  // This tick's change of the handle's frame velocity since the last tick, over the tick's
  // `duration`: its acceleration (linear) and angular acceleration (angular).
  static FrameVelocity tickAcceleration(const Handle& handle, double duration);
  // Why the cloth cannot follow `pose` from the handle's current one, or empty.
  std::string refusal(const Handle& handle, const FramePose& pose) const;
  // Takes the particles' offsets anew at `pose`, where they are now (no jump).
  static void regrip(Handle& handle, const FramePose& pose);

  int dimension_ = 3;
  Eigen::Vector3d grid_offset_;
  std::vector<Handle> handles_;
};

}  // namespace modal_mass_spring
