// The paper's experiments on the core: cost, accuracy against `full`, and the largest stable step.
#pragma once

#include "handle_scenarios.h"

#include "modal_mass_spring/adaptive.h"
#include "modal_mass_spring/cpu_time.h"
#include "modal_mass_spring/simulation.h"

#include <Eigen/Core>

#include <functional>
#include <limits>
#include <ostream>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace modal_mass_spring
{

// One combination of parameters an experiment runs, named for the CSV `variant` column ("base", or
// the varied keys as "key=value key=value").
struct ExperimentSetup
{
  std::string variant = "base";
  GridParams grid;
  SimulationParams sim;
  // The varied keys and their values (YAML text), in --vary order; empty for "base".
  std::vector<std::pair<std::string, std::string>> settings;
  // With a scenario, grid.handles are its particle groups and every run of the accuracy experiment
  // moves them along it, one step at a time (HandleDriver).
  std::optional<HandleScenario> handle_scenario;
};

// The setup among `setups` that differs from `setup` only in running the explicit integrator: every
// other varied setting equal, `integrator` explicit. Nullptr when there is none.
const ExperimentSetup* explicitTwin(const ExperimentSetup& setup, const std::vector<ExperimentSetup>& setups);

// CPU seconds per simulated second of a step of `time_step` s that took `step_cpu_seconds` of CPU: the
// figure that compares steps of different sizes; its inverse is the real-time factor the CPU allows
// (above 1: faster than real time). NaN unless both are positive and finite.
double cpuPerSimulatedSecond(double step_cpu_seconds, double time_step);
double realTimeFactor(double step_cpu_seconds, double time_step);

// Reports how far a long run is (label, fraction done in [0, 1]); may be empty.
using ProgressFn = std::function<void(const std::string&, double)>;

// ---------------------------------------------------------------- 1. cost

struct CostOptions
{
  std::vector<int> sizes{5, 10, 20, 40};  // square grids, sizes x sizes particles
  std::vector<Method> methods{Method::Full, Method::Linear, Method::Physical, Method::Cubature};
  int repeats = 7;                   // timed runs per method and size; the median is reported
  double min_repeat_seconds = 0.02;  // each timed run takes at least this many steps' worth
  int build_repeats = 3;             // basis builds per size; the median is reported
  bool adaptive = false;             // also time method "adaptive" (as AccuracyOptions::adaptive)
};

struct CostRow
{
  std::string variant, method;
  int dimension = 0, rows = 0, cols = 0, particles = 0, free_dofs = 0, springs = 0, num_modes = 0;
  double build_seconds = 0.0;        // median time to build the modal basis
  double step_seconds = 0.0;         // median time per step
  double step_seconds_min = 0.0;
  double step_cpu_seconds = 0.0;     // median of this thread's CPU time per step
  double time_step = 0.0;            // s
  double cpu_per_simulated_second = 0.0, real_time_factor = 0.0;  // of step_cpu_seconds and time_step
  int repeats = 0, steps_per_repeat = 0;
  // A timed run diverged: the step it diverged at (1: the first; the same in every run), and each run
  // ended there, its time per step over the steps up to and including that one. 0: none diverged.
  long diverged_step = 0;
  // Method "adaptive": the share of the last timed run's steps taken reduced and its switches (else
  // NaN, -1).
  double reduced_share = std::numeric_limits<double>::quiet_NaN();
  int switches = -1;
};

std::vector<CostRow> runCost(const ExperimentSetup& setup, const CostOptions& options, const ProgressFn& progress = {});

// ---------------------------------------------------------------- 2. and 4. accuracy

struct AccuracyOptions
{
  std::vector<Method> methods{Method::Linear, Method::Physical, Method::Cubature};  // compared with `full`
  int steps = 5000;
  int interval = 1000;  // snapshots of every particle every `interval` steps, as in the paper
  int sample = 10;      // error samples every `sample` steps (must divide `interval`)
  // 0: the reference is `full` of the same setup at the same time step (the paper's comparison).
  // > 0: the reference is `full` with the explicit integrator at this time step (s; time_step must be
  // a whole multiple of it), method "reference" in the results; `full` of the setup is compared with
  // it like the modal methods, and a second reference at half this step checks that the first one is
  // converged (`reference_check`).
  double reference_time_step = 0.0;
  bool adaptive = false;  // also run method "adaptive" (AdaptiveStepper, the setup's adaptive settings)
  // How many of the setup's time steps one step of `coarse` spans (0: coarseStepMultiple, or the
  // largest smaller number that divides `sample`); it must divide `sample`.
  int coarse_step_multiple = 0;
  bool snapshots = true;  // keep the particle positions every `interval` steps
  // Each run steps a block of samples alone, against the reference's points kept for the block (this
  // many bytes of them, at least one sample, and the block's start): a run stepped between the
  // others' steps would find its data evicted from the cache by theirs, and be timed slower than it
  // runs alone. The results are in the same order (the divergence messages grouped by run).
  size_t reference_block_bytes = size_t{256} << 20;
  // Where the bases and cubatures are cached between runs (directory empty: off). The cost
  // experiment never uses it: it measures the build.
  CacheOptions cache;
};

// One method at one step, against `full` at the same step. Distances are per particle, between the
// method's and full's positions: the largest and the RMS over the free particles (neither fixed nor
// held by a handle: handles sit where they are put under every method).
struct ErrorSample
{
  std::string variant, method;
  long step = 0;
  double time = 0.0;
  double max_distance = 0.0, rms_distance = 0.0;
  double max_displacement = 0.0;  // of this method's particles from the initial positions
  double energy = 0.0;            // kinetic + spring + gravity
  bool diverged = false;          // the method diverged at or before this step: no distances
  // Wall time per step over the `sample` steps that led here (0 at step 0 and for the reference).
  double step_seconds = 0.0;
  double step_cpu_seconds = 0.0;  // and this thread's CPU time per step, which other processes do not inflate
  // The particles' mean y (m): a swing of a 3D sheet about its top edge (along x) moves it; 0 in 2D.
  double center_y = 0.0;
  // The method's error indicator, the largest since the state was set (Simulation::errorIndicator,
  // m); NaN for `full` and the reference.
  double error_indicator = std::numeric_limits<double>::quiet_NaN();
  // The estimate of its distance to `full` made of it (errorEstimate, m: what `adaptive` holds against
  // error_tolerance); NaN likewise.
  double error_estimate = std::numeric_limits<double>::quiet_NaN();
  // Method "adaptive": the share of its steps so far taken reduced and its switches (else NaN, -1).
  double reduced_share = std::numeric_limits<double>::quiet_NaN();
  int switches = -1;
  double time_step = 0.0;  // this method's own (s): `coarse` may span several of the setup's
  double depth = 0.0;      // how deep its deepest free particle is inside a collider (m; 0: none; NaN: no colliders)
  // The distance to `full` as surfaces (surfaceDistance, m): where the cloth crumples, how alike the
  // folds are, which the per-particle distance does not tell.
  double surface_distance = 0.0;
};

struct Snapshot
{
  std::string variant, method;
  long step = 0;
  double time = 0.0;
  Eigen::Matrix3Xd points;
};

// A cubature's training report (|T|, errors, time) for one setup.
struct CubatureRow
{
  std::string variant;
  int springs = 0, grid_springs = 0, training_poses = 0;
  double tolerance = 0.0, training_error = 0.0, heldout_error = 0.0, training_seconds = 0.0;
  double validation_error = 0.0;  // on the last validation set, which decided the stop
  bool loaded = false;            // from the cache (with --no-cache: the one the check before the runs filled)
};

struct AccuracyResult
{
  std::vector<ErrorSample> errors;  // `full` included, with zero distances
  std::vector<Snapshot> snapshots;  // `full` included
  std::vector<std::string> messages;  // divergences, one line each
  // With a reference_time_step: the reference at half that step against the one at that step
  // (method "reference_half_step"), and the largest RMS and largest particle distance between them.
  std::vector<ErrorSample> reference_check;
  double reference_check_max_rms = 0.0, reference_check_max_distance = 0.0;
  // The eigenbasis of the setup (`linear`'s), and the basis of `physical`: with modal derivatives,
  // what building them did and the Ritz frequencies of the whole basis.
  Eigen::VectorXd frequencies;
  int num_zero_modes = 0;
  BasisKind basis = BasisKind::LinearModes;
  DerivativeBasisInfo derivatives;
  SkinningInfo skinning;  // with basis: skinning
  Eigen::VectorXd physical_frequencies;
  // The training of `cubature` when it was compared, and the grid's number of springs.
  std::optional<CubatureRow> cubature;
  // Compared methods whose Simulation could not be built on the setup (e.g. no constraint modes),
  // with the reason; the other methods run without them.
  std::vector<std::pair<std::string, std::string>> not_built;
};

AccuracyResult runAccuracy(const ExperimentSetup& setup, const AccuracyOptions& options, const ProgressFn& progress = {});

// ---------------------------------------------------------------- 3. stability

// Stability is not monotone in the time step (a grid can diverge at one step and run at a larger
// one), so the search never assumes one boundary: it scans upward and reports the largest step
// below which every step it tried was stable, then the stable windows it found above that.
struct StabilityOptions
{
  std::vector<Method> methods{Method::Full, Method::Linear, Method::Physical, Method::Cubature};
  int steps = 10000;        // S: a time step is stable when S steps from the setup's initial state do not diverge
  double tolerance = 1e-3;  // the last bracket is bisected until (unstable - stable) <= tolerance * stable
  double max_time_step = 10.0;  // s; no divergence up to here counts as unbounded
  double min_time_step = 1e-9;  // s; divergence down to here counts as no stable step
  // The scan: doubling (or halving) from the setup's time_step to the first divergence, then upward
  // in steps of this ratio through the last octave, then bisection of the first divergence found,
  // then a look for pockets of divergence over the scan step below it, at the tolerance's
  // resolution (at most 20 trials a scan step).
  double scan_ratio = 1.02;
  // Stable windows are looked for by the same scan from the boundary up to this multiple of it (and
  // at most max_time_step).
  double window_factor = 2.0;
  CacheOptions cache;  // as AccuracyOptions::cache
  bool adaptive = false;  // also search method "adaptive" (as AccuracyOptions::adaptive)
};

// The smallest and largest step of a run of consecutive stable scan steps above the boundary.
struct StableWindow
{
  double from = 0.0, to = 0.0;
};

struct StabilityTrial
{
  double dt = 0.0;
  bool stable = false;
};

struct StabilityRow
{
  std::string variant, method;
  // The largest step below which every step tried was stable (0: none above min_time_step), and the
  // smallest step found to diverge (infinity: none up to max_time_step).
  double stable_dt = 0.0;
  double unstable_dt = 0.0;
  int trials = 0;
  int steps = 0;
  double tolerance = 0.0;
  // Closed forms of the explicit scheme, 2 / omega: for the highest mode of the basis and for the
  // highest frequency of K(x0) over all free dofs (NaN when the grid is too large for a dense solve;
  // infinity when every mode of the basis is a zero mode).
  double modal_bound = 0.0;
  double full_bound = 0.0;
  // Stable windows above unstable_dt, in increasing order.
  std::vector<StableWindow> windows;
  // Every step tried, in the order tried.
  std::vector<StabilityTrial> tried;
  // A direct check at one time step (see checkStableAt): the step (0: not checked) and the outcome.
  double check_dt = 0.0;
  bool check_stable = false;
};

// Throws std::invalid_argument (rejectParameter, with the tool's option names) for options with which
// the search could not end: a tolerance below what doubles resolve, a scan ratio too close to 1, ...
constexpr double kMinTolerance = 1e-12;
void checkStabilityOptions(const StabilityOptions& options);

std::vector<StabilityRow> runStability(const ExperimentSetup& setup, const StabilityOptions& options,
                                       const ProgressFn& progress = {});

// time_step / reference_time_step when it is a whole number in [1, kMaxReferenceSubsteps]; throws
// std::invalid_argument (naming --reference-time-step) otherwise.
constexpr int kMaxReferenceSubsteps = 100000;
int referenceSubsteps(double time_step, double reference_time_step);

// Whether `method` on the setup runs `steps` steps at time step `dt` without diverging; with
// `adaptive`, the setup's adaptive_method stepped through an AdaptiveStepper.
bool checkStableAt(const ExperimentSetup& setup, Method method, double dt, int steps, bool adaptive = false);

// Largest dense eigen-frequency of M^-1 K(x0) on the free dofs, NaN above `max_dofs`.
double highestFrequencyAtRest(const Grid& grid, int max_dofs = 3000);

// ---------------------------------------------------------------- CSV files the plotting script reads
// A number that is not finite (a diverged sample, the bound of a basis of zero modes, no divergence
// found) is written as an empty field: the `diverged` flag or the column's meaning says why.

void writeCostCsv(std::ostream& out, const std::vector<CostRow>& rows);
void writeErrorCsv(std::ostream& out, const std::vector<ErrorSample>& rows);
void writeCubatureCsv(std::ostream& out, const std::vector<CubatureRow>& rows);
// The accuracy experiment's summary per variant and method: mean and largest RMS distance to the
// reference, the distance at the end, and the median wall time per step.
struct AccuracySummary
{
  std::string variant, method;
  double mean_rms = 0.0, max_rms = 0.0, mean_max = 0.0, final_rms = 0.0;
  double step_seconds_median = 0.0, step_seconds_mean = 0.0, step_cpu_seconds_median = 0.0, step_cpu_seconds_mean = 0.0;
  // The CPU time per step over the time step (cpuPerSimulatedSecond) and its inverse: of the median
  // step, and for `adaptive`, whose steps have two costs, of the mean.
  double cpu_per_simulated_second = 0.0, real_time_factor = 0.0;
  bool diverged = false;
  std::string not_built;  // why the method could not be built (no samples, distances NaN); empty when it ran
  // Spearman's rank correlation of the error estimate with the RMS distance over the samples after
  // step 0 (NaN for `full`, or with fewer than three samples).
  double indicator_rank_correlation = std::numeric_limits<double>::quiet_NaN();
  // Method "adaptive": its share of reduced steps and its switches over the run (else NaN, -1).
  double reduced_share = std::numeric_limits<double>::quiet_NaN();
  int switches = -1;
  double time_step = std::numeric_limits<double>::quiet_NaN();  // s, the method's own
  double deepest = std::numeric_limits<double>::quiet_NaN();    // m, over the samples (NaN: no colliders)
  double mean_surface = 0.0;  // m, the mean surface distance (ErrorSample::surface_distance)
};
// Spearman's rank correlation of a and b (equal sizes; ties take their mean rank); NaN below three
// pairs or where either is constant.
double rankCorrelation(const std::vector<double>& a, const std::vector<double>& b);
// The summaries of the methods of `result` that did not build, for its variant.
std::vector<AccuracySummary> notBuiltSummaries(const std::string& variant, const AccuracyResult& result);
std::vector<AccuracySummary> summarizeAccuracy(const std::vector<ErrorSample>& rows);
void writeAccuracySummaryCsv(std::ostream& out, const std::vector<AccuracySummary>& rows);
void writeSnapshotCsv(std::ostream& out, const Grid& grid, const std::vector<Snapshot>& snapshots);
void writeStabilityCsv(std::ostream& out, const std::vector<StabilityRow>& rows);

}  // namespace modal_mass_spring
