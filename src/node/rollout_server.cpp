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
  // A fixed collider stands where it is defined, active (~set_colliders may have put it there since the
  // state was saved, where a frame's collider stood, inactive before its first pose).
  if (const Contact* contact = simulation.contact())
    for (int i = 0; i < static_cast<int>(contact->colliders().size()); ++i)
    {
      const Collider& c = contact->colliders()[i];
      if (c.frame.empty() && (!contact->active(i) || !contact->pose(i).isApprox(c.pose, 0.0)))
        simulation.placeCollider(i, c.pose);
    }
  primary().restartAdaptive();  // under adaptive, a stepper from the restored state
  primary().name = methodName(primary());
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

// The goal's method. When it names none: `coarse`, the fastest within a few centimetres of `full` on
// a held cloth (docs/benchmarks.md, "Rollouts"), or `full` where `coarse` cannot run (self-collision,
// handles its grid cannot hold apart).
Method rolloutMethod(const std::string& name, const GridParams& grid, SimulationParams params)
{
  if (name.empty())
  {
    params.method = Method::Coarse;
    try
    {
      validateParameters(grid, params);
      return Method::Coarse;
    }
    catch (const std::invalid_argument&)
    {
      return Method::Full;
    }
  }
  try
  {
    return parseMethod(name);
  }
  catch (const std::invalid_argument&)
  {
    throw std::invalid_argument("method '" + name + "': must be one of " + methodList() +
                                " (empty: coarse, or full where coarse cannot run)");
  }
}

// The goal's candidates, each handle frame's times and poses as waypoints; throws
// std::invalid_argument for a handle whose times and poses differ in number.
std::vector<CandidateMotion> candidateMotions(const RolloutGoal& goal)
{
  std::vector<CandidateMotion> candidates;
  for (const auto& candidate : goal.candidates)
  {
    CandidateMotion motion;
    for (const auto& handle : candidate.handles)
    {
      std::vector<HandleWaypoint> waypoints;
      if (handle.times.size() != handle.poses.size())
        throw std::invalid_argument("candidates[" + std::to_string(candidates.size()) + "]: handle frame '" +
                                    handle.frame + "' has " + std::to_string(handle.times.size()) + " times and " +
                                    std::to_string(handle.poses.size()) + " poses: must have one pose per time");
      for (size_t i = 0; i < handle.times.size(); ++i)
        waypoints.push_back(HandleWaypoint{handle.times[i], framePose(handle.poses[i])});
      motion.frames.emplace_back(handle.frame, std::move(waypoints));
    }
    candidates.push_back(std::move(motion));
  }
  return candidates;
}

// "3 of 3 candidates (0 diverged) x 1 s simulated with full at time_step 0.001 s in ... s wall on 2
// threads, ... s of their CPU", with the seconds of it `built` building the workers when not 0.
std::string rolloutSummary(const std::vector<CandidateOutcome>& outcomes, const RolloutRequest& request,
                           size_t threads, double wall, double cpu, double built)
{
  const long diverged = std::count_if(outcomes.begin(), outcomes.end(), [](const auto& o) { return o.diverged; });
  std::ostringstream message;
  message << outcomes.size() << " of " << request.candidates.size() << " candidates (" << diverged << " diverged) x "
          << request.horizon << " s simulated with " << toString(request.method) << " at time_step "
          << request.time_step << " s in " << wall << " s wall on " << threads << " threads, " << cpu
          << " s of their CPU"
          << (built > 0.0 ? " (" + std::to_string(built) + " s of it building their simulations)" : std::string());
  return message.str();
}

}  // namespace

// What a goal runs from: its request and the node's limits, and the live simulation's grid,
// parameters and build, copied under the lock.
struct SimulationNode::RolloutSetup
{
  RolloutRequest request;
  RolloutLimits limits;
  GridParams grid;
  SimulationParams params;
  long build = 0;
};

SimulationNode::RolloutSetup SimulationNode::rolloutSetup(const RolloutGoal& goal)
{
  RolloutSetup setup;
  RolloutRequest& request = setup.request;
  {
    ServiceLock lock(*this);
    const Simulation& live = *primary().simulation;
    setup.grid = live.grid().params();
    setup.params = live.params();
    setup.build = live_builds_;
    request.frames = *handle_frames_;
    request.grid_offset = primary().offset;
    setup.limits = RolloutLimits{config_.node.rollout_threads, config_.node.rollout_max_horizon,
                                 config_.node.rollout_max_candidates, setup.params.memory_limit_gb};
    request.state = goal.use_state ? simulationState(goal.state, request.frames) : live.saveState();
    if (goal.use_state)
      placeHandleFrames(goal.state, request.frames);
  }
  request.method = rolloutMethod(goal.method, setup.grid, setup.params);
  request.time_step =
      goal.time_step == 0.0 ? defaultRolloutTimeStep(request.method, goal.horizon, setup.grid, setup.params) : goal.time_step;
  request.horizon = goal.horizon;
  request.sample_times = goal.sample_times;
  request.candidates = candidateMotions(goal);
  checkRolloutRequest(request, setup.limits, setup.grid, setup.params);
  return setup;
}

double SimulationNode::prepareRolloutWorkers(const RolloutSetup& setup)
{
  const auto start = std::chrono::steady_clock::now();
  double built = 0.0;
  const SimulationParams& params = setup.params;
  // Self-collision and the contact thickness are tuned live without a rebuild: workers built with other
  // settings are built anew.
  const auto tunedSince = [&params](const Simulation& worker) {
    const SimulationParams& p = worker.params();
    return p.self_collision != params.self_collision || p.self_collision_thickness != params.self_collision_thickness ||
           p.self_friction != params.self_friction || p.contact_thickness != params.contact_thickness;
  };
  if (rollout_workers_build_ != setup.build ||
      rollout_workers_.size() != static_cast<size_t>(setup.limits.threads) || tunedSince(*rollout_workers_.front()))
  {
    rollout_workers_.clear();
    for (int k = 0; k < setup.limits.threads; ++k)
      rollout_workers_.push_back(
          buildSimulation(setup.grid, params, false, "building rollout worker " + std::to_string(k)));
    rollout_workers_build_ = setup.build;
    built = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  }
  rolloutStart(*rollout_workers_.front(), setup.request);  // a start that does not fit is refused here
  return built;
}

std::vector<CandidateOutcome> SimulationNode::runRolloutWorkers(const RolloutRequest& request, double& cpu)
{
  std::vector<Simulation*> workers;
  for (const auto& worker : rollout_workers_)
    workers.push_back(worker.get());
  int finished = 0;
  const int total = static_cast<int>(request.candidates.size());
  return runRollouts(workers, request, rollout_cancel_, [&](const CandidateOutcome& outcome) {
    RolloutFeedback feedback;
    feedback.candidate = outcome.candidate;
    feedback.finished = ++finished;
    feedback.total = total;
    feedback.diverged = outcome.diverged;
    rollout_server_->publishFeedback(feedback);
  }, &cpu);
}

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
  RolloutSetup setup;
  try
  {
    setup = rolloutSetup(*goal);
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
    built = prepareRolloutWorkers(setup);
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
  const RolloutRequest& request = setup.request;
  std::vector<CandidateOutcome> outcomes;
  double cpu = 0.0;
  try
  {
    outcomes = runRolloutWorkers(request, cpu);
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
  result.message = rolloutSummary(outcomes, request, rollout_workers_.size(), wall, cpu, built);
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
