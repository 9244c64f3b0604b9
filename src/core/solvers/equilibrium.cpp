// Static equilibrium by damped Newton with an energy line search.
#include "solvers/equilibrium.h"

#include "modal_mass_spring/spring_forces.h"
#include "solvers/tangent_solver.h"

#include <Eigen/SparseCholesky>

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace modal_mass_spring
{
namespace
{

// Saddles a solve leaves along negative curvature before it returns the state it is at.
constexpr int kMaxSaddleEscapes = 10;

double potential(const Grid& grid, const Eigen::VectorXd& x)
{
  return springEnergy(grid, x) + gravityEnergy(grid, x);
}

// Net force (springs + gravity) on the free dofs.
Eigen::VectorXd unbalanced(const Grid& grid, const Eigen::VectorXd& x)
{
  Eigen::VectorXd f;
  springAndGravityForces(grid, x, f);
  return grid.gatherFree(f);
}

// Newton's direction K^-1 r. CHOLMOD's supernodal LLT (BLAS) factorises a 100 x 100 cloth's tangent
// several times faster than the simplicial LDL^T; its solve is refined against K, because near a
// flat start K is nearly singular (out of its plane only the 1e-8 regularisation holds a sheet), and
// there an unrefined solve is accurate to only about cond(K) eps of r, which stalled Newton near
// 1e-8 N on config/cloth.yaml. The simplicial LDL^T, whose pivots tell an indefinite K, where
// CHOLMOD's factorisation fails or its direction makes no progress.
class NewtonDirection
{
public:
  NewtonDirection() : cholmod_(TangentSolverKind::Cholmod), simplicial_(TangentSolverKind::SimplicialLdlt) {}

  // d <- (K + regularisation)^-1 r with the exact Hessian where that is positive definite, else the
  // one without compressed springs' geometric part; false where neither gives a descent direction.
  bool solve(const TangentAssembler& assembler, const Eigen::VectorXd& x, const Eigen::VectorXd& r,
             bool simplicial_only, Eigen::VectorXd& d)
  {
    // The simplicial factorisation only where CHOLMOD's failed on both: an indefinite exact Hessian,
    // which CHOLMOD refuses at once, would only be refused again after a whole simplicial one.
    if (!simplicial_only && solveWith(cholmod_, assembler, x, r, d))
      return true;
    return solveWith(simplicial_, assembler, x, r, d);
  }

  // d <- (K + regularisation + shift I)^-1 r with the exact Hessian; false where that is not positive
  // definite. `predicted` <- the energy drop the quadratic model with the exact K predicts along d.
  bool solveShifted(const TangentAssembler& assembler, const Eigen::VectorXd& x, const Eigen::VectorXd& r,
                    double shift, bool simplicial_only, Eigen::VectorXd& d, double& predicted)
  {
    TangentSolver& solver = simplicial_only ? simplicial_ : cholmod_;
    assembler.assemble(x, k_, CompressedSprings::Keep);
    const double added = 1e-8 * k_.diagonal().cwiseAbs().maxCoeff() + shift;
    addToDiagonal(added);
    if (!solver.solve(k_, r, d, 0.0) || !refine(solver, r, d))
      return false;
    predicted = r.dot(d) - 0.5 * (d.dot(k_ * d) - added * d.squaredNorm());
    return true;
  }
  // Whether x is a saddle: the exact Hessian (+ regularisation) not positive definite there. If so, v <-
  // its most negative curvature direction (unit; inverse iteration on K + sigma I, sigma raised until
  // that factorises), lambda <- v^T K v (N/m), sigma <- the shift used (N/m); false where K is positive
  // definite or no negative curvature is found.
  bool negativeCurvature(const TangentAssembler& assembler, const Eigen::VectorXd& x, const Eigen::VectorXd& r,
                         bool simplicial_only, Eigen::VectorXd& v, double& lambda, double& sigma)
  {
    TangentSolver& solver = simplicial_only ? simplicial_ : cholmod_;
    assembler.assemble(x, k_, CompressedSprings::Keep);
    const SparseMatrix exact = k_;
    const double largest = k_.diagonal().cwiseAbs().maxCoeff();
    const double regularisation = 1e-8 * largest;
    Eigen::VectorXd d;
    for (sigma = 0.0;; sigma = std::max(2.0 * sigma, 1e-6 * largest))
    {
      k_ = exact;
      addToDiagonal(regularisation + sigma);
      if (solver.solve(k_, r, d, 0.0) && d.allFinite())
        break;
      if (sigma > 10.0 * largest)
        return false;
    }
    if (sigma == 0.0)
      return false;  // stable
    // A fixed start (no random state): every component nonzero, so no eigenvector is missed.
    v = Eigen::VectorXd::LinSpaced(k_.rows(), 1.0, 2.0).normalized();
    for (int pass = 0; pass < kInverseIterations; ++pass)
    {
      Eigen::VectorXd w;
      if (!solver.solveWithFactor(v, w) || !w.allFinite())
        return false;
      v = w.normalized();
    }
    lambda = v.dot(exact * v);
    return lambda < 0.0;
  }

  // Whether the last direction of solve() came from the tangent without compressed springs' geometric part.
  bool dropped() const { return dropped_; }
  // The largest diagonal entry of the last tangent assembled.
  double largestDiagonal() const { return k_.diagonal().cwiseAbs().maxCoeff(); }

private:
  bool solveWith(TangentSolver& solver, const TangentAssembler& assembler, const Eigen::VectorXd& x,
                 const Eigen::VectorXd& r, Eigen::VectorXd& d)
  {
    for (CompressedSprings compressed : {CompressedSprings::Keep, CompressedSprings::Drop})
    {
      assembler.assemble(x, k_, compressed);
      const double regularisation = 1e-8 * k_.diagonal().cwiseAbs().maxCoeff();
      addToDiagonal(regularisation);
      dropped_ = compressed == CompressedSprings::Drop;
      if (solver.solve(k_, r, d, 0.0) && refine(solver, r, d))
        return true;
    }
    return false;
  }


  // Iterative refinement: d += K^-1 (r - K d) while the residual of the linear system shrinks.
  bool refine(TangentSolver& solver, const Eigen::VectorXd& r, Eigen::VectorXd& d)
  {
    if (!d.allFinite())
      return false;
    Eigen::VectorXd residual = r - k_ * d;
    double norm = residual.norm();
    for (int pass = 0; pass < kMaxRefinements && norm > 1e-15 * r.norm(); ++pass)
    {
      Eigen::VectorXd correction;
      if (!solver.solveWithFactor(residual, correction))
        break;
      const Eigen::VectorXd refined = d + correction;
      const Eigen::VectorXd refined_residual = r - k_ * refined;
      if (!(refined_residual.norm() < 0.5 * norm))
        break;
      d = refined;
      residual = refined_residual;
      norm = residual.norm();
    }
    return r.dot(d) > 0.0;
  }

  void addToDiagonal(double value)
  {
    for (int i = 0; i < k_.rows(); ++i)
      k_.coeffRef(i, i) += value;
  }

  static constexpr int kMaxRefinements = 3;
  static constexpr int kInverseIterations = 50;
  TangentSolver cholmod_, simplicial_;
  SparseMatrix k_;
  bool dropped_ = false;
};

// One solve's state and its steps: Newton with a backtracking line search, Levenberg-Marquardt on the
// exact Hessian once the drop tangent creeps, and the escape from a saddle (equilibrium.h says when each).
class EquilibriumSolve
{
public:
  EquilibriumSolve(const Grid& grid, const Eigen::VectorXd& start, EquilibriumSolver solver)
    : grid_(grid), assembler_(grid), simplicial_only_(solver == EquilibriumSolver::SimplicialLdlt)
  {
    result_.positions = start;
    r_ = unbalanced(grid, start);
  }

  Equilibrium& result() { return result_; }
  double largestForce() const { return r_.cwiseAbs().maxCoeff(); }

  // One iteration's step: true where one was accepted.
  bool step() { return creeping_ ? levenbergMarquardtStep() : newtonStep(); }

  // Levenberg-Marquardt, like Newton, also converges to saddles (mu M keeps K + mu M positive definite
  // there): a buckled sheet balanced on one is pushed along its most negative curvature, as far
  // (halving from one spacing) as lowers the energy most, and the solve goes on from there. True where
  // it moved the sheet.
  bool leaveSaddle()
  {
    Eigen::VectorXd v;
    double lambda = 0.0, sigma = 0.0;
    if (!creeping_ || escapes_ >= kMaxSaddleEscapes ||
        !newton_.negativeCurvature(assembler_, result_.positions, r_, simplicial_only_, v, lambda, sigma))
      return false;
    const double spacing = grid_.params().spacing;
    const double energy = potential(grid_, result_.positions);
    double best_drop = 0.0;
    Eigen::VectorXd best = result_.positions;
    for (double a = spacing; a > 1e-6 * spacing; a *= 0.5)
      for (double sign : {1.0, -1.0})
      {
        Eigen::VectorXd trial = result_.positions;
        grid_.addFree(sign * a * v, trial);
        const double drop = energy - potential(grid_, trial);
        if (drop > best_drop)
        {
          best_drop = drop;
          best = trial;
        }
      }
    if (best_drop <= 0.0)
      return false;
    result_.positions = best;
    r_ = unbalanced(grid_, result_.positions);
    mu_ = sigma / grid_.particleMass();  // K + mu M just positive definite here
    in_stable_basin_ = false;
    ++escapes_;
    return true;
  }

private:
  // Levenberg-Marquardt on the exact Hessian: K + mu M, mu raised until K + mu M factorises and the
  // step lowers the energy by a quarter of the model's prediction (or, where energy differences are
  // round-off, the unbalanced force); lowered after each accepted step, to 0 (plain Newton) once the
  // sheet sits in a stable state's basin.
  bool levenbergMarquardtStep()
  {
    const double mass = grid_.particleMass();
    const double mu_scale = newton_.largestDiagonal() / mass;  // where mu M is as stiff as K
    const double energy = potential(grid_, result_.positions);
    while (mu_ <= 1e3 * mu_scale)
    {
      Eigen::VectorXd direction;
      double predicted = 0.0;
      if (newton_.solveShifted(assembler_, result_.positions, r_, mu_ * mass, simplicial_only_, direction, predicted))
      {
        Eigen::VectorXd trial = result_.positions;
        grid_.addFree(direction, trial);
        const Eigen::VectorXd trial_r = unbalanced(grid_, trial);
        const double drop = energy - potential(grid_, trial);
        if ((predicted > 0.0 && drop >= 0.25 * predicted) ||
            (trial_r.norm() < (1.0 - 1e-4) * r_.norm() && (in_stable_basin_ || drop >= 0.0)))
        {
          result_.positions = trial;
          r_ = trial_r;
          in_stable_basin_ = in_stable_basin_ || mu_ == 0.0;
          mu_ = mu_ < 1e-9 * mu_scale ? 0.0 : 0.3 * mu_;
          return true;
        }
      }
      // From about the regularisation: a larger restart swamps a buckled sheet's small negative
      // curvature and cycles (docs/benchmarks.md, "Released at 60 degrees").
      mu_ = std::max(4.0 * mu_, 1e-8 * mu_scale);
    }
    return false;
  }

  // Newton: the exact Hessian where it is positive definite (quadratic convergence near a stable
  // equilibrium); where compressed springs make it indefinite, the one without their geometric part,
  // which is semi-definite and so gives a descent direction. On CHOLMOD, then once more on the
  // simplicial LDL^T where CHOLMOD's direction made no progress.
  bool newtonStep()
  {
    for (;;)
    {
      Eigen::VectorXd direction;
      if (!newton_.solve(assembler_, result_.positions, r_, simplicial_only_, direction))
        return false;
      if (backtrack(direction))
        return true;
      if (simplicial_only_)
        return false;
      simplicial_only_ = true;  // the same iteration again on the simplicial LDL^T
    }
  }

  // Backtrack along a Newton direction until the energy drops (Armijo) or, where energy differences
  // are lost in round-off near the solution, the unbalanced force shrinks.
  bool backtrack(const Eigen::VectorXd& direction)
  {
    const double energy = potential(grid_, result_.positions);
    const double slope = r_.dot(direction);  // -dE/ds along the direction, > 0
    for (double s = 1.0; s > 1e-10; s *= 0.5)
    {
      Eigen::VectorXd trial = result_.positions;
      grid_.addFree(s * direction, trial);
      const Eigen::VectorXd trial_r = unbalanced(grid_, trial);
      const double trial_energy = potential(grid_, trial);
      if (trial_energy <= energy - 1e-4 * s * slope || trial_r.norm() < (1.0 - 1e-4 * s) * r_.norm())
      {
        // A buckling sheet: the tangent without compressed springs' geometric part overestimates
        // the buckling directions' stiffness and the force falls a few percent an iteration
        // (docs/benchmarks.md, "Released at 60 degrees"); from the first such step on, the shifted exact
        // Hessian. Flat starts, whose drop-tangent steps converge fast, keep this path.
        if (newton_.dropped() && trial_r.cwiseAbs().maxCoeff() > 0.5 * r_.cwiseAbs().maxCoeff())
          creeping_ = true;
        result_.positions = trial;
        r_ = trial_r;
        return true;
      }
    }
    return false;
  }

  const Grid& grid_;
  Equilibrium result_;
  Eigen::VectorXd r_;                  // the unbalanced force at result_.positions
  const TangentAssembler assembler_;  // K's pattern never changes: assembled in place, analysed once
  NewtonDirection newton_;
  bool simplicial_only_;  // once a CHOLMOD direction made no progress, the simplicial LDL^T for the rest
  bool creeping_ = false;  // once the drop tangent creeps: Levenberg-Marquardt with shift mu M (1/s^2)
  double mu_ = 0.0;
  int escapes_ = 0;  // saddles left so far
  // Whether a step may be accepted for a smaller force alone: not after an escape until plain Newton
  // (mu = 0, the exact Hessian positive definite) has taken one.
  bool in_stable_basin_ = true;
};

}  // namespace

Equilibrium solveEquilibrium(const Grid& grid, const Eigen::VectorXd& start, int max_iterations, double tolerance,
                             const EquilibriumProgress& progress, EquilibriumSolver solver)
{
  const GridParams& p = grid.params();
  // Forces are compared with one particle's weight, or without gravity with a small spring force.
  const double weight = p.mass * p.gravity.norm();
  const double scale = weight > 0.0 ? weight : p.structural_stiffness * p.spacing;
  // No iteration gets the unbalanced force below the round-off of the spring forces; on stiff grids
  // that is above 1e-9 of a weight.
  const double roundoff = springForceRoundoff(grid, start);
  const double target = std::max(tolerance * scale, 10.0 * roundoff);
  const double fallback = std::max(std::sqrt(tolerance) * scale, 1000.0 * roundoff);

  EquilibriumSolve solve(grid, start, solver);
  Equilibrium& result = solve.result();
  for (result.iterations = 0; result.iterations < max_iterations; ++result.iterations)
  {
    result.residual = solve.largestForce();
    if (progress)
      progress(result.iterations, result.residual, target);
    if (result.residual <= target)
    {
      if (solve.leaveSaddle())
        continue;
      return result;
    }
    if (!solve.step())
    {
      // No further progress: the unbalanced force is at the round-off of the spring forces.
      // Accept when that is small anyway (the square root of the tolerance).
      if (solve.leaveSaddle())
        continue;
      if (solve.largestForce() <= fallback)
      {
        result.residual = solve.largestForce();
        return result;
      }
      break;
    }
  }
  result.residual = solve.largestForce();
  if (result.residual <= target)
    return result;
  std::ostringstream msg;
  msg << "static equilibrium not found: Newton stopped after " << result.iterations << " iterations"
      << (result.iterations >= max_iterations ? " (its limit)" : " (no descent left)") << " with an unbalanced force of "
      << result.residual << " N (tolerance " << target << " N, of which the spring forces' round-off is about "
      << roundoff << " N); "
      << (result.iterations >= max_iterations
              ? "raise equilibrium_max_iterations (now " + std::to_string(max_iterations) + "), or "
              : std::string())
      << "use linearization 'rest' and initial_state 'initial', which need no equilibrium";
  throw std::runtime_error(msg.str());
}

}  // namespace modal_mass_spring
