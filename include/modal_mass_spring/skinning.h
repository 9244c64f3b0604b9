// The skinning subspace: every particle moved by a blend of a few affine transforms,
//   x_i = sum_j w_ij (A_j (xbar_i - c) + t_j) + c,
// with weights w_j from the cloth's own stiffness (skinning eigenmodes, Benchekroun et al. 2023). The
// displacement is linear in the transforms' entries z, u = B z, so the subspace holds any rotation of
// the whole cloth exactly and of every region as far as the weights can tell the regions apart.
#pragma once

#include "modal_mass_spring/grid.h"
#include "modal_mass_spring/modal_basis.h"
#include "modal_mass_spring/spring_forces.h"

#include <Eigen/Core>

#include <random>
#include <string>
#include <vector>

namespace modal_mass_spring
{

// Reduced coordinates per weight: a dim x dim matrix and a dim translation.
inline int skinningCoordinatesPerWeight(int dimension) { return (dimension + 1) * dimension; }

// The held groups of the skinning weights: each handle's particles, handle by handle, then the fixed
// particles as one group when there are any; empty when nothing is held.
std::vector<std::vector<int>> skinningHandleGroups(const Grid& grid);

// Particles x m weights from the spring graph's Laplacian L (edge weight k_s / L_s^2, L_s the spring's
// length at x) against the particle masses. Nothing held: its m lowest eigenvectors (the first
// constant: rigid and affine motions of the whole cloth are in the span). Else, with g held groups
// (skinningHandleGroups): first one harmonic weight per group, 1 on it, 0 on the others and L w = 0
// at every other particle (they sum to one: any affine map of all handles together is in the span,
// and a group's transform moves its particles alone); then the m - g lowest eigenvectors of L with
// every held particle as a Dirichlet boundary, zero there, so that the handles' constraints take
// the groups' coordinates only and every further weight's coordinates move the cloth between them.
// Throws std::invalid_argument naming num_skinning_weights outside [1, particles] (nothing held) or
// [g, g + particles neither held nor fixed], and naming handles and fixed when a part of the cloth is
// connected to no held particle.
Eigen::MatrixXd skinningWeights(const Grid& grid, const Eigen::VectorXd& x, int m);

// B over all dofs (numDofs x (dim + 1) dim m): column (j, a, b) moves dof a of particle i by
// w_ij (xbar_i,b - c_b) for b < dim (the entry A_j(a, b)) and by w_ij for b = dim (t_j(a)), with c the
// centroid of xbar (for conditioning; the span does not depend on it).
Eigen::MatrixXd skinningMap(const Grid& grid, const Eigen::VectorXd& xbar, const Eigen::MatrixXd& weights);

// What building the subspace found, for the start-up report (describeSkinning).
struct SkinningInfo
{
  int weights = 0;
  int coordinates = 0;        // (dim + 1) dim weights: the transforms' entries
  int constraint_dofs = 0;    // fixed and handle dofs, the equations B_c z = dx_c
  int constraint_rank = 0;    // of B_c: the held groups' affine motions are met exactly, the rest only by least squares
  int modes = 0;              // fixed-interface modes added to the span
  int basis_size = 0;         // the interior subspace's dimension (coordinates - rank + modes, less dependent directions)
  double seconds = 0.0;
};

// "skinning: 24 weights, 288 coordinates, 24 constraint dofs (fixed and handles) met exactly, with 30
// modes 294 directions for the free particles, built in 41 ms"; "... 60 constraint dofs (fixed and
// handles) of rank 18 (each held group's affine motions met exactly, the rest of 6 by least
// squares) ...".
std::string describeSkinning(const SkinningInfo& info);

struct SkinningBasis
{
  // Phi = B_i N (N the null space of B_c) rotated by Rayleigh-Ritz: Phi^T M Phi = I and
  // Phi^T K Phi = diag(eigenvalues), zero for the motions that stretch no spring.
  ModalBasis basis;
  // Psi (interior x handle dofs), the interior's part carried by the handles, in the span: the part of
  // dx_b that is an affine map of the handle particles (a rigid motion of the handles, a turn of any
  // angle included) moves the free particles by the same map, so a turned clamp turns the reference
  // x_ref + Psi dx_b and X carries only the deformation; the rest of dx_b moves them by B_i G, G the
  // least-squares solution of B_c z = (0, dx_b), made M-orthogonal to Phi. Empty without handles.
  Eigen::MatrixXd constraint_modes;
  SkinningInfo info;
};

// P = Phi^T M B_i (basis size x coordinates): the M-orthogonal projection of a skinning pose z onto
// the basis' coordinates, X = P z (handles at rest).
Eigen::MatrixXd skinningProjection(const Grid& grid, const Eigen::VectorXd& x_ref, const ModalBasis& basis,
                                   const Eigen::VectorXd& mass, int num_weights);

// `count` cubature training poses (columns of X) that turn the cloth: the first weight's region (the
// whole cloth when it is constant: nothing held, one handle, or only fixed particles) by a random
// rotation of up to 180 degrees, every further weight's transform by one of up to 90 / sqrt(j)
// degrees, projected by P, plus a pose of trainingPoses' law (stretches up to `size`). The rotations of the further weights are halved while a spring would be shortened
// below kShortestTrainingSpring of its length (the pose would fold the cloth).
Eigen::MatrixXd skinningTrainingPoses(const Grid& grid, const ModalBasis& basis, const Eigen::VectorXd& x_ref,
                                      const Eigen::MatrixXd& projection, int count, double size, std::mt19937_64& rng);

// `stiffness` and `mass`: K at x_ref and the diagonal of M on the free dofs. `modes` (free dofs x r,
// may be empty): interior directions added to the span, the fixed-interface modes, which carry the
// local bending near a clamp that a few smooth weights cannot. Throws std::invalid_argument naming
// num_skinning_weights when the span leaves the free particles nothing to move.
SkinningBasis buildSkinningBasis(const Grid& grid, const Eigen::VectorXd& x_ref, const SparseMatrix& stiffness,
                                 const Eigen::VectorXd& mass, int num_weights,
                                 const Eigen::MatrixXd& modes = Eigen::MatrixXd());

}  // namespace modal_mass_spring
