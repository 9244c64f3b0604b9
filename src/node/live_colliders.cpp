// ~set_colliders: the colliders set, added, replaced or removed by id while the simulation runs. The
// change is made on every track between two steps; from the next step on, the contact pushes the cloth
// out of a collider that appeared on it, as it does for a frame's collider that appears.
#include "contact_messages.h"
#include "simulation_node.h"

namespace modal_mass_spring
{

bool SimulationNode::setColliders(SetColliders::Request& request, SetColliders::Response& response)
{
  boost::recursive_mutex::scoped_lock tuning(tuning_mutex_);  // reconfigure reads the colliders
  ServiceLock lock(*this);
  response.success = false;
  for (const Collider& c : config_.simulation.colliders)
    response.ids.push_back(c.id);
  if (rebuilding())
  {
    response.message = "set_colliders refused: a rebuild or a cubature training is under way (~status REBUILDING), "
                       "built with the colliders it started with; call again after it";
    return true;
  }
  ColliderChange change;
  try
  {
    change = changeColliders(config_.simulation.colliders, request, config_.node.offset,
                             primary().simulation->grid().dimension());
    // Every track runs the same grid and formulation: what the first accepts, the others accept.
    for (Track& track : tracks_)
      track.simulation->setColliders(change.colliders, change.keep);
  }
  catch (const std::invalid_argument& error)
  {
    response.message = std::string("set_colliders refused, nothing changed: ") + error.what();
    return true;
  }
  colliders_set_live_ = true;
  // A rebuild keeps the formulation that runs: with no collider left, `auto` could resolve to the
  // moving frame, which would start the gripper's frame at rest at its first pose.
  config_.simulation.handle_formulation = primary().simulation->handleFormulation();
  accepted_.simulation.handle_formulation = config_.simulation.handle_formulation;
  config_.simulation.colliders = change.colliders;
  accepted_.simulation.colliders = change.colliders;
  collider_frames_ = std::make_unique<ColliderFrames>(config_.simulation.colliders, config_.node.offset);
  for (Track& track : tracks_)
  {
    track.restartAdaptive();  // its checkpoints hold the old colliders
    advertiseWrenches(track, track.contact_force_pubs, "contact_force/collider_", change.colliders.size());
  }
  ++live_builds_;  // the rollouts' workers are built anew with the new colliders
  response.ids.clear();
  std::string ids;
  for (const Collider& c : change.colliders)
  {
    response.ids.push_back(c.id);
    ids += (ids.empty() ? "'" : ", '") + c.id + "'";
  }
  response.success = true;
  response.message = "colliders set at step " + std::to_string(steps(primary())) + ": " +
                     (ids.empty() ? std::string("none") : ids) + " (the new ones act from the next step)";
  ROS_INFO("%s", response.message.c_str());
  return true;
}

}  // namespace modal_mass_spring
