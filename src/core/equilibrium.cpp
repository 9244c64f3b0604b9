// Static equilibrium by damped Newton with an energy line search.
#include "modal_mass_spring/equilibrium.h"

#include "modal_mass_spring/spring_forces.h"

#include <Eigen/SparseCholesky>

#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace modal_mass_spring
{
namespace
{

double potential(const Grid& grid, const Eigen::VectorXd& x)
{
  return springEnergy(grid, x) + gravityEnergy(grid, x);
}

// Net force (springs + gravity) on the free dofs.
Eigen::VectorXd unbalanced(const Grid& grid, const Eigen::VectorXd& x)
{
  Eigen::VectorXd f;
  springForces(grid, x, f);
  return grid.gatherFree(f + grid.gravityForce());
}

}  // namespace

Equilibrium solveEquilibrium(const Grid& grid, const Eigen::VectorXd& start, int max_iterations, double tolerance,
                             const EquilibriumProgress& progress)
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

  Equilibrium result;
  result.positions = start;
  Eigen::VectorXd r = unbalanced(grid, start);
  // K's pattern never changes: assembled in place, analysed once. Eigen's simplicial LDL^T, whose
  // pivots tell an indefinite K: with CHOLMOD's LLT Newton stalled near 1e-8 N on config/cloth.yaml.
  const TangentAssembler assembler(grid);
  Eigen::SimplicialLDLT<SparseMatrix> ldlt;
  SparseMatrix k;
  for (result.iterations = 0; result.iterations < max_iterations; ++result.iterations)
  {
    result.residual = r.cwiseAbs().maxCoeff();
    if (progress)
      progress(result.iterations, result.residual, target);
    if (result.residual <= target)
      return result;

    // The exact Hessian where it is positive definite (Newton converges quadratically near a
    // stable equilibrium); where compressed springs make it indefinite, the one without their
    // geometric part, which is semi-definite and so gives a descent direction.
    Eigen::VectorXd direction;
    for (CompressedSprings compressed : {CompressedSprings::Keep, CompressedSprings::Drop})
    {
      assembler.assemble(result.positions, k, compressed);
      const double regularisation = 1e-8 * k.diagonal().cwiseAbs().maxCoeff();
      for (int i = 0; i < k.rows(); ++i)
        k.coeffRef(i, i) += regularisation;
      if (result.iterations == 0)
        ldlt.analyzePattern(k);
      ldlt.factorize(k);
      if (ldlt.info() == Eigen::Success && ldlt.vectorD().minCoeff() > 0.0)
      {
        direction = ldlt.solve(r);
        break;
      }
    }
    if (direction.size() == 0 || !direction.allFinite())
      break;

    // Backtrack until the energy drops (Armijo) or, where energy differences are lost in round-off
    // near the solution, the unbalanced force shrinks.
    const double energy = potential(grid, result.positions);
    const double slope = r.dot(direction);  // -dE/ds along the direction, > 0
    bool accepted = false;
    for (double s = 1.0; s > 1e-10 && !accepted; s *= 0.5)
    {
      Eigen::VectorXd trial = result.positions;
      grid.addFree(s * direction, trial);
      const Eigen::VectorXd trial_r = unbalanced(grid, trial);
      const double trial_energy = potential(grid, trial);
      if (trial_energy <= energy - 1e-4 * s * slope || trial_r.norm() < (1.0 - 1e-4 * s) * r.norm())
      {
        result.positions = trial;
        r = trial_r;
        accepted = true;
      }
    }
    if (!accepted)
    {
      // No further progress: the unbalanced force is at the round-off of the spring forces.
      // Accept when that is small anyway (the square root of the tolerance).
      if (r.cwiseAbs().maxCoeff() <= fallback)
      {
        result.residual = r.cwiseAbs().maxCoeff();
        return result;
      }
      break;
    }
  }
  result.residual = r.cwiseAbs().maxCoeff();
  if (result.residual <= target)
    return result;
  std::ostringstream msg;
  msg << "static equilibrium not found: Newton stopped after " << result.iterations << " iterations"
      << (result.iterations >= max_iterations ? " (its limit)" : " (no descent left)") << " with an unbalanced force of " << result.residual << " N (tolerance " << target
      << " N, of which the spring forces' round-off is about " << roundoff
      << " N); use linearization 'rest' and initial_state 'initial', which need no equilibrium";
  throw std::runtime_error(msg.str());
}

}  // namespace modal_mass_spring
