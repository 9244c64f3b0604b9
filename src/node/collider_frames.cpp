// The colliders' frames as their poses in the grid's coordinates (collider_frames.h).
#include "collider_frames.h"

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

void ColliderFrames::setTargets(const std::vector<std::optional<FramePose>>& poses, const std::vector<std::string>& problems)
{
  for (size_t k = 0; k < colliders_.size(); ++k)
  {
    Entry& entry = colliders_[k];
    entry.missing = !poses[k];
    entry.problem = k < problems.size() && !problems[k].empty() ? problems[k] : "not available";
    if (!poses[k])
    {
      entry.target = entry.current;  // held where it is
      continue;
    }
    if (!entry.found)
    {
      entry.current = *poses[k];
      entry.found = true;
    }
    entry.target = *poses[k];
  }
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
  return held;
}

}  // namespace modal_mass_spring
