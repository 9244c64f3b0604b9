// modal_compare's experiments run over the setups: each writes its CSV files after every setup and
// prints its summary tables.
#include "compare_experiments.h"

#include "compare_setups.h"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iomanip>
#include <iostream>
#include <limits>
#include <new>
#include <set>
#include <sstream>
#include <stdexcept>

namespace modal_mass_spring::compare
{

Progress::Progress(bool enabled) : enabled_(enabled), tty_(isatty(fileno(stderr))) {}

void Progress::operator()(const std::string& label, double fraction)
{
  if (!enabled_)
    return;
  const auto now = std::chrono::steady_clock::now();
  const double since = std::chrono::duration<double>(now - last_).count();
  if (since < (tty_ ? 0.2 : 10.0) && fraction < 1.0)
    return;
  last_ = now;
  std::ostringstream line;
  line << "[" << std::fixed << std::setprecision(0) << std::setw(3) << 100.0 * fraction << "%] " << label;
  if (tty_)
    std::cerr << "\r" << std::left << std::setw(60) << line.str() << (fraction >= 1.0 ? "\n" : "") << std::flush;
  else
    std::cerr << line.str() << "\n";
}

namespace
{

// Said once per file, however often it is rewritten.
std::set<std::string> announced;

std::ofstream openCsv(const Options& o, const std::string& name)
{
  const std::filesystem::path path = std::filesystem::path(o.output) / name;
  std::ofstream out(path);
  if (!out)
    throw std::runtime_error("cannot write '" + path.string() + "'");
  if (announced.insert(path.string()).second)
    std::cout << "wrote " << path.string() << "\n";
  return out;
}

// Runs one experiment's setups in turn and writes its files after each, so that a failure (or a
// kill) late in a run never loses what finished before; a failure is named by experiment and setup.
void runEachSetup(const Options& o, const std::string& experiment, const std::vector<ExperimentSetup>& setups,
                  const std::function<void(const ExperimentSetup&)>& run, const std::function<void()>& write)
{
  for (size_t k = 0; k < setups.size(); ++k)
  {
    std::string failure;
    try
    {
      run(setups[k]);
    }
    catch (const std::bad_alloc&)
    {
      // The memory estimate (memory_limit_gb) passed, but the machine had less than that to give.
      failure = "out of memory (std::bad_alloc): the machine could not provide what this setup needs; use a smaller "
                "grid or fewer modes, or lower memory_limit_gb to what is free";
    }
    catch (const std::exception& e)
    {
      failure = e.what();
    }
    if (failure.empty())
    {
      write();
      continue;
    }
    const std::string where = experiment == "handles" ? "scenario '" + setups[k].variant + "'"
                                                      : "variant '" + setups[k].variant + "'";
    if (k > 0)
    {
      write();
      failure += "; the results of the " + std::to_string(k) + " " + experiment + " setup(s) finished before it are "
                 "written to '" + o.output + "'";
    }
    throw std::runtime_error(experiment + " experiment, " + where + ": " + failure);
  }
}

// Prints a table with columns padded to their widest cell.
// The reference against itself at half its step, as surfaces: the mean over the samples.
double referenceCheckSurface(const AccuracyResult& result)
{
  const std::vector<AccuracySummary> check = summarizeAccuracy(result.reference_check);
  return check.empty() ? std::numeric_limits<double>::quiet_NaN() : check.front().mean_surface;
}

void printTable(const std::string& title, const std::vector<std::vector<std::string>>& table)
{
  std::vector<size_t> width;
  for (const auto& row : table)
    for (size_t c = 0; c < row.size(); ++c)
    {
      width.resize(std::max(width.size(), row.size()), 0);
      width[c] = std::max(width[c], row[c].size());
    }
  std::cout << "\n" << title << "\n";
  for (size_t r = 0; r < table.size(); ++r)
  {
    std::cout << "|";
    for (size_t c = 0; c < table[r].size(); ++c)
      std::cout << " " << std::left << std::setw(static_cast<int>(width[c])) << table[r][c] << " |";
    std::cout << "\n";
    if (r == 0)
    {
      std::cout << "|";
      for (size_t w : width)
        std::cout << std::string(w + 2, '-') << "|";
      std::cout << "\n";
    }
  }
}

}  // namespace

void runCostExperiment(const Options& o, const std::vector<ExperimentSetup>& setups, Progress& progress)
{
  std::vector<CostRow> rows;
  runEachSetup(
      o, "cost", setups,
      [&](const ExperimentSetup& setup) {
        const auto part = runCost(setup, o.cost, std::ref(progress));
        rows.insert(rows.end(), part.begin(), part.end());
      },
      [&] {
        std::ofstream out = openCsv(o, "cost_" + o.tag + ".csv");
        writeCostCsv(out, rows);
      });
  std::vector<std::vector<std::string>> table{
      {"variant", "grid", "dim", "free dofs", "modes", "basis build ms", "method", "step us (median)",
       "CPU us (median)", "CPU s per simulated s", "real-time factor"}};
  for (const CostRow& r : rows)
    table.push_back({r.variant, std::to_string(r.rows) + "x" + std::to_string(r.cols), std::to_string(r.dimension),
                     std::to_string(r.free_dofs), std::to_string(r.num_modes), fmt(1e3 * r.build_seconds),
                     r.method,
                     fmt(1e6 * r.step_seconds) +
                         (r.diverged_step > 0 ? " (diverged at step " + std::to_string(r.diverged_step) + ")" : ""),
                     fmt(1e6 * r.step_cpu_seconds), fmt(r.cpu_per_simulated_second), fmt(r.real_time_factor)});
  printTable("cost (" + o.tag + "): median of " + std::to_string(o.cost.repeats) +
                 " timed runs; wall and this thread's CPU time per step, the CPU time per simulated second and "
                 "the real-time factor it allows (time_step / CPU per step)",
             table);
  for (const CostRow& r : rows)
    if (r.method == "adaptive")
      std::cout << "adaptive (" << r.variant << ", " << r.rows << "x" << r.cols << "): " << fmt(100.0 * r.reduced_share)
                << "% of its steps reduced, " << r.switches << " switches (the last timed run)\n";
}

namespace
{

// The basis and, with a converged reference, how well it agrees with itself at half its step.
void printAccuracyHeader(const Options& o, const ExperimentSetup& setup, const AccuracyResult& result)
{
  std::ostringstream freq;
  for (int k = 0; k < result.frequencies.size(); ++k)
    freq << (k ? " " : "") << fmt(result.frequencies[k]);
  std::cout << "basis (" << setup.variant << "): " << result.frequencies.size() << " modes, "
            << result.num_zero_modes << " zero, omega [rad/s] = " << freq.str() << "\n";
  if (result.basis == BasisKind::ModalDerivatives && result.physical_frequencies.size() > 0)
  {
    const DerivativeBasisInfo& d = result.derivatives;
    std::cout << "physical basis (" << setup.variant << "): modal_derivatives, " << d.linear_modes
              << " linear modes kept, " << d.derivative_directions << " derivative directions added (from "
              << d.derivatives_computed << " derivatives) in " << fmt(1e3 * d.seconds) << " ms, omega up to "
              << fmt(result.physical_frequencies.maxCoeff()) << " rad/s; singular values relative to the largest: "
              << "smallest kept " << fmt(d.smallest_kept_singular_value) << ", largest dropped "
              << fmt(d.largest_dropped_singular_value) << "\n";
  }
  if (result.basis == BasisKind::Skinning && result.physical_frequencies.size() > 0)
    std::cout << "physical basis (" << setup.variant << "): " << describeSkinning(result.skinning)
              << ", omega up to " << fmt(result.physical_frequencies.maxCoeff()) << " rad/s\n";
  if (o.accuracy.reference_time_step > 0.0)
    std::cout << "reference (" << setup.variant << "): full, explicit, dt = " << fmt(o.accuracy.reference_time_step)
              << " s; against dt / 2: largest RMS distance " << fmt(result.reference_check_max_rms)
              << " m, largest particle distance " << fmt(result.reference_check_max_distance)
              << " m, mean surface distance " << fmt(referenceCheckSurface(result)) << " m\n";
}

// For method "adaptive": its share of reduced steps and its switches, one line per variant.
void printAdaptive(const std::vector<AccuracySummary>& summaries)
{
  for (const AccuracySummary& s : summaries)
    if (s.method == "adaptive" && s.not_built.empty())
      std::cout << "adaptive (" << s.variant << "): " << fmt(100.0 * s.reduced_share) << "% of its steps reduced, "
                << s.switches << " switches\n";
}

void printAccuracySummary(const Options& o, const std::string& reference, const std::vector<ErrorSample>& errors)
{
  std::vector<std::vector<std::string>> summary{{"variant", "method", "mean RMS m", "largest RMS m", "mean largest m",
                                                 "RMS at the end m", "step us (median)", "step us (mean)",
                                                 "CPU us (median)", "CPU s per simulated s", "real-time factor",
                                                 "time step s", "deepest m", "mean surface distance m"}};
  for (const AccuracySummary& s : summarizeAccuracy(errors))
    if (s.method != reference && s.method != "reference_half_step")
      summary.push_back({s.variant, s.method, fmt(s.mean_rms), fmt(s.max_rms), fmt(s.mean_max),
                         s.diverged ? "diverged" : fmt(s.final_rms), fmt(1e6 * s.step_seconds_median),
                         fmt(1e6 * s.step_seconds_mean), fmt(1e6 * s.step_cpu_seconds_median),
                         fmt(s.cpu_per_simulated_second), fmt(s.real_time_factor), fmt(s.time_step),
                         fmt(s.deepest), fmt(s.mean_surface)});
  printTable("accuracy (" + o.tag + "): over every sample after step 0, against " + reference +
                 "; wall and this thread's CPU time per step while running, the CPU time per simulated second "
                 "and the real-time factor it allows (time_step / CPU per step); each method's time step; how "
                 "deep its deepest free particle went inside a collider over the samples; the distance as surfaces "
                 "(each free particle to the other's triangles and back)",
             summary);
  printAdaptive(summarizeAccuracy(errors));
}

}  // namespace

void runAccuracyExperiment(const Options& o, const std::vector<ExperimentSetup>& setups, Progress& progress)
{
  const std::string reference = o.accuracy.reference_time_step > 0.0 ? "reference" : "full";
  std::vector<ErrorSample> errors;
  std::vector<Snapshot> snapshots;
  std::vector<std::string> messages;
  std::vector<CubatureRow> cubatures;
  std::vector<std::vector<std::string>> table{
      {"variant", "method", "step", "time s", "max distance m", "RMS distance m", "max displacement m"}};
  auto write = [&] {
    std::ofstream out = openCsv(o, "accuracy_" + o.tag + "_error.csv");
    writeErrorCsv(out, errors);
    if (!cubatures.empty())
    {
      std::ofstream cubature_out = openCsv(o, "accuracy_" + o.tag + "_cubature.csv");
      writeCubatureCsv(cubature_out, cubatures);
    }
    if (o.accuracy.snapshots)
    {
      std::ofstream snap = openCsv(o, "accuracy_" + o.tag + "_snapshots.csv");
      writeSnapshotCsv(snap, Grid(setups.front().grid), snapshots);
    }
  };
  auto run = [&](const ExperimentSetup& setup) {
    const AccuracyResult result = runAccuracy(setup, o.accuracy, std::ref(progress));
    errors.insert(errors.end(), result.errors.begin(), result.errors.end());
    errors.insert(errors.end(), result.reference_check.begin(), result.reference_check.end());
    snapshots.insert(snapshots.end(), result.snapshots.begin(), result.snapshots.end());
    messages.insert(messages.end(), result.messages.begin(), result.messages.end());
    for (const auto& [method, reason] : result.not_built)
      messages.push_back(setup.variant + ": " + method + " did not build: " + reason);
    printAccuracyHeader(o, setup, result);
    if (result.cubature)
    {
      const CubatureRow& c = *result.cubature;
      cubatures.push_back(c);
      std::cout << "cubature (" << setup.variant << "): " << c.springs << " of " << c.grid_springs
                << " springs, training error " << fmt(100.0 * c.training_error) << "% on " << c.training_poses
                << " poses (cubature_tolerance " << fmt(100.0 * c.tolerance) << "%), held-out "
                << fmt(100.0 * c.heldout_error) << "%, trained in " << fmt(c.training_seconds) << " s"
                << (c.loaded ? " (loaded from the cache)" : "");
      // The training stops at its caps too: say so rather than let the figures pass for the tolerance.
      if (std::max(c.training_error, c.validation_error) > c.tolerance)
        std::cout << "; above cubature_tolerance (validation " << fmt(100.0 * c.validation_error)
                  << "%): the training stopped at its caps (cubature_max_springs, cubature_max_training_poses) or "
                     "found no spring that helps";
      std::cout << "\n";
    }
    for (const ErrorSample& e : result.errors)
    {
      if (e.step % o.accuracy.interval != 0 && e.step != o.accuracy.steps)
        continue;
      if (e.method == reference)
        std::cout << reference << " (" << setup.variant << ") at step " << e.step << ": max displacement "
                  << fmt(e.max_displacement) << " m\n";
      else
        table.push_back({e.variant, e.method, std::to_string(e.step), fmt(e.time), fmt(e.max_distance),
                         fmt(e.rms_distance), fmt(e.max_displacement)});
    }
  };
  runEachSetup(o, "accuracy", setups, run, write);
  printTable("accuracy (" + o.tag + "): distance to " + reference + " every " + std::to_string(o.accuracy.interval) +
                 " steps",
             table);
  printAccuracySummary(o, reference, errors);
  for (const std::string& m : messages)
    std::cout << "note: " << m << "\n";
}

namespace
{

// Each implicit method at check_factor times the largest stable step of the same method in the
// setup's explicit twin (same settings, integrator explicit); one line per check.
std::vector<std::string> checkImplicitAtFactor(const Options& o, const std::vector<ExperimentSetup>& setups,
                                               std::vector<std::vector<StabilityRow>>& rows)
{
  std::vector<std::string> checks;
  for (size_t s = 0; s < setups.size(); ++s)
  {
    const ExperimentSetup* twin = explicitTwin(setups[s], setups);
    if (setups[s].sim.integrator != IntegratorKind::Implicit || !twin)
      continue;
    const std::vector<StabilityRow>& explicit_rows = rows[twin - setups.data()];
    for (StabilityRow& row : rows[s])
    {
      const auto explicit_row = std::find_if(explicit_rows.begin(), explicit_rows.end(),
                                             [&](const StabilityRow& r) { return r.method == row.method; });
      if (explicit_row == explicit_rows.end() || !(explicit_row->stable_dt > 0.0))
        continue;
      row.check_dt = o.check_factor * explicit_row->stable_dt;
      const bool adaptive = row.method == "adaptive";
      row.check_stable = checkStableAt(setups[s], adaptive ? setups[s].sim.adaptive_method : parseMethod(row.method),
                                       row.check_dt, o.stability.steps, adaptive);
      checks.push_back(row.variant + ", " + row.method + " at " + fmt(o.check_factor) + " x the explicit " +
                       row.method + "'s largest stable step (" + fmt(1e3 * row.check_dt, 4) + " ms, " +
                       twin->variant + "): " + (row.check_stable ? "stable" : "DIVERGED") + " over " +
                       std::to_string(o.stability.steps) + " steps");
    }
  }
  return checks;
}

std::string windowsText(const std::vector<StableWindow>& windows)
{
  std::string text;
  for (const StableWindow& w : windows)
    text += (text.empty() ? "" : ", ") + (w.from == w.to ? fmt(w.from, 4) : fmt(w.from, 4) + "-" + fmt(w.to, 4));
  return text.empty() ? "none" : text;
}

}  // namespace

void runHandlesExperiment(const Options& o, const std::vector<ExperimentSetup>& setups, Progress& progress)
{
  const std::string reference = o.accuracy.reference_time_step > 0.0 ? "reference" : "full";
  std::vector<ErrorSample> errors;
  std::vector<Snapshot> snapshots;
  std::vector<std::string> messages;
  std::vector<AccuracySummary> not_built;  // methods that could not be built on a scenario
  auto summaries_of = [&] {
    std::vector<AccuracySummary> summaries = summarizeAccuracy(errors);
    summaries.insert(summaries.end(), not_built.begin(), not_built.end());
    return summaries;
  };
  auto write = [&] {
    std::ofstream out = openCsv(o, "handles_" + o.tag + "_error.csv");
    writeErrorCsv(out, errors);
    std::ofstream summary_out = openCsv(o, "handles_" + o.tag + "_summary.csv");
    writeAccuracySummaryCsv(summary_out, summaries_of());
    if (o.accuracy.snapshots)
    {
      std::ofstream snap = openCsv(o, "handles_" + o.tag + "_snapshots.csv");
      writeSnapshotCsv(snap, Grid(setups.front().grid), snapshots);
    }
  };
  auto run = [&](const ExperimentSetup& setup) {
    AccuracyOptions options = o.accuracy;
    options.steps = handleSteps(o, setup);
    options.interval = handleSteps(o, setup, true);
    const AccuracyResult result = runAccuracy(setup, options, std::ref(progress));
    // The shapes where the move ends, where the methods differ most, and at the end of the hold, where
    // the cloth has settled (a fold lies on itself); of the first --vary combination only, to keep the
    // file small.
    for (const Snapshot& snapshot : result.snapshots)
      if ((snapshot.step == options.interval || snapshot.step == options.steps) &&
          setup.settings == setups.front().settings)
        snapshots.push_back(snapshot);
    errors.insert(errors.end(), result.errors.begin(), result.errors.end());
    errors.insert(errors.end(), result.reference_check.begin(), result.reference_check.end());
    messages.insert(messages.end(), result.messages.begin(), result.messages.end());
    const std::vector<AccuracySummary> failed = notBuiltSummaries(setup.variant, result);
    not_built.insert(not_built.end(), failed.begin(), failed.end());
    const HandleScenario& scenario = *setup.handle_scenario;
    std::cout << "handle scenario " << setup.variant << ": " << scenario.handles.size() << " handle(s), "
              << setup.grid.rows << "x" << setup.grid.cols << " grid, moved over " << fmt(scenario.move_time)
              << " s, held " << fmt(scenario.hold_time) << " s, " << options.steps << " steps of "
              << fmt(setup.sim.time_step) << " s";
    if (o.accuracy.reference_time_step > 0.0)
      std::cout << "; reference full, explicit, dt = " << fmt(o.accuracy.reference_time_step)
                << " s, against dt / 2: largest RMS distance " << fmt(result.reference_check_max_rms)
                << " m, mean surface distance " << fmt(referenceCheckSurface(result)) << " m";
    std::cout << "\n";
  };
  runEachSetup(o, "handles", setups, run, write);
  const std::vector<AccuracySummary> summaries = summaries_of();
  std::vector<std::vector<std::string>> table{
      {"scenario", "method", "mean RMS m", "largest RMS m", "RMS at the end m", "step us (median)", "CPU us (median)",
       "CPU s per simulated s", "real-time factor", "indicator rank corr.", "time step s", "deepest m",
       "mean surface distance m"}};
  for (const AccuracySummary& s : summaries)
    if (!s.not_built.empty())
      table.push_back({s.variant, s.method, "did not build: " + s.not_built, "", "", "", "", "", "", "", "", "", ""});
    else if (s.method != "reference_half_step" && (s.method != reference || s.step_seconds_median > 0.0))
      // The reference's own row when it is timed (`full` at the methods' step): the step times to compare.
      table.push_back({s.variant, s.method, s.method == reference ? "(reference)" : fmt(s.mean_rms),
                       s.method == reference ? "" : fmt(s.max_rms),
                       s.method == reference ? "" : s.diverged ? "diverged" : fmt(s.final_rms),
                       fmt(1e6 * s.step_seconds_median), fmt(1e6 * s.step_cpu_seconds_median),
                       fmt(s.cpu_per_simulated_second), fmt(s.real_time_factor),
                       fmt(s.indicator_rank_correlation), fmt(s.time_step), fmt(s.deepest),
                       s.method == reference ? "" : fmt(s.mean_surface)});
  printTable("handles (" + o.tag + "): distance of the free particles to " + reference +
                 " over every sample after step 0; wall and this thread's CPU time per step while running, the "
                 "CPU time per simulated second and the real-time factor it allows (time_step / CPU per step); "
                 "the rank correlation of the method's error estimate with that distance; each method's time "
                 "step; how deep its deepest free particle went inside a collider over the samples; the distance as "
                 "surfaces (each free particle to the other's triangles and back)",
             table);
  printAdaptive(summaries);
  for (const std::string& m : messages)
    std::cout << "note: " << m << "\n";
}

void runStabilityExperiment(const Options& o, const std::vector<ExperimentSetup>& setups, Progress& progress)
{
  std::vector<std::vector<StabilityRow>> per_setup;
  std::vector<StabilityRow> rows;
  auto write = [&] {
    rows.clear();
    for (const auto& part : per_setup)
      rows.insert(rows.end(), part.begin(), part.end());
    std::ofstream out = openCsv(o, "stability_" + o.tag + ".csv");
    writeStabilityCsv(out, rows);
  };
  runEachSetup(
      o, "stability", setups,
      [&](const ExperimentSetup& setup) { per_setup.push_back(runStability(setup, o.stability, std::ref(progress))); },
      write);
  const std::vector<std::string> checks =
      o.check_factor > 0.0 ? checkImplicitAtFactor(o, setups, per_setup) : std::vector<std::string>{};
  if (!checks.empty())
    write();
  std::vector<std::vector<std::string>> table{{"variant", "method", "largest stable dt s", "diverges at s", "trials",
                                               "2/omega (highest mode)", "2/omega (K(x0), all dofs)",
                                               "stable windows above s"}};
  // No divergence found, or no bound (every mode a zero mode): said in words, never inf.
  auto finiteOr = [](double value, const std::string& otherwise) {
    return std::isfinite(value) ? fmt(value, 6) : otherwise;
  };
  const std::string unbounded = "none up to " + fmt(o.stability.max_time_step);
  for (const StabilityRow& r : rows)
    table.push_back({r.variant, r.method, fmt(r.stable_dt, 6), finiteOr(r.unstable_dt, unbounded),
                     std::to_string(r.trials), finiteOr(r.modal_bound, "none (all zero modes)"),
                     finiteOr(r.full_bound, "-"), windowsText(r.windows)});
  std::ostringstream title;
  title << "stability (" << o.tag << "): " << o.stability.steps << " steps without divergence; every step tried "
        << "below the largest stable one was stable (scan ratio " << o.stability.scan_ratio
        << ", bisection to a relative " << fmt(o.stability.tolerance) << "); windows up to "
        << fmt(o.stability.window_factor) << " x the boundary";
  printTable(title.str(), table);
  for (const std::string& c : checks)
    std::cout << "check: " << c << "\n";
}

}  // namespace modal_mass_spring::compare
