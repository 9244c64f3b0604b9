// The setups a modal_compare run builds from its config and options, each checked (and built
// once) before any experiment runs.
#include "compare_setups.h"

#include "yaml_colliders.h"
#include "yaml_parameter_source.h"

#include "modal_mass_spring/parameter_error.h"
#include "modal_mass_spring/parameters.h"
#include "modal_mass_spring/validation.h"

#include <climits>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <limits>
#include <new>
#include <sstream>
#include <stdexcept>
#include <system_error>

namespace modal_mass_spring::compare
{
namespace
{

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

}  // namespace

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

int handleSteps(const Options& o, const ExperimentSetup& setup, bool move_only)
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

namespace
{

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

// With --reference-time-step, the reference's steps per sample of the setup must fit an int.
void checkReferenceSteps(const Options& o, const ExperimentSetup& setup)
{
  if (!(o.accuracy.reference_time_step > 0.0))
    return;
  const int substeps = referenceSubsteps(setup.sim.time_step, o.accuracy.reference_time_step);
  if (2LL * o.accuracy.sample * substeps > std::numeric_limits<int>::max())
    rejectParameter("--reference-time-step", o.accuracy.reference_time_step,
                    "with --sample " + std::to_string(o.accuracy.sample) + " too many reference steps per sample");
}

// What the accuracy or handles experiment keeps of one setup until its files are written: an error
// sample per run every `sample` steps, every particle of every run every `interval` steps; and while
// it runs, the reference's points for a block of samples.
double resultBytes(const Options& o, const ExperimentSetup& setup, long steps, long interval)
{
  const double runs = o.methods.size() + 1.0 + (o.accuracy.reference_time_step > 0.0 ? 1.0 : 0.0);
  const double samples = static_cast<double>(steps) / o.accuracy.sample + 1.0;
  const double sample_bytes = sizeof(ErrorSample) + 2.0 * setup.variant.size() + 64.0;
  const double points_bytes = 24.0 * setup.grid.rows * setup.grid.cols;
  double bytes = runs * samples * sample_bytes +
                 std::min(static_cast<double>(o.accuracy.reference_block_bytes) + points_bytes, samples * points_bytes);
  if (o.accuracy.snapshots)
    bytes += runs * (static_cast<double>(steps) / interval + 2.0) * (sizeof(Snapshot) + points_bytes);
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

}  // namespace

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
  // `coarse` builds its own grid (cheap): built too, so that its parameters are checked.
  std::vector<Method> builds{method};
  if (std::find(o.methods.begin(), o.methods.end(), Method::Coarse) != o.methods.end())
    builds.push_back(Method::Coarse);
  for (const ExperimentSetup& setup : setups)
    for (Method m : builds)
    {
      try
      {
        build(setup, m);
      }
      catch (const std::invalid_argument& e)
      {
        if (!methods_may_fail || m == Method::Full)
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
    checkReferenceSteps(o, setup);
  }
  checkResultMemory(o, handle_setups, result_bytes);
}

void validate(const Options& o, const std::vector<ExperimentSetup>& setups)
{
  if (!o.runs("cost") && !o.runs("accuracy") && !o.runs("stability"))
    return;
  for (const ExperimentSetup& setup : setups)
  {
    validateSetup(o, setup, setup.grid, "");
    if (o.runs("accuracy"))
      checkReferenceSteps(o, setup);
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

namespace
{

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

}  // namespace

void checkOutputNames(const Options& o)
{
  for (const std::string& name : outputNames(o))
    if (name.size() > NAME_MAX)
      rejectParameter("--tag", "'" + o.tag + "'",
                      "makes the file name '" + name + "' " + std::to_string(name.size()) + " characters long, above " +
                          std::to_string(NAME_MAX) + "; use a shorter --tag (default: the config file's stem)");
}

void prepareOutput(const Options& o)
{
  std::error_code ec;
  std::filesystem::create_directories(o.output, ec);
  if (ec || !std::filesystem::is_directory(o.output))
    rejectParameter("--output", "'" + o.output + "'", "cannot create the folder" + (ec ? ": " + ec.message() : ""));
  const std::filesystem::path probe = std::filesystem::path(o.output) / (".modal_compare_write_test_" + std::to_string(getpid()));
  const bool writable = static_cast<bool>(std::ofstream(probe));
  std::filesystem::remove(probe, ec);
  if (!writable)
    rejectParameter("--output", "'" + o.output + "'", "the folder is not writable");
}

}  // namespace modal_mass_spring::compare
