// The node adds nothing numerical: it steps the core Simulation on a timer and shows its state.
#include "simulation_node.h"

#include "modal_mass_spring/Status.h"
#include "grid_messages.h"
#include "startup_report.h"
#include "xmlrpc_parameter_source.h"

#include <geometry_msgs/TransformStamped.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <condition_variable>
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

SimulationNode::SimulationNode(ros::NodeHandle& nh, ros::NodeHandle& private_nh) : nh_(nh), private_nh_(private_nh)
{
  // Every parameter is read and checked before anything is built, so a bad one fails at once even on
  // a grid whose basis would take minutes.
  XmlRpc::XmlRpcValue private_params;
  if (!ros::param::get(private_nh_.getNamespace(), private_params))
    private_params = XmlRpc::XmlRpcValue();
  const XmlRpcParameterSource source(private_params);
  config_ = loadNodeConfiguration(source, source.keys());
  for (const auto& key : config_.unknown_keys)
    ROS_WARN("parameter '%s/%s' is not a parameter of this node and is ignored", private_nh_.getNamespace().c_str(),
             key.c_str());
  // diagnostic_updater reads ~diagnostic_period itself, and only as a number: give it the checked one.
  private_nh_.setParam("diagnostic_period", params_.diagnostic_period);

  buildSimulation();

  markers_pub_ = private_nh_.advertise<visualization_msgs::MarkerArray>("markers", 1);
  status_pub_ = private_nh_.advertise<Status>("status", 10);
  publishStaticFrame();

  const Grid& grid = simulation_->grid();
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
  service_spinner_ = std::make_unique<ros::AsyncSpinner>(1, &service_queue_);
  service_spinner_->start();

  last_status_log_ = ros::WallTime::now();
  timer_ = nh_.createTimer(ros::Duration(1.0 / params_.publish_rate), &SimulationNode::onTick, this);
}

SimulationNode::~SimulationNode()
{
  if (service_spinner_)
    service_spinner_->stop();
  timer_.stop();
}

void SimulationNode::buildSimulation()
{
  const SimulationParams& sim_params = config_.simulation;
  const auto start = Clock::now();
  StartupProgress progress([](const std::string& line) { ROS_INFO("%s", line.c_str()); },
                           [start] { return secondsSince(start); });
  {
    ProgressWatcher watcher(progress);
    simulation_ = std::make_unique<Simulation>(config_.grid, sim_params,
                                               [&progress](const std::string& stage) { progress.onStage(stage); });
  }
  const double total_seconds = secondsSince(start);

  steps_per_tick_ = params_.real_time_factor / (params_.publish_rate * sim_params.time_step);
  last_points_ = simulation_->points();

  const Grid& grid = simulation_->grid();
  ROS_INFO("%d x %d grid (%dD, %d particles, %zu springs, %zu fixed), method %s: %s; %s; time_step %g s, "
           "%.4g steps per tick at %g Hz, real_time_factor %g",
           grid.params().rows, grid.params().cols, grid.dimension(), grid.numParticles(), grid.springs().size(),
           grid.fixedParticles().size(), toString(simulation_->method()).c_str(),
           describeModes(simulation_->basis().frequencies, simulation_->basis().num_zero_modes).c_str(),
           describeStartupTimes(simulation_->linearization(), simulation_->basis(), total_seconds).c_str(),
           sim_params.time_step, steps_per_tick_, params_.publish_rate, params_.real_time_factor);
  const LinearizationInfo& lin = simulation_->linearization();
  ROS_INFO("linearization %s, integrator %s, initial_state %s%s", toString(sim_params.linearization).c_str(),
           toString(sim_params.integrator).c_str(), toString(sim_params.initial_state).c_str(),
           lin.equilibrium_solved
               ? (": equilibrium in " + std::to_string(lin.equilibrium_iterations) + " Newton iterations, " +
                  std::to_string(lin.dropped_compressed_springs) + " compressed springs' geometric stiffness dropped, " +
                  "start projected onto the modes with a largest error of " +
                  std::to_string(simulation_->projectionError()) + " m")
                     .c_str()
               : "");
}

void SimulationNode::publishStaticFrame()
{
  geometry_msgs::TransformStamped frame;
  frame.header.stamp = ros::Time::now();
  frame.header.frame_id = params_.fixed_frame;
  frame.child_frame_id = params_.grid_frame;
  frame.transform.translation.x = params_.offset.x();
  frame.transform.translation.y = params_.offset.y();
  frame.transform.translation.z = params_.offset.z();
  frame.transform.rotation.w = 1.0;
  static_broadcaster_.sendTransform(frame);
}

void SimulationNode::onTick(const ros::TimerEvent&)
{
  const double period = 1.0 / params_.publish_rate;
  const ros::Time stamp = ros::Time::now();
  // tf2 rejects a second transform of a frame at the same stamp (e.g. a paused /clock): skip it.
  const bool send_tf = stamp > last_tf_stamp_ && !params_.tf_particles.empty();
  visualization_msgs::MarkerArray markers;
  std::vector<geometry_msgs::TransformStamped> frames;
  Status status;
  std::string divergence, status_line;
  {
    std::unique_lock<std::mutex> lock(mutex_);
    tick_steps_ = 0;
    tick_step_seconds_ = 0.0;
    if (!paused_ && !simulation_->diverged())
    {
      // A fixed simulated time per tick, in whole steps; how late the tick is does not matter.
      owed_steps_ += steps_per_tick_;
      const int steps = static_cast<int>(std::floor(owed_steps_ + 1e-9));
      owed_steps_ = std::max(0.0, owed_steps_ - steps);
      const long changes = state_changes_;
      auto start = Clock::now();
      for (int k = 0; k < steps; ++k)
      {
        if (services_waiting_.load() > 0)
        {
          // A service call goes in between two steps; a call that changes the state (pause, reset,
          // set_method) ends this tick's stepping.
          tick_step_seconds_ += secondsSince(start);
          lock.unlock();
          while (services_waiting_.load() > 0)
            std::this_thread::yield();
          lock.lock();
          start = Clock::now();
          if (state_changes_ != changes || paused_ || simulation_->diverged())
            break;
        }
        const StepResult result = simulation_->step(1);
        tick_steps_ += result.steps_taken;
        if (result.diverged)
        {
          divergence_message_ = divergence = result.message;
          break;
        }
      }
      tick_step_seconds_ += secondsSince(start);
    }

    // The core keeps the last good state on divergence; never publish a non-finite one anyway.
    const Eigen::Matrix3Xd points = simulation_->points();
    if (points.allFinite())
      last_points_ = points;
    const double energy = simulation_->totalEnergy();
    if (std::isfinite(energy))
      last_energy_ = energy;
    markers = makeMarkers(simulation_->grid(), markerOptions(params_), last_points_, stamp);
    if (send_tf)
    {
      frames.reserve(params_.tf_particles.size());
      for (int particle : params_.tf_particles)
      {
        geometry_msgs::TransformStamped frame;
        frame.header.stamp = stamp;
        frame.header.frame_id = params_.grid_frame;
        frame.child_frame_id = particleFrame(params_.grid_frame, particle);
        frame.transform.translation.x = last_points_(0, particle);
        frame.transform.translation.y = last_points_(1, particle);
        frame.transform.translation.z = last_points_(2, particle);
        frame.transform.rotation.w = 1.0;
        frames.push_back(frame);
      }
    }
    status.header.stamp = stamp;
    status.header.frame_id = params_.fixed_frame;
    status.method = toString(simulation_->method());
    status.linearization = toString(simulation_->params().linearization);
    status.integrator = toString(simulation_->params().integrator);
    status.newton_iterations = simulation_->lastNewtonIterations();
    status.step_count = simulation_->stepCount();
    status.sim_time = simulation_->time();
    status.tick_steps = tick_steps_;
    status.tick_step_seconds = tick_step_seconds_;
    status.total_energy = last_energy_;
    status.state = state();
    status.message = simulation_->diverged() ? divergence_message_ : "";

    if (params_.status_log_period > 0.0 && (ros::WallTime::now() - last_status_log_).toSec() >= params_.status_log_period)
    {
      last_status_log_ = ros::WallTime::now();
      char line[256];
      std::snprintf(line, sizeof line, "%s: method %s, step %ld, simulated %.3f s, energy %.6g J, %.3f ms of stepping per tick",
                    stateName().c_str(), status.method.c_str(), simulation_->stepCount(), simulation_->time(),
                    last_energy_, 1e3 * tick_step_seconds_);
      status_line = line;
    }
  }
  if (!divergence.empty())
    ROS_ERROR("%s", divergence.c_str());

  markers_pub_.publish(markers);
  if (send_tf)
  {
    tf_broadcaster_.sendTransform(frames);
    last_tf_stamp_ = stamp;
  }
  status_pub_.publish(status);

  // A tick is late when its stepping alone takes longer than the period: the timer cannot keep up.
  ++diag_ticks_;
  diag_step_seconds_ += tick_step_seconds_;
  if (tick_step_seconds_ > period)
    ++diag_late_ticks_;
  diagnostics_->update();

  if (!status_line.empty())
    ROS_INFO("%s", status_line.c_str());
}

uint8_t SimulationNode::state() const
{
  if (simulation_->diverged())
    return Status::DIVERGED;
  return paused_ ? Status::PAUSED : Status::RUNNING;
}

std::string SimulationNode::stateName() const
{
  switch (state())
  {
    case Status::DIVERGED:
      return "DIVERGED";
    case Status::PAUSED:
      return "PAUSED";
    default:
      return "RUNNING";
  }
}

void SimulationNode::diagnose(diagnostic_updater::DiagnosticStatusWrapper& status)
{
  const double period = 1.0 / params_.publish_rate;
  const double mean_cost = diag_ticks_ ? diag_step_seconds_ / diag_ticks_ : 0.0;
  std::lock_guard<std::mutex> lock(mutex_);
  if (simulation_->diverged())
    status.summary(diagnostic_msgs::DiagnosticStatus::ERROR, "diverged: " + divergence_message_);
  else if (diag_ticks_ > 0 && (mean_cost > period || 2 * diag_late_ticks_ > diag_ticks_))
    status.summaryf(diagnostic_msgs::DiagnosticStatus::WARN,
                    "falling behind real time: %.2f ms of stepping per %.2f ms tick, %d of %d ticks late "
                    "(stepping longer than the period)",
                    1e3 * mean_cost, 1e3 * period, diag_late_ticks_, diag_ticks_);
  else
    status.summary(diagnostic_msgs::DiagnosticStatus::OK, paused_ ? "paused" : "stepping");
  status.add("state", stateName());
  status.add("method", toString(simulation_->method()));
  status.add("step count", simulation_->stepCount());
  status.add("simulated time (s)", simulation_->time());
  status.add("steps per tick", steps_per_tick_);
  status.add("mean stepping per tick (s)", mean_cost);
  status.add("tick period (s)", period);
  status.add("ticks", diag_ticks_);
  status.add("late ticks (stepping longer than the period)", diag_late_ticks_);
  status.add("modes", static_cast<int>(simulation_->basis().frequencies.size()));
  diag_ticks_ = diag_late_ticks_ = 0;
  diag_step_seconds_ = 0.0;
}

bool SimulationNode::setMethod(SetMethod::Request& request, SetMethod::Response& response)
{
  ServiceLock lock(*this);
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
                       "; still running '" + toString(simulation_->method()) + "'";
    return true;
  }
  const std::string previous = toString(simulation_->method());
  const bool was_diverged = simulation_->diverged();
  simulation_->setMethod(method);
  divergence_message_.clear();
  ++state_changes_;
  response.success = true;
  response.message = "switched from " + previous + " to " + request.method + " at step " +
                     std::to_string(simulation_->stepCount()) + (was_diverged ? ", recovering from the divergence" : "");
  ROS_INFO("%s", response.message.c_str());
  return true;
}

bool SimulationNode::reset(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& response)
{
  ServiceLock lock(*this);
  simulation_->reset();
  owed_steps_ = 0.0;
  divergence_message_.clear();
  ++state_changes_;
  response.success = true;
  response.message = "reset to the initial state at rest (method " + toString(simulation_->method()) +
                     (paused_ ? ", still paused)" : ")");
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
  response.message = std::string(paused_ ? "paused" : "running") + " at step " + std::to_string(simulation_->stepCount());
  ROS_INFO("%s", response.message.c_str());
  return true;
}

}  // namespace modal_mass_spring
