// The ROS wrapper of a Simulation: parameters, timer, markers, point cloud, TF, status, clock,
// diagnostics, services; or of several, stepped in lockstep for a live comparison of methods.
#pragma once

#include "applied_forces.h"
#include "drag_and_poke.h"
#include "collider_frames.h"
#include "handle_frames.h"
#include "warning_throttle.h"
#include "modal_mass_spring/adaptive.h"
#include "modal_mass_spring/ApplyForce.h"
#include "modal_mass_spring/GetState.h"
#include "modal_mass_spring/RolloutAction.h"
#include "modal_mass_spring/SetState.h"
#include "modal_mass_spring/Attach.h"
#include "modal_mass_spring/Detach.h"
#include "modal_mass_spring/SetColliders.h"
#include "modal_mass_spring/SetMethod.h"
#include "modal_mass_spring/SimulationConfig.h"
#include "modal_mass_spring/Status.h"
#include "modal_mass_spring/Step.h"
#include "modal_mass_spring/simulation.h"
#include "node_params.h"
#include "rollouts.h"
#include "tick_pacing.h"

#include <actionlib/server/simple_action_server.h>
#include <boost/thread/recursive_mutex.hpp>
#include <diagnostic_updater/diagnostic_updater.h>
#include <dynamic_reconfigure/server.h>
#include <geometry_msgs/PointStamped.h>
#include <geometry_msgs/TransformStamped.h>
#include <geometry_msgs/WrenchStamped.h>
#include <interactive_markers/interactive_marker_server.h>
#include <ros/callback_queue.h>
#include <ros/ros.h>
#include <sensor_msgs/PointCloud2.h>
#include <std_srvs/SetBool.h>
#include <std_srvs/Trigger.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/static_transform_broadcaster.h>
#include <tf2_ros/transform_broadcaster.h>
#include <tf2_ros/transform_listener.h>
#include <visualization_msgs/MarkerArray.h>

#include <atomic>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

namespace modal_mass_spring
{

// A step's CPU time, the CPU seconds per simulated second it costs (over time_step) and the real-time
// factor the CPU allows (its inverse), for the status line and the labels; "no step timed yet" before one.
std::string formatCpuPace(double step_cpu_seconds, double time_step);

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
  // The constructor's steps: the parameters read and checked (the unknown ones warned about); each
  // drawn track's topics; the services on their own queue and thread, with what they act on (the
  // applied forces, the handle and collider frames followed in TF, the rollouts, the drag marker).
  void loadConfiguration();
  void advertiseTracks();
  void startServices();
  void startForcesAndFrames();
  // Holds the simulation for a service callback; the timer's step loop lets it in between two steps.
  class ServiceLock;
  // One simulated grid: a method of the comparison, the single method, or the shadow full.
  struct Track
  {
    std::string name;    // the method's name; "shadow_full" for the shadow
    bool shadow = false; // the unreduced reference beside a single method: no topics of its own
    std::unique_ptr<Simulation> simulation;
    // Method adaptive (the single method's track): its stepper, made for `simulation` once that runs
    // the reduced method, and the switches it has logged. Declared after `simulation`, which it uses.
    std::unique_ptr<AdaptiveStepper> adaptive;
    int logged_switches = 0;
    // A reduced method's estimated RMS distance to full (m; the stepper's last check under adaptive),
    // the wall time it was last refreshed, and the largest indicator read since the state was set.
    double error_estimate = 0.0;
    double estimate_wall = -1.0;
    IndicatorMaximum indicator_max;
    // After a state, a simulation or colliders the stepper's checkpoints do not know: made again at
    // the next step, the estimate measured again.
    void restartAdaptive()
    {
      adaptive.reset();
      error_estimate = 0.0;
      estimate_wall = -1.0;
    }
    Eigen::Vector3d offset = Eigen::Vector3d::Zero();
    std::string grid_frame;
    std::string ns_prefix;  // of its marker namespaces
    ros::Publisher markers_pub, status_pub, points_pub;  // none for the shadow
    // The force each handle and each collider takes from the grid (geometry_msgs/WrenchStamped).
    std::vector<ros::Publisher> handle_force_pubs, contact_force_pubs;
    Eigen::Matrix3Xd last_points;  // the last finite positions
    double last_energy = 0.0;
    std::string divergence_message;
    double tick_seconds = 0.0;      // this tick's stepping of this method
    double tick_cpu_seconds = 0.0;  // and the stepping thread's CPU time in it
    int tick_steps = 0;
    double step_seconds = 0.0;      // the last tick's mean step
    double step_cpu_seconds = 0.0;  // and its mean CPU time
    void startTick() { tick_seconds = tick_cpu_seconds = 0.0, tick_steps = 0; }
    void finishTick()
    {
      if (tick_steps == 0)
        return;
      step_seconds = tick_seconds / tick_steps;
      step_cpu_seconds = tick_cpu_seconds / tick_steps;
    }
    double rms_distance = 0.0, max_distance = 0.0;  // to the reference, m
    long step_offset = 0;  // steps of the models a rebuild replaced: the count goes on across a swap
    // The collider markers the last ~markers drew (the output's bookkeeping, kept while it is built
    // from a const track): fewer colliders then delete the rest.
    mutable size_t collider_markers = 0;
  };
  // `pubs`: `count` wrench publishers, <topic><k> in the track's namespace (a shadow has none); those
  // there are kept, the extra ones dropped.
  void advertiseWrenches(const Track& track, std::vector<ros::Publisher>& pubs, const std::string& topic, size_t count);

  // What one tick publishes, built under the lock and sent after it.
  struct Output;

  // Builds a simulation, logging its stages when slow ("<activity> for N s: ...") and, with `report`,
  // the start-up line.
  std::unique_ptr<Simulation> buildSimulation(const GridParams& grid, const SimulationParams& params, bool report,
                                              const std::string& activity = "starting up",
                                              bool with_basis = false) const;
  // Builds a `full` simulation's modal basis (Simulation::buildBasis) unless built, logging its
  // stages and iterations when slow, then the modes.
  void buildBasis(Simulation& simulation, const std::string& activity) const;
  // Runs work with the callbacks it reports its stages and iterations through, logged by a
  // StartupProgress once it has taken a second (start-up, the basis, the cubature's training).
  void withProgress(const std::string& activity,
                    const std::function<void(const StageFn&, const IterationFn&)>& work) const;
  void buildTracks();
  // Puts every full track at the state of the first reduced one (the same state, the same time), so
  // that the distances measure the methods, not their start.
  void synchronise();
  // One step of every track that has not diverged; false when stepping must stop (the single method
  // diverged, or every method of the comparison).
  bool stepAll();
  // Method adaptive (adaptive_tracks.cpp): whether `track` runs it; one step of a track, through its
  // AdaptiveStepper when it does (each switch logged once); a reduced track's error estimate,
  // refreshed at most once a second (its indicator costs a full force and a sparse solve).
  bool adaptiveTrack(const Track& track) const { return adaptive_ && &track == &tracks_.front(); }
  StepResult stepTrack(Track& track);
  void refreshErrorEstimate(Track& track);
  std::string methodName(const Track& track) const;   // "adaptive" or the method
  std::string adaptiveNote(const Track& track) const;  // the status line's part
  void onTick();
  // The tick's stepping (with mutex_ held through `lock`, which a waiting service call opens between
  // two steps), and the periodic status line.
  void stepTick(std::unique_lock<std::mutex>& lock, double period);
  std::string statusLine() const;  // with mutex_ held
  // What a tick publishes, and the state and diagnostics (status.cpp).
  Output snapshot(const ros::Time& stamp);  // with mutex_ held
  // The snapshot's steps, with mutex_ held: every track's last finite positions and energy and its
  // distances to the reference; a drawn track's markers, wrenches, point cloud and ~status; the TF
  // frames of its tf_particles.
  void keepLastStates();
  void addGrid(const Track& track, const Track* ref, const ros::Time& stamp, Output& output);
  void deleteColliderMarkers(const Track& track, size_t drawn, const std::string& frame_id, const ros::Time& stamp,
                             visualization_msgs::MarkerArray& markers) const;
  std::string trackLabel(const Track& track, bool measured) const;
  void addHandleWrenches(const Track& track, const std::string& frame_id, const ros::Time& stamp,
                         std::vector<std::pair<ros::Publisher, geometry_msgs::WrenchStamped>>& wrenches);
  Status trackStatus(const Track& track, bool measured, const ros::Time& stamp);
  void addBasisStatus(const Simulation& simulation, Status& status) const;  // the basis, cubature and cache
  void addParticleFrames(const Track& track, const ros::Time& stamp, Output& output) const;
  void send(const Output& output);
  ros::Time stamp() const;  // with mutex_ held: the simulated clock under use_sim_time, else now
  void publishStaticFrames();
  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& status);
  uint8_t state(const Track& track) const;  // with mutex_ held
  std::string stateName(const Track& track) const;
  Track& primary() { return tracks_.front(); }
  const Track* reference() const;  // the full track the others are measured against, or null
  bool lockstep() const { return !config_.node.methods.empty(); }
  long steps(const Track& track) const { return track.step_offset + track.simulation->stepCount(); }
  double simTime(const Track& track) const { return steps(track) * config_.simulation.time_step; }

  // Live tuning with dynamic_reconfigure (live_tuning.cpp). A change is checked as the start-up
  // parameters are (loadNodeConfiguration) and refused whole, or applied: node parameters at the next
  // tick, the ones that need a new basis by a rebuild in the background, swapped in at a tick boundary
  // with the motion carried over.
  void startLiveTuning();
  void reconfigure(SimulationConfig& config, uint32_t level);
  void rebuildLoop();
  // What each track runs (its method; whether its basis is built: a full track that switched to a
  // modal method needs it again), to build it anew; with mutex_ held.
  struct TrackKind
  {
    Method method;
    bool with_basis;
  };
  std::vector<TrackKind> trackKinds() const;
  // A simulation for each of `kinds` on `config` (no lock needed); throws what buildSimulation throws.
  std::vector<std::unique_ptr<Simulation>> buildTracksFor(const NodeConfiguration& config,
                                                          const std::vector<TrackKind>& kinds,
                                                          const std::string& activity) const;
  void swapRebuilt();  // with mutex_ held, at a tick boundary
  bool rebuilding() const { return rebuilding_ || !rebuilt_.empty() || training_; }

  // ~set_method to `cubature` before it is trained (services.cpp): the training runs on a thread of
  // its own while the current method steps on (state REBUILDING, its progress in ~status's message
  // and the diagnostics), and the switch happens at the first tick after it (adoptTrainedCubature).
  void trainInBackground(Simulation::CubatureTraining training);  // with mutex_ held
  void adoptTrainedCubature();  // with mutex_ held, at a tick boundary
  // What a switch does besides Simulation::setMethod, and its reply ("switched from ... at step ...").
  std::string finishSwitch(const std::string& previous, Method method, bool was_diverged);  // with mutex_ held
  std::string trainingProgress() const;

  // The services (services.cpp).
  bool setMethod(SetMethod::Request& request, SetMethod::Response& response);
  bool reset(std_srvs::Trigger::Request& request, std_srvs::Trigger::Response& response);
  bool pause(std_srvs::SetBool::Request& request, std_srvs::SetBool::Response& response);
  bool step(Step::Request& request, Step::Response& response);

  // Grasps while running (grasps.cpp): ~attach makes particles a new handle on a TF frame, ~detach
  // lets a handle's particles go, and a grasp given a max_force lets go beyond it. Each change builds
  // every track anew for the new held set with the service lock open (the old model steps on), then
  // swaps it in between two steps with the motion carried over.
  bool attach(Attach::Request& request, Attach::Response& response);
  bool detach(Detach::Request& request, Detach::Response& response);
  // Builds the tracks for `next` (its handles the new held set), then, with the lock taken again,
  // swaps them in; `keep[h]` is the handle of the running set that new handle h continues, or -1 for
  // the one `grip` grips. Empty, or why it could not.
  struct Grip
  {
    FramePose pose;
    bool snap = false;
  };
  std::string changeHandles(ServiceLock* lock, NodeConfiguration next, const std::vector<int>& keep,
                            const std::optional<Grip>& grip);
  // With the lock held: the built tracks in, the motion carried over, the grips, the configuration.
  void swapInHeldSet(const NodeConfiguration& next, std::vector<std::unique_ptr<Simulation>>& built,
                     const std::vector<int>& keep, const std::optional<Grip>& grip);
  // Why the held set cannot change now (a rebuild, a divergence, moving_frame), or empty.
  std::string graspChangeRefusal() const;
  // `frame`'s latest pose in fixed_frame into `pose`, or why not.
  std::string lookupGraspFrame(const std::string& frame, FramePose& pose);
  // Lets handle h go (its particles free); `lock` as changeHandles (null: held throughout).
  std::string releaseHandle(ServiceLock* lock, size_t h);
  void releaseSlippingGrasps();  // with mutex_ held, after a tick's stepping
  std::vector<double> grasp_limits_;  // N per handle: beyond it the grasp lets go; 0: never

  // ~set_colliders (live_colliders.cpp): the colliders set, added, replaced or removed by id on every
  // track between two steps; a collider that appears on the cloth pushes it out from the next step.
  bool setColliders(SetColliders::Request& request, SetColliders::Response& response);
  std::atomic<bool> colliders_set_live_{false};  // since the first: see buildSimulation

  // Saving and restoring the state, and rollouts of candidate handle motions on simulations of their
  // own (rollout_server.cpp): the goal is checked and the start copied under the lock, the rollouts
  // run without it while the live simulation steps on.
  bool getState(GetState::Request& request, GetState::Response& response);
  bool setState(SetState::Request& request, SetState::Response& response);
  void startRollouts();
  void executeRollout(const RolloutGoalConstPtr& goal);
  // The goal's steps: its request checked against the node's limits, with the live simulation's
  // grid and parameters copied under the lock (throws std::invalid_argument: the goal is refused);
  // the workers built unless built for them (the seconds it took, else 0), then run.
  struct RolloutSetup;
  RolloutSetup rolloutSetup(const RolloutGoal& goal);
  double prepareRolloutWorkers(const RolloutSetup& setup);
  std::vector<CandidateOutcome> runRolloutWorkers(const RolloutRequest& request, double& cpu);

  // External forces (services.cpp): ~apply_force messages (checked, turned into the fixed frame with
  // tf2, summed) and ~clear_forces; every track gets the same total.
  void applyForce(const ApplyForce::ConstPtr& message);
  bool clearForces(std_srvs::Trigger::Request& request, std_srvs::Trigger::Response& response);
  void updateExternalForces();  // with mutex_ held: drops the forces whose time is up, sets the rest
  // What a reply of ~reset or ~set_method adds while forces of ~apply_force act: empty, or how many.
  std::string forcesActingNote() const;
  // What a divergence message of `track` adds when forces from outside acted on it (they may be why).
  std::string externalForcesNote(size_t track) const;
  // A warning about a dropped message (~apply_force, /clicked_point, a drag pose), throttled per text.
  void warnDropped(const std::string& text);
  std::mutex warnings_mutex_;
  WarningThrottle dropped_warnings_;
  // Handles: looks every handle frame up (the latest pose in tf_buffer_), warns for the missing ones.
  void updateHandleTargets();   // with mutex_ held
  // Whether a handle or a collider follows a TF frame now.
  bool followsFrames() const;
  // The latest pose of `frame` in fixed_frame (tf_buffer_), or nothing and why (`problem`): not
  // available (tf2's reason in brackets), stale, non-finite; a frame never seen yet is waited for
  // quietly (nothing, `problem` empty) during its first seconds. Handles and colliders alike.
  std::optional<FramePose> lookupFrame(const std::string& frame, bool ever_found, std::string& problem);
  // Colliders on TF frames: looks their frames up, warns for the missing ones (throttled).
  void updateColliderTargets();  // with mutex_ held
  // Places the frame colliders at the fraction s of the tick on every track.
  void setColliderPoses(double s);  // with mutex_ held
  // Prescribes the handles' motion at the fraction s of a tick of `duration` s on every track.
  void setHandleMotion(double duration, double s);  // with mutex_ held

  // By hand in rviz (interaction.cpp): the drag marker (~drag/update, ~drag/feedback) and pokes from
  // /clicked_point, both on the global queue (between ticks); their force joins track k's external
  // force before each of its steps.
  void startInteraction();
  void showDragMarker();  // with mutex_ held: shown while drag_stiffness > 0
  void onDragFeedback(const visualization_msgs::InteractiveMarkerFeedbackConstPtr& feedback);
  void onClickedPoint(const geometry_msgs::PointStamped::ConstPtr& message);
  // A point of a message in the fixed frame (tf2 for another frame); false and why for a bad one.
  bool toFixedFrame(const std::string& frame_id, const geometry_msgs::Point& point, Eigen::Vector3d& result,
                    std::string& why);
  // The free particle nearest to a fixed-frame point over the drawn tracks, its track and distance.
  int nearestOnTracks(const Eigen::Vector3d& point, size_t& track, double& distance) const;  // with mutex_ held
  void applyHandForce(size_t k);  // with mutex_ held, before track k's step
  // Where the marker goes this tick (on its particle while not dragged), if it moved; then placeDragMarker.
  std::optional<Eigen::Vector3d> dragMarkerTarget();  // with mutex_ held
  void placeDragMarker(const Eigen::Vector3d& position);

  ros::NodeHandle nh_, private_nh_;
  NodeConfiguration config_;

  // The simulations and the state around them, shared by the timer and the service thread.
  std::mutex mutex_;
  std::atomic<int> services_waiting_{0};
  long state_changes_ = 0;  // by a service: pause, reset, set_method; ends the tick's stepping
  std::vector<Track> tracks_;  // the first is the one a single-method node shows
  TickPacing pacing_;          // the steps a tick owes, the fraction of one carried over
  bool paused_ = false;
  bool use_sim_time_ = false;
  double clock_seconds_ = 0.0;  // simulated seconds stepped since start-up: /clock, never reset
  double achieved_factor_ = 0.0;

  // This tick's steps and cost; the counters behind the diagnostics since their last update (timer
  // thread only).
  int tick_steps_ = 0;
  double tick_step_seconds_ = 0.0;
  int diag_ticks_ = 0, diag_late_ticks_ = 0;
  double diag_step_seconds_ = 0.0;
  ros::Time last_tf_stamp_;
  int ticks_since_markers_ = 0;  // markers_rate: the ticks since ~markers last went out
  ros::WallTime last_status_log_;

  ros::Publisher clock_pub_;
  tf2_ros::TransformBroadcaster tf_broadcaster_;
  tf2_ros::StaticTransformBroadcaster static_broadcaster_;
  std::unique_ptr<diagnostic_updater::Updater> diagnostics_;
  ros::CallbackQueue service_queue_;
  std::unique_ptr<ros::AsyncSpinner> service_spinner_;
  ros::ServiceServer set_method_srv_, reset_srv_, pause_srv_, step_srv_, clear_forces_srv_, attach_srv_, detach_srv_,
      set_colliders_srv_;
  ros::Subscriber apply_force_sub_;
  std::unique_ptr<AppliedForces> applied_forces_;  // with mutex_
  Eigen::VectorXd external_force_;                  // their sum, on every dof
  tf2_ros::Buffer tf_buffer_;
  std::unique_ptr<tf2_ros::TransformListener> tf_listener_;
  std::unique_ptr<HandleFrames> handle_frames_;     // with mutex_
  std::unique_ptr<ColliderFrames> collider_frames_; // with mutex_
  ros::WallTime frames_first_lookup_;               // when the handle and collider frames were first looked up
  std::unique_ptr<HandForces> hand_forces_;         // with mutex_
  std::unique_ptr<interactive_markers::InteractiveMarkerServer> drag_server_;
  ros::Subscriber clicked_point_sub_;
  int selected_particle_ = -1;  // the marker's particle, on selected_track_
  size_t selected_track_ = 0;
  bool placing_ = false;        // the marker is moved by its arrows
  Eigen::Vector3d marker_position_ = Eigen::Vector3d::Zero();  // where it was last placed
  // Live tuning: the private parameters as last accepted, the configuration they give, the rebuild.
  XmlRpc::XmlRpcValue private_params_;
  NodeConfiguration accepted_;
  boost::recursive_mutex tuning_mutex_;
  std::unique_ptr<dynamic_reconfigure::Server<SimulationConfig>> tuning_server_;
  std::optional<NodeConfiguration> pending_rebuild_;        // the latest change waiting to be built
  std::vector<std::unique_ptr<Simulation>> rebuilt_;        // built, one per track, waiting for a tick
  NodeConfiguration rebuilt_config_;
  bool rebuilding_ = false;
  bool stopping_ = false;
  std::thread rebuild_thread_;
  // The cubature's training in the background: running (with mutex_), its result or failure waiting
  // for a tick, whether the switch is still wanted (a later ~set_method to another method cancels
  // it), and its progress (with progress_mutex_: the training thread updates it without mutex_).
  bool training_ = false;
  bool switch_after_training_ = false;
  bool adaptive_ = false;  // the single method is adaptive (method: adaptive, or ~set_method)
  bool adaptive_after_training_ = false;  // the switch after the training is to adaptive
  std::optional<Cubature> trained_;
  std::string training_failure_;
  std::atomic<bool> cancel_training_{false};
  std::thread training_thread_;
  mutable std::mutex progress_mutex_;
  std::string training_progress_;

  // ~rollout: its workers' simulations (only the action's thread touches them), built for the live
  // simulation of live_builds_ (counted by swapRebuilt), and the cancel flag of the running goal.
  ros::ServiceServer get_state_srv_, set_state_srv_;
  long live_builds_ = 0;  // with mutex_
  std::vector<std::unique_ptr<Simulation>> rollout_workers_;
  long rollout_workers_build_ = -1;
  std::atomic<bool> rollout_cancel_{false};
  std::unique_ptr<actionlib::SimpleActionServer<RolloutAction>> rollout_server_;

  ros::Timer timer_;
  ros::WallTimer wall_timer_;  // under use_sim_time: the node makes the clock, so it cannot wait on it
};

// Defined here for the node's files that take the lock (services.cpp) or build and send what a tick
// publishes (status.cpp).
class SimulationNode::ServiceLock
{
public:
  explicit ServiceLock(SimulationNode& node) : node_(node)
  {
    ++node_.services_waiting_;  // the step loop sees this and lets go between two steps
    lock_ = std::unique_lock<std::mutex>(node_.mutex_);
    --node_.services_waiting_;
  }
  // Opens the lock for work that needs no state (a build), and takes it again between two steps.
  void unlock() { lock_.unlock(); }
  void relock()
  {
    ++node_.services_waiting_;
    lock_.lock();
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
  bool markers = true;  // ~markers go out this tick (markers_rate)
};

}  // namespace modal_mass_spring
