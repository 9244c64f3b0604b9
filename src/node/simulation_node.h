// The ROS wrapper of a Simulation: parameters, timer, markers, TF, status, diagnostics, services.
#pragma once

#include "modal_mass_spring/SetMethod.h"
#include "modal_mass_spring/simulation.h"

#include <diagnostic_updater/diagnostic_updater.h>
#include <ros/ros.h>
#include <std_srvs/SetBool.h>
#include <std_srvs/Trigger.h>
#include <tf2_ros/static_transform_broadcaster.h>
#include <tf2_ros/transform_broadcaster.h>
#include <visualization_msgs/MarkerArray.h>

#include <memory>
#include <string>
#include <vector>

namespace modal_mass_spring
{

class ParameterSource;

// Parameters of the node itself, on top of the core's GridParams and SimulationParams.
struct NodeParams
{
  double real_time_factor = 1.0;  // simulated seconds per wall second
  double publish_rate = 30.0;     // Hz: timer ticks, markers, TF and status
  std::string fixed_frame = "world";
  std::string grid_frame = "grid";       // static child of fixed_frame, translated by offset
  std::vector<int> tf_particles;         // broadcast as <grid_frame>/particle_<index>
  Eigen::Vector3d offset = Eigen::Vector3d::Zero();  // m, where the grid is drawn in fixed_frame
  bool color_by_strain = true;
  double strain_scale = 0.1;      // |strain| drawn in full colour
  double particle_diameter = 0.0; // m
  double spring_width = 0.0;      // m
  double status_log_period = 5.0; // s of wall time between status lines in the log; 0: never
};

// Reads and validates the node's own parameters; defaults that depend on the grid (tf_particles, the
// marker sizes) come from `grid`. Throws std::invalid_argument naming the parameter, its value and
// what is allowed.
NodeParams loadNodeParams(const ParameterSource& source, const GridParams& grid, const SimulationParams& sim);

// The child frame of a broadcast particle.
std::string particleFrame(const std::string& grid_frame, int particle);

class SimulationNode
{
public:
  // Reads all parameters from private_nh, builds the simulation and starts the timer. Throws
  // std::invalid_argument for a bad parameter (the message names it), std::runtime_error when the
  // basis cannot be computed.
  SimulationNode(ros::NodeHandle& nh, ros::NodeHandle& private_nh);

private:
  void onTick(const ros::TimerEvent& event);
  void publish(const ros::Time& stamp, bool send_tf);
  visualization_msgs::MarkerArray makeMarkers(const Eigen::Matrix3Xd& points, const ros::Time& stamp) const;
  void publishStaticFrame();
  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& status);
  uint8_t state() const;
  std::string stateName() const;

  bool setMethod(SetMethod::Request& request, SetMethod::Response& response);
  bool reset(std_srvs::Trigger::Request& request, std_srvs::Trigger::Response& response);
  bool pause(std_srvs::SetBool::Request& request, std_srvs::SetBool::Response& response);

  ros::NodeHandle nh_, private_nh_;
  NodeParams params_;
  std::unique_ptr<Simulation> simulation_;

  double steps_per_tick_ = 0.0;  // real_time_factor / (publish_rate * time_step), not whole
  double owed_steps_ = 0.0;      // the fraction of a step carried to the next tick
  bool paused_ = false;
  std::string divergence_message_;
  Eigen::Matrix3Xd last_points_;  // the last published (finite) positions

  // This tick's steps and cost; the counters behind the diagnostics since their last update.
  int tick_steps_ = 0;
  double tick_step_seconds_ = 0.0;
  int diag_ticks_ = 0, diag_slow_ticks_ = 0, diag_late_ticks_ = 0;
  double diag_step_seconds_ = 0.0;
  ros::Time last_tf_stamp_;
  ros::WallTime last_status_log_;

  ros::Publisher markers_pub_, status_pub_;
  tf2_ros::TransformBroadcaster tf_broadcaster_;
  tf2_ros::StaticTransformBroadcaster static_broadcaster_;
  diagnostic_updater::Updater diagnostics_;
  ros::ServiceServer set_method_srv_, reset_srv_, pause_srv_;
  ros::Timer timer_;
};

}  // namespace modal_mass_spring
