// Non-negative least squares: min |A w - b| subject to w >= 0 (Lawson-Hanson active set).
#pragma once

#include <Eigen/Core>

namespace modal_mass_spring
{

struct NnlsResult
{
  bool converged = false;
  int iterations = 0;  // variables moved into the passive set
};

// Lawson and Hanson's active-set method on the normal equations: `gram` = A^T A (symmetric positive
// semi-definite), `atb` = A^T b. `w` is a warm start (resized to zeros when its size does not match;
// negative entries are clamped to 0) and holds the solution on return. A variable enters the passive
// set only while its gradient exceeds `tolerance` times the largest |A^T b| entry, so columns in the
// span of the passive ones (a rank-deficient A) stay out. Eigen 3.4 has no NNLS solver (its NNLS
// module is unsupported and unreleased), hence this small one, written for the cubature training.
NnlsResult solveNnlsNormal(const Eigen::MatrixXd& gram, const Eigen::VectorXd& atb, Eigen::VectorXd& w,
                           double tolerance = 1e-12, int max_iterations = -1);

// The same for A and b given: forms A^T A and A^T b.
Eigen::VectorXd nnls(const Eigen::MatrixXd& a, const Eigen::VectorXd& b, NnlsResult* result = nullptr);

}  // namespace modal_mass_spring
