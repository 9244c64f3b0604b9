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

}  // namespace modal_mass_spring
