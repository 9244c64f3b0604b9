// The whole grid's spring forces, energy and tangent stiffness K(x) = -df/dx, summed over its springs
// from the spring law (spring_law.h).
#pragma once

#include "modal_mass_spring/grid.h"
#include "modal_mass_spring/spring_law.h"

#include <Eigen/SparseCore>

#include <vector>

namespace modal_mass_spring
{

using SparseMatrix = Eigen::SparseMatrix<double>;

// Sum of all spring forces on every dof at positions x (gravity not included); with `energy`, also
// the spring energy, from the same lengths at little extra cost.
void springForces(const Grid& grid, const Eigen::VectorXd& x, Eigen::VectorXd& f, double* energy = nullptr);

// The springs' force plus gravity on every dof at positions x: the grid's own force, what balances
// at its equilibrium. `spring_energy` as springForces.
void springAndGravityForces(const Grid& grid, const Eigen::VectorXd& x, Eigen::VectorXd& f,
                            double* spring_energy = nullptr);

// The round-off of the spring forces on one dof at positions x (N): a spring's force
// k (l - l0) d / l is computed from coordinates of size |x|, so it carries an error of about
// k |x| eps, and a particle sums up to 12 of them. No iteration brings an unbalanced force below it.
double springForceRoundoff(const Grid& grid, const Eigen::VectorXd& x);

// Total spring energy sum 1/2 k (l - l0)^2.
double springEnergy(const Grid& grid, const Eigen::VectorXd& x);

// Potential energy of gravity, -f_g . x.
double gravityEnergy(const Grid& grid, const Eigen::VectorXd& x);

// The Hessian of the spring energy restricted to the free dofs (free-dof numbering of the grid).
SparseMatrix tangentStiffness(const Grid& grid, const Eigen::VectorXd& x,
                              CompressedSprings compressed = CompressedSprings::Keep,
                              int* num_dropped = nullptr);

// The springs' Laplacian sum_s k_s G_s^T G_s on the free dofs (G_s x = x_i - x_j, each dof
// direction alike): constant, and at least K(x) at every x (a spring's Hessian is k_s along it and
// k_s (1 - L / l) < k_s across), so an implicit step solved with it in place of K descends.
SparseMatrix springLaplacian(const Grid& grid);
// Its diagonal alone, without forming the matrix (each spring's k_s on both ends' free dofs).
Eigen::VectorXd springLaplacianDiagonal(const Grid& grid);

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

// K(x) kept as its springs' blocks, never assembled: a spring s = (i, j) with Hessian block k_s adds
// k_s (p_i - p_j) to (K p)_i and its negative to (K p)_j. A product then reads one Dim x Dim block a
// spring where a sparse K holds four (and an index per entry): several times less memory traffic, which
// bounds the products of conjugate gradients. The exact Hessian (CompressedSprings::Keep).
class SpringTangent
{
public:
  explicit SpringTangent(const Grid& grid);
  // The springs' blocks at positions x (all dofs).
  void update(const Eigen::VectorXd& x);
  // y += scale K p (free-dof numbering).
  void multiplyAdd(const Eigen::VectorXd& p, double scale, Eigen::VectorXd& y) const;
  // blocks += scale K's Dim x Dim diagonal blocks, one a free particle, Dim^2 values each (column-major).
  void addDiagonalBlocks(double scale, Eigen::VectorXd& blocks) const;

private:
  template <int Dim>
  void multiplyAddDim(const Eigen::VectorXd& p, double scale, Eigen::VectorXd& y) const;

  const Grid& grid_;
  std::vector<int> order_;        // the grid's springs, those with both ends free first
  int num_interior_ = 0;          // how many have both ends free
  std::vector<int> ends_;         // per spring in that order, the free dofs where its ends i and j start; -1 fixed
  std::vector<double> hessians_;  // per spring in that order, k_s (Dim^2 values)
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
