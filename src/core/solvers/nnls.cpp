// Lawson-Hanson non-negative least squares on the normal equations, with a growing Cholesky factor.
#include "solvers/nnls.h"

#include <Eigen/Cholesky>

#include <algorithm>
#include <cmath>

namespace modal_mass_spring
{
namespace
{

// A column whose part independent of the passive ones is below this fraction of its norm (squared)
// does not enter: round-off would make its weight meaningless.
constexpr double kDependent = 1e-20;

}  // namespace

void NnlsNormal::addVariable(const Eigen::VectorXd& gram_column, double atb)
{
  const Eigen::Index n = size();
  if (n + 1 > gram_.rows())  // room doubles: appending stays O(n) on average
  {
    const Eigen::Index capacity = std::max<Eigen::Index>(16, 2 * gram_.rows());
    Eigen::MatrixXd grown(capacity, capacity), factor(capacity, capacity);
    grown.topLeftCorner(n, n) = gram_.topLeftCorner(n, n);
    factor.topLeftCorner(order_.size(), order_.size()) = factor_.topLeftCorner(order_.size(), order_.size());
    gram_.swap(grown);
    factor_.swap(factor);
  }
  gram_.row(n).head(n + 1) = gram_column.head(n + 1).transpose();
  gram_.col(n).head(n) = gram_column.head(n);
  atb_.conservativeResize(n + 1);
  atb_[n] = atb;
  w_.conservativeResize(n + 1);
  w_[n] = 0.0;
  passive_.push_back(false);
}

bool NnlsNormal::appendToFactor(Eigen::Index j)
{
  const Eigen::Index k = static_cast<Eigen::Index>(order_.size());
  Eigen::VectorXd y(k);
  for (Eigen::Index i = 0; i < k; ++i)
    y[i] = gram_(order_[i], j);
  factor_.topLeftCorner(k, k).triangularView<Eigen::Lower>().solveInPlace(y);
  const double d = gram_(j, j) - y.squaredNorm();
  if (!(d > kDependent * gram_(j, j)))
    return false;
  factor_.row(k).head(k) = y.transpose();
  factor_(k, k) = std::sqrt(d);
  order_.push_back(j);
  return true;
}

void NnlsNormal::removeFromFactor(Eigen::Index position)
{
  const Eigen::Index k = static_cast<Eigen::Index>(order_.size());
  // Without its row, L L^T is the Gram matrix of the others, but rows position..k-2 then hold one
  // entry right of the diagonal: Givens rotations of neighbouring columns (orthogonal, so L L^T is
  // unchanged) move it back onto the diagonal, O((k - position)^2) against O(k^3) for a refactor.
  for (Eigen::Index row = position; row + 1 < k; ++row)
    factor_.row(row).head(k) = factor_.row(row + 1).head(k);
  for (Eigen::Index m = position; m + 1 < k; ++m)
  {
    const double a = factor_(m, m), b = factor_(m, m + 1);  // b is the removed row's successor's diagonal, > 0
    const double r = std::hypot(a, b), c = a / r, s = b / r;
    for (Eigen::Index row = m; row + 1 < k; ++row)
    {
      const double x = factor_(row, m), y = factor_(row, m + 1);
      factor_(row, m) = c * x + s * y;
      factor_(row, m + 1) = c * y - s * x;
    }
  }
  order_.erase(order_.begin() + position);
}

void NnlsNormal::dropLeftVariables()
{
  for (Eigen::Index position = static_cast<Eigen::Index>(order_.size()) - 1; position >= 0; --position)
    if (!passive_[order_[position]])
      removeFromFactor(position);
}

Eigen::VectorXd NnlsNormal::passiveSolution() const
{
  const Eigen::Index k = static_cast<Eigen::Index>(order_.size());
  Eigen::VectorXd c(k);
  for (Eigen::Index i = 0; i < k; ++i)
    c[i] = atb_[order_[i]];
  const auto l = factor_.topLeftCorner(k, k);
  l.triangularView<Eigen::Lower>().solveInPlace(c);
  l.transpose().triangularView<Eigen::Upper>().solveInPlace(c);
  Eigen::VectorXd z = Eigen::VectorXd::Zero(size());
  for (Eigen::Index i = 0; i < k; ++i)
    z[order_[i]] = c[i];
  return z;
}

NnlsResult NnlsNormal::solve(double tolerance, int max_iterations)
{
  const Eigen::Index n = size();
  if (max_iterations < 0)
    max_iterations = static_cast<int>(3 * n + 10);
  const double threshold = n > 0 ? tolerance * std::max(atb_.cwiseAbs().maxCoeff(), 1e-300) : 0.0;
  std::vector<bool> rejected(n, false);
  NnlsResult result;
  while (true)
  {
    const Eigen::VectorXd gradient = atb_ - gram() * w_;  // -d/dw of 1/2 |A w - b|^2
    Eigen::Index entered = -1;
    for (Eigen::Index k = 0; k < n; ++k)
      if (!passive_[k] && !rejected[k] && gradient[k] > threshold && (entered < 0 || gradient[k] > gradient[entered]))
        entered = k;
    if (entered < 0)
    {
      result.converged = true;
      break;
    }
    if (result.iterations >= max_iterations)
      break;
    ++result.iterations;
    if (!appendToFactor(entered))
    {
      rejected[entered] = true;
      continue;
    }
    passive_[entered] = true;
    // Move towards the passive set's least-squares solution until every passive weight is positive.
    while (true)
    {
      const Eigen::VectorXd z = passiveSolution();
      double step = 1.0;
      Eigen::Index blocking = -1;  // the variable that reaches 0 first
      for (Eigen::Index k = 0; k < n; ++k)
        if (passive_[k] && z[k] <= 0.0)
        {
          const double to_zero = w_[k] > 0.0 ? w_[k] / (w_[k] - z[k]) : 0.0;
          if (blocking < 0 || to_zero < step)
          {
            step = std::min(step, to_zero);
            blocking = k;
          }
        }
      if (blocking < 0)
      {
        w_ = z;
        break;
      }
      w_ += step * (z - w_);
      w_[blocking] = 0.0;  // exactly: round-off must not leave it passive at a tiny weight forever
      for (Eigen::Index k = 0; k < n; ++k)
        if (passive_[k] && w_[k] <= 0.0)
        {
          passive_[k] = false;
          w_[k] = 0.0;
        }
      dropLeftVariables();
    }
    // A variable whose gradient is positive but whose least-squares weight is not (round-off in a
    // nearly dependent column) would enter and leave forever: skip it until another one enters.
    if (passive_[entered])
      std::fill(rejected.begin(), rejected.end(), false);
    else
      rejected[entered] = true;
  }
  return result;
}

Eigen::VectorXd nnls(const Eigen::MatrixXd& a, const Eigen::VectorXd& b, NnlsResult* result)
{
  NnlsNormal solver;
  for (Eigen::Index j = 0; j < a.cols(); ++j)
    solver.addVariable(a.leftCols(j + 1).transpose() * a.col(j), a.col(j).dot(b));
  const NnlsResult r = solver.solve();
  if (result)
    *result = r;
  return solver.weights();
}

}  // namespace modal_mass_spring
