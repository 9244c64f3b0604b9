// The supernodal Cholesky's solves against a dense factorisation of the same matrix.
#include "solvers/supernodal_cholesky.h"

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

using SparseMatrix = Eigen::SparseMatrix<double>;

// A symmetric matrix from its lower-triangle entries (i >= j), both triangles stored.
SparseMatrix symmetric(int n, const std::vector<Eigen::Triplet<double>>& lower)
{
  std::vector<Eigen::Triplet<double>> both(lower);
  for (const auto& t : lower)
    if (t.row() != t.col())
      both.emplace_back(t.col(), t.row(), t.value());
  SparseMatrix a(n, n);
  a.setFromTriplets(both.begin(), both.end());
  return a;
}

// The stiffness-like matrix of a rows x cols grid with `dofs` unknowns per node, 8 neighbours each
// (the supernodes come in runs of `dofs` columns and wider on the separators), made diagonally
// dominant, so positive definite, with random couplings.
SparseMatrix gridMatrix(int rows, int cols, int dofs, unsigned seed)
{
  std::mt19937 random(seed);
  std::uniform_real_distribution<double> coupling(-1.0, 1.0);
  const int n = rows * cols * dofs;
  std::vector<Eigen::Triplet<double>> lower;
  Eigen::VectorXd row_sum = Eigen::VectorXd::Zero(n);
  auto couple = [&](int i, int j) {
    const double v = coupling(random);
    lower.emplace_back(std::max(i, j), std::min(i, j), v);
    row_sum[i] += std::abs(v);
    row_sum[j] += std::abs(v);
  };
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c)
      for (int dr = 0; dr <= 1; ++dr)
        for (int dc = -1; dc <= 1; ++dc)
        {
          if ((dr == 0 && dc <= 0) || r + dr >= rows || c + dc < 0 || c + dc >= cols)
            continue;
          for (int a = 0; a < dofs; ++a)
            for (int b = 0; b < dofs; ++b)
              couple((r * cols + c) * dofs + a, ((r + dr) * cols + c + dc) * dofs + b);
        }
  for (int r = 0; r < rows * cols; ++r)  // the dofs of one node coupled too
    for (int a = 0; a < dofs; ++a)
      for (int b = 0; b < a; ++b)
        couple(r * dofs + a, r * dofs + b);
  for (int i = 0; i < n; ++i)
    lower.emplace_back(i, i, row_sum[i] + 0.1);
  return symmetric(n, lower);
}

// Largest relative error of solve(b) against a dense LLT solve, over a few right-hand sides.
double solveError(const SparseMatrix& a, double sigma = 0.0)
{
  const SupernodalCholesky cholesky(a, sigma);
  EXPECT_EQ(cholesky.info(), Eigen::Success);
  Eigen::MatrixXd dense = Eigen::MatrixXd(a);
  dense.diagonal().array() -= sigma;
  const Eigen::LLT<Eigen::MatrixXd> reference(dense);
  EXPECT_EQ(reference.info(), Eigen::Success);
  std::mt19937 random(7);
  std::normal_distribution<double> normal;
  double error = 0.0;
  for (int k = 0; k < 3; ++k)
  {
    Eigen::VectorXd b(a.rows());
    for (Eigen::Index i = 0; i < b.size(); ++i)
      b[i] = normal(random);
    Eigen::VectorXd x = b;
    cholesky.solveInPlace(x);
    const Eigen::VectorXd expected = reference.solve(b);
    error = std::max(error, (x - expected).norm() / expected.norm());
  }
  return error;
}

}  // namespace

TEST(SupernodalCholesky, SolvesGridMatricesLikeADenseFactorisation)
{
  for (int dofs : {1, 2, 3})
  {
    const SparseMatrix a = gridMatrix(12, 9, dofs, 3 + dofs);
    EXPECT_LT(solveError(a), 1e-12) << dofs << " dofs per node";
    // Supernodes of more than one column: the dense block paths run.
    EXPECT_LT(SupernodalCholesky(a).supernodes(), a.rows()) << dofs;
  }
}

TEST(SupernodalCholesky, FactorisesTheShiftedMatrix)
{
  // A grid matrix moved so its smallest eigenvalue is 0.5: A - sigma I is definite for sigma < 0.5
  // only, and the solves are those of A - sigma I.
  SparseMatrix a = gridMatrix(8, 8, 2, 11);
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> spectrum{Eigen::MatrixXd(a)};
  SparseMatrix identity(a.rows(), a.cols());
  identity.setIdentity();
  a -= (spectrum.eigenvalues()[0] - 0.5) * identity;
  EXPECT_LT(solveError(a, -2.0), 1e-12);
  EXPECT_LT(solveError(a, 0.4), 1e-10);
  EXPECT_EQ(SupernodalCholesky(a, 0.6).info(), Eigen::NumericalIssue);
}

TEST(SupernodalCholesky, HandlesDenseRowsDiagonalAndTinyMatrices)
{
  // An arrow: every unknown coupled to the first, which AMD orders last, one supernode of its own
  // that every other updates.
  const int n = 40;
  std::vector<Eigen::Triplet<double>> arrow;
  for (int i = 1; i < n; ++i)
  {
    arrow.emplace_back(i, 0, 1.0);
    arrow.emplace_back(i, i, 2.0 + i);
  }
  arrow.emplace_back(0, 0, 2.0 * n);
  EXPECT_LT(solveError(symmetric(n, arrow)), 1e-12);

  std::vector<Eigen::Triplet<double>> diagonal;
  for (int i = 0; i < 10; ++i)
    diagonal.emplace_back(i, i, 1.0 + i);
  EXPECT_LT(solveError(symmetric(10, diagonal)), 1e-14);

  EXPECT_LT(solveError(symmetric(1, {{0, 0, 4.0}})), 1e-15);

  // Fully dense: one supernode.
  std::vector<Eigen::Triplet<double>> dense;
  for (int i = 0; i < 12; ++i)
    for (int j = 0; j <= i; ++j)
      dense.emplace_back(i, j, i == j ? 20.0 : 1.0 / (1.0 + i + j));
  const SparseMatrix full = symmetric(12, dense);
  EXPECT_LT(solveError(full), 1e-13);
  EXPECT_EQ(SupernodalCholesky(full).supernodes(), 1);
}

TEST(SupernodalCholesky, SolvesWideSupernodesWithRowsBelowThem)
{
  // A chain of dense 10 x 10 blocks, each coupled densely to the next: supernodes ten and more
  // columns wide with rows below them (the Eigen products of the solves and of the updates).
  const int blocks = 6, size = 10, n = blocks * size;
  std::vector<Eigen::Triplet<double>> lower;
  for (int b = 0; b < blocks; ++b)
    for (int i = 0; i < size; ++i)
    {
      const int row = b * size + i;
      for (int j = 0; j < i; ++j)
        lower.emplace_back(row, b * size + j, 0.3 / (1.0 + i + j));
      if (b > 0)
        for (int j = 0; j < size; ++j)
          lower.emplace_back(row, (b - 1) * size + j, 0.2 / (2.0 + i + j));
      lower.emplace_back(row, row, 4.0 + 0.1 * i);
    }
  const SparseMatrix a = symmetric(n, lower);
  EXPECT_LT(solveError(a), 1e-13);
  EXPECT_LE(SupernodalCholesky(a).supernodes(), 2 * blocks);  // wide, not column by column
}

TEST(SupernodalCholesky, ReadsTheLowerTriangle)
{
  // The same matrix given by its lower triangle alone solves the same.
  const SparseMatrix a = gridMatrix(7, 6, 2, 5);
  const SparseMatrix lower = a.triangularView<Eigen::Lower>();
  Eigen::VectorXd x = Eigen::VectorXd::LinSpaced(a.rows(), -1.0, 2.0), y = x;
  SupernodalCholesky(a).solveInPlace(x);
  SupernodalCholesky(lower).solveInPlace(y);
  EXPECT_LT((x - y).norm(), 1e-14 * x.norm());
}

TEST(SupernodalCholesky, RefusesAnIndefiniteOrNonFiniteMatrix)
{
  std::vector<Eigen::Triplet<double>> lower = {{0, 0, 1.0}, {1, 0, 2.0}, {1, 1, 1.0}, {2, 2, 3.0}};
  EXPECT_EQ(SupernodalCholesky(symmetric(3, lower)).info(), Eigen::NumericalIssue);
  lower = {{0, 0, 1.0}, {1, 0, 0.5}, {1, 1, std::nan("")}, {2, 2, 3.0}};
  EXPECT_EQ(SupernodalCholesky(symmetric(3, lower)).info(), Eigen::NumericalIssue);
  lower = {{0, 0, 1.0}, {1, 1, std::numeric_limits<double>::infinity()}};
  EXPECT_EQ(SupernodalCholesky(symmetric(2, lower)).info(), Eigen::NumericalIssue);
}
