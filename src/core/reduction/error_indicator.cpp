#include "reduction/error_indicator.h"

#include "modal_mass_spring/spring_forces.h"

#include <cmath>
#include <stdexcept>

namespace modal_mass_spring
{

ErrorIndicator::ErrorIndicator(const Grid& grid, const Eigen::VectorXd& mass) : grid_(grid), mass_(mass)
{
  particle_mass_ = mass_.sum() / grid_.dimension();
  diagonal_ = springLaplacianDiagonal(grid_) + mass_ / (kTau * kTau);
}

Eigen::VectorXd ErrorIndicator::force(const Eigen::VectorXd& x, const Eigen::VectorXd& external) const
{
  Eigen::VectorXd f_all;
  springAndGravityForces(grid_, x, f_all);
  if (external.size() == f_all.size())
    f_all += external;
  return grid_.gatherFree(f_all);
}

double ErrorIndicator::balance(const Eigen::VectorXd& r)
{
  if (!factored_)
  {
    // Formed here, not with the diagonal: `coarse` needs no more, and on a large grid forming it
    // costs as much as a dozen checks.
    Eigen::SparseMatrix<double> matrix = springLaplacian(grid_);
    for (Eigen::Index k = 0; k < mass_.size(); ++k)
      matrix.coeffRef(k, k) += mass_[k] / (kTau * kTau);
    factor_.compute(matrix);
    if (factor_.info() != Eigen::Success)
      throw std::runtime_error("error indicator: the springs' Laplacian plus the mass could not be factorised");
    factored_ = true;
  }
  return rms(factor_.solve(r));
}

double ErrorIndicator::balanceLocally(const Eigen::VectorXd& r) const { return rms(r.cwiseQuotient(diagonal_)); }

double ErrorIndicator::rms(const Eigen::VectorXd& du) const
{
  return particle_mass_ > 0.0 ? std::sqrt(du.dot(mass_.cwiseProduct(du)) / particle_mass_) : 0.0;
}

CoarseErrorIndicator::CoarseErrorIndicator(const Grid& grid, const CoarseGrid& coarse, const Eigen::VectorXd& mass,
                                           const Eigen::VectorXd& x_ref, const Eigen::VectorXd& equilibrium)
  : grid_(grid), coarse_(coarse)
{
  const int coarse_cols = coarse.grid.params().cols;
  const int view_cols = kViewRefinement * (coarse_cols - 1) + 1;
  if (view_cols < grid.params().cols)
  {
    // The view only makes the reading cheaper: where it cannot be built or fitted, the grid itself is read.
    try
    {
      auto view = std::make_unique<CoarseGrid>(grid, view_cols);
      if (equilibrium.size() == 0 || view->fitRestLengths(equilibrium, CoarseGrid::Held::Sampled))
      {
        span_ = std::make_unique<CoarseGrid>(view->grid, coarse_cols);
        view_ = std::move(view);
      }
    }
    catch (const std::exception&)
    {
      // view_ is still null: the grid itself.
    }
  }
  if (!view_)
  {
    indicator_ = std::make_unique<ErrorIndicator>(grid, mass);
    return;
  }
  indicator_ = std::make_unique<ErrorIndicator>(view_->grid, view_->mass);
  // S split by the grid's dofs: its free ones (to which P interpolates), its handles, the rest held.
  const SparseMatrix& sampling = view_->sampling;
  std::vector<Eigen::Triplet<double>> on_free, on_handles;
  Eigen::VectorXd held_ref = x_ref;
  for (int dof : grid.freeDofs())
    held_ref[dof] = 0.0;
  std::vector<int> handle_index(static_cast<size_t>(grid.numDofs()), -1);
  for (int k = 0; k < grid.numHandleDofs(); ++k)
    handle_index[static_cast<size_t>(grid.handleDofs()[k])] = k;
  for (int col = 0; col < sampling.outerSize(); ++col)
    for (SparseMatrix::InnerIterator it(sampling, col); it; ++it)
      if (const int free = grid.freeIndex(col); free >= 0)
        on_free.emplace_back(static_cast<int>(it.row()), free, it.value());
      else if (handle_index[static_cast<size_t>(col)] >= 0)
        on_handles.emplace_back(static_cast<int>(it.row()), handle_index[static_cast<size_t>(col)], it.value());
  SparseMatrix free_sampling(sampling.rows(), grid.numFreeDofs());
  free_sampling.setFromTriplets(on_free.begin(), on_free.end());
  from_coarse_ = free_sampling * coarse.interpolation;
  from_handles_.resize(sampling.rows(), grid.numHandleDofs());
  from_handles_.setFromTriplets(on_handles.begin(), on_handles.end());
  at_rest_ = sampling * held_ref;
}

void CoarseErrorIndicator::setMissed(const Eigen::VectorXd& missed, long state_sets)
{
  missed_.resize(0);
  if (view_ && missed.size() > 0)
  {
    Eigen::VectorXd all = Eigen::VectorXd::Zero(grid_.numDofs());
    grid_.addFree(missed, all);
    missed_ = view_->sampling * all;
  }
  missed_sets_ = state_sets;
}

double CoarseErrorIndicator::operator()(const Eigen::VectorXd& x, const Eigen::VectorXd& external) const
{
  if (!view_)
    return indicator_->balanceLocally(coarse_.outsideSpan(indicator_->force(x, external)));
  return fromView(view_->sampling * x, external);
}

double CoarseErrorIndicator::operator()(const Eigen::VectorXd& coarse_positions,
                                        const Eigen::VectorXd& handle_displacement, const Eigen::VectorXd& external) const
{
  if (!view_)
    throw std::logic_error("coarse error indicator: no view to read the coarse state on");
  Eigen::VectorXd x_view = from_coarse_ * coarse_positions + at_rest_;
  if (handle_displacement.size() > 0)
    x_view += from_handles_ * handle_displacement;
  if (missed_.size() > 0)
    x_view += missed_;
  return fromView(x_view, external);
}

double CoarseErrorIndicator::fromView(const Eigen::VectorXd& x_view, const Eigen::VectorXd& external) const
{
  // The external force on the view's particles: what the grid's free particles carry, spread as
  // the view's interpolation spreads its particles' motion onto them (its total kept).
  Eigen::VectorXd external_view;
  if (external.size() == grid_.numDofs() && !external.isZero(0.0))
    external_view = view_->interpolation.transpose() * grid_.gatherFree(external);
  return indicator_->balanceLocally(span_->outsideSpan(indicator_->force(x_view, external_view)));
}

}  // namespace modal_mass_spring
