// What the node publishes of its state: each tick's markers, point cloud, particle frames, wrenches
// and ~status, assembled under the lock (snapshot) and sent after it; the state a track is in, and
// /diagnostics.
#include "simulation_node.h"

#include "contact_messages.h"
#include "grid_messages.h"
#include "lockstep.h"

#include <rosgraph_msgs/Clock.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace modal_mass_spring
{
namespace
{

// How often falling behind real time is logged: once a user knows, the diagnostics keep the count.
constexpr double kBehindWarningPeriod = 10.0;

std::string formatDistance(double metres)
{
  char text[64];
  if (metres < 1e-3)
    std::snprintf(text, sizeof text, "%.3g mm", 1e3 * metres);
  else
    std::snprintf(text, sizeof text, "%.1f mm", 1e3 * metres);
  return text;
}

std::string formatCost(double seconds)
{
  char text[64];
  if (seconds < 1e-3)
    std::snprintf(text, sizeof text, "%.3g us/step", 1e6 * seconds);
  else
    std::snprintf(text, sizeof text, "%.3g ms/step", 1e3 * seconds);
  return text;
}

MarkerOptions markerOptions(const NodeParams& params)
{
  MarkerOptions options;
  options.frame_id = params.fixed_frame;
  options.offset = params.offset;
  options.surface = params.show_surface;
  options.particles = params.show_particles;
  options.springs = params.show_springs;
  options.color_by_strain = params.color_by_strain;
  options.strain_scale = params.strain_scale;
  options.particle_diameter = params.particle_diameter;
  options.spring_width = params.spring_width;
  options.surface_max_cells = params.surface_max_cells;
  return options;
}

}  // namespace

std::string formatCpuPace(double step_cpu_seconds, double time_step)
{
  if (!(step_cpu_seconds > 0.0) || !(time_step > 0.0))
    return "no step timed yet";
  char text[128];
  std::snprintf(text, sizeof text, "%.3g ms of CPU a step, %.3g CPU s per simulated s, %.3g x real time",
                1e3 * step_cpu_seconds, step_cpu_seconds / time_step, time_step / step_cpu_seconds);
  return text;
}

SimulationNode::Output SimulationNode::snapshot(const ros::Time& stamp)
{
  Output output;
  output.stamp = stamp;
  keepLastStates();
  const Track* ref = reference();
  // tf2 rejects a second transform of a frame at the same stamp (e.g. a paused /clock): skip it.
  const bool send_tf = stamp > last_tf_stamp_ && !config_.node.tf_particles.empty();
  if (send_tf)
    last_tf_stamp_ = stamp;
  const NodeParams& params = config_.node;
  // Every k-th tick, k the nearest whole number to publish_rate / markers_rate.
  const int every = params.markers_rate > 0.0 ? std::max(1, static_cast<int>(std::lround(params.publish_rate / params.markers_rate))) : 1;
  output.markers = ++ticks_since_markers_ >= every;
  if (output.markers)
    ticks_since_markers_ = 0;
  for (const Track& track : tracks_)
  {
    if (track.shadow)
      continue;
    addGrid(track, ref, stamp, output);
    if (send_tf)
      addParticleFrames(track, stamp, output);
  }
  return output;
}

void SimulationNode::keepLastStates()
{
  // The core keeps the last good state on divergence; never publish a non-finite one anyway.
  // The positions are reconstructed here, once per published tick (x_ref + Phi X costs O(n r)), not
  // at every step.
  for (Track& track : tracks_)
  {
    const Eigen::VectorXd positions = track.simulation->positions();
    const Eigen::Matrix3Xd points = track.simulation->grid().toPoints(positions);
    if (points.allFinite())
      track.last_points = points;
    const double energy = track.simulation->totalEnergy(positions);
    if (std::isfinite(energy))
      track.last_energy = energy;
  }
  const Track* ref = reference();
  for (Track& track : tracks_)
  {
    track.rms_distance = track.max_distance = 0.0;
    if (!ref || &track == ref)
      continue;
    const ParticleDistances d = particleDistances(track.last_points, ref->last_points);
    track.rms_distance = d.rms;
    track.max_distance = d.max;
  }
}

void SimulationNode::deleteColliderMarkers(const Track& track, size_t drawn, const std::string& frame_id,
                                           const ros::Time& stamp, visualization_msgs::MarkerArray& markers) const
{
  // Fewer colliders than before (~set_colliders): their markers beyond the drawn ones go.
  for (size_t id = drawn; id < track.collider_markers; ++id)
  {
    visualization_msgs::Marker m;
    m.header.frame_id = frame_id;
    m.header.stamp = stamp;
    m.ns = track.ns_prefix + "colliders";
    m.id = static_cast<int>(id);
    m.action = visualization_msgs::Marker::DELETE;
    markers.markers.push_back(m);
  }
  track.collider_markers = drawn;
}

void SimulationNode::addGrid(const Track& track, const Track* ref, const ros::Time& stamp, Output& output)
{
  const NodeParams& params = config_.node;
  const Simulation& simulation = *track.simulation;
  const bool measured = ref && &track != ref;
  Output::Grid grid;
  grid.markers_pub = track.markers_pub;
  grid.status_pub = track.status_pub;
  grid.points_pub = track.points_pub;

  MarkerOptions options = markerOptions(params);
  options.offset = track.offset;
  options.ns_prefix = track.ns_prefix;
  if (params.show_labels)
    options.label = trackLabel(track, measured);
  // One pass over the springs for both the surface's colours and the cloud.
  const Eigen::VectorXd strains = particleStrains(simulation.grid(), track.last_points);
  if (output.markers)
    grid.markers = makeMarkers(simulation.grid(), options, track.last_points, stamp, strains);
  if (const Contact* contact = simulation.contact())
  {
    if (output.markers)
    {
      const auto colliders = colliderMarkers(*contact, options.frame_id, track.offset, track.ns_prefix + "colliders", stamp);
      grid.markers.markers.insert(grid.markers.markers.end(), colliders.markers.begin(), colliders.markers.end());
      deleteColliderMarkers(track, colliders.markers.size(), options.frame_id, stamp, grid.markers);
    }
    for (size_t i = 0; i < track.contact_force_pubs.size() && i < contact->report().force.size(); ++i)
      grid.wrenches.emplace_back(track.contact_force_pubs[i],
                                 forceWrench(contact->report().force[i], options.frame_id, stamp));
  }
  else if (output.markers)
    deleteColliderMarkers(track, 0, options.frame_id, stamp, grid.markers);
  addHandleWrenches(track, options.frame_id, stamp, grid.wrenches);
  if (measured && ref->shadow && output.markers)
  {
    // The reference drawn faintly where the method is: the gap between them is the error.
    MarkerOptions ghost = options;
    ghost.ns_prefix = ref->ns_prefix;
    ghost.ghost = true;
    ghost.surface = ghost.particles = params.show_shadow;
    ghost.springs = false;
    ghost.label.clear();
    const auto shadow = makeMarkers(simulation.grid(), ghost, ref->last_points, stamp);
    grid.markers.markers.insert(grid.markers.markers.end(), shadow.markers.begin(), shadow.markers.end());
  }
  grid.points = makePointCloud(track.last_points, strains, simulation.particleContacts(),
                               track.offset, params.fixed_frame, stamp);
  grid.status = trackStatus(track, measured, stamp);
  output.grids.push_back(std::move(grid));
}

std::string SimulationNode::trackLabel(const Track& track, bool measured) const
{
  const Simulation& simulation = *track.simulation;
  std::string label = toString(simulation.method()) +
                      (measured ? "\nRMS " + formatDistance(track.rms_distance) + " to full" : "") + "\n" +
                      formatCost(track.step_seconds) + "\n" +
                      formatCpuPace(track.step_cpu_seconds, config_.simulation.time_step) +
                      (simulation.selfCollision() ? "\nself-collision " + formatCost(simulation.lastSelfCollisionSeconds())
                                                  : "");
  if (lockstep())
  {
    char pace[64];
    std::snprintf(pace, sizeof pace, "\n%.2f x real time", achieved_factor_);
    label += pace;
  }
  return label;
}

void SimulationNode::addHandleWrenches(const Track& track, const std::string& frame_id, const ros::Time& stamp,
                                       std::vector<std::pair<ros::Publisher, geometry_msgs::WrenchStamped>>& wrenches)
{
  if (track.handle_force_pubs.empty())
    return;
  const Simulation& simulation = *track.simulation;
  // Torques about each handle frame's origin (before it is found, about the grid's: unused).
  std::vector<Eigen::Vector3d> origins(simulation.grid().handles().size(), Eigen::Vector3d::Zero());
  for (size_t h = 0; h < origins.size() && h < handle_frames_->size(); ++h)
    if (handle_frames_->everFound(h))
      origins[h] = handle_frames_->originInGrid(h);
  const std::vector<Simulation::Wrench> handle_wrenches = simulation.handleWrenches(origins);
  for (size_t h = 0; h < track.handle_force_pubs.size() && h < handle_wrenches.size(); ++h)
  {
    const Simulation::Wrench& wrench = handle_wrenches[h];
    if (!wrench.force.allFinite() || !wrench.torque.allFinite())
      continue;
    // In the handle's own frame once it was found (what a force-torque sensor at the gripper
    // reads; tf2 turns it into any other frame), the force alone in fixed_frame axes before.
    if (handle_frames_->everFound(h))
    {
      const Eigen::Quaterniond to_frame = handle_frames_->current(h).rotation.conjugate();
      wrenches.emplace_back(track.handle_force_pubs[h], forceWrench(to_frame * wrench.force, handle_frames_->frame(h),
                                                                    stamp, to_frame * wrench.torque));
    }
    else
      wrenches.emplace_back(track.handle_force_pubs[h], forceWrench(wrench.force, frame_id, stamp));
  }
}

Status SimulationNode::trackStatus(const Track& track, bool measured, const ros::Time& stamp)
{
  const Simulation& simulation = *track.simulation;
  Status status;
  status.header.stamp = stamp;
  status.header.frame_id = config_.node.fixed_frame;
  status.method = methodName(track);
  status.active_method = toString(simulation.method());
  status.error_estimate = track.error_estimate;
  status.reduced_share = simulation.method() == Method::Full ? 0.0 : 1.0;
  if (track.adaptive && adaptiveTrack(track))
  {
    status.reduced_share = track.adaptive->reducedShare();
    status.switches = static_cast<uint32_t>(track.adaptive->switches());
  }
  status.linearization = toString(simulation.params().linearization);
  status.integrator = toString(simulation.params().integrator);
  status.newton_iterations = simulation.lastNewtonIterations();
  status.step_count = steps(track);
  status.sim_time = simTime(track);
  status.tick_steps = track.tick_steps;
  status.tick_step_seconds = lockstep() ? track.tick_seconds : tick_step_seconds_;
  status.total_energy = track.last_energy;
  status.state = state(track);
  // Why it diverged, else what a training in the background has done so far.
  status.message = simulation.diverged() ? track.divergence_message
                   : training_ && &track == &primary() ? trainingProgress() : "";
  status.handles = handle_frames_->status();
  status.handle_formulation =
      handle_frames_->empty() ? "" : toString(simulation.handleFormulation());
  status.applied_forces = static_cast<uint32_t>(applied_forces_->size());
  status.dragged_particle = hand_forces_ ? hand_forces_->draggedParticle() : -1;
  status.reference = measured ? "full" : "";
  status.rms_distance = track.rms_distance;
  status.max_distance = track.max_distance;
  status.step_seconds = track.step_seconds;
  status.step_cpu_seconds = track.step_cpu_seconds;
  status.cpu_per_simulated_second =
      track.step_cpu_seconds > 0.0 ? track.step_cpu_seconds / config_.simulation.time_step : 0.0;
  status.real_time_factor = achieved_factor_;
  if (const SelfCollision* self = simulation.selfCollision())
  {
    status.self_collision_seconds = simulation.lastSelfCollisionSeconds();
    status.self_collision_contacts = static_cast<uint32_t>(self->report().contacts);
  }
  addBasisStatus(simulation, status);
  return status;
}

void SimulationNode::addBasisStatus(const Simulation& simulation, Status& status) const
{
  const DerivativeBasisInfo& derivatives = simulation.derivativeInfo();
  status.basis = toString(simulation.params().basis);
  status.linear_modes = simulation.basis().phi.cols();
  status.derivative_directions = derivatives.derivative_directions;
  status.basis_seconds = simulation.basis().build_seconds + derivatives.seconds + simulation.skinningInfo().seconds;
  status.largest_dropped_singular_value = derivatives.largest_dropped_singular_value;
  if (const Cubature* cubature = simulation.cubature())
  {
    status.cubature_springs = static_cast<uint32_t>(cubature->springs.size());
    status.cubature_training_error = cubature->training_error;
    status.cubature_heldout_error = cubature->heldout_error;
    status.cubature_training_seconds = cubature->training_seconds;
  }
  const CacheReport& cache = simulation.cacheReport();
  status.basis_from_cache = cache.basis_loaded;
  status.cubature_from_cache = cache.cubature_loaded;
  status.cache = describeCache(cache);
}

void SimulationNode::addParticleFrames(const Track& track, const ros::Time& stamp, Output& output) const
{
  for (int particle : config_.node.tf_particles)
  {
    geometry_msgs::TransformStamped frame;
    frame.header.stamp = stamp;
    frame.header.frame_id = track.grid_frame;
    frame.child_frame_id = particleFrame(track.grid_frame, particle);
    frame.transform.translation.x = track.last_points(0, particle);
    frame.transform.translation.y = track.last_points(1, particle);
    frame.transform.translation.z = track.last_points(2, particle);
    frame.transform.rotation.w = 1.0;
    output.frames.push_back(frame);
  }
}

void SimulationNode::send(const Output& output)
{
  if (use_sim_time_)
  {
    rosgraph_msgs::Clock clock;
    clock.clock = output.stamp;
    clock_pub_.publish(clock);
  }
  for (const auto& grid : output.grids)
  {
    if (output.markers)
      grid.markers_pub.publish(grid.markers);
    grid.points_pub.publish(grid.points);
  }
  if (!output.frames.empty())
    tf_broadcaster_.sendTransform(output.frames);
  for (const auto& grid : output.grids)
  {
    grid.status_pub.publish(grid.status);
    for (const auto& [publisher, wrench] : grid.wrenches)
      publisher.publish(wrench);
  }
}

uint8_t SimulationNode::state(const Track& track) const
{
  if (track.simulation->diverged())
    return Status::DIVERGED;
  if (rebuilding())
    return Status::REBUILDING;
  return paused_ ? Status::PAUSED : Status::RUNNING;
}

std::string SimulationNode::stateName(const Track& track) const
{
  switch (state(track))
  {
    case Status::DIVERGED:
      return "DIVERGED";
    case Status::PAUSED:
      return "PAUSED";
    case Status::REBUILDING:
      return "REBUILDING";
    default:
      return "RUNNING";
  }
}

void SimulationNode::diagnose(diagnostic_updater::DiagnosticStatusWrapper& status)
{
  std::lock_guard<std::mutex> lock(mutex_);
  const NodeParams& params = config_.node;
  const double period = 1.0 / params.publish_rate;
  const double mean_cost = diag_ticks_ ? diag_step_seconds_ / diag_ticks_ : 0.0;
  const Track& first = primary();
  const Simulation& simulation = *first.simulation;
  if (simulation.diverged())
    status.summary(diagnostic_msgs::DiagnosticStatus::ERROR, "diverged: " + first.divergence_message);
  else if (diag_ticks_ > 0 && (mean_cost > period || 2 * diag_late_ticks_ > diag_ticks_))
  {
    double step_seconds = 0.0;
    for (const Track& track : tracks_)
      step_seconds = std::max(step_seconds, track.step_seconds);
    char behind[200];
    std::snprintf(behind, sizeof behind,
                  "falling behind real time: %.2f ms of stepping per %.2f ms tick, %d of %d ticks late "
                  "(stepping longer than the period)",
                  1e3 * mean_cost, 1e3 * period, diag_late_ticks_, diag_ticks_);
    status.summary(diagnostic_msgs::DiagnosticStatus::WARN, behind);
    // On the console too, with what costs: the steps a tick asks for and what one takes.
    // Frames moved in wall time then move faster in simulated time than their broadcaster meant.
    const bool compressed = !use_sim_time_ && followsFrames();
    ROS_WARN_THROTTLE(kBehindWarningPeriod,
                      "%s: %s takes %.3g ms a step and a tick asks for %.1f steps (real_time_factor / "
                      "(publish_rate time_step)); a smaller real_time_factor, a larger time_step or a cheaper "
                      "method keeps up%s",
                      behind, lockstep() ? "the slowest method in lockstep" : ("method " + toString(simulation.method())).c_str(),
                      1e3 * step_seconds,
                      params.real_time_factor / (params.publish_rate * config_.simulation.time_step),
                      compressed ? ". The TF frames the cloth follows move in wall time, so their motion is compressed "
                                   "into less simulated time: with use_sim_time:=true the node publishes /clock and "
                                   "their broadcasters keep its pace"
                                 : "");
  }
  else
    status.summary(diagnostic_msgs::DiagnosticStatus::OK, paused_ ? "paused" : "stepping");
  if (!handle_frames_->status().empty())  // whatever else is said
    status.mergeSummary(diagnostic_msgs::DiagnosticStatus::WARN,
                        "handles " + handle_frames_->status() + " (their particles hold where they are)");
  if (!collider_frames_->status().empty())
    status.mergeSummary(diagnostic_msgs::DiagnosticStatus::WARN, collider_frames_->status());
  for (const Track& track : tracks_)
    if (!track.shadow && !adaptiveTrack(track) && track.error_estimate > config_.simulation.error_tolerance)
      status.mergeSummary(diagnostic_msgs::DiagnosticStatus::WARN,
                          (lockstep() ? track.name + ": " : "") + "estimated distance to full " +
                              formatDistance(track.error_estimate) + " above error_tolerance " +
                              formatDistance(config_.simulation.error_tolerance) +
                              " since the state was last set: the reduced span may not follow this motion "
                              "(method adaptive falls back to full)");
  status.add("state", stateName(first));
  if (training_)
    status.add("cubature training", trainingProgress());
  status.add("method", lockstep() ? "lockstep" : methodName(first));
  status.add("estimated distance to full (m)", first.error_estimate);
  if (first.adaptive && adaptiveTrack(first))
  {
    status.add("adaptive: stepping now", toString(simulation.method()));
    status.add("adaptive: share of steps reduced", first.adaptive->reducedShare());
    status.add("adaptive: switches", first.adaptive->switches());
    status.add("adaptive: last switch", first.adaptive->lastSwitch());
  }
  status.add("step count", steps(first));
  status.add("simulated time (s)", simTime(first));
  status.add("steps per tick", params.real_time_factor / (params.publish_rate * config_.simulation.time_step));
  status.add("mean stepping per tick (s)", mean_cost);
  status.add("tick period (s)", period);
  status.add("ticks", diag_ticks_);
  status.add("late ticks (stepping longer than the period)", diag_late_ticks_);
  status.add("modes", static_cast<int>(simulation.basis().frequencies.size()));
  if (lockstep())
    status.add("achieved real-time factor", achieved_factor_);
  diag_ticks_ = diag_late_ticks_ = 0;
  diag_step_seconds_ = 0.0;
}

std::string SimulationNode::methodName(const Track& track) const
{
  return adaptiveTrack(track) ? "adaptive" : toString(track.simulation->method());
}

std::string SimulationNode::adaptiveNote(const Track& track) const
{
  if (!adaptiveTrack(track))
    return "";
  if (!track.adaptive)
    return "; adaptive: waiting for " + toString(config_.simulation.adaptive_method);
  char text[200];
  const int switches = track.adaptive->switches();
  std::snprintf(text, sizeof text, "; adaptive: now %s, %.1f%% of steps reduced, %d switch%s, estimate %s",
                toString(track.simulation->method()).c_str(), 100.0 * track.adaptive->reducedShare(), switches,
                switches == 1 ? "" : "es", formatDistance(track.error_estimate).c_str());
  return text;
}

std::string SimulationNode::statusLine() const
{
  const Track& first = tracks_.front();
  const double dt = config_.simulation.time_step;
  char line[480];
  std::snprintf(line, sizeof line,
                "%s: %s, step %ld, simulated %.3f s, energy %.6g J, %.3f ms of stepping per tick; %s%s%s",
                stateName(first).c_str(),
                lockstep() ? "methods in lockstep" : ("method " + methodName(first)).c_str(), steps(first),
                simTime(first), first.last_energy, 1e3 * tick_step_seconds_,
                lockstep() ? (first.name + ": ").c_str() : "", formatCpuPace(first.step_cpu_seconds, dt).c_str(),
                lockstep() ? ("; achieved real-time factor " + std::to_string(achieved_factor_)).c_str() : "");
  return line + adaptiveNote(first);
}

}  // namespace modal_mass_spring
