// Handles that follow TF frames: each handle's particles keep the offsets they had in its frame at
// the frame's first lookup, and move with the frame, interpolated over the steps of a tick.
#pragma once

#include "modal_mass_spring/grid.h"
#include "modal_mass_spring/handles.h"
#include "node_params.h"

#include <Eigen/Core>

#include <optional>
#include <string>
#include <vector>

namespace modal_mass_spring
{

class HandleFrames
{
public:
  // `x_ref`: the positions the handles rest at (grid coordinates); `grid_offset`: where the grid's
  // origin is in the fixed frame the poses are given in.
  HandleFrames(const std::vector<HandleParam>& handles, const Grid& grid, const Eigen::VectorXd& x_ref,
               const Eigen::Vector3d& grid_offset);

  bool empty() const { return handles_.empty(); }
  const std::string& frame(size_t h) const { return handles_[h].frame; }
  size_t size() const { return handles_.size(); }

  // This tick's target pose of each frame in the fixed frame; nothing: not available, held where it is.
  // A frame's first pose fixes its particles' offsets (no motion on that tick).
  void setTargets(const std::vector<std::optional<FramePose>>& poses);
  // The handle dofs' positions (grid coordinates), velocities and accelerations at the fraction s of
  // a tick lasting `duration` seconds, in Grid::handleDofs() order.
  void motion(double duration, double s, Eigen::VectorXd& x, Eigen::VectorXd& v, Eigen::VectorXd& a) const;
  // When every handle names one frame (the moving-frame formulation): that frame's motion at the
  // fraction s of the tick relative to its pose at the first lookup, in grid coordinates, from the
  // same interpolation as motion(); at rest before the first lookup.
  FrameMotion frameMotion(double duration, double s) const;
  // The tick's stepping ended at the fraction s: the handles are there now.
  void finishTick(double s);
  // Back to the start (Simulation::reset puts the handles at rest at x_ref); offsets are kept.
  void reset();
  // Empty, or which frames are held because they could not be looked up.
  std::string status() const;
  // Whether handle h follows its frame: it was looked up at the last tick.
  bool following(size_t h) const { return handles_[h].found && !handles_[h].missing; }
  // Whether handle h's frame was ever looked up.
  bool everFound(size_t h) const { return handles_[h].found; }
  size_t particles(size_t h) const { return static_cast<size_t>(handles_[h].start.cols()); }

private:
  struct Handle
  {
    std::string frame;
    Eigen::Matrix3Xd start;    // the particles at x_ref, in the fixed frame
    Eigen::Matrix3Xd offsets;  // in the frame, from its first pose
    bool found = false;        // the frame was looked up at least once
    bool missing = false;      // it could not be looked up this tick
    FramePose start_pose, current, target;
  };
  int dimension_;
  Eigen::Vector3d grid_offset_;
  std::vector<Handle> handles_;
};

}  // namespace modal_mass_spring
