// Runs the experiments on Simulation objects and writes their CSV files.
#include "experiments.h"

#include "modal_mass_spring/spring_forces.h"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <memory>
#include <stdexcept>

namespace modal_mass_spring
{
namespace
{

using Clock = std::chrono::steady_clock;

double seconds(Clock::time_point start)
{
  return std::chrono::duration<double>(Clock::now() - start).count();
}

double median(std::vector<double> values)
{
  if (values.empty())
    return std::numeric_limits<double>::quiet_NaN();
  std::sort(values.begin(), values.end());
  const size_t n = values.size();
  return n % 2 ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
}

void report(const ProgressFn& progress, const std::string& label, double fraction)
{
  if (progress)
    progress(label, fraction);
}

SimulationParams withMethod(SimulationParams params, Method method)
{
  params.method = method;
  return params;
}

// Per-particle distances between two sets of points, over the free particles.
void distances(const Grid& grid, const Eigen::Matrix3Xd& a, const Eigen::Matrix3Xd& b, double& max, double& rms)
{
  max = 0.0;
  double sum2 = 0.0;
  int count = 0;
  for (int p = 0; p < grid.numParticles(); ++p)
  {
    if (grid.isFixed(p))
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

// ---------------------------------------------------------------- cost

std::vector<CostRow> runCost(const ExperimentSetup& setup, const CostOptions& options, const ProgressFn& progress)
{
  std::vector<CostRow> rows;
  const double total = static_cast<double>(options.sizes.size());
  for (size_t s = 0; s < options.sizes.size(); ++s)
  {
    const int size = options.sizes[s];
    GridParams grid = setup.grid;
    grid.rows = grid.cols = size;
    grid.fixed.clear();  // a fixed list names particles of the configured size only: use the top row
    const std::string label = "cost " + std::to_string(size) + "x" + std::to_string(size);
    report(progress, label, s / total);

    std::vector<double> builds;
    std::unique_ptr<Simulation> sim;
    for (int b = 0; b < std::max(1, options.build_repeats); ++b)
    {
      sim = std::make_unique<Simulation>(grid, setup.sim);
      builds.push_back(sim->basis().build_seconds);
    }
    const double build_seconds = median(builds);

    for (size_t m = 0; m < options.methods.size(); ++m)
    {
      const Method method = options.methods[m];
      sim->setMethod(method);
      sim->reset();
      // Calibrate the steps per timed run so that one run is long enough for the clock.
      int calibration = 10;
      double elapsed = 0.0;
      while (true)
      {
        sim->reset();
        const auto start = Clock::now();
        sim->step(calibration);
        elapsed = seconds(start);
        if (elapsed > 0.2 * options.min_repeat_seconds || calibration >= 1000000)
          break;
        calibration *= 4;
      }
      const int steps = std::max(
          10, static_cast<int>(std::min(1e7, calibration * options.min_repeat_seconds / std::max(elapsed, 1e-9))));

      CostRow row;
      row.variant = setup.variant;
      row.method = toString(method);
      row.dimension = grid.dimension;
      row.rows = row.cols = size;
      row.particles = sim->grid().numParticles();
      row.free_dofs = sim->grid().numFreeDofs();
      row.springs = static_cast<int>(sim->grid().springs().size());
      row.num_modes = setup.sim.num_modes;
      row.build_seconds = build_seconds;
      row.repeats = options.repeats;
      row.steps_per_repeat = steps;
      std::vector<double> per_step;
      for (int r = 0; r < options.repeats; ++r)
      {
        sim->reset();
        // A method may diverge (the linear one drifts without bound along zero modes): start over and
        // go on, so every timed run has the same number of steps.
        const auto start = Clock::now();
        for (int taken = 0; taken < steps;)
        {
          const StepResult result = sim->step(steps - taken);
          taken += std::max(1, result.steps_taken);  // a first step that diverges still counts
          if (result.diverged)
          {
            row.diverged = true;
            sim->reset();
          }
        }
        per_step.push_back(seconds(start) / steps);
        report(progress, label + " " + row.method,
               (s + (m + (r + 1.0) / options.repeats) / options.methods.size()) / total);
      }
      row.step_seconds = median(per_step);
      row.step_seconds_min = *std::min_element(per_step.begin(), per_step.end());
      rows.push_back(row);
    }
  }
  report(progress, "cost", 1.0);
  return rows;
}

// ---------------------------------------------------------------- accuracy

int referenceSubsteps(double time_step, double reference_time_step)
{
  const double ratio = time_step / reference_time_step;
  const double whole = std::round(ratio);
  if (!(reference_time_step > 0.0) || whole < 1.0 || std::abs(ratio - whole) > 1e-6 * ratio)
    throw std::invalid_argument("reference time step " + std::to_string(reference_time_step) +
                                " s must divide time_step " + std::to_string(time_step) + " s a whole number of times");
  return static_cast<int>(whole);
}

AccuracyResult runAccuracy(const ExperimentSetup& setup, const AccuracyOptions& options, const ProgressFn& progress)
{
  if (options.steps < 1 || options.interval < 1 || options.sample < 1 || options.interval % options.sample != 0)
    throw std::invalid_argument("accuracy: steps, interval and sample must be >= 1 and sample must divide interval");
  if (options.reference_time_step < 0.0)
    throw std::invalid_argument("accuracy: reference_time_step must be >= 0");
  const int divisor =
      options.reference_time_step > 0.0 ? referenceSubsteps(setup.sim.time_step, options.reference_time_step) : 0;

  // runs[0] is the reference every other run is measured against.
  struct Run
  {
    std::string name;
    std::unique_ptr<Simulation> sim;
    int steps_per_sample = 0;
    bool timed = false;
    bool diverged = false;
    double step_seconds = 0.0;
  };
  std::vector<Run> runs;
  auto referenceParams = [&](int divide) {
    SimulationParams p = withMethod(setup.sim, Method::Full);
    p.integrator = IntegratorKind::Explicit;
    p.linearization = Linearization::Rest;
    p.time_step = setup.sim.time_step / divide;
    return p;
  };
  if (divisor == 0)
    runs.push_back({"full", std::make_unique<Simulation>(setup.grid, withMethod(setup.sim, Method::Full)),
                    options.sample, true});
  else
    runs.push_back({"reference", std::make_unique<Simulation>(setup.grid, referenceParams(divisor)),
                    options.sample * divisor, false});
  std::vector<Method> compared;
  for (Method m : options.methods)
    if ((divisor > 0 || m != Method::Full) && std::find(compared.begin(), compared.end(), m) == compared.end())
      compared.push_back(m);
  for (Method m : compared)
    runs.push_back({toString(m), std::make_unique<Simulation>(setup.grid, withMethod(setup.sim, m)), options.sample,
                    true});
  std::unique_ptr<Simulation> check;  // the reference at half its step
  bool check_diverged = false;
  if (divisor > 0)
    check = std::make_unique<Simulation>(setup.grid, referenceParams(2 * divisor));
  const Grid& grid = runs[0].sim->grid();

  AccuracyResult result;
  const Simulation& modal = *runs.back().sim;  // every run of the setup has the same basis
  result.frequencies = modal.basis().frequencies;
  result.num_zero_modes = modal.basis().num_zero_modes;

  auto record = [&](long step) {
    const Eigen::Matrix3Xd reference = runs[0].sim->points();
    const bool snapshot = options.snapshots && (step % options.interval == 0 || step == options.steps);
    for (const Run& run : runs)
    {
      ErrorSample e;
      e.variant = setup.variant;
      e.method = run.name;
      e.step = step;
      e.time = step * setup.sim.time_step;
      e.diverged = run.diverged || runs[0].diverged;
      e.step_seconds = run.timed && step > 0 ? run.step_seconds : 0.0;
      if (e.diverged)
      {
        e.max_distance = e.rms_distance = e.max_displacement = e.energy = std::numeric_limits<double>::quiet_NaN();
      }
      else
      {
        const Eigen::Matrix3Xd points = run.sim->points();
        distances(grid, points, reference, e.max_distance, e.rms_distance);
        e.max_displacement = maxDisplacement(grid, points);
        e.energy = run.sim->totalEnergy();
        if (snapshot)
          result.snapshots.push_back({setup.variant, e.method, step, e.time, points});
      }
      result.errors.push_back(e);
    }
    if (check)
    {
      ErrorSample e;
      e.variant = setup.variant;
      e.method = "reference_half_step";
      e.step = step;
      e.time = step * setup.sim.time_step;
      e.diverged = check_diverged || runs[0].diverged;
      if (e.diverged)
        e.max_distance = e.rms_distance = e.max_displacement = e.energy = std::numeric_limits<double>::quiet_NaN();
      else
      {
        const Eigen::Matrix3Xd points = check->points();
        distances(grid, points, reference, e.max_distance, e.rms_distance);
        e.max_displacement = maxDisplacement(grid, points);
        e.energy = check->totalEnergy();
        result.reference_check_max_rms = std::max(result.reference_check_max_rms, e.rms_distance);
        result.reference_check_max_distance = std::max(result.reference_check_max_distance, e.max_distance);
      }
      result.reference_check.push_back(e);
    }
  };

  record(0);
  for (long step = options.sample; step <= options.steps; step += options.sample)
  {
    for (Run& run : runs)
    {
      if (run.diverged)
        continue;
      const auto start = Clock::now();
      const StepResult r = run.sim->step(run.steps_per_sample);
      run.step_seconds = seconds(start) / run.steps_per_sample;
      if (r.diverged)
      {
        run.diverged = true;
        result.messages.push_back(setup.variant + ": " + run.name + ": " + r.message);
      }
    }
    if (check && !check_diverged)
    {
      const StepResult r = check->step(2 * options.sample * divisor);
      if (r.diverged)
      {
        check_diverged = true;
        result.messages.push_back(setup.variant + ": reference at half its step: " + r.message);
      }
    }
    record(step);
    report(progress, "accuracy " + setup.variant, static_cast<double>(step) / options.steps);
  }
  if (check && check_diverged)
    result.reference_check_max_rms = result.reference_check_max_distance = std::numeric_limits<double>::infinity();
  return result;
}

std::vector<AccuracySummary> summarizeAccuracy(const std::vector<ErrorSample>& rows)
{
  std::vector<AccuracySummary> out;
  std::vector<std::vector<double>> times;
  std::vector<int> counts;
  for (const ErrorSample& e : rows)
  {
    auto it = std::find_if(out.begin(), out.end(), [&](const AccuracySummary& s) {
      return s.variant == e.variant && s.method == e.method;
    });
    if (it == out.end())
    {
      out.push_back({e.variant, e.method});
      times.emplace_back();
      counts.push_back(0);
      it = out.end() - 1;
    }
    const size_t k = it - out.begin();
    AccuracySummary& s = *it;
    if (e.step == 0)
      continue;
    if (e.diverged)
    {
      s.diverged = true;
      continue;
    }
    s.mean_rms += e.rms_distance;
    s.mean_max += e.max_distance;
    s.max_rms = std::max(s.max_rms, e.rms_distance);
    s.final_rms = e.rms_distance;
    if (e.step_seconds > 0.0)
      times[k].push_back(e.step_seconds);
    ++counts[k];
  }
  for (size_t k = 0; k < out.size(); ++k)
  {
    AccuracySummary& s = out[k];
    if (counts[k] > 0)
    {
      s.mean_rms /= counts[k];
      s.mean_max /= counts[k];
    }
    if (s.diverged)
      s.final_rms = std::numeric_limits<double>::quiet_NaN();
    s.step_seconds_median = median(times[k]);
    double sum = 0.0;
    for (double t : times[k])
      sum += t;
    s.step_seconds_mean = times[k].empty() ? std::numeric_limits<double>::quiet_NaN() : sum / times[k].size();
  }
  return out;
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

bool checkStableAt(const ExperimentSetup& setup, Method method, double dt, int steps)
{
  SimulationParams params = withMethod(setup.sim, method);
  params.time_step = dt;
  Simulation sim(setup.grid, params);
  return !sim.step(steps).diverged;
}

std::vector<StabilityRow> runStability(const ExperimentSetup& setup, const StabilityOptions& options, const ProgressFn& progress)
{
  if (options.steps < 1 || !(options.tolerance > 0.0) || !(options.min_time_step > 0.0) ||
      !(options.max_time_step > options.min_time_step))
    throw std::invalid_argument("stability: steps >= 1, tolerance > 0 and 0 < min_time_step < max_time_step");

  std::vector<StabilityRow> rows;
  for (size_t m = 0; m < options.methods.size(); ++m)
  {
    const Method method = options.methods[m];
    Simulation sim(setup.grid, withMethod(setup.sim, method));
    StabilityRow row;
    row.variant = setup.variant;
    row.method = toString(method);
    row.steps = options.steps;
    row.tolerance = options.tolerance;
    row.modal_bound = 2.0 / sim.basis().frequencies.maxCoeff();
    row.full_bound = 2.0 / highestFrequencyAtRest(sim.grid());
    const std::string label = "stability " + row.method;

    auto stable = [&](double dt) {
      sim.setTimeStep(dt);
      sim.reset();
      ++row.trials;
      return !sim.step(options.steps).diverged;
    };

    // Bracket the boundary from the configured step by doubling or halving, then bisect.
    double lo = setup.sim.time_step, hi = lo;
    if (stable(lo))
    {
      hi = 2.0 * lo;
      while (hi <= options.max_time_step && stable(hi))
      {
        lo = hi;
        hi *= 2.0;
      }
      if (hi > options.max_time_step)
        hi = std::numeric_limits<double>::infinity();
    }
    else
    {
      lo = 0.5 * hi;
      while (lo >= options.min_time_step && !stable(lo))
      {
        hi = lo;
        lo *= 0.5;
      }
      if (lo < options.min_time_step)
        lo = 0.0;
    }
    report(progress, label, (m + 0.2) / options.methods.size());
    if (lo > 0.0 && std::isfinite(hi))
    {
      const double width0 = std::log((hi - lo) / (options.tolerance * lo));
      while (hi - lo > options.tolerance * lo)
      {
        const double mid = 0.5 * (lo + hi);
        (stable(mid) ? lo : hi) = mid;
        const double done = 1.0 - std::log(std::max(1.0, (hi - lo) / (options.tolerance * lo))) / width0;
        report(progress, label, (m + 0.2 + 0.7 * done) / options.methods.size());
      }
      for (double fraction : {0.25, 0.5, 0.75})
        row.below_stable = stable(fraction * lo) && row.below_stable;
    }
    row.stable_dt = lo;
    row.unstable_dt = hi;
    rows.push_back(row);
    report(progress, label, (m + 1.0) / options.methods.size());
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

void writeCostCsv(std::ostream& out, const std::vector<CostRow>& rows)
{
  precise(out) << "variant,method,dimension,rows,cols,particles,free_dofs,springs,num_modes,"
                  "build_seconds,step_seconds,step_seconds_min,repeats,steps_per_repeat,diverged\n";
  for (const CostRow& r : rows)
    out << r.variant << ',' << r.method << ',' << r.dimension << ',' << r.rows << ',' << r.cols << ','
        << r.particles << ',' << r.free_dofs << ',' << r.springs << ',' << r.num_modes << ','
        << r.build_seconds << ',' << r.step_seconds << ',' << r.step_seconds_min << ',' << r.repeats << ','
        << r.steps_per_repeat << ',' << (r.diverged ? 1 : 0) << '\n';
}

void writeErrorCsv(std::ostream& out, const std::vector<ErrorSample>& rows)
{
  precise(out) << "variant,method,step,time,max_distance,rms_distance,max_displacement,energy,diverged,step_seconds\n";
  for (const ErrorSample& e : rows)
    out << e.variant << ',' << e.method << ',' << e.step << ',' << e.time << ',' << e.max_distance << ','
        << e.rms_distance << ',' << e.max_displacement << ',' << e.energy << ',' << (e.diverged ? 1 : 0) << ','
        << e.step_seconds << '\n';
}

void writeSnapshotCsv(std::ostream& out, const Grid& grid, const std::vector<Snapshot>& snapshots)
{
  precise(out) << "variant,method,step,time,particle,row,col,fixed,x,y,z\n";
  const int cols = grid.params().cols;
  for (const Snapshot& s : snapshots)
    for (int p = 0; p < grid.numParticles(); ++p)
      out << s.variant << ',' << s.method << ',' << s.step << ',' << s.time << ',' << p << ',' << p / cols << ','
          << p % cols << ',' << (grid.isFixed(p) ? 1 : 0) << ',' << s.points(0, p) << ',' << s.points(1, p) << ','
          << s.points(2, p) << '\n';
}

void writeStabilityCsv(std::ostream& out, const std::vector<StabilityRow>& rows)
{
  precise(out) << "variant,method,stable_dt,unstable_dt,trials,steps,tolerance,modal_bound,full_bound,below_stable,"
                  "check_dt,check_stable\n";
  for (const StabilityRow& r : rows)
    out << r.variant << ',' << r.method << ',' << r.stable_dt << ',' << r.unstable_dt << ',' << r.trials << ','
        << r.steps << ',' << r.tolerance << ',' << r.modal_bound << ',' << r.full_bound << ','
        << (r.below_stable ? 1 : 0) << ',' << r.check_dt << ',' << (r.check_dt > 0.0 ? (r.check_stable ? 1 : 0) : -1)
        << '\n';
}

}  // namespace modal_mass_spring
