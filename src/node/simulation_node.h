// The ROS wrapper of a Simulation: parameters, timer, markers, TF, status, diagnostics, services.
#pragma once

#include "modal_mass_spring/SetMethod.h"
#include "modal_mass_spring/simulation.h"
#include "node_params.h"

#include <diagnostic_updater/diagnostic_updater.h>
#include <ros/callback_queue.h>
#include <ros/ros.h>
#include <std_srvs/SetBool.h>
#include <std_srvs/Trigger.h>
#include <tf2_ros/static_transform_broadcaster.h>
#include <tf2_ros/transform_broadcaster.h>
#include <visualization_msgs/MarkerArray.h>

#include <atomic>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

namespace modal_mass_spring
{

class SimulationNode
{
public:
  // Reads and validates every parameter from private_nh before building anything, then builds the
  // simulation (saying what a slow start-up is doing), and starts the timer on nh's queue and the
  // services on a queue and thread of their own. Throws std::invalid_argument for a bad parameter
  // (the message names it), std::runtime_error when the basis cannot be computed.
  SimulationNode(ros::NodeHandle& nh, ros::NodeHandle& private_nh);
  ~SimulationNode();

private:
  // Holds the simulation for a service callback; the timer's step loop lets it in between two steps.
  class ServiceLock;

  void buildSimulation();
  void onTick(const ros::TimerEvent& event);
  void publishStaticFrame();
  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& status);
  uint8_t state() const;  // with mutex_ held
  std::string stateName() const;

  bool setMethod(SetMethod::Request& request, SetMethod::Response& response);
  bool reset(std_srvs::Trigger::Request& request, std_srvs::Trigger::Response& response);
  bool pause(std_srvs::SetBool::Request& request, std_srvs::SetBool::Response& response);

  ros::NodeHandle nh_, private_nh_;
  NodeConfiguration config_;
  const NodeParams& params_ = config_.node;

  // The simulation and the state around it, shared by the timer and the service thread.
  std::mutex mutex_;
  std::atomic<int> services_waiting_{0};
  long state_changes_ = 0;  // by a service: pause, reset, set_method; ends the tick's stepping
  std::unique_ptr<Simulation> simulation_;
  double steps_per_tick_ = 0.0;  // real_time_factor / (publish_rate * time_step), not whole
  double owed_steps_ = 0.0;      // the fraction of a step carried to the next tick
  bool paused_ = false;
  std::string divergence_message_;
  Eigen::Matrix3Xd last_points_;  // the last published (finite) positions
  double last_energy_ = 0.0;      // and the last finite total energy

  // This tick's steps and cost; the counters behind the diagnostics since their last update (timer
  // thread only).
  int tick_steps_ = 0;
  double tick_step_seconds_ = 0.0;
  int diag_ticks_ = 0, diag_late_ticks_ = 0;
  double diag_step_seconds_ = 0.0;
  ros::Time last_tf_stamp_;
  ros::WallTime last_status_log_;

  ros::Publisher markers_pub_, status_pub_;
  tf2_ros::TransformBroadcaster tf_broadcaster_;
  tf2_ros::StaticTransformBroadcaster static_broadcaster_;
  std::unique_ptr<diagnostic_updater::Updater> diagnostics_;
  ros::CallbackQueue service_queue_;
  std::unique_ptr<ros::AsyncSpinner> service_spinner_;
  ros::ServiceServer set_method_srv_, reset_srv_, pause_srv_;
  ros::Timer timer_;
};

}  // namespace modal_mass_spring
