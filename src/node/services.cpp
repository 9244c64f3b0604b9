// The node's services (~set_method, ~reset, ~pause, ~step) and the forces from outside (~apply_force,
// ~clear_forces): each takes the simulation between two steps (ServiceLock).
#include "simulation_node.h"

#include <Eigen/Geometry>
#include <geometry_msgs/TransformStamped.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <string>

namespace modal_mass_spring
{
namespace
{

// The largest ~step request: more would hold the services for minutes on a large grid.
constexpr uint32_t kMaxStepRequest = 10000;

}  // namespace

bool SimulationNode::setMethod(SetMethod::Request& request, SetMethod::Response& response)
{
  ServiceLock lock(*this);
  if (lockstep())
  {
    response.success = false;
    response.message = "this node compares methods in lockstep (parameter 'methods'); set_method switches a "
                       "single-method node";
    return true;
  }
  adoptTrainedCubature();  // a training done since the last tick
  Simulation& simulation = *primary().simulation;
  const std::string previous = methodName(primary());
  // adaptive steps adaptive_method, falling back to full (adaptive_tracks.cpp).
  const bool to_adaptive = request.method == "adaptive";
  Method method = config_.simulation.adaptive_method;
  try
  {
    if (!to_adaptive)
      method = parseMethod(request.method);
  }
  catch (const std::invalid_argument&)
  {
    response.success = false;
    response.message = "unknown method '" + request.method + "': must be one of " + methodList() +
                       ", adaptive; still running '" + previous + "'";
    return true;
  }
  const bool was_diverged = simulation.diverged();
  if (training_ && method == Method::Cubature)
  {
    adaptive_after_training_ = to_adaptive;
    switch_after_training_ = true;
    response.success = true;
    response.message = "the cubature is being trained in the background (" + trainingProgress() + "); still running '" +
                       previous + "', switched to " + (to_adaptive ? "adaptive" : "cubature") +
                       " when the training is done";
    return true;
  }
  try
  {
    if (isModal(method))
    {
      buildBasis(simulation, "building the modal basis");  // once, with its progress logged
      simulation.prepareConstraintModes(method);           // before any training
    }
    if (method == Method::Cubature && !simulation.loadCachedCubature())
    {
      // Training takes up to minutes on the skinning span: the current method steps on meanwhile.
      trainInBackground(simulation.cubatureTraining());  // refuses a training beyond memory_limit_gb
      adaptive_after_training_ = to_adaptive;
      switch_after_training_ = true;
      response.success = true;
      response.message = "training the cubature in the background on basis " + toString(simulation.params().basis) +
                         "; still running '" + previous +
                         "' (~status state REBUILDING, its message the training's progress), switched to " +
                         (to_adaptive ? "adaptive" : "cubature") + " when the training is done";
      ROS_INFO("%s", response.message.c_str());
      return true;
    }
    simulation.setMethod(method);  // builds before it replaces anything: a failure keeps the run
  }
  catch (const std::exception& error)
  {
    response.success = false;
    response.message = "cannot switch to " + request.method + ": " + error.what() + "; still running '" + previous + "'";
    ROS_ERROR("%s", response.message.c_str());
    return true;
  }
  // A later choice cancels the switch a training was to end with (the training goes on and is kept).
  if (training_ && switch_after_training_)
  {
    switch_after_training_ = false;
    ROS_INFO("~set_method %s: the switch to cubature after its training is cancelled (the training goes on, "
             "kept for a later switch)",
             request.method.c_str());
  }
  adaptive_ = to_adaptive;
  response.success = true;
  response.message = finishSwitch(previous, method, was_diverged);
  return true;
}

std::string SimulationNode::finishSwitch(const std::string& previous, Method method, bool was_diverged)
{
  const Simulation& simulation = *primary().simulation;
  primary().restartAdaptive();  // under adaptive, a stepper from this state
  primary().name = methodName(primary());
  primary().divergence_message.clear();
  synchronise();  // the shadow full starts again from the state carried over
  ++state_changes_;
  std::string message = "switched from " + previous + " to " + primary().name + " at step " +
                        std::to_string(steps(primary())) + (was_diverged ? ", recovering from the divergence" : "");
  // `linear` never runs on a richer basis (its force is the modes' own -Lambda q): say what it runs on.
  if (method == Method::Linear && simulation.params().basis != BasisKind::LinearModes)
    message += "; linear keeps the " + std::to_string(simulation.params().num_modes) + " lowest modes, not basis " +
               toString(simulation.params().basis);
  if (was_diverged)  // forces that caused it act on, as after a reset
    message += forcesActingNote();
  ROS_INFO("%s", message.c_str());
  return message;
}

void SimulationNode::trainInBackground(Simulation::CubatureTraining training)
{
  if (training_thread_.joinable())
    training_thread_.join();  // finished: it cleared training_ on its way out
  training_ = true;
  trained_.reset();
  training_failure_.clear();
  {
    std::lock_guard<std::mutex> lock(progress_mutex_);
    training_progress_ = "training the cubature: drawing the training poses";
  }
  ROS_INFO("training the cubature in the background on basis %s (%s); the current method steps on",
           toString(primary().simulation->params().basis).c_str(),
           config_.node.cache_dir.empty() ? "no cache_dir: trained again at every start" : "cached for the next start");
  training_thread_ = std::thread([this, training = std::move(training)] {
    std::optional<Cubature> cubature;
    std::string failure;
    const auto start = std::chrono::steady_clock::now();
    try
    {
      withProgress("training the cubature", [&](const StageFn& on_stage, const IterationFn& on_iteration) {
        on_stage("cubature");
        cubature = training([&](const std::string& stage, int springs, double error, double tolerance) {
          if (cancel_training_)
            throw std::runtime_error("cancelled: the node is shutting down");
          on_iteration(stage, springs, error, tolerance);
          char text[160];
          std::snprintf(text, sizeof text,
                        "training the cubature: %d springs, training error %.3g%% (cubature_tolerance %.3g%%), %.0f s",
                        springs, 100.0 * error, 100.0 * tolerance,
                        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
          std::lock_guard<std::mutex> lock(progress_mutex_);
          training_progress_ = text;
        });
      });
    }
    catch (const std::exception& error)
    {
      failure = error.what();
    }
    std::lock_guard<std::mutex> lock(mutex_);
    trained_ = std::move(cubature);
    training_failure_ = failure;
    training_ = false;
  });
}

void SimulationNode::adoptTrainedCubature()
{
  if (training_ || (!trained_ && training_failure_.empty()))
    return;
  Simulation& simulation = *primary().simulation;
  const std::string previous = methodName(primary());
  if (!trained_)
  {
    ROS_ERROR("cannot switch to cubature: its training failed: %s; still running '%s'", training_failure_.c_str(),
              previous.c_str());
    training_failure_.clear();
    return;
  }
  simulation.setCubature(std::move(*trained_));
  trained_.reset();
  ROS_INFO("%s", describeCubature(*simulation.cubature(), static_cast<int>(simulation.grid().springs().size()),
                                  simulation.params().cubature_tolerance)
                     .c_str());
  if (!switch_after_training_)
    return;
  switch_after_training_ = false;
  const bool was_diverged = simulation.diverged();
  try
  {
    simulation.setMethod(Method::Cubature);
  }
  catch (const std::exception& error)
  {
    ROS_ERROR("cannot switch to cubature: %s; still running '%s'", error.what(), previous.c_str());
    return;
  }
  adaptive_ = adaptive_after_training_;
  finishSwitch(previous, Method::Cubature, was_diverged);
}

std::string SimulationNode::trainingProgress() const
{
  std::lock_guard<std::mutex> lock(progress_mutex_);
  return training_progress_;
}

bool SimulationNode::reset(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& response)
{
  ServiceLock lock(*this);
  for (Track& track : tracks_)
  {
    track.simulation->reset();
    track.restartAdaptive();  // its checkpoints were before the reset
    track.step_offset = 0;
    track.divergence_message.clear();
  }
  handle_frames_->reset();
  synchronise();
  pacing_.dropOwed();
  ++state_changes_;
  response.success = true;
  response.message = "reset to the initial state at rest (" +
                     (lockstep() ? std::string("methods in lockstep") : "method " + methodName(primary())) +
                     (paused_ ? ", still paused)" : ")");
  response.message += forcesActingNote();
  ROS_INFO("%s", response.message.c_str());
  return true;
}

bool SimulationNode::pause(std_srvs::SetBool::Request& request, std_srvs::SetBool::Response& response)
{
  ServiceLock lock(*this);
  if (paused_ != static_cast<bool>(request.data))
    ++state_changes_;
  paused_ = request.data;
  response.success = true;
  response.message = std::string(paused_ ? "paused" : "running") + " at step " + std::to_string(steps(primary()));
  ROS_INFO("%s", response.message.c_str());
  return true;
}

bool SimulationNode::step(Step::Request& request, Step::Response& response)
{
  Output output;
  {
    ServiceLock lock(*this);
    Simulation& simulation = *primary().simulation;
    response.step_count = steps(primary());
    response.sim_time = simTime(primary());
    response.success = false;
    if (!paused_)
    {
      response.message = "refused: the simulation is running; pause it first (~pause data: true)";
      return true;
    }
    if (request.steps < 1 || request.steps > kMaxStepRequest)
    {
      response.message = "invalid steps = " + std::to_string(request.steps) + ": must be in [1, " +
                         std::to_string(kMaxStepRequest) + "]";
      return true;
    }
    if (simulation.diverged())
    {
      response.message = "refused: the simulation diverged (" + primary().divergence_message +
                         "); ~reset or ~set_method recovers";
      return true;
    }
    for (Track& track : tracks_)
      track.startTick();
    // No frame is looked up while paused: the handles hold where they are, at rest, rather than go
    // on at the last tick's velocity and acceleration.
    handle_frames_->hold();
    setHandleMotion(config_.simulation.time_step, 1.0);
    uint32_t taken = 0;
    while (taken < request.steps && stepAll())
      ++taken;
    int stepped = 0;
    for (Track& track : tracks_)
    {
      stepped = std::max(stepped, track.tick_steps);
      track.finishTick();
    }
    clock_seconds_ += stepped * config_.simulation.time_step;
    ++state_changes_;
    output = snapshot(stamp());
    response.step_count = steps(primary());
    response.sim_time = simTime(primary());
    response.success = !simulation.diverged();
    response.message = simulation.diverged()
                           ? "diverged after " + std::to_string(stepped) + " steps: " + primary().divergence_message
                           : "advanced " + std::to_string(stepped) + " steps to step " +
                                 std::to_string(response.step_count);
  }
  send(output);
  return true;
}

void SimulationNode::applyForce(const ApplyForce::ConstPtr& message)
{
  // The vectors are turned into the fixed frame, whose axes are the grid's (its frame is only
  // translated); an unknown frame drops the message.
  const std::string& fixed_frame = config_.node.fixed_frame;
  const std::string frame = message->header.frame_id.empty() ? fixed_frame : message->header.frame_id;
  Eigen::Quaterniond rotation = Eigen::Quaterniond::Identity();
  if (frame != fixed_frame)
  {
    try
    {
      const geometry_msgs::TransformStamped t = tf_buffer_.lookupTransform(fixed_frame, frame, ros::Time(0));
      rotation = Eigen::Quaterniond(t.transform.rotation.w, t.transform.rotation.x, t.transform.rotation.y,
                                    t.transform.rotation.z);
    }
    catch (const tf2::TransformException& e)
    {
      warnDropped("~apply_force: message dropped: frame '" + frame + "' cannot be turned into '" + fixed_frame +
                  "': " + e.what());
      return;
    }
  }
  std::vector<Eigen::Vector3d> forces;
  for (const geometry_msgs::Vector3& f : message->forces)
    forces.push_back(frame == fixed_frame ? Eigen::Vector3d(f.x, f.y, f.z) : rotation * Eigen::Vector3d(f.x, f.y, f.z));
  std::string why;
  size_t acting = 0;
  {
    ServiceLock lock(*this);
    why = applied_forces_->add(message->particles, forces, message->duration, clock_seconds_);
    if (why.empty())
      updateExternalForces();
    acting = applied_forces_->size();
  }
  if (!why.empty())
    warnDropped("~apply_force: message dropped: " + why);
  else if (message->duration > 0.0)
    ROS_INFO_THROTTLE(1.0, "~apply_force: taken: %zu %s for %g s; %zu %s", message->particles.size(),
                      message->particles.size() == 1 ? "particle" : "particles", message->duration, acting,
                      acting == 1 ? "force acts" : "forces act");
  else
    ROS_INFO_THROTTLE(1.0, "~apply_force: taken: %zu %s until ~clear_forces; %zu %s", message->particles.size(),
                      message->particles.size() == 1 ? "particle" : "particles", acting,
                      acting == 1 ? "force acts" : "forces act");
}

bool SimulationNode::clearForces(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& response)
{
  ServiceLock lock(*this);
  const size_t count = applied_forces_->clear();
  hand_forces_->release();  // a drag whose release never came ends too
  updateExternalForces();
  response.success = true;
  response.message = "cleared " + std::to_string(count) + (count == 1 ? " force" : " forces");
  return true;
}

std::string SimulationNode::forcesActingNote() const
{
  // Forces from ~apply_force act on across a reset and a method switch (as a wrench applied in Gazebo
  // does); after a divergence they caused the run would diverge again, so the reply says they are there.
  const size_t forces = applied_forces_->size();
  if (forces == 0)
    return "";
  return "; " + std::to_string(forces) + (forces == 1 ? " force from ~apply_force acts" : " forces from ~apply_force act") +
         " on (~clear_forces ends them)";
}

std::string SimulationNode::externalForcesNote(size_t track) const
{
  const size_t applied = applied_forces_->size();
  const bool hand = hand_forces_ && hand_forces_->active(track);
  if (applied == 0 && !hand)
    return "";
  std::string acting = applied > 0 ? std::to_string(applied) + " from ~apply_force" : "";
  if (hand)
    acting += std::string(applied > 0 ? " and " : "") + (hand_forces_->dragging() ? "a drag" : "a poke");
  return "; forces from outside were acting (" + acting +
         "): too large a force diverges too; ~clear_forces ends them, then ~reset starts again";
}

void SimulationNode::updateExternalForces()
{
  // On /clock's seconds, which a reset does not take back: a force lasts its duration of simulated
  // time across resets too.
  applied_forces_->update(clock_seconds_, external_force_);
  // A rebuilt simulation starts without them: every track is brought to the current total.
  // A track under the hand's force gets the total before its next step (applyHandForce).
  for (size_t k = 0; k < tracks_.size(); ++k)
    if (!(hand_forces_ && hand_forces_->active(k)) && tracks_[k].simulation->externalForce() != external_force_)
      tracks_[k].simulation->setExternalForce(external_force_);
}

}  // namespace modal_mass_spring
