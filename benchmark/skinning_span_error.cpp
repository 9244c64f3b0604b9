// Span or dynamics: how far `physical` on the skinning subspace is from the converged `full` of a
// handle scenario, next to how far the subspace's best pose is. At every sample the reference's free
// particles are projected onto what `physical` can reach, x_ref + Psi dx_b + Phi q with the handles
// where they are (q = Phi^T M (u - Psi dx_b), the M-weighted least squares since Phi^T M Phi = I), and
// the RMS distance of the free particles of that pose is printed beside `physical`'s own, for each
// number of weights. Optionally also: `full` at the setup's step, `full` perturbed at one instant (how
// sensitive the motion itself is), and `physical` restarted from the projection of the reference at
// one instant (how fast the reduced dynamics leave the best pose), and the reference continued from
// `physical`'s state at one instant (whether `full` itself would go where `physical` goes from there).
//   skinning_span_error --config FILE --scenario NAME [--weights 24,48,96,192] [--set key=value ...]
//     [--sample 10] [--reference-time-step 0.0001] [--perturb-time 0.4 --perturb dx,dy,dz]
//     [--restart-time 0.4] [--handover-time 1.2] [--off-plane axis] [--energy 1] [--every k]
// (--perturb moves every free dof by its axis' component, in the grid's dof order: x, y, z in 3D.)
#include "handle_scenarios.h"
#include "yaml_parameter_source.h"

#include "modal_mass_spring/parameters.h"
#include "modal_mass_spring/simulation.h"
#include "modal_mass_spring/spring_forces.h"

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

using namespace modal_mass_spring;

namespace
{

struct Args
{
  std::string config, scenario;
  std::vector<int> weights{24, 48, 96, 192};
  std::vector<std::pair<std::string, std::string>> sets;
  int sample = 10;
  double reference_time_step = 1e-4;
  double perturb_time = -1.0;
  Eigen::Vector3d perturb = Eigen::Vector3d::Zero();
  double restart_time = -1.0;
  double handover_time = -1.0;
  int every = 1;  // print every k-th sample
  bool energy = false;  // also the spring energy of the reference, each best pose and each run (mJ)
  int normal_axis = -1;  // >= 0: also the RMS distance of the reference's and physical's free particles off their start along this axis
};

// A number of option `key`, the whole text read; throws std::invalid_argument naming the option.
double number(const std::string& key, const std::string& text)
{
  size_t used = 0;
  double v = 0.0;
  try
  {
    v = std::stod(text, &used);
  }
  catch (const std::exception&)
  {
    used = 0;
  }
  if (used == 0 || used != text.size() || !std::isfinite(v))
    throw std::invalid_argument(key + " '" + text + "': not a finite number");
  return v;
}

int whole(const std::string& key, const std::string& text, int lowest)
{
  const double v = number(key, text);
  if (v != std::floor(v) || v < lowest || v > 1e6)
    throw std::invalid_argument(key + " '" + text + "': must be a whole number in [" + std::to_string(lowest) + ", 1e6]");
  return static_cast<int>(v);
}

std::vector<std::string> items(const std::string& text)
{
  std::vector<std::string> out;
  std::stringstream in(text);
  std::string item;
  while (std::getline(in, item, ','))
    out.push_back(item);
  return out;
}

Args parse(int argc, char** argv)
{
  Args a;
  for (int i = 1; i < argc; ++i)
  {
    const std::string key = argv[i];
    if (i + 1 >= argc)
      throw std::invalid_argument(key + ": needs a value");
    const std::string value = argv[++i];
    if (key == "--config")
      a.config = value;
    else if (key == "--scenario")
      a.scenario = value;
    else if (key == "--weights")
    {
      a.weights.clear();
      for (const std::string& w : items(value))
        a.weights.push_back(whole(key, w, 1));
      if (a.weights.empty())
        throw std::invalid_argument(key + " '" + value + "': expected numbers of weights, e.g. 24,48");
    }
    else if (key == "--set")
    {
      const size_t eq = value.find('=');
      if (eq == std::string::npos)
        throw std::invalid_argument("--set '" + value + "': expected key=value");
      a.sets.emplace_back(value.substr(0, eq), value.substr(eq + 1));
    }
    else if (key == "--sample")
      a.sample = whole(key, value, 1);
    else if (key == "--reference-time-step")
      a.reference_time_step = number(key, value);
    else if (key == "--perturb-time")
    {
      a.perturb_time = number(key, value);
      if (a.perturb_time < 0.0)
        throw std::invalid_argument(key + " '" + value + "': a time >= 0 (s) of the scenario");
    }
    else if (key == "--perturb")
    {
      const std::vector<std::string> v = items(value);
      if (v.size() != 3)
        throw std::invalid_argument(key + " '" + value + "': expected dx,dy,dz (m)");
      a.perturb = Eigen::Vector3d(number(key, v[0]), number(key, v[1]), number(key, v[2]));
    }
    else if (key == "--restart-time")
    {
      a.restart_time = number(key, value);
      if (a.restart_time < 0.0)
        throw std::invalid_argument(key + " '" + value + "': a time >= 0 (s) of the scenario");
    }
    else if (key == "--handover-time")
    {
      a.handover_time = number(key, value);
      if (a.handover_time < 0.0)
        throw std::invalid_argument(key + " '" + value + "': a time >= 0 (s) of the scenario");
    }
    else if (key == "--energy")
    {
      if (value != "0" && value != "1")
        throw std::invalid_argument(key + " '" + value + "': 0 or 1");
      a.energy = value == "1";
    }
    else if (key == "--off-plane")
      a.normal_axis = whole(key, value, 0);
    else if (key == "--every")
      a.every = whole(key, value, 1);
    else
      throw std::invalid_argument("unknown option '" + key + "'");
  }
  if (a.config.empty() || a.scenario.empty())
    throw std::invalid_argument("--config and --scenario are required");
  if (!(a.reference_time_step > 0.0))
    throw std::invalid_argument("--reference-time-step must be > 0 (s)");
  if (a.normal_axis > 2)
    throw std::invalid_argument("--off-plane " + std::to_string(a.normal_axis) + ": an axis 0, 1 or 2 (x, y, z)");
  return a;
}

// RMS over the free particles of their distance from where they start along one axis: how far a
// sheet that starts in a plane has left it.
double rmsOffPlane(const Grid& grid, const Eigen::VectorXd& x, int axis)
{
  const int dim = grid.dimension();
  double sum2 = 0.0;
  int count = 0;
  for (int k : grid.freeDofs())
    if (k % dim == axis)
    {
      sum2 += std::pow(x[k] - grid.initialPositions()[k], 2);
      ++count;
    }
  return count ? std::sqrt(sum2 / count) : 0.0;
}

// RMS distance over the free particles (neither fixed nor held) of two all-dof position vectors.
double rmsFree(const Grid& grid, const Eigen::VectorXd& a, const Eigen::VectorXd& b)
{
  const Eigen::VectorXd d = grid.gatherFree(a - b);
  const int dim = grid.dimension();
  return std::sqrt(d.squaredNorm() / (d.size() / dim));
}

// One simulation and what drives its handles.
struct Run
{
  std::string name;
  std::unique_ptr<Simulation> sim;
  std::unique_ptr<HandleDriver> driver;
  int substeps = 1;  // steps per setup step
  bool diverged = false;
  void advance(int steps)
  {
    for (int k = 0; k < steps * substeps && !diverged; ++k)
    {
      driver->drive(*sim);
      diverged = sim->step().diverged;
    }
  }
};

// The positions of `physical`'s best pose for the reference's positions x: the handles where they are,
// the free dofs x_ref + Psi dx_b + Phi Phi^T M (x - x_ref - Psi dx_b).
Eigen::VectorXd bestPose(const Simulation& modal, const Eigen::VectorXd& x)
{
  const Grid& grid = modal.grid();
  const Eigen::VectorXd& x_ref = modal.linearizationPositions();
  const Eigen::MatrixXd& phi = modal.physicalBasis().phi;
  Eigen::VectorXd mass(grid.numFreeDofs());
  for (int k = 0; k < mass.size(); ++k)
    mass[k] = grid.particleMass();  // M is the particle mass on every dof
  Eigen::VectorXd carried = Eigen::VectorXd::Zero(grid.numFreeDofs());
  // (The handles' motion is empty while they rest at the linearization point.)
  if (grid.numHandleDofs() > 0 && modal.handleMotion().displacement.size() > 0)
    carried = modal.skinningConstraintModes() * modal.handleMotion().displacement;
  const Eigen::VectorXd rest = grid.gatherFree(x - x_ref) - carried;
  const Eigen::VectorXd free = carried + phi * (phi.transpose() * mass.cwiseProduct(rest));
  Eigen::VectorXd out = x;  // the handles (and fixed particles) where the reference has them
  for (int k = 0; k < free.size(); ++k)
    out[grid.freeDofs()[k]] = x_ref[grid.freeDofs()[k]] + free[k];
  return out;
}

// Puts `sim` at the reference's free positions and velocities (its own linearization point's
// displacement); the handles are where both were driven.
void takeState(Simulation& sim, const Simulation& reference)
{
  const Grid& grid = sim.grid();
  sim.setPhysicalState(grid.gatherFree(reference.positions() - sim.linearizationPositions()), reference.velocity());
}

struct Column
{
  std::string name;
  double sum = 0.0, max = 0.0;
  int count = 0;
  void add(double v)
  {
    sum += v;
    max = std::max(max, v);
    ++count;
  }
};

}  // namespace

int main(int argc, char** argv)
{
  try
  {
    const Args args = parse(argc, argv);
    YamlParameterSource source = YamlParameterSource::fromFile(args.config);
    for (const auto& [key, value] : args.sets)
      source.set(key, value);
    GridParams grid_params = loadGridParams(source);
    SimulationParams sim_params = loadSimulationParams(source);
    const std::vector<HandleScenario> scenarios = parseHandleScenarios(source.getNode("handle_scenarios"), "handle_scenarios");
    const HandleScenario* scenario = nullptr;
    for (const HandleScenario& s : scenarios)
      if (s.name == args.scenario)
        scenario = &s;
    if (!scenario)
      throw std::invalid_argument("no handle scenario '" + args.scenario + "' in " + args.config);
    grid_params = gridWithHandles(grid_params, *scenario);
    sim_params.handles_one_body = scenario->handles.size() == 1;

    const double dt = sim_params.time_step;
    const int substeps = static_cast<int>(std::lround(dt / args.reference_time_step));
    if (substeps < 1 || std::abs(substeps * args.reference_time_step - dt) > 1e-9 * dt)
      throw std::invalid_argument("--reference-time-step must divide time_step");
    const long steps = static_cast<long>(std::ceil(std::ceil(scenario->duration() / dt - 1e-9) / args.sample)) * args.sample;
    const long perturb_step = args.perturb_time >= 0.0 ? std::lround(args.perturb_time / dt) : -1;
    const long restart_step = args.restart_time >= 0.0 ? std::lround(args.restart_time / dt) : -1;
    const long handover_step = args.handover_time >= 0.0 ? std::lround(args.handover_time / dt) : -1;
    for (const auto& [name, at] : {std::pair<const char*, long>{"--perturb-time", perturb_step},
                                   {"--restart-time", restart_step}, {"--handover-time", handover_step}})
      if (at > steps)
        throw std::invalid_argument(std::string(name) + ": after the scenario's end (" + std::to_string(steps * dt) + " s)");
    if (args.normal_axis >= grid_params.dimension)
      throw std::invalid_argument("--off-plane: axis " + std::to_string(args.normal_axis) + " of a " +
                                  std::to_string(grid_params.dimension) + "D grid");

    // The reference as modal_compare's: `full`, explicit, linearized at rest, handles in the world.
    SimulationParams ref_params = sim_params;
    ref_params.method = Method::Full;
    ref_params.integrator = IntegratorKind::Explicit;
    ref_params.linearization = Linearization::Rest;
    ref_params.handle_formulation = HandleFormulation::ConstraintModes;
    ref_params.basis = BasisKind::LinearModes;
    ref_params.num_skinning_weights = 0;
    ref_params.time_step = args.reference_time_step;

    std::vector<Run> runs;
    auto add = [&](const std::string& name, const SimulationParams& p, int sub) {
      Run r;
      r.name = name;
      r.sim = std::make_unique<Simulation>(grid_params, p);
      r.driver = std::make_unique<HandleDriver>(*scenario, *r.sim);
      r.substeps = sub;
      runs.push_back(std::move(r));
    };
    add("reference", ref_params, substeps);
    SimulationParams full_params = sim_params;
    full_params.method = Method::Full;
    add("full", full_params, 1);
    const bool perturbed = args.perturb_time >= 0.0;
    if (perturbed)
      add("perturbed", ref_params, substeps);
    const size_t first_modal = runs.size();
    for (int w : args.weights)
    {
      SimulationParams p = sim_params;
      p.method = Method::Physical;
      p.basis = BasisKind::Skinning;
      p.num_skinning_weights = w;
      add("physical_" + std::to_string(w), p, 1);
      std::fprintf(stderr, "%d weights: %s\n", w, describeSkinning(runs.back().sim->skinningInfo()).c_str());
    }
    const size_t num_physical = runs.size() - first_modal;
    if (args.restart_time >= 0.0)
      for (size_t k = 0; k < num_physical; ++k)
      {
        SimulationParams p = runs[first_modal + k].sim->params();
        add("restart_" + std::to_string(args.weights[k]), p, 1);
      }
    const size_t first_handover = runs.size();
    if (args.handover_time >= 0.0)
      for (int w : args.weights)
        add("handover_" + std::to_string(w), ref_params, substeps);

    const Grid& grid = runs[0].sim->grid();
    std::vector<Column> columns;
    std::printf("# %s, %s, %zu sample(s) of %d steps of %g s, reference at %g s\n", args.config.c_str(),
                args.scenario.c_str(), static_cast<size_t>(steps / args.sample), args.sample, dt,
                args.reference_time_step);
    std::printf("# RMS distance of the free particles to the reference, mm: span_W the best pose of W weights' "
                "span, physical_W its run%s%s%s\n",
                perturbed ? ", perturbed the reference moved at --perturb-time" : "",
                args.restart_time >= 0.0 ? ", restart_W physical started from span_W's pose at --restart-time" : "",
                args.handover_time >= 0.0 ? ", handover_W the reference continued from physical_W's state at --handover-time" : "");
    std::printf("%8s %9s", "t", "full");
    columns.push_back({"full"});
    if (perturbed)
    {
      std::printf(" %9s", "perturbed");
      columns.push_back({"perturbed"});
    }
    for (int w : args.weights)
    {
      std::printf(" %9s %11s", ("span_" + std::to_string(w)).c_str(), ("physical_" + std::to_string(w)).c_str());
      columns.push_back({"span_" + std::to_string(w)});
      columns.push_back({"physical_" + std::to_string(w)});
    }
    for (const char* kind : {"restart_", "handover_"})
      if ((kind[0] == 'r' ? args.restart_time : args.handover_time) >= 0.0)
        for (int w : args.weights)
        {
          std::printf(" %11s", (kind + std::to_string(w)).c_str());
          columns.push_back({kind + std::to_string(w)});
        }
    if (args.normal_axis >= 0)
    {
      std::printf(" %9s", "off_ref");
      columns.push_back({"off_ref"});
      for (int w : args.weights)
      {
        std::printf(" %9s", ("off_" + std::to_string(w)).c_str());
        columns.push_back({"off_" + std::to_string(w)});
      }
    }
    if (args.energy)
    {
      std::printf(" %9s", "E_ref");
      columns.push_back({"E_ref"});
      for (int w : args.weights)
        for (const char* kind : {"E_span_", "E_phys_"})
        {
          std::printf(" %9s", (kind + std::to_string(w)).c_str());
          columns.push_back({kind + std::to_string(w)});
        }
    }
    std::printf("\n");
    if (args.normal_axis >= 0 || args.energy)
      std::printf("# off_*: RMS distance (mm) of the free particles from their start along axis %d; E_*: spring "
                  "energy (mJ) of the reference, each best pose and each run\n", args.normal_axis);

    // Every run one setup step at a time, in lockstep: the perturbation and the restart at the step
    // they name, with the reference at that step.
    for (long step = 0; step <= steps; ++step)
    {
      if (step > 0)
        for (Run& r : runs)
          r.advance(1);
      if (step == perturb_step)
        for (Run& r : runs)
          if (r.name == "perturbed")
          {
            Eigen::VectorXd u = grid.gatherFree(r.sim->positions() - r.sim->linearizationPositions());
            for (int k = 0; k < u.size(); ++k)
              u[k] += args.perturb[grid.freeDofs()[k] % grid.dimension()];
            r.sim->setPhysicalState(u, r.sim->velocity());
          }
      if (step == restart_step)
        for (Run& r : runs)
          if (r.name.rfind("restart_", 0) == 0)
            takeState(*r.sim, *runs[0].sim);
      if (step == handover_step)
        for (size_t k = 0; k < args.weights.size(); ++k)
          takeState(*runs[first_handover + k].sim, *runs[first_modal + k].sim);
      if (step % args.sample != 0)
        continue;
      const Eigen::VectorXd ref = runs[0].sim->positions();
      size_t c = 0;
      const bool print = (step / args.sample) % args.every == 0 || step == steps;
      auto cell = [&](const Run& r, const Eigen::VectorXd& x, int width) {
        const double v = r.diverged ? NAN : 1e3 * rmsFree(grid, x, ref);
        if (print)
          std::printf(" %*.*f", width, 2, v);
        if (!std::isnan(v) && step > 0)  // as modal_compare: over every sample after the start
          columns[c].add(v);
        ++c;
      };
      if (print)
        std::printf("%8.3f", step * dt);
      cell(runs[1], runs[1].sim->positions(), 9);
      if (perturbed)
        cell(runs[2], runs[2].sim->positions(), 9);
      for (size_t k = 0; k < num_physical; ++k)
      {
        const Run& r = runs[first_modal + k];
        cell(r, bestPose(*r.sim, ref), 9);
        cell(r, r.sim->positions(), 11);
      }
      for (size_t k = first_modal + num_physical; k < runs.size(); ++k)
        cell(runs[k], runs[k].sim->positions(), 11);
      if (args.normal_axis >= 0)
      {
        auto off = [&](const Eigen::VectorXd& x) {
          const double v = 1e3 * rmsOffPlane(grid, x, args.normal_axis);
          if (print)
            std::printf(" %9.2e", v);
          if (step > 0)
            columns[c].add(v);
          ++c;
        };
        off(ref);
        for (size_t k = 0; k < num_physical; ++k)
          off(runs[first_modal + k].sim->positions());
      }
      if (args.energy)
      {
        auto energy = [&](const Eigen::VectorXd& x) {
          const double v = 1e3 * springEnergy(grid, x);
          if (print)
            std::printf(" %9.2f", v);
          if (step > 0)
            columns[c].add(v);
          ++c;
        };
        energy(ref);
        for (size_t k = 0; k < num_physical; ++k)
        {
          energy(bestPose(*runs[first_modal + k].sim, ref));
          energy(runs[first_modal + k].sim->positions());
        }
      }
      if (print)
        std::printf("\n");
    }
    std::printf("%8s", "mean");
    for (const Column& col : columns)
      std::printf(" %*.2f", col.name.rfind("physical_", 0) == 0 || col.name.rfind("restart_", 0) == 0 || col.name.rfind("handover_", 0) == 0 ? 11 : 9,
                  col.count ? col.sum / col.count : NAN);
    std::printf("\n%8s", "largest");
    for (const Column& col : columns)
      std::printf(" %*.2f", col.name.rfind("physical_", 0) == 0 || col.name.rfind("restart_", 0) == 0 || col.name.rfind("handover_", 0) == 0 ? 11 : 9, col.max);
    std::printf("\n");
    return 0;
  }
  catch (const std::exception& e)
  {
    std::cerr << "skinning_span_error: " << e.what() << "\n";
    return 2;
  }
}
