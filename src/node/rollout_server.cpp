// ~get_state, ~set_state and ~rollout: the state saved and restored, and candidate handle motions
// simulated from it on worker simulations while the live one steps on.
#include "grid_messages.h"
#include "rollouts.h"
#include "simulation_node.h"
#include "state_messages.h"

#include <algorithm>
#include <chrono>
#include <mutex>
#include <sstream>
#include <string>

namespace modal_mass_spring
{

bool SimulationNode::getState(GetState::Request&, GetState::Response& response)
{
  ServiceLock lock(*this);
  const Simulation& simulation = *primary().simulation;
  response.state = stateMessage(simulation.saveState(), *handle_frames_, simulation.points(), primary().offset);
  response.success = true;
  response.message = "state of method " + toString(simulation.method()) + " at step " +
                     std::to_string(simulation.stepCount());
  return true;
}

bool SimulationNode::setState(SetState::Request& request, SetState::Response& response)
{
  ServiceLock lock(*this);
  response.success = false;
  if (lockstep())
  {
    response.message = "this node compares methods in lockstep (parameter 'methods'); set_state restores a "
                       "single-method node";
    return true;
  }
  Simulation& simulation = *primary().simulation;
  try
  {
    simulation.restoreState(simulationState(request.state, *handle_frames_));
  }
  catch (const std::exception& error)
  {
    response.message = std::string("state refused: ") + error.what() + "; the run goes on unchanged";
    ROS_WARN("~set_state %s", response.message.c_str());
    return true;
  }
  primary().name = toString(simulation.method());
  primary().step_offset = 0;
  primary().divergence_message = simulation.diverged() ? request.state.divergence_message : "";
  synchronise();  // the shadow full from the restored state
  pacing_.dropOwed();
  ++state_changes_;
  response.success = true;
  response.message = "restored method " + toString(simulation.method()) + " at step " +
                     std::to_string(simulation.stepCount()) + " (t = " + std::to_string(simulation.time()) + " s)";
  ROS_INFO("~set_state: %s", response.message.c_str());
  return true;
}

void SimulationNode::startRollouts()
{
  ros::NodeHandle service_nh(private_nh_);
  service_nh.setCallbackQueue(&service_queue_);
  // The goals run on the server's own thread; its queue (the services') takes goals and cancels.
  rollout_server_ = std::make_unique<actionlib::SimpleActionServer<RolloutAction>>(
      service_nh, "rollout", [this](const RolloutGoalConstPtr& goal) { executeRollout(goal); }, false);
  rollout_server_->registerPreemptCallback([this] { rollout_cancel_ = true; });
  rollout_server_->start();
}

namespace
{

RolloutOutcome outcomeMessage(const CandidateOutcome& outcome)
{
  RolloutOutcome m;
  m.candidate = outcome.candidate;
  m.diverged = outcome.diverged;
  m.message = outcome.message;
  m.simulated_time = outcome.simulated_time;
  for (const GridSample& sample : outcome.samples)
  {
    RolloutSample s;
    s.time = sample.time;
    s.positions.resize(static_cast<size_t>(sample.positions.cols()));
    for (Eigen::Index p = 0; p < sample.positions.cols(); ++p)
      s.positions[p] = point(sample.positions.col(p));
    for (const Eigen::Vector3d& f : sample.handle_forces)
    {
      geometry_msgs::Wrench w;
      w.force.x = f.x(), w.force.y = f.y(), w.force.z = f.z();
      s.handle_wrenches.push_back(w);
    }
    for (const Eigen::Vector3d& f : sample.contact_forces)
    {
      geometry_msgs::Vector3 v;
      v.x = f.x(), v.y = f.y(), v.z = f.z();
      s.contact_forces.push_back(v);
    }
    m.samples.push_back(std::move(s));
  }
  return m;
}

}  // namespace

void SimulationNode::executeRollout(const RolloutGoalConstPtr& goal)
{
  rollout_cancel_ = false;
  RolloutResult result;
  auto refuse = [&](const std::string& why) {
    result.success = false;
    result.message = "goal refused: " + why;
    ROS_WARN("~rollout %s", result.message.c_str());
    rollout_server_->setAborted(result, result.message);
  };
  // The start and the limits, copied under the lock; nothing after this touches the live simulation.
  RolloutRequest request;
  RolloutLimits limits;
  GridParams grid;
  SimulationParams params;
  long build = 0;
  {
    ServiceLock lock(*this);
    const Simulation& live = *primary().simulation;
    grid = live.grid().params();
    params = live.params();
    build = live_builds_;
    request.frames = *handle_frames_;
    request.grid_offset = primary().offset;
    limits = RolloutLimits{config_.node.rollout_threads, config_.node.rollout_max_horizon,
                           config_.node.rollout_max_candidates, params.memory_limit_gb};
    try
    {
      request.state = goal->use_state ? simulationState(goal->state, request.frames) : live.saveState();
    }
    catch (const std::invalid_argument& error)
    {
      refuse(error.what());
      return;
    }
    if (goal->use_state)
      placeHandleFrames(goal->state, request.frames);
  }
  try
  {
    request.method = goal->method.empty() ? Method::Full : parseMethod(goal->method);
  }
  catch (const std::invalid_argument&)
  {
    refuse("method '" + goal->method + "': must be full, linear, physical or cubature (empty: full)");
    return;
  }
  request.time_step = goal->time_step == 0.0 ? params.time_step : goal->time_step;
  request.horizon = goal->horizon;
  request.sample_times = goal->sample_times;
  for (const auto& candidate : goal->candidates)
  {
    CandidateMotion motion;
    for (const auto& handle : candidate.handles)
    {
      std::vector<HandleWaypoint> waypoints;
      if (handle.times.size() != handle.poses.size())
      {
        refuse("candidates[" + std::to_string(request.candidates.size()) + "]: handle frame '" + handle.frame +
               "' has " + std::to_string(handle.times.size()) + " times and " + std::to_string(handle.poses.size()) +
               " poses: must have one pose per time");
        return;
      }
      for (size_t i = 0; i < handle.times.size(); ++i)
        waypoints.push_back(HandleWaypoint{handle.times[i], framePose(handle.poses[i])});
      motion.frames.emplace_back(handle.frame, std::move(waypoints));
    }
    request.candidates.push_back(std::move(motion));
  }
  try
  {
    checkRolloutRequest(request, limits, grid, params);
  }
  catch (const std::invalid_argument& error)
  {
    refuse(error.what());
    return;
  }

  // The workers' simulations, built once for the live simulation's parameters (the cache serves
  // their bases), then restored to each candidate's start.
  const auto start = std::chrono::steady_clock::now();
  double built = 0.0;  // s: building the workers' simulations (the first goal's)
  try
  {
    // Self-collision is tuned live without a rebuild: workers built with other settings are built anew.
    const auto tunedSince = [&params](const Simulation& worker) {
      const SimulationParams& p = worker.params();
      return p.self_collision != params.self_collision || p.self_collision_thickness != params.self_collision_thickness ||
             p.self_friction != params.self_friction;
    };
    if (rollout_workers_build_ != build || rollout_workers_.size() != static_cast<size_t>(limits.threads) ||
        tunedSince(*rollout_workers_.front()))
    {
      rollout_workers_.clear();
      for (int k = 0; k < limits.threads; ++k)
        rollout_workers_.push_back(buildSimulation(grid, params, false, "building rollout worker " + std::to_string(k)));
      rollout_workers_build_ = build;
      built = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    }
    rolloutStart(*rollout_workers_.front(), request);  // a start that does not fit is refused here
  }
  catch (const std::invalid_argument& error)
  {
    refuse(error.what());
    return;
  }
  catch (const std::exception& error)
  {
    result.success = false;
    result.message = std::string("rollout workers could not be built: ") + error.what();
    ROS_ERROR("~rollout: %s", result.message.c_str());
    rollout_server_->setAborted(result, result.message);
    return;
  }
  std::vector<Simulation*> workers;
  for (const auto& worker : rollout_workers_)
    workers.push_back(worker.get());
  int finished = 0;
  const int total = static_cast<int>(request.candidates.size());
  std::vector<CandidateOutcome> outcomes;
  double cpu = 0.0;
  try
  {
    outcomes = runRollouts(workers, request, rollout_cancel_, [&](const CandidateOutcome& outcome) {
      RolloutFeedback feedback;
      feedback.candidate = outcome.candidate;
      feedback.finished = ++finished;
      feedback.total = total;
      feedback.diverged = outcome.diverged;
      rollout_server_->publishFeedback(feedback);
    }, &cpu);
  }
  catch (const std::exception& error)
  {
    result.success = false;
    result.message = error.what();
    ROS_ERROR("~rollout: %s", result.message.c_str());
    rollout_server_->setAborted(result, result.message);
    return;
  }
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  for (const CandidateOutcome& outcome : outcomes)
    result.outcomes.push_back(outcomeMessage(outcome));
  const long diverged = std::count_if(outcomes.begin(), outcomes.end(), [](const auto& o) { return o.diverged; });
  std::ostringstream message;
  message << outcomes.size() << " of " << total << " candidates (" << diverged << " diverged) x " << request.horizon
          << " s simulated with " << toString(request.method) << " at time_step " << request.time_step << " s in "
          << wall << " s wall on " << workers.size() << " threads, " << cpu << " s of their CPU"
          << (built > 0.0 ? " (" + std::to_string(built) + " s of it building their simulations)" : std::string());
  result.message = message.str();
  if (rollout_cancel_)
  {
    result.success = false;
    result.message = "cancelled: " + result.message;
    rollout_server_->setPreempted(result, result.message);
    return;
  }
  result.success = true;
  rollout_server_->setSucceeded(result, result.message);
}

}  // namespace modal_mass_spring
