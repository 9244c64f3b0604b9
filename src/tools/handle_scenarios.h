// Handle scenarios of modal_compare: particle groups held by rigid frames that move along a smooth
// path and then hold still, and the one place where that motion is handed to a Simulation.
#pragma once

#include "modal_mass_spring/grid.h"
#include "modal_mass_spring/handles.h"
#include "modal_mass_spring/simulation.h"

#include <yaml-cpp/yaml.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <string>
#include <vector>

namespace modal_mass_spring
{

// Where a handle's frame is at a waypoint, relative to where it starts.
struct HandlePose
{
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();  // m, grid coordinates
  double rotation_deg = 0.0;                              // about the path's rotation_axis
};

// One handle: its particles and where its frame goes. The frame's origin is the particles' centroid
// at the start, its axes the grid's; over the move it translates by `translation` and turns by
// `rotation_deg` about `rotation_axis` through its origin. With `waypoints` it visits them in turn
// instead (a shake, a return), one leg each, each leg a ramp from rest to rest.
struct HandlePath
{
  std::vector<int> particles;  // row * cols + col
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();  // m, grid coordinates
  Eigen::Vector3d rotation_axis = Eigen::Vector3d::UnitZ();  // unit length
  double rotation_deg = 0.0;
  std::vector<HandlePose> waypoints;  // empty: one leg to (translation, rotation_deg)
};

// The poses a path visits after its start, in order: its waypoints, or its one target.
std::vector<HandlePose> pathLegs(const HandlePath& path);

// Every handle moves over [0, move_time] along the same ramp (with waypoints, move_time split evenly
// among its legs), then holds still for hold_time.
struct HandleScenario
{
  std::string name;
  std::vector<HandlePath> handles;
  double move_time = 1.0;  // s
  double hold_time = 2.0;  // s
  double duration() const { return move_time + hold_time; }
};

// The ramp of the move, s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5 for tau = t / move_time in [0, 1] (0
// before, 1 after), and its first and second time derivatives: velocity and acceleration start and
// end at zero and the acceleration is continuous, so the integrators see no jump.
struct Ramp
{
  double s = 0.0, ds = 0.0, dds = 0.0;  // 1, 1/s, 1/s^2
};
Ramp moveRamp(double t, double move_time);

// A rigid frame's motion at one instant, in grid coordinates: what a moving-frame formulation of
// the handles takes (the pose, the origin's velocity and acceleration, the angular velocity and
// acceleration), and what pointsOnFrame turns into particle motion.
struct RigidFrameMotion
{
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  Eigen::Quaterniond rotation = Eigen::Quaterniond::Identity();  // from the start orientation
  Eigen::Vector3d velocity = Eigen::Vector3d::Zero(), acceleration = Eigen::Vector3d::Zero();
  Eigen::Vector3d angular_velocity = Eigen::Vector3d::Zero(), angular_acceleration = Eigen::Vector3d::Zero();
};

// The frame of `path` at time t, its origin starting at `start_origin`: on leg k of n (of length
// move_time / n), the pose ramps from waypoint k - 1 (the start for k = 0) to waypoint k.
RigidFrameMotion frameMotion(const HandlePath& path, const Eigen::Vector3d& start_origin, double move_time, double t);

// Particles at `offsets` (3 x N, from the origin, in the start orientation) carried by the frame:
// p = o + R r0, v = v_o + w x r, a = a_o + alpha x r + w x (w x r), with r = R r0.
RigidPointMotion pointsOnFrame(const RigidFrameMotion& frame, const Eigen::Matrix3Xd& offsets);

// Reads `handle_scenarios` (a list of maps; `key` names it in messages). Throws
// std::invalid_argument naming the element, e.g. handle_scenarios[1].handles[0].rotation_axis, for a
// wrong shape, an unknown key, a missing name or particle list, a name given twice, a non-finite or
// out-of-range number.
std::vector<HandleScenario> parseHandleScenarios(const YAML::Node& node, const std::string& key);

// The grid of `grid` with the scenario's particle groups as its handles, checked by the core
// (validateGridParams: indices in range, one handle each, not fixed), and the scenario's motion
// checked against the grid (in 2D the motion must stay in the x-z plane). Throws
// std::invalid_argument naming the scenario.
GridParams gridWithHandles(const GridParams& grid, const HandleScenario& scenario);

// Moves one Simulation's handles along a scenario, from where its handle particles start.
class HandleDriver
{
public:
  HandleDriver(const HandleScenario& scenario, const Simulation& sim);

  // The frame of handle h at time t.
  RigidFrameMotion frame(int h, double t) const;
  // Positions, velocities and accelerations of every handle particle at time t, over
  // grid().handleDofs().
  void particleMotion(double t, Eigen::VectorXd& positions, Eigen::VectorXd& velocities,
                      Eigen::VectorXd& accelerations) const;
  // The motion of the frame B of a scenario with one handle (x = p + R y, B at the world's at the
  // start), as Simulation::setHandleFrameMotion takes it.
  FrameMotion bodyFrameMotion(double t) const;
  // Hands the motion at the end of the simulation's next step (Simulation::nextStepTime) to it,
  // as its handle formulation takes it: the frame's motion in the moving frame, every handle
  // particle's motion with constraint modes.
  void drive(Simulation& sim) const;

private:
  HandleScenario scenario_;
  int dimension_;
  std::vector<Eigen::Vector3d> start_origins_;
  std::vector<Eigen::Matrix3Xd> offsets_;
};

}  // namespace modal_mass_spring
