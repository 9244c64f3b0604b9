// The r lowest modes of K u = lambda^2 M u, mass-normalised (Phi^T M Phi = I).
#pragma once

#include "modal_mass_spring/spring_forces.h"

#include <Eigen/Core>

#include <algorithm>
#include <functional>
#include <string>

namespace modal_mass_spring
{

struct ModalBasis
{
  Eigen::MatrixXd phi;          // free dofs x r, columns are the modes
  Eigen::VectorXd eigenvalues;  // lambda^2, ascending
  Eigen::VectorXd frequencies;  // omega = sqrt(lambda^2) in rad/s (0 for numerically zero modes)
  int num_zero_modes = 0;       // lambda^2 below 1e-8 of the largest diagonal stiffness per mass
  bool sparse = true;           // false only when r is so close to the size that Lanczos cannot run
  double shift = 0.0;           // sigma of the shift-invert, negative so K - sigma M stays regular
  int deflation_passes = 0;     // extra Lanczos passes that looked for more of a large null space
  double build_seconds = 0.0;
  double factorization_seconds = 0.0;  // of build_seconds, the sparse LDLT of K - sigma M, regrouped for the solves
  // Phi^T K Phi (r x r, dense) when the columns are not all eigenvectors of K (a basis with modal
  // derivatives: the reduced stiffness and Rayleigh damping are then dense); empty for an eigenbasis,
  // where it is diag(eigenvalues).
  Eigen::MatrixXd reduced_stiffness;
};

// Told the name of each stage of a long computation as it starts ("factorisation", "eigensolver"),
// so a caller can say what a slow start-up is doing.
using StageFn = std::function<void(const std::string& stage)>;
// Told how the iterations of a long stage go, so a caller can show that it moves: "equilibrium" with
// Newton's iteration, its largest unbalanced force and the target (N); "eigensolver" with the Lanczos
// step, the largest residual estimate of the wanted Ritz values relative to them and the tolerance.
using IterationFn = std::function<void(const std::string& stage, int iteration, double residual, double target)>;

// The most Lanczos vectors (of the free dofs' length) computeModalBasis holds for r modes; for memory
// estimates.
inline int maxLanczosVectors(int r) { return std::max(4 * r, r + 80) + 1; }

// K: free-dof stiffness (symmetric, positive semi-definite); mass: the diagonal of M over the same
// dofs. Throws std::invalid_argument for r outside [1, size] and std::runtime_error when the
// eigensolver does not converge.
ModalBasis computeModalBasis(const SparseMatrix& stiffness, const Eigen::VectorXd& mass, int r,
                             const StageFn& on_stage = {}, const IterationFn& on_iteration = {});

}  // namespace modal_mass_spring
