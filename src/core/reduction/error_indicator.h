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
// alone, O(n) instead of a solve that costs tens of coarse steps (docs/results.md). On a grid more
// than three times finer than its coarse grid, `coarse` reads the same residual on a view of the
// cloth at a third of the coarse spacing (CoarseErrorIndicator).
#pragma once

#include "modal_mass_spring/grid.h"
#include "reduction/coarse_grid.h"

#include <Eigen/Core>
#include <Eigen/SparseCholesky>

#include <memory>

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

// `coarse`'s indicator. Its calibration (indicatorScale) was taken where the grid has three times the
// coarse grid's columns, as the default coarse grid gives up to 58 columns; on a grid with more than
// that (a larger grid, whose default coarse grid stays at 20 columns, or fewer coarse_cols) it is
// read on a view of the cloth with three times the coarse columns: its positions sampled from the
// grid's, its rest lengths fitted, where the grid has a hanging equilibrium, so that there it is in
// the balance the grid is in. But for one pass over the external force, its cost then grows with the
// coarse grid, not the fine one, and it ranks the distance to `full` as well as the grid's residual
// (docs/results.md, "The indicator on a view of the cloth").
class CoarseErrorIndicator
{
public:
  // `mass`: the diagonal of M on the grid's free dofs; `x_ref`: the positions (every dof) the
  // grid's displacements are from, where its fixed particles stay; `equilibrium`: its hanging
  // equilibrium (empty: none).
  CoarseErrorIndicator(const Grid& grid, const CoarseGrid& coarse, const Eigen::VectorXd& mass,
                       const Eigen::VectorXd& x_ref, const Eigen::VectorXd& equilibrium);
  // Whether it reads a view (else the grid itself).
  bool viewed() const { return view_ != nullptr; }
  // The estimate at the grid's positions x (every dof), with the external force on every dof (zero
  // or empty: none).
  double operator()(const Eigen::VectorXd& x, const Eigen::VectorXd& external) const;
  // The same where `coarse` steps, from its own state (a view only, viewed()): the coarse grid's
  // positions (every dof) and the grid's handle dofs' displacement (empty: none), what it reads
  // of the grid's free particles. What its interpolation misses, frozen at a state set, is taken
  // by setMissed; missedSets says at which set it was last.
  double operator()(const Eigen::VectorXd& coarse_positions, const Eigen::VectorXd& handle_displacement,
                    const Eigen::VectorXd& external) const;
  void setMissed(const Eigen::VectorXd& missed, long state_sets);
  long missedSets() const { return missed_sets_; }

  static constexpr int kViewRefinement = 3;

private:
  double fromView(const Eigen::VectorXd& x_view, const Eigen::VectorXd& external) const;

  const Grid& grid_;
  const CoarseGrid& coarse_;
  std::unique_ptr<CoarseGrid> view_;  // null: the grid itself
  std::unique_ptr<CoarseGrid> span_;  // the coarse grid over the view
  std::unique_ptr<ErrorIndicator> indicator_;
  // The view's positions from the coarse state: S (sampling) times the grid's positions, which are
  // P x_c + missed on the free dofs, x_ref + displacement on the handle dofs, x_ref on the fixed.
  SparseMatrix from_coarse_;    // S P
  SparseMatrix from_handles_;   // S on the handle dofs
  Eigen::VectorXd at_rest_;     // S x_ref on the held dofs
  Eigen::VectorXd missed_;      // S missed
  long missed_sets_ = -1;
};
}  // namespace modal_mass_spring
