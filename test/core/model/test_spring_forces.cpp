// Forces and tangent stiffness against central finite differences of the energy.
#include "modal_mass_spring/spring_forces.h"

#include <Eigen/Eigenvalues>
#include <gtest/gtest.h>

using namespace modal_mass_spring;

namespace
{

Grid deformedGrid3D(Eigen::VectorXd& x, bool bending)
{
  GridParams p;
  p.rows = 4;
  p.cols = 3;
  p.dimension = 3;
  p.bending = bending;
  p.structural_stiffness = 20.0;
  p.shear_stiffness = 7.0;
  p.bending_stiffness = 3.0;
  Grid grid(p);
  std::srand(7);
  // 30% of the spacing: some springs stretch, some compress, all directions.
  x = grid.initialPositions() + 0.3 * p.spacing * Eigen::VectorXd::Random(grid.numDofs());
  return grid;
}

}  // namespace

TEST(SpringForces, ForceIsMinusEnergyGradient)
{
  for (bool bending : {false, true})
  {
    Eigen::VectorXd x;
    const Grid grid = deformedGrid3D(x, bending);
    Eigen::VectorXd f;
    springForces(grid, x, f);
    const double h = 1e-6;
    for (int d = 0; d < x.size(); ++d)
    {
      Eigen::VectorXd xp = x, xm = x;
      xp[d] += h;
      xm[d] -= h;
      const double gradient = (springEnergy(grid, xp) - springEnergy(grid, xm)) / (2 * h);
      EXPECT_NEAR(f[d], -gradient, 1e-6 * (1.0 + std::abs(gradient))) << "dof " << d;
    }
  }
}

// Largest entry of K(x) + df/dx over the free dofs, df/dx by central differences.
double tangentError(const Grid& grid, const Eigen::VectorXd& x, const Eigen::MatrixXd& k)
{
  const double h = 1e-6;
  double largest = 0.0;
  for (int c = 0; c < grid.numFreeDofs(); ++c)
  {
    Eigen::VectorXd xp = x, xm = x, fp, fm;
    xp[grid.freeDofs()[c]] += h;
    xm[grid.freeDofs()[c]] -= h;
    springForces(grid, xp, fp);
    springForces(grid, xm, fm);
    largest = std::max(largest, (k.col(c) + grid.gatherFree(fp - fm) / (2 * h)).cwiseAbs().maxCoeff());
  }
  return largest;
}

TEST(SpringForces, TangentIsMinusForceJacobian)
{
  Eigen::VectorXd x;
  const Grid grid = deformedGrid3D(x, true);
  const Eigen::MatrixXd k = Eigen::MatrixXd(tangentStiffness(grid, x));
  ASSERT_EQ(k.rows(), grid.numFreeDofs());
  EXPECT_LT(tangentError(grid, x, k), 1e-5 * k.cwiseAbs().maxCoeff());
  EXPECT_LT((k - k.transpose()).cwiseAbs().maxCoeff(), 1e-12);
}

TEST(SpringForces, TangentIn2D)
{
  GridParams p;
  p.rows = 3;
  p.cols = 3;
  const Grid grid(p);
  std::srand(3);
  const Eigen::VectorXd x = grid.initialPositions() + 0.02 * Eigen::VectorXd::Random(grid.numDofs());
  const Eigen::MatrixXd k = Eigen::MatrixXd(tangentStiffness(grid, x));
  EXPECT_LT(tangentError(grid, x, k), 1e-5 * k.cwiseAbs().maxCoeff());
}

TEST(SpringForces, DroppingCompressionKeepsTangentSemiDefinite)
{
  Eigen::VectorXd x;
  const Grid grid = deformedGrid3D(x, false);
  int dropped = 0;
  const Eigen::MatrixXd exact = Eigen::MatrixXd(tangentStiffness(grid, x));
  const Eigen::MatrixXd clamped = Eigen::MatrixXd(tangentStiffness(grid, x, CompressedSprings::Drop, &dropped));
  EXPECT_GT(dropped, 0);
  EXPECT_LT(Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(exact).eigenvalues().minCoeff(), -1e-9);
  EXPECT_GT(Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(clamped).eigenvalues().minCoeff(), -1e-9);
}

TEST(SpringForces, RestStateHasNoForceAndGravityEnergyIsLinear)
{
  GridParams p;
  const Grid grid(p);
  Eigen::VectorXd f;
  springForces(grid, grid.initialPositions(), f);
  EXPECT_LT(f.cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_DOUBLE_EQ(springEnergy(grid, grid.initialPositions()), 0.0);
  Eigen::VectorXd lowered = grid.initialPositions();
  for (int i = 0; i < grid.numParticles(); ++i)
    lowered[2 * i + 1] -= 1.0;
  EXPECT_NEAR(gravityEnergy(grid, lowered) - gravityEnergy(grid, grid.initialPositions()),
              -9.81 * p.mass * grid.numParticles(), 1e-12);
}

TEST(SpringForces, TangentTimesBasisMatchesTheAssembledTangent)
{
  for (bool three_d : {false, true})
  {
    Eigen::VectorXd x;
    Grid grid = deformedGrid3D(x, true);
    if (!three_d)
    {
      GridParams p;
      p.rows = 4;
      p.cols = 4;
      p.bending = true;
      grid = Grid(p);
      x = grid.initialPositions() + 0.03 * Eigen::VectorXd::Random(grid.numDofs());
    }
    const Eigen::MatrixXd phi = Eigen::MatrixXd::Random(grid.numFreeDofs(), 7);
    Eigen::MatrixXd k_phi_t;
    tangentTimesBasis(grid, x, phi.transpose(), k_phi_t);
    const Eigen::MatrixXd expected = tangentStiffness(grid, x) * phi;
    EXPECT_LT((k_phi_t.transpose() - expected).cwiseAbs().maxCoeff(), 1e-10 * expected.cwiseAbs().maxCoeff());
  }
}

TEST(SpringForces, TheLaplaciansDiagonalAloneIsTheMatrixsOwn)
{
  for (int dimension : {2, 3})
  {
    GridParams p;
    p.rows = 5;
    p.cols = 4;
    p.dimension = dimension;
    p.bending = true;
    p.shear_stiffness = 7.0;
    p.bending_stiffness = 3.0;
    p.fixed = {0, 3};
    p.handles = {{17, 18}};
    const Grid grid(p);
    const Eigen::VectorXd expected = springLaplacian(grid).diagonal();
    const Eigen::VectorXd diagonal = springLaplacianDiagonal(grid);
    ASSERT_EQ(diagonal.size(), grid.numFreeDofs());
    EXPECT_LT((diagonal - expected).cwiseAbs().maxCoeff(), 1e-12) << dimension << "D";
    // A free particle beside a fixed one has lost that spring: the count is not the same everywhere.
    EXPECT_GT(diagonal.maxCoeff() - diagonal.minCoeff(), 1.0);
  }
}
