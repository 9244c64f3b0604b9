// The accuracy experiment: every method stepped to the same samples as the reference, measured
// against it there, and its summary per variant and method.
#include "experiment_support.h"
#include "experiments.h"

#include "modal_mass_spring/surface_distance.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <tuple>

namespace modal_mass_spring
{

using namespace experiment_support;

namespace
{

// Per-particle distances between two sets of points, over the free particles.
void distances(const Grid& grid, const Eigen::Matrix3Xd& a, const Eigen::Matrix3Xd& b, double& max, double& rms)
{
  max = 0.0;
  double sum2 = 0.0;
  int count = 0;
  for (int p = 0; p < grid.numParticles(); ++p)
  {
    if (grid.isFixed(p) || grid.isHandle(p))
      continue;
    const double d = (a.col(p) - b.col(p)).norm();
    max = std::max(max, d);
    sum2 += d * d;
    ++count;
  }
  rms = count ? std::sqrt(sum2 / count) : 0.0;
}

double maxDisplacement(const Grid& grid, const Eigen::Matrix3Xd& points)
{
  const Eigen::Matrix3Xd initial = grid.toPoints(grid.initialPositions());
  return (points - initial).colwise().norm().maxCoeff();
}

}  // namespace

int referenceSubsteps(double time_step, double reference_time_step)
{
  const double ratio = time_step / reference_time_step;
  const double whole = std::round(ratio);
  // Checked before the conversion: a ratio beyond int is undefined behaviour to convert.
  if (!(reference_time_step > 0.0) || !std::isfinite(ratio) || whole < 1.0 || whole > kMaxReferenceSubsteps ||
      std::abs(ratio - whole) > 1e-6 * ratio)
  {
    std::ostringstream allowed;
    allowed << "must divide time_step = " << time_step << " s a whole number of times, at most "
            << kMaxReferenceSubsteps;
    rejectParameter("--reference-time-step", reference_time_step, allowed.str());
  }
  return static_cast<int>(whole);
}

namespace
{

// One simulation of the accuracy experiment, stepped `steps_per_sample` steps between samples.
struct AccuracyRun
{
  std::string name;
  std::unique_ptr<Simulation> sim;
  int steps_per_sample = 0;
  bool timed = false;  // its wall time per step is reported
  bool diverged = false;
  double step_seconds = 0.0, step_cpu_seconds = 0.0;
  std::unique_ptr<HandleDriver> driver = nullptr;  // moves the handles of a handle scenario, one step at a time
  std::unique_ptr<AdaptiveStepper> adaptive = nullptr;  // steps `sim` for method "adaptive"
  IndicatorMaximum indicator_max{};  // of the samples' readings

  void advance(const std::string& variant, std::vector<std::string>& messages)
  {
    if (diverged)
      return;
    const auto start = Clock::now();
    const double cpu_start = threadCpuSeconds();
    StepResult r;
    if (adaptive)
    {
      // It drives its own steps, which span one time step or several.
      const long until = sim->stepCount() + steps_per_sample;
      while (sim->stepCount() < until && !r.diverged)
        r = adaptive->step();
    }
    else if (driver)
      for (int k = 0; k < steps_per_sample && !r.diverged; ++k)
      {
        driver->drive(*sim);
        r = sim->step();
      }
    else
      r = sim->step(steps_per_sample);
    step_seconds = seconds(start) / steps_per_sample;
    step_cpu_seconds = (threadCpuSeconds() - cpu_start) / steps_per_sample;
    if (r.diverged)
    {
      diverged = true;
      messages.push_back(variant + ": " + name + ": " + r.message);
    }
  }
};

// The reference (runs[0]: `full` at the setup's step, or the converged `full` at the reference
// step) and every compared method; the check at half the reference step goes into `check`.
std::vector<AccuracyRun> accuracyRuns(const ExperimentSetup& setup, const AccuracyOptions& options, int divisor,
                                      std::unique_ptr<AccuracyRun>& check,
                                      std::vector<std::pair<std::string, std::string>>& not_built)
{
  auto referenceParams = [&](int divide) {
    SimulationParams p = withMethod(setup.sim, Method::Full);
    p.integrator = IntegratorKind::Explicit;
    p.linearization = Linearization::Rest;
    // In the world, handles prescribed: the same reference whichever formulation the methods use.
    p.handle_formulation = HandleFormulation::ConstraintModes;
    // `full` projects onto no basis: the same reference whichever basis the methods are given (an
    // enriched basis could not even be built at rest).
    p.basis = BasisKind::LinearModes;
    p.num_derivative_modes = 0;
    p.num_skinning_weights = 0;
    p.time_step = setup.sim.time_step / divide;
    return p;
  };
  std::vector<AccuracyRun> runs;
  if (divisor == 0)
    runs.push_back({"full", std::make_unique<Simulation>(setup.grid, withMethod(setup.sim, Method::Full), StageFn{}, options.cache),
                    options.sample, true});
  else
  {
    runs.push_back({"reference", std::make_unique<Simulation>(setup.grid, referenceParams(divisor), StageFn{}, options.cache),
                    options.sample * divisor, false});
    check.reset(new AccuracyRun{"reference at half its step",
                                std::make_unique<Simulation>(setup.grid, referenceParams(2 * divisor), StageFn{}, options.cache),
                                2 * options.sample * divisor, false});
  }
  // `coarse` spans several of the setup's steps at the margin to stability the setup's step has
  // (coarseStepMultiple), a number that divides the steps between samples.
  auto coarseMultiple = [&] {
    if (options.coarse_step_multiple > 0)
      return options.coarse_step_multiple;
    return coarseStepMultiple(setup.grid, withMethod(setup.sim, Method::Coarse), options.sample);
  };
  std::vector<Method> compared;
  for (Method m : options.methods)
    if ((divisor > 0 || m != Method::Full) && std::find(compared.begin(), compared.end(), m) == compared.end())
      compared.push_back(m);
  // A method that cannot be built on this setup (a basis or constraint modes that do not exist) is
  // reported and left out; the reference must build.
  for (Method m : compared)
    try
    {
      SimulationParams p = withMethod(setup.sim, m);
      const int multiple = m == Method::Coarse ? coarseMultiple() : 1;
      p.time_step *= multiple;
      runs.push_back({toString(m), std::make_unique<Simulation>(setup.grid, p, StageFn{}, options.cache),
                      options.sample / multiple, true});
    }
    catch (const std::bad_alloc&)
    {
      throw;
    }
    catch (const std::exception& e)
    {
      not_built.emplace_back(toString(m), e.what());
    }
  if (options.adaptive)
    try
    {
      AccuracyRun run{"adaptive",
                      std::make_unique<Simulation>(setup.grid, withMethod(setup.sim, setup.sim.adaptive_method),
                                                   StageFn{}, options.cache),
                      options.sample, true};
      if (setup.handle_scenario)
        run.driver = std::make_unique<HandleDriver>(*setup.handle_scenario, *run.sim);
      // `coarse` at its own step, as it runs alone.
      AdaptiveSettings settings = adaptiveSettings(setup.sim);
      if (settings.reduced == Method::Coarse)
        settings.reduced_step_span = coarseMultiple();
      const HandleDriver* driver = run.driver.get();
      run.adaptive = std::make_unique<AdaptiveStepper>(*run.sim, settings, [driver](Simulation& sim) {
        if (driver)
          driver->drive(sim);
      });
      runs.push_back(std::move(run));
    }
    catch (const std::bad_alloc&)
    {
      throw;
    }
    catch (const std::exception& e)
    {
      not_built.emplace_back("adaptive", e.what());
    }
  if (setup.handle_scenario)
  {
    for (AccuracyRun& run : runs)
      if (!run.driver)
        run.driver = std::make_unique<HandleDriver>(*setup.handle_scenario, *run.sim);
    if (check)
      check->driver = std::make_unique<HandleDriver>(*setup.handle_scenario, *check->sim);
  }
  return runs;
}

// One run at one step against the reference's points; no distances once either has diverged.
ErrorSample sample(const ExperimentSetup& setup, const Grid& grid, AccuracyRun& run, const std::string& method,
                   long step, const Eigen::Matrix3Xd& reference, bool reference_diverged)
{
  ErrorSample e;
  e.variant = setup.variant;
  e.method = method;
  e.step = step;
  e.time = step * setup.sim.time_step;
  e.diverged = run.diverged || reference_diverged;
  e.time_step = run.sim->params().time_step;
  e.step_seconds = run.timed && step > 0 ? run.step_seconds : 0.0;
  e.step_cpu_seconds = run.timed && step > 0 ? run.step_cpu_seconds : 0.0;
  if (e.diverged)
  {
    e.max_distance = e.rms_distance = e.max_displacement = e.energy = e.center_y = e.depth = e.surface_distance =
        std::numeric_limits<double>::quiet_NaN();
    return e;
  }
  const Eigen::Matrix3Xd points = run.sim->points();
  distances(grid, points, reference, e.max_distance, e.rms_distance);
  e.surface_distance = surfaceDistance(grid, points, reference);
  e.max_displacement = maxDisplacement(grid, points);
  e.energy = run.sim->totalEnergy();
  e.center_y = points.row(1).mean();
  const Contact* contact = run.sim->contact();
  e.depth = contact ? deepestInside(grid, points, *contact) : std::numeric_limits<double>::quiet_NaN();
  if (run.adaptive)
  {
    e.reduced_share = run.adaptive->reducedShare();
    e.switches = run.adaptive->switches();
  }
  if (run.sim->method() != Method::Full)
  {
    e.error_indicator = run.indicator_max(*run.sim, run.sim->errorIndicator());
    e.error_estimate = errorEstimate(*run.sim, e.error_indicator);
  }
  return e;
}

}  // namespace

AccuracyResult runAccuracy(const ExperimentSetup& setup, const AccuracyOptions& options, const ProgressFn& progress)
{
  if (options.steps < 1 || options.interval < 1 || options.sample < 1 || options.interval % options.sample != 0)
    throw std::invalid_argument("accuracy: steps, interval and sample must be >= 1 and sample must divide interval");
  if (options.coarse_step_multiple < 0 ||
      (options.coarse_step_multiple > 0 && options.sample % options.coarse_step_multiple != 0))
    throw std::invalid_argument("accuracy: coarse_step_multiple must be 0 (automatic) or divide sample");
  if (options.reference_time_step < 0.0)
    throw std::invalid_argument("accuracy: reference_time_step must be >= 0");
  const int divisor =
      options.reference_time_step > 0.0 ? referenceSubsteps(setup.sim.time_step, options.reference_time_step) : 0;
  std::unique_ptr<AccuracyRun> check;
  AccuracyResult result;
  std::vector<AccuracyRun> runs = accuracyRuns(setup, options, divisor, check, result.not_built);
  const Grid& grid = runs[0].sim->grid();

  // Every modal run of the setup has the same basis (`full` and `coarse` build none).
  auto last_modal = std::find_if(runs.rbegin(), runs.rend(), [](const AccuracyRun& run) { return isModal(run.sim->method()); });
  const Simulation& modal = last_modal != runs.rend() ? *last_modal->sim : *runs.back().sim;
  result.frequencies = modal.basis().frequencies;
  result.num_zero_modes = modal.basis().num_zero_modes;
  result.basis = setup.sim.basis;
  result.derivatives = modal.derivativeInfo();
  result.skinning = modal.skinningInfo();
  result.physical_frequencies = modal.physicalBasis().frequencies;
  for (const AccuracyRun& run : runs)
    if (const Cubature* c = run.sim->cubature())
      result.cubature = CubatureRow{setup.variant, static_cast<int>(c->springs.size()),
                                    static_cast<int>(grid.springs().size()), c->training_poses,
                                    setup.sim.cubature_tolerance, c->training_error, c->heldout_error,
                                    c->training_seconds, c->validation_error,
                                    run.sim->cacheReport().cubature_loaded};

  // Each run steps a block of samples alone, after the reference has stepped them (see
  // reference_block_bytes).
  const long samples = options.steps / options.sample;
  const long block = std::max<long>(
      1, static_cast<long>(options.reference_block_bytes / (sizeof(Eigen::Vector3d) * grid.numParticles())));
  std::vector<std::vector<ErrorSample>> errors(runs.size());
  std::vector<std::pair<size_t, Snapshot>> snapshots;  // with the run's index, for the order below
  auto record = [&](size_t k, long step, const Eigen::Matrix3Xd& reference, bool reference_diverged) {
    AccuracyRun& run = runs[k];
    errors[k].push_back(sample(setup, grid, run, run.name, step, reference, reference_diverged));
    const bool snapshot = options.snapshots && (step % options.interval == 0 || step == options.steps);
    if (snapshot && !errors[k].back().diverged)
      snapshots.push_back({k, {setup.variant, run.name, step, errors[k].back().time, run.sim->points()}});
  };
  auto recordCheck = [&](long step, const Eigen::Matrix3Xd& reference, bool reference_diverged) {
    const ErrorSample e = sample(setup, grid, *check, "reference_half_step", step, reference, reference_diverged);
    if (!e.diverged)
    {
      result.reference_check_max_rms = std::max(result.reference_check_max_rms, e.rms_distance);
      result.reference_check_max_distance = std::max(result.reference_check_max_distance, e.max_distance);
    }
    result.reference_check.push_back(e);
  };

  // The reference at samples base, base + 1, ...: its points, and whether it had diverged.
  struct ReferenceSample
  {
    Eigen::Matrix3Xd points;
    bool diverged = false;
  };
  std::vector<ReferenceSample> reference{{runs[0].sim->points(), false}};
  long base = 0;
  const double total = static_cast<double>(samples + 1) * (runs.size() + (check ? 1 : 0));
  double done = 0.0;
  auto advance = [&](AccuracyRun& run, long i) {
    if (i > 0)
      run.advance(setup.variant, result.messages);
    report(progress, "accuracy " + setup.variant, ++done / total);
  };
  for (long first = 0; first <= samples; first += block)
  {
    const long last = std::min(samples, first + block - 1);  // samples first..last, each i at step i * sample
    for (long i = first; i <= last; ++i)
    {
      advance(runs[0], i);
      if (i > 0)
        reference.push_back({runs[0].sim->points(), runs[0].diverged});
      record(0, i * options.sample, reference[i - base].points, reference[i - base].diverged);
    }
    for (size_t k = 1; k < runs.size(); ++k)
      for (long i = first; i <= last; ++i)
      {
        advance(runs[k], i);
        record(k, i * options.sample, reference[i - base].points, reference[i - base].diverged);
      }
    for (long i = first; check && i <= last; ++i)
    {
      advance(*check, i);
      recordCheck(i * options.sample, reference[i - base].points, reference[i - base].diverged);
    }
    reference.erase(reference.begin(), reference.end() - 1);
    base = last;
  }
  // Samples in the order of time, then of the runs.
  for (long i = 0; i <= samples; ++i)
    for (std::vector<ErrorSample>& run_errors : errors)
      result.errors.push_back(std::move(run_errors[i]));
  std::stable_sort(snapshots.begin(), snapshots.end(), [](const auto& a, const auto& b) {
    return std::tie(a.second.step, a.first) < std::tie(b.second.step, b.first);
  });
  for (auto& [k, snapshot] : snapshots)
    result.snapshots.push_back(std::move(snapshot));
  if (check && check->diverged)
    result.reference_check_max_rms = result.reference_check_max_distance = std::numeric_limits<double>::infinity();
  return result;
}

double rankCorrelation(const std::vector<double>& a, const std::vector<double>& b)
{
  const size_t n = a.size();
  if (n < 3 || b.size() != n)
    return std::numeric_limits<double>::quiet_NaN();
  auto ranks = [n](const std::vector<double>& v) {
    std::vector<size_t> order(n);
    for (size_t i = 0; i < n; ++i)
      order[i] = i;
    std::sort(order.begin(), order.end(), [&](size_t i, size_t j) { return v[i] < v[j]; });
    Eigen::VectorXd r(n);
    for (size_t i = 0; i < n;)
    {
      size_t j = i;
      while (j + 1 < n && v[order[j + 1]] == v[order[i]])
        ++j;
      for (size_t k = i; k <= j; ++k)
        r[order[k]] = 0.5 * static_cast<double>(i + j);
      i = j + 1;
    }
    return Eigen::VectorXd(r.array() - r.mean());
  };
  const Eigen::VectorXd ra = ranks(a), rb = ranks(b);
  const double norms = ra.norm() * rb.norm();
  return norms > 0.0 ? ra.dot(rb) / norms : std::numeric_limits<double>::quiet_NaN();
}

std::vector<AccuracySummary> summarizeAccuracy(const std::vector<ErrorSample>& rows)
{
  std::vector<AccuracySummary> out;
  std::vector<std::vector<double>> times, cpu_times, indicators, distances;
  std::vector<int> counts;
  std::vector<double> time_steps;  // of each summary's method
  for (const ErrorSample& e : rows)
  {
    auto it = std::find_if(out.begin(), out.end(), [&](const AccuracySummary& s) {
      return s.variant == e.variant && s.method == e.method;
    });
    if (it == out.end())
    {
      out.emplace_back();
      out.back().variant = e.variant;
      out.back().method = e.method;
      times.emplace_back();
      cpu_times.emplace_back();
      indicators.emplace_back();
      distances.emplace_back();
      counts.push_back(0);
      time_steps.push_back(0.0);
      it = out.end() - 1;
    }
    const size_t k = it - out.begin();
    AccuracySummary& s = *it;
    if (e.step == 0)
      continue;
    time_steps[k] = e.time_step;
    if (e.diverged)
    {
      s.diverged = true;
      continue;
    }
    s.mean_rms += e.rms_distance;
    s.mean_surface += e.surface_distance;
    s.mean_max += e.max_distance;
    s.max_rms = std::max(s.max_rms, e.rms_distance);
    s.final_rms = e.rms_distance;
    s.deepest = std::isnan(s.deepest) ? e.depth : std::max(s.deepest, e.depth);
    if (e.step_seconds > 0.0)
      times[k].push_back(e.step_seconds);
    if (e.step_cpu_seconds > 0.0)
      cpu_times[k].push_back(e.step_cpu_seconds);
    s.reduced_share = e.reduced_share;
    s.switches = e.switches;
    if (!std::isnan(e.error_estimate))
    {
      indicators[k].push_back(e.error_estimate);
      distances[k].push_back(e.rms_distance);
    }
    ++counts[k];
  }
  for (size_t k = 0; k < out.size(); ++k)
  {
    AccuracySummary& s = out[k];
    if (counts[k] > 0)
    {
      s.mean_rms /= counts[k];
      s.mean_surface /= counts[k];
      s.mean_max /= counts[k];
    }
    else
    {
      // Not one sample after step 0 (diverged before the first): no error to report, never 0.
      s.mean_rms = s.max_rms = s.mean_max = s.mean_surface = std::numeric_limits<double>::quiet_NaN();
    }
    if (s.diverged)
      s.final_rms = std::numeric_limits<double>::quiet_NaN();
    s.time_step = time_steps[k];
    s.step_seconds_median = median(times[k]);
    s.step_cpu_seconds_median = median(cpu_times[k]);
    s.indicator_rank_correlation = rankCorrelation(indicators[k], distances[k]);
    s.step_seconds_mean = mean(times[k]);
    s.step_cpu_seconds_mean = mean(cpu_times[k]);
    // `adaptive` takes steps of two costs, reduced and `full`: the median is one of them, the mean
    // what the run cost.
    const double cpu = std::isnan(s.reduced_share) ? s.step_cpu_seconds_median : s.step_cpu_seconds_mean;
    s.cpu_per_simulated_second = cpuPerSimulatedSecond(cpu, time_steps[k]);
    s.real_time_factor = realTimeFactor(cpu, time_steps[k]);
  }
  return out;
}

}  // namespace modal_mass_spring
