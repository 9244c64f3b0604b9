// The linear solvers of Newton's tangents: each against Eigen's simplicial LDL^T (the solver the
// implicit step used before them), on single solves and on whole implicit steps of grids with slack and
// compressed springs and with handles; and the pattern-keeping tangent assembly against the one from
// triplets.
#include "modal_mass_spring/force_model.h"
#include "modal_mass_spring/spring_forces.h"
#include "dynamics/integrator.h"
#include "solvers/equilibrium.h"
#include "solvers/tangent_solver.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <stdexcept>
#include <string>
#include <vector>

using namespace modal_mass_spring;

namespace
{

const TangentSolverKind kNewKinds[] = {TangentSolverKind::Cholmod, TangentSolverKind::BlockJacobiCg};

std::string name(TangentSolverKind kind)
{
  return "solver " + std::to_string(static_cast<int>(kind));
}

// A 3D cloth of n x n particles with bending springs, top row fixed (or the given handles instead).
GridParams cloth(int n, std::vector<std::vector<int>> handles = {})
{
  GridParams g;
  g.rows = n;
  g.cols = n;
  g.dimension = 3;
  g.spacing = 0.05;
  g.mass = 0.002;
  g.structural_stiffness = 200.0;
  g.shear_stiffness = 80.0;
  g.bending = true;
  g.bending_stiffness = 20.0;
  g.handles = std::move(handles);
  return g;
}

MassDamping massDamping(const Grid& grid, double alpha)
{
  const Eigen::VectorXd mass = Eigen::VectorXd::Constant(grid.numFreeDofs(), grid.particleMass());
  SparseMatrix damping(mass.size(), mass.size());
  damping.setIdentity();
  damping = (alpha * mass).asDiagonal() * damping;
  return MassDamping{mass, damping};
}

// Free-dof displacements that squeeze the sheet to `scale` of its size about its top-left corner
// (compressed springs: an indefinite K) and add noise of `noise` spacings (slack and stretched ones).
Eigen::VectorXd deformation(const Grid& grid, double scale, double noise)
{
  std::srand(7);
  const Eigen::VectorXd x0 = grid.initialPositions();
  const Eigen::VectorXd all = (scale - 1.0) * x0 + noise * grid.params().spacing * Eigen::VectorXd::Random(x0.size());
  return grid.gatherFree(all);
}

// Steps `steps` times from the same state with the given solver; returns the final q.
Eigen::VectorXd stepWith(TangentSolverKind kind, const Grid& grid, const Eigen::VectorXd& q0, double dt, int steps,
                         int* substeps = nullptr, NewtonStart start = NewtonStart::ConstantVelocity,
                         long* newton_iterations = nullptr, long* cg_iterations = nullptr)
{
  FullForceModel model(grid, grid.initialPositions());
  ImplicitNewmark integrator(massDamping(grid, 0.5), dt, 50, -0.1, 1e-9, kind);
  integrator.setNewtonStart(start);
  State state, next;
  state.q = q0;
  state.v = Eigen::VectorXd::Zero(q0.size());
  integrator.initialize(model, state);
  for (int k = 0; k < steps; ++k)
  {
    EXPECT_TRUE(integrator.step(model, state, next)) << name(kind) << " step " << k;
    if (substeps)
      *substeps = std::max(*substeps, integrator.lastSubsteps());
    if (newton_iterations)
      *newton_iterations += integrator.lastIterations();
    std::swap(state, next);
  }
  if (cg_iterations)
    *cg_iterations = integrator.linearSolver().cgIterations();
  return state.q;
}

}  // namespace

TEST(TangentAssembler, MatchesTheAssemblyFromTriplets)
{
  for (int dimension : {2, 3})
  {
    GridParams g = cloth(6, {{30, 31}});
    g.dimension = dimension;
    const Grid grid(g);
    Eigen::VectorXd x = grid.initialPositions();
    grid.addFree(deformation(grid, 0.9, 0.3), x);
    const TangentAssembler assembler(grid);
    SparseMatrix k;
    for (CompressedSprings compressed : {CompressedSprings::Keep, CompressedSprings::Drop})
    {
      int dropped = -1, dropped_triplets = -2;
      assembler.assemble(x, k, compressed, &dropped);
      const SparseMatrix expected = tangentStiffness(grid, x, compressed, &dropped_triplets);
      EXPECT_EQ(dropped, dropped_triplets);
      EXPECT_LT((Eigen::MatrixXd(k) - Eigen::MatrixXd(expected)).norm(), 1e-12 * Eigen::MatrixXd(expected).norm())
          << dimension << "D";
    }
  }
}

TEST(TangentSolver, EveryKindSolvesAPositiveDefiniteTangentAndRefusesAnIndefiniteOne)
{
  const Grid grid(cloth(8));
  const TangentAssembler assembler(grid);
  Eigen::VectorXd x = grid.initialPositions();
  grid.addFree(deformation(grid, 1.05, 0.05), x);
  SparseMatrix k;
  assembler.assemble(x, k);
  SparseMatrix inertia(k.rows(), k.rows());
  inertia.setIdentity();
  const SparseMatrix j = SparseMatrix(k + 500.0 * inertia);
  std::srand(3);
  const Eigen::VectorXd b = Eigen::VectorXd::Random(k.rows());
  Eigen::VectorXd reference;
  ASSERT_TRUE(TangentSolver(TangentSolverKind::SimplicialLdlt).solve(j, b, reference, 0.0));

  // Squeezed to 80%, every spring is compressed: K alone is indefinite.
  Eigen::VectorXd squeezed = grid.initialPositions();
  grid.addFree(deformation(grid, 0.8, 0.0), squeezed);
  SparseMatrix indefinite;
  assembler.assemble(squeezed, indefinite);
  Eigen::VectorXd unused;
  EXPECT_FALSE(TangentSolver(TangentSolverKind::SimplicialLdlt).solve(indefinite, b, unused, 0.0));

  for (TangentSolverKind kind : kNewKinds)
  {
    TangentSolver solver(kind);
    solver.setBlockSize(3);  // a particle's dofs: BlockJacobiCg's blocks (the others ignore it)
    Eigen::VectorXd x_solved;
    const double tolerance = 1e-10 * b.norm();
    ASSERT_TRUE(solver.solve(j, b, x_solved, tolerance)) << name(kind);
    EXPECT_LE((b - j * x_solved).norm(), tolerance * (1.0 + 1e-6)) << name(kind);
    EXPECT_LT((x_solved - reference).norm(), 1e-8 * reference.norm()) << name(kind);
    // A second, nearby J: a reused factor preconditions it.
    const SparseMatrix j2 = SparseMatrix(k + 520.0 * inertia);
    ASSERT_TRUE(solver.solve(j2, b, x_solved, tolerance)) << name(kind);
    EXPECT_LE((b - j2 * x_solved).norm(), tolerance * (1.0 + 1e-6)) << name(kind);
    EXPECT_FALSE(solver.solve(indefinite, b, unused, tolerance)) << name(kind);
  }
}

TEST(TangentSolver, ImplicitStepsMatchTheSimplicialSolverOnSlackCompressedAndHeldGrids)
{
  struct Case
  {
    std::string what;
    GridParams grid;
    double scale, noise;
  };
  const Case cases[] = {
      {"compressed", cloth(10), 0.85, 0.0},
      {"slack and stretched", cloth(10), 1.0, 0.3},
      {"handles", cloth(10, {{90, 91}, {98, 99}}), 1.02, 0.1},
  };
  for (const Case& c : cases)
  {
    const Grid grid(c.grid);
    const Eigen::VectorXd q0 = deformation(grid, c.scale, c.noise);
    for (const int steps : {1, 20})
    {
      const Eigen::VectorXd reference = stepWith(TangentSolverKind::SimplicialLdlt, grid, q0, 0.005, steps);
      const double motion = (reference - q0).norm();
      ASSERT_GT(motion, 1e-3) << c.what;
      for (TangentSolverKind kind : kNewKinds)
      {
        const Eigen::VectorXd q = stepWith(kind, grid, q0, 0.005, steps);
        // Both converged to the Newton tolerance 1e-9 of the forces: they agree far below the motion.
        EXPECT_LT((q - reference).norm(), 1e-6 * motion) << c.what << ", " << name(kind) << ", " << steps << " steps";
      }
    }
  }
}

TEST(TangentSolver, ANonConvergingStepIsStillSplitOrRefused)
{
  const Grid grid(cloth(10));
  const Eigen::VectorXd q0 = deformation(grid, 1.0, 0.3);
  // (BlockJacobiCg is not among them: on this squeezed, noisy grid at 50 ms its Newton needs the step
  // split in 3 where the others take it whole, presumably because its conjugate gradients converge
  // before they meet J's negative curvature, so no inertia is added (not yet checked); the parts still
  // converge.)
  for (TangentSolverKind kind : {TangentSolverKind::SimplicialLdlt, TangentSolverKind::Cholmod})
  {
    FullForceModel model(grid, grid.initialPositions());
    State state, next;
    state.q = q0;
    state.v = Eigen::VectorXd::Zero(q0.size());
    ImplicitNewmark whole(massDamping(grid, 0.5), 0.05, 50, -0.1, 1e-9, kind);
    whole.initialize(model, state);
    ASSERT_TRUE(whole.step(model, state, next)) << name(kind);
    ASSERT_EQ(whole.lastSubsteps(), 1) << name(kind);
    const int needed = whole.lastIterations();
    ASSERT_GT(needed, 2) << name(kind);
    // One iteration fewer than the whole step needs: it is taken in parts, or refused; never whole.
    ImplicitNewmark fewer(massDamping(grid, 0.5), 0.05, needed - 1, -0.1, 1e-9, kind);
    if (fewer.step(model, state, next))
    {
      EXPECT_GT(fewer.lastSubsteps(), 1) << name(kind);
    }
    // One iteration converges nothing, even in 1/16 of the step: refused.
    ImplicitNewmark refused(massDamping(grid, 0.5), 0.05, 1, -0.1, 1e-9, kind);
    EXPECT_FALSE(refused.step(model, state, next)) << name(kind);
  }
}

TEST(SpringTangent, ProductsAndDiagonalBlocksMatchTheAssembledTangent)
{
  for (int dimension : {2, 3})
  {
    // Handles and the fixed top row leave springs with one end or none free; squeezed and noisy,
    // some springs are compressed (the exact Hessian keeps their geometric part).
    GridParams g = cloth(7, {{40, 41}});
    g.dimension = dimension;
    const Grid grid(g);
    Eigen::VectorXd x = grid.initialPositions();
    grid.addFree(deformation(grid, 0.9, 0.3), x);
    const SparseMatrix k = tangentStiffness(grid, x);
    SpringTangent springs(grid);
    springs.update(x);
    std::srand(5);
    const Eigen::VectorXd p = Eigen::VectorXd::Random(k.rows());
    Eigen::VectorXd kp = Eigen::VectorXd::Ones(k.rows());
    springs.multiplyAdd(p, 2.0, kp);
    const Eigen::VectorXd expected = Eigen::VectorXd::Ones(k.rows()) + 2.0 * (k * p);
    EXPECT_LT((kp - expected).norm(), 1e-12 * expected.norm()) << dimension << "D";

    Eigen::VectorXd blocks = Eigen::VectorXd::Zero(k.rows() * dimension);
    springs.addDiagonalBlocks(0.5, blocks);
    const Eigen::MatrixXd dense(k);
    double largest_error = 0.0;
    for (int particle = 0; particle < k.rows() / dimension; ++particle)
      for (int c = 0; c < dimension; ++c)
        for (int r = 0; r < dimension; ++r)
          largest_error = std::max(largest_error, std::abs(blocks[(particle * dimension + c) * dimension + r] -
                                                           0.5 * dense(particle * dimension + r, particle * dimension + c)));
    EXPECT_LT(largest_error, 1e-12 * dense.cwiseAbs().maxCoeff()) << dimension << "D";
  }
}

// A swinging cloth: the sheet turned 60 degrees out of the vertical about its fixed top row, released
// from rest.
GridParams swinging(int n)
{
  GridParams g = cloth(n);
  g.rotation_deg = 60.0;
  return g;
}

TEST(TangentSolver, ParticleBlocksNeedFewerIterationsThanTheDiagonalForTheSameSolution)
{
  // Newton's tangent of a 5 ms step (HHT alpha -0.1) on the swinging cloth, disturbed: block Jacobi
  // with a particle's 3 dofs a block against blocks of one dof (J's diagonal).
  const Grid grid(swinging(12));
  const TangentAssembler assembler(grid);
  Eigen::VectorXd x = grid.initialPositions();
  grid.addFree(deformation(grid, 1.0, 0.1), x);
  SparseMatrix k;
  assembler.assemble(x, k, CompressedSprings::Drop);
  SparseMatrix inertia(k.rows(), k.rows());
  inertia.setIdentity();
  const double beta = 0.25 * 1.1 * 1.1, h = 0.005;
  const SparseMatrix j = SparseMatrix(grid.particleMass() / (beta * h * h) * inertia + 1.1 * k);
  std::srand(3);
  const Eigen::VectorXd b = Eigen::VectorXd::Random(k.rows());
  const double tolerance = 1e-10 * b.norm();
  Eigen::VectorXd reference;
  ASSERT_TRUE(TangentSolver(TangentSolverKind::SimplicialLdlt).solve(j, b, reference, 0.0));
  long iterations[2] = {0, 0};
  for (int block_size : {1, 3})
  {
    TangentSolver solver(TangentSolverKind::BlockJacobiCg);
    solver.setBlockSize(block_size);
    Eigen::VectorXd solved;
    ASSERT_TRUE(solver.solve(j, b, solved, tolerance)) << block_size;
    EXPECT_EQ(solver.factorisations(), 0) << block_size;  // converged, no fallback
    EXPECT_LT((solved - reference).norm(), 1e-8 * reference.norm()) << block_size;
    iterations[block_size == 3] = solver.cgIterations();
  }
  EXPECT_GT(iterations[0], 0);
  EXPECT_LT(iterations[1], iterations[0]);
}

TEST(ImplicitNewmark, StartingFromTheConstantAccelerationConvergesToTheSameStepsInNoMoreIterations)
{
  const Grid grid(swinging(12));
  const Eigen::VectorXd q0 = Eigen::VectorXd::Zero(grid.numFreeDofs());
  for (TangentSolverKind kind : {TangentSolverKind::SimplicialLdlt, TangentSolverKind::BlockJacobiCg})
  {
    long constant_velocity = 0, constant_acceleration = 0;
    const Eigen::VectorXd reference =
        stepWith(kind, grid, q0, 0.005, 40, nullptr, NewtonStart::ConstantVelocity, &constant_velocity);
    const Eigen::VectorXd q =
        stepWith(kind, grid, q0, 0.005, 40, nullptr, NewtonStart::ConstantAcceleration, &constant_acceleration);
    ASSERT_GT((reference - q0).norm(), 1e-2) << name(kind);
    EXPECT_LT((q - reference).norm(), 1e-6 * (reference - q0).norm()) << name(kind);
    EXPECT_LE(constant_acceleration, constant_velocity) << name(kind);
  }
}

TEST(Equilibrium, TellsItsProgressAndNamesItsIterationLimit)
{
  const Grid grid(cloth(12));
  std::vector<double> residuals;
  double target = 0.0;
  const Equilibrium found = solveEquilibrium(grid, grid.initialPositions(), 1000, 1e-9,
                                             [&](int iteration, double residual, double goal) {
                                               EXPECT_EQ(iteration, static_cast<int>(residuals.size()));
                                               residuals.push_back(residual);
                                               target = goal;
                                             });
  ASSERT_EQ(static_cast<int>(residuals.size()), found.iterations + 1);
  ASSERT_GT(found.iterations, 2);
  EXPECT_EQ(residuals.back(), found.residual);
  EXPECT_LE(found.residual, target);
  EXPECT_GT(residuals.front(), 1e3 * target);  // the flat sheet hangs far from balance

  // Two iterations are not enough: refused, saying the limit stopped it, after telling both.
  residuals.clear();
  try
  {
    solveEquilibrium(grid, grid.initialPositions(), 2, 1e-9,
                     [&](int, double residual, double) { residuals.push_back(residual); });
    FAIL() << "two iterations found the equilibrium";
  }
  catch (const std::runtime_error& e)
  {
    EXPECT_NE(std::string(e.what()).find("Newton stopped after 2 iterations (its limit)"), std::string::npos) << e.what();
  }
  EXPECT_EQ(residuals.size(), 2u);
}
