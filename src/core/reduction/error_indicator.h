// How far a reduced state is from what `full` would do there, estimated from the state alone (Kim
// and James 2009 watch the same residual to leave the subspace). The full model's force at the
// reconstructed positions, f(x) (springs and external), has a part the span cannot represent,
//   r = f - M Phi Phi^T f        (Phi mass-orthonormal on the free dofs: Phi^T M Phi = I),
// which the reduced model drops and `full` would act on. The estimate is the displacement that
// balances it, du = (L + M / tau^2)^-1 r (L the springs' Laplacian, constant and factorised once;
// tau = 1 s keeps the rigid motions, which L does not resist, bounded), as an RMS over the free
// particles (m): the same measure as the distance to `full` it stands for.
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
  // The estimate (m) at positions x (every dof) with the free-dof basis phi and the external force
  // on every dof (gravity is the grid's own and is added here).
  double estimate(const Eigen::VectorXd& x, const Eigen::MatrixXd& phi, const Eigen::VectorXd& external) const;

private:
  static constexpr double kTau = 1.0;  // s
  const Grid& grid_;
  Eigen::VectorXd mass_;
  double particle_mass_ = 0.0;  // the free particles' total mass
  Eigen::SimplicialLLT<Eigen::SparseMatrix<double>> factor_;
};

}  // namespace modal_mass_spring
