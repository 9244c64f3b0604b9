// Rollouts: candidate handle motions simulated from a saved state, each on a simulation of its own
// (never the live one), on worker threads, for a planner (~rollout). No ROS here: the node turns its
// action's goal into a RolloutRequest and the outcomes into its result.
#pragma once

#include "handle_frames.h"
#include "modal_mass_spring/simulation.h"

#include <Eigen/Core>

#include <atomic>
#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace modal_mass_spring
{

// A handle frame's pose at a time from the rollout's start (fixed frame).
struct HandleWaypoint
{
  double time = 0.0;  // s
  FramePose pose;
};

// One candidate: the waypoints of each handle frame it moves, by frame name (the others hold still).
struct CandidateMotion
{
  std::vector<std::pair<std::string, std::vector<HandleWaypoint>>> frames;
};

struct RolloutRequest
{
  SimulationState state;  // the start
  HandleFrames frames;    // the handle frames where the start has them (the live node's, copied)
  Method method = Method::Full;
  double time_step = 1e-3;  // s
  double horizon = 1.0;     // s
  std::vector<double> sample_times;  // s, increasing, in (0, horizon]
  std::vector<CandidateMotion> candidates;
  Eigen::Vector3d grid_offset = Eigen::Vector3d::Zero();  // the grid's origin in the fixed frame
};

// The node's limits on a request.
struct RolloutLimits
{
  int threads = 2;
  double max_horizon = 10.0;     // s
  int max_candidates = 256;
  double memory_limit_gb = 12.0;
};

struct GridSample
{
  double time = 0.0;
  Eigen::Matrix3Xd positions;                 // fixed frame
  std::vector<Eigen::Vector3d> handle_forces; // per handle (Simulation::handleForces)
  std::vector<Eigen::Vector3d> contact_forces;// per collider, over the last step
};

struct CandidateOutcome
{
  int candidate = 0;
  bool diverged = false;
  std::string message;
  double simulated_time = 0.0;
  std::vector<GridSample> samples;
};

// A request's time step when its goal gives none: the live simulation's (params.time_step), which
// `coarse` (unless it is the live method already) spans a whole number of: coarseStepMultiple, or
// the largest smaller number that divides the live steps in the horizon.
double defaultRolloutTimeStep(Method method, double horizon, const GridParams& grid, SimulationParams params);

// Refuses a request before any work: no candidate, more than max_candidates, a horizon not in
// (0, max_horizon], a time step validateParameters refuses, sample times not increasing in
// (0, horizon], a frame that is no handle's (or was never looked up), waypoint times not increasing
// or not positive, a non-finite pose or one that jumps or turns farther than a handle frame may
// between two ticks, and a memory estimate (threads simulations of `grid` and `params` with the
// request's method, plus the samples) above memory_limit_gb. Throws std::invalid_argument naming
// the field (candidates[2].handles[0].poses[1]) and what is allowed.
void checkRolloutRequest(const RolloutRequest& request, const RolloutLimits& limits, const GridParams& grid,
                         const SimulationParams& params);

// Runs one candidate on `simulation` (which it restores to `start`, the request's state in the
// request's method and time step: see rolloutStart), stepping until the horizon, a divergence or
// `cancel` (checked every step).
CandidateOutcome runCandidate(Simulation& simulation, const SimulationState& start, const RolloutRequest& request,
                            int candidate, const std::atomic<bool>& cancel);

// The request's state carried into its method and time step on `simulation` (restored, switched):
// the start every candidate is restored to.
SimulationState rolloutStart(Simulation& simulation, const RolloutRequest& request);

// Runs every candidate on one thread per simulation of `workers` (each built with the live
// simulation's grid and parameters), told to on_finished (from the worker's thread, one call at a
// time) as each finishes. Stops within one step of `cancel`; returns the finished candidates in
// the request's order, and adds the workers' CPU time (s) to `cpu_seconds` when given.
std::vector<CandidateOutcome> runRollouts(const std::vector<Simulation*>& workers, const RolloutRequest& request,
                                        const std::atomic<bool>& cancel,
                                        const std::function<void(const CandidateOutcome&)>& on_finished = {},
                                        double* cpu_seconds = nullptr);

}  // namespace modal_mass_spring
