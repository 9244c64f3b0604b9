// modal_compare's command line (compare_options.h).
#include "compare_options.h"

#include "modal_mass_spring/parameter_error.h"

#include <cctype>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <iomanip>
#include <iostream>
#include <map>
#include <set>
#include <sstream>
#include <stdexcept>

namespace modal_mass_spring::compare
{
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
  --methods LIST        comma-separated of full, linear, physical, cubature, coarse, adaptive (default: the first four;
                        adaptive: adaptive_method stepped while its error indicator allows, full
                        where it does not (error_tolerance, adaptive_dwell), in every experiment;
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
              --coarse-step-multiple K (0, the default: `coarse`, and `adaptive`'s reduced steps on it,
                step time_step times the square root of
                the fine particles per coarse one, rounded down (explicit: at most 2 / (alpha time_step)),
                or the largest smaller number that divides --sample; K >= 1: K time steps, K dividing
                --sample)
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
      rejectParameter("--methods", "'" + name + "'", "unknown method: must be one of " + methodList() + ", adaptive");
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
      {"--coarse-step-multiple",
       [](Options& o, const std::string& v) {
         o.accuracy.coarse_step_multiple = parseInt("--coarse-step-multiple", v, 0, 100000000);
       }},
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
  if (o.accuracy.coarse_step_multiple > 0 && o.accuracy.sample % o.accuracy.coarse_step_multiple != 0)
    rejectParameter("--coarse-step-multiple", o.accuracy.coarse_step_multiple,
                    "must be 0 (automatic) or divide --sample " + std::to_string(o.accuracy.sample));
  if (o.check_factor > 0.0 && !o.runs("stability"))
    rejectParameter("--check-factor", o.check_factor, "needs the stability experiment");
  checkStabilityOptions(o.stability);
  o.accuracy.methods = o.methods;
  o.accuracy.adaptive = o.adaptive;
  o.stability.methods = o.methods;
  o.stability.adaptive = o.adaptive;
  o.cost.methods = o.methods;
  o.cost.adaptive = o.adaptive;
  if (o.tag.empty())
    setTag(o, std::filesystem::path(o.config).stem().string());
}

}  // namespace

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

std::string fmt(double value, int precision)
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

}  // namespace modal_mass_spring::compare
