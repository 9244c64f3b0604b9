// Prototype, not in the library: an implicit step on the skinning subspace whose system matrix is
// constant and factorised once, beside the package's own implicit `cubature` step on the same held
// cloth (docs/design.md and docs/benchmarks.md, "A reduced step with a constant matrix").
//
// The reduced equation is the package's, X'' + alpha X' = F(X, x_b) - Phi^T M Psi (a_b + alpha v_b),
// with u = Psi dx_b + Phi X (Phi^T M Phi = I) and F the cubature's force (its springs T and weights,
// the package's trained ones). One backward Euler step solves
//   G(X) = (1/h^2 + alpha/h) X - F(X) - R_n = 0,  R_n = (X_n + h X'_n) / h^2 + alpha X_n / h - load,
// by the fixed-point iteration A dX = -G(X_k) with a constant A = (1/h^2 + alpha/h) I + K_c:
//   --matrix laplacian:   K_c = Phi^T L Phi, L = sum_s k_s G_s^T G_s over every spring: projective
//                         dynamics (each spring's projection onto its rest length is the local step,
//                         F(X_k) + K_c X_k its right-hand side) with the right-hand side over T only,
//                         the hyper-reduced projective dynamics of Brandt et al. 2018;
//   --matrix equilibrium: K_c = Phi^T K(x_ref) Phi, the reduced tangent at the hanging equilibrium
//                         (a quasi-Newton with the tangent lagged to the start);
//   --matrix lagged:      the cubature's reduced tangent at the start of every --refresh-th step,
//                         factorised again then (a quasi-Newton with a lagged tangent; counted with
//                         the steps: --toggle-collect on refreshTangent too).
// An iteration costs the cubature's force (2 |T| dim r multiply-adds) and two triangular solves of
// size r; nothing grows with the grid. At every step the iteration is first run to convergence (the
// converged implicit step X*, not timed) and then, from the same start, for --iterations (counted
// under callgrind: --toggle-collect on constantMatrixStep); the trajectory goes on from X*. Printed:
// per step, the iterations the first reached within 1 mm and 0.1 mm (largest particle distance) of
// X*, the CPU time of the counted steps, and how far a run that takes --iterations at every step
// (from X*'s state at the window's start) gets from the converged run over the window.
//   constant_matrix_step --config config/compare/cloth_drag_50.yaml --steps 400 --iterations 10
//     [--matrix laplacian|equilibrium] [--skip N] [--set key=value ...]
#include "experiments.h"
#include "handle_scenarios.h"
#include "yaml_parameter_source.h"

#include "modal_mass_spring/cache.h"
#include "modal_mass_spring/parameters.h"
#include "modal_mass_spring/simulation.h"
#include "modal_mass_spring/spring_forces.h"

#include <valgrind/callgrind.h>

#include <Eigen/Cholesky>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <stdexcept>
#include <string>
#include <vector>

using namespace modal_mass_spring;

namespace
{

// The reduced system over the cubature's springs T, built from a Simulation of method `cubature`.
struct ConstantMatrixStep
{
  int r = 0, dim = 3;
  double h = 0.0, alpha = 0.0, inertia = 0.0;  // inertia = 1/h^2 + alpha/h
  Eigen::MatrixXd d;            // 3|T| x r: Phi rows of spring end i minus those of end j (zero for a handle end)
  Eigen::MatrixXd base_of_handles;  // 3|T| x handle dofs: the same rows of Psi, and +-1 for a handle end
  Eigen::VectorXd base_ref;     // 3|T|: x_ref,i - x_ref,j
  Eigen::VectorXd weighted_stiffness, rest_length, reference_force;  // per spring of T; the force at X = 0, dx_b = 0
  Eigen::VectorXd f0;           // Phi^T (f(x_ref) + f_g), every spring
  Eigen::MatrixXd load_of_handles;  // Phi^T M Psi (r x handle dofs)
  Eigen::LLT<Eigen::MatrixXd> factor;
  // Per step: the springs' positions at X = 0 and the right-hand side's constant part.
  Eigen::VectorXd base, rhs, diff, g, force, residual, delta;

  // F(X) over T: the exact force at the reference plus the cubature's estimate of its change.
  void cubatureForce(const Eigen::VectorXd& x)
  {
    diff.noalias() = d * x;
    diff += base;
    for (Eigen::Index s = 0; s < rest_length.size(); ++s)
    {
      const auto ds = diff.segment<3>(3 * s);
      const double length = ds.norm();
      // The spring's pull on end i, weighted, minus its value at the reference.
      g.segment<3>(3 * s) = weighted_stiffness[s] * (length - rest_length[s]) / length * ds;
    }
    g -= reference_force;
    force = f0;
    force.noalias() -= d.transpose() * g;
  }

  // The cubature's reduced tangent at x, sum_s D_s^T (w_s K_s) D_s, a compressed spring's geometric
  // part dropped so that it stays positive semi-definite.
  Eigen::MatrixXd tangent(const Eigen::VectorXd& x)
  {
    diff.noalias() = d * x;
    diff += base;
    Eigen::MatrixXd k = Eigen::MatrixXd::Zero(d.cols(), d.cols());
    Eigen::MatrixXd kd(3, d.cols());
    for (Eigen::Index s = 0; s < rest_length.size(); ++s)
    {
      const Eigen::Vector3d ds = diff.segment<3>(3 * s);
      const double length = ds.norm();
      const Eigen::Vector3d n = ds / length;
      const double geometric = std::max(0.0, 1.0 - rest_length[s] / length);
      const Eigen::Matrix3d ks =
          weighted_stiffness[s] * (geometric * Eigen::Matrix3d::Identity() + (1.0 - geometric) * n * n.transpose());
      kd.noalias() = ks * d.middleRows<3>(3 * s);
      k.noalias() += d.middleRows<3>(3 * s).transpose() * kd;
    }
    return k;
  }

  // k iterations of A dX = -G(X) from x.
  void iterate(Eigen::VectorXd& x, int k)
  {
    for (int i = 0; i < k; ++i)
    {
      cubatureForce(x);
      residual = inertia * x - force - rhs;
      delta = factor.solve(residual);
      x -= delta;
    }
  }
};

// Counted under callgrind: one step of `iterations` iterations from the predictor.
__attribute__((noinline)) void constantMatrixStep(ConstantMatrixStep& p, Eigen::VectorXd& x, int iterations)
{
  p.iterate(x, iterations);
}

// Counted under callgrind with the steps: the tangent at x and the new factor (--matrix lagged).
__attribute__((noinline)) void refreshTangent(ConstantMatrixStep& p, const Eigen::VectorXd& x)
{
  p.factor.compute(p.inertia * Eigen::MatrixXd::Identity(p.r, p.r) + p.tangent(x));
}

int run(int argc, char** argv)
{
  std::string config, matrix = "laplacian";
  int steps = 400, skip = 0, iterations = 10, refresh = 10;
  std::vector<std::pair<std::string, std::string>> sets;
  for (int i = 1; i < argc; ++i)
  {
    const std::string arg = argv[i];
    if (i + 1 >= argc)
      throw std::invalid_argument("option " + arg + " needs a value");
    const std::string value = argv[++i];
    if (arg == "--config")
      config = value;
    else if (arg == "--matrix")
      matrix = value;
    else if (arg == "--steps")
      steps = std::stoi(value);
    else if (arg == "--skip")
      skip = std::stoi(value);
    else if (arg == "--iterations")
      iterations = std::stoi(value);
    else if (arg == "--refresh")
      refresh = std::stoi(value);
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
  if (config.empty() || steps < 1 || skip < 0 || iterations < 1 || (matrix != "laplacian" && matrix != "equilibrium" && matrix != "lagged") ||
      refresh < 1)
    throw std::invalid_argument("need --config FILE, --steps >= 1, --skip >= 0, --iterations >= 1, "
                                "--matrix laplacian, equilibrium or lagged, --refresh >= 1");

  // The package's cubature on the skinning span, constraint modes for the handle (u = Psi dx_b + Phi X).
  YamlParameterSource source = YamlParameterSource::fromFile(config);
  for (const auto& [key, value] : sets)
    source.set(key, value);
  source.set("method", "cubature");
  source.set("handle_formulation", "constraint_modes");
  GridParams grid_params = loadGridParams(source);
  const SimulationParams params = loadSimulationParams(source);  // its colliders are not read: no table
  const HandleScenario scenario =
      parseHandleScenarios(source.getNode("handle_scenarios"), "handle_scenarios").front();
  grid_params = gridWithHandles(grid_params, scenario);
  CacheOptions cache;
  cache.directory = defaultCacheDirectory();
  Simulation sim(grid_params, params, StageFn{}, cache);
  const HandleDriver driver(scenario, sim);
  const Grid& grid = sim.grid();
  const Eigen::MatrixXd& phi = sim.physicalBasis().phi;
  const Eigen::MatrixXd& psi = sim.skinningConstraintModes();
  if (!sim.cubature())
    throw std::runtime_error("the simulation has no cubature");
  const Cubature& cubature = *sim.cubature();
  const Eigen::VectorXd& x_ref = sim.linearizationPositions();
  if (psi.rows() != phi.rows())
    throw std::invalid_argument("needs basis: skinning with handles (Psi over the interior)");

  ConstantMatrixStep p;
  p.r = static_cast<int>(phi.cols());
  p.h = params.time_step;
  p.alpha = params.alpha;
  p.inertia = 1.0 / (p.h * p.h) + p.alpha / p.h;
  const int nt = static_cast<int>(cubature.springs.size());
  const int nb = grid.numHandleDofs();
  std::vector<int> handle_index(grid.numDofs(), -1);
  for (int k = 0; k < nb; ++k)
    handle_index[grid.handleDofs()[k]] = k;
  // Rows of Phi and Psi for one dof, and where a handle dof sits in dx_b.
  using Row = Eigen::Ref<Eigen::RowVectorXd, 0, Eigen::InnerStride<>>;
  auto addRows = [&](int dof, double sign, Row d_row, Row b_row) {
    const int f = grid.freeIndex(dof);
    if (f >= 0)
    {
      d_row += sign * phi.row(f);
      b_row += sign * psi.row(f);
    }
    else if (handle_index[dof] >= 0)
      b_row[handle_index[dof]] += sign;
  };
  p.d.setZero(3 * nt, p.r);
  p.base_of_handles.setZero(3 * nt, nb);
  p.base_ref.resize(3 * nt);
  p.weighted_stiffness.resize(nt);
  p.rest_length.resize(nt);
  for (int t = 0; t < nt; ++t)
  {
    const Spring& s = grid.springs()[cubature.springs[t]];
    for (int a = 0; a < 3; ++a)
    {
      addRows(3 * s.i + a, 1.0, p.d.row(3 * t + a), p.base_of_handles.row(3 * t + a));
      addRows(3 * s.j + a, -1.0, p.d.row(3 * t + a), p.base_of_handles.row(3 * t + a));
      p.base_ref[3 * t + a] = x_ref[3 * s.i + a] - x_ref[3 * s.j + a];
    }
    p.weighted_stiffness[t] = cubature.weights[t] * s.stiffness;
    p.rest_length[t] = s.rest_length;
  }
  p.base = p.base_ref;
  p.reference_force.setZero(3 * nt);
  p.g.resize(3 * nt);
  {
    // The springs' weighted pull at the reference, which F's change is measured from.
    p.reference_force.setZero();
    Eigen::VectorXd zero = Eigen::VectorXd::Zero(p.r);
    p.f0.setZero(p.r);
    p.cubatureForce(zero);
    p.reference_force = p.g;
  }
  Eigen::VectorXd f_all;
  springForces(grid, x_ref, f_all);
  f_all += grid.gravityForce();
  p.f0 = phi.transpose() * grid.gatherFree(f_all);
  const Eigen::VectorXd mass = grid.gatherFree(Eigen::VectorXd::Constant(grid.numDofs(), grid.particleMass()));
  p.load_of_handles = phi.transpose() * mass.asDiagonal() * psi;

  Eigen::MatrixXd k_c;
  if (matrix == "lagged")
    k_c = p.tangent(Eigen::VectorXd::Zero(p.r));  // refreshed every --refresh steps below
  else if (matrix == "equilibrium")
  {
    const ModalBasis& b = sim.physicalBasis();
    k_c = b.reduced_stiffness.size() > 0 ? b.reduced_stiffness : Eigen::MatrixXd(b.eigenvalues.asDiagonal());
  }
  else
  {
    // Phi^T L Phi with L = sum_s k_s G_s^T G_s over every spring (handle ends held: only free rows).
    Eigen::MatrixXd rows(3, p.r);
    k_c.setZero(p.r, p.r);
    for (const Spring& s : grid.springs())
    {
      rows.setZero();
      for (int a = 0; a < 3; ++a)
      {
        if (const int f = grid.freeIndex(3 * s.i + a); f >= 0)
          rows.row(a) += phi.row(f);
        if (const int f = grid.freeIndex(3 * s.j + a); f >= 0)
          rows.row(a) -= phi.row(f);
      }
      k_c.noalias() += s.stiffness * rows.transpose() * rows;
    }
  }
  p.factor.compute(p.inertia * Eigen::MatrixXd::Identity(p.r, p.r) + k_c);
  if (p.factor.info() != Eigen::Success)
    throw std::runtime_error("the constant matrix is not positive definite");

  // The largest particle distance (m) of a change in X, over the interior.
  auto largestDistance = [&](const Eigen::VectorXd& dx) {
    const Eigen::VectorXd u = phi * dx;
    double largest = 0.0;
    for (Eigen::Index k = 0; k + 3 <= u.size(); k += 3)
      largest = std::max(largest, u.segment<3>(k).norm());
    return largest;
  };

  Eigen::VectorXd x = Eigen::VectorXd::Zero(p.r), v = Eigen::VectorXd::Zero(p.r);
  Eigen::VectorXd positions, velocities, accelerations;
  const Eigen::VectorXd x_ref_b = [&] {
    Eigen::VectorXd b(nb);
    for (int k = 0; k < nb; ++k)
      b[k] = x_ref[grid.handleDofs()[k]];
    return b;
  }();
  std::vector<int> to_1mm;
  int never = 0, largest_fine = 0;
  double predictor_distance = 0.0, step_motion = 0.0;  // largest over the counted steps (m)
  // The run of `iterations` a step, from the converged run's state at the window's start, and its
  // largest particle distance from the converged run over the window (m).
  Eigen::VectorXd x_fixed = x, v_fixed = v;
  double drift = 0.0;
  long converged_iterations = 0;
  double cpu = 0.0;
  for (int n = 0; n < skip + steps; ++n)
  {
    const double t = (n + 1) * p.h;
    driver.particleMotion(t, positions, velocities, accelerations);
    p.base = p.base_ref + p.base_of_handles * (positions - x_ref_b);
    if (matrix == "lagged" && n % refresh == 0)
    {
      // The tangent at the start of this step, factorised again: counted with the step.
      CALLGRIND_START_INSTRUMENTATION;
      const double start = threadCpuSeconds();
      refreshTangent(p, x);
      if (n >= skip)
        cpu += threadCpuSeconds() - start;
      CALLGRIND_STOP_INSTRUMENTATION;
    }
    const Eigen::VectorXd load = p.load_of_handles * (accelerations + p.alpha * velocities);
    p.rhs = (x + p.h * v) / (p.h * p.h) + (p.alpha / p.h) * x - load;
    // The converged implicit step, not counted.
    Eigen::VectorXd converged = x + p.h * v;
    int k = 0;
    for (; k < 5000; ++k)
    {
      const Eigen::VectorXd before = converged;
      p.iterate(converged, 1);
      if ((converged - before).norm() <= 1e-12 * (1.0 + converged.norm()))
        break;
    }
    if (!converged.allFinite())
      throw std::runtime_error("the iteration diverged at step " + std::to_string(n + 1));
    if (n >= skip)
    {
      converged_iterations += k + 1;
      // Iterations to 1 mm (and to 0.1 mm) of the converged step, from the same predictor (0: the
      // predictor is already there).
      Eigen::VectorXd trial = x + p.h * v;
      predictor_distance = std::max(predictor_distance, largestDistance(trial - converged));
      int reached = largestDistance(trial - converged) <= 1e-3 ? 0 : -1;
      int reached_fine = largestDistance(trial - converged) <= 1e-4 ? 0 : -1;
      for (int i = 1; i <= 200 && reached_fine < 0; ++i)
      {
        p.iterate(trial, 1);
        const double distance = largestDistance(trial - converged);
        if (reached < 0 && distance <= 1e-3)
          reached = i;
        if (distance <= 1e-4)
          reached_fine = i;
      }
      if (reached < 0)
        ++never;
      else
        to_1mm.push_back(reached);
      largest_fine = std::max(largest_fine, reached_fine < 0 ? 1000 : reached_fine);
      step_motion = std::max(step_motion, largestDistance(converged - x));
      // The counted step: `iterations` from the predictor, on a run of its own that takes them at
      // every step from the start of the window, measured against the converged run.
      const Eigen::VectorXd converged_rhs = p.rhs;
      p.rhs = (x_fixed + p.h * v_fixed) / (p.h * p.h) + (p.alpha / p.h) * x_fixed - load;
      Eigen::VectorXd counted = x_fixed + p.h * v_fixed;
      CALLGRIND_START_INSTRUMENTATION;
      const double start = threadCpuSeconds();
      constantMatrixStep(p, counted, iterations);
      cpu += threadCpuSeconds() - start;
      CALLGRIND_STOP_INSTRUMENTATION;
      p.rhs = converged_rhs;
      v_fixed = (counted - x_fixed) / p.h;
      x_fixed = counted;
      drift = std::max(drift, largestDistance(x_fixed - converged));
    }
    v = (converged - x) / p.h;
    x = converged;
    if (n + 1 == skip)
    {
      x_fixed = x;
      v_fixed = v;
    }
  }
  std::sort(to_1mm.begin(), to_1mm.end());
  double mean = 0.0;
  for (int k : to_1mm)
    mean += k;
  mean /= std::max<size_t>(1, to_1mm.size());
  std::printf("%s matrix, r = %d, |T| = %d, h = %g s, steps %d..%d (t = %.3f s): iterations to 1 mm of the "
              "converged step: mean %.2f, median %d, largest %d, not within 200: %d; to convergence (1e-12): "
              "mean %.1f; to 0.1 mm: largest %d (1000: not within 200); the predictor up to %.3g mm from the "
              "converged step, the step's largest particle motion %.3g mm; %d iterations a step: CPU %.3f ms a step, "
              "the run of %d iterations a step up to %.3g mm from the converged run\n",
              matrix.c_str(), p.r, nt, p.h, skip, skip + steps, (skip + steps) * p.h, mean,
              to_1mm.empty() ? -1 : to_1mm[to_1mm.size() / 2], to_1mm.empty() ? -1 : to_1mm.back(), never,
              static_cast<double>(converged_iterations) / steps, largest_fine, 1e3 * predictor_distance,
              1e3 * step_motion, iterations, 1e3 * cpu / steps, iterations, 1e3 * drift);
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
    std::cerr << "constant_matrix_step: " << e.what() << "\n";
    return 2;
  }
}
