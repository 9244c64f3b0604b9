// modal_compare: runs the paper's experiments on a YAML config and writes CSV files and a summary.
#include "experiments.h"
#include "yaml_colliders.h"
#include "yaml_parameter_source.h"

#include "modal_mass_spring/parameters.h"
#include "modal_mass_spring/validation.h"

#include <climits>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iomanip>
#include <iostream>
#include <limits>
#include <map>
#include <new>
#include <optional>
#include <set>
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
CSV files to the output folder plus a summary table on stdout. Every option and every setup is
checked before anything runs; bad input ends with exit code 2 and a message naming it.

  --config FILE         YAML map of parameters (rows, cols, dimension, mass, ..., num_modes, alpha,
                        beta, time_step); the node's own keys are ignored, other unknown keys warned about
  --experiment LIST     comma-separated: cost, accuracy, stability, handles, or all (default: all, the
                        paper's three: cost, accuracy and stability; handles runs only when named)
  --output DIR          folder for the CSV files (default: .)
  --tag NAME            file name tag, <experiment>_<tag>.csv (default: the config file's stem); no '/'
  --methods LIST        comma-separated of full, linear, physical, cubature, adaptive (default: the first four;
                        adaptive, in accuracy and handles only: adaptive_method stepped while its error
                        indicator allows, full where it does not (error_tolerance, adaptive_dwell);
                        accuracy always runs full as the reference and writes cubature's training
                        report, |T|, training and held-out error and time, to accuracy_<tag>_cubature.csv)
  --set KEY=VALUE       override one parameter of the config (VALUE is YAML); repeatable, once per key
  --vary KEY=V1,V2,...  run every experiment for each value; several --vary give every combination,
                        e.g. --vary integrator=explicit,implicit --vary linearization=rest,equilibrium
  --quiet               no progress line on stderr
  --cache-dir DIR       where the equilibrium, bases and cubatures are cached between runs (default:
                        the node's, $ROS_HOME/modal_mass_spring, else ~/.ros/modal_mass_spring)
  --no-cache            compute them every time, reading and writing no cache: what the check before
                        the runs builds is kept for this run alone in a temporary folder, removed at
                        the end (the cost experiment, which times the build, never uses it)

  accuracy:   --steps N (5000)  --interval N (1000, snapshots)  --sample N (10, error samples; divides
                --interval, at most --steps)
              --reference-time-step DT (s; default: the reference is `full` at the same step, as in the
                paper; with DT: `full`, explicit, at DT, checked against DT / 2, and every method,
                `full` too, measured against it, with its wall time per step; DT must divide time_step,
                at most 100000 times)
              --no-snapshots (no particle positions file)
  stability:  --stability-steps S (10000)  --tolerance T (1e-3, relative, in [1e-12, 0.5])
              --max-time-step DT (10 s; above time_step; no divergence up to DT counts as unbounded)
              --scan-ratio R (1.02, in [1.001, 2]: the upward scan's step ratio)
              --window-factor F (2, in [1, 100]: stable windows are looked for up to F times the boundary)
              --check-factor F (0: off; needs --vary integrator=explicit,implicit: each implicit
                method is also run at F times the largest stable step of the same method under
                the explicit integrator, and the summary says whether it stayed stable)
  handles:    every scenario of the config's handle_scenarios (a list of {name, handles: [{particles,
                translation, rotation_axis, rotation_deg}], move_time, hold_time}; see config/compare/
                held_cloth.yaml): the grid's handles are the scenario's particle groups, each moved as a
                rigid frame over move_time s along a smooth ramp, then held for hold_time s (or, with
                waypoints: [{translation, rotation_deg}, ...] instead, through each in turn, one ramp
                from rest to rest a leg, move_time split evenly; config/compare/large_motion.yaml); a
                method that cannot be built on a scenario is reported as "did not build"; every method
                against the reference as in accuracy (--sample, --reference-time-step, --methods), each
                scenario run for its move_time (at least 10 time steps) + hold_time; writes handles_<tag>_error.csv,
                handles_<tag>_summary.csv and (unless --no-snapshots) handles_<tag>_snapshots.csv,
                every particle of every run where the move ends and at the end of the hold (of the
                first --vary combination)
  cost:       --sizes LIST (5,10,20,40; square grids)  --repeats R (7)  --min-repeat-seconds T (0.02)
)";

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

// `all`: the paper's experiments. `handles` needs handle_scenarios in the config, so it runs only when named.
const std::vector<std::string> kExperiments{"cost", "accuracy", "stability"};
const std::vector<std::string> kAllExperiments{"cost", "accuracy", "stability", "handles"};

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

// The items of a comma-separated option value: none empty, none twice.
std::vector<std::string> parseList(const std::string& option, const std::string& text)
{
  const std::vector<std::string> items = splitList(text);
  for (size_t k = 0; k < items.size(); ++k)
  {
    if (items[k].empty())
      rejectParameter(option, "'" + text + "'", "must be a comma-separated list without empty items");
    if (std::find(items.begin(), items.begin() + k, items[k]) != items.begin() + k)
      rejectParameter(option, "'" + text + "'", "lists '" + items[k] + "' twice");
  }
  return items;
}

int parseInt(const std::string& option, const std::string& text, long min, long max)
{
  try
  {
    size_t used = 0;
    const long value = std::stol(text, &used);
    if (used == text.size() && value >= min && value <= max)
      return static_cast<int>(value);
  }
  catch (const std::exception&)
  {
  }
  rejectParameter(option, "'" + text + "'",
                  "must be an integer in [" + std::to_string(min) + ", " + std::to_string(max) + "]");
}

// A finite number in (low, high] (open_low) or [low, high].
double parseNumber(const std::string& option, const std::string& text, double low, double high, bool open_low)
{
  try
  {
    size_t used = 0;
    const double value = std::stod(text, &used);
    if (used == text.size() && std::isfinite(value) && (open_low ? value > low : value >= low) && value <= high)
      return value;
  }
  catch (const std::exception&)
  {
  }
  std::ostringstream range;
  range << "must be a number in " << (open_low ? "(" : "[") << low << ", " << high << "]";
  rejectParameter(option, "'" + text + "'", range.str());
}

std::pair<std::string, std::string> splitKeyValue(const std::string& option, const std::string& text)
{
  const size_t eq = text.find('=');
  if (eq == std::string::npos || eq == 0 || eq + 1 == text.size())
    rejectParameter(option, "'" + text + "'", "must be KEY=VALUE");
  const std::string key = text.substr(0, eq);
  for (char c : key)
    if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '_'))
      rejectParameter(option, "'" + text + "'", "KEY must be a parameter name (letters, digits, '_')");
  return {key, text.substr(eq + 1)};
}

struct Options
{
  std::string config;
  std::vector<std::string> experiments = kExperiments;
  std::string output = ".";
  std::string tag;
  std::vector<Method> methods{Method::Full, Method::Linear, Method::Physical, Method::Cubature};
  bool adaptive = false;  // --methods named `adaptive`
  std::vector<std::pair<std::string, std::string>> sets;
  std::vector<std::pair<std::string, std::vector<std::string>>> varies;
  bool quiet = false;
  std::string cache_dir = defaultCacheDirectory();
  bool no_cache = false;
  double check_factor = 0.0;
  AccuracyOptions accuracy;
  StabilityOptions stability;
  CostOptions cost;

  bool runs(const std::string& experiment) const
  {
    return std::find(experiments.begin(), experiments.end(), experiment) != experiments.end();
  }
};

void setExperiments(Options& o, const std::string& text)
{
  o.experiments.clear();
  for (const std::string& name : parseList("--experiment", text))
  {
    if (name == "all")
      o.experiments = kExperiments;
    else if (std::find(kAllExperiments.begin(), kAllExperiments.end(), name) != kAllExperiments.end())
    {
      if (!o.runs(name))
        o.experiments.push_back(name);
    }
    else
      rejectParameter("--experiment", "'" + name + "'",
                      "unknown experiment: must be cost, accuracy, stability, handles or all");
  }
}

void setMethods(Options& o, const std::string& text)
{
  o.methods.clear();
  o.adaptive = false;
  for (const std::string& name : parseList("--methods", text))
  {
    if (name == "adaptive")
    {
      o.adaptive = true;
      continue;
    }
    try
    {
      o.methods.push_back(parseMethod(name));
    }
    catch (const std::invalid_argument&)
    {
      std::string names;
      for (const std::string& known : methodNames())
        names += (names.empty() ? "" : ", ") + known;
      rejectParameter("--methods", "'" + name + "'", "unknown method: must be one of " + names + ", adaptive");
    }
  }
}

void setTag(Options& o, const std::string& text)
{
  for (char c : text)
    if (c == '/' || std::iscntrl(static_cast<unsigned char>(c)))
      rejectParameter("--tag", "'" + text + "'", "a file name part: no '/' and no control characters");
  if (text.empty() || text == "." || text == "..")
    rejectParameter("--tag", "'" + text + "'", "must be a non-empty file name part");
  o.tag = text;
}

void addSet(Options& o, const std::string& text)
{
  const auto kv = splitKeyValue("--set", text);
  for (const auto& [key, value] : o.sets)
    if (key == kv.first)
      rejectParameter("--set", "'" + text + "'", "sets '" + key + "' twice (already '" + value + "')");
  o.sets.push_back(kv);
}

void addVary(Options& o, const std::string& text)
{
  const auto [key, values] = splitKeyValue("--vary", text);
  if (key == "method")
    rejectParameter("--vary", "'" + text + "'", "use --methods to choose methods");
  for (const auto& vary : o.varies)
    if (vary.first == key)
      rejectParameter("--vary", "'" + text + "'", "varies '" + key + "' twice");
  o.varies.push_back({key, parseList("--vary " + key, values)});
}

using Setter = std::function<void(Options&, const std::string&)>;

// Every option that takes a value; each may be given once, except --set and --vary.
const std::map<std::string, Setter>& valueOptions()
{
  static const std::map<std::string, Setter> options{
      {"--config", [](Options& o, const std::string& v) { o.config = v; }},
      {"--cache-dir",
       [](Options& o, const std::string& v) {
         if (v.empty())
           rejectParameter("--cache-dir", "''", "must be a folder (use --no-cache to run without a cache)");
         o.cache_dir = v;
       }},
      {"--experiment", setExperiments},
      {"--output", [](Options& o, const std::string& v) { o.output = v; }},
      {"--tag", setTag},
      {"--methods", setMethods},
      {"--set", addSet},
      {"--vary", addVary},
      {"--steps", [](Options& o, const std::string& v) { o.accuracy.steps = parseInt("--steps", v, 1, 100000000); }},
      {"--interval",
       [](Options& o, const std::string& v) { o.accuracy.interval = parseInt("--interval", v, 1, 100000000); }},
      {"--sample", [](Options& o, const std::string& v) { o.accuracy.sample = parseInt("--sample", v, 1, 100000000); }},
      {"--reference-time-step",
       [](Options& o, const std::string& v) {
         o.accuracy.reference_time_step = parseNumber("--reference-time-step", v, 0.0, 1e6, true);
       }},
      {"--max-time-step",
       [](Options& o, const std::string& v) {
         o.stability.max_time_step = parseNumber("--max-time-step", v, o.stability.min_time_step, 1e6, true);
       }},
      {"--check-factor",
       [](Options& o, const std::string& v) { o.check_factor = parseNumber("--check-factor", v, 0.0, 1e4, true); }},
      {"--stability-steps",
       [](Options& o, const std::string& v) { o.stability.steps = parseInt("--stability-steps", v, 1, 100000000); }},
      {"--tolerance",
       [](Options& o, const std::string& v) { o.stability.tolerance = parseNumber("--tolerance", v, kMinTolerance, 0.5, false); }},
      {"--scan-ratio",
       [](Options& o, const std::string& v) { o.stability.scan_ratio = parseNumber("--scan-ratio", v, 1.001, 2.0, false); }},
      {"--window-factor",
       [](Options& o, const std::string& v) {
         o.stability.window_factor = parseNumber("--window-factor", v, 1.0, 100.0, false);
       }},
      {"--sizes",
       [](Options& o, const std::string& v) {
         o.cost.sizes.clear();
         for (const std::string& size : parseList("--sizes", v))
           o.cost.sizes.push_back(parseInt("--sizes", size, 2, 1000000));
       }},
      {"--repeats", [](Options& o, const std::string& v) { o.cost.repeats = parseInt("--repeats", v, 1, 1000); }},
      {"--min-repeat-seconds",
       [](Options& o, const std::string& v) {
         o.cost.min_repeat_seconds = parseNumber("--min-repeat-seconds", v, 0.0, 60.0, true);
       }},
  };
  return options;
}

// What can be checked from the options alone; the setups are checked by validate().
void finishOptions(Options& o)
{
  if (o.config.empty())
    rejectParameter("--config", "''", "a YAML file is required (see --help)");
  if (o.output.empty())
    rejectParameter("--output", "''", "must name a folder");
  if (o.accuracy.interval % o.accuracy.sample != 0)
    rejectParameter("--sample", o.accuracy.sample, "must divide --interval " + std::to_string(o.accuracy.interval));
  if (o.accuracy.sample > o.accuracy.steps)
    rejectParameter("--sample", o.accuracy.sample, "must be at most --steps " + std::to_string(o.accuracy.steps));
  if (o.check_factor > 0.0 && !o.runs("stability"))
    rejectParameter("--check-factor", o.check_factor, "needs the stability experiment");
  checkStabilityOptions(o.stability);
  o.accuracy.methods = o.methods;
  o.accuracy.adaptive = o.adaptive;
  o.stability.methods = o.methods;
  o.cost.methods = o.methods;
  if (o.tag.empty())
    setTag(o, fs::path(o.config).stem().string());
}

Options parseArguments(int argc, char** argv)
{
  Options o;
  std::set<std::string> given;
  for (int i = 1; i < argc; ++i)
  {
    const std::string arg = argv[i];
    if (arg == "--help" || arg == "-h")
    {
      std::cout << kUsage;
      std::exit(0);
    }
    if (arg != "--set" && arg != "--vary" && !given.insert(arg).second)
      rejectParameter(arg, "(given twice)", "each option may be given once (only --set and --vary may repeat)");
    if (arg == "--quiet")
      o.quiet = true;
    else if (arg == "--no-snapshots")
      o.accuracy.snapshots = false;
    else if (arg == "--no-cache")
      o.no_cache = true;
    else if (const auto option = valueOptions().find(arg); option != valueOptions().end())
    {
      if (i + 1 >= argc)
        rejectParameter(arg, "(missing)", "needs a value");
      option->second(o, argv[++i]);
    }
    else
      rejectParameter("option", "'" + arg + "'", "not an option of modal_compare (see --help)");
  }
  if (o.no_cache && given.count("--cache-dir"))
    rejectParameter("--cache-dir", "'" + o.cache_dir + "'", "must not be given with --no-cache");
  o.accuracy.cache.directory = o.stability.cache.directory = o.no_cache ? "" : o.cache_dir;
  finishOptions(o);
  return o;
}

// Every combination of the --vary values.
std::vector<std::vector<std::pair<std::string, std::string>>> combinations(const Options& o)
{
  std::vector<std::vector<std::pair<std::string, std::string>>> all{{}};
  for (const auto& [key, values] : o.varies)
  {
    std::vector<std::vector<std::pair<std::string, std::string>>> next;
    for (const auto& combination : all)
      for (const std::string& v : values)
      {
        auto extended = combination;
        extended.push_back({key, v});
        next.push_back(extended);
      }
    all = next;
  }
  return all;
}

// Config keys that neither the core nor the node reads: most likely misspelled.
void warnAboutUnknownKeys(const YamlParameterSource& source)
{
  for (const std::string& key : source.unknownKeys())
    std::cerr << "modal_compare: warning: config '" << source.origin() << "': unknown parameter '" << key
                << "' ignored (neither the core nor the node reads it)\n";
}

// Every combination of the --vary values, each loaded from its own copy of the config; the config's
// handle scenarios (none when it has no handle_scenarios) go to `scenarios`.
std::vector<ExperimentSetup> buildSetups(const Options& o, std::vector<HandleScenario>& scenarios)
{
  YamlParameterSource base = YamlParameterSource::fromFile(o.config);
  if (base.keys().empty())
    std::cerr << "modal_compare: warning: config '" << base.origin()
              << "' sets no parameter: every parameter takes its default (the paper's 5 x 5 2D grid)\n";
  for (const auto& [key, text] : o.sets)
    base.set(key, text);

  std::vector<ExperimentSetup> setups;
  for (const auto& combination : combinations(o))
  {
    YamlParameterSource source = base.clone();
    ExperimentSetup setup;
    setup.settings = combination;
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
      if (const YAML::Node node = source.getNode("colliders"); node.IsDefined())
      {
        setup.sim.colliders = parseColliders(node, "colliders");
        // The node looks a collider's frame up in TF; the tool has no TF to follow.
        for (size_t i = 0; i < setup.sim.colliders.size(); ++i)
          if (!setup.sim.colliders[i].frame.empty())
            rejectParameter("colliders[" + std::to_string(i) + "].frame", "'" + setup.sim.colliders[i].frame + "'",
                            "modal_compare has no TF frames to follow: leave frame out (the node follows it)");
      }
      if (const YAML::Node node = source.getNode("handle_scenarios"); node.IsDefined())
        scenarios = parseHandleScenarios(node, "handle_scenarios");
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
        rejectParameter(key, "(in --set/--vary)", "unknown parameter: the core reads no parameter of that name");
    if (setups.empty())
      warnAboutUnknownKeys(source);
    setups.push_back(setup);
  }
  return setups;
}

// The handles experiment's setups: every scenario on every setup, the grid's handles the scenario's,
// the variant the scenario's name followed by the setup's varied settings.
std::vector<ExperimentSetup> handleSetups(const Options& o, const std::vector<ExperimentSetup>& setups,
                                          const std::vector<HandleScenario>& scenarios)
{
  std::vector<ExperimentSetup> out;
  for (const HandleScenario& scenario : scenarios)
    for (const ExperimentSetup& setup : setups)
    {
      ExperimentSetup s = setup;
      try
      {
        s.grid = gridWithHandles(setup.grid, scenario);
      }
      catch (const std::invalid_argument& e)
      {
        throw std::invalid_argument("config '" + o.config + "': " + e.what());
      }
      // One handle is one rigid body: with `auto` and nothing fixed, the methods simulate in its frame.
      s.sim.handles_one_body = scenario.handles.size() == 1;
      s.variant = scenario.name + (setup.settings.empty() ? "" : " " + setup.variant);
      s.handle_scenario = scenario;
      out.push_back(s);
    }
  return out;
}

constexpr int kMinMoveSteps = 10;

// Steps a handle scenario runs on a setup: its move and hold (or its move alone), rounded up to whole
// samples.
int handleSteps(const Options& o, const ExperimentSetup& setup, bool move_only = false)
{
  const HandleScenario& scenario = *setup.handle_scenario;
  // The ramp's velocity and acceleration exist only where steps resolve it: a shorter move is a jump.
  if (scenario.move_time < kMinMoveSteps * setup.sim.time_step)
    rejectParameter("handle_scenarios." + scenario.name + ".move_time", scenario.move_time,
                    "must be at least " + std::to_string(kMinMoveSteps) + " time steps (" +
                        fmt(kMinMoveSteps * setup.sim.time_step) + " s at time_step = " + fmt(setup.sim.time_step) +
                        " s): a shorter move is a jump the smooth ramp cannot give");
  const double seconds = move_only ? scenario.move_time : scenario.duration();
  const double steps = std::ceil(seconds / setup.sim.time_step - 1e-9);
  const double samples = std::ceil(steps / o.accuracy.sample);
  if (!(samples * o.accuracy.sample <= 100000000.0))
    rejectParameter("time_step", setup.sim.time_step,
                    "handle scenario '" + setup.handle_scenario->name + "' of " +
                        std::to_string(setup.handle_scenario->duration()) + " s would take more than 1e8 steps");
  return static_cast<int>(samples) * o.accuracy.sample;
}

bool runsCubature(const Options& o)
{
  return o.adaptive || std::find(o.methods.begin(), o.methods.end(), Method::Cubature) != o.methods.end();
}

// The core's checks of one setup (validateParameters: ranges, sizes, the memory estimate), which
// build nothing, named by config and variant. The cubature's training counts when a method of the
// run is `cubature`, whatever the config's `method`.
void validateSetup(const Options& o, const ExperimentSetup& setup, const GridParams& grid, const std::string& what)
{
  try
  {
    SimulationParams params = setup.sim;
    params.method = runsCubature(o) ? Method::Cubature : Method::Physical;
    validateParameters(grid, params);
  }
  catch (const std::invalid_argument& e)
  {
    throw std::invalid_argument("config '" + o.config + "' (" + setup.variant + what + "): " + e.what());
  }
}

void validateStabilitySetups(const Options& o, const std::vector<ExperimentSetup>& setups)
{
  for (const ExperimentSetup& setup : setups)
    if (!(setup.sim.time_step < o.stability.max_time_step))
      rejectParameter("--max-time-step", o.stability.max_time_step,
                      "must be above time_step = " + fmt(setup.sim.time_step) + " s (" + setup.variant +
                          "), where the search starts");
  if (o.check_factor <= 0.0)
    return;
  bool paired = false;
  for (const ExperimentSetup& setup : setups)
    paired = paired || (setup.sim.integrator == IntegratorKind::Implicit && explicitTwin(setup, setups));
  if (!paired)
    rejectParameter("--check-factor", o.check_factor,
                    "needs an implicit setup and its explicit twin: --vary integrator=explicit,implicit");
}

// What the accuracy or handles experiment keeps of one setup until its files are written: an error
// sample per run every `sample` steps, every particle of every run every `interval` steps.
double resultBytes(const Options& o, const ExperimentSetup& setup, long steps, long interval)
{
  const double runs = o.methods.size() + 1.0 + (o.accuracy.reference_time_step > 0.0 ? 1.0 : 0.0);
  const double samples = static_cast<double>(steps) / o.accuracy.sample + 1.0;
  const double sample_bytes = sizeof(ErrorSample) + 2.0 * setup.variant.size() + 64.0;
  double bytes = runs * samples * sample_bytes;
  if (o.accuracy.snapshots)
  {
    const double particles = static_cast<double>(setup.grid.rows) * setup.grid.cols;
    bytes += runs * (static_cast<double>(steps) / interval + 2.0) * (sizeof(Snapshot) + 24.0 * particles);
  }
  return bytes;
}

// Refuses results that would not fit in memory_limit_gb (with what one setup's simulations need), and
// names what takes most of it: the results kept, or the setup's simulations.
void checkResultMemory(const Options& o, const std::vector<ExperimentSetup>& setups, double result_bytes)
{
  const bool cubature = runsCubature(o);
  for (const ExperimentSetup& setup : setups)
  {
    // Every method's simulation and the references are alive at once; only `cubature`'s trains.
    const double runs = o.methods.size() + 2.0;
    SimulationParams untrained = setup.sim;
    untrained.method = Method::Physical;
    const double training_bytes = cubature ? cubatureTrainingBytes(setup.grid, setup.sim) : 0.0;
    const double simulation_bytes = runs * estimateMemoryBytes(setup.grid, untrained) + training_bytes;
    const double needed_gb = (result_bytes + simulation_bytes) / 1e9;
    if (needed_gb <= setup.sim.memory_limit_gb)
      continue;
    std::ostringstream allowed;
    allowed.precision(3);
    allowed << "need about " << needed_gb << " GB, above memory_limit_gb = " << setup.sim.memory_limit_gb << " GB ("
            << setup.variant << "): ";
    if (result_bytes >= simulation_bytes)
    {
      allowed << "the results kept in memory (an error sample per method every --sample steps, every particle "
              << "every --interval steps) take " << result_bytes / 1e9
              << " GB of it; use fewer --steps, a larger --sample or --interval, or --no-snapshots";
      rejectParameter("--steps, --sample", std::to_string(o.accuracy.steps) + ", " + std::to_string(o.accuracy.sample),
                      allowed.str());
    }
    allowed << "the setup's " << runs << " simulations take " << simulation_bytes / 1e9 << " GB of it"
            << (cubature ? " (the cubature's training " + fmt(training_bytes / 1e9) + " GB)" : std::string())
            << "; use a smaller grid, fewer num_modes or num_skinning_weights, fewer --methods, or raise "
               "memory_limit_gb";
    rejectParameter("memory_limit_gb", setup.sim.memory_limit_gb, allowed.str());
  }
}

// Builds what each setup's runs build (the equilibrium, both bases, the constraint modes of its
// handles, the cubature's training) once, one setup at a time, before the first simulation steps:
// a setup that cannot be built is refused in seconds, not after the setups before it ran. With the
// cache on, the runs load them again.
// Builds every setup with the method that builds the most. A handle scenario on which that method
// cannot be built (two small grips leave no constraint modes) still runs when `full` builds: the
// handles experiment reports the methods that cannot as "did not build" and goes on.
void buildEverySetup(const Options& o, const std::vector<ExperimentSetup>& setups, bool methods_may_fail)
{
  // The method that builds the most: the cubature is trained on the physical basis.
  Method method = Method::Full;
  for (Method m : {Method::Linear, Method::Physical, Method::Cubature})
    if (std::find(o.methods.begin(), o.methods.end(), m) != o.methods.end())
      method = m;
  auto build = [&](const ExperimentSetup& setup, Method m) {
    SimulationParams params = setup.sim;
    params.method = m;
    // A slow equilibrium or eigensolver says how it goes on stderr, every 2 s.
    const auto start = std::chrono::steady_clock::now();
    auto last = start;
    IterationFn on_iteration;
    if (!o.quiet)
      on_iteration = [&](const std::string& stage, int iteration, double residual, double target) {
        const auto now = std::chrono::steady_clock::now();
        if (std::chrono::duration<double>(now - last).count() < 2.0)
          return;
        last = now;
        std::cerr << "building " << setup.variant << ": " << stage << ", ";
        if (stage == "cubature")
          std::cerr << iteration << " springs selected, training error " << 100.0 * residual
                    << "% (cubature_tolerance " << 100.0 * target << "%), ";
        else
          std::cerr << (stage == "equilibrium" ? "Newton iteration " : "Lanczos step ") << iteration << ", "
                    << (stage == "equilibrium" ? "largest unbalanced force " : "residual ") << residual
                    << (stage == "equilibrium" ? " N (target " : " (target ") << target
                    << (stage == "equilibrium" ? " N), " : "), ");
        std::cerr << std::fixed << std::setprecision(1) << std::chrono::duration<double>(now - start).count() << " s"
                  << std::defaultfloat << std::setprecision(6) << "\n";
      };
    try
    {
      Simulation built(setup.grid, params, StageFn{}, o.accuracy.cache, on_iteration);
    }
    catch (const std::bad_alloc&)
    {
      throw std::invalid_argument("config '" + o.config + "' (" + setup.variant + "): out of memory while building "
                                  "it: lower memory_limit_gb to what is free, or use a smaller grid or fewer modes");
    }
    catch (const std::exception& e)
    {
      throw std::invalid_argument("config '" + o.config + "' (" + setup.variant + "): cannot be built (" +
                                  toString(m) + "): " + e.what());
    }
  };
  for (const ExperimentSetup& setup : setups)
  {
    try
    {
      build(setup, method);
    }
    catch (const std::invalid_argument& e)
    {
      if (!methods_may_fail || method == Method::Full)
        throw;
      build(setup, Method::Full);
      std::cout << "note: " << e.what() << "; the methods that cannot be built are reported as 'did not build'\n";
    }
  }
}

void validateHandleSetups(const Options& o, const std::vector<ExperimentSetup>& handle_setups)
{
  if (handle_setups.empty())
    rejectParameter("handle_scenarios", "(absent)",
                    "the handles experiment needs a list of scenarios in the config '" + o.config +
                        "' (see config/compare/held_cloth.yaml)");
  double result_bytes = 0.0;
  for (const ExperimentSetup& setup : handle_setups)
  {
    validateSetup(o, setup, setup.grid, "");
    result_bytes += resultBytes(o, setup, handleSteps(o, setup), handleSteps(o, setup, true));
    if (o.accuracy.reference_time_step > 0.0)
    {
      const int substeps = referenceSubsteps(setup.sim.time_step, o.accuracy.reference_time_step);
      if (2LL * o.accuracy.sample * substeps > std::numeric_limits<int>::max())
        rejectParameter("--reference-time-step", o.accuracy.reference_time_step,
                        "with --sample " + std::to_string(o.accuracy.sample) + " too many reference steps per sample");
    }
  }
  checkResultMemory(o, handle_setups, result_bytes);
}

// Fails before any experiment runs. The setups as configured run in cost, accuracy and stability
// only: the handles experiment runs them with its scenarios' handles (validateHandleSetups).
void validate(const Options& o, const std::vector<ExperimentSetup>& setups)
{
  if (!o.runs("cost") && !o.runs("accuracy") && !o.runs("stability"))
    return;
  for (const ExperimentSetup& setup : setups)
  {
    validateSetup(o, setup, setup.grid, "");
    if (o.runs("accuracy") && o.accuracy.reference_time_step > 0.0)
    {
      const int substeps = referenceSubsteps(setup.sim.time_step, o.accuracy.reference_time_step);
      if (2LL * o.accuracy.sample * substeps > std::numeric_limits<int>::max())
        rejectParameter("--reference-time-step", o.accuracy.reference_time_step,
                        "with --sample " + std::to_string(o.accuracy.sample) + " too many reference steps per sample");
    }
    if (o.runs("cost"))
      for (int size : o.cost.sizes)
      {
        GridParams g = setup.grid;
        g.rows = g.cols = size;
        g.fixed.clear();
        validateSetup(o, setup, g, ", --sizes " + std::to_string(size));
      }
  }
  if (o.runs("stability"))
    validateStabilitySetups(o, setups);
  if (o.runs("accuracy"))
  {
    double bytes = 0.0;
    for (const ExperimentSetup& setup : setups)
      bytes += resultBytes(o, setup, o.accuracy.steps, o.accuracy.interval);
    checkResultMemory(o, setups, bytes);
  }
}

// Every file the run writes, in the output folder.
std::vector<std::string> outputNames(const Options& o)
{
  std::vector<std::string> names;
  for (const std::string& experiment : o.experiments)
  {
    const std::string stem = experiment + "_" + o.tag;
    if (experiment == "cost" || experiment == "stability")
      names.push_back(stem + ".csv");
    else
      for (const char* part : {"_error", "_summary", "_cubature", "_snapshots"})
        names.push_back(stem + part + ".csv");
  }
  return names;
}

// Refuses a --tag (or config file name) that makes a file name longer than file systems allow.
void checkOutputNames(const Options& o)
{
  for (const std::string& name : outputNames(o))
    if (name.size() > NAME_MAX)
      rejectParameter("--tag", "'" + o.tag + "'",
                      "makes the file name '" + name + "' " + std::to_string(name.size()) + " characters long, above " +
                          std::to_string(NAME_MAX) + "; use a shorter --tag (default: the config file's stem)");
}

// Creates the output folder and makes sure a file can be written there, before any work.
void prepareOutput(const Options& o)
{
  std::error_code ec;
  fs::create_directories(o.output, ec);
  if (ec || !fs::is_directory(o.output))
    rejectParameter("--output", "'" + o.output + "'", "cannot create the folder" + (ec ? ": " + ec.message() : ""));
  const fs::path probe = fs::path(o.output) / (".modal_compare_write_test_" + std::to_string(getpid()));
  const bool writable = static_cast<bool>(std::ofstream(probe));
  fs::remove(probe, ec);
  if (!writable)
    rejectParameter("--output", "'" + o.output + "'", "the folder is not writable");
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

// Said once per file, however often it is rewritten.
std::set<std::string> announced;

std::ofstream openCsv(const Options& o, const std::string& name)
{
  const fs::path path = fs::path(o.output) / name;
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
}

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
  if (result.basis == BasisKind::Skinning)
    std::cout << "physical basis (" << setup.variant << "): " << describeSkinning(result.skinning)
              << ", omega up to " << fmt(result.physical_frequencies.maxCoeff()) << " rad/s\n";
  if (o.accuracy.reference_time_step > 0.0)
    std::cout << "reference (" << setup.variant << "): full, explicit, dt = " << fmt(o.accuracy.reference_time_step)
              << " s; against dt / 2: largest RMS distance " << fmt(result.reference_check_max_rms)
              << " m, largest particle distance " << fmt(result.reference_check_max_distance) << " m\n";
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
                                                 "CPU us (median)", "CPU s per simulated s", "real-time factor"}};
  for (const AccuracySummary& s : summarizeAccuracy(errors))
    if (s.method != reference && s.method != "reference_half_step")
      summary.push_back({s.variant, s.method, fmt(s.mean_rms), fmt(s.max_rms), fmt(s.mean_max),
                         s.diverged ? "diverged" : fmt(s.final_rms), fmt(1e6 * s.step_seconds_median),
                         fmt(1e6 * s.step_seconds_mean), fmt(1e6 * s.step_cpu_seconds_median),
                         fmt(s.cpu_per_simulated_second), fmt(s.real_time_factor)});
  printTable("accuracy (" + o.tag + "): over every sample after step 0, against " + reference +
                 "; wall and this thread's CPU time per step while running, the CPU time per simulated second "
                 "and the real-time factor it allows (time_step / CPU per step)",
             summary);
  printAdaptive(summarizeAccuracy(errors));
}

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
      row.check_stable = checkStableAt(setups[s], parseMethod(row.method), row.check_dt, o.stability.steps);
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
                << " s, against dt / 2: largest RMS distance " << fmt(result.reference_check_max_rms) << " m";
    std::cout << "\n";
  };
  runEachSetup(o, "handles", setups, run, write);
  const std::vector<AccuracySummary> summaries = summaries_of();
  std::vector<std::vector<std::string>> table{
      {"scenario", "method", "mean RMS m", "largest RMS m", "RMS at the end m", "step us (median)", "CPU us (median)",
       "CPU s per simulated s", "real-time factor", "indicator rank corr."}};
  for (const AccuracySummary& s : summaries)
    if (!s.not_built.empty())
      table.push_back({s.variant, s.method, "did not build: " + s.not_built, "", "", "", "", "", "", ""});
    else if (s.method != "reference_half_step" && (s.method != reference || s.step_seconds_median > 0.0))
      // The reference's own row when it is timed (`full` at the methods' step): the step times to compare.
      table.push_back({s.variant, s.method, s.method == reference ? "(reference)" : fmt(s.mean_rms),
                       s.method == reference ? "" : fmt(s.max_rms),
                       s.method == reference ? "" : s.diverged ? "diverged" : fmt(s.final_rms),
                       fmt(1e6 * s.step_seconds_median), fmt(1e6 * s.step_cpu_seconds_median),
                       fmt(s.cpu_per_simulated_second), fmt(s.real_time_factor),
                       fmt(s.indicator_rank_correlation)});
  printTable("handles (" + o.tag + "): distance of the free particles to " + reference +
                 " over every sample after step 0; wall and this thread's CPU time per step while running, the "
                 "CPU time per simulated second and the real-time factor it allows (time_step / CPU per step); "
                 "the rank correlation of the method's error indicator with that distance",
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

// With --no-cache, a cache folder of this run alone: what the check before the runs builds (the
// equilibrium, bases, cubature) is built once and the runs load it; removed when the run ends.
class RunCache
{
public:
  explicit RunCache(Options& o)
  {
    if (!o.no_cache)
      return;
    std::string pattern = (std::filesystem::temp_directory_path() / "modal_compare_cache.XXXXXX").string();
    if (!mkdtemp(pattern.data()))
      throw std::runtime_error("--no-cache: cannot create a temporary folder in " +
                               std::filesystem::temp_directory_path().string() + " for this run's precomputation");
    directory_ = pattern;
    o.accuracy.cache.directory = o.stability.cache.directory = directory_;
  }
  ~RunCache()
  {
    std::error_code ignored;
    if (!directory_.empty())
      std::filesystem::remove_all(directory_, ignored);
  }
  RunCache(const RunCache&) = delete;
  RunCache& operator=(const RunCache&) = delete;

private:
  std::string directory_;
};

}  // namespace

int main(int argc, char** argv)
{
  Options options;
  std::vector<ExperimentSetup> setups, handle_setups;
  std::optional<RunCache> run_cache;
  try
  {
    options = parseArguments(argc, argv);
    run_cache.emplace(options);
    std::vector<HandleScenario> scenarios;
    setups = buildSetups(options, scenarios);
    validate(options, setups);
    if (options.runs("handles"))
    {
      handle_setups = handleSetups(options, setups, scenarios);
      validateHandleSetups(options, handle_setups);
    }
    checkOutputNames(options);
    if (options.runs("accuracy") || options.runs("stability"))
      buildEverySetup(options, setups, false);
    buildEverySetup(options, handle_setups, true);
    prepareOutput(options);
  }
  catch (const std::bad_alloc&)
  {
    std::cerr << "modal_compare: error: out of memory while checking the input\n";
    return 2;
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
      else if (experiment == "handles")
        runHandlesExperiment(options, handle_setups, progress);
      else
        runStabilityExperiment(options, setups, progress);
    }
  }
  catch (const std::bad_alloc&)
  {
    // The memory estimate (memory_limit_gb) passed, but the machine had less than that to give.
    std::cerr << "modal_compare: failed: out of memory (std::bad_alloc): the machine could not provide what this "
                 "grid needs; use a smaller grid or fewer modes, or lower memory_limit_gb to what is free\n";
    return 1;
  }
  catch (const std::exception& e)
  {
    std::cerr << "modal_compare: failed: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
