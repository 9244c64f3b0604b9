// The node adds nothing numerical: it steps the core Simulation on a timer and shows its state.
#include "simulation_node.h"

#include "modal_mass_spring/Status.h"
#include "contact_messages.h"
#include "grid_messages.h"
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

// The largest ~step request: more would hold the services for minutes on a large grid.
constexpr uint32_t kMaxStepRequest = 10000;

// How long a handle's or a collider's frame never seen is waited for before its warning: a
// broadcaster launched beside the node needs a moment to come up.
constexpr double kFrameGraceSeconds = 5.0;

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

class SimulationNode::ServiceLock
{
public:
  explicit ServiceLock(SimulationNode& node) : node_(node)
  {
    ++node_.services_waiting_;  // the step loop sees this and lets go between two steps
    lock_ = std::unique_lock<std::mutex>(node_.mutex_);
    --node_.services_waiting_;
  }

private:
  SimulationNode& node_;
  std::unique_lock<std::mutex> lock_;
};

struct SimulationNode::Output
{
  struct Grid
  {
    ros::Publisher markers_pub, status_pub, points_pub;
    visualization_msgs::MarkerArray markers;
    Status status;
    sensor_msgs::PointCloud2 points;
    std::vector<std::pair<ros::Publisher, geometry_msgs::WrenchStamped>> wrenches;
  };
  std::vector<Grid> grids;
  std::vector<geometry_msgs::TransformStamped> frames;  // empty: no TF this time
  ros::Time stamp;
};

SimulationNode::SimulationNode(ros::NodeHandle& nh, ros::NodeHandle& private_nh) : nh_(nh), private_nh_(private_nh)
{
  // Every parameter is read and checked before anything is built, so a bad one fails at once even on
  // a grid whose basis would take minutes.
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
  const NodeParams& params = config_.node;
  // diagnostic_updater reads ~diagnostic_period itself, and only as a number: give it the checked one.
  private_nh_.setParam("diagnostic_period", params.diagnostic_period);
  // Under simulated time this node is the clock, as Gazebo is: it publishes /clock from its steps.
  use_sim_time_ = ros::Time::isSimTime();

  buildTracks();

  for (Track& track : tracks_)
  {
    if (track.shadow)
      continue;  // drawn with the method it shadows
    // A comparison publishes each method below its name: ~linear/markers, ~full/status, ...
    ros::NodeHandle track_nh = lockstep() ? ros::NodeHandle(private_nh_, track.name) : private_nh_;
    track.markers_pub = track_nh.advertise<visualization_msgs::MarkerArray>("markers", 1);
    track.status_pub = track_nh.advertise<Status>("status", 10);
    track.points_pub = track_nh.advertise<sensor_msgs::PointCloud2>("points", 1);
    for (size_t h = 0; h < params.handles.size(); ++h)
      track.handle_force_pubs.push_back(
          track_nh.advertise<geometry_msgs::WrenchStamped>("handle_force/handle_" + std::to_string(h), 10));
    for (size_t i = 0; i < config_.simulation.colliders.size(); ++i)
      track.contact_force_pubs.push_back(
          track_nh.advertise<geometry_msgs::WrenchStamped>("contact_force/collider_" + std::to_string(i), 10));
  }
  if (use_sim_time_)
    clock_pub_ = nh_.advertise<rosgraph_msgs::Clock>("/clock", 10);
  publishStaticFrames();

  const Grid& grid = primary().simulation->grid();
  diagnostics_ = std::make_unique<diagnostic_updater::Updater>(nh_, private_nh_);
  diagnostics_->setHardwareID("modal_mass_spring " + std::to_string(grid.params().rows) + "x" +
                              std::to_string(grid.params().cols) + " grid");
  diagnostics_->add("simulation", this, &SimulationNode::diagnose);

  // Services have their own queue and thread: a call waits for the step in progress, not the tick.
  ros::NodeHandle service_nh(private_nh_);
  service_nh.setCallbackQueue(&service_queue_);
  set_method_srv_ = service_nh.advertiseService("set_method", &SimulationNode::setMethod, this);
  reset_srv_ = service_nh.advertiseService("reset", &SimulationNode::reset, this);
  pause_srv_ = service_nh.advertiseService("pause", &SimulationNode::pause, this);
  step_srv_ = service_nh.advertiseService("step", &SimulationNode::step, this);
  clear_forces_srv_ = service_nh.advertiseService("clear_forces", &SimulationNode::clearForces, this);
  applied_forces_ = std::make_unique<AppliedForces>(primary().simulation->grid());
  external_force_ = Eigen::VectorXd::Zero(primary().simulation->positions().size());
  tf_listener_ = std::make_unique<tf2_ros::TransformListener>(tf_buffer_);
  handle_frames_ = std::make_unique<HandleFrames>(params.handles, primary().simulation->grid(),
                                                  primary().simulation->linearizationPositions(), params.offset);
  collider_frames_ = std::make_unique<ColliderFrames>(config_.simulation.colliders, params.offset);
  for (size_t k = 0; k < collider_frames_->size(); ++k)
    ROS_INFO("collider %d follows the TF frame '%s' relative to '%s' (inactive until the frame is found)",
             collider_frames_->collider(k), collider_frames_->frame(k).c_str(), params.fixed_frame.c_str());
  if (!params.handles.empty())
  {
    std::string frames;
    for (size_t h = 0; h < params.handles.size(); ++h)
      frames += (h ? ", '" : "'") + params.handles[h].frame + "' (" +
                std::to_string(params.handles[h].particles.size()) + " particles)";
    ROS_INFO("handles following the TF frames %s relative to '%s', offsets taken at each frame's first lookup",
             frames.c_str(), params.fixed_frame.c_str());
    ROS_INFO("%s", describeHandleFormulation(config_.grid, config_.simulation, handleFrames(params.handles)).c_str());
  }
  apply_force_sub_ = private_nh_.subscribe("apply_force", 10, &SimulationNode::applyForce, this);
  startInteraction();
  service_spinner_ = std::make_unique<ros::AsyncSpinner>(1, &service_queue_);
  service_spinner_->start();

  startLiveTuning();

  last_status_log_ = ros::WallTime::now();
  const double period = 1.0 / params.publish_rate;
  if (use_sim_time_)
    wall_timer_ = nh_.createWallTimer(ros::WallDuration(period), [this](const ros::WallTimerEvent&) { onTick(); });
  else
    timer_ = nh_.createTimer(ros::Duration(period), [this](const ros::TimerEvent&) { onTick(); });
}

SimulationNode::~SimulationNode()
{
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
}

std::unique_ptr<Simulation> SimulationNode::buildSimulation(const GridParams& grid_params,
                                                            const SimulationParams& sim_params, bool report,
                                                            const std::string& activity) const
{
  const auto start = Clock::now();
  StartupProgress progress([](const std::string& line) { ROS_INFO("%s", line.c_str()); },
                           [start] { return secondsSince(start); }, 1.0, 10.0, activity);
  std::unique_ptr<Simulation> simulation;
  {
    ProgressWatcher watcher(progress);
    CacheOptions cache{config_.node.cache_dir, [](const std::string& warning) { ROS_WARN("%s", warning.c_str()); }};
    simulation = std::make_unique<Simulation>(grid_params, sim_params,
                                              [&progress](const std::string& stage) { progress.onStage(stage); }, cache);
  }
  if (!report)
    return simulation;
  const double total_seconds = secondsSince(start);
  const NodeParams& params = config_.node;
  const Grid& grid = simulation->grid();
  ROS_INFO("%d x %d grid (%dD, %d particles, %zu springs, %zu fixed), method %s: %s; %s; time_step %g s, "
           "%.4g steps per tick at %g Hz, real_time_factor %g",
           grid.params().rows, grid.params().cols, grid.dimension(), grid.numParticles(), grid.springs().size(),
           grid.fixedParticles().size(), toString(simulation->method()).c_str(),
           describeModes(simulation->basis().frequencies, simulation->basis().num_zero_modes).c_str(),
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
  for (size_t k = 0; k < methods.size(); ++k)
  {
    SimulationParams sim_params = config_.simulation;
    sim_params.method = methods[k];
    Track track;
    track.name = toString(methods[k]);
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
  const Track* source = nullptr;
  for (const Track& track : tracks_)
    if (track.simulation->method() != Method::Full || (!lockstep() && &track == &tracks_.front()))
    {
      source = &track;
      break;
    }
  if (!source)
    return;
  const Eigen::VectorXd u = source->simulation->displacement(), v = source->simulation->velocity();
  for (Track& track : tracks_)
    if (&track != source && track.simulation->method() == Method::Full)
    {
      track.simulation->setPhysicalState(u, v);
      track.divergence_message.clear();
    }
}

const SimulationNode::Track* SimulationNode::reference() const
{
  for (const Track& track : tracks_)
    if (track.shadow || (lockstep() && track.simulation->method() == Method::Full))
      return &track;
  return nullptr;
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
    const auto stamped = tf_buffer_.lookupTransform(config_.node.fixed_frame, frame, ros::Time(0));
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
  // A collider not placed yet on a track (its frame just found, or the track built anew by a rebuild
  // while paused) appears now, where its frame is, even if no step follows.
  for (size_t k = 0; k < collider_frames_->size(); ++k)
    if (const std::optional<Eigen::Isometry3d> pose = collider_frames_->pose(k, 0.0))
      for (Track& track : tracks_)
        if (const Contact* contact = track.simulation->contact(); contact && !contact->active(collider_frames_->collider(k)))
          track.simulation->setColliderPose(collider_frames_->collider(k), *pose);
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
  if (primary().simulation->handleFormulation() == HandleFormulation::MovingFrame)
  {
    // Every track simulates in the frame: its motion, from the same interpolation.
    const FrameMotion motion = handle_frames_->frameMotion(duration, s);
    try
    {
      for (Track& track : tracks_)
        if (!track.simulation->diverged())
          track.simulation->setHandleFrameMotion(motion);
    }
    catch (const std::invalid_argument& error)
    {
      // A 2D grid's frame that turns out of the grid's plane: held where it was.
      ROS_WARN_THROTTLE(5.0, "handle frame '%s' refused, its particles hold where they are: %s",
                        handle_frames_->frame(0).c_str(), error.what());
    }
    return;
  }
  Eigen::VectorXd x, v, a;
  handle_frames_->motion(duration, s, x, v, a);
  for (Track& track : tracks_)
    if (!track.simulation->diverged())
      track.simulation->setHandleMotion(x, v, a);
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
    const StepResult result = track.simulation->step(1);
    track.tick_seconds += secondsSince(start);
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
    swapRebuilt();
    updateExternalForces();
    updateHandleTargets();
    updateColliderTargets();
    const NodeParams& params = config_.node;
    const double dt = config_.simulation.time_step;
    period = 1.0 / params.publish_rate;
    const ros::WallTime now = ros::WallTime::now();
    const double wall = last_tick_.isZero() ? period : (now - last_tick_).toSec();
    last_tick_ = now;
    tick_steps_ = 0;
    tick_step_seconds_ = 0.0;
    for (Track& track : tracks_)
    {
      track.tick_seconds = 0.0;
      track.tick_steps = 0;
    }
    const bool running = lockstep() ? std::any_of(tracks_.begin(), tracks_.end(),
                                                  [](const Track& t) { return !t.simulation->diverged(); })
                                    : !primary().simulation->diverged();
    if (!paused_ && running)
    {
      // A fixed simulated time per tick, in whole steps; how late the tick is does not matter.
      owed_steps_ += params.real_time_factor / (params.publish_rate * dt);
      const int steps = static_cast<int>(std::floor(owed_steps_ + 1e-9));
      owed_steps_ = std::max(0.0, owed_steps_ - steps);
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
          owed_steps_ = 0.0;
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
        handle_frames_->finishTick(static_cast<double>(stepped) / steps);
        collider_frames_->finishTick(static_cast<double>(stepped) / steps);
      }
    }
    for (Track& track : tracks_)
    {
      tick_steps_ = std::max(tick_steps_, track.tick_steps);
      if (track.tick_steps > 0)
        track.step_seconds = track.tick_seconds / track.tick_steps;
    }
    clock_seconds_ += tick_steps_ * dt;
    achieved_factor_ = tick_steps_ * dt / std::max(wall, 1e-9);
    output = snapshot(stamp());
    drag_marker = dragMarkerTarget();

    if (params.status_log_period > 0.0 && (ros::WallTime::now() - last_status_log_).toSec() >= params.status_log_period)
    {
      last_status_log_ = ros::WallTime::now();
      const Track& first = primary();
      status_warns = state(first) == Status::DIVERGED;
      char line[320];
      std::snprintf(line, sizeof line,
                    "%s: method %s, step %ld, simulated %.3f s, energy %.6g J, %.3f ms of stepping per tick%s",
                    stateName(first).c_str(), lockstep() ? "s in lockstep" : toString(first.simulation->method()).c_str(),
                    steps(first), simTime(first), first.last_energy,
                    1e3 * tick_step_seconds_,
                    lockstep() ? (", real-time factor " + std::to_string(achieved_factor_)).c_str() : "");
      status_line = line;
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

SimulationNode::Output SimulationNode::snapshot(const ros::Time& stamp)
{
  const NodeParams& params = config_.node;
  Output output;
  output.stamp = stamp;
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
    const Eigen::VectorXd distances = (track.last_points - ref->last_points).colwise().norm();
    track.rms_distance = std::sqrt(distances.squaredNorm() / std::max<Eigen::Index>(1, distances.size()));
    track.max_distance = distances.maxCoeff();
  }

  // tf2 rejects a second transform of a frame at the same stamp (e.g. a paused /clock): skip it.
  const bool send_tf = stamp > last_tf_stamp_ && !params.tf_particles.empty();
  if (send_tf)
    last_tf_stamp_ = stamp;
  for (const Track& track : tracks_)
  {
    if (track.shadow)
      continue;
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
    {
      options.label = toString(simulation.method()) +
                      (measured ? "\nRMS " + formatDistance(track.rms_distance) + " to full" : "") + "\n" +
                      formatCost(track.step_seconds);
      if (lockstep())
      {
        char pace[64];
        std::snprintf(pace, sizeof pace, "\n%.2f x real time", achieved_factor_);
        options.label += pace;
      }
    }
    // One pass over the springs for both the surface's colours and the cloud.
    const Eigen::VectorXd strains = particleStrains(simulation.grid(), track.last_points);
    grid.markers = makeMarkers(simulation.grid(), options, track.last_points, stamp, strains);
    if (const Contact* contact = simulation.contact())
    {
      const auto colliders = colliderMarkers(*contact, options.frame_id, track.offset, track.ns_prefix + "colliders", stamp);
      grid.markers.markers.insert(grid.markers.markers.end(), colliders.markers.begin(), colliders.markers.end());
      for (size_t i = 0; i < track.contact_force_pubs.size() && i < contact->report().force.size(); ++i)
        grid.wrenches.emplace_back(track.contact_force_pubs[i],
                                   forceWrench(contact->report().force[i], options.frame_id, stamp));
    }
    if (!track.handle_force_pubs.empty())
    {
      const std::vector<Eigen::Vector3d> forces = simulation.handleForces();
      for (size_t h = 0; h < track.handle_force_pubs.size() && h < forces.size(); ++h)
      {
        if (!forces[h].allFinite())
          continue;
        // In the handle's own frame once it was found (what a force-torque sensor at the gripper
        // reads; tf2 turns it into any other frame), in fixed_frame axes before.
        if (handle_frames_->everFound(h))
          grid.wrenches.emplace_back(track.handle_force_pubs[h],
                                     forceWrench(handle_frames_->current(h).rotation.conjugate() * forces[h],
                                                 handle_frames_->frame(h), stamp));
        else
          grid.wrenches.emplace_back(track.handle_force_pubs[h], forceWrench(forces[h], options.frame_id, stamp));
      }
    }
    if (measured && ref->shadow)
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
    grid.points = makePointCloud(track.last_points, strains,
                                 track.offset, params.fixed_frame, stamp);

    Status& status = grid.status;
    status.header.stamp = stamp;
    status.header.frame_id = params.fixed_frame;
    status.method = toString(simulation.method());
    status.linearization = toString(simulation.params().linearization);
    status.integrator = toString(simulation.params().integrator);
    status.newton_iterations = simulation.lastNewtonIterations();
    status.step_count = steps(track);
    status.sim_time = simTime(track);
    status.tick_steps = track.tick_steps;
    status.tick_step_seconds = lockstep() ? track.tick_seconds : tick_step_seconds_;
    status.total_energy = track.last_energy;
    status.state = state(track);
    status.message = simulation.diverged() ? track.divergence_message : "";
    status.handles = handle_frames_->status();
    status.handle_formulation =
        handle_frames_->empty() ? "" : toString(simulation.handleFormulation());
    status.applied_forces = static_cast<uint32_t>(applied_forces_->size());
    status.dragged_particle = hand_forces_ ? hand_forces_->draggedParticle() : -1;
    status.reference = measured ? "full" : "";
    status.rms_distance = track.rms_distance;
    status.max_distance = track.max_distance;
    status.step_seconds = track.step_seconds;
    status.real_time_factor = achieved_factor_;
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

    if (send_tf)
      for (int particle : params.tf_particles)
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
    output.grids.push_back(std::move(grid));
  }
  return output;
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
    ROS_WARN_THROTTLE(kBehindWarningPeriod,
                      "%s: %s takes %.3g ms a step and a tick asks for %.1f steps (real_time_factor / "
                      "(publish_rate time_step)); a smaller real_time_factor, a larger time_step or a cheaper "
                      "method keeps up",
                      behind, lockstep() ? "the slowest method in lockstep" : ("method " + toString(simulation.method())).c_str(),
                      1e3 * step_seconds,
                      params.real_time_factor / (params.publish_rate * config_.simulation.time_step));
  }
  else
    status.summary(diagnostic_msgs::DiagnosticStatus::OK, paused_ ? "paused" : "stepping");
  if (!handle_frames_->status().empty())  // whatever else is said
    status.mergeSummary(diagnostic_msgs::DiagnosticStatus::WARN,
                        "handles " + handle_frames_->status() + " (their particles hold where they are)");
  if (!collider_frames_->status().empty())
    status.mergeSummary(diagnostic_msgs::DiagnosticStatus::WARN, collider_frames_->status());
  status.add("state", stateName(first));
  status.add("method", lockstep() ? "lockstep" : toString(simulation.method()));
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
  Simulation& simulation = *primary().simulation;
  Method method;
  try
  {
    method = parseMethod(request.method);
  }
  catch (const std::invalid_argument&)
  {
    std::string names;
    for (const auto& name : methodNames())
      names += (names.empty() ? "" : ", ") + name;
    response.success = false;
    response.message = "unknown method '" + request.method + "': must be one of " + names +
                       "; still running '" + toString(simulation.method()) + "'";
    return true;
  }
  const std::string previous = toString(simulation.method());
  const bool was_diverged = simulation.diverged();
  const bool trains = method == Method::Cubature && !simulation.cubature();
  try
  {
    simulation.setMethod(method);  // trains before it replaces anything: a failure keeps the run
  }
  catch (const std::exception& error)
  {
    response.success = false;
    response.message = "cannot switch to " + request.method + ": " + error.what() + "; still running '" + previous + "'";
    ROS_ERROR("%s", response.message.c_str());
    return true;
  }
  if (trains)
    ROS_INFO("%s", describeCubature(*simulation.cubature(), static_cast<int>(simulation.grid().springs().size()),
                                    simulation.params().cubature_tolerance)
                       .c_str());
  primary().name = toString(method);
  primary().divergence_message.clear();
  synchronise();  // the shadow full starts again from the state carried over
  ++state_changes_;
  response.success = true;
  response.message = "switched from " + previous + " to " + request.method + " at step " +
                     std::to_string(steps(primary())) + (was_diverged ? ", recovering from the divergence" : "");
  if (was_diverged)  // forces that caused it act on, as after a reset
    response.message += forcesActingNote();
  ROS_INFO("%s", response.message.c_str());
  return true;
}

bool SimulationNode::reset(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& response)
{
  ServiceLock lock(*this);
  for (Track& track : tracks_)
  {
    track.simulation->reset();
    track.step_offset = 0;
    track.divergence_message.clear();
  }
  handle_frames_->reset();
  synchronise();
  owed_steps_ = 0.0;
  ++state_changes_;
  response.success = true;
  response.message = "reset to the initial state at rest (method " +
                     (lockstep() ? std::string("s in lockstep") : toString(primary().simulation->method())) +
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
    {
      track.tick_seconds = 0.0;
      track.tick_steps = 0;
    }
    uint32_t taken = 0;
    while (taken < request.steps && stepAll())
      ++taken;
    int stepped = 0;
    for (Track& track : tracks_)
    {
      stepped = std::max(stepped, track.tick_steps);
      if (track.tick_steps > 0)
        track.step_seconds = track.tick_seconds / track.tick_steps;
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

void SimulationNode::warnDropped(const std::string& text)
{
  std::lock_guard<std::mutex> lock(warnings_mutex_);
  if (dropped_warnings_.allow(text, ros::SteadyTime::now().toSec()))
    ROS_WARN("%s", text.c_str());
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
