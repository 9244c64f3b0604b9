// Where a step's time goes: builds one method on a config's first handle scenario (its colliders
// too), steps it `--skip` steps, then `--steps` more, and reports the thread's CPU time per step of
// the second stretch. Under callgrind, only that stretch is instrumented (run with --instr-atstart=no
// and --toggle-collect on Simulation::step), so setup and the skipped steps cost no instructions:
//   valgrind --tool=callgrind --instr-atstart=no --collect-atstart=no
//     '--toggle-collect=modal_mass_spring::Simulation::step(int)'
//     step_breakdown --config FILE --method cubature --skip 800 --steps 200 [--set key=value ...]
// docs/benchmarks.md, "Where a reduced step's time goes", reads the inclusive costs per function.
#include "experiments.h"
#include "handle_scenarios.h"
#include "yaml_colliders.h"
#include "yaml_parameter_source.h"

#include "modal_mass_spring/cache.h"
#include "modal_mass_spring/options.h"
#include "modal_mass_spring/parameters.h"
#include "modal_mass_spring/simulation.h"

#include <valgrind/callgrind.h>

#include <algorithm>
#include <cstdio>
#include <iostream>
#include <stdexcept>
#include <string>
#include <vector>

using namespace modal_mass_spring;

namespace
{

int run(int argc, char** argv)
{
  std::string config, method = "cubature";
  int skip = 0, steps = 200;
  std::vector<std::pair<std::string, std::string>> sets;
  for (int i = 1; i < argc; ++i)
  {
    const std::string arg = argv[i];
    if (i + 1 >= argc)
      throw std::invalid_argument("option " + arg + " needs a value");
    const std::string value = argv[++i];
    if (arg == "--config")
      config = value;
    else if (arg == "--method")
      method = value;
    else if (arg == "--skip")
      skip = std::stoi(value);
    else if (arg == "--steps")
      steps = std::stoi(value);
    else if (arg == "--set")
    {
      const size_t eq = value.find('=');
      if (eq == std::string::npos)
        throw std::invalid_argument("--set must be KEY=VALUE, got '" + value + "'");
      sets.emplace_back(value.substr(0, eq), value.substr(eq + 1));
    }
    else
      throw std::invalid_argument("unknown option " + arg);
  }
  if (config.empty() || skip < 0 || steps < 1)
    throw std::invalid_argument("need --config FILE, --skip >= 0 and --steps >= 1");

  YamlParameterSource source = YamlParameterSource::fromFile(config);
  for (const auto& [key, value] : sets)
    source.set(key, value);
  source.set("method", method);
  GridParams grid = loadGridParams(source);
  SimulationParams params = loadSimulationParams(source);
  if (const YAML::Node node = source.getNode("colliders"); node.IsDefined())
    params.colliders = parseColliders(node, "colliders");
  const YAML::Node scenarios_node = source.getNode("handle_scenarios");
  if (!scenarios_node.IsDefined())
    throw std::invalid_argument("config '" + config + "' has no handle_scenarios");
  const HandleScenario scenario = parseHandleScenarios(scenarios_node, "handle_scenarios").front();
  grid = gridWithHandles(grid, scenario);
  params.handles_one_body = scenario.handles.size() == 1;  // as modal_compare's handles experiment

  CacheOptions cache;
  cache.directory = defaultCacheDirectory();
  Simulation sim(grid, params, StageFn{}, cache);
  const HandleDriver driver(scenario, sim);
  // The deepest any free particle lies inside a collider (m): a contact sample corrects only some.
  double deepest = 0.0;
  auto measureDepth = [&] {
    const Contact* contact = sim.contact();
    if (!contact)
      return;
    const Eigen::VectorXd x = sim.positions();
    Eigen::Vector3d normal;
    for (int p = 0; p < sim.grid().numParticles(); ++p)
    {
      if (sim.grid().isFixed(p) || sim.grid().isHandle(p))
        continue;
      const Eigen::Vector3d at = x.segment<3>(3 * p);
      for (int c = 0; c < static_cast<int>(contact->colliders().size()); ++c)
        if (contact->active(c))
          deepest = std::max(deepest, -signedDistance(contact->colliders()[c], contact->pose(c), at, normal));
    }
  };
  double cpu = 0.0;
  auto advance = [&](int count, long& newton, bool measured) {
    for (int k = 0; k < count; ++k)
    {
      const double start = threadCpuSeconds();
      driver.drive(sim);
      const StepResult r = sim.step();
      cpu += threadCpuSeconds() - start;
      if (r.diverged)
        throw std::runtime_error(r.message);
      newton += sim.lastNewtonIterations();
      if (measured)
        measureDepth();
    }
  };
  long newton = 0;
  advance(skip, newton, false);
  newton = 0;
  cpu = 0.0;
  CALLGRIND_START_INSTRUMENTATION;
  advance(steps, newton, true);
  CALLGRIND_STOP_INSTRUMENTATION;
  std::printf("method %s, %d particles, r = %d, steps %d..%d (t = %.3f s), CPU per step %.3f ms, "
              "Newton iterations per step %.2f",
              method.c_str(), sim.grid().numParticles(), static_cast<int>(sim.physicalBasis().phi.cols()), skip,
              skip + steps, sim.time(), 1e3 * cpu / steps, static_cast<double>(newton) / steps);
  if (const Contact* contact = sim.contact())
  {
    int touching = 0;
    for (int t : contact->report().touching)
      touching += t;
    std::printf(", touching %d, deepest after correction %.2f mm, of every particle %.2f mm", touching,
                1e3 * contact->report().penetration_after, 1e3 * deepest);
  }
  std::printf("\n");
  return 0;
}

}  // namespace

int main(int argc, char** argv)
{
  try
  {
    return run(argc, argv);
  }
  catch (const std::exception& e)
  {
    std::cerr << "step_breakdown: " << e.what() << "\n";
    return 2;
  }
}
