// The colliders' frames as their poses in the grid's coordinates (collider_frames.h).
#include "collider_frames.h"

#include <cstdio>

namespace modal_mass_spring
{

ColliderFrames::ColliderFrames(const std::vector<Collider>& colliders, const Eigen::Vector3d& grid_offset)
  : grid_offset_(grid_offset)
{
  for (size_t i = 0; i < colliders.size(); ++i)
    if (!colliders[i].frame.empty())
    {
      Entry entry;
      entry.index = static_cast<int>(i);
      entry.frame = colliders[i].frame;
      colliders_.push_back(entry);
    }
}

namespace
{

constexpr double kPi = 3.14159265358979323846;

// Empty, or why `to` is too far from `from` for one tick.
std::string jump(const FramePose& from, const FramePose& to)
{
  const double distance = (to.translation - from.translation).norm();
  const double turn = from.rotation.angularDistance(to.rotation);
  if (distance <= ColliderFrames::kMaxJumpPerTick && turn <= ColliderFrames::kMaxTurnPerTick)
    return "";
  char text[300];
  std::snprintf(text, sizeof text,
                "refused: it jumped %.3g m and turned %.0f degrees since the last tick, above %.3g m or %.0f degrees "
                "(a glitching frame; held at its last pose, it is placed there anew if the frame stays)",
                distance, turn * 180.0 / kPi, ColliderFrames::kMaxJumpPerTick, ColliderFrames::kMaxTurnPerTick * 180.0 / kPi);
  return text;
}

}  // namespace

void ColliderFrames::setTargets(const std::vector<std::optional<FramePose>>& poses, const std::vector<std::string>& problems)
{
  for (size_t k = 0; k < colliders_.size(); ++k)
  {
    Entry& entry = colliders_[k];
    entry.missing = !poses[k];
    entry.refused = entry.placed = false;
    entry.problem = k < problems.size() && !problems[k].empty() ? problems[k] : "not available";
    if (!poses[k])
    {
      entry.target = entry.current;  // held where it is
      entry.refused_pose.reset();
      continue;
    }
    const FramePose& pose = *poses[k];
    if (!entry.found)
    {
      entry.current = pose;
      entry.found = true;
    }
    std::string why = jump(entry.current, pose);
    if (!why.empty() && entry.refused_pose && jump(*entry.refused_pose, pose).empty())
    {
      // Not a glitch: the frame stays where it jumped. Placed there, not swept there.
      entry.current = pose;
      entry.placed = true;
      why.clear();
    }
    entry.refused_pose.reset();
    if (!why.empty())
    {
      entry.refused_pose = pose;
      entry.refused = true;
      entry.problem = why;
      entry.target = entry.current;  // held
      continue;
    }
    entry.target = pose;
  }
}

std::vector<std::string> ColliderFrames::refusals() const
{
  std::vector<std::string> lines;
  for (const Entry& entry : colliders_)
    if (entry.refused)
      lines.push_back("collider " + std::to_string(entry.index) + " frame '" + entry.frame + "' " + entry.problem);
  return lines;
}

std::optional<Eigen::Isometry3d> ColliderFrames::pose(size_t k, double s) const
{
  const Entry& entry = colliders_[k];
  if (!entry.found)
    return std::nullopt;
  const Eigen::Vector3d translation = (1.0 - s) * entry.current.translation + s * entry.target.translation;
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() = entry.current.rotation.slerp(s, entry.target.rotation).toRotationMatrix();
  pose.translation() = translation - grid_offset_;  // the grid's origin sits at grid_offset_
  return pose;
}

void ColliderFrames::finishTick(double s)
{
  for (Entry& entry : colliders_)
  {
    entry.current.translation = (1.0 - s) * entry.current.translation + s * entry.target.translation;
    entry.current.rotation = entry.current.rotation.slerp(s, entry.target.rotation);
  }
}

std::string ColliderFrames::status() const
{
  std::string held;
  for (const Entry& entry : colliders_)
    if (entry.missing)
      held += (held.empty() ? "" : ", ") + std::string("collider ") + std::to_string(entry.index) + " frame '" +
              entry.frame + "' " + entry.problem + (entry.found ? " (kept at its last pose)" : " (inactive until found)");
    else if (entry.refused)
      held += (held.empty() ? "" : ", ") + std::string("collider ") + std::to_string(entry.index) + " frame '" +
              entry.frame + "' " + entry.problem;
  return held;
}

}  // namespace modal_mass_spring
