// A coarse grid as the reduced model: the same cloth (width, total mass, spring constants, colliders,
// contact thickness in metres) at fewer particles, simulated by `full`, its positions bilinearly
// interpolated in the grid's material coordinates onto the fine grid's particles, and compared with a
// converged explicit `full` on the fine grid over a config's first handle scenario. The scenario's
// handles are mapped to the coarse particles whose interpolation covers the fine handle particles.
//   coarse_grid_accuracy --config FILE --coarse 25x25 [--coarse 17x17 ...] --reference-step 0.0001
//     [--sample 0.05] [--implicit-step 0.005] [--explicit-from 0.0005] [--handle-map cover|nearest]
//     [--hold SECONDS] [--series K] [--set key=value ...]
// prints one row per run: mean and largest RMS distance over the fine grid's free particles to the
// reference (the mean also split where the reference stops being converged), the deepest of them
// inside a collider, their mean y at the end, and the thread's CPU per simulated second (of the steps
// and the handles' motion only). Each grid's explicit step is its largest stable one of the form
// sample / n, searched from --explicit-from up. --handle-map nearest holds the coarse particle nearest
// each fine handle particle instead of those covering it; --hold replaces the scenario's hold time;
// --series K prints every K-th sample's RMS distance and mean y after each row. For callgrind, one
// run alone with only its steps instrumented:
//   valgrind --tool=callgrind --instr-atstart=no coarse_grid_accuracy --config FILE --only 25x25
//     --integrator explicit --step 0.002 [--until 2.0]
// docs/benchmarks.md, "A coarse grid as the reduced model: accuracy and cost", has the figures.
#include "experiments.h"
#include "handle_scenarios.h"
#include "yaml_colliders.h"
#include "yaml_parameter_source.h"

#include "modal_mass_spring/cache.h"
#include "modal_mass_spring/contact.h"
#include "modal_mass_spring/options.h"
#include "modal_mass_spring/parameters.h"
#include "modal_mass_spring/simulation.h"

#include <valgrind/callgrind.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <limits>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

using namespace modal_mass_spring;

namespace
{

// The scene: the fine grid, its parameters and its scenario as the config gives them.
struct Scene
{
  GridParams grid;
  SimulationParams sim;
  HandleScenario scenario;
};

// A grid's size, rows x cols.
struct GridSize
{
  int rows = 0, cols = 0;
};

GridSize parseSize(const std::string& text)
{
  const size_t x = text.find('x');
  GridSize size;
  try
  {
    if (x == std::string::npos)
      throw std::invalid_argument("");
    size.rows = std::stoi(text.substr(0, x));
    size.cols = std::stoi(text.substr(x + 1));
  }
  catch (const std::exception&)
  {
    throw std::invalid_argument("a grid size must be ROWSxCOLS (e.g. 25x25), got '" + text + "'");
  }
  if (size.rows < 2 || size.cols < 2)
    throw std::invalid_argument("a grid size needs at least 2 rows and 2 columns, got '" + text + "'");
  return size;
}

// Where fine particle (row, col) lies on the coarse grid, in coarse index units: the same material
// point, since both grids span the same sheet.
double coarseCoordinate(int fine_index, int fine_count, int coarse_count)
{
  return static_cast<double>(fine_index) * (coarse_count - 1) / (fine_count - 1);
}

// One fine particle's bilinear interpolation: four coarse particles and their weights.
struct Stencil
{
  int particle[4];
  double weight[4];
};

std::vector<Stencil> interpolationStencils(const GridParams& fine, const GridSize& coarse)
{
  std::vector<Stencil> stencils(static_cast<size_t>(fine.rows) * fine.cols);
  for (int r = 0; r < fine.rows; ++r)
    for (int c = 0; c < fine.cols; ++c)
    {
      const double v = coarseCoordinate(r, fine.rows, coarse.rows);
      const double u = coarseCoordinate(c, fine.cols, coarse.cols);
      // The cell's lower corner, kept inside the grid so the last row and column interpolate too.
      const int r0 = std::min(static_cast<int>(std::floor(v)), coarse.rows - 2);
      const int c0 = std::min(static_cast<int>(std::floor(u)), coarse.cols - 2);
      const double tv = v - r0, tu = u - c0;
      Stencil& s = stencils[static_cast<size_t>(r) * fine.cols + c];
      s.particle[0] = r0 * coarse.cols + c0;
      s.particle[1] = r0 * coarse.cols + c0 + 1;
      s.particle[2] = (r0 + 1) * coarse.cols + c0;
      s.particle[3] = (r0 + 1) * coarse.cols + c0 + 1;
      s.weight[0] = (1 - tv) * (1 - tu);
      s.weight[1] = (1 - tv) * tu;
      s.weight[2] = tv * (1 - tu);
      s.weight[3] = tv * tu;
    }
  return stencils;
}

// The coarse grid's positions at the fine grid's particles (3 x fine particles).
Eigen::Matrix3Xd interpolate(const Eigen::Matrix3Xd& coarse_points, const std::vector<Stencil>& stencils)
{
  Eigen::Matrix3Xd fine(3, static_cast<Eigen::Index>(stencils.size()));
  for (size_t p = 0; p < stencils.size(); ++p)
  {
    Eigen::Vector3d x = Eigen::Vector3d::Zero();
    for (int k = 0; k < 4; ++k)
      x += stencils[p].weight[k] * coarse_points.col(stencils[p].particle[k]);
    fine.col(static_cast<Eigen::Index>(p)) = x;
  }
  return fine;
}

// The same cloth on a coarse grid: the width kept (spacing scaled), the total mass kept (mass per
// particle scaled), the spring constants kept (a square mass-spring grid's stretch modulus is k,
// whatever the spacing), the contact thickness kept in metres; the scenario's handles are the coarse
// particles that interpolate a fine handle particle with a weight above round-off (cover), or the
// coarse particle nearest each fine handle particle in material coordinates (nearest).
enum class HandleMap
{
  Cover,
  Nearest
};

Scene coarseScene(const Scene& fine, const GridSize& size, HandleMap map)
{
  const double width = (fine.grid.cols - 1) * fine.grid.spacing;
  const double height = (fine.grid.rows - 1) * fine.grid.spacing;
  const double spacing = width / (size.cols - 1);
  if (std::abs((size.rows - 1) * spacing - height) > 1e-9 * width)
    throw std::invalid_argument("a coarse grid of " + std::to_string(size.rows) + " x " + std::to_string(size.cols) +
                                " particles has another aspect ratio than the fine one's (" +
                                std::to_string(fine.grid.rows) + " x " + std::to_string(fine.grid.cols) +
                                "): one spacing cannot span the same sheet");
  if (!fine.grid.fixed.empty())
    throw std::invalid_argument("the fine config fixes particles (fixed): only handles are mapped to the coarse grid");
  Scene coarse = fine;
  coarse.grid.rows = size.rows;
  coarse.grid.cols = size.cols;
  coarse.grid.spacing = spacing;
  coarse.grid.mass = fine.grid.mass * fine.grid.rows * fine.grid.cols / (static_cast<double>(size.rows) * size.cols);
  coarse.sim.contact_thickness = resolveContactThickness(fine.sim.contact_thickness, fine.grid.spacing);
  const std::vector<Stencil> stencils = interpolationStencils(fine.grid, size);
  std::set<int> taken;
  for (HandlePath& path : coarse.scenario.handles)
  {
    std::set<int> mapped;
    for (int p : path.particles)
    {
      const Stencil& s = stencils[static_cast<size_t>(p)];
      if (map == HandleMap::Nearest)
        mapped.insert(s.particle[std::max_element(s.weight, s.weight + 4) - s.weight]);
      else
        for (int k = 0; k < 4; ++k)
          if (s.weight[k] > 1e-9)
            mapped.insert(s.particle[k]);
    }
    for (int p : mapped)
      if (!taken.insert(p).second)
        throw std::invalid_argument("two handles of the scenario map to coarse particle " + std::to_string(p) +
                                    ": the coarse grid is too coarse to hold them apart");
    path.particles.assign(mapped.begin(), mapped.end());
  }
  return coarse;
}

// One run's outcome: its samples of every particle, and the CPU and steps of the stepping alone.
struct Run
{
  std::vector<Eigen::Matrix3Xd> samples;
  double cpu_seconds = 0.0, simulated_seconds = 0.0, time_step = 0.0;
  long steps = 0, newton_iterations = 0;
  bool diverged = false;
  std::string message;
};

// `full` on a scene with one integrator and step, sampled every `sample` s (a whole number of steps)
// from the start to the scenario's end (or `until`). Under callgrind only the steps and the handles'
// motion are instrumented.
Run runFull(const Scene& scene, IntegratorKind integrator, double dt, double sample, double until = -1.0)
{
  const long per_sample = std::lround(sample / dt);
  if (per_sample < 1 || std::abs(per_sample * dt - sample) > 1e-9 * sample)
    throw std::invalid_argument("the sample interval " + std::to_string(sample) + " s is not a whole number of steps of " +
                                std::to_string(dt) + " s");
  SimulationParams params = scene.sim;
  params.method = Method::Full;
  params.integrator = integrator;
  params.time_step = dt;
  params.handles_one_body = scene.scenario.handles.size() == 1;  // as modal_compare's handles experiment
  const GridParams grid = gridWithHandles(scene.grid, scene.scenario);
  CacheOptions cache;
  cache.directory = defaultCacheDirectory();
  Simulation sim(grid, params, StageFn{}, cache);
  const HandleDriver driver(scene.scenario, sim);
  const double end = until > 0.0 ? until : scene.scenario.duration();
  const long samples = std::lround(std::ceil(end / sample - 1e-9));
  Run run;
  run.time_step = dt;
  run.samples.push_back(sim.points());
  for (long s = 0; s < samples && !run.diverged; ++s)
  {
    CALLGRIND_START_INSTRUMENTATION;
    const double start = threadCpuSeconds();
    for (long k = 0; k < per_sample; ++k)
    {
      driver.drive(sim);
      const StepResult r = sim.step();
      run.newton_iterations += sim.lastNewtonIterations();
      ++run.steps;
      if (r.diverged)
      {
        run.diverged = true;
        run.message = r.message;
        break;
      }
    }
    run.cpu_seconds += threadCpuSeconds() - start;
    CALLGRIND_STOP_INSTRUMENTATION;
    if (!run.diverged)
      run.samples.push_back(sim.points());
  }
  run.simulated_seconds = run.steps * dt;
  return run;
}

// The largest explicit step sample / n (n a whole number) at which `full` runs the whole scenario
// without diverging: n lowered by about 10% from sample / from until a run diverges, then bisected.
int largestStableSubdivision(const Scene& scene, double sample, double from)
{
  int stable = std::max(1, static_cast<int>(std::lround(sample / from)));
  if (runFull(scene, IntegratorKind::Explicit, sample / stable, sample).diverged)
    throw std::runtime_error("explicit `full` diverges already at " + std::to_string(sample / stable) +
                             " s: give a smaller --explicit-from");
  int unstable = 0;
  while (unstable == 0 && stable > 1)
  {
    const int n = std::max(1, static_cast<int>(std::floor(stable / 1.1)));
    if (runFull(scene, IntegratorKind::Explicit, sample / n, sample).diverged)
      unstable = n;
    else
      stable = n;
  }
  while (unstable > 0 && stable - unstable > 1)
  {
    const int n = (stable + unstable) / 2;
    if (runFull(scene, IntegratorKind::Explicit, sample / n, sample).diverged)
      unstable = n;
    else
      stable = n;
  }
  return stable;
}

// Distances of a run's samples (interpolated where the run is coarse) to the reference's, over the
// fine grid's free particles, and the deepest of those points inside a collider. The mean is also
// split at the sample where the reference stops being converged (its half-step run more than 1 mm
// RMS off): a cloth crumpling on a table is sensitive to any change, its step included.
struct Accuracy
{
  double mean_rms = 0.0, max_rms = 0.0, deepest = 0.0;
  double mean_rms_converged = 0.0, mean_rms_after = 0.0;  // before and from that sample
  double final_center_y = 0.0;
  std::vector<double> rms;       // per sample
  std::vector<double> center_y;  // the free particles' mean y per sample: which way the cloth folds
};

// The samples over which the reference is converged (all of them until the half-step check is made).
size_t converged_samples = std::numeric_limits<size_t>::max();

Accuracy compare(const Run& run, const std::vector<Stencil>* stencils, const Run& reference,
                 const std::vector<bool>& free, const std::vector<Collider>& colliders)
{
  Accuracy a;
  const size_t count = std::min(run.samples.size(), reference.samples.size());
  for (size_t s = 0; s < count; ++s)
  {
    const Eigen::Matrix3Xd x = stencils ? interpolate(run.samples[s], *stencils) : run.samples[s];
    double sum = 0.0, y = 0.0;
    int n = 0;
    for (Eigen::Index p = 0; p < x.cols(); ++p)
    {
      if (!free[static_cast<size_t>(p)])
        continue;
      sum += (x.col(p) - reference.samples[s].col(p)).squaredNorm();
      y += x(1, p);
      ++n;
      Eigen::Vector3d normal;
      for (const Collider& c : colliders)
        a.deepest = std::max(a.deepest, -signedDistance(c, c.pose, x.col(p), normal));
    }
    const double rms = std::sqrt(sum / n);
    a.rms.push_back(rms);
    a.center_y.push_back(y / n);
    a.mean_rms += rms / static_cast<double>(count);
    a.max_rms = std::max(a.max_rms, rms);
    (s < converged_samples ? a.mean_rms_converged : a.mean_rms_after) += rms;
  }
  const size_t before = std::min(count, converged_samples);
  a.mean_rms_converged /= static_cast<double>(std::max<size_t>(before, 1));
  a.mean_rms_after = count > before ? a.mean_rms_after / static_cast<double>(count - before) : 0.0;
  a.final_center_y = a.center_y.empty() ? 0.0 : a.center_y.back();
  return a;
}

// With --series, the RMS distance every `every` samples follows each row.
int series_every = 0;

void printRow(const std::string& label, const Run& run, const Accuracy& accuracy)
{
  std::printf("| %s | %.4g ms | %.1f mm | %.1f mm | %.1f mm | %.1f mm | %.2f mm | %.0f mm | %.3g | %.2f |\n",
              label.c_str(), 1e3 * run.time_step, 1e3 * accuracy.mean_rms, 1e3 * accuracy.mean_rms_converged,
              1e3 * accuracy.mean_rms_after, 1e3 * accuracy.max_rms, 1e3 * accuracy.deepest,
              1e3 * accuracy.final_center_y,
              run.cpu_seconds / run.simulated_seconds,
              run.newton_iterations > 0 ? static_cast<double>(run.newton_iterations) / run.steps : 0.0);
  if (series_every > 0)
  {
    std::printf("  RMS (mm) every %d samples:", series_every);
    for (size_t s = 0; s < accuracy.rms.size(); s += static_cast<size_t>(series_every))
      std::printf(" %.1f", 1e3 * accuracy.rms[s]);
    std::printf("\n  mean y (mm):");
    for (size_t s = 0; s < accuracy.center_y.size(); s += static_cast<size_t>(series_every))
      std::printf(" %.1f", 1e3 * accuracy.center_y[s]);
    std::printf("\n");
  }
  std::fflush(stdout);
}

std::string sizeLabel(int rows, int cols)
{
  return std::to_string(rows) + " x " + std::to_string(cols);
}

IntegratorKind parseIntegrator(const std::string& name)
{
  if (name == "explicit")
    return IntegratorKind::Explicit;
  if (name == "implicit")
    return IntegratorKind::Implicit;
  throw std::invalid_argument("--integrator must be explicit or implicit, got '" + name + "'");
}

// A number of an option, or an error naming the option.
double number(const std::string& option, const std::string& value)
{
  try
  {
    size_t used = 0;
    const double x = std::stod(value, &used);
    if (used == value.size() && std::isfinite(x))
      return x;
  }
  catch (const std::exception&)
  {
  }
  throw std::invalid_argument(option + " must be a finite number, got '" + value + "'");
}

int run(int argc, char** argv)
{
  std::string config, only, integrator = "explicit";
  std::vector<GridSize> coarse_sizes;
  double hold = -1.0;
  HandleMap handle_map = HandleMap::Cover;
  double reference_step = 0.0, sample = 0.05, implicit_step = 0.005, explicit_from = 0.0005, step = 0.0, until = -1.0;
  std::vector<std::pair<std::string, std::string>> sets;
  for (int i = 1; i < argc; ++i)
  {
    const std::string arg = argv[i];
    if (i + 1 >= argc)
      throw std::invalid_argument("option " + arg + " needs a value");
    const std::string value = argv[++i];
    if (arg == "--config")
      config = value;
    else if (arg == "--coarse")
      coarse_sizes.push_back(parseSize(value));
    else if (arg == "--reference-step")
      reference_step = number(arg, value);
    else if (arg == "--sample")
      sample = number(arg, value);
    else if (arg == "--implicit-step")
      implicit_step = number(arg, value);
    else if (arg == "--explicit-from")
      explicit_from = number(arg, value);
    else if (arg == "--only")
      only = value;
    else if (arg == "--integrator")
      integrator = value;
    else if (arg == "--step")
      step = number(arg, value);
    else if (arg == "--handle-map")
    {
      if (value != "cover" && value != "nearest")
        throw std::invalid_argument("--handle-map must be cover or nearest, got '" + value + "'");
      handle_map = value == "cover" ? HandleMap::Cover : HandleMap::Nearest;
    }
    else if (arg == "--hold")
    {
      hold = number(arg, value);
      if (hold < 0.0)
        throw std::invalid_argument("--hold must be >= 0 s, got '" + value + "'");
    }
    else if (arg == "--series")
    {
      series_every = static_cast<int>(number(arg, value));
      if (series_every < 1)
        throw std::invalid_argument("--series must be a whole number >= 1, got '" + value + "'");
    }
    else if (arg == "--until")
      until = number(arg, value);
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
  if (config.empty())
    throw std::invalid_argument("need --config FILE");
  if (!(sample > 0.0) || !(implicit_step > 0.0) || !(explicit_from > 0.0))
    throw std::invalid_argument("--sample, --implicit-step and --explicit-from must be > 0 s");

  YamlParameterSource source = YamlParameterSource::fromFile(config);
  for (const auto& [key, value] : sets)
    source.set(key, value);
  source.set("method", "full");
  Scene fine;
  fine.grid = loadGridParams(source);
  fine.sim = loadSimulationParams(source);
  if (fine.grid.dimension != 3)
    throw std::invalid_argument("config '" + config + "' is 2D: the coarse grid's interpolation is written for 3D grids");
  if (const YAML::Node node = source.getNode("colliders"); node.IsDefined())
    fine.sim.colliders = parseColliders(node, "colliders");
  const YAML::Node scenarios_node = source.getNode("handle_scenarios");
  if (!scenarios_node.IsDefined())
    throw std::invalid_argument("config '" + config + "' has no handle_scenarios");
  fine.scenario = parseHandleScenarios(scenarios_node, "handle_scenarios").front();
  if (hold >= 0.0)
    fine.scenario.hold_time = hold;

  if (!only.empty())  // one run alone, for callgrind
  {
    if (!(step > 0.0))
      throw std::invalid_argument("--only needs --step > 0 s");
    const Scene scene = only == "fine" ? fine : coarseScene(fine, parseSize(only), handle_map);
    const Run r = runFull(scene, parseIntegrator(integrator), step, sample, until);
    std::printf("%s, %s %.4g ms: %ld steps, %.3f simulated s%s, CPU per simulated second %.3g\n", only.c_str(),
                integrator.c_str(), 1e3 * step, r.steps, r.simulated_seconds,
                r.diverged ? (", diverged: " + r.message).c_str() : "", r.cpu_seconds / r.simulated_seconds);
    return r.diverged ? 1 : 0;
  }

  if (!(reference_step > 0.0))
    throw std::invalid_argument("need --reference-step > 0 s (the converged explicit `full` on the fine grid)");
  // Every coarse grid checked before the fine runs.
  std::vector<Scene> coarse_scenes;
  for (const GridSize& size : coarse_sizes)
  {
    coarse_scenes.push_back(coarseScene(fine, size, handle_map));
    gridWithHandles(coarse_scenes.back().grid, coarse_scenes.back().scenario);
  }
  const GridParams fine_held = gridWithHandles(fine.grid, fine.scenario);
  std::vector<bool> free(static_cast<size_t>(fine.grid.rows) * fine.grid.cols, true);
  for (const auto& handle : fine_held.handles)
    for (int p : handle)
      free[static_cast<size_t>(p)] = false;

  std::printf("%s: %s, spacing %.4g m, %s, sampled every %.3g s over %.3g s\n", config.c_str(),
              sizeLabel(fine.grid.rows, fine.grid.cols).c_str(), fine.grid.spacing, fine.scenario.name.c_str(), sample,
              fine.scenario.duration());
  std::printf("| grid, integrator | step | mean RMS | mean RMS while the reference converges | mean RMS after | "
              "largest RMS | deepest inside a collider | mean y at the end | CPU s per simulated s | Newton iterations "
              "a step |\n|---|---|---|---|---|---|---|---|---|---|\n");
  const Run reference = runFull(fine, IntegratorKind::Explicit, reference_step, sample);
  if (reference.diverged)
    throw std::runtime_error("the reference diverged: " + reference.message);
  printRow(sizeLabel(fine.grid.rows, fine.grid.cols) + ", reference explicit", reference,
           compare(reference, nullptr, reference, free, fine.sim.colliders));
  const Run half = runFull(fine, IntegratorKind::Explicit, reference_step / 2, sample);
  const Accuracy check = compare(half, nullptr, reference, free, fine.sim.colliders);
  converged_samples = static_cast<size_t>(
      std::find_if(check.rms.begin(), check.rms.end(), [](double rms) { return rms > 1e-3; }) - check.rms.begin());
  printRow(sizeLabel(fine.grid.rows, fine.grid.cols) + ", explicit at half the reference's step", half,
           compare(half, nullptr, reference, free, fine.sim.colliders));

  std::printf("| the half-step run within 1 mm RMS of the reference up to t = %.3g s |\n",
              sample * static_cast<double>(converged_samples - 1));

  // The fine grid's own `full` at its cheapest: explicit at its largest stable step, implicit.
  auto both = [&](const Scene& scene, const std::vector<Stencil>* stencils, const std::string& label) {
    const int n = largestStableSubdivision(scene, sample, explicit_from);
    const Run exp = runFull(scene, IntegratorKind::Explicit, sample / n, sample);
    printRow(label + ", explicit (largest stable)", exp, compare(exp, stencils, reference, free, fine.sim.colliders));
    const Run imp = runFull(scene, IntegratorKind::Implicit, implicit_step, sample);
    if (imp.diverged)
      std::printf("| %s, implicit diverged at t = %.3f s: %s |\n", label.c_str(), imp.simulated_seconds,
                  imp.message.c_str());
    else
      printRow(label + ", implicit", imp, compare(imp, stencils, reference, free, fine.sim.colliders));
  };
  both(fine, nullptr, sizeLabel(fine.grid.rows, fine.grid.cols));
  for (size_t i = 0; i < coarse_sizes.size(); ++i)
  {
    const GridSize& size = coarse_sizes[i];
    const Scene& coarse = coarse_scenes[i];
    const std::vector<Stencil> stencils = interpolationStencils(fine.grid, size);
    std::printf("| %s: spacing %.4g m, mass %.4g kg, handle particles %zu |\n", sizeLabel(size.rows, size.cols).c_str(),
                coarse.grid.spacing, coarse.grid.mass, coarse.scenario.handles.front().particles.size());
    both(coarse, &stencils, sizeLabel(size.rows, size.cols));
  }
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
    std::cerr << "coarse_grid_accuracy: " << e.what() << "\n";
    return 2;
  }
}
