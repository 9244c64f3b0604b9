// What the node says about its start-up: the time of each stage, the modes found, and, while a slow
// start-up runs, what it is doing.
#pragma once

#include "modal_mass_spring/modal_basis.h"
#include "modal_mass_spring/simulation.h"

#include <Eigen/Core>

#include <functional>
#include <mutex>
#include <string>
#include <vector>

namespace modal_mass_spring
{

// "4 modes, 5.186 to 18.85 rad/s, none zero"; "30 modes, 12 zero, the non-zero ones 0.5 to 9 rad/s";
// "30 modes, all zero (no stiffness along any of them: ...)".
std::string describeModes(const Eigen::VectorXd& frequencies, int num_zero_modes);

// Method `coarse`'s grid beside the grid, and how many time steps a step of it can span
// (coarseStepMultiple): "coarse grid 20 x 20 (400 particles, 25 of the grid's a coarse one), stable
// to about 5 x time_step".
std::string describeCoarseGrid(const Grid& grid, const Grid& coarse, int step_multiple);

// "start-up 3.1 s: equilibrium 3.02 s, stiffness 2.1 ms, factorisation 4.9 ms, eigensolver 28.9 ms"
// (equilibrium only when it was solved); `total_seconds` is the whole Simulation construction.
// With modal derivatives, ", modal derivatives 12.3 ms" at the end; with a cubature trained at
// start-up, its training time ("..., cubature 0.29 s").
std::string describeStartupTimes(const LinearizationInfo& linearization, const ModalBasis& basis, double total_seconds,
                                 const DerivativeBasisInfo& derivatives = {}, const Cubature* cubature = nullptr);

// "basis linear_modes" or "basis modal_derivatives: 6 linear modes kept, 6 derivative directions added
// (from 21 derivatives) in 12.3 ms, frequencies up to 126 rad/s; singular values (relative) smallest
// kept 0.12, largest dropped 0.081".
// With basis: skinning, describeSkinning's line and the highest frequency.
std::string describeBasis(const SimulationParams& params, const DerivativeBasisInfo& info, const ModalBasis& physical_basis,
                          const SkinningInfo& skinning = {});

// The start-up line on the handles' formulation and why it was chosen: "handles: moving frame of
// 'gripper' (...)" or "handles: constraint modes (Craig-Bampton) ..., 2 handles on 2 frames ...".
// `frames`: the handles' distinct TF frames.
std::string describeHandleFormulation(const GridParams& grid, const SimulationParams& params,
                                      const std::vector<std::string>& frames);

// "solving the static equilibrium under gravity" for "equilibrium", and so on for the core's stages.
std::string describeStage(const std::string& stage);

// Follows the core's start-up stages (onStage is a StageFn) and their iterations (onIteration is an
// IterationFn) and, once the start-up has taken longer than `quiet_seconds`, logs what it is doing:
// at once, then at each new stage, every `repeat_seconds` within a long one, and every
// `iteration_seconds` while its iterations move (the latest iteration, its residual and target at
// the end of the line). poll() is called from another thread (or a test) with the time; `now` gives
// seconds on any monotonic clock.
class StartupProgress
{
public:
  // `activity` begins each line: "starting up", or "rebuilding" for a live rebuild.
  StartupProgress(std::function<void(const std::string&)> log, std::function<double()> now,
                  double quiet_seconds = 1.0, double repeat_seconds = 10.0, std::string activity = "starting up",
                  double iteration_seconds = 2.0);

  void onStage(const std::string& stage);
  void onIteration(const std::string& stage, int iteration, double residual, double target);
  void poll();

private:
  std::function<void(const std::string&)> log_;
  std::function<double()> now_;
  double quiet_seconds_, repeat_seconds_;
  std::string activity_;
  double iteration_seconds_;
  std::string iteration_;        // the latest iteration's words, empty in a stage without any
  bool iteration_new_ = false;   // not logged yet
  std::mutex mutex_;
  double start_ = 0.0, stage_start_ = 0.0, last_report_ = 0.0;
  std::string stage_ = "building the grid", reported_stage_;
};

}  // namespace modal_mass_spring
