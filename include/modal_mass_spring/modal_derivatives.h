// Modal derivatives (Barbic & James 2005): the second-order static response to pairs of linear modes,
// added to the modes to give a basis that can foreshorten (a swing pulls particles in).
#pragma once

#include "modal_mass_spring/grid.h"
#include "modal_mass_spring/modal_basis.h"
#include "modal_mass_spring/spring_forces.h"

#include <Eigen/Core>

#include <utility>
#include <vector>

namespace modal_mass_spring
{

// Psi_ij for i <= j among the linear modes: K(x_ref) Psi_ij = -(dK/dx[Phi_j]) Phi_i.
struct ModalDerivatives
{
  Eigen::MatrixXd psi;                     // free dofs x pairs, one column per pair
  std::vector<std::pair<int, int>> pairs;  // (i, j), i <= j, in the order of psi's columns
  Eigen::MatrixXd rhs;                     // (dK/dx[Phi_j]) Phi_i, the same columns
};

// One sparse LDLT of `stiffness` (K at x_ref on the free dofs), then one solve per pair of the
// columns of `modes`. Throws std::invalid_argument (naming the parameter 'basis') when `modes`
// has zero modes, where K is singular and the derivatives are not defined, and std::runtime_error when
// the factorisation fails.
ModalDerivatives computeModalDerivatives(const Grid& grid, const Eigen::VectorXd& x_ref, const SparseMatrix& stiffness,
                                         const ModalBasis& modes);

// What building a basis with modal derivatives did, for the start-up report and status.
struct DerivativeBasisInfo
{
  int linear_modes = 0;           // kept as the basis' first columns
  int derivative_directions = 0;  // added after them
  int derivatives_computed = 0;   // pairs i <= j, one solve each
  double seconds = 0.0;           // derivatives, mass-PCA and the reduced stiffness
  // Singular values of the weighted derivatives (outside the span of the modes, mass norm) relative to
  // the largest: the smallest kept, and the largest dropped (0 when none is dropped).
  double smallest_kept_singular_value = 0.0;
  double largest_dropped_singular_value = 0.0;
};

// The linear modes followed by num_derivative_modes directions from the derivatives of every pair of
// them: each Psi_ij weighted by lambda_1^2 / (lambda_i lambda_j) (Barbic & James: the derivatives
// of the softest modes matter most), its part in the span of the modes removed, then mass-PCA
// (the leading singular vectors in the M-norm). The result is mass-orthonormal; its
// reduced_stiffness is Phi^T K Phi (dense), and eigenvalues / frequencies hold the linear modes'
// values followed by the Ritz values of the derivative directions (which are rotated to diagonalise
// their block). Throws std::invalid_argument naming 'num_derivative_modes' when the derivatives span
// fewer independent directions than asked for.
ModalBasis buildDerivativeBasis(const Grid& grid, const Eigen::VectorXd& x_ref, const SparseMatrix& stiffness,
                                const Eigen::VectorXd& mass, const ModalBasis& modes, int num_derivative_modes,
                                DerivativeBasisInfo* info = nullptr);

}  // namespace modal_mass_spring
