// The cost and accuracy of contact (docs/benchmarks.md, docs/results.md "Contact"): a sheet of
// N x N pinned along row 0, released flat above a table whose edge it drapes over, and the same
// sheet resting on the table; per method the deepest penetration over the run, the largest
// particle distance to `full` at the end, and the step's cost (CPU time) with the table against without it.
// The modal methods are linearized where the sheet hangs (a flat sheet has no out-of-plane
// stiffness) and switched to at the start, so that the flat sheet stays as their offset.
// Usage: contact_cost drop|rest N seconds [--explicit DT] [methods...] (rest: the sheet starts on the
// table top; --explicit: the explicit scheme at time step DT instead of implicit 5 ms steps, and for
// `full` alone linearized at rest, which skips the equilibrium solves a large grid waits minutes for).
#include "modal_mass_spring/cpu_time.h"
#include "modal_mass_spring/simulation.h"

#include <cstdio>
#include <cstdlib>
#include <string>

#include <time.h>

using namespace modal_mass_spring;

namespace
{

GridParams sheet(int n)
{
  GridParams g;
  g.rows = g.cols = n;
  g.dimension = 3;
  g.spacing = 1.0 / (n - 1);
  g.mass = 1.0 / (n * n);
  g.structural_stiffness = 50.0;
  g.shear_stiffness = 20.0;
  g.bending = true;
  g.bending_stiffness = 5.0;
  g.rotation_deg = 90.0;  // flat at z = 0, rows along +y
  return g;
}

bool resting = false;
bool explicit_scheme = false;
double explicit_step = 0.0;
bool full_only = true;

Collider table(int n)
{
  Collider c;
  c.type = ColliderType::Box;
  // drop: the top 5 cm below the sheet; rest: the sheet lies on it at the thickness.
  c.center = Eigen::Vector3d(0.5, 0.25, resting ? -0.4 - kDefaultThicknessFraction / (n - 1) : -0.45);
  c.half_extents = Eigen::Vector3d(0.7, 0.35, 0.4);  // top at z = -0.05, edge at y = 0.6
  return c;
}

struct Run
{
  double deepest = 0.0, ms_per_step = 0.0, contact_ms_per_step = 0.0;
  Eigen::Matrix3Xd end;
};

Run run(int n, Method method, bool with_table, double seconds)
{
  SimulationParams s;
  s.method = Method::Full;
  s.integrator = explicit_scheme ? IntegratorKind::Explicit : IntegratorKind::Implicit;
  s.time_step = explicit_scheme ? explicit_step : 5e-3;
  s.alpha = 0.5;
  s.num_modes = 30;
  // `full` alone needs no modes: at rest it starts at once (the equilibrium is for the modal methods).
  s.linearization = explicit_scheme && full_only ? Linearization::Rest : Linearization::Equilibrium;
  if (with_table)
    s.colliders = {table(n)};
  Simulation sim(sheet(n), s);
  // Switched to after the start: the flat sheet the hanging modes cannot hold stays as their offset.
  sim.setMethod(method);
  Run r;
  const Collider t = table(n);
  const int steps = static_cast<int>(seconds / s.time_step);
  double busy = 0.0;
  for (int k = 0; k < steps; ++k)
  {
    const double start = processCpuSeconds();
    const StepResult result = sim.step();
    busy += processCpuSeconds() - start;
    r.contact_ms_per_step += 1e3 * sim.lastContactSeconds() / steps;
    if (result.diverged)
    {
      std::printf("  %s diverged: %s\n", toString(method).c_str(), result.message.c_str());
      break;
    }
    const Eigen::Matrix3Xd points = sim.points();
    for (int p = n; p < points.cols(); ++p)
    {
      Eigen::Vector3d normal;
      r.deepest = std::max(r.deepest, -signedDistance(t, Eigen::Isometry3d::Identity(), points.col(p), normal));
    }
  }
  r.ms_per_step = 1e3 * busy / steps;
  r.end = sim.points();
  return r;
}

}  // namespace

int main(int argc, char** argv)
{
  if (argc < 4)
  {
    std::fprintf(stderr, "usage: contact_cost drop|rest N seconds [methods...]\n");
    return 2;
  }
  resting = std::string(argv[1]) == "rest";
  const int n = std::atoi(argv[2]);
  const double seconds = std::atof(argv[3]);
  std::vector<Method> methods{Method::Full};
  for (int a = 4; a < argc; ++a)
  {
    if (std::string(argv[a]) == "--explicit" && a + 1 < argc)
    {
      explicit_scheme = true;
      explicit_step = std::atof(argv[++a]);
      if (!(explicit_step > 0.0))
      {
        std::fprintf(stderr, "--explicit needs a time step > 0 (s)\n");
        return 2;
      }
      continue;
    }
    methods.push_back(parseMethod(argv[a]));
    full_only = false;
  }
  Eigen::Matrix3Xd full_with, full_without;
  if (explicit_scheme)
    std::printf("%s, %d x %d, %.2f s, explicit %g ms steps\n", argv[1], n, n, seconds, 1e3 * explicit_step);
  else
    std::printf("%s, %d x %d, %.2f s, implicit 5 ms steps\n", argv[1], n, n, seconds);
  std::printf("method     deepest(mm)  to_full(mm)  to_full_no_table(mm)  ms/step  contact(ms/step)  contact_share  ms/step(no table)  [CPU ms]\n");
  for (Method m : methods)
  {
    const Run with = run(n, m, true, seconds);
    const Run without = run(n, m, false, seconds);
    if (m == Method::Full)
    {
      full_with = with.end;
      full_without = without.end;
    }
    std::printf("%-10s %11.3f  %11.1f  %20.1f  %7.3f  %16.3f  %12.1f%%  %17.3f\n", toString(m).c_str(), with.deepest * 1e3,
                1e3 * (with.end - full_with).colwise().norm().maxCoeff(),
                1e3 * (without.end - full_without).colwise().norm().maxCoeff(), with.ms_per_step,
                with.contact_ms_per_step, 100.0 * with.contact_ms_per_step / (with.ms_per_step - with.contact_ms_per_step),
                without.ms_per_step);
  }
}
