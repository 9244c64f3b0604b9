// modal_compare: runs the paper's experiments on a YAML config and writes CSV files and a summary.
#include "experiments.h"
#include "yaml_parameter_source.h"

#include "modal_mass_spring/parameters.h"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <map>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

using namespace modal_mass_spring;
namespace fs = std::filesystem;

namespace
{

const char* const kUsage = R"(usage: modal_compare --config FILE [options]

Runs the paper's experiments on the grid of a YAML config (the node's parameter names) and writes
CSV files to the output folder plus a summary table on stdout.

  --config FILE         YAML map of parameters (rows, cols, dimension, mass, ..., num_modes, alpha,
                        beta, time_step); keys the core does not know are ignored
  --experiment LIST     comma-separated: cost, accuracy, stability, or all (default: all)
  --output DIR          folder for the CSV files (default: .)
  --tag NAME            file name tag, <experiment>_<tag>.csv (default: the config file's stem)
  --methods LIST        comma-separated of full, linear, physical (default: all three; accuracy
                        always runs full as the reference)
  --set KEY=VALUE       override one parameter of the config (VALUE is YAML); repeatable
  --vary KEY=V1,V2,...  run every experiment for each value; several --vary give every combination,
                        e.g. --vary integrator=explicit,implicit --vary linearization=rest,equilibrium
  --quiet               no progress line on stderr

  accuracy:   --steps N (5000)  --interval N (1000, snapshots)  --sample N (10, error samples)
              --reference-time-step DT (s; default: the reference is `full` at the same step, as in the
                paper; with DT: `full`, explicit, at DT, checked against DT / 2, and every method,
                `full` too, measured against it, with its wall time per step; DT must divide time_step)
              --no-snapshots (no particle positions file)
  stability:  --stability-steps S (10000)  --tolerance T (1e-3, relative)
              --max-time-step DT (10 s; no divergence up to DT counts as unbounded)
              --check-factor F (0: off; with --vary integrator=explicit,implicit, each implicit
                method is also run at F times the largest stable step of the same method under
                the explicit integrator, and the summary says whether it stayed stable)
  cost:       --sizes LIST (5,10,20,40; square grids)  --repeats R (7)  --min-repeat-seconds T (0.02)
)";

struct UsageError : std::invalid_argument
{
  using std::invalid_argument::invalid_argument;
};

// Splits on commas outside brackets, so "fixed=[0,4],[1,3]" keeps its lists.
std::vector<std::string> splitList(const std::string& text)
{
  std::vector<std::string> items;
  std::string item;
  int depth = 0;
  for (char c : text)
  {
    if (c == '[')
      ++depth;
    if (c == ']')
      --depth;
    if (c == ',' && depth == 0)
    {
      items.push_back(item);
      item.clear();
    }
    else
      item += c;
  }
  items.push_back(item);
  return items;
}

int parseInt(const std::string& option, const std::string& text, int min)
{
  try
  {
    size_t used = 0;
    const int value = std::stoi(text, &used);
    if (used == text.size() && value >= min)
      return value;
  }
  catch (const std::exception&)
  {
  }
  throw UsageError("invalid value '" + text + "' for " + option + ": must be an integer >= " + std::to_string(min));
}

double parsePositive(const std::string& option, const std::string& text)
{
  try
  {
    size_t used = 0;
    const double value = std::stod(text, &used);
    if (used == text.size() && std::isfinite(value) && value > 0.0)
      return value;
  }
  catch (const std::exception&)
  {
  }
  throw UsageError("invalid value '" + text + "' for " + option + ": must be a number > 0");
}

std::pair<std::string, std::string> splitKeyValue(const std::string& option, const std::string& text)
{
  const size_t eq = text.find('=');
  if (eq == std::string::npos || eq == 0 || eq + 1 == text.size())
    throw UsageError("invalid value '" + text + "' for " + option + ": must be KEY=VALUE");
  return {text.substr(0, eq), text.substr(eq + 1)};
}

struct Options
{
  std::string config;
  std::vector<std::string> experiments{"cost", "accuracy", "stability"};
  std::string output = ".";
  std::string tag;
  std::vector<Method> methods{Method::Full, Method::Linear, Method::Physical};
  std::vector<std::pair<std::string, std::string>> sets;
  std::vector<std::pair<std::string, std::vector<std::string>>> varies;
  bool quiet = false;
  double check_factor = 0.0;
  AccuracyOptions accuracy;
  StabilityOptions stability;
  CostOptions cost;
};

Options parseArguments(int argc, char** argv)
{
  Options o;
  auto value = [&](int& i) -> std::string {
    if (i + 1 >= argc)
      throw UsageError(std::string("option ") + argv[i] + " needs a value");
    return argv[++i];
  };
  for (int i = 1; i < argc; ++i)
  {
    const std::string arg = argv[i];
    if (arg == "--help" || arg == "-h")
    {
      std::cout << kUsage;
      std::exit(0);
    }
    else if (arg == "--config")
      o.config = value(i);
    else if (arg == "--experiment")
    {
      const std::string text = value(i);
      o.experiments.clear();
      for (const std::string& name : splitList(text))
      {
        if (name == "all")
          o.experiments = {"cost", "accuracy", "stability"};
        else if (name == "cost" || name == "accuracy" || name == "stability")
          o.experiments.push_back(name);
        else
          throw UsageError("unknown experiment '" + name + "': must be cost, accuracy, stability or all");
      }
    }
    else if (arg == "--output")
      o.output = value(i);
    else if (arg == "--tag")
      o.tag = value(i);
    else if (arg == "--methods")
    {
      o.methods.clear();
      for (const std::string& name : splitList(value(i)))
      {
        try
        {
          o.methods.push_back(parseMethod(name));
        }
        catch (const std::invalid_argument&)
        {
          throw UsageError("unknown method '" + name + "' in --methods: must be full, linear or physical");
        }
      }
    }
    else if (arg == "--set")
      o.sets.push_back(splitKeyValue(arg, value(i)));
    else if (arg == "--vary")
    {
      const auto [key, values] = splitKeyValue(arg, value(i));
      if (key == "method")
        throw UsageError("--vary method: use --methods to choose methods");
      o.varies.push_back({key, splitList(values)});
    }
    else if (arg == "--quiet")
      o.quiet = true;
    else if (arg == "--steps")
      o.accuracy.steps = parseInt(arg, value(i), 1);
    else if (arg == "--interval")
      o.accuracy.interval = parseInt(arg, value(i), 1);
    else if (arg == "--sample")
      o.accuracy.sample = parseInt(arg, value(i), 1);
    else if (arg == "--reference-time-step")
      o.accuracy.reference_time_step = parsePositive(arg, value(i));
    else if (arg == "--no-snapshots")
      o.accuracy.snapshots = false;
    else if (arg == "--max-time-step")
      o.stability.max_time_step = parsePositive(arg, value(i));
    else if (arg == "--check-factor")
      o.check_factor = parsePositive(arg, value(i));
    else if (arg == "--stability-steps")
      o.stability.steps = parseInt(arg, value(i), 1);
    else if (arg == "--tolerance")
    {
      o.stability.tolerance = parsePositive(arg, value(i));
      if (o.stability.tolerance >= 1.0)
        throw UsageError("invalid value for --tolerance: must be a relative tolerance in (0, 1)");
    }
    else if (arg == "--sizes")
    {
      o.cost.sizes.clear();
      for (const std::string& s : splitList(value(i)))
        o.cost.sizes.push_back(parseInt("--sizes", s, 2));
    }
    else if (arg == "--repeats")
      o.cost.repeats = parseInt(arg, value(i), 1);
    else if (arg == "--min-repeat-seconds")
      o.cost.min_repeat_seconds = parsePositive(arg, value(i));
    else
      throw UsageError("unknown option '" + arg + "' (see --help)");
  }
  if (o.config.empty())
    throw UsageError("--config FILE is required (see --help)");
  if (o.accuracy.interval % o.accuracy.sample != 0)
    throw UsageError("--sample " + std::to_string(o.accuracy.sample) + " must divide --interval " +
                     std::to_string(o.accuracy.interval));
  o.accuracy.methods = o.methods;
  o.stability.methods = o.methods;
  o.cost.methods = o.methods;
  if (o.tag.empty())
    o.tag = fs::path(o.config).stem().string();
  return o;
}

// Every combination of the --vary values, each loaded and validated from its own copy of the config.
std::vector<ExperimentSetup> buildSetups(const Options& o)
{
  YamlParameterSource base = YamlParameterSource::fromFile(o.config);
  for (const auto& [key, text] : o.sets)
    base.set(key, text);

  std::vector<std::vector<std::pair<std::string, std::string>>> combinations{{}};
  for (const auto& [key, values] : o.varies)
  {
    std::vector<std::vector<std::pair<std::string, std::string>>> next;
    for (const auto& combination : combinations)
      for (const std::string& v : values)
      {
        auto extended = combination;
        extended.push_back({key, v});
        next.push_back(extended);
      }
    combinations = next;
  }

  std::vector<ExperimentSetup> setups;
  for (const auto& combination : combinations)
  {
    YamlParameterSource source = base.clone();
    ExperimentSetup setup;
    std::string label;
    for (const auto& [key, v] : combination)
    {
      source.set(key, v);
      label += (label.empty() ? "" : " ") + key + "=" + v;
    }
    for (char& c : label)
      if (c == ',')
        c = ';';  // the label is a CSV field
    if (!label.empty())
      setup.variant = label;
    try
    {
      setup.grid = loadGridParams(source);
      setup.sim = loadSimulationParams(source);
    }
    catch (const std::invalid_argument& e)
    {
      throw std::invalid_argument("config '" + o.config + "': " + e.what());
    }
    std::vector<std::string> overridden;
    for (const auto& kv : o.sets)
      overridden.push_back(kv.first);
    for (const auto& kv : combination)
      overridden.push_back(kv.first);
    for (const std::string& key : overridden)
      if (!source.queried().count(key))
        throw UsageError("unknown parameter '" + key + "' in --set/--vary: the core reads no parameter of that name");
    setups.push_back(setup);
  }
  return setups;
}

// Fails before any experiment runs: builds each setup once (ranges are checked there) and checks
// that the cost sizes leave room for the modes.
void validate(const Options& o, const std::vector<ExperimentSetup>& setups)
{
  for (const ExperimentSetup& setup : setups)
  {
    try
    {
      Simulation check(setup.grid, setup.sim);
    }
    catch (const std::invalid_argument& e)
    {
      throw std::invalid_argument("config '" + o.config + "' (" + setup.variant + "): " + e.what());
    }
    if (o.accuracy.reference_time_step > 0.0 &&
        std::find(o.experiments.begin(), o.experiments.end(), "accuracy") != o.experiments.end())
    {
      try
      {
        referenceSubsteps(setup.sim.time_step, o.accuracy.reference_time_step);
      }
      catch (const std::invalid_argument& e)
      {
        throw UsageError(std::string("--reference-time-step: ") + e.what());
      }
    }
    const bool cost = std::find(o.experiments.begin(), o.experiments.end(), "cost") != o.experiments.end();
    if (cost)
      for (int size : o.cost.sizes)
      {
        GridParams g = setup.grid;
        g.rows = g.cols = size;
        g.fixed.clear();
        const int free_dofs = Grid(g).numFreeDofs();
        if (setup.sim.num_modes > free_dofs)
          throw UsageError("--sizes " + std::to_string(size) + ": a " + std::to_string(size) + "x" +
                           std::to_string(size) + " grid has " + std::to_string(free_dofs) +
                           " free degrees of freedom, fewer than num_modes = " + std::to_string(setup.sim.num_modes));
      }
  }
}

// One line on stderr, rewritten in place on a terminal, a few lines a minute otherwise.
class Progress
{
public:
  explicit Progress(bool enabled) : enabled_(enabled), tty_(isatty(fileno(stderr))) {}
  void operator()(const std::string& label, double fraction)
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

private:
  bool enabled_, tty_;
  std::chrono::steady_clock::time_point last_{};
};

std::ofstream openCsv(const Options& o, const std::string& name)
{
  const fs::path path = fs::path(o.output) / name;
  std::ofstream out(path);
  if (!out)
    throw std::runtime_error("cannot write '" + path.string() + "'");
  std::cout << "wrote " << path.string() << "\n";
  return out;
}

std::string fmt(double value, int precision = 3)
{
  std::ostringstream s;
  if (std::isnan(value))
    s << "-";
  else if (std::isinf(value))
    s << "inf";
  else
    s << std::setprecision(precision) << value;
  return s.str();
}

// Prints a table with columns padded to their widest cell.
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

void runCostExperiment(const Options& o, const std::vector<ExperimentSetup>& setups, Progress& progress)
{
  std::vector<CostRow> rows;
  for (const ExperimentSetup& setup : setups)
  {
    const auto part = runCost(setup, o.cost, std::ref(progress));
    rows.insert(rows.end(), part.begin(), part.end());
  }
  std::ofstream out = openCsv(o, "cost_" + o.tag + ".csv");
  writeCostCsv(out, rows);
  std::vector<std::vector<std::string>> table{
      {"variant", "grid", "dim", "free dofs", "modes", "basis build ms", "method", "step us (median)"}};
  for (const CostRow& r : rows)
    table.push_back({r.variant, std::to_string(r.rows) + "x" + std::to_string(r.cols), std::to_string(r.dimension),
                     std::to_string(r.free_dofs), std::to_string(r.num_modes), fmt(1e3 * r.build_seconds),
                     r.method, fmt(1e6 * r.step_seconds) + (r.diverged ? " (diverged)" : "")});
  printTable("cost (" + o.tag + "): median of " + std::to_string(o.cost.repeats) + " timed runs", table);
}

void runAccuracyExperiment(const Options& o, const std::vector<ExperimentSetup>& setups, Progress& progress)
{
  const bool with_reference = o.accuracy.reference_time_step > 0.0;
  const std::string reference = with_reference ? "reference" : "full";
  std::vector<ErrorSample> errors;
  std::vector<Snapshot> snapshots;
  std::vector<std::string> messages;
  std::vector<std::vector<std::string>> table{
      {"variant", "method", "step", "time s", "max distance m", "RMS distance m", "max displacement m"}};
  for (const ExperimentSetup& setup : setups)
  {
    const AccuracyResult result = runAccuracy(setup, o.accuracy, std::ref(progress));
    errors.insert(errors.end(), result.errors.begin(), result.errors.end());
    errors.insert(errors.end(), result.reference_check.begin(), result.reference_check.end());
    snapshots.insert(snapshots.end(), result.snapshots.begin(), result.snapshots.end());
    messages.insert(messages.end(), result.messages.begin(), result.messages.end());
    std::ostringstream freq;
    for (int k = 0; k < result.frequencies.size(); ++k)
      freq << (k ? " " : "") << fmt(result.frequencies[k]);
    std::cout << "basis (" << setup.variant << "): " << result.frequencies.size() << " modes, "
              << result.num_zero_modes << " zero, omega [rad/s] = " << freq.str() << "\n";
    if (with_reference)
      std::cout << "reference (" << setup.variant << "): full, explicit, dt = "
                << fmt(o.accuracy.reference_time_step) << " s; against dt / 2: largest RMS distance "
                << fmt(result.reference_check_max_rms) << " m, largest particle distance "
                << fmt(result.reference_check_max_distance) << " m\n";
    for (const ErrorSample& e : result.errors)
      if ((e.step % o.accuracy.interval == 0 || e.step == o.accuracy.steps) && e.method != reference)
        table.push_back({e.variant, e.method, std::to_string(e.step), fmt(e.time), fmt(e.max_distance),
                         fmt(e.rms_distance), fmt(e.max_displacement)});
    for (const ErrorSample& e : result.errors)
      if ((e.step % o.accuracy.interval == 0 || e.step == o.accuracy.steps) && e.method == reference)
        std::cout << reference << " (" << setup.variant << ") at step " << e.step
                  << ": max displacement " << fmt(e.max_displacement) << " m\n";
  }
  std::ofstream out = openCsv(o, "accuracy_" + o.tag + "_error.csv");
  writeErrorCsv(out, errors);
  if (o.accuracy.snapshots)
  {
    std::ofstream snap = openCsv(o, "accuracy_" + o.tag + "_snapshots.csv");
    writeSnapshotCsv(snap, Grid(setups.front().grid), snapshots);
  }
  printTable("accuracy (" + o.tag + "): distance to " + reference + " every " + std::to_string(o.accuracy.interval) +
                 " steps",
             table);
  std::vector<std::vector<std::string>> summary{{"variant", "method", "mean RMS m", "largest RMS m", "mean largest m",
                                                 "RMS at the end m", "step us (median)", "step us (mean)"}};
  for (const AccuracySummary& s : summarizeAccuracy(errors))
    if (s.method != reference && s.method != "reference_half_step")
      summary.push_back({s.variant, s.method, fmt(s.mean_rms), fmt(s.max_rms), fmt(s.mean_max),
                         s.diverged ? "diverged" : fmt(s.final_rms), fmt(1e6 * s.step_seconds_median),
                         fmt(1e6 * s.step_seconds_mean)});
  printTable("accuracy (" + o.tag + "): over every sample after step 0, against " + reference +
                 "; wall time per step while running",
             summary);
  for (const std::string& m : messages)
    std::cout << "note: " << m << "\n";
}

void runStabilityExperiment(const Options& o, const std::vector<ExperimentSetup>& setups, Progress& progress)
{
  std::vector<StabilityRow> rows;
  for (const ExperimentSetup& setup : setups)
  {
    const auto part = runStability(setup, o.stability, std::ref(progress));
    rows.insert(rows.end(), part.begin(), part.end());
  }
  // Each implicit method at check_factor times the largest stable step of its explicit twin (the
  // setup whose variant differs only in integrator=explicit).
  std::vector<std::string> checks;
  if (o.check_factor > 0.0)
    for (const ExperimentSetup& setup : setups)
    {
      if (setup.sim.integrator != IntegratorKind::Implicit)
        continue;
      std::string twin = setup.variant;
      const size_t at = twin.find("integrator=implicit");
      if (at == std::string::npos)
        continue;
      twin.replace(at, std::string("integrator=implicit").size(), "integrator=explicit");
      for (StabilityRow& row : rows)
      {
        if (row.variant != setup.variant)
          continue;
        const auto explicit_row = std::find_if(rows.begin(), rows.end(), [&](const StabilityRow& r) {
          return r.variant == twin && r.method == row.method;
        });
        if (explicit_row == rows.end() || !(explicit_row->stable_dt > 0.0))
          continue;
        row.check_dt = o.check_factor * explicit_row->stable_dt;
        row.check_stable = checkStableAt(setup, parseMethod(row.method), row.check_dt, o.stability.steps);
        checks.push_back(row.variant + ", " + row.method + " at " + fmt(o.check_factor) + " x the explicit " +
                         row.method + "'s largest stable step (" + fmt(1e3 * row.check_dt, 4) + " ms): " +
                         (row.check_stable ? "stable" : "DIVERGED") + " over " + std::to_string(o.stability.steps) +
                         " steps");
      }
    }
  std::ofstream out = openCsv(o, "stability_" + o.tag + ".csv");
  writeStabilityCsv(out, rows);
  std::vector<std::vector<std::string>> table{{"variant", "method", "largest stable dt s", "diverges at s", "trials",
                                               "2/omega (highest mode)", "2/omega (K(x0), all dofs)", "below stable"}};
  for (const StabilityRow& r : rows)
    table.push_back({r.variant, r.method, fmt(r.stable_dt, 6), fmt(r.unstable_dt, 6), std::to_string(r.trials),
                     fmt(r.modal_bound, 6), fmt(r.full_bound, 6), r.below_stable ? "yes" : "NO"});
  printTable("stability (" + o.tag + "): " + std::to_string(o.stability.steps) + " steps without divergence, " +
                 "bisection to a relative " + fmt(o.stability.tolerance),
             table);
  for (const std::string& c : checks)
    std::cout << "check: " << c << "\n";
}

}  // namespace

int main(int argc, char** argv)
{
  Options options;
  std::vector<ExperimentSetup> setups;
  try
  {
    options = parseArguments(argc, argv);
    setups = buildSetups(options);
    validate(options, setups);
    std::error_code ec;
    fs::create_directories(options.output, ec);
    if (ec || !fs::is_directory(options.output))
      throw std::invalid_argument("cannot create output folder '" + options.output + "'");
  }
  catch (const std::exception& e)
  {
    std::cerr << "modal_compare: error: " << e.what() << "\n";
    return 2;
  }

  try
  {
    Progress progress(!options.quiet);
    std::cout << "config " << options.config << ", " << setups.size() << " variant(s)\n";
    for (const std::string& experiment : options.experiments)
    {
      if (experiment == "cost")
        runCostExperiment(options, setups, progress);
      else if (experiment == "accuracy")
        runAccuracyExperiment(options, setups, progress);
      else
        runStabilityExperiment(options, setups, progress);
    }
  }
  catch (const std::exception& e)
  {
    std::cerr << "modal_compare: failed: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
