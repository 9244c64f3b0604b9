// Method `coarse`: the same cloth on a coarser grid, interpolated onto the grid.
#include "modal_mass_spring/simulation.h"
#include "reduction/coarse_grid.h"
#include "reduction/error_indicator.h"

#include "test_support.h"

#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>

#include <cmath>
#include <iostream>

using namespace modal_mass_spring;

namespace
{

// The RMS over the particles of the distance between two position vectors (m).
double rmsDistance(const Eigen::VectorXd& a, const Eigen::VectorXd& b, int dim)
{
  const Eigen::VectorXd d = a - b;
  return std::sqrt(d.squaredNorm() / (d.size() / dim));
}

// A sheet turned 60 degrees from hanging, top row fixed: it swings down.
GridParams swingingSheet(int n)
{
  GridParams g = clothSheet(n);
  g.rotation_deg = 60.0;
  return g;
}

SimulationParams coarseParams(int coarse_cols, double dt = 1e-3)
{
  SimulationParams s = methodParams(Method::Coarse, 4, dt);
  s.coarse_cols = coarse_cols;
  return s;
}

// The highest angular frequency of M^-1 K on a coarse grid's free dofs at rest (rad/s; dense: small
// grids only).
double highestFrequency(const CoarseGrid& g)
{
  const Eigen::MatrixXd stiffness(g.stiffness);
  const Eigen::MatrixXd mass = g.mass.asDiagonal();
  Eigen::GeneralizedSelfAdjointEigenSolver<Eigen::MatrixXd> eig(stiffness, mass, Eigen::EigenvaluesOnly);
  return std::sqrt(eig.eigenvalues().maxCoeff());
}

}  // namespace

TEST(CoarseGrid, SpansTheSameClothWithItsMass)
{
  GridParams fine = swingingSheet(13);
  const Grid grid(fine);
  const CoarseGrid coarse(grid, 5);
  EXPECT_EQ(coarse.grid.params().rows, 5);
  EXPECT_DOUBLE_EQ(coarse.grid.params().spacing, 3 * fine.spacing);
  EXPECT_DOUBLE_EQ(coarse.grid.params().structural_stiffness, fine.structural_stiffness);
  EXPECT_DOUBLE_EQ(coarse.grid.params().bending_stiffness, fine.bending_stiffness);
  EXPECT_NEAR(coarse.grid.particleMass() * coarse.grid.numParticles(), fine.mass * grid.numParticles(), 1e-12);
  // The fine rest is the interpolation of the coarse rest, and the coarse rest the sample of the fine.
  const Eigen::VectorXd interpolated = coarse.interpolation * coarse.x_ref;
  EXPECT_LT((interpolated - grid.gatherFree(grid.initialPositions())).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT((coarse.sampling * grid.initialPositions() - coarse.x_ref).cwiseAbs().maxCoeff(), 1e-12);
  // The top row stays fixed.
  EXPECT_EQ(coarse.grid.fixedParticles(), (std::vector<int>{0, 1, 2, 3, 4}));
}

TEST(CoarseGrid, AboutAThirdOfTheColumnsAtMostTwentyByDefault)
{
  GridParams g = clothSheet(100);
  EXPECT_EQ(resolveCoarseCols(g, 0), 20);
  g = clothSheet(200);
  EXPECT_EQ(resolveCoarseCols(g, 0), 20);
  g = clothSheet(50);
  EXPECT_EQ(resolveCoarseCols(g, 0), 18);
  // 100 rows, 199 columns: only odd counts allowed; 19 and 21 are as near 20, and 21 is above it.
  g.rows = 100, g.cols = 199;
  EXPECT_EQ(resolveCoarseCols(g, 0), 19);
  // 30 rows, 40 columns: only columns whose rows come out whole.
  g.rows = 30, g.cols = 40;
  const int cols = resolveCoarseCols(g, 0);
  EXPECT_EQ(29 * (cols - 1) % 39, 0) << cols;
}

// The explicit step's limit, 2 / omega_max, grows on the coarse grid as the square root of its
// particles' mass; coarseStepMultiple spans that many fine steps, rounded down, and `coarse` is stable
// there and unstable well beyond its own limit.
TEST(CoarseGrid, StepMultipleKeepsTheMarginToTheExplicitLimit)
{
  const GridParams fine = swingingSheet(19);
  const Grid grid(fine);
  const CoarseGrid itself(grid, 19), coarse(grid, 0);
  ASSERT_EQ(coarse.grid.params().cols, 7);
  const double omega = highestFrequency(itself);
  const double ratio = omega / highestFrequency(coarse);
  const double mass_ratio = 19.0 * 19.0 / (7.0 * 7.0);
  EXPECT_NEAR(ratio, std::sqrt(mass_ratio), 0.1 * std::sqrt(mass_ratio));

  SimulationParams p = coarseParams(0, 0.9 * 2.0 / omega);  // 90% of the fine grid's limit
  p.alpha = p.beta = 0.0;
  const int multiple = coarseStepMultiple(fine, p);
  EXPECT_EQ(multiple, 2);
  EXPECT_LE(multiple, ratio);
  p.time_step *= multiple;
  Simulation stable(fine, p);
  EXPECT_FALSE(stable.step(4000).diverged);
  p.time_step = 1.3 * 2.0 * ratio / omega;  // past the coarse grid's own limit
  Simulation unstable(fine, p);
  EXPECT_TRUE(unstable.step(4000).diverged);

  // The damping's limit bounds it under the explicit integrator only.
  const GridParams large = clothSheet(100);
  SimulationParams q = coarseParams(12, 1e-3);  // 100 x 100 on 12 x 12: 69 fine particles a coarse one
  EXPECT_EQ(coarseStepMultiple(large, q), 8);
  q.alpha = 500.0;  // alpha time_step = 0.5
  EXPECT_EQ(coarseStepMultiple(large, q), 4);
  q.integrator = IntegratorKind::Implicit;
  EXPECT_EQ(coarseStepMultiple(large, q), 8);
  // Dividing a number of steps (between samples, to a horizon): the largest such at most the limit's.
  EXPECT_EQ(coarseStepMultiple(large, q, 12), 6);
  EXPECT_EQ(coarseStepMultiple(large, q, 7), 7);
  EXPECT_EQ(coarseStepMultiple(large, q, 5), 5);
  EXPECT_EQ(coarseStepMultiple(large, q, 11), 1);
  EXPECT_EQ(coarseStepMultiple(large, q, 64), 8);
  q.coarse_cols = 100;
  EXPECT_EQ(coarseStepMultiple(large, q), 1);
}

TEST(CoarseGrid, RefusesByNameWhatCannotSpanOrHoldTheCloth)
{
  GridParams g = clothSheet(30);
  g.cols = 40;
  const std::string uneven = refusal([&] { resolveCoarseCols(g, 20); });
  EXPECT_TRUE(contains(uneven, "'coarse_cols' = 20")) << uneven;
  EXPECT_TRUE(contains(uneven, "whole")) << uneven;
  EXPECT_TRUE(contains(refusal([&] { resolveCoarseCols(g, -1); }), "coarse_cols"));
  // Two neighbouring grips fall on one particle of a grid three times coarser.
  const GridParams held = heldCloth({{0}, {1}}, 10);
  const std::string clash = refusal([&] { CoarseGrid(Grid(held), 4); });
  EXPECT_TRUE(contains(clash, "handles[0] and handles[1]")) << clash;
  SimulationParams s = coarseParams(4);
  EXPECT_TRUE(contains(refusal([&] { Simulation(held, s); }), "coarse_cols")) << "refused before the build";
  // Held by its top and bottom rows, a 2 x 2 coarse grid has no particle left to move.
  const std::string all_held = refusal([&] { Simulation(heldCloth({{0, 1, 2, 3}, {12, 13, 14, 15}}, 4), coarseParams(2)); });
  EXPECT_TRUE(contains(all_held, "'coarse_cols' = 2")) << all_held;
  EXPECT_TRUE(contains(all_held, "every particle")) << all_held;
}

TEST(CoarseGrid, HandlesHoldTheNearestCoarseParticles)
{
  const GridParams held = heldCloth({{0, 1}, {9}}, 10);
  const CoarseGrid coarse(Grid(held), 4);
  ASSERT_EQ(coarse.grid.handles().size(), 2u);
  EXPECT_EQ(coarse.grid.handles()[0], std::vector<int>{0});
  EXPECT_EQ(coarse.grid.handles()[1], std::vector<int>{3});
  // Each copies its own fine particle's motion: handle 0's particle 0, handle 1's particle 9.
  EXPECT_EQ(coarse.handle_source, (std::vector<int>{0, 1, 2, 6, 7, 8}));
  EXPECT_TRUE(coarse.grid.fixedParticles().empty());
}

// The interpolation reproduces an affine map of the grid exactly, so nothing of it is missed; a
// particle moved between the coarse ones is. What is outside the span of a force is orthogonal to
// every coarse free dof's interpolation, and nothing of a force in it is outside.
TEST(CoarseGrid, MissesWhatItsInterpolationCannotHold)
{
  const Grid grid(swingingSheet(13));
  const CoarseGrid coarse(grid, 5);
  const Eigen::Matrix3d a = Eigen::AngleAxisd(0.4, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix() * 1.1;
  Eigen::VectorXd x = grid.initialPositions();
  for (Eigen::Index k = 0; k < x.size(); k += 3)
    x.segment<3>(k) = a * x.segment<3>(k) + Eigen::Vector3d(0.1, -0.2, 0.3);
  EXPECT_LT(coarse.missed(x).cwiseAbs().maxCoeff(), 1e-12);
  const int between = 4 * 13 + 4;  // row 4, column 4: between coarse particles (every third)
  x[3 * between + 2] += 0.01;
  const Eigen::VectorXd missed = coarse.missed(x);
  EXPECT_NEAR(missed[grid.freeIndex(3 * between + 2)], 0.01, 1e-12);
  EXPECT_GT(missed.cwiseAbs().maxCoeff(), 0.009);

  // P_f: the interpolation from the coarse free dofs.
  Eigen::MatrixXd p_free = Eigen::MatrixXd::Zero(grid.numFreeDofs(), coarse.grid.numFreeDofs());
  const Eigen::MatrixXd p(coarse.interpolation);
  for (int c = 0; c < coarse.grid.numDofs(); ++c)
    if (const int free = coarse.grid.freeIndex(c); free >= 0)
      p_free.col(free) = p.col(c);
  const Eigen::VectorXd f = Eigen::VectorXd::Random(grid.numFreeDofs());
  const Eigen::VectorXd outside = coarse.outsideSpan(f);
  EXPECT_GT(outside.norm(), 0.1 * f.norm());
  EXPECT_LT((p_free.transpose() * outside).cwiseAbs().maxCoeff(), 1e-12);
  const Eigen::VectorXd in_span = p_free * Eigen::VectorXd::Random(coarse.grid.numFreeDofs());
  EXPECT_LT(coarse.outsideSpan(in_span).cwiseAbs().maxCoeff(), 1e-12);
}

// The error indicator of `coarse`: nothing on the grid itself, where the span is every
// displacement; on a coarser grid, the swinging sheet leaves force outside it, the more the coarser.
// How far a state is from the span: nothing for a state `coarse` itself stepped to, something for
// `full`'s, and what a switch freezes.
TEST(Coarse, ErrorIndicatorAndSpanDistanceSeeWhatTheCoarseGridCannotHold)
{
  const GridParams g = swingingSheet(13);
  std::vector<double> indicator;
  for (int cols : {4, 7, 13})
  {
    Simulation sim(g, coarseParams(cols, 5e-4));
    ASSERT_FALSE(sim.step(400).diverged);
    indicator.push_back(sim.errorIndicator());
    EXPECT_LT(sim.spanDistance(Method::Coarse), 1e-12) << cols << " columns";
  }
  std::cout << "indicator on 4, 7, 13 columns: " << indicator[0] << ", " << indicator[1] << ", " << indicator[2] << " m\n";
  EXPECT_LT(indicator[2], 1e-12);
  EXPECT_GT(indicator[1], 1e-6);
  EXPECT_GT(indicator[0], indicator[1]);

  Simulation sim(g, methodParams(Method::Full, 4, 5e-4));
  ASSERT_FALSE(sim.step(400).diverged);
  EXPECT_THROW(sim.spanDistance(Method::Coarse), std::logic_error);  // no coarse grid yet
  sim.setMethod(Method::Coarse);
  sim.setMethod(Method::Full);
  const double distance = sim.spanDistance(Method::Coarse);
  EXPECT_GT(distance, 1e-5);
  sim.setMethod(Method::Coarse);
  const Eigen::VectorXd frozen = sim.saveState().offset;
  EXPECT_NEAR(std::sqrt(frozen.squaredNorm() / (frozen.size() / 3)), distance, 1e-12);
}

// On a grid more than three times finer than its coarse grid, `coarse`'s indicator reads a view with
// three times the coarse columns; on one at most that fine, the grid itself. The view is fitted to
// the hanging equilibrium, where nothing is left outside the span. Read from the coarse state while
// `coarse` steps (its handles slid, the detail frozen at its start), it is what the grid's positions
// sampled onto the view give after a switch to `full`, which moves no particle; and the swing's
// speed, over a lattice of the particles on a grid this large, is what `full` reads of them one at a
// time.
TEST(Coarse, OnAFinerGridItsIndicatorReadsAViewAtAThirdOfTheCoarseSpacing)
{
  const Grid fine(swingingSheet(13));
  const CoarseGrid on_5(fine, 5);  // 3 x 4 + 1 = 13 columns: the grid itself
  EXPECT_FALSE(CoarseErrorIndicator(fine, on_5, Eigen::VectorXd::Ones(fine.numFreeDofs()), fine.initialPositions(),
                                    Eigen::VectorXd())
                   .viewed());

  const GridParams g = heldCloth({{0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22,
                                   23, 24, 25, 26, 27, 28, 29, 30, 31, 32, 33}},
                                 34);
  SimulationParams s = coarseParams(6, 5e-4);  // a view of 16 columns
  s.linearization = Linearization::Equilibrium;
  s.initial_state = InitialState::Equilibrium;
  s.alpha = 0.5;
  Simulation sim(g, s);
  const CoarseGrid coarse(sim.grid(), 6);
  const Eigen::VectorXd mass = Eigen::VectorXd::Constant(sim.grid().numFreeDofs(), sim.grid().particleMass());
  const CoarseErrorIndicator unfitted(sim.grid(), coarse, mass, sim.linearizationPositions(), Eigen::VectorXd());
  const CoarseErrorIndicator fitted(sim.grid(), coarse, mass, sim.linearizationPositions(), sim.linearizationPositions());
  ASSERT_TRUE(unfitted.viewed());
  ASSERT_TRUE(fitted.viewed());
  const double at_rest = sim.errorIndicator();
  EXPECT_LT(at_rest, 1e-12);
  EXPECT_GT(unfitted(sim.positions(), Eigen::VectorXd()), 1e3 * at_rest + 1e-9) << "the fit must matter";

  const Eigen::VectorXd start = sim.handlePositions();
  for (long k = 0; k < 200; ++k)
  {
    slideHandles(sim, start, k, 2.0);
    ASSERT_FALSE(sim.step().diverged);
  }
  const double stepping = sim.errorIndicator(), speed = sim.deformationSpeed();
  EXPECT_GT(stepping, 1e-7);
  EXPECT_NEAR(fitted(sim.positions(), Eigen::VectorXd()), stepping, 1e-9 * stepping) << "the simulation reads the view";
  sim.setMethod(Method::Full);
  EXPECT_NEAR(sim.errorIndicator(Method::Coarse), stepping, 1e-9 * stepping);
  EXPECT_GT(speed, 1e-3);
  EXPECT_NEAR(sim.deformationSpeed(), speed, 1e-9 * speed);
}

// With as many columns as the grid, the coarse grid is the grid: `coarse` steps as `full` does, held
// by moving handles over a table it lands on.
TEST(Coarse, OnTheGridItselfIsFull)
{
  const GridParams g = heldCloth({{0}, {7}}, 8);
  SimulationParams s = coarseParams(8);
  s.alpha = 0.5;
  s.colliders = {tableBelow(g, 0.02)};
  Simulation coarse(g, s);
  s.method = Method::Full;
  Simulation full(g, s);
  const Eigen::VectorXd start = full.handlePositions();
  double largest = 0.0;
  for (long k = 0; k < 300; ++k)
  {
    slideHandles(full, start, k, 0.4);
    slideHandles(coarse, start, k, 0.4);
    ASSERT_FALSE(full.step().diverged);
    ASSERT_FALSE(coarse.step().diverged);
    largest = std::max(largest, (full.positions() - coarse.positions()).cwiseAbs().maxCoeff());
  }
  EXPECT_LT(largest, 1e-12);
  ASSERT_GT(full.contact()->report().touching[0], 0) << "the cloth must reach the table for the test to mean anything";
  EXPECT_EQ(coarse.contact()->report().touching, full.contact()->report().touching);
  EXPECT_EQ(coarse.contact()->report().force[0], full.contact()->report().force[0]);
  EXPECT_EQ(coarse.particleContacts(), full.particleContacts());
  const Eigen::VectorXd v_full = full.velocity(), v_coarse = coarse.velocity();
  EXPECT_LT((v_full - v_coarse).cwiseAbs().maxCoeff(), 1e-10);
  for (int k = 0; k < v_full.size(); k += 5)
    EXPECT_NEAR(coarse.displacement()[k], full.displacement()[k], 1e-12);
}

// A sheet swinging down from 60 degrees: the coarser the grid, the further from `full`, and on half
// the columns within a centimetre.
TEST(Coarse, ApproachesFullAsTheCoarseGridRefines)
{
  const GridParams g = swingingSheet(13);
  SimulationParams s = methodParams(Method::Full, 4, 5e-4);
  s.alpha = 0.2;
  Simulation full(g, s);
  std::vector<std::unique_ptr<Simulation>> coarse;
  for (int cols : {4, 5, 7})
    coarse.push_back(std::make_unique<Simulation>(g, coarseParams(cols, 5e-4)));
  std::vector<double> mean(coarse.size(), 0.0);
  const int samples = 20;
  for (int k = 0; k < samples; ++k)
  {
    ASSERT_FALSE(full.step(50).diverged);
    for (size_t i = 0; i < coarse.size(); ++i)
    {
      ASSERT_FALSE(coarse[i]->step(50).diverged);
      mean[i] += rmsDistance(coarse[i]->positions(), full.positions(), 3) / samples;
    }
  }
  EXPECT_GT((full.positions() - Grid(g).initialPositions()).cwiseAbs().maxCoeff(), 0.1) << "it must swing";
  EXPECT_GT(mean[0], mean[1]);
  EXPECT_GT(mean[1], mean[2]);
  EXPECT_LT(mean[2], 0.01) << mean[2];
  std::cout << "mean RMS to full on 4, 5, 7 columns: " << mean[0] << ", " << mean[1] << ", " << mean[2] << " m\n";
}

// Without damping `coarse` conserves its grid's energy as `full` does its own.
TEST(Coarse, ConservesEnergyWithoutDamping)
{
  Simulation sim(swingingSheet(13), coarseParams(7, 5e-4));
  const double start = sim.methodEnergy();
  double farthest = 0.0;
  for (int k = 0; k < 40; ++k)
  {
    ASSERT_FALSE(sim.step(50).diverged);
    farthest = std::max(farthest, std::abs(sim.methodEnergy() - start));
  }
  EXPECT_GT(start - sim.totalEnergy(), -1.0) << "sanity";
  EXPECT_LT(farthest, 1e-3 * sim.energyScale());
}

// A switch carries the state over without moving a particle, both ways.
TEST(Coarse, SwitchMovesNoParticle)
{
  Simulation sim(swingingSheet(13), methodParams(Method::Full, 4, 5e-4));
  sim.step(200);
  const Eigen::VectorXd before = sim.positions();
  sim.setMethod(Method::Coarse);
  EXPECT_EQ(sim.method(), Method::Coarse);
  EXPECT_NE(sim.coarseGrid(), nullptr);
  EXPECT_LT((sim.positions() - before).cwiseAbs().maxCoeff(), 1e-12);
  ASSERT_FALSE(sim.step(200).diverged);
  const Eigen::VectorXd later = sim.positions();
  sim.setMethod(Method::Full);
  EXPECT_LT((sim.positions() - later).cwiseAbs().maxCoeff(), 1e-12);
}

// A saved state of `coarse` (its offset too) replays in a simulation still on `full`.
TEST(Coarse, RestoredStateReplays)
{
  const GridParams g = swingingSheet(13);
  Simulation live(g, methodParams(Method::Full, 4, 5e-4));
  live.step(100);
  live.setMethod(Method::Coarse);
  live.step(50);
  const SimulationState saved = live.saveState();
  ASSERT_GT(saved.offset.cwiseAbs().maxCoeff(), 1e-6);
  live.step(100);
  const Eigen::VectorXd original = live.positions();
  Simulation copy(g, methodParams(Method::Full, 4, 5e-4));
  copy.restoreState(saved);
  EXPECT_EQ(copy.method(), Method::Coarse);
  copy.step(100);
  EXPECT_EQ((copy.positions() - original).cwiseAbs().maxCoeff(), 0.0);
}

// A cloth dropped on a table: no particle of the grid, interpolated, ends up inside it, and the table
// carries the cloth's weight.
TEST(Coarse, KeepsTheGridOutOfATable)
{
  GridParams g = clothSheet(13);
  g.rotation_deg = 90.0;  // lying flat
  g.fixed = {0};
  SimulationParams s = coarseParams(5, 5e-4);
  s.alpha = 1.0;
  Collider table;
  table.type = ColliderType::Plane;
  table.point = Eigen::Vector3d(0.0, 0.0, -0.05);
  s.colliders = {table};
  Simulation sim(g, s);
  ASSERT_FALSE(sim.step(3000).diverged);
  const Eigen::Matrix3Xd points = sim.points();
  EXPECT_GT(points.row(2).minCoeff(), -0.05 - 1e-3);
  EXPECT_LT(points.row(2).minCoeff(), -0.04) << "the cloth must lie on the table";
  const double weight = sim.grid().particleMass() * (sim.grid().numParticles() - 1) * 9.81;
  EXPECT_NEAR(sim.contact()->report().force[0].z(), -weight, 0.2 * weight);
  int touching = 0;
  for (int c : sim.particleContacts())
    touching += c == 0;
  EXPECT_GT(touching, 100);
}

TEST(Coarse, RefusedWhereItHasNoMeaning)
{
  SimulationParams s = coarseParams(0);
  s.self_collision = true;
  EXPECT_TRUE(contains(refusal([&] { Simulation(clothSheet(13), s); }), "method"));
  GridParams row = clothSheet(13);
  row.rows = 1;
  row.fixed = {0};
  const std::string one_row = refusal([&] { Simulation(row, coarseParams(0)); });
  EXPECT_TRUE(contains(one_row, "2 x 2")) << one_row;
}

// A cloth hanging at rest from two corner grips: each carries half its weight under `coarse` as under
// `full` (the grid's springs at the interpolated positions would report a third of it).
TEST(Coarse, GripsCarryTheClothsWeight)
{
  const GridParams g = heldCloth({{0}, {9}}, 10);
  SimulationParams s = coarseParams(4, 5e-4);
  s.alpha = 5.0;
  Simulation coarse(g, s);
  s.method = Method::Full;
  Simulation full(g, s);
  ASSERT_FALSE(coarse.step(6000).diverged);
  ASSERT_FALSE(full.step(6000).diverged);
  const double weight = g.mass * g.rows * g.cols * 9.81;
  const std::vector<Eigen::Vector3d> by_coarse = coarse.handleForces(), by_full = full.handleForces();
  ASSERT_EQ(by_coarse.size(), 2u);
  EXPECT_NEAR((by_coarse[0] + by_coarse[1]).z(), -weight, 0.02 * weight);
  for (int h = 0; h < 2; ++h)
    EXPECT_NEAR(by_coarse[h].z(), by_full[h].z(), 0.05 * weight) << h;
  // A force on a grip's own particle is the grip's.
  Eigen::VectorXd force = Eigen::VectorXd::Zero(3 * g.rows * g.cols);
  force[3 * 9 + 2] = -1.0;
  coarse.setExternalForce(force);
  EXPECT_NEAR(coarse.handleForces()[1].z() - by_coarse[1].z(), -1.0, 1e-12);
}

TEST(CoarseGrid, FittedRestLengthsBalanceItAtTheFineGridsShape)
{
  const GridParams g = heldCloth({{0, 1, 2}, {7, 8, 9}}, 10);
  SimulationParams s = methodParams(Method::Full, 4, 1e-3);
  s.initial_state = InitialState::Equilibrium;
  const Simulation full(g, s);
  const Eigen::VectorXd x_fine = full.positions();
  const Grid& fine = full.grid();
  CoarseGrid coarse(fine, 4);
  // The coarse particles at the fine equilibrium sampled, the held ones where the method holds them.
  Eigen::VectorXd x = coarse.grid.initialPositions();
  const Eigen::VectorXd sampled = coarse.sampling * x_fine;
  for (int dof : coarse.grid.freeDofs())
    x[dof] = sampled[dof];
  auto unbalanced = [&] {
    Eigen::VectorXd f;
    springForces(coarse.grid, x, f);
    f += coarse.grid.gravityForce();
    return coarse.grid.gatherFree(f).cwiseAbs().maxCoeff();
  };
  const double weight = g.mass * 9.81 * fine.numParticles() / coarse.grid.numParticles();
  // Its own sag differs from the fine grid's: at the fine shape a coarse particle is pulled by a good
  // part of its weight.
  const double before = unbalanced();
  EXPECT_GT(before, 0.05 * weight);
  ASSERT_TRUE(coarse.fitRestLengths(x_fine));
  EXPECT_LT(unbalanced(), 1e-6 * weight) << "before the fit: " << before;
}

TEST(Coarse, HangsStillInTheFineGridsShape)
{
  const GridParams g = heldCloth({{0, 1, 2}, {7, 8, 9}}, 10);
  SimulationParams s = coarseParams(4);
  s.initial_state = InitialState::Equilibrium;
  Simulation coarse(g, s);
  const Eigen::VectorXd start = coarse.positions();
  ASSERT_FALSE(coarse.step(500).diverged);
  // Fitted to the fine equilibrium, the coarse grid stays where it started: without the fit it sank
  // to its own sag, centimetres lower (docs/results.md).
  EXPECT_LT(rmsDistance(coarse.positions(), start, 3), 1e-6);
}

TEST(Coarse, StartsWhereItIsPutWithTheDetailItsGridMisses)
{
  // A start keeps what the interpolation misses frozen, as a switch does: the hanging cloth starts
  // where `full` starts, and a state set from outside is where it was set.
  const GridParams g = heldCloth({{0, 1, 2}, {7, 8, 9}}, 10);
  SimulationParams s = coarseParams(4);
  s.initial_state = InitialState::Equilibrium;
  Simulation coarse(g, s);
  s.method = Method::Full;
  const Simulation full(g, s);
  EXPECT_LT((coarse.positions() - full.positions()).cwiseAbs().maxCoeff(), 1e-12);

  Eigen::VectorXd u = Eigen::VectorXd::Zero(coarse.grid().numFreeDofs());
  for (Eigen::Index k = 0; k < u.size(); ++k)
    u[k] = 0.01 * std::sin(1.7 * static_cast<double>(k));
  coarse.setPhysicalState(u, Eigen::VectorXd::Zero(u.size()));
  const Eigen::VectorXd expected = coarse.grid().gatherFree(coarse.linearizationPositions()) + u;
  EXPECT_LT((coarse.grid().gatherFree(coarse.positions()) - expected).cwiseAbs().maxCoeff(), 1e-12);
}
