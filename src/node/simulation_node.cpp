// The node adds nothing numerical: it steps the core Simulation on a timer and shows its state.
#include "simulation_node.h"

#include "modal_mass_spring/Status.h"
#include "modal_mass_spring/parameters.h"
#include "modal_mass_spring/validation.h"
#include "ros_parameter_source.h"

#include <geometry_msgs/TransformStamped.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace modal_mass_spring
{
namespace
{

// More steps per tick than this would stall the timer for seconds; it is a configuration mistake.
constexpr double kMaxStepsPerTick = 100000.0;


double positive(const ParameterSource& s, const std::string& name, double fallback, double max)
{
  const double value = s.getDouble(name).value_or(fallback);
  if (!std::isfinite(value) || value <= 0.0 || value > max)
  {
    std::ostringstream allowed;
    allowed << "must be a number > 0 and <= " << max;
    rejectParameter(name, value, allowed.str());
  }
  return value;
}

std::string frameId(const ParameterSource& s, const std::string& name, const std::string& fallback)
{
  const std::string value = s.getString(name).value_or(fallback);
  if (value.empty() || value.front() == '/' || value.find_first_of(" \t\n") != std::string::npos)
    rejectParameter(name, "'" + value + "'", "must be a non-empty frame id without a leading '/' or spaces");
  return value;
}

std_msgs::ColorRGBA rgba(float r, float g, float b, float a = 1.0f)
{
  std_msgs::ColorRGBA c;
  c.r = r;
  c.g = g;
  c.b = b;
  c.a = a;
  return c;
}

geometry_msgs::Point point(const Eigen::Vector3d& p)
{
  geometry_msgs::Point msg;
  msg.x = p.x();
  msg.y = p.y();
  msg.z = p.z();
  return msg;
}

}  // namespace

std::string particleFrame(const std::string& grid_frame, int particle)
{
  return grid_frame + "/particle_" + std::to_string(particle);
}

NodeParams loadNodeParams(const ParameterSource& s, const GridParams& grid, const SimulationParams& sim)
{
  NodeParams p;
  p.real_time_factor = positive(s, "real_time_factor", p.real_time_factor, 1000.0);
  p.publish_rate = positive(s, "publish_rate", p.publish_rate, 1000.0);
  const double steps_per_tick = p.real_time_factor / (p.publish_rate * sim.time_step);
  if (steps_per_tick > kMaxStepsPerTick)
  {
    std::ostringstream allowed;
    allowed << "real_time_factor / (publish_rate * time_step) = " << steps_per_tick
            << " steps per tick; must be at most " << kMaxStepsPerTick
            << " (lower real_time_factor, raise publish_rate or time_step)";
    rejectParameter("real_time_factor", p.real_time_factor, allowed.str());
  }

  p.fixed_frame = frameId(s, "fixed_frame", p.fixed_frame);
  p.grid_frame = frameId(s, "grid_frame", p.grid_frame);
  if (p.grid_frame == p.fixed_frame)
    rejectParameter("grid_frame", "'" + p.grid_frame + "'", "must differ from fixed_frame");

  const int n = grid.rows * grid.cols;
  // The two bottom corners: the particles that move most under gravity.
  std::vector<int> corners{(grid.rows - 1) * grid.cols, n - 1};
  corners.erase(std::unique(corners.begin(), corners.end()), corners.end());
  p.tf_particles = s.getIntList("tf_particles").value_or(corners);
  checkParticleIndices("tf_particles", p.tf_particles, n);

  if (const auto offset = s.getDoubleList("offset"))
  {
    if (offset->size() != 3 || !std::all_of(offset->begin(), offset->end(), [](double v) { return std::isfinite(v); }))
      rejectParameter("offset", std::to_string(offset->size()) + " values", "must be a list of 3 finite numbers [x, y, z] in m");
    p.offset = Eigen::Vector3d((*offset)[0], (*offset)[1], (*offset)[2]);
  }
  p.color_by_strain = s.getBool("color_by_strain").value_or(p.color_by_strain);
  p.strain_scale = positive(s, "strain_scale", p.strain_scale, 1e6);
  const double spacing = std::isfinite(grid.spacing) && grid.spacing > 0.0 ? grid.spacing : 1.0;
  p.particle_diameter = positive(s, "particle_diameter", 0.3 * spacing, 1e6);
  p.spring_width = positive(s, "spring_width", 0.06 * spacing, 1e6);
  p.status_log_period = s.getDouble("status_log_period").value_or(p.status_log_period);
  if (!std::isfinite(p.status_log_period) || p.status_log_period < 0.0)
    rejectParameter("status_log_period", p.status_log_period, "must be a number of seconds >= 0 (0: no status lines)");
  return p;
}

SimulationNode::SimulationNode(ros::NodeHandle& nh, ros::NodeHandle& private_nh)
  : nh_(nh), private_nh_(private_nh), diagnostics_(nh, private_nh)
{
  RosParameterSource source(private_nh_);
  const GridParams grid_params = loadGridParams(source);
  const SimulationParams sim_params = loadSimulationParams(source);
  // The core validates its parameters first: the node's own checks (tf_particles, steps per tick)
  // rely on a valid grid and time step.
  simulation_ = std::make_unique<Simulation>(grid_params, sim_params);
  params_ = loadNodeParams(source, grid_params, sim_params);
  source.getDouble("diagnostic_period");  // read by diagnostic_updater itself
  for (const auto& key : source.unqueried())
    ROS_WARN("parameter '%s/%s' is not a parameter of this node and is ignored", private_nh_.getNamespace().c_str(),
             key.c_str());

  steps_per_tick_ = params_.real_time_factor / (params_.publish_rate * sim_params.time_step);
  last_points_ = simulation_->points();

  const Grid& grid = simulation_->grid();
  const ModalBasis& basis = simulation_->basis();
  const int r = static_cast<int>(basis.frequencies.size());
  double lowest_nonzero = 0.0;
  for (int k = 0; k < r; ++k)
    if (basis.frequencies[k] > 0.0)
    {
      lowest_nonzero = basis.frequencies[k];
      break;
    }
  ROS_INFO("%d x %d grid (%dD, %d particles, %zu springs, %zu fixed), method %s: %d modes in %.1f ms, "
           "frequencies %.4g to %.4g rad/s, %d zero (lowest non-zero %.4g rad/s); time_step %g s, "
           "%.4g steps per tick at %g Hz, real_time_factor %g",
           grid.params().rows, grid.params().cols, grid.dimension(), grid.numParticles(), grid.springs().size(),
           grid.fixedParticles().size(), toString(simulation_->method()).c_str(), r, 1e3 * basis.build_seconds,
           r ? basis.frequencies.minCoeff() : 0.0, r ? basis.frequencies.maxCoeff() : 0.0, basis.num_zero_modes,
           lowest_nonzero, sim_params.time_step, steps_per_tick_, params_.publish_rate, params_.real_time_factor);
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

  markers_pub_ = private_nh_.advertise<visualization_msgs::MarkerArray>("markers", 1);
  status_pub_ = private_nh_.advertise<Status>("status", 10);
  publishStaticFrame();

  diagnostics_.setHardwareID("modal_mass_spring " + std::to_string(grid.params().rows) + "x" +
                             std::to_string(grid.params().cols) + " grid");
  diagnostics_.add("simulation", this, &SimulationNode::diagnose);

  set_method_srv_ = private_nh_.advertiseService("set_method", &SimulationNode::setMethod, this);
  reset_srv_ = private_nh_.advertiseService("reset", &SimulationNode::reset, this);
  pause_srv_ = private_nh_.advertiseService("pause", &SimulationNode::pause, this);

  last_status_log_ = ros::WallTime::now();
  timer_ = nh_.createTimer(ros::Duration(1.0 / params_.publish_rate), &SimulationNode::onTick, this);
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

void SimulationNode::onTick(const ros::TimerEvent& event)
{
  const double period = 1.0 / params_.publish_rate;
  tick_steps_ = 0;
  tick_step_seconds_ = 0.0;
  if (!paused_ && !simulation_->diverged())
  {
    // A fixed simulated time per tick, in whole steps; how late the tick is does not matter.
    owed_steps_ += steps_per_tick_;
    const int steps = static_cast<int>(std::floor(owed_steps_ + 1e-9));
    owed_steps_ = std::max(0.0, owed_steps_ - steps);
    const auto start = std::chrono::steady_clock::now();
    const StepResult result = simulation_->step(steps);
    tick_step_seconds_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    tick_steps_ = result.steps_taken;
    if (result.diverged)
    {
      divergence_message_ = result.message;
      ROS_ERROR("%s", result.message.c_str());
    }
  }

  ++diag_ticks_;
  diag_step_seconds_ += tick_step_seconds_;
  if (tick_step_seconds_ > period)
    ++diag_slow_ticks_;
  if (!event.current_expected.isZero() && (event.current_real - event.current_expected).toSec() > period)
    ++diag_late_ticks_;

  const ros::Time stamp = ros::Time::now();
  // tf2 rejects a second transform of a frame at the same stamp (e.g. a paused /clock): skip it.
  const bool send_tf = stamp > last_tf_stamp_;
  publish(stamp, send_tf);
  if (send_tf)
    last_tf_stamp_ = stamp;
  diagnostics_.update();

  if (params_.status_log_period > 0.0 &&
      (ros::WallTime::now() - last_status_log_).toSec() >= params_.status_log_period)
  {
    last_status_log_ = ros::WallTime::now();
    ROS_INFO("%s: method %s, step %ld, simulated %.3f s, energy %.6g J, %.3f ms of stepping per tick",
             stateName().c_str(), toString(simulation_->method()).c_str(), simulation_->stepCount(),
             simulation_->time(), simulation_->totalEnergy(), 1e3 * tick_step_seconds_);
  }
}

void SimulationNode::publish(const ros::Time& stamp, bool send_tf)
{
  // The core keeps the last good state on divergence; never publish a non-finite one anyway.
  const Eigen::Matrix3Xd points = simulation_->points();
  if (points.allFinite())
    last_points_ = points;

  markers_pub_.publish(makeMarkers(last_points_, stamp));

  if (send_tf && !params_.tf_particles.empty())
  {
    std::vector<geometry_msgs::TransformStamped> frames;
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
    tf_broadcaster_.sendTransform(frames);
  }

  Status status;
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
  const double energy = simulation_->totalEnergy();
  status.total_energy = std::isfinite(energy) ? energy : 0.0;
  status.state = state();
  status.message = simulation_->diverged() ? divergence_message_ : "";
  status_pub_.publish(status);
}

visualization_msgs::MarkerArray SimulationNode::makeMarkers(const Eigen::Matrix3Xd& points, const ros::Time& stamp) const
{
  const Grid& grid = simulation_->grid();
  visualization_msgs::MarkerArray array;
  visualization_msgs::Marker particles;
  particles.header.frame_id = params_.fixed_frame;
  particles.header.stamp = stamp;
  particles.ns = "particles";
  particles.id = 0;
  particles.type = visualization_msgs::Marker::SPHERE_LIST;
  particles.action = visualization_msgs::Marker::ADD;
  particles.pose.orientation.w = 1.0;
  particles.scale.x = particles.scale.y = particles.scale.z = params_.particle_diameter;
  particles.color = rgba(0.2f, 0.5f, 1.0f);
  const std_msgs::ColorRGBA free_colour = rgba(0.2f, 0.5f, 1.0f), fixed_colour = rgba(0.9f, 0.2f, 0.15f);
  for (int k = 0; k < points.cols(); ++k)
  {
    particles.points.push_back(point(points.col(k) + params_.offset));
    particles.colors.push_back(grid.isFixed(k) ? fixed_colour : free_colour);
  }

  visualization_msgs::Marker springs;
  springs.header = particles.header;
  springs.ns = "springs";
  springs.id = 0;
  springs.type = visualization_msgs::Marker::LINE_LIST;
  springs.action = visualization_msgs::Marker::ADD;
  springs.pose.orientation.w = 1.0;
  springs.scale.x = params_.spring_width;
  springs.color = rgba(0.8f, 0.8f, 0.8f);
  const std_msgs::ColorRGBA rest = rgba(0.8f, 0.8f, 0.8f), stretched = rgba(1.0f, 0.1f, 0.05f),
                            compressed = rgba(0.1f, 0.3f, 1.0f);
  for (const Spring& spring : grid.springs())
  {
    springs.points.push_back(point(points.col(spring.i) + params_.offset));
    springs.points.push_back(point(points.col(spring.j) + params_.offset));
    if (!params_.color_by_strain)
      continue;
    const double strain = ((points.col(spring.j) - points.col(spring.i)).norm() - spring.rest_length) / spring.rest_length;
    const float t = static_cast<float>(std::min(1.0, std::abs(strain) / params_.strain_scale));
    const std_msgs::ColorRGBA& end = strain > 0.0 ? stretched : compressed;
    const std_msgs::ColorRGBA c = rgba(rest.r + t * (end.r - rest.r), rest.g + t * (end.g - rest.g),
                                       rest.b + t * (end.b - rest.b));
    springs.colors.push_back(c);
    springs.colors.push_back(c);
  }
  array.markers.push_back(particles);
  array.markers.push_back(springs);
  return array;
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
  if (simulation_->diverged())
    status.summary(diagnostic_msgs::DiagnosticStatus::ERROR, "diverged: " + divergence_message_);
  else if (diag_ticks_ > 0 && (mean_cost > period || 2 * diag_late_ticks_ > diag_ticks_))
    status.summaryf(diagnostic_msgs::DiagnosticStatus::WARN,
                    "falling behind real time: %.2f ms of stepping per %.2f ms tick, %d of %d ticks late",
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
  status.add("ticks with stepping longer than the period", diag_slow_ticks_);
  status.add("ticks later than a period", diag_late_ticks_);
  status.add("modes", static_cast<int>(simulation_->basis().frequencies.size()));
  diag_ticks_ = diag_slow_ticks_ = diag_late_ticks_ = 0;
  diag_step_seconds_ = 0.0;
}

bool SimulationNode::setMethod(SetMethod::Request& request, SetMethod::Response& response)
{
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
  response.success = true;
  response.message = "switched from " + previous + " to " + request.method + " at step " +
                     std::to_string(simulation_->stepCount()) + (was_diverged ? ", recovering from the divergence" : "");
  ROS_INFO("%s", response.message.c_str());
  return true;
}

bool SimulationNode::reset(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& response)
{
  simulation_->reset();
  owed_steps_ = 0.0;
  divergence_message_.clear();
  response.success = true;
  response.message = "reset to the initial state at rest (method " + toString(simulation_->method()) +
                     (paused_ ? ", still paused)" : ")");
  ROS_INFO("%s", response.message.c_str());
  return true;
}

bool SimulationNode::pause(std_srvs::SetBool::Request& request, std_srvs::SetBool::Response& response)
{
  paused_ = request.data;
  response.success = true;
  response.message = std::string(paused_ ? "paused" : "running") + " at step " + std::to_string(simulation_->stepCount());
  ROS_INFO("%s", response.message.c_str());
  return true;
}

}  // namespace modal_mass_spring
