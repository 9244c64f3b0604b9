// Explicit or implicit at a config's time step? Runs the config's method both ways, and explicitly at a
// quarter of the step as the reference, for some seconds after a push, and prints for each: the CPU
// time per step, the most Newton iterations, the largest frequency of the reduced tangent met along
// the motion times the step (the explicit scheme needs it below 2), and the RMS distance to the
// reference, sampled every 0.1 s.
//
//   integrator_choice config/cloth_large.yaml [seconds = 10] [cache_dir = ~/.ros/modal_mass_spring]
//
// The push: 0.05 N out of the sheet, opposite ways on the two bottom corners, for the first 0.2 s.
#include "modal_mass_spring/cubature.h"
#include "modal_mass_spring/simulation.h"
#include "experiments.h"
#include "yaml_parameter_source.h"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <memory>
#include <string>
#include <vector>

using namespace modal_mass_spring;

namespace
{

struct Run
{
  std::string name;
  IntegratorKind integrator;
  double time_step;
  std::vector<Eigen::VectorXd> samples;  // positions every 0.1 s
};

// The largest and smallest eigenvalue of the reduced tangent at X (mass-orthonormal modes: lambda^2).
Eigen::Vector2d tangentRange(ForceModel& model, const Eigen::VectorXd& q)
{
  SparseMatrix k;
  model.tangentStiffness(q, k);
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> solver{Eigen::MatrixXd(k)};
  return {solver.eigenvalues().maxCoeff(), solver.eigenvalues().minCoeff()};
}

}  // namespace

int main(int argc, char** argv)
{
  if (argc < 2)
  {
    std::fprintf(stderr, "usage: %s config.yaml [seconds] [cache_dir]\n", argv[0]);
    return 2;
  }
  try
  {
    const YamlParameterSource source = YamlParameterSource::fromFile(argv[1]);
    const GridParams grid = loadGridParams(source);
    SimulationParams params = loadSimulationParams(source);
    const double seconds = argc > 2 ? std::atof(argv[2]) : 10.0;
    CacheOptions cache;
    cache.directory = argc > 3 ? argv[3] : defaultCacheDirectory();
    const double dt = params.time_step;
    std::vector<Run> runs{{"explicit", IntegratorKind::Explicit, dt, {}},
                          {"implicit", IntegratorKind::Implicit, dt, {}},
                          {"reference (explicit, dt / 4)", IntegratorKind::Explicit, dt / 4.0, {}}};
    for (Run& run : runs)
    {
      params.integrator = run.integrator;
      params.time_step = run.time_step;
      Simulation sim(grid, params, {}, cache);
      std::unique_ptr<ForceModel> model;
      if (sim.method() == Method::Cubature)
        model = std::make_unique<CubatureForceModel>(sim.grid(), sim.physicalBasis(), sim.linearizationPositions(),
                                                     *sim.cubature());
      else if (sim.method() == Method::Physical)
        model = std::make_unique<PhysicalModalForceModel>(sim.grid(), sim.physicalBasis(), sim.linearizationPositions());
      const int dim = sim.grid().dimension();
      Eigen::VectorXd push = Eigen::VectorXd::Zero(sim.positions().size());
      const int corner = grid.rows * grid.cols - 1;
      push[dim * corner + 1] = 0.05;
      push[dim * (corner - grid.cols + 1) + 1] = -0.05;
      if (dim == 3)
        sim.setExternalForce(push);
      Eigen::Vector2d range(0.0, 0.0);
      if (model)
        range = tangentRange(*model, sim.state().q);
      const double lowest_at_start = range[1];
      const int per_sample = static_cast<int>(std::lround(0.1 / run.time_step));
      double step_seconds = 0.0, largest = range[0];
      long steps = 0;
      int newton = 0;
      for (int k = 0; k < static_cast<int>(std::lround(seconds / 0.1)) && !sim.diverged(); ++k)
      {
        if (k == 2)
          sim.setExternalForce(Eigen::VectorXd::Zero(push.size()));
        for (int j = 0; j < per_sample && !sim.diverged(); ++j)
        {
          const double start = threadCpuSeconds();
          steps += sim.step(1).steps_taken;
          step_seconds += threadCpuSeconds() - start;
          newton = std::max(newton, sim.lastNewtonIterations());
        }
        run.samples.push_back(sim.positions());
        if (model)
          largest = std::max(largest, tangentRange(*model, sim.state().q)[0]);
      }
      std::printf("%s at %g s: %ld steps%s, %.3g us a step (CPU), at most %d Newton iterations; omega_max dt %.3g "
                  "(largest tangent eigenvalue along the motion), lowest tangent eigenvalue at the start %.4g s^-2\n",
                  run.name.c_str(), run.time_step, steps, sim.diverged() ? " then DIVERGED" : "",
                  1e6 * step_seconds / std::max(1L, steps), newton, std::sqrt(std::max(0.0, largest)) * run.time_step,
                  lowest_at_start);
    }
    const Run& reference = runs.back();
    for (size_t r = 0; r + 1 < runs.size(); ++r)
    {
      double sum = 0.0, worst = 0.0;
      const size_t count = std::min(runs[r].samples.size(), reference.samples.size());
      for (size_t k = 0; k < count; ++k)
      {
        const Eigen::VectorXd d = runs[r].samples[k] - reference.samples[k];
        const Eigen::Map<const Eigen::MatrixXd> points(d.data(), grid.dimension, d.size() / grid.dimension);
        const double rms = std::sqrt(points.colwise().squaredNorm().mean());
        sum += rms;
        worst = std::max(worst, rms);
      }
      std::printf("%s: RMS distance to the reference, mean %.3g m, largest %.3g m over %zu samples\n",
                  runs[r].name.c_str(), count ? sum / count : 0.0, worst, count);
    }
  }
  catch (const std::exception& e)
  {
    std::fprintf(stderr, "%s\n", e.what());
    return 1;
  }
  return 0;
}
