// Non-negative least squares: min |A w - b| subject to w >= 0 (Lawson-Hanson active set).
#pragma once

#include <Eigen/Core>

#include <vector>

namespace modal_mass_spring
{

struct NnlsResult
{
  bool converged = false;
  int iterations = 0;  // variables moved into the passive set
};

// Lawson and Hanson's active-set method on the normal equations (A^T A and A^T b), for a problem
// that grows a variable (a column of A) at a time, as the cubature's greedy selection does: the
// weights and the Cholesky factor of the passive variables' Gram matrix are kept between solves, so
// a variable entering or leaving costs O(k^2), not a new factorisation. Eigen 3.4 has no NNLS solver (its
// NNLS module is unsupported and unreleased), hence this small one.
class NnlsNormal
{
public:
  // Appends a variable with weight 0: `gram_column` holds its products with the existing columns and
  // itself (size() + 1 entries), `atb` its product with b.
  void addVariable(const Eigen::VectorXd& gram_column, double atb);
  // Solves from the current weights. A variable enters only while its gradient exceeds `tolerance`
  // times the largest |A^T b| entry and its column is independent of the passive ones (to a relative
  // 1e-10 of its norm), so a rank-deficient A leaves the dependent columns out.
  NnlsResult solve(double tolerance = 1e-12, int max_iterations = -1);
  int size() const { return static_cast<int>(atb_.size()); }
  const Eigen::VectorXd& weights() const { return w_; }

private:
  auto gram() const { return gram_.topLeftCorner(size(), size()); }
  // Appends variable j to the factor; false when its column depends on the passive ones.
  bool appendToFactor(Eigen::Index j);
  // Removes the variable at `position` of the factor's order (a Cholesky downdate).
  void removeFromFactor(Eigen::Index position);
  // Removes from the factor the variables that left the passive set.
  void dropLeftVariables();
  // The least-squares weights of the passive variables (zero elsewhere).
  Eigen::VectorXd passiveSolution() const;

  Eigen::MatrixXd gram_;          // capacity x capacity; the top-left size() x size() is used
  Eigen::VectorXd atb_, w_;
  std::vector<bool> passive_;
  std::vector<Eigen::Index> order_;  // the passive variables, in the factor's order
  Eigen::MatrixXd factor_;           // lower triangular L, L L^T = G(order_, order_)
};

// min |A w - b| with w >= 0 for A and b given.
Eigen::VectorXd nnls(const Eigen::MatrixXd& a, const Eigen::VectorXd& b, NnlsResult* result = nullptr);

}  // namespace modal_mass_spring
