// Live tuning of a running node with dynamic_reconfigure: node parameters at the next tick; stiffness,
// mass, modes, linearization and damping by a model rebuilt in the background and swapped in at a tick
// boundary with the motion carried over. The core fixes damping and basis when a Simulation is built,
// so those changes need a new one; building it beside the running one keeps the markers coming.
#include "simulation_node.h"
#include "xmlrpc_parameter_source.h"

namespace modal_mass_spring
{

SimulationConfig SimulationNode::tuningOf(const NodeConfiguration& c) const
{
  SimulationConfig config = SimulationConfig::__getDefault__();
  config.real_time_factor = c.node.real_time_factor;
  config.publish_rate = c.node.publish_rate;
  config.strain_scale = c.node.strain_scale;
  config.show_surface = c.node.show_surface;
  config.show_particles = c.node.show_particles;
  config.show_springs = c.node.show_springs;
  config.show_labels = c.node.show_labels;
  config.show_shadow = c.node.show_shadow;
  config.drag_stiffness = c.node.drag_stiffness;
  config.poke_impulse = c.node.poke_impulse;
  config.self_collision = c.simulation.self_collision;
  config.self_collision_thickness = c.simulation.self_collision_thickness;
  config.self_friction = c.simulation.self_friction;
  config.alpha = c.simulation.alpha;
  config.beta = c.simulation.beta;
  config.structural_stiffness = c.grid.structural_stiffness;
  config.shear_stiffness = c.grid.shear_stiffness;
  config.bending_stiffness = c.grid.bending_stiffness;
  config.mass = c.grid.mass;
  config.num_modes = c.simulation.num_modes;
  config.linearization = toString(c.simulation.linearization);
  return config;
}

void SimulationNode::startLiveTuning()
{
  tuning_server_ = std::make_unique<dynamic_reconfigure::Server<SimulationConfig>>(tuning_mutex_, private_nh_);
  // The server starts from the cfg defaults where a parameter is not set; the node's values are the
  // ones in force (show_particles, for one, depends on the grid's size).
  tuning_server_->updateConfig(tuningOf(accepted_));
  tuning_server_->setCallback(
      [this](SimulationConfig& config, uint32_t level) { reconfigure(config, level); });
}

void SimulationNode::reconfigure(SimulationConfig& config, uint32_t)
{
  // Called on the timer's thread (the global queue): never inside a tick's stepping.
  std::lock_guard<std::mutex> lock(mutex_);
  XmlRpc::XmlRpcValue params = private_params_;
  params["real_time_factor"] = config.real_time_factor;
  params["publish_rate"] = config.publish_rate;
  params["strain_scale"] = config.strain_scale;
  params["show_surface"] = static_cast<bool>(config.show_surface);
  params["show_particles"] = static_cast<bool>(config.show_particles);
  params["show_springs"] = static_cast<bool>(config.show_springs);
  params["show_labels"] = static_cast<bool>(config.show_labels);
  params["show_shadow"] = static_cast<bool>(config.show_shadow);
  params["drag_stiffness"] = config.drag_stiffness;
  params["poke_impulse"] = config.poke_impulse;
  params["self_collision"] = static_cast<bool>(config.self_collision);
  params["self_collision_thickness"] = config.self_collision_thickness;
  params["self_friction"] = config.self_friction;
  params["alpha"] = config.alpha;
  params["beta"] = config.beta;
  params["structural_stiffness"] = config.structural_stiffness;
  params["shear_stiffness"] = config.shear_stiffness;
  params["bending_stiffness"] = config.bending_stiffness;
  params["mass"] = config.mass;
  params["num_modes"] = config.num_modes;
  params["linearization"] = config.linearization;
  NodeConfiguration candidate;
  try
  {
    candidate = loadNodeConfiguration(XmlRpcParameterSource(params), {});
  }
  catch (const std::invalid_argument& error)
  {
    ROS_ERROR("dynamic_reconfigure: %s; refused, nothing changed", error.what());
    config = tuningOf(accepted_);  // what the client gets back, and what the server keeps
    return;
  }
  // Self-collision acts from the next step on every track; a track that runs a modal method now (a
  // switch since the start) refuses it, and then nothing changes.
  const SimulationParams& self = candidate.simulation;
  if (self.self_collision)
    for (const Track& track : tracks_)
      if (track.simulation->method() != Method::Full)
      {
        ROS_ERROR("dynamic_reconfigure: self_collision: true needs method full on every grid, but '%s' runs %s; "
                  "refused, nothing changed",
                  track.name.c_str(), toString(track.simulation->method()).c_str());
        config = tuningOf(accepted_);
        return;
      }
  for (Track& track : tracks_)
    track.simulation->setSelfCollision(self.self_collision, self.self_collision_thickness, self.self_friction);
  config_.simulation.self_collision = self.self_collision;
  config_.simulation.self_collision_thickness = self.self_collision_thickness;
  config_.simulation.self_friction = self.self_friction;
  const NodeConfiguration previous = accepted_;
  private_params_ = params;
  accepted_ = candidate;
  config = tuningOf(accepted_);

  // Node parameters: in force from the next tick.
  NodeParams& node = config_.node;
  const double old_rate = node.publish_rate;
  node.real_time_factor = candidate.node.real_time_factor;
  node.publish_rate = candidate.node.publish_rate;
  node.strain_scale = candidate.node.strain_scale;
  node.show_surface = candidate.node.show_surface;
  node.show_particles = candidate.node.show_particles;
  node.show_springs = candidate.node.show_springs;
  node.show_labels = candidate.node.show_labels;
  node.show_shadow = candidate.node.show_shadow;
  node.drag_stiffness = candidate.node.drag_stiffness;
  node.poke_impulse = candidate.node.poke_impulse;
  hand_forces_->configure(node.drag_stiffness, config_.grid.mass, config_.simulation.time_step);
  showDragMarker();
  if (node.publish_rate != old_rate)
  {
    timer_.setPeriod(ros::Duration(1.0 / node.publish_rate));
    wall_timer_.setPeriod(ros::WallDuration(1.0 / node.publish_rate));
  }

  // The rest needs a new basis.
  const GridParams &g = candidate.grid, &pg = previous.grid;
  const SimulationParams &p = candidate.simulation, &pp = previous.simulation;
  const bool rebuild = g.structural_stiffness != pg.structural_stiffness || g.shear_stiffness != pg.shear_stiffness ||
                       g.bending_stiffness != pg.bending_stiffness || g.mass != pg.mass ||
                       p.num_modes != pp.num_modes || p.linearization != pp.linearization || p.alpha != pp.alpha ||
                       p.beta != pp.beta;
  if (!rebuild)
    return;
  ROS_INFO("dynamic_reconfigure: rebuilding the model in the background (structural_stiffness %g, shear_stiffness "
           "%g, bending_stiffness %g, mass %g, num_modes %d, linearization %s, alpha %g, beta %g); the old one "
           "runs on",
           g.structural_stiffness, g.shear_stiffness, g.bending_stiffness, g.mass, p.num_modes,
           toString(p.linearization).c_str(), p.alpha, p.beta);
  pending_rebuild_ = candidate;
  if (rebuilding_)
    return;  // the loop picks the latest up when its build is done
  rebuilding_ = true;
  if (rebuild_thread_.joinable())
    rebuild_thread_.join();  // finished: it cleared rebuilding_ on its way out
  rebuild_thread_ = std::thread(&SimulationNode::rebuildLoop, this);
}

void SimulationNode::rebuildLoop()
{
  for (;;)
  {
    NodeConfiguration target;
    std::vector<Method> methods;
    std::vector<bool> with_basis;  // a full track that has switched to a modal method needs it again
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (!pending_rebuild_ || stopping_)
      {
        rebuilding_ = false;
        return;
      }
      target = *pending_rebuild_;
      pending_rebuild_.reset();
      for (const Track& track : tracks_)
      {
        methods.push_back(track.simulation->method());
        with_basis.push_back(track.simulation->basisBuilt());
      }
    }
    std::vector<std::unique_ptr<Simulation>> built;
    const ros::WallTime start = ros::WallTime::now();
    try
    {
      for (size_t k = 0; k < methods.size(); ++k)
      {
        SimulationParams params = target.simulation;
        params.method = methods[k];
        built.push_back(buildSimulation(target.grid, params, false, "rebuilding", with_basis[k]));
      }
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
        accepted_.grid = in_force.grid;
        accepted_.simulation = in_force.simulation;
        private_params_["alpha"] = accepted_.simulation.alpha;
        private_params_["beta"] = accepted_.simulation.beta;
        private_params_["structural_stiffness"] = accepted_.grid.structural_stiffness;
        private_params_["shear_stiffness"] = accepted_.grid.shear_stiffness;
        private_params_["bending_stiffness"] = accepted_.grid.bending_stiffness;
        private_params_["mass"] = accepted_.grid.mass;
        private_params_["num_modes"] = accepted_.simulation.num_modes;
        private_params_["linearization"] = toString(accepted_.simulation.linearization);
        running = tuningOf(accepted_);
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
    track.divergence_message.clear();
  }
  rebuilt_.clear();
  config_.grid = rebuilt_config_.grid;
  config_.simulation = rebuilt_config_.simulation;
  // Self-collision may have been changed live while the model was built: the values in force now.
  const SimulationParams& self = accepted_.simulation;
  for (Track& track : tracks_)
    try
    {
      track.simulation->setSelfCollision(self.self_collision, self.self_collision_thickness, self.self_friction);
    }
    catch (const std::invalid_argument& error)
    {
      ROS_ERROR("dynamic_reconfigure: %s", error.what());
    }
  config_.simulation.self_collision = self.self_collision;
  config_.simulation.self_collision_thickness = self.self_collision_thickness;
  config_.simulation.self_friction = self.self_friction;
  hand_forces_->configure(config_.node.drag_stiffness, config_.grid.mass, config_.simulation.time_step);
  ROS_INFO("dynamic_reconfigure: rebuilt model swapped in at step %ld, motion carried over", steps(primary()));
}

}  // namespace modal_mass_spring
