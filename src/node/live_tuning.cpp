// Live tuning of a running node with dynamic_reconfigure: node parameters at the next tick; stiffness,
// mass, modes, linearization and damping by a model rebuilt in the background and swapped in at a tick
// boundary with the motion carried over. The core fixes damping and basis when a Simulation is built,
// so those changes need a new one; building it beside the running one keeps the markers coming.
#include "live_parameters.h"
#include "simulation_node.h"
#include "xmlrpc_parameter_source.h"

namespace modal_mass_spring
{

void SimulationNode::startLiveTuning()
{
  tuning_server_ = std::make_unique<dynamic_reconfigure::Server<SimulationConfig>>(tuning_mutex_, private_nh_);
  // The server starts from the cfg defaults where a parameter is not set; the node's values are the
  // ones in force (show_particles, for one, depends on the grid's size).
  tuning_server_->updateConfig(liveValues(accepted_));
  tuning_server_->setCallback(
      [this](SimulationConfig& config, uint32_t level) { reconfigure(config, level); });
}

void SimulationNode::reconfigure(SimulationConfig& config, uint32_t)
{
  // Called on the timer's thread (the global queue): never inside a tick's stepping.
  std::lock_guard<std::mutex> lock(mutex_);
  XmlRpc::XmlRpcValue params = private_params_;
  writeLiveValues(config, params);
  NodeConfiguration candidate;
  try
  {
    candidate = loadNodeConfiguration(XmlRpcParameterSource(params), {});
  }
  catch (const std::invalid_argument& error)
  {
    ROS_ERROR("dynamic_reconfigure: %s; refused, nothing changed", error.what());
    config = liveValues(accepted_);  // what the client gets back, and what the server keeps
    return;
  }
  // The colliders are ~set_colliders's since the start: the set in force, not the parameter's.
  candidate.simulation.colliders = config_.simulation.colliders;
  // Self-collision acts from the next step on every track; a track that runs a reduced method now (a
  // switch since the start) refuses it, and then nothing changes.
  const SimulationParams& self = candidate.simulation;
  if (self.self_collision)
    for (const Track& track : tracks_)
      if (track.simulation->method() != Method::Full || adaptiveTrack(track))
      {
        ROS_ERROR("dynamic_reconfigure: self_collision: true needs method full on every grid, but '%s' runs %s; "
                  "refused, nothing changed",
                  track.name.c_str(), methodName(track).c_str());
        config = liveValues(accepted_);
        return;
      }
  for (Track& track : tracks_)
  {
    track.simulation->setSelfCollision(self.self_collision, self.self_collision_thickness, self.self_friction);
    track.simulation->setContactThickness(self.contact_thickness);  // checked with the parameters above
  }
  const NodeConfiguration previous = accepted_;
  private_params_ = params;
  accepted_ = candidate;
  config = liveValues(accepted_);

  // Node parameters and self-collision: in force from the next tick.
  const double old_rate = config_.node.publish_rate;
  copyLiveValues(candidate, config_, kLiveLevel);
  const NodeParams& node = config_.node;
  hand_forces_->configure(node.drag_stiffness, config_.grid.mass, config_.simulation.time_step);
  showDragMarker();
  if (node.publish_rate != old_rate)
  {
    timer_.setPeriod(ros::Duration(1.0 / node.publish_rate));
    wall_timer_.setPeriod(ros::WallDuration(1.0 / node.publish_rate));
  }

  // The rest needs a new basis.
  if (!liveValuesDiffer(candidate, previous, kRebuildLevel))
    return;
  ROS_INFO("dynamic_reconfigure: rebuilding the model in the background (%s); the old one runs on",
           describeLiveValues(candidate, kRebuildLevel).c_str());
  pending_rebuild_ = candidate;
  if (rebuilding_)
    return;  // the loop picks the latest up when its build is done
  rebuilding_ = true;
  if (rebuild_thread_.joinable())
    rebuild_thread_.join();  // finished: it cleared rebuilding_ on its way out
  rebuild_thread_ = std::thread(&SimulationNode::rebuildLoop, this);
}

std::vector<SimulationNode::TrackKind> SimulationNode::trackKinds() const
{
  std::vector<TrackKind> kinds;
  for (const Track& track : tracks_)
    kinds.push_back({adaptiveTrack(track) ? config_.simulation.adaptive_method : track.simulation->method(),
                     track.simulation->basisBuilt()});
  return kinds;
}

std::vector<std::unique_ptr<Simulation>> SimulationNode::buildTracksFor(const NodeConfiguration& config,
                                                                       const std::vector<TrackKind>& kinds,
                                                                       const std::string& activity) const
{
  std::vector<std::unique_ptr<Simulation>> built;
  for (const TrackKind& kind : kinds)
  {
    SimulationParams params = config.simulation;
    params.method = kind.method;
    built.push_back(buildSimulation(config.grid, params, false, activity, kind.with_basis));
  }
  return built;
}

void SimulationNode::rebuildLoop()
{
  for (;;)
  {
    NodeConfiguration target;
    std::vector<TrackKind> kinds;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (!pending_rebuild_ || stopping_)
      {
        rebuilding_ = false;
        return;
      }
      target = *pending_rebuild_;
      pending_rebuild_.reset();
      kinds = trackKinds();
    }
    std::vector<std::unique_ptr<Simulation>> built;
    const ros::WallTime start = ros::WallTime::now();
    try
    {
      built = buildTracksFor(target, kinds, "rebuilding");
    }
    catch (const std::exception& error)
    {
      ROS_ERROR("dynamic_reconfigure: the rebuild failed: %s; the old model runs on", error.what());
      SimulationConfig running;
      {
        std::lock_guard<std::mutex> lock(mutex_);
        if (pending_rebuild_)
          continue;  // a later change is waiting: it is what the values say now
        // Back to the model that runs (or the one already built and waiting), so that the values
        // reported and the next change start from it.
        const NodeConfiguration& in_force = rebuilt_.empty() ? config_ : rebuilt_config_;
        copyLiveValues(in_force, accepted_, kRebuildLevel);
        running = liveValues(accepted_);
        writeLiveValues(running, private_params_, kRebuildLevel);
      }
      tuning_server_->updateConfig(running);  // outside mutex_: the server's callback takes it
      continue;
    }
    std::lock_guard<std::mutex> lock(mutex_);
    if (pending_rebuild_)
      continue;  // superseded while it was built
    rebuilt_ = std::move(built);
    rebuilt_config_ = target;
    ROS_INFO("dynamic_reconfigure: model rebuilt in %.3f s; swapped in at the next tick",
             (ros::WallTime::now() - start).toSec());
  }
}

void SimulationNode::swapRebuilt()
{
  // A cubature trained in the background reads the running simulation: the swap waits for it.
  if (rebuilt_.empty() || training_)
    return;
  ++live_builds_;  // the rollouts' workers are built anew for the new parameters
  for (size_t k = 0; k < tracks_.size() && k < rebuilt_.size(); ++k)
  {
    Track& track = tracks_[k];
    const Simulation& old = *track.simulation;
    Simulation& next = *rebuilt_[k];
    if (next.method() != old.method())
      next.setMethod(old.method());  // switched while it was built
    // The motion carries over: the handles where they are (in a moving frame, the frame where it has
    // gone), then the same positions and velocities around them, measured from the new linearization
    // point (a modal method takes their projection onto the new modes).
    if (next.handleFormulation() == HandleFormulation::MovingFrame)
      next.placeFrame(old.frameMotion());
    else if (next.grid().numHandleDofs() > 0)
      next.setHandleState(old.handlePositions(), old.handleMotion().velocity, old.handleMotion().acceleration);
    next.setPhysicalState(next.grid().gatherFree(old.positions() - next.linearizationPositions()), old.velocity());
    track.step_offset += old.stepCount();
    track.simulation = std::move(rebuilt_[k]);
    track.restartAdaptive();
    track.divergence_message.clear();
  }
  rebuilt_.clear();
  config_.grid = rebuilt_config_.grid;
  config_.simulation = rebuilt_config_.simulation;
  // Self-collision and the contact thickness may have been changed live while the model was built:
  // the values in force now.
  const SimulationParams& self = accepted_.simulation;
  for (Track& track : tracks_)
    try
    {
      track.simulation->setSelfCollision(self.self_collision, self.self_collision_thickness, self.self_friction);
      track.simulation->setContactThickness(self.contact_thickness);
    }
    catch (const std::invalid_argument& error)
    {
      ROS_ERROR("dynamic_reconfigure: %s", error.what());
    }
  config_.simulation.self_collision = self.self_collision;
  config_.simulation.self_collision_thickness = self.self_collision_thickness;
  config_.simulation.self_friction = self.self_friction;
  config_.simulation.contact_thickness = self.contact_thickness;
  hand_forces_->configure(config_.node.drag_stiffness, config_.grid.mass, config_.simulation.time_step);
  ROS_INFO("dynamic_reconfigure: rebuilt model swapped in at step %ld, motion carried over", steps(primary()));
}

}  // namespace modal_mass_spring
