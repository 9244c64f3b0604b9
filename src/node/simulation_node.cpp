// The node adds nothing numerical: it steps the core Simulation on a timer and shows its state (what
// it publishes is assembled in status.cpp; its services are in services.cpp).
#include "simulation_node.h"

#include "lockstep.h"
#include "modal_mass_spring/cpu_time.h"

#include "modal_mass_spring/Status.h"
#include "startup_report.h"
#include "xmlrpc_parameter_source.h"

#include <Eigen/Geometry>
#include <geometry_msgs/TransformStamped.h>
#include <rosgraph_msgs/Clock.h>
#include <sensor_msgs/PointCloud2.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <condition_variable>
#include <stdexcept>
#include <thread>

namespace modal_mass_spring
{
namespace
{

using Clock = std::chrono::steady_clock;

double secondsSince(Clock::time_point start)
{
  return std::chrono::duration<double>(Clock::now() - start).count();
}

// Polls a StartupProgress from its own thread while the simulation is built.
class ProgressWatcher
{
public:
  explicit ProgressWatcher(StartupProgress& progress)
    : thread_([this, &progress] {
        std::unique_lock<std::mutex> lock(mutex_);
        while (!cv_.wait_for(lock, std::chrono::milliseconds(100), [this] { return done_; }))
          progress.poll();
      })
  {
  }
  ~ProgressWatcher()
  {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      done_ = true;
    }
    cv_.notify_all();
    thread_.join();
  }

private:
  std::mutex mutex_;
  std::condition_variable cv_;
  bool done_ = false;
  std::thread thread_;  // last: starts once the rest is there
};

// How long a handle's or a collider's frame never seen is waited for before its warning: a
// broadcaster launched beside the node needs a moment to come up.
constexpr double kFrameGraceSeconds = 5.0;

}  // namespace

SimulationNode::SimulationNode(ros::NodeHandle& nh, ros::NodeHandle& private_nh) : nh_(nh), private_nh_(private_nh)
{
  // Every parameter is read and checked before anything is built, so a bad one fails at once even on
  // a grid whose basis would take minutes.
  loadConfiguration();
  const NodeParams& params = config_.node;
  // diagnostic_updater reads ~diagnostic_period itself, and only as a number: give it the checked one.
  private_nh_.setParam("diagnostic_period", params.diagnostic_period);
  // Under simulated time this node is the clock, as Gazebo is: it publishes /clock from its steps.
  use_sim_time_ = ros::Time::isSimTime();

  buildTracks();

  advertiseTracks();
  if (use_sim_time_)
    clock_pub_ = nh_.advertise<rosgraph_msgs::Clock>("/clock", 10);
  publishStaticFrames();

  const Grid& grid = primary().simulation->grid();
  diagnostics_ = std::make_unique<diagnostic_updater::Updater>(nh_, private_nh_);
  diagnostics_->setHardwareID("modal_mass_spring " + std::to_string(grid.params().rows) + "x" +
                              std::to_string(grid.params().cols) + " grid");
  diagnostics_->add("simulation", this, &SimulationNode::diagnose);

  startServices();
  startLiveTuning();

  last_status_log_ = ros::WallTime::now();
  const double period = 1.0 / params.publish_rate;
  if (use_sim_time_)
    wall_timer_ = nh_.createWallTimer(ros::WallDuration(period), [this](const ros::WallTimerEvent&) { onTick(); });
  else
    timer_ = nh_.createTimer(ros::Duration(period), [this](const ros::TimerEvent&) { onTick(); });
}

void SimulationNode::loadConfiguration()
{
  XmlRpc::XmlRpcValue private_params;
  if (!ros::param::get(private_nh_.getNamespace(), private_params))
    private_params = XmlRpc::XmlRpcValue();
  const XmlRpcParameterSource source(private_params);
  config_ = loadNodeConfiguration(source, source.keys());
  private_params_ = private_params;
  accepted_ = config_;
  for (const auto& key : config_.unknown_keys)
    ROS_WARN("parameter '%s/%s' is not a parameter of this node and is ignored", private_nh_.getNamespace().c_str(),
             key.c_str());
}

void SimulationNode::advertiseTracks()
{
  for (Track& track : tracks_)
  {
    if (track.shadow)
      continue;  // drawn with the method it shadows
    // A comparison publishes each method below its name: ~linear/markers, ~full/status, ...
    ros::NodeHandle track_nh = lockstep() ? ros::NodeHandle(private_nh_, track.name) : private_nh_;
    track.markers_pub = track_nh.advertise<visualization_msgs::MarkerArray>("markers", 1);
    track.status_pub = track_nh.advertise<Status>("status", 10);
    track.points_pub = track_nh.advertise<sensor_msgs::PointCloud2>("points", 1);
    advertiseWrenches(track, track.handle_force_pubs, "handle_force/handle_", config_.node.handles.size());
    advertiseWrenches(track, track.contact_force_pubs, "contact_force/collider_", config_.simulation.colliders.size());
  }
}

void SimulationNode::advertiseWrenches(const Track& track, std::vector<ros::Publisher>& pubs, const std::string& topic,
                                       size_t count)
{
  if (track.shadow || pubs.size() == count)
    return;
  pubs.resize(std::min(pubs.size(), count));  // those kept keep their subscribers
  ros::NodeHandle track_nh = lockstep() ? ros::NodeHandle(private_nh_, track.name) : private_nh_;
  for (size_t k = pubs.size(); k < count; ++k)
    pubs.push_back(track_nh.advertise<geometry_msgs::WrenchStamped>(topic + std::to_string(k), 10));
}

void SimulationNode::startServices()
{
  // Services have their own queue and thread: a call waits for the step in progress, not the tick.
  ros::NodeHandle service_nh(private_nh_);
  service_nh.setCallbackQueue(&service_queue_);
  set_method_srv_ = service_nh.advertiseService("set_method", &SimulationNode::setMethod, this);
  reset_srv_ = service_nh.advertiseService("reset", &SimulationNode::reset, this);
  pause_srv_ = service_nh.advertiseService("pause", &SimulationNode::pause, this);
  step_srv_ = service_nh.advertiseService("step", &SimulationNode::step, this);
  clear_forces_srv_ = service_nh.advertiseService("clear_forces", &SimulationNode::clearForces, this);
  attach_srv_ = service_nh.advertiseService("attach", &SimulationNode::attach, this);
  detach_srv_ = service_nh.advertiseService("detach", &SimulationNode::detach, this);
  set_colliders_srv_ = service_nh.advertiseService("set_colliders", &SimulationNode::setColliders, this);
  startForcesAndFrames();
  get_state_srv_ = service_nh.advertiseService("get_state", &SimulationNode::getState, this);
  set_state_srv_ = service_nh.advertiseService("set_state", &SimulationNode::setState, this);
  startRollouts();
  apply_force_sub_ = private_nh_.subscribe("apply_force", 10, &SimulationNode::applyForce, this);
  startInteraction();
  service_spinner_ = std::make_unique<ros::AsyncSpinner>(1, &service_queue_);
  service_spinner_->start();
}

void SimulationNode::startForcesAndFrames()
{
  const NodeParams& params = config_.node;
  applied_forces_ = std::make_unique<AppliedForces>(primary().simulation->grid());
  external_force_ = Eigen::VectorXd::Zero(primary().simulation->positions().size());
  tf_listener_ = std::make_unique<tf2_ros::TransformListener>(tf_buffer_);
  handle_frames_ = std::make_unique<HandleFrames>(params.handles, primary().simulation->grid(),
                                                  primary().simulation->linearizationPositions(), params.offset);
  collider_frames_ = std::make_unique<ColliderFrames>(config_.simulation.colliders, params.offset);
  for (size_t k = 0; k < collider_frames_->size(); ++k)
    ROS_INFO("collider %d follows the TF frame '%s' relative to '%s' (inactive until the frame is found)",
             collider_frames_->collider(k), collider_frames_->frame(k).c_str(), params.fixed_frame.c_str());
  if (params.handles.empty())
    return;
  std::string frames;
  for (size_t h = 0; h < params.handles.size(); ++h)
    frames += (h ? ", '" : "'") + params.handles[h].frame + "' (" +
              std::to_string(params.handles[h].particles.size()) + " particles)";
  ROS_INFO("handles following the TF frames %s relative to '%s', offsets taken at each frame's first lookup",
           frames.c_str(), params.fixed_frame.c_str());
  ROS_INFO("%s", describeHandleFormulation(config_.grid, config_.simulation, handleFrames(params.handles)).c_str());
}

SimulationNode::~SimulationNode()
{
  rollout_cancel_ = true;  // running rollouts stop within a step
  if (rollout_server_)
    rollout_server_->shutdown();
  if (service_spinner_)
    service_spinner_->stop();
  timer_.stop();
  wall_timer_.stop();
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
    pending_rebuild_.reset();
  }
  if (rebuild_thread_.joinable())
    rebuild_thread_.join();  // a basis being built is finished and dropped
  cancel_training_ = true;     // a cubature being trained stops at its next spring
  if (training_thread_.joinable())
    training_thread_.join();
}

void SimulationNode::buildBasis(Simulation& simulation, const std::string& activity) const
{
  if (simulation.basisBuilt())
    return;
  const auto start = Clock::now();
  withProgress(activity, [&simulation](const StageFn& on_stage, const IterationFn& on_iteration) {
    simulation.buildBasis(on_stage, on_iteration);
  });
  ROS_INFO("modal basis built in %.3f s: %s", secondsSince(start),
           describeModes(simulation.basis().frequencies, simulation.basis().num_zero_modes).c_str());
}

void SimulationNode::withProgress(const std::string& activity,
                                  const std::function<void(const StageFn&, const IterationFn&)>& work) const
{
  const auto start = Clock::now();
  StartupProgress progress([](const std::string& line) { ROS_INFO("%s", line.c_str()); },
                           [start] { return secondsSince(start); }, 1.0, 10.0, activity);
  ProgressWatcher watcher(progress);
  work([&progress](const std::string& stage) { progress.onStage(stage); },
       [&progress](const std::string& stage, int iteration, double residual, double target) {
         progress.onIteration(stage, iteration, residual, target);
       });
}

std::unique_ptr<Simulation> SimulationNode::buildSimulation(const GridParams& grid_params,
                                                            const SimulationParams& sim_params, bool report,
                                                            const std::string& activity, bool with_basis) const
{
  const auto start = Clock::now();
  std::unique_ptr<Simulation> simulation;
  // Colliders set by ~set_colliders may stand where the grid started: a simulation that takes over
  // the run (a rebuild, a rollout's worker) gets them once built, without the start's check (the
  // state it takes over is outside them), and the formulation colliders need.
  SimulationParams built = sim_params;
  const bool live_colliders = colliders_set_live_ && !built.colliders.empty();
  if (live_colliders)
  {
    built.colliders.clear();
    if (built.handle_formulation == HandleFormulation::Auto)
      built.handle_formulation = HandleFormulation::ConstraintModes;
  }
  withProgress(activity, [&](const StageFn& on_stage, const IterationFn& on_iteration) {
    CacheOptions cache{config_.node.cache_dir, [](const std::string& warning) { ROS_WARN("%s", warning.c_str()); }};
    simulation = std::make_unique<Simulation>(grid_params, built, on_stage, cache, on_iteration);
    if (with_basis)
      simulation->buildBasis(on_stage, on_iteration);
  });
  if (live_colliders)
    simulation->setColliders(sim_params.colliders, std::vector<int>(sim_params.colliders.size(), -1));
  if (!report)
    return simulation;
  const double total_seconds = secondsSince(start);
  const NodeParams& params = config_.node;
  const Grid& grid = simulation->grid();
  const Grid* coarse = simulation->method() == Method::Coarse ? simulation->coarseGrid() : nullptr;
  const std::string reduced =
      coarse ? describeCoarseGrid(grid, *coarse, coarseStepMultiple(grid.params(), sim_params))
      : simulation->basisBuilt()
          ? describeModes(simulation->basis().frequencies, simulation->basis().num_zero_modes)
          : "no modal basis yet (full needs none; it is built at the first switch to a modal method)";
  ROS_INFO("%d x %d grid (%dD, %d particles, %zu springs, %zu fixed), method %s: %s; %s; time_step %g s, "
           "%.4g steps per tick at %g Hz, real_time_factor %g",
           grid.params().rows, grid.params().cols, grid.dimension(), grid.numParticles(), grid.springs().size(),
           grid.fixedParticles().size(), toString(simulation->method()).c_str(), reduced.c_str(),
           describeStartupTimes(simulation->linearization(), simulation->basis(), total_seconds,
                                simulation->derivativeInfo(),
                                simulation->cacheReport().cubature_loaded ? nullptr : simulation->cubature())
               .c_str(),
           sim_params.time_step, params.real_time_factor / (params.publish_rate * sim_params.time_step),
           params.publish_rate, params.real_time_factor);
  const LinearizationInfo& lin = simulation->linearization();
  ROS_INFO("linearization %s, integrator %s, initial_state %s%s", toString(sim_params.linearization).c_str(),
           toString(sim_params.integrator).c_str(), toString(sim_params.initial_state).c_str(),
           lin.equilibrium_solved
               ? (": equilibrium in " + std::to_string(lin.equilibrium_iterations) + " Newton iterations, " +
                  std::to_string(lin.dropped_compressed_springs) + " compressed springs' geometric stiffness dropped, " +
                  "start projected onto the modes with a largest error of " +
                  std::to_string(simulation->projectionError()) + " m")
                     .c_str()
               : "");
  ROS_INFO("%s", describeBasis(sim_params, simulation->derivativeInfo(), simulation->physicalBasis(),
                                  simulation->skinningInfo()).c_str());
  ROS_INFO("%s", describeCache(simulation->cacheReport()).c_str());
  if (const Cubature* cubature = simulation->cubature())
    ROS_INFO("%s", describeCubature(*cubature, static_cast<int>(grid.springs().size()), sim_params.cubature_tolerance).c_str());
  return simulation;
}

void SimulationNode::buildTracks()
{
  const NodeParams& params = config_.node;
  const std::vector<Method> methods = lockstep() ? params.methods : std::vector<Method>{config_.simulation.method};
  adaptive_ = config_.simulation.adaptive && !lockstep();
  for (size_t k = 0; k < methods.size(); ++k)
  {
    SimulationParams sim_params = config_.simulation;
    sim_params.method = methods[k];
    Track track;
    track.name = adaptive_ ? "adaptive" : toString(methods[k]);
    track.simulation = buildSimulation(config_.grid, sim_params, true);
    track.offset = lockstep() ? methodOffset(params, k) : params.offset;
    track.grid_frame = lockstep() ? track.name + "/" + params.grid_frame : params.grid_frame;
    track.ns_prefix = lockstep() ? track.name + "/" : "";
    tracks_.push_back(std::move(track));
  }
  if (params.shadow_full)
  {
    SimulationParams sim_params = config_.simulation;
    sim_params.method = Method::Full;
    Track shadow;
    shadow.name = "shadow_full";
    shadow.shadow = true;
    shadow.simulation = buildSimulation(config_.grid, sim_params, false);
    shadow.offset = params.offset;
    shadow.ns_prefix = "shadow_full/";
    tracks_.push_back(std::move(shadow));
    ROS_INFO("shadow_full: an unreduced simulation runs beside %s from the same state", tracks_.front().name.c_str());
  }
  synchronise();
  for (Track& track : tracks_)
  {
    track.last_points = track.simulation->points();
    track.last_energy = track.simulation->totalEnergy();
  }
}

void SimulationNode::synchronise()
{
  std::vector<Simulation*> simulations;
  for (Track& track : tracks_)
    simulations.push_back(track.simulation.get());
  for (size_t k : synchroniseFull(simulations, !lockstep()))
    tracks_[k].divergence_message.clear();
}

const SimulationNode::Track* SimulationNode::reference() const
{
  for (const Track& track : tracks_)
    if (track.shadow || (lockstep() && track.simulation->method() == Method::Full))
      return &track;
  return nullptr;
}

bool SimulationNode::followsFrames() const
{
  for (size_t h = 0; h < handle_frames_->size(); ++h)
    if (handle_frames_->following(h))
      return true;
  for (size_t k = 0; k < collider_frames_->size(); ++k)
    if (collider_frames_->following(k))
      return true;
  return false;
}

std::optional<FramePose> SimulationNode::lookupFrame(const std::string& frame, bool ever_found, std::string& problem)
{
  problem.clear();
  // A broadcaster started beside the node (a launch file's gripper) may come up after it: a frame
  // never seen yet is waited for quietly at first, then warned about.
  const ros::WallTime wall_now = ros::WallTime::now();
  if (frames_first_lookup_.isZero())
    frames_first_lookup_ = wall_now;
  const bool waiting = (wall_now - frames_first_lookup_).toSec() < kFrameGraceSeconds;
  if (waiting && !ever_found && !tf_buffer_.canTransform(config_.node.fixed_frame, frame, ros::Time(0)))
    return std::nullopt;
  try
  {
    // Under simulated time a broadcaster (scripts/gripper.py) answers the clock this node published
    // last: the frame is taken at that stamp, interpolated between its samples, so that the motion
    // keeps its pace in simulated time however slowly the node steps. A stamp not yet answered, or
    // wall time, takes the latest sample.
    const ros::Time at_clock(clock_seconds_);
    const bool at_stamp = use_sim_time_ && tf_buffer_.canTransform(config_.node.fixed_frame, frame, at_clock);
    const auto stamped = tf_buffer_.lookupTransform(config_.node.fixed_frame, frame, at_stamp ? at_clock : ros::Time(0));
    const auto& t = stamped.transform;
    FramePose pose;
    pose.translation = Eigen::Vector3d(t.translation.x, t.translation.y, t.translation.z);
    pose.rotation = Eigen::Quaterniond(t.rotation.w, t.rotation.x, t.rotation.y, t.rotation.z).normalized();
    // tf2 keeps a frame's last pose after its broadcaster stops: an old one is not followed. A
    // static frame's pose has no stamp.
    const ros::Time now = ros::Time::now();  // the stamps' clock, for a frame's age
    const double age = stamped.header.stamp.isZero() ? 0.0 : (now - stamped.header.stamp).toSec();
    if (!pose.translation.allFinite() || !pose.rotation.coeffs().allFinite())
      problem = "has a non-finite pose";
    else if (age > kStaleHandleFrameSeconds)
    {
      char text[120];
      std::snprintf(text, sizeof text, "stale (its last pose is %.1f s old, above %.1f s)", age,
                    kStaleHandleFrameSeconds);
      problem = text;
    }
    else
      return pose;
  }
  catch (const tf2::TransformException& error)
  {
    problem = std::string("not available (") + error.what() + ")";
  }
  return std::nullopt;
}

void SimulationNode::updateHandleTargets()
{
  std::vector<std::optional<FramePose>> poses(handle_frames_->size());
  std::vector<std::string> problems(poses.size());
  std::string missing;  // every frame not available, so one throttled warning names them all
  for (size_t h = 0; h < poses.size(); ++h)
  {
    const std::string& frame = handle_frames_->frame(h);
    poses[h] = lookupFrame(frame, handle_frames_->everFound(h), problems[h]);
    if (!poses[h] && !problems[h].empty())
      missing += (missing.empty() ? "'" : "; '") + frame + "' " + problems[h];
  }
  if (!missing.empty())
    ROS_WARN_THROTTLE(5.0, "handle frame %s: its particles hold where they are", missing.c_str());
  // A frame found (at last, or again) is said once, so that a run whose broadcaster starts after the
  // node does not end its log on the warning.
  for (size_t h = 0; h < poses.size(); ++h)
    if (poses[h] && !handle_frames_->following(h))
      ROS_INFO("handle frame '%s' found: its %zu %s it", handle_frames_->frame(h).c_str(),
               handle_frames_->particles(h), handle_frames_->particles(h) == 1 ? "particle follows" : "particles follow");
  // Short reasons in the status ("not available", "stale"); the log line above has the details.
  for (std::string& problem : problems)
    problem = problem.substr(0, problem.find(" ("));
  handle_frames_->setTargets(poses, problems);
  for (const std::string& refusal : handle_frames_->refusals())
    ROS_WARN_THROTTLE(5.0, "%s", refusal.c_str());
}

void SimulationNode::updateColliderTargets()
{
  std::vector<std::optional<FramePose>> poses(collider_frames_->size());
  std::vector<std::string> problems(poses.size());
  std::string missing;
  for (size_t k = 0; k < poses.size(); ++k)
  {
    const std::string& frame = collider_frames_->frame(k);
    poses[k] = lookupFrame(frame, collider_frames_->everFound(k), problems[k]);
    if (!poses[k] && !problems[k].empty())
      missing += (missing.empty() ? "collider " : "; collider ") + std::to_string(collider_frames_->collider(k)) +
                 " frame '" + frame + "' " + problems[k] +
                 (collider_frames_->everFound(k) ? ": it keeps its last pose" : ": it is inactive until its frame is found");
  }
  if (!missing.empty())
    ROS_WARN_THROTTLE(5.0, "%s", missing.c_str());
  for (size_t k = 0; k < poses.size(); ++k)
    if (poses[k] && !collider_frames_->following(k))
      ROS_INFO("collider %d frame '%s' found: the collider follows it", collider_frames_->collider(k),
               collider_frames_->frame(k).c_str());
  for (std::string& problem : problems)
    problem = problem.substr(0, problem.find(" ("));
  collider_frames_->setTargets(poses, problems);
  for (const std::string& refusal : collider_frames_->refusals())
    ROS_WARN_THROTTLE(5.0, "%s", refusal.c_str());
  // A collider not placed yet on a track (its frame just found, or the track built anew by a rebuild
  // while paused) appears now, where its frame is, even if no step follows; so does one whose frame
  // jumped and stayed there (placed anew, not swept through the cloth).
  for (size_t k = 0; k < collider_frames_->size(); ++k)
    if (const std::optional<Eigen::Isometry3d> pose = collider_frames_->pose(k, 0.0))
      for (Track& track : tracks_)
        if (const Contact* contact = track.simulation->contact())
        {
          const int i = collider_frames_->collider(k);
          if (!contact->active(i))
            track.simulation->setColliderPose(i, *pose);
          else if (collider_frames_->placed(k))
            track.simulation->placeCollider(i, *pose);
        }
}

void SimulationNode::setColliderPoses(double s)
{
  // Every step, on every track: a track built anew (a rebuild, ~set_method) gets them at its first step.
  for (size_t k = 0; k < collider_frames_->size(); ++k)
    if (const std::optional<Eigen::Isometry3d> pose = collider_frames_->pose(k, s))
      for (Track& track : tracks_)
        if (!track.simulation->diverged())
          track.simulation->setColliderPose(collider_frames_->collider(k), *pose);
}

void SimulationNode::setHandleMotion(double duration, double s)
{
  if (handle_frames_->empty())
    return;
  try
  {
    for (Track& track : tracks_)
      if (!track.simulation->diverged())
        handle_frames_->drive(*track.simulation, duration, s);
  }
  catch (const std::invalid_argument& error)
  {
    // A 2D grid's frame that turns out of the grid's plane: held where it was.
    ROS_WARN_THROTTLE(5.0, "handle frame '%s' refused, its particles hold where they are: %s",
                      handle_frames_->frame(0).c_str(), error.what());
  }
}

bool SimulationNode::stepAll()
{
  bool any_running = false;
  for (size_t k = 0; k < tracks_.size(); ++k)
  {
    Track& track = tracks_[k];
    if (track.simulation->diverged())
    {
      hand_forces_->skip(k);
      continue;
    }
    applyHandForce(k);
    const auto start = Clock::now();
    const double cpu_start = threadCpuSeconds();
    const StepResult result = stepTrack(track);
    track.tick_cpu_seconds += threadCpuSeconds() - cpu_start;
    track.tick_seconds += secondsSince(start);
    refreshErrorEstimate(track);
    track.tick_steps += result.steps_taken;
    if (result.diverged)
    {
      // Said where it happens, by a tick or by ~step: the step, the reason and the forces acting.
      track.divergence_message = result.message + externalForcesNote(k);
      ROS_ERROR("%s%s", tracks_.size() > 1 ? (track.name + ": ").c_str() : "", track.divergence_message.c_str());
    }
    else
      any_running = true;
  }
  return lockstep() ? any_running : !primary().simulation->diverged();
}

ros::Time SimulationNode::stamp() const
{
  return use_sim_time_ ? ros::Time(clock_seconds_) : ros::Time::now();
}

void SimulationNode::publishStaticFrames()
{
  const NodeParams& params = config_.node;
  std::vector<geometry_msgs::TransformStamped> frames;
  for (const Track& track : tracks_)
  {
    if (track.grid_frame.empty())
      continue;
    geometry_msgs::TransformStamped frame;
    frame.header.stamp = stamp();
    frame.header.frame_id = params.fixed_frame;
    frame.child_frame_id = track.grid_frame;
    frame.transform.translation.x = track.offset.x();
    frame.transform.translation.y = track.offset.y();
    frame.transform.translation.z = track.offset.z();
    frame.transform.rotation.w = 1.0;
    frames.push_back(frame);
  }
  static_broadcaster_.sendTransform(frames);
}

void SimulationNode::onTick()
{
  Output output;
  std::string status_line;
  bool status_warns = false;
  double period = 0.0;
  std::optional<Eigen::Vector3d> drag_marker;
  {
    std::unique_lock<std::mutex> lock(mutex_);
    adoptTrainedCubature();  // before a rebuild's swap: it was trained on the running model
    swapRebuilt();
    updateExternalForces();
    updateHandleTargets();
    updateColliderTargets();
    const NodeParams& params = config_.node;
    const double dt = config_.simulation.time_step;
    period = 1.0 / params.publish_rate;
    const double now = ros::WallTime::now().toSec();
    tick_steps_ = 0;
    tick_step_seconds_ = 0.0;
    for (Track& track : tracks_)
      track.startTick();
    const bool running = lockstep() ? std::any_of(tracks_.begin(), tracks_.end(),
                                                  [](const Track& t) { return !t.simulation->diverged(); })
                                    : !primary().simulation->diverged();
    if (!paused_ && running)
    {
      stepTick(lock, period);
      releaseSlippingGrasps();
    }
    for (Track& track : tracks_)
    {
      tick_steps_ = std::max(tick_steps_, track.tick_steps);
      track.finishTick();
    }
    clock_seconds_ += tick_steps_ * dt;
    achieved_factor_ = pacing_.achievedFactor(tick_steps_, dt, now, period);
    output = snapshot(stamp());
    drag_marker = dragMarkerTarget();

    if (params.status_log_period > 0.0 && (ros::WallTime::now() - last_status_log_).toSec() >= params.status_log_period)
    {
      last_status_log_ = ros::WallTime::now();
      status_warns = state(primary()) == Status::DIVERGED;
      status_line = statusLine();
    }
  }
  send(output);
  if (drag_marker)
    placeDragMarker(*drag_marker);

  // A tick is late when its stepping alone takes longer than the period: the timer cannot keep up.
  ++diag_ticks_;
  diag_step_seconds_ += tick_step_seconds_;
  if (tick_step_seconds_ > period)
    ++diag_late_ticks_;
  diagnostics_->update();

  if (status_warns)
    ROS_WARN("%s", status_line.c_str());
  else if (!status_line.empty())
    ROS_INFO("%s", status_line.c_str());
}

void SimulationNode::stepTick(std::unique_lock<std::mutex>& lock, double period)
{
  const NodeParams& params = config_.node;
  const double dt = config_.simulation.time_step;
  const int steps = pacing_.stepsOwed(params.real_time_factor, params.publish_rate, dt);
  const long changes = state_changes_;
  const auto tick_start = Clock::now();
  auto start = tick_start;
  int stepped = 0;  // how far along the tick the handles have moved
  for (int k = 0; k < steps; ++k)
  {
    if (services_waiting_.load() > 0)
    {
      // A service call goes in between two steps; a call that changes the state (pause, reset,
      // set_method, step) ends this tick's stepping.
      tick_step_seconds_ += secondsSince(start);
      lock.unlock();
      while (services_waiting_.load() > 0)
        std::this_thread::yield();
      lock.lock();
      start = Clock::now();
      if (state_changes_ != changes || paused_)
        break;
    }
    // A comparison shows every method at the same moment: when the slowest cannot keep up, a
    // tick steps for at most its period and drops the rest, so all slow down together.
    if (lockstep() && secondsSince(tick_start) > period)
    {
      pacing_.dropOwed();
      break;
    }
    setHandleMotion(steps * dt, static_cast<double>(k + 1) / steps);
    setColliderPoses(static_cast<double>(k + 1) / steps);
    stepped = k + 1;
    if (!stepAll())
      break;
  }
  tick_step_seconds_ += secondsSince(start);
  if (steps > 0)
  {
    handle_frames_->finishTick(steps * dt, static_cast<double>(stepped) / steps);
    collider_frames_->finishTick(static_cast<double>(stepped) / steps);
  }
}

void SimulationNode::warnDropped(const std::string& text)
{
  std::lock_guard<std::mutex> lock(warnings_mutex_);
  if (dropped_warnings_.allow(text, ros::SteadyTime::now().toSec()))
    ROS_WARN("%s", text.c_str());
}

}  // namespace modal_mass_spring
