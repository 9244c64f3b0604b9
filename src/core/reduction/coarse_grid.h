// Method `coarse`'s reduced model: the same cloth on a coarser grid. The coarse grid keeps the fine
// one's width, height, total mass and spring constants (a square grid's stiffness in tension does
// not depend on its spacing; docs/design.md has what softening the bending springs did), so its
// particles are heavier and further apart and it is stable at a larger explicit step. The fine
// particles follow it by bilinear interpolation in material coordinates; the fine grid's fixed and
// handle particles hold the coarse particles nearest them. Where the grid has a hanging
// equilibrium, the coarse springs' rest lengths are fitted to hold it (fitRestLengths).
#pragma once

#include "modal_mass_spring/grid.h"
#include "modal_mass_spring/spring_forces.h"  // SparseMatrix

#include <Eigen/Core>
#include <Eigen/SparseCholesky>

#include <array>
#include <vector>

namespace modal_mass_spring
{

// A point of one grid as a bilinear blend of four particles of another.
struct Stencil
{
  std::array<int, 4> particle;
  std::array<double, 4> weight;
};

struct CoarseGrid
{
  // The coarse grid for `fine` (coarse_cols as coarseGridParams takes it, which throws).
  CoarseGrid(const Grid& fine, int coarse_cols);

  Grid grid;
  // Its linearization at its own rest (the positions the fine grid's interpolate): what `full` on it
  // takes as x_ref, K (Rayleigh damping), the free dofs' masses and K_ib.
  Eigen::VectorXd x_ref;
  SparseMatrix stiffness;
  Eigen::VectorXd mass;
  SparseMatrix handle_coupling;
  // P: the fine grid's free dofs from every coarse dof (four entries a row, one per stencil particle).
  SparseMatrix interpolation;
  // Per fine particle, its stencil on the coarse grid.
  std::vector<Stencil> interpolation_stencils;
  // R: every coarse particle's position sampled from the fine grid's every dof (a coarse particle
  // lies between fine ones unless the spacings divide).
  SparseMatrix sampling;
  // Per coarse handle dof (Grid::handleDofs() order): the fine handle dof (an index into the fine
  // grid's handleDofs()) whose motion it copies, that of the fine handle particle nearest it.
  std::vector<int> handle_source;

  // Fits the springs' rest lengths so that the coarse grid, at the fine positions x_fine sampled, is
  // in the balance the fine grid is in there (their forces restricted, P^T f): the change smallest in
  // norm. At a fine equilibrium the coarse grid then hangs in its shape, not its own sag, and keeps
  // it as it turns (a rest length turns with its spring). K and K_ib stay those of the unfitted grid
  // (Rayleigh damping, the handles' damping load, the step limit: as before the fit). False, and
  // nothing changed, where the fit would take a rest length to zero or below, or not finite.
  // `held`: where its fixed and handle particles are in that balance, at its own rest as the coarse
  // method holds them, or sampled from x_fine as every other (a grid that only views the fine one).
  enum class Held { AtRest, Sampled };
  bool fitRestLengths(const Eigen::VectorXd& x_fine, Held held = Held::AtRest);

  // What the interpolation misses of fine positions x (every fine dof), on the fine free dofs:
  // x less its interpolation from the coarse particles sampled from it, P R x. A switch to the coarse
  // grid keeps this part frozen.
  Eigen::VectorXd missed(const Eigen::VectorXd& x) const;
  // The part of a fine free-dof force that the coarse free dofs cannot represent:
  // f - M P_f (P_f^T M P_f)^-1 P_f^T f, P_f the interpolation from the coarse free dofs (the
  // fine particles weigh the same, so M drops out).
  Eigen::VectorXd outsideSpan(const Eigen::VectorXd& f) const;

private:
  const Grid& fine_;
  SparseMatrix free_interpolation_;  // P_f
  Eigen::SimplicialLLT<SparseMatrix> span_gram_;  // P_f^T P_f, factorised
};

// The most columns the default coarse grid has: on a cloth a metre wide, 5 cm apart, 4-5 mm mean RMS
// from `full` on a 60 degree turn (docs/benchmarks.md).
constexpr int kMaxDefaultCoarseCols = 20;

// The coarse grid's columns for `coarse_cols` (0: about a third of the fine grid's columns, at most
// kMaxDefaultCoarseCols, the nearest allowed): its rows
// follow from the spacing, (rows - 1) (coarse_cols - 1) / (cols - 1), which must be whole so that both
// grids span the same cloth. Throws std::invalid_argument naming coarse_cols, with the allowed values.
int resolveCoarseCols(const GridParams& fine, int coarse_cols);
// The coarse grid's parameters for `coarse_cols` (0 resolved as above): the fine grid's with the
// spacing and particle mass scaled, and the fine grid's fixed and handle particles moved to the
// coarse particles nearest them. Throws std::invalid_argument naming coarse_cols when it is not
// allowed, or when two fine handles, or a handle and a fixed particle, fall on one coarse particle.
GridParams coarseGridParams(const GridParams& fine, int coarse_cols);

}  // namespace modal_mass_spring
