// Spring forces (paper eq. 13), energy and the analytic tangent stiffness K(x) = -df/dx.
#pragma once

#include "modal_mass_spring/grid.h"

#include <Eigen/SparseCore>

#include <vector>

namespace modal_mass_spring
{

using SparseMatrix = Eigen::SparseMatrix<double>;

// Sum of all spring forces on every dof at positions x (gravity not included); with `energy`, also
// the spring energy, from the same lengths at little extra cost.
void springForces(const Grid& grid, const Eigen::VectorXd& x, Eigen::VectorXd& f, double* energy = nullptr);

// The round-off of the spring forces on one dof at positions x (N): a spring's force
// k (l - l0) d / l is computed from coordinates of size |x|, so it carries an error of about
// k |x| eps, and a particle sums up to 12 of them. No iteration brings an unbalanced force below it.
double springForceRoundoff(const Grid& grid, const Eigen::VectorXd& x);

// Total spring energy sum 1/2 k (l - l0)^2.
double springEnergy(const Grid& grid, const Eigen::VectorXd& x);

// Potential energy of gravity, -f_g . x.
double gravityEnergy(const Grid& grid, const Eigen::VectorXd& x);

// How the geometric part (1 - l0/l)(I - u u^T) of a compressed spring (l < l0) enters K.
enum class CompressedSprings
{
  Keep,  // the exact Hessian
  Drop,  // keep only k u u^T: K stays positive semi-definite (used at a hanging equilibrium)
};

// The Hessian of the spring energy restricted to the free dofs (free-dof numbering of the grid).
SparseMatrix tangentStiffness(const Grid& grid, const Eigen::VectorXd& x,
                              CompressedSprings compressed = CompressedSprings::Keep,
                              int* num_dropped = nullptr);

// K(x) assembled again and again on one grid: its pattern and where each spring's entries land in its
// values are found once, so an assembly writes the values in place (an assembly from triplets, sorting
// 36 per spring, costs several times more).
class TangentAssembler
{
public:
  explicit TangentAssembler(const Grid& grid);
  // k <- K(x) (as tangentStiffness); k takes the kept pattern unless it has it already.
  void assemble(const Eigen::VectorXd& x, SparseMatrix& k, CompressedSprings compressed = CompressedSprings::Keep,
                int* num_dropped = nullptr) const;

private:
  template <int Dim>
  void assembleDim(const Eigen::VectorXd& x, SparseMatrix& k, CompressedSprings compressed, int& dropped) const;

  const Grid& grid_;
  SparseMatrix pattern_;
  std::vector<int> slots_;  // per spring, blocks (i, i), (j, j), (i, j), (j, i), column-major: -1 for a fixed dof
};

// dK/dx[direction]: the directional derivative of the exact tangent K(x) (CompressedSprings::Keep)
// along a free-dof displacement, the third derivative of the spring energy contracted with it. Free-dof
// numbering; (dK/dx[Phi_j]) Phi_i is the right-hand side of the modal derivative Psi_ij.
SparseMatrix tangentStiffnessDerivative(const Grid& grid, const Eigen::VectorXd& x, const Eigen::VectorXd& direction);

// (K(x) Phi)^T from Phi^T (r x free dofs) without assembling K: a spring adds its 2 x 2 block
// pattern to the rows of its two particles. The reduced tangent Phi^T K Phi then costs O(springs r
// + n r^2) instead of an assembly of K per Newton iteration.
void tangentTimesBasis(const Grid& grid, const Eigen::VectorXd& x, const Eigen::MatrixXd& phi_t,
                       Eigen::MatrixXd& k_phi_t);

}  // namespace modal_mass_spring
