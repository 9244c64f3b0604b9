// The core's sparse Cholesky (CHOLMOD) against a dense factorisation of the same shifted matrix.
#include "solvers/sparse_cholesky.h"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <vector>

using namespace modal_mass_spring;

namespace
{

// A symmetric rows x cols grid matrix, `dofs` unknowns a node coupled to its 8 neighbours with random
// weights, its diagonal `diagonal` plus the row's absolute sum (both triangles stored).
SparseMatrix gridMatrix(int rows, int cols, int dofs, double diagonal)
{
  std::mt19937 random(3);
  std::uniform_real_distribution<double> coupling(-1.0, 1.0);
  const int n = rows * cols * dofs;
  std::vector<Eigen::Triplet<double>> entries;
  Eigen::VectorXd row_sum = Eigen::VectorXd::Zero(n);
  auto couple = [&](int i, int j) {
    const double v = coupling(random);
    entries.emplace_back(i, j, v);
    entries.emplace_back(j, i, v);
    row_sum[i] += std::abs(v);
    row_sum[j] += std::abs(v);
  };
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c)
      for (int dr = 0; dr <= 1; ++dr)
        for (int dc = -1; dc <= 1; ++dc)
          if (!((dr == 0 && dc <= 0) || r + dr >= rows || c + dc < 0 || c + dc >= cols))
            for (int a = 0; a < dofs; ++a)
              for (int b = 0; b < dofs; ++b)
                couple((r * cols + c) * dofs + a, ((r + dr) * cols + c + dc) * dofs + b);
  for (int i = 0; i < n; ++i)
    entries.emplace_back(i, i, row_sum[i] + diagonal);
  SparseMatrix a(n, n);
  a.setFromTriplets(entries.begin(), entries.end());
  return a;
}

// |x - (A + shift I)^-1 b| / |(A + shift I)^-1 b| of the sparse solve against a dense LLT.
double solveError(const SparseCholesky& cholesky, const SparseMatrix& a, double shift)
{
  Eigen::MatrixXd dense(a);
  dense.diagonal().array() += shift;
  const Eigen::LLT<Eigen::MatrixXd> reference(dense);
  EXPECT_EQ(reference.info(), Eigen::Success);
  const Eigen::VectorXd b = Eigen::VectorXd::LinSpaced(a.rows(), -1.0, 2.0);
  Eigen::VectorXd x = b;
  cholesky.solveInPlace(x);
  const Eigen::VectorXd expected = reference.solve(b);
  return (x - expected).norm() / expected.norm();
}

}  // namespace

TEST(SparseCholesky, SolvesTheShiftedMatrixLikeADenseFactorisation)
{
  for (int dofs : {1, 2, 3})
  {
    const SparseMatrix a = gridMatrix(12, 9, dofs, 0.1);
    SparseCholesky cholesky;
    ASSERT_TRUE(cholesky.factorise(a, 2.0)) << dofs;
    EXPECT_LT(solveError(cholesky, a, 2.0), 1e-12) << dofs;
    EXPECT_GE(cholesky.storedEntries(), a.nonZeros() / 2) << dofs;  // at least A's lower triangle
    // A new matrix on the same pattern, factorised again.
    const SparseMatrix b = gridMatrix(12, 9, dofs, 5.0);
    ASSERT_TRUE(cholesky.factorise(b)) << dofs;
    EXPECT_LT(solveError(cholesky, b, 0.0), 1e-12) << dofs;
  }
}

TEST(SparseCholesky, RefusesAnIndefiniteOrNonFiniteMatrixAndFactorisesTheNextOne)
{
  // Smallest eigenvalue moved to 0.5: A + shift I is positive definite for shift > -0.5 only.
  SparseMatrix a = gridMatrix(8, 8, 2, 0.1);
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> spectrum{Eigen::MatrixXd(a)};
  SparseMatrix identity(a.rows(), a.cols());
  identity.setIdentity();
  a -= (spectrum.eigenvalues()[0] - 0.5) * identity;
  SparseCholesky cholesky;
  EXPECT_FALSE(cholesky.factorise(a, -0.6));
  EXPECT_EQ(cholesky.storedEntries(), 0);
  ASSERT_TRUE(cholesky.factorise(a, -0.4));
  EXPECT_LT(solveError(cholesky, a, -0.4), 1e-9);
  SparseMatrix not_finite = a;
  not_finite.coeffRef(3, 3) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(cholesky.factorise(not_finite));
  // A smaller matrix: a new pattern, analysed again.
  const SparseMatrix small = gridMatrix(3, 4, 1, 1.0);
  ASSERT_TRUE(cholesky.factorise(small));
  EXPECT_LT(solveError(cholesky, small, 0.0), 1e-12);
}
