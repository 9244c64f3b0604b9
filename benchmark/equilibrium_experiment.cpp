// Experiment (not a test): the swinging cloth's static equilibrium from a rotated start by three
// Newton variants, logged an iteration at a time (docs/benchmarks.md, "Equilibrium100").
//   equilibrium_experiment SIZE ROTATION_DEG MODE [MAX_ITERATIONS] [SAVE_FILE] [START_FILE]
// MODE: newton  (solveEquilibrium's direction: exact K where positive definite, else compressed
//               springs' geometric part dropped; energy line search)
//       lm      (exact K + mu M, mu halved after a successful step, raised x4 after a failed
//               factorisation or a rejected step; acceptance on the energy or the unbalanced force)
//       lme     (lm, and where it balances on a saddle (the exact K indefinite) a step along the
//               most negative curvature direction, then lm again)
//       hyb     (newton while each drop-tangent step at least halves the largest force, then lm)
//       ptc     (pseudo-transient continuation: exact K + M / h^2, h grown by |r_old| / |r_new|
//               (switched evolution relaxation), halved when the factorisation fails)
//       solve   (solveEquilibrium itself)
// Prints: iteration, largest unbalanced force (N), step accepted, tangent used, springs compressed,
// CPU seconds so far. SAVE_FILE gets the converged positions (binary doubles); START_FILE starts there.
#include "modal_mass_spring/grid.h"
#include "modal_mass_spring/modal_basis.h"
#include "modal_mass_spring/spring_forces.h"
#include "solvers/equilibrium.h"
#include "solvers/tangent_solver.h"

#include "swinging_cloth.h"

#include <ctime>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <stdexcept>
#include <string>

using namespace modal_mass_spring;

namespace
{
double cpu() { return static_cast<double>(std::clock()) / CLOCKS_PER_SEC; }

double potential(const Grid& grid, const Eigen::VectorXd& x) { return springEnergy(grid, x) + gravityEnergy(grid, x); }

Eigen::VectorXd unbalanced(const Grid& grid, const Eigen::VectorXd& x)
{
  Eigen::VectorXd f;
  springForces(grid, x, f);
  return grid.gatherFree(f + grid.gravityForce());
}

// d <- (K + shift I)^-1 r refined; false where not positive definite.
bool solveShifted(TangentSolver& solver, SparseMatrix& k, double shift, const Eigen::VectorXd& r, Eigen::VectorXd& d)
{
  for (int i = 0; i < k.rows(); ++i)
    k.coeffRef(i, i) += shift;
  if (!solver.solve(k, r, d, 0.0) || !d.allFinite())
    return false;
  for (int pass = 0; pass < 3; ++pass)
  {
    const Eigen::VectorXd res = r - k * d;
    Eigen::VectorXd c;
    if (!solver.solveWithFactor(res, c))
      break;
    if (!((r - k * (d + c)).norm() < 0.5 * res.norm()))
      break;
    d += c;
  }
  return r.dot(d) > 0.0;
}
}  // namespace

int main(int argc, char** argv)
{
  if (argc < 4)
  {
    std::fprintf(stderr, "usage: %s SIZE ROTATION_DEG newton|lm|ptc|solve [MAX_ITERATIONS] [SAVE_FILE] [START_FILE]\n", argv[0]);
    return 2;
  }
  // SIZE "paper3d": config/paper_3d.yaml's (10 x 10, 0.1 m, 10 g, 10/5 N/m, no bending).
  // SIZE "yaml": config/cloth.yaml's sheet (20 x 20, 0.05 m, 5 g a particle, springs 50/20/5 N/m; also
  // large_motion_release.yaml's at 60 degrees and cloth_table.yaml's at 90). "cloth50":
  // config/compare/cloth_50.yaml's (50 x 50, 0.02 m, 0.8 g, 50/20/5 N/m).
  const std::string size = argv[1];
  GridParams g = swingingCloth(size == "yaml" || size == "paper3d" || size == "cloth50" ? 20 : std::stoi(size));
  if (size == "yaml")
  {
    g.spacing = 0.05;
    g.mass = 0.005;
    g.structural_stiffness = 50.0;
    g.shear_stiffness = 20.0;
    g.bending_stiffness = 5.0;
  }
  if (size == "cloth50")  // config/compare/cloth_50.yaml's sheet
  {
    g = swingingCloth(50);
    g.spacing = 0.02;
    g.mass = 0.0008;
    g.structural_stiffness = 50.0;
    g.shear_stiffness = 20.0;
    g.bending_stiffness = 5.0;
  }
  if (size == "paper3d")  // config/paper_3d.yaml's sheet
  {
    g = GridParams{};
    g.rows = g.cols = 10;
    g.dimension = 3;
    g.spacing = 0.1;
    g.mass = 0.01;
    g.structural_stiffness = 10.0;
    g.shear_stiffness = 5.0;
  }
  g.rotation_deg = std::stod(argv[2]);
  const std::string mode = argv[3];
  const int max_iterations = argc > 4 ? std::stoi(argv[4]) : 1000;
  const Grid grid(g);
  Eigen::VectorXd x = grid.initialPositions();
  if (argc > 6)
  {
    std::ifstream in(argv[6], std::ios::binary);
    in.read(reinterpret_cast<char*>(x.data()), static_cast<std::streamsize>(x.size() * sizeof(double)));
  }
  const double weight = g.mass * g.gravity.norm();
  const double target = std::max(kEquilibriumTolerance * weight, 10.0 * springForceRoundoff(grid, x));
  std::printf("# size %d rotation %g mode %s target %.3g N\n", g.rows, g.rotation_deg, mode.c_str(), target);
  const double t0 = cpu();

  if (mode == "solve")
  {
    const Equilibrium e = solveEquilibrium(grid, x, max_iterations, kEquilibriumTolerance,
                                           [&](int it, double res, double) { std::printf("%4d %.3e %.1f\n", it, res, cpu() - t0); });
    x = e.positions;
  }
  else
  {
    const TangentAssembler assembler(grid);
    TangentSolver solver(TangentSolverKind::Cholmod);
    SparseMatrix k;
    Eigen::VectorXd r = unbalanced(grid, x);
    const double m = grid.particleMass();
    // lm: mu in 1/s^2 (the shift is mu M); ptc: h in s (the shift M / h^2).
    double mu = 0.0, h = 0.0;
    double old_norm = r.norm();
    int it = 0, escapes = 0;
    // lm, hyb: the shift's schedule (relative to the largest diagonal of K / m): the smallest nonzero
    // mu after a failed factorisation or a rejected step (MU_FLOOR, 1e-4), the mu below which an
    // accepted step sets it to 0 (MU_ZERO, 1e-6), and its factor after an accepted step (MU_DOWN, 0.3).
    const auto env = [](const char* name, double fallback) {
      const char* value = std::getenv(name);
      return value ? std::stod(value) : fallback;
    };
    const double mu_floor = env("MU_FLOOR", 1e-4), mu_zero = env("MU_ZERO", 1e-6), mu_down = env("MU_DOWN", 0.3);
    bool creeping = false;
    for (; it < max_iterations; ++it)
    {
      const double res = r.cwiseAbs().maxCoeff();
      int dropped = 0;
      assembler.assemble(x, k, CompressedSprings::Drop, &dropped);
      const double energy = potential(grid, x);
      const double reg = 1e-8 * k.diagonal().cwiseAbs().maxCoeff();
      if (res <= target)
      {
        // lme: balanced, but a saddle where the exact K is indefinite. Its most negative curvature
        // direction by inverse iteration on K + sigma I (sigma raised until that factorises), then a
        // step along it that lowers the energy, and on again.
        if (mode != "lme" || escapes >= 10)
          break;
        assembler.assemble(x, k, CompressedSprings::Keep);
        Eigen::VectorXd probe;
        if (solveShifted(solver, k, reg, r, probe))
          break;  // stable
        const double kscale = k.diagonal().cwiseAbs().maxCoeff();
        double sigma = 1e-6 * kscale;
        SparseMatrix shifted;
        for (;;)
        {
          assembler.assemble(x, shifted, CompressedSprings::Keep);
          for (int i = 0; i < shifted.rows(); ++i)
            shifted.coeffRef(i, i) += sigma;
          if (solver.solve(shifted, r, probe, 0.0))
            break;
          sigma *= 2.0;
        }
        assembler.assemble(x, k, CompressedSprings::Keep);
        std::srand(1);
        Eigen::VectorXd v = Eigen::VectorXd::Random(k.rows()).normalized();
        double lambda = 0.0;
        for (int pass = 0; pass < 100; ++pass)
        {
          Eigen::VectorXd w;
          solver.solveWithFactor(v, w);
          v = w.normalized();
          lambda = v.dot(k * v);
        }
        std::printf("saddle at %.3e N: lowest curvature %.3e N/m (sigma %.3e), ", res, lambda, sigma);
        if (lambda >= 0.0)
        {
          std::printf("none negative\n");
          break;
        }
        // Along +-v: the quadratic model drops 0.5 |lambda| a^2; the largest a (from 0.1 spacing,
        // halved) whose energy drop is at least half that.
        double best = 0.0;
        Eigen::VectorXd best_x = x;
        for (double a = 0.1 * g.spacing; a > 1e-9 && best == 0.0; a *= 0.5)
          for (double sign : {1.0, -1.0})
          {
            Eigen::VectorXd trial = x;
            grid.addFree(sign * a * v, trial);
            const double drop = energy - potential(grid, trial);
            if (drop > best && drop >= 0.25 * std::abs(lambda) * a * a)
            {
              best = drop;
              best_x = trial;
            }
          }
        std::printf("step lowers the energy by %.3e J\n", best);
        if (best == 0.0)
          break;
        x = best_x;
        r = unbalanced(grid, x);
        mu = sigma / m;
        ++escapes;
        continue;
      }
      Eigen::VectorXd d;
      std::string tangent;
      double step = 0.0;
      // solveEquilibrium's line search along d: halved from 1 until the energy falls by 1e-4 of the
      // slope's prediction or the force's norm falls; moves x and r there, returns the step (0: none).
      const auto backtrack = [&] {
        const double slope = r.dot(d);
        for (double s = 1.0; s > 1e-10; s *= 0.5)
        {
          Eigen::VectorXd trial = x;
          grid.addFree(s * d, trial);
          const Eigen::VectorXd tr = unbalanced(grid, trial);
          if (potential(grid, trial) <= energy - 1e-4 * s * slope || tr.norm() < (1.0 - 1e-4 * s) * r.norm())
          {
            x = trial;
            r = tr;
            return s;
          }
        }
        return 0.0;
      };
      if (mode == "newton")
      {
        for (CompressedSprings c : {CompressedSprings::Keep, CompressedSprings::Drop})
        {
          assembler.assemble(x, k, c);
          if (solveShifted(solver, k, reg, r, d))
          {
            tangent = c == CompressedSprings::Keep ? "exact" : "drop";
            break;
          }
        }
        if (tangent.empty())
        {
          std::printf("no direction\n");
          break;
        }
        step = backtrack();
        if (step == 0.0)
        {
          std::printf("line search failed\n");
          break;
        }
      }
      else if (mode == "lm" || mode == "lme" || mode == "hyb")
      {
        // hyb: solveEquilibrium's direction while it converges fast (each drop-tangent step at
        // least halves the largest force); once one does not, the shifted exact K for the rest.
        if (mode == "hyb" && !creeping)
        {
          assembler.assemble(x, k, CompressedSprings::Keep);
          bool ok = solveShifted(solver, k, reg, r, d);
          tangent = "exact";
          if (!ok)
          {
            assembler.assemble(x, k, CompressedSprings::Drop);
            ok = solveShifted(solver, k, reg, r, d);
            tangent = "drop";
          }
          if (ok)
            step = backtrack();
          if (step == 0.0 || (tangent == "drop" && r.cwiseAbs().maxCoeff() > 0.5 * res))
            creeping = true;
        }
        int tries = 0;
        // The exact Hessian shifted by mu M: mu 0 tried first while it has been working.
        const double scale = k.diagonal().cwiseAbs().maxCoeff() / m;  // 1/s^2 where mu M matches K
        for (; step == 0.0; ++tries)
        {
          assembler.assemble(x, k, CompressedSprings::Keep);
          if (!solveShifted(solver, k, reg + mu * m, r, d))
          {
            mu = std::max(4.0 * mu, mu_floor * scale);
            continue;
          }
          // Predicted drop of the quadratic model with the exact K (k now holds K + shift).
          Eigen::VectorXd kd = k * d;
          kd -= (reg + mu * m) * d;
          const double predicted = r.dot(d) - 0.5 * d.dot(kd);
          Eigen::VectorXd trial = x;
          grid.addFree(d, trial);
          const Eigen::VectorXd tr = unbalanced(grid, trial);
          const double actual = energy - potential(grid, trial);
          const bool ok = (predicted > 0.0 && actual >= 0.25 * predicted) || tr.norm() < (1.0 - 1e-4) * r.norm();
          if (ok)
          {
            x = trial;
            r = tr;
            step = 1.0;
            char buf[64];
            std::snprintf(buf, sizeof buf, "exact+%.2gM(%d)", mu, tries);
            tangent = buf;
            mu = mu < mu_zero * scale ? 0.0 : mu_down * mu;
            break;
          }
          mu = std::max(4.0 * mu, mu_floor * scale);
          if (mu > 1e3 * scale)
            break;
        }
        if (step == 0.0)
        {
          std::printf("lm: no step\n");
          break;
        }
      }
      else if (mode == "ptc")
      {
        if (h == 0.0)
          h = 1e-2;
        for (;;)
        {
          assembler.assemble(x, k, CompressedSprings::Keep);
          if (solveShifted(solver, k, reg + m / (h * h), r, d))
            break;
          h *= 0.5;
        }
        // Full step, but not where it raises the energy and the force both (then h shrinks).
        Eigen::VectorXd trial = x;
        grid.addFree(d, trial);
        const Eigen::VectorXd tr = unbalanced(grid, trial);
        char buf[64];
        std::snprintf(buf, sizeof buf, "exact+M/h^2 h=%.3g", h);
        tangent = buf;
        if (potential(grid, trial) <= energy || tr.norm() < r.norm())
        {
          x = trial;
          r = tr;
          step = 1.0;
          h = std::min(h * std::max(old_norm / r.norm(), 0.5), 1e8);
          old_norm = r.norm();
        }
        else
          h *= 0.5;
      }
      std::printf("%4d %.3e step %.3g %-22s compressed %d cpu %.1f\n", it, res, step, tangent.c_str(), dropped, cpu() - t0);
      std::fflush(stdout);
    }
    std::printf("end: %d iterations, %.3e N, cpu %.1f s, energy %.12g J\n", it, r.cwiseAbs().maxCoeff(), cpu() - t0,
                potential(grid, x));
  }
  if (argc > 5)
  {
    std::ofstream out(argv[5], std::ios::binary);
    out.write(reinterpret_cast<const char*>(x.data()), static_cast<std::streamsize>(x.size() * sizeof(double)));
  }
  int dropped = 0;
  tangentStiffness(grid, x, CompressedSprings::Drop, &dropped);
  // A stable equilibrium: the exact Hessian positive definite. CHOLMOD's Cholesky of K with no
  // regularisation says whether it is; the lowest eigenvalues of K u = lambda M u (shift-invert
  // Lanczos, as the modal basis) say by how much.
  SparseMatrix k = tangentStiffness(grid, x, CompressedSprings::Keep);
  TangentSolver check(TangentSolverKind::Cholmod);
  Eigen::VectorXd d;
  const Eigen::VectorXd r_final = unbalanced(grid, x);
  const bool stable = check.solve(k, r_final, d, 0.0) && d.allFinite();
  const double kscale = k.diagonal().cwiseAbs().maxCoeff() / grid.particleMass();
  std::string lowest = "not computed";
  try
  {
    const ModalBasis basis = computeModalBasis(k, Eigen::VectorXd::Constant(k.rows(), grid.particleMass()), 3);
    char buf[160];
    std::snprintf(buf, sizeof buf, "%.4g, %.4g, %.4g 1/s^2 (largest diagonal K/m %.3g 1/s^2)", basis.eigenvalues(0),
                  basis.eigenvalues(1), basis.eigenvalues(2), kscale);
    lowest = buf;
  }
  catch (const std::exception& e)
  {
    lowest = std::string("not computed: ") + e.what();
  }
  std::printf("final: energy %.12g J, compressed springs %d, largest force %.3e N, exact K %s, cpu %.1f s\n"
              "lowest eigenvalues of K u = lambda M u: %s\n",
              potential(grid, x), dropped, r_final.cwiseAbs().maxCoeff(),
              stable ? "positive definite (stable)" : "not positive definite", cpu() - t0, lowest.c_str());
  return 0;
}
