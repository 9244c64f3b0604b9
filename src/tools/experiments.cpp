// Runs the cost and stability experiments on Simulation objects and writes every experiment's CSV
// files (the accuracy experiment: accuracy_experiment.cpp).
#include "experiment_support.h"
#include "experiments.h"

#include "modal_mass_spring/spring_forces.h"
#include "modal_mass_spring/validation.h"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <memory>
#include <sstream>
#include <stdexcept>

#include <time.h>

namespace modal_mass_spring
{

using namespace experiment_support;

double cpuPerSimulatedSecond(double step_cpu_seconds, double time_step)
{
  if (!(step_cpu_seconds > 0.0 && time_step > 0.0) || !std::isfinite(step_cpu_seconds) || !std::isfinite(time_step))
    return std::numeric_limits<double>::quiet_NaN();
  return step_cpu_seconds / time_step;
}

double realTimeFactor(double step_cpu_seconds, double time_step)
{
  return 1.0 / cpuPerSimulatedSecond(step_cpu_seconds, time_step);
}

// ---------------------------------------------------------------- setups

const ExperimentSetup* explicitTwin(const ExperimentSetup& setup, const std::vector<ExperimentSetup>& setups)
{
  auto othersEqual = [](const ExperimentSetup& a, const ExperimentSetup& b) {
    if (a.settings.size() != b.settings.size())
      return false;
    for (size_t k = 0; k < a.settings.size(); ++k)
      if (a.settings[k].first != b.settings[k].first ||
          (a.settings[k].first != "integrator" && a.settings[k].second != b.settings[k].second))
        return false;
    return true;
  };
  for (const ExperimentSetup& other : setups)
    if (&other != &setup && other.sim.integrator == IntegratorKind::Explicit && othersEqual(setup, other))
      return &other;
  return nullptr;
}

// ---------------------------------------------------------------- cost

namespace
{

// The median time to build the modal basis, and the last Simulation built.
std::unique_ptr<Simulation> buildTimed(const GridParams& grid, const SimulationParams& params, int repeats,
                                       double& build_seconds)
{
  std::vector<double> builds;
  std::unique_ptr<Simulation> sim;
  for (int b = 0; b < std::max(1, repeats); ++b)
  {
    sim = std::make_unique<Simulation>(grid, params);
    sim->buildBasis();  // `full` builds none until a modal method is set: its build is timed here too
    builds.push_back(sim->basis().build_seconds);
  }
  build_seconds = median(builds);
  return sim;
}

// Method "adaptive"'s settings from a setup's parameters, or none for the plain methods.
std::optional<AdaptiveSettings> adaptiveIf(bool adaptive, const SimulationParams& params)
{
  return adaptive ? std::optional<AdaptiveSettings>(adaptiveSettings(params)) : std::nullopt;
}

// A run from the initial state: the simulation reset and, with `adaptive`, an AdaptiveStepper made
// there (both before any timing starts); then steps of the simulation's method or through the
// stepper, which stop at a divergence.
class RunFromReset
{
public:
  RunFromReset(Simulation& sim, const std::optional<AdaptiveSettings>& adaptive) : sim_(sim)
  {
    sim_.reset();
    if (adaptive)
      stepper_.emplace(sim_, *adaptive);
  }
  StepResult step(int steps)
  {
    if (!stepper_)
      return sim_.step(steps);
    StepResult total;
    for (int k = 0; k < steps && !total.diverged; ++k)
    {
      const StepResult result = stepper_->step();
      total.diverged = result.diverged;
      total.message = result.message;
      total.steps_taken += result.diverged ? 0 : 1;
    }
    return total;
  }
  // Method "adaptive": its share of reduced steps and its switches.
  void report(CostRow& row) const
  {
    if (!stepper_)
      return;
    row.reduced_share = stepper_->reducedShare();
    row.switches = stepper_->switches();
  }

private:
  Simulation& sim_;
  std::optional<AdaptiveStepper> stepper_;
};

// Steps per timed run so that one run lasts about min_repeat_seconds, timed on the steps the method
// takes: one that diverges is timed up to its divergence (its timed runs end there). An adaptive
// run spans two of its checks at least, so that its time holds what the checks cost and decide.
int stepsPerRepeat(Simulation& sim, double min_repeat_seconds, const std::optional<AdaptiveSettings>& adaptive)
{
  int calibration = 10;
  double per_step = 0.0;
  while (true)
  {
    RunFromReset run(sim, adaptive);
    const auto start = Clock::now();
    const StepResult result = run.step(calibration);
    const double elapsed = seconds(start);
    per_step = elapsed / (result.steps_taken + (result.diverged ? 1 : 0));
    if (result.diverged || elapsed > 0.2 * min_repeat_seconds || calibration >= 1000000)
      break;
    calibration *= 4;
  }
  const int fewest = adaptive ? std::max(10, 2 * adaptive->check_steps) : 10;
  return std::max(fewest, static_cast<int>(std::min(1e7, min_repeat_seconds / std::max(per_step, 1e-9))));
}

// Seconds per step of one timed run of up to `steps` steps. A run that diverges ends there (the linear
// method drifts without bound along zero modes; a step too large diverges at once): its time is per
// step up to and including the one that diverged, and diverged_step says which (the first of the
// run is 1). Starting over and going on instead would time resets, millions of them for a method
// that diverges at its first step. Wall time per step; the thread's CPU time per step goes to
// `cpu_seconds`.
double timedRun(Simulation& sim, int steps, const std::optional<AdaptiveSettings>& adaptive, CostRow& row,
                double& cpu_seconds)
{
  long& diverged_step = row.diverged_step;
  RunFromReset run(sim, adaptive);
  const auto start = Clock::now();
  const double cpu_start = threadCpuSeconds();
  const StepResult result = run.step(steps);
  const double elapsed = seconds(start), cpu = threadCpuSeconds() - cpu_start;
  run.report(row);
  const long taken = result.diverged ? result.steps_taken + 1 : steps;
  if (result.diverged)
    diverged_step = taken;
  cpu_seconds = cpu / taken;
  return elapsed / taken;
}

}  // namespace

std::vector<CostRow> runCost(const ExperimentSetup& setup, const CostOptions& options, const ProgressFn& progress)
{
  std::vector<CostRow> rows;
  const double total = static_cast<double>(options.sizes.size());
  for (size_t s = 0; s < options.sizes.size(); ++s)
  {
    GridParams grid = setup.grid;
    grid.rows = grid.cols = options.sizes[s];
    grid.fixed.clear();  // a fixed list names particles of the configured size only: use the top row
    const std::string label = "cost " + std::to_string(grid.rows) + "x" + std::to_string(grid.cols);
    report(progress, label, s / total);
    double build_seconds = 0.0;
    const std::unique_ptr<Simulation> sim = buildTimed(grid, setup.sim, options.build_repeats, build_seconds);

    const size_t runs = options.methods.size() + (options.adaptive ? 1 : 0);
    for (size_t m = 0; m < runs; ++m)
    {
      // The last run is adaptive's: its reduced method under its stepper.
      const bool adaptive = m == options.methods.size();
      const std::optional<AdaptiveSettings> settings = adaptiveIf(adaptive, setup.sim);
      CostRow row;
      row.variant = setup.variant;
      row.method = adaptive ? "adaptive" : toString(options.methods[m]);
      row.dimension = grid.dimension;
      row.rows = grid.rows;
      row.cols = grid.cols;
      row.particles = sim->grid().numParticles();
      row.free_dofs = sim->grid().numFreeDofs();
      row.springs = static_cast<int>(sim->grid().springs().size());
      row.num_modes = setup.sim.num_modes;
      row.build_seconds = build_seconds;
      row.repeats = options.repeats;
      sim->setMethod(adaptive ? setup.sim.adaptive_method : options.methods[m]);
      row.steps_per_repeat = stepsPerRepeat(*sim, options.min_repeat_seconds, settings);
      std::vector<double> per_step, cpu_per_step;
      for (int r = 0; r < options.repeats; ++r)
      {
        cpu_per_step.emplace_back();
        per_step.push_back(timedRun(*sim, row.steps_per_repeat, settings, row, cpu_per_step.back()));
        report(progress, label + " " + row.method, (s + (m + (r + 1.0) / options.repeats) / runs) / total);
      }
      row.step_seconds = median(per_step);
      row.step_seconds_min = *std::min_element(per_step.begin(), per_step.end());
      row.step_cpu_seconds = median(cpu_per_step);
      row.time_step = setup.sim.time_step;
      row.cpu_per_simulated_second = cpuPerSimulatedSecond(row.step_cpu_seconds, row.time_step);
      row.real_time_factor = realTimeFactor(row.step_cpu_seconds, row.time_step);
      rows.push_back(row);
    }
  }
  report(progress, "cost", 1.0);
  return rows;
}

// ---------------------------------------------------------------- stability

double highestFrequencyAtRest(const Grid& grid, int max_dofs)
{
  const int n = grid.numFreeDofs();
  if (n > max_dofs)
    return std::numeric_limits<double>::quiet_NaN();
  const Eigen::MatrixXd k = Eigen::MatrixXd(tangentStiffness(grid, grid.initialPositions())) / grid.particleMass();
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> solver(k, Eigen::EigenvaluesOnly);
  return std::sqrt(std::max(0.0, solver.eigenvalues().maxCoeff()));
}

bool checkStableAt(const ExperimentSetup& setup, Method method, double dt, int steps, bool adaptive)
{
  SimulationParams params = withMethod(setup.sim, adaptive ? setup.sim.adaptive_method : method);
  params.time_step = dt;
  Simulation sim(setup.grid, params);
  return !RunFromReset(sim, adaptiveIf(adaptive, params)).step(steps).diverged;
}

namespace
{

// The search for one method: every trial is kept in the row, so "every step tried below stable_dt
// was stable" can be checked from the outside.
class StabilitySearch
{
public:
  StabilitySearch(Simulation& sim, const StabilityOptions& options, StabilityRow& row,
                  std::optional<AdaptiveSettings> adaptive)
    : sim_(sim), options_(options), row_(row), adaptive_(std::move(adaptive))
  {
  }

  // From `start`: the bracket by doubling or halving, the upward scan through it, then bisection.
  void boundary(double start)
  {
    double lo = start, hi = start;
    if (stable(start))
    {
      for (hi = 2.0 * lo; hi <= options_.max_time_step && stable(hi); hi *= 2.0)
        lo = hi;
      if (hi > options_.max_time_step)
      {
        row_.stable_dt = lo;
        row_.unstable_dt = std::numeric_limits<double>::infinity();
        return;
      }
    }
    else
    {
      for (lo = 0.5 * hi; lo >= options_.min_time_step && !stable(lo); lo *= 0.5)
        hi = lo;
      if (lo < options_.min_time_step)
      {
        row_.stable_dt = 0.0;
        row_.unstable_dt = hi;
        return;
      }
    }
    // Through the bracket upward: the first divergence may lie below the one the doubling found.
    for (double dt = lo * options_.scan_ratio; dt < hi; dt *= options_.scan_ratio)
    {
      if (!stable(dt))
      {
        hi = dt;
        break;
      }
      lo = dt;
    }
    // Bisection keeps every tried step below lo stable: a divergence only ever lowers hi. It stops
    // at the tolerance or when the midpoint is no longer a new number.
    while (hi - lo > options_.tolerance * lo)
    {
      const double mid = 0.5 * (lo + hi);
      if (!(mid > lo && mid < hi))
        break;
      (stable(mid) ? lo : hi) = mid;
    }
    pocketsBelow(lo, hi);
    row_.stable_dt = lo;
    row_.unstable_dt = hi;
  }

  // Pockets of divergence narrower than a scan step hide between scan steps (paper_2d's `full` has
  // one: docs/results.md, "Claim 2"). Downward from lo over one scan step, at
  // the tolerance's resolution but at most 20 trials a scan step: a divergence found moves hi there
  // and lo to the next stable step below it, and the look continues one scan step below that.
  void pocketsBelow(double& lo, double& hi)
  {
    const double ratio = 1.0 + std::max(options_.tolerance, (options_.scan_ratio - 1.0) / 20.0);
    if (ratio >= options_.scan_ratio)
      return;
    double floor = lo / options_.scan_ratio;
    for (double dt = lo / ratio; dt > floor; dt /= ratio)
    {
      if (stable(dt))
        continue;
      for (hi = dt; !stable(dt /= ratio); hi = dt)
        if (dt < options_.min_time_step)
        {
          lo = 0.0;
          return;
        }
      lo = dt;
      floor = lo / options_.scan_ratio;
    }
  }

  // Runs of stable scan steps above the boundary, up to window_factor times it.
  void windows()
  {
    if (!(row_.stable_dt > 0.0) || !std::isfinite(row_.unstable_dt))
      return;
    const double end = std::min(options_.window_factor * row_.unstable_dt, options_.max_time_step);
    bool open = false;
    for (double dt = row_.unstable_dt * options_.scan_ratio; dt <= end; dt *= options_.scan_ratio)
    {
      const bool ok = stable(dt);
      if (ok && open)
        row_.windows.back().to = dt;
      else if (ok)
        row_.windows.push_back({dt, dt});
      open = ok;
    }
  }

private:
  bool stable(double dt)
  {
    sim_.setTimeStep(dt);
    const bool ok = !RunFromReset(sim_, adaptive_).step(options_.steps).diverged;
    row_.tried.push_back({dt, ok});
    ++row_.trials;
    return ok;
  }

  Simulation& sim_;
  const StabilityOptions& options_;
  StabilityRow& row_;
  std::optional<AdaptiveSettings> adaptive_;  // method "adaptive": each trial through its stepper
};

}  // namespace

void checkStabilityOptions(const StabilityOptions& options)
{
  if (options.steps < 1)
    rejectParameter("--stability-steps", options.steps, "must be an integer >= 1");
  if (!(options.tolerance >= kMinTolerance && options.tolerance <= 0.5))
    rejectParameter("--tolerance", options.tolerance,
                    "must be a relative tolerance in [" + std::to_string(kMinTolerance) +
                        ", 0.5]: below that the bisection cannot resolve the step in double precision");
  if (!(options.min_time_step > 0.0 && options.max_time_step > options.min_time_step &&
        std::isfinite(options.max_time_step)))
    rejectParameter("--max-time-step", options.max_time_step,
                    "must be a finite number of seconds above " + std::to_string(options.min_time_step));
  if (!(options.scan_ratio >= 1.001 && options.scan_ratio <= 2.0))
    rejectParameter("--scan-ratio", options.scan_ratio, "must be in [1.001, 2]");
  if (!(options.window_factor >= 1.0 && options.window_factor <= 100.0))
    rejectParameter("--window-factor", options.window_factor, "must be in [1, 100]");
}

std::vector<StabilityRow> runStability(const ExperimentSetup& setup, const StabilityOptions& options, const ProgressFn& progress)
{
  checkStabilityOptions(options);
  if (!(setup.sim.time_step < options.max_time_step))
    rejectParameter("--max-time-step", options.max_time_step,
                    "must be above time_step = " + std::to_string(setup.sim.time_step) + " s, where the search starts");
  std::vector<StabilityRow> rows;
  const size_t runs = options.methods.size() + (options.adaptive ? 1 : 0);
  for (size_t m = 0; m < runs; ++m)
  {
    // The last run is adaptive's: its reduced method under its stepper.
    const bool adaptive = m == options.methods.size();
    const Method method = adaptive ? setup.sim.adaptive_method : options.methods[m];
    Simulation sim(setup.grid, withMethod(setup.sim, method), StageFn{}, options.cache);
    StabilityRow row;
    row.variant = setup.variant;
    row.method = adaptive ? "adaptive" : toString(method);
    row.steps = options.steps;
    row.tolerance = options.tolerance;
    sim.buildBasis();  // `full` builds none by itself; its row reports the modal bound beside its own
    const ModalBasis& basis = method == Method::Linear ? sim.basis() : sim.physicalBasis();
    row.modal_bound = 2.0 / basis.frequencies.maxCoeff();
    row.full_bound = 2.0 / highestFrequencyAtRest(sim.grid());
    const std::string label = "stability " + row.method;
    report(progress, label, static_cast<double>(m) / runs);
    StabilitySearch search(sim, options, row, adaptiveIf(adaptive, setup.sim));
    search.boundary(setup.sim.time_step);
    report(progress, label, (m + 0.6) / runs);
    search.windows();
    rows.push_back(row);
    report(progress, label, (m + 1.0) / runs);
  }
  return rows;
}

// ---------------------------------------------------------------- CSV

namespace
{

// Enough digits to round-trip what the plots and tests compare.
std::ostream& precise(std::ostream& out)
{
  out.precision(10);
  return out;
}

}  // namespace

namespace
{

// A number as a CSV field: empty when not finite.
struct Field
{
  double value;
};

std::ostream& operator<<(std::ostream& out, Field f)
{
  if (std::isfinite(f.value))
    out << f.value;
  return out;
}

// "from:to" per window, windows separated by ';' (the field stays one CSV field).
std::string windowsField(const std::vector<StableWindow>& windows)
{
  std::ostringstream text;
  text.precision(6);
  for (size_t k = 0; k < windows.size(); ++k)
    text << (k ? ";" : "") << windows[k].from << ':' << windows[k].to;
  return text.str();
}

}  // namespace

void writeCostCsv(std::ostream& out, const std::vector<CostRow>& rows)
{
  precise(out) << "variant,method,dimension,rows,cols,particles,free_dofs,springs,num_modes,"
                  "build_seconds,step_seconds,step_seconds_min,step_cpu_seconds,time_step,cpu_per_simulated_second,"
                  "real_time_factor,repeats,steps_per_repeat,diverged,diverged_step,reduced_share,switches\n";
  for (const CostRow& r : rows)
    out << r.variant << ',' << r.method << ',' << r.dimension << ',' << r.rows << ',' << r.cols << ','
        << r.particles << ',' << r.free_dofs << ',' << r.springs << ',' << r.num_modes << ','
        << Field{r.build_seconds} << ',' << Field{r.step_seconds} << ',' << Field{r.step_seconds_min} << ','
        << Field{r.step_cpu_seconds} << ',' << Field{r.time_step} << ',' << Field{r.cpu_per_simulated_second} << ','
        << Field{r.real_time_factor} << ',' << r.repeats << ',' << r.steps_per_repeat << ','
        << (r.diverged_step > 0 ? 1 : 0) << ',' << r.diverged_step << ',' << Field{r.reduced_share} << ','
        << (r.switches >= 0 ? std::to_string(r.switches) : "") << '\n';
}

void writeErrorCsv(std::ostream& out, const std::vector<ErrorSample>& rows)
{
  precise(out) << "variant,method,step,time,max_distance,rms_distance,max_displacement,energy,diverged,step_seconds,"
                  "center_y,error_indicator,surface_distance,error_estimate\n";
  for (const ErrorSample& e : rows)
    out << e.variant << ',' << e.method << ',' << e.step << ',' << Field{e.time} << ',' << Field{e.max_distance}
        << ',' << Field{e.rms_distance} << ',' << Field{e.max_displacement} << ',' << Field{e.energy} << ','
        << (e.diverged ? 1 : 0) << ',' << Field{e.step_seconds} << ',' << Field{e.center_y} << ','
        << Field{e.error_indicator} << ',' << Field{e.surface_distance} << ',' << Field{e.error_estimate}
        << '\n';
}

void writeCubatureCsv(std::ostream& out, const std::vector<CubatureRow>& rows)
{
  precise(out) << "variant,springs,grid_springs,training_poses,tolerance,training_error,heldout_error,training_seconds\n";
  for (const CubatureRow& r : rows)
    out << r.variant << ',' << r.springs << ',' << r.grid_springs << ',' << r.training_poses << ','
        << Field{r.tolerance} << ',' << Field{r.training_error} << ',' << Field{r.heldout_error} << ','
        << Field{r.training_seconds} << '\n';
}

std::vector<AccuracySummary> notBuiltSummaries(const std::string& variant, const AccuracyResult& result)
{
  const double nan = std::numeric_limits<double>::quiet_NaN();
  std::vector<AccuracySummary> out;
  for (const auto& [method, reason] : result.not_built)
    out.push_back({variant, method, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, false, reason, nan, nan, -1, nan, nan, nan});
  return out;
}

void writeAccuracySummaryCsv(std::ostream& out, const std::vector<AccuracySummary>& rows)
{
  precise(out) << "variant,method,mean_rms,max_rms,mean_max,final_rms,step_seconds_median,step_seconds_mean,"
                  "step_cpu_seconds_mean,step_cpu_seconds_median,cpu_per_simulated_second,real_time_factor,diverged,not_built,"
                  "indicator_rank_correlation,reduced_share,switches,time_step,deepest,mean_surface\n";
  for (const AccuracySummary& s : rows)
  {
    // The reason is free text: quoted, its quotes doubled.
    std::string reason;
    for (char c : s.not_built)
      reason += c == '"' ? std::string("\"\"") : std::string(1, c);
    out << s.variant << ',' << s.method << ',' << Field{s.mean_rms} << ',' << Field{s.max_rms} << ','
        << Field{s.mean_max} << ',' << Field{s.final_rms} << ',' << Field{s.step_seconds_median} << ','
        << Field{s.step_seconds_mean} << ',' << Field{s.step_cpu_seconds_mean} << ',' << Field{s.step_cpu_seconds_median} << ','
        << Field{s.cpu_per_simulated_second} << ',' << Field{s.real_time_factor} << ',' << (s.diverged ? 1 : 0) << ",\"" << reason << "\","
        << Field{s.indicator_rank_correlation} << ',' << Field{s.reduced_share} << ','
        << (s.switches >= 0 ? std::to_string(s.switches) : std::string()) << ',' << Field{s.time_step} << ','
        << Field{s.deepest} << ',' << Field{s.mean_surface} << '\n';
  }
}

void writeSnapshotCsv(std::ostream& out, const Grid& grid, const std::vector<Snapshot>& snapshots)
{
  precise(out) << "variant,method,step,time,particle,row,col,fixed,x,y,z\n";
  const int cols = grid.params().cols;
  for (const Snapshot& s : snapshots)
    for (int p = 0; p < grid.numParticles(); ++p)
      out << s.variant << ',' << s.method << ',' << s.step << ',' << Field{s.time} << ',' << p << ',' << p / cols
          << ',' << p % cols << ',' << (grid.isFixed(p) ? 1 : 0) << ',' << Field{s.points(0, p)} << ','
          << Field{s.points(1, p)} << ',' << Field{s.points(2, p)} << '\n';
}

void writeStabilityCsv(std::ostream& out, const std::vector<StabilityRow>& rows)
{
  precise(out) << "variant,method,stable_dt,unstable_dt,trials,steps,tolerance,modal_bound,full_bound,"
                  "stable_windows,check_dt,check_stable\n";
  for (const StabilityRow& r : rows)
    out << r.variant << ',' << r.method << ',' << Field{r.stable_dt} << ',' << Field{r.unstable_dt} << ','
        << r.trials << ',' << r.steps << ',' << Field{r.tolerance} << ',' << Field{r.modal_bound} << ','
        << Field{r.full_bound} << ',' << windowsField(r.windows) << ',' << Field{r.check_dt} << ','
        << (r.check_dt > 0.0 ? (r.check_stable ? 1 : 0) : -1) << '\n';
}

}  // namespace modal_mass_spring
