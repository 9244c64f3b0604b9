// The static equilibrium of a grid under gravity, the linearization point of `equilibrium`.
#pragma once

#include "modal_mass_spring/grid.h"

#include <Eigen/Core>

#include <functional>

namespace modal_mass_spring
{

struct Equilibrium
{
  Eigen::VectorXd positions;   // all dofs
  int iterations = 0;          // Newton iterations taken
  double residual = 0.0;       // largest unbalanced force component left, N
};

// Newton on the free dofs from `start`, the fixed particles held. The direction (CHOLMOD's
// supernodal Cholesky, refined; the simplicial LDL^T where that fails or makes no progress) comes from the
// tangent with compressed springs' geometric part dropped (positive semi-definite, so a descent
// direction of the potential energy) plus a 1e-8 relative regularisation (a flat 3D sheet has no
// out-of-plane stiffness); a backtracking line search on the energy makes it converge from far away,
// such as a sheet rotated 45 degrees out of the vertical. Once a step on the tangent without the
// compressed springs' part leaves more than half the largest force (a buckling sheet, on which that
// tangent creeps), Levenberg-Marquardt on the exact Hessian for the rest: K + mu M, mu raised until
// that factorises and the step lowers the energy, lowered after each accepted step down to plain Newton;
// where it balances on a saddle (the exact Hessian not positive definite), a step along the most
// negative curvature and on (at most 10 times), so that a buckled sheet hangs in a stable state. A flat
// start keeps Newton's path, and a flat sheet its flat (saddle) state. Converged when every unbalanced force
// component is below `tolerance` times one particle's weight, or, once the line search can make no
// more progress (round-off), below its square root; never below ten times the round-off of the
// spring forces (about stiffness x coordinates x machine epsilon), which on stiff grids is the
// larger. Throws std::runtime_error otherwise, saying whether the iteration limit stopped it.
// `progress`, when given, is told each iteration's number, its largest unbalanced force and the
// target (N) before the iteration, so that a slow solve can be reported.
// The limit, when it stops Newton, is named in the refusal as the parameter equilibrium_max_iterations.
using EquilibriumProgress = std::function<void(int iteration, double residual, double target)>;
// `solver` SimplicialLdlt keeps to the simplicial LDL^T throughout: for tests and the benchmark's
// side-by-side comparison.
enum class EquilibriumSolver
{
  Cholmod,
  SimplicialLdlt,
};
constexpr int kDefaultEquilibriumMaxIterations = 1000;
constexpr double kEquilibriumTolerance = 1e-9;
Equilibrium solveEquilibrium(const Grid& grid, const Eigen::VectorXd& start,
                             int max_iterations = kDefaultEquilibriumMaxIterations,
                             double tolerance = kEquilibriumTolerance, const EquilibriumProgress& progress = {},
                             EquilibriumSolver solver = EquilibriumSolver::Cholmod);

}  // namespace modal_mass_spring
