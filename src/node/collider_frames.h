// Colliders that follow TF frames (a collider map's `frame`): each one's pose in the grid's
// coordinates, from its frame's latest pose, interpolated over the steps of a tick as the handles are.
#pragma once

#include "modal_mass_spring/contact.h"
#include "modal_mass_spring/handles.h"

#include <Eigen/Geometry>

#include <optional>
#include <string>
#include <vector>

namespace modal_mass_spring
{

class ColliderFrames
{
public:
  // The colliders with a `frame` among `colliders`; `grid_offset`: where the grid's origin is in the
  // fixed frame the poses are given in.
  ColliderFrames(const std::vector<Collider>& colliders, const Eigen::Vector3d& grid_offset);

  bool empty() const { return colliders_.empty(); }
  size_t size() const { return colliders_.size(); }
  // Which collider (its index in `colliders`) the k-th frame collider is, and its frame.
  int collider(size_t k) const { return colliders_[k].index; }
  const std::string& frame(size_t k) const { return colliders_[k].frame; }
  bool everFound(size_t k) const { return colliders_[k].found; }
  bool following(size_t k) const { return colliders_[k].found && !colliders_[k].missing; }

  // This tick's pose of each frame in the fixed frame; nothing: not usable (the collider keeps its
  // last pose, or stays inactive before its first), for the reason in `problems`. A frame's first
  // pose places its collider there for the whole tick (it appears; no sweep).
  // A frame that jumps since the last tick, farther than kMaxJumpPerTick or turned more than
  // kMaxTurnPerTick, is refused and its collider held where it was (a glitching frame: swept there
  // over one tick's steps it would throw the cloth or pass through it, since contact is found at
  // each step's end). A jump that stays (the next tick's pose within those limits of the refused
  // one) is a new placement: the collider is put there at the tick's start without a sweep
  // (placed(k)), as at a first pose, and follows the frame from there.
  void setTargets(const std::vector<std::optional<FramePose>>& poses, const std::vector<std::string>& problems);
  static constexpr double kMaxJumpPerTick = kMaxFrameJumpPerTick;
  static constexpr double kMaxTurnPerTick = kMaxFrameTurnPerTick;
  // Frame collider k was placed anew by the last setTargets (a jump that stayed): to be put at
  // pose(k, 0) without a sweep (Simulation::placeCollider).
  bool placed(size_t k) const { return colliders_[k].placed; }
  // The refusals of the last setTargets, one line each (for a warning).
  std::vector<std::string> refusals() const;
  // Frame collider k's pose in the grid's coordinates at the fraction s of the tick (translation
  // linear, rotation slerp); nothing before its frame's first pose.
  std::optional<Eigen::Isometry3d> pose(size_t k, double s) const;
  // The tick's stepping ended at the fraction s: the colliders are there now.
  void finishTick(double s);
  // Empty, or which collider frames are held and why.
  std::string status() const;

private:
  struct Entry
  {
    int index = 0;
    std::string frame;
    bool found = false, missing = false;
    bool refused = false, placed = false;  // this tick: a jump refused, a jump that stayed placed
    std::string problem;
    FramePose current, target;  // in the fixed frame
    std::optional<FramePose> refused_pose;  // the last tick's refused jump
  };
  Eigen::Vector3d grid_offset_;
  std::vector<Entry> colliders_;
};

}  // namespace modal_mass_spring
