// The static equilibrium under gravity and the linearization there: the force balance, closed forms
// (a hanging chain's modes), a stiff grid's round-off, and what a failed solve says.
#include "modal_mass_spring/modal_basis.h"
#include "modal_mass_spring/simulation.h"
#include "modal_mass_spring/spring_forces.h"
#include "solvers/equilibrium.h"

#include "test_support.h"

#include <Eigen/SparseCholesky>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <sstream>
#include <string>
#include <vector>

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

namespace
{

// config/cloth.yaml's sheet: 20 x 20, 0.05 m, 5 g a particle, springs 50/20/5 N/m, released 30
// degrees out of the vertical (where an unrefined CHOLMOD solve stalled Newton near 1e-8 N).
GridParams clothYaml()
{
  GridParams g = clothSheet();
  g.rotation_deg = 30.0;
  return g;
}

double largestUnbalancedForce(const Grid& grid, const Eigen::VectorXd& x)
{
  Eigen::VectorXd f;
  springForces(grid, x, f);
  return grid.gatherFree(f + grid.gravityForce()).cwiseAbs().maxCoeff();
}

}  // namespace

TEST(Equilibrium, CholmodConvergesOnClothYaml)
{
  // Released at 30 degrees the sheet buckles as it hangs: Newton's path (and which of the buckled
  // equilibria it finds) hangs on round-off, so only the force balance is compared here.
  const Grid grid(clothYaml());
  const Equilibrium eq = solveEquilibrium(grid, grid.initialPositions());
  EXPECT_LE(largestUnbalancedForce(grid, eq.positions), 1e-9 * grid.particleMass() * 9.81);
}

namespace
{

// The inertia of the free dofs' exact Hessian K: its negative eigenvalues counted by the signs of the
// pivots of an LDL^T (Sylvester's law of inertia: K = P^T L D L^T P is a congruence).
int negativeEigenvalues(const Grid& grid, const Eigen::VectorXd& x)
{
  Eigen::SimplicialLDLT<SparseMatrix> ldlt(tangentStiffness(grid, x, CompressedSprings::Keep));
  EXPECT_EQ(ldlt.info(), Eigen::Success);
  return static_cast<int>((ldlt.vectorD().array() < 0.0).count());
}

}  // namespace

TEST(Equilibrium, RotatedSheetsHangInStableStates)
{
  // A buckling sheet's solve switches to Levenberg-Marquardt on the exact Hessian, which converges to
  // saddles too: the states reached must be stable, the lowest eigenvalue of K u = lambda M u positive.
  for (const GridParams& g : {clothYaml(), paper3D()})
  {
    const Grid grid(g);
    const Equilibrium eq = solveEquilibrium(grid, grid.initialPositions());
    EXPECT_EQ(negativeEigenvalues(grid, eq.positions), 0) << g.rows << " x " << g.cols;
    const SparseMatrix k = tangentStiffness(grid, eq.positions, CompressedSprings::Keep);
    const ModalBasis lowest = computeModalBasis(k, Eigen::VectorXd::Constant(k.rows(), g.mass), 1);
    EXPECT_GT(lowest.eigenvalues(0), 0.1) << g.rows << " x " << g.cols;  // 1/s^2 (2.5 and 0.57 measured)
  }
}

TEST(Equilibrium, LeavesASaddleItConvergesTo)
{
  // cloth.yaml's hanging sheet bulged slightly out of its plane: the flat state is a saddle (compressed
  // springs buckle it) and the solve from just beside it is drawn to it; it must go on to a
  // stable buckled state below it.
  GridParams flat_params = clothYaml();
  flat_params.rotation_deg = 0.0;
  const Grid grid(flat_params);
  const Equilibrium flat = solveEquilibrium(grid, grid.initialPositions());
  ASSERT_GT(negativeEigenvalues(grid, flat.positions), 0) << "the premise: the flat hanging sheet is a saddle";
  Eigen::VectorXd start = flat.positions;
  for (int row = 0; row < flat_params.rows; ++row)
    for (int col = 0; col < flat_params.cols; ++col)
      start(3 * grid.particleIndex(row, col) + 1) +=
          1e-4 * std::sin(M_PI * col / (flat_params.cols - 1)) * row / (flat_params.rows - 1);
  const Equilibrium eq = solveEquilibrium(grid, start);
  EXPECT_LE(largestUnbalancedForce(grid, eq.positions), 1e-9 * grid.particleMass() * 9.81);
  EXPECT_EQ(negativeEigenvalues(grid, eq.positions), 0);
  const auto energy = [&](const Eigen::VectorXd& x) { return springEnergy(grid, x) + gravityEnergy(grid, x); };
  EXPECT_LT(energy(eq.positions), energy(flat.positions) - 1e-9);
}

TEST(Equilibrium, CholmodFindsTheSimplicialLdltsEquilibrium)
{
  GridParams hanging = clothYaml();
  hanging.rotation_deg = 0.0;  // hangs from the flat vertical sheet without buckling
  for (const GridParams& g : {hanging, turnedSheet(), paper2D()})
  {
    const Grid grid(g);
    const Equilibrium cholmod = solveEquilibrium(grid, grid.initialPositions());
    const Equilibrium simplicial = solveEquilibrium(grid, grid.initialPositions(), kDefaultEquilibriumMaxIterations,
                                                    kEquilibriumTolerance, {}, EquilibriumSolver::SimplicialLdlt);
    // Both to the full tolerance, 1e-9 of a particle's weight (not the square-root fallback).
    const double target = 1e-9 * g.mass * 9.81;
    EXPECT_LE(largestUnbalancedForce(grid, cholmod.positions), target) << g.rows << " x " << g.cols;
    EXPECT_LE(largestUnbalancedForce(grid, simplicial.positions), target) << g.rows << " x " << g.cols;
    EXPECT_LT((cholmod.positions - simplicial.positions).cwiseAbs().maxCoeff(), 1e-9) << g.rows << " x " << g.cols;
  }
}

TEST(Equilibrium, TellsItsProgressAndItsLimitNamesTheParameter)
{
  const Grid grid(clothYaml());
  std::vector<double> residuals;
  double told_target = 0.0;
  const Equilibrium eq = solveEquilibrium(grid, grid.initialPositions(), kDefaultEquilibriumMaxIterations,
                                          kEquilibriumTolerance, [&](int iteration, double residual, double target) {
                                            EXPECT_EQ(iteration, static_cast<int>(residuals.size()));
                                            residuals.push_back(residual);
                                            told_target = target;
                                          });
  ASSERT_EQ(static_cast<int>(residuals.size()), eq.iterations + 1);
  EXPECT_GT(residuals.front(), 1e3 * told_target);
  EXPECT_LE(residuals.back(), told_target);
  ASSERT_GT(eq.iterations, 2);

  // Two iterations fewer than it needs: refused, naming the force reached and the parameter.
  SimulationParams s = methodParams(Method::Full, 4, 1e-3);
  s.linearization = Linearization::Equilibrium;
  s.equilibrium_max_iterations = eq.iterations - 2;
  try
  {
    Simulation sim(clothYaml(), s);
    FAIL() << "the iteration limit did not stop the equilibrium";
  }
  catch (const std::runtime_error& e)
  {
    std::ostringstream reached;
    reached << "unbalanced force of " << residuals[eq.iterations - 2] << " N";
    EXPECT_TRUE(contains(e.what(), reached.str())) << e.what();
    EXPECT_TRUE(contains(e.what(), "(its limit)")) << e.what();
    EXPECT_TRUE(contains(e.what(), "raise equilibrium_max_iterations (now " + std::to_string(eq.iterations - 2) + ")"))
        << e.what();
  }
}

TEST(Equilibrium, FullBuildsItsBasisOnlyWhenAModalMethodIsSet)
{
  SimulationParams s = methodParams(Method::Full, 6, 1e-3);
  s.linearization = Linearization::Equilibrium;
  GridParams g = clothYaml();
  g.rows = g.cols = 8;
  std::vector<std::string> stages, iterated;
  Simulation full(
      g, s, [&](const std::string& stage) { stages.push_back(stage); }, {},
      [&](const std::string& stage, int, double, double) { iterated.push_back(stage); });
  EXPECT_FALSE(full.basisBuilt());
  EXPECT_EQ(full.basis().phi.cols(), 0);
  EXPECT_EQ(std::count(stages.begin(), stages.end(), "eigensolver"), 0);
  EXPECT_GT(std::count(iterated.begin(), iterated.end(), "equilibrium"), 2);
  EXPECT_EQ(std::count(iterated.begin(), iterated.end(), "eigensolver"), 0);
  full.step(20);
  const Eigen::VectorXd before = full.positions();

  full.setMethod(Method::Physical);  // builds it now, the motion carried over
  EXPECT_TRUE(full.basisBuilt());
  EXPECT_LT((full.positions() - before).cwiseAbs().maxCoeff(), 1e-14);
  s.method = Method::Physical;
  const Simulation modal(g, s);
  ASSERT_EQ(full.basis().phi.cols(), 6);
  EXPECT_LT((full.basis().frequencies - modal.basis().frequencies).cwiseAbs().maxCoeff(),
            1e-9 * modal.basis().frequencies.maxCoeff());
  EXPECT_LT((full.basis().phi - modal.basis().phi).cwiseAbs().maxCoeff(), 1e-6);
}
