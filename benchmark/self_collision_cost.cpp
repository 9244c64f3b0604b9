// Self-collision's cost (docs/benchmarks.md, "Self-collision"): an N x N cloth (1 m square) lying on a
// table folded in half, its upper half the thickness (5 mm) above the lower one, stepped by explicit
// `full` at 0.2 ms with and without self-collision, and the self-collision pass alone on that state
// with the upper half 0.1 mm into the thickness (every particle of it touching); and a towel dropped
// in a heap onto the table.
// Usage: catkin_make self_collision_cost && devel/lib/modal_mass_spring/self_collision_cost
#include "modal_mass_spring/self_collision.h"
#include "modal_mass_spring/simulation.h"

#include <benchmark/benchmark.h>

#include <cmath>
#include <ctime>
#include <random>

using namespace modal_mass_spring;

namespace
{

constexpr double kThickness = 0.005;

GridParams cloth(int n)
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
  g.rotation_deg = 90.0;  // lying flat, rows along +y
  return g;
}

// Folded at its middle row over a crease of radius thickness / 2: the upper half `gap` above the lower.
Eigen::VectorXd folded(const Grid& grid, double gap)
{
  const GridParams& g = grid.params();
  const double flat = (g.rows / 2 - 1) * g.spacing, rho = 0.5 * gap;
  Eigen::VectorXd x(grid.numDofs());
  for (int r = 0; r < g.rows; ++r)
    for (int c = 0; c < g.cols; ++c)
    {
      const double t = r * g.spacing;
      Eigen::Vector3d at(c * g.spacing, t, 0.0);
      if (t > flat + M_PI * rho)
        at.tail<2>() << flat - (t - flat - M_PI * rho), 2.0 * rho;
      else if (t > flat)
        at.tail<2>() << flat + rho * std::sin((t - flat) / rho), rho * (1.0 - std::cos((t - flat) / rho));
      x.segment<3>(3 * grid.particleIndex(r, c)) = at;
    }
  return x;
}

SimulationParams explicitFull(bool self)
{
  SimulationParams s;
  s.method = Method::Full;
  s.integrator = IntegratorKind::Explicit;
  s.time_step = 2e-4;
  s.alpha = 1.0;
  Collider table;
  table.point = Eigen::Vector3d(0.0, 0.0, -0.001);
  s.colliders = {table};
  s.contact_thickness = 0.001;
  s.self_collision = self;
  s.self_collision_thickness = kThickness;
  return s;
}

// The steps measured, apart from the settling ones (valgrind --toggle-collect='*measuredStep*').
[[gnu::noinline]] void measuredStep(Simulation& sim)
{
  sim.step();
}

// One explicit `full` step of the folded cloth on the table, after arg 2 steps (100: 20 ms; 1000:
// 0.2 s, the crease still rolling; 5000: 1 s) that let the upper half settle onto the lower one; arg 1: with self-collision. Reports the
// self-collision share of the step (its CPU time, Simulation::lastSelfCollisionSeconds), and per step
// the pairs, the particles whose candidate pairs were listed anew, the pairs that kept their closest
// points, the correction's sweeps (positions and velocities) and the share of steps whose narrow
// phase ran (`looked`).
void BM_FoldedFullStep(benchmark::State& state)
{
  GridParams g = cloth(static_cast<int>(state.range(0)));
  g.fixed = {0};
  Simulation sim(g, explicitFull(state.range(1) != 0));
  sim.setPhysicalState(sim.grid().gatherFree(folded(sim.grid(), kThickness) - sim.linearizationPositions()),
                       Eigen::VectorXd::Zero(sim.grid().numFreeDofs()));
  for (int k = 0; k < state.range(2); ++k)
    sim.step();
  double self_seconds = 0.0, relisted = 0.0, reused = 0.0, sweeps = 0.0, looked = 0.0;
  for (auto _ : state)
  {
    measuredStep(sim);
    self_seconds += sim.lastSelfCollisionSeconds();
    if (const SelfCollision* self = sim.selfCollision())
    {
      looked += self->report().looked;
      relisted += self->report().relisted;
      reused += self->report().reused;
      sweeps += self->report().position_sweeps + self->report().velocity_sweeps;
    }
  }
  state.counters["self_ms"] = benchmark::Counter(1e3 * self_seconds / state.iterations());
  state.counters["contacts"] = sim.selfCollision() ? sim.selfCollision()->report().contacts : 0;
  state.counters["relisted"] = benchmark::Counter(relisted / state.iterations());
  state.counters["reused"] = benchmark::Counter(reused / state.iterations());
  state.counters["sweeps"] = benchmark::Counter(sweeps / state.iterations());
  state.counters["looked"] = benchmark::Counter(looked / state.iterations());
}
BENCHMARK(BM_FoldedFullStep)->ArgsProduct({{30, 100}, {0, 1}, {100, 1000, 5000}})->Unit(benchmark::kMicrosecond);

// The self-collision pass alone on the folded cloth, its upper half 0.1 mm into the thickness (the
// state copied back each time), its narrow phase run every time (no lapse: the state does not move).
void BM_SelfCollisionPass(benchmark::State& state)
{
  GridParams g = cloth(static_cast<int>(state.range(0)));
  g.fixed = {0};
  const Grid grid(g);
  SelfCollision self(grid, kThickness, 0.5, SelfPrimitive::Triangles, 0.0);  // its narrow phase every time
  const Eigen::VectorXd start = grid.gatherFree(folded(grid, kThickness));
  const Eigen::VectorXd end = grid.gatherFree(folded(grid, kThickness - 1e-4));
  Eigen::VectorXd x = end, v = Eigen::VectorXd::Zero(end.size());
  for (auto _ : state)
  {
    x = end;
    v.setZero();
    self.correct(start, x, v, 2e-4);
    benchmark::DoNotOptimize(x.data());
  }
  state.counters["contacts"] = self.report().contacts;
}
BENCHMARK(BM_SelfCollisionPass)->Arg(30)->Arg(100)->Unit(benchmark::kMicrosecond);

// A crumple: an N x N towel 2 cm apart hanging in the x-z plane from nothing but a bottom corner,
// given a random push (as SelfCollision.TowelDroppedInAHeapKeepsItsLayersApart), falls onto a table
// in a heap: one iteration is 1.5 s of explicit `full` at 0.5 ms with self-collision (10 mm).
// Reports the self-collision share of the run's CPU time, and per step the particles whose candidate
// pairs were listed anew and the pairs.
void BM_HeapDrop(benchmark::State& state)
{
  const int n = static_cast<int>(state.range(0));
  GridParams g = cloth(n);
  g.spacing = 0.02;
  g.mass = 0.002;
  g.bending_stiffness = 1.0;
  g.rotation_deg = 0.0;
  g.fixed = {n * n - 1};
  SimulationParams s = explicitFull(true);
  s.time_step = 5e-4;
  s.colliders[0].point = Eigen::Vector3d(0.0, 0.0, -0.45 - 0.02 * (n - 20));
  s.contact_thickness = 0.001;
  s.self_collision_thickness = 0.01;
  s.self_friction = 0.5;
  double total = 0.0, self_seconds = 0.0, relisted = 0.0, contacts = 0.0;
  long steps = 0;
  for (auto _ : state)
  {
    Simulation sim(g, s);
    std::mt19937_64 rng(7);
    std::normal_distribution<double> normal(0.0, 0.5);
    Eigen::VectorXd v(sim.grid().numFreeDofs());
    for (Eigen::Index k = 0; k < v.size(); ++k)
      v[k] = normal(rng);
    sim.setPhysicalState(Eigen::VectorXd::Zero(v.size()), v);
    const std::clock_t start = std::clock();
    for (int k = 0; k < 3000; ++k, ++steps)
    {
      sim.step();
      self_seconds += sim.lastSelfCollisionSeconds();
      relisted += sim.selfCollision()->report().relisted;
      contacts += sim.selfCollision()->report().contacts;
    }
    total += static_cast<double>(std::clock() - start) / CLOCKS_PER_SEC;
  }
  state.counters["self_share"] = benchmark::Counter(self_seconds / total);
  state.counters["relisted"] = benchmark::Counter(relisted / steps);
  state.counters["contacts"] = benchmark::Counter(contacts / steps);
}
BENCHMARK(BM_HeapDrop)->Arg(20)->Arg(40)->Iterations(1)->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
