// The modal basis against closed-form frequencies and its defining properties.
#include "modal_mass_spring/modal_basis.h"

#include "solvers/equilibrium.h"

#include <Eigen/Eigenvalues>
#include <gtest/gtest.h>

#include <cmath>

using namespace modal_mass_spring;

namespace
{

// n free particles hanging below one fixed particle, gravity off: a fixed-free chain.
GridParams chain(int n, double k, double m)
{
  GridParams p;
  p.rows = n + 1;
  p.cols = 1;
  p.mass = m;
  p.structural_stiffness = k;
  p.gravity.setZero();
  return p;
}

// Particle masses from 0.5 m to 1.5 m, the same for every dof of a particle: M is no multiple of I.
Eigen::VectorXd unequalMasses(const Grid& grid, double m)
{
  const int dimension = grid.params().dimension;
  Eigen::VectorXd mass(grid.numFreeDofs());
  for (int i = 0; i < mass.size(); ++i)
    mass[i] = m * (1.0 + 0.5 * std::sin(1.7 * grid.freeDofs()[i] / dimension));
  return mass;
}

// The r lowest eigenpairs against a dense generalized solve of K u = lambda^2 M u: eigenvalues to
// 1e-9 relative, each mode the dense one up to sign (M-inner product 1 in magnitude) where its
// eigenvalue is apart from its neighbours, and Phi^T M Phi = I.
void expectDenseAgreement(const SparseMatrix& k, const Eigen::VectorXd& mass, int r)
{
  const ModalBasis basis = computeModalBasis(k, mass, r);
  ASSERT_TRUE(basis.sparse);
  EXPECT_EQ(basis.num_zero_modes, 0);
  const Eigen::GeneralizedSelfAdjointEigenSolver<Eigen::MatrixXd> dense(Eigen::MatrixXd(k),
                                                                        Eigen::MatrixXd(mass.asDiagonal()));
  const Eigen::VectorXd& lambda = dense.eigenvalues();
  for (int j = 0; j < r; ++j)
  {
    EXPECT_NEAR(basis.eigenvalues[j] / lambda[j], 1.0, 1e-9) << "mode " << j;
    const bool apart = (j == 0 || lambda[j] - lambda[j - 1] > 1e-3 * lambda[j]) && lambda[j + 1] - lambda[j] > 1e-3 * lambda[j];
    if (apart)
    {
      const double overlap = basis.phi.col(j).dot(mass.asDiagonal() * dense.eigenvectors().col(j));
      EXPECT_NEAR(std::abs(overlap), 1.0, 1e-8) << "mode " << j;
    }
  }
  const Eigen::MatrixXd gram = basis.phi.transpose() * mass.asDiagonal() * basis.phi;
  EXPECT_LT((gram - Eigen::MatrixXd::Identity(r, r)).cwiseAbs().maxCoeff(), 1e-10);
  // The sign convention: each mode's largest entry is positive.
  for (int j = 0; j < r; ++j)
  {
    Eigen::Index largest = 0;
    basis.phi.col(j).cwiseAbs().maxCoeff(&largest);
    EXPECT_GT(basis.phi(largest, j), 0.0) << "mode " << j;
  }
}

}  // namespace

TEST(ModalBasis, MatchesDenseGeneralizedSolveIn2DWithUnequalMasses)
{
  GridParams p;
  p.rows = 20;
  p.cols = 20;
  const Grid grid(p);
  expectDenseAgreement(tangentStiffness(grid, grid.initialPositions()), unequalMasses(grid, p.mass), 30);
}

TEST(ModalBasis, MatchesDenseGeneralizedSolveOnAHangingSheetWithBending)
{
  // Three dofs per particle and the bending springs' wider stencil: other shapes of the factor.
  GridParams p;
  p.rows = 12;
  p.cols = 10;
  p.dimension = 3;
  p.bending = true;
  const Grid grid(p);
  const Eigen::VectorXd x_eq = solveEquilibrium(grid, grid.initialPositions()).positions;
  expectDenseAgreement(tangentStiffness(grid, x_eq, CompressedSprings::Drop), unequalMasses(grid, p.mass), 20);
}

TEST(ModalBasis, HangingChainMatchesClosedForm)
{
  const int n = 40;
  const double k = 50.0, m = 0.02;
  const Grid grid(chain(n, k, m));
  const SparseMatrix stiffness = tangentStiffness(grid, grid.initialPositions());
  // At rest the sideways (x) dofs have no stiffness: n zero modes below the n axial ones.
  const int axial = 6;
  const ModalBasis basis = computeModalBasis(stiffness, Eigen::VectorXd::Constant(grid.numFreeDofs(), m), n + axial);
  ASSERT_TRUE(basis.sparse);
  EXPECT_EQ(basis.num_zero_modes, n);
  for (int j = 1; j <= axial; ++j)
  {
    const double expected = 2.0 * std::sqrt(k / m) * std::sin((2 * j - 1) * M_PI / (2.0 * (2 * n + 1)));
    EXPECT_NEAR(basis.frequencies[n + j - 1] / expected, 1.0, 1e-9) << "mode " << j;
  }
}

TEST(ModalBasis, MassOrthonormalWithSmallResiduals)
{
  GridParams p;
  p.rows = 12;
  p.cols = 9;
  p.mass = 0.03;
  const Grid grid(p);
  const SparseMatrix k = tangentStiffness(grid, grid.initialPositions());
  const Eigen::VectorXd mass = Eigen::VectorXd::Constant(grid.numFreeDofs(), p.mass);
  const ModalBasis basis = computeModalBasis(k, mass, 10);
  ASSERT_TRUE(basis.sparse);
  EXPECT_EQ(basis.num_zero_modes, 0);
  const Eigen::MatrixXd gram = basis.phi.transpose() * mass.asDiagonal() * basis.phi;
  EXPECT_LT((gram - Eigen::MatrixXd::Identity(10, 10)).cwiseAbs().maxCoeff(), 1e-10);
  for (int j = 0; j < 10; ++j)
  {
    const Eigen::VectorXd u = basis.phi.col(j);
    const Eigen::VectorXd ku = k * u;
    const Eigen::VectorXd residual = ku - basis.eigenvalues[j] * mass.cwiseProduct(u);
    EXPECT_LT(residual.norm() / ku.norm(), 1e-9) << "mode " << j;
    if (j > 0)
    {
      EXPECT_GE(basis.eigenvalues[j], basis.eigenvalues[j - 1]);
    }
  }
  // The lowest modes: a dense solve of the same small problem agrees.
  const Eigen::MatrixXd a = Eigen::MatrixXd(k) / p.mass;
  const Eigen::VectorXd dense = Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(a).eigenvalues();
  for (int j = 0; j < 10; ++j)
    EXPECT_NEAR(basis.eigenvalues[j] / dense[j], 1.0, 1e-9);
}

TEST(ModalBasis, FlatSheetIn3DReportsItsZeroModes)
{
  GridParams p;
  p.dimension = 3;
  p.rotation_deg = 45.0;
  const Grid grid(p);
  const SparseMatrix k = tangentStiffness(grid, grid.initialPositions());
  const ModalBasis basis = computeModalBasis(k, Eigen::VectorXd::Constant(grid.numFreeDofs(), p.mass), 30);
  // 20 free particles, one out-of-plane direction each with no stiffness at rest.
  EXPECT_EQ(basis.num_zero_modes, 20);
  EXPECT_TRUE(basis.phi.allFinite());
  EXPECT_GT(basis.frequencies[20], 0.0);
}

TEST(ModalBasis, AllModesFallBackToDense)
{
  GridParams p;
  p.rows = 3;
  p.cols = 2;
  const Grid grid(p);
  const SparseMatrix k = tangentStiffness(grid, grid.initialPositions());
  const int n = grid.numFreeDofs();
  const ModalBasis basis = computeModalBasis(k, Eigen::VectorXd::Constant(n, p.mass), n);
  EXPECT_FALSE(basis.sparse);
  EXPECT_EQ(basis.phi.cols(), n);
  EXPECT_TRUE(computeModalBasis(k, Eigen::VectorXd::Constant(n, p.mass), n - 2).sparse);
  EXPECT_THROW(computeModalBasis(k, Eigen::VectorXd::Constant(n, p.mass), n + 1), std::invalid_argument);
}

TEST(ModalBasis, LargeNullSpaceIsFoundWhole)
{
  // A 10 x 10 flat 3D sheet at rest: 90 zero modes, far more than one Lanczos run finds.
  GridParams p;
  p.rows = 10;
  p.cols = 10;
  p.dimension = 3;
  p.rotation_deg = 45.0;
  const Grid grid(p);
  const SparseMatrix k = tangentStiffness(grid, grid.initialPositions());
  const Eigen::VectorXd mass = Eigen::VectorXd::Constant(grid.numFreeDofs(), p.mass);
  const ModalBasis all_zero = computeModalBasis(k, mass, 30);
  EXPECT_EQ(all_zero.num_zero_modes, 30);
  const ModalBasis beyond = computeModalBasis(k, mass, 95);
  EXPECT_EQ(beyond.num_zero_modes, 90);
  // The five above zero are the lowest in-plane modes, as a dense solve says.
  const Eigen::VectorXd dense =
      Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(Eigen::MatrixXd(k) / p.mass).eigenvalues();
  for (int j = 90; j < 95; ++j)
    EXPECT_NEAR(beyond.eigenvalues[j] / dense[j], 1.0, 1e-8) << "mode " << j;
  const Eigen::MatrixXd gram = beyond.phi.transpose() * mass.asDiagonal() * beyond.phi;
  EXPECT_LT((gram - Eigen::MatrixXd::Identity(95, 95)).cwiseAbs().maxCoeff(), 1e-9);
}
