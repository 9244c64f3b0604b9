// The static equilibrium under gravity and the linearization there: the force balance, closed forms
// (a hanging chain's modes), a stiff grid's round-off, and what a failed solve says.
#include "modal_mass_spring/equilibrium.h"
#include "modal_mass_spring/simulation.h"
#include "modal_mass_spring/spring_forces.h"

#include "test_support.h"

#include <gtest/gtest.h>

#include <cmath>

using namespace modal_mass_spring;

namespace
{

GridParams paper2D() { return GridParams{}; }  // 5 x 5, top row fixed

}  // namespace

TEST(Equilibrium, BalancesGravityFromARotatedSheet)
{
  const Grid grid(turnedSheet());
  const Equilibrium eq = solveEquilibrium(grid, grid.initialPositions());
  Eigen::VectorXd f;
  springForces(grid, eq.positions, f);
  const Eigen::VectorXd net = grid.gatherFree(f + grid.gravityForce());
  EXPECT_LT(net.cwiseAbs().maxCoeff(), 1e-8 * grid.particleMass() * 9.81);
  // The sheet swung down from 45 degrees (bottom row at y = 0.28) to hang nearly vertically;
  // compressed springs near the bottom let it bulge a little out of its plane.
  const Eigen::Matrix3Xd points = grid.toPoints(eq.positions);
  EXPECT_LT(std::abs(points(1, grid.particleIndex(4, 2))), 0.05);
  EXPECT_LT(points(2, grid.particleIndex(4, 2)), -0.4);
}

TEST(Equilibrium, HangingChainSidewaysModesMatchTheContinuum)
{
  // A stiff chain of many particles: the sideways modes about the hanging equilibrium tend to the
  // continuum chain's omega_n = (z_n / 2) sqrt(g / L), z_n the zeros of J0.
  GridParams g;
  g.rows = 201;
  g.cols = 1;
  g.spacing = 0.01;
  g.mass = 0.001;
  g.structural_stiffness = 1e4;
  SimulationParams s = methodParams(Method::Linear, 3, 1e-4);
  s.linearization = Linearization::Equilibrium;
  const Simulation sim(g, s);
  ASSERT_TRUE(sim.linearization().equilibrium_solved);
  const Eigen::Matrix3Xd points = sim.grid().toPoints(sim.linearizationPositions());
  const double length = -points(2, g.rows - 1);
  EXPECT_GT(length, 2.0);  // stretched under its own weight
  const double zeros[] = {2.404826, 5.520078, 8.653728};
  for (int n = 0; n < 3; ++n)
  {
    const double expected = 0.5 * zeros[n] * std::sqrt(9.81 / length);
    EXPECT_NEAR(sim.basis().frequencies[n] / expected, 1.0, 0.03) << "mode " << n;
  }
}

TEST(Equilibrium, Paper3DSheetHasNoZeroModesThere)
{
  GridParams g = turnedSheet();
  g.rotation_deg = 0.0;  // no rotation needed at the equilibrium
  SimulationParams s = methodParams(Method::Physical, 30, 1e-3);
  s.linearization = Linearization::Equilibrium;
  const Simulation sim(g, s);
  EXPECT_EQ(sim.basis().num_zero_modes, 0);
  EXPECT_GT(sim.basis().eigenvalues.minCoeff(), 1e-6 * sim.basis().eigenvalues.maxCoeff());

  // The same sheet linearised at rest has one zero mode per free particle.
  s.linearization = Linearization::Rest;
  EXPECT_EQ(Simulation(g, s).basis().num_zero_modes, 20);
}

TEST(Equilibrium, LinearIsExactAtRestThere)
{
  SimulationParams s = methodParams(Method::Linear, 8, 1e-3);
  s.linearization = Linearization::Equilibrium;
  s.initial_state = InitialState::Equilibrium;
  Simulation sim(paper2D(), s);
  const Eigen::VectorXd start = sim.positions();
  EXPECT_LT((start - sim.linearizationPositions()).cwiseAbs().maxCoeff(), 1e-15);
  sim.step(2000);
  EXPECT_LT((sim.positions() - start).cwiseAbs().maxCoeff(), 1e-9);

  // Starting from the unloaded grid instead, the modal state is a projection, and its error is told.
  s.initial_state = InitialState::Initial;
  const Simulation from_initial(paper2D(), s);
  EXPECT_GT(from_initial.projectionError(), 0.0);
  // The projection error is the largest particle distance between the projected and requested grids.
  const Grid& grid = from_initial.grid();
  EXPECT_NEAR((grid.toPoints(from_initial.positions()) - grid.toPoints(grid.initialPositions())).colwise().norm().maxCoeff(),
              from_initial.projectionError(), 1e-12);
}

TEST(Equilibrium, StiffGridsConvergeAtTheRoundOffOfTheirForces)
{
  // Both stiffnesses 3e6: k l eps is above 1e-9 of a particle's weight.
  GridParams g = paper2D();
  g.structural_stiffness = g.shear_stiffness = 3e6;
  const Grid grid(g);
  const Equilibrium eq = solveEquilibrium(grid, grid.initialPositions());
  Eigen::VectorXd f;
  springForces(grid, eq.positions, f);
  const Eigen::VectorXd net = grid.gatherFree(f + grid.gravityForce());
  EXPECT_LT(net.cwiseAbs().maxCoeff(), 1e-6 * g.mass * 9.81);
  EXPECT_GT((eq.positions - grid.initialPositions()).cwiseAbs().maxCoeff(), 1e-9);  // it did sag
}

TEST(Equilibrium, FailureSaysWhatToDoInstead)
{
  const Grid grid(paper3D());
  try
  {
    solveEquilibrium(grid, grid.initialPositions(), 1);
    FAIL() << "one Newton iteration cannot bring a sheet turned 45 degrees to rest";
  }
  catch (const std::runtime_error& e)
  {
    EXPECT_TRUE(contains(e.what(), "after 1 iterations")) << e.what();
    EXPECT_TRUE(contains(e.what(), "linearization 'rest'")) << e.what();
    EXPECT_FALSE(contains(e.what(), "stiffer springs")) << e.what();
  }
}
