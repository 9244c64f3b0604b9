// How far a reduced state is from what `full` would do there, estimated from the state alone (Kim
// and James 2009 watch the same residual to leave the subspace). The full model's force at the
// reconstructed positions, f(x) (springs and external), has a part r the method's coordinates cannot
// represent, which the reduced model drops and `full` would act on: for a modal method
//   r = f - M Phi Phi^T f        (Phi mass-orthonormal on the free dofs: Phi^T M Phi = I),
// for `coarse` the same with the interpolation from the coarse grid (CoarseGrid::outsideSpan). The
// estimate is the displacement that balances it, du = (L + M / tau^2)^-1 r (L the springs'
// Laplacian, constant and factorised once; tau = 1 s keeps the rigid motions, which L does not
// resist, bounded), as an RMS over the free particles (m): the same measure as the distance to
// `full` it stands for. What the coarse grid leaves out has wavelengths below its spacing, where L
// acts within a factor of about two as its diagonal does: `coarse` balances r through the diagonal
// alone, O(n) instead of a solve that costs tens of coarse steps (docs/results.md).
#pragma once

#include "modal_mass_spring/grid.h"

#include <Eigen/Core>
#include <Eigen/SparseCholesky>

namespace modal_mass_spring
{

class ErrorIndicator
{
public:
  // `mass`: the diagonal of M on the free dofs.
  ErrorIndicator(const Grid& grid, const Eigen::VectorXd& mass);
  // The full model's force on the free dofs at positions x (every dof), with the external force on
  // every dof (empty: none; gravity is the grid's own and is added here).
  Eigen::VectorXd force(const Eigen::VectorXd& x, const Eigen::VectorXd& external) const;
  // The estimate (m) for the part r of that force outside the method's span: through the solve
  // (factorised at the first call), or through the diagonal alone.
  double balance(const Eigen::VectorXd& r);
  double balanceLocally(const Eigen::VectorXd& r) const;

private:
  double rms(const Eigen::VectorXd& du) const;  // over the free particles, mass-weighted

  static constexpr double kTau = 1.0;  // s
  const Grid& grid_;
  Eigen::VectorXd mass_;
  double particle_mass_ = 0.0;  // the free particles' total mass
  Eigen::VectorXd diagonal_;  // of L + M / tau^2
  Eigen::SimplicialLLT<Eigen::SparseMatrix<double>> factor_;
  bool factored_ = false;
};

}  // namespace modal_mass_spring
