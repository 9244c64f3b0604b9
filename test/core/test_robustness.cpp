// Bad and extreme inputs, divergence detection and what is kept after it, and the parts of the
// force models and integrators that only matter when something goes wrong.
#include "modal_mass_spring/equilibrium.h"
#include "modal_mass_spring/force_model.h"
#include "modal_mass_spring/simulation.h"
#include "modal_mass_spring/spring_forces.h"

#include "test_support.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cctype>
#include <functional>
#include <string>
#include <type_traits>

using namespace modal_mass_spring;

// The force models and integrators refer to the Simulation's members: it must stay where it was built.
static_assert(!std::is_copy_constructible_v<Simulation> && !std::is_copy_assignable_v<Simulation>);
static_assert(!std::is_move_constructible_v<Simulation> && !std::is_move_assignable_v<Simulation>);

namespace
{

GridParams paper2D() { return GridParams{}; }

SimulationParams params(Method method, double dt, IntegratorKind integrator = IntegratorKind::Explicit)
{
  SimulationParams s;
  s.method = method;
  s.time_step = dt;
  s.integrator = integrator;
  return s;
}

double largestParticleDistance(const Simulation& sim, const Eigen::VectorXd& positions)
{
  return (sim.grid().toPoints(sim.positions()) - sim.grid().toPoints(positions)).colwise().norm().maxCoeff();
}

}  // namespace

TEST(Validation, GridSizesAreCountedIn64Bits)
{
  for (const auto& [rows, cols] : {std::pair{65538, 65536}, std::pair{46341, 46341}, std::pair{2, 536870912}})
  {
    GridParams g;
    g.rows = rows;
    g.cols = cols;
    const std::string message = refusal([&] { validateParameters(g, SimulationParams{}); });
    EXPECT_TRUE(contains(message, "'rows x cols' = " + std::to_string(rows) + " x " + std::to_string(cols)))
        << message;
    EXPECT_TRUE(contains(message, std::to_string(static_cast<long long>(rows) * cols) + " particles")) << message;
    const auto negative = std::adjacent_find(message.begin(), message.end(),
                                             [](char a, char b) { return a == '-' && std::isdigit(b); });
    EXPECT_EQ(negative, message.end()) << "a negative count: " << message;
  }
}

TEST(Validation, ProblemTooLargeForTheMemoryLimitIsRefusedBeforeBuilding)
{
  GridParams g;
  g.rows = g.cols = 2000;
  SimulationParams s;
  s.num_modes = 30;
  const std::string message = refusal([&] { Simulation sim(g, s); });
  EXPECT_TRUE(contains(message, "'rows, cols, num_modes' = 2000 x 2000 grid (2D), num_modes = 30")) << message;
  EXPECT_TRUE(contains(message, "memory_limit_gb = 12")) << message;
  // The same problem passes with a limit above its estimate, and a small one below the default.
  s.memory_limit_gb = 2.0 * estimateMemoryBytes(g, s) / 1e9;
  EXPECT_EQ(refusal([&] { validateParameters(g, s); }), "");
  g.rows = g.cols = 100;
  s = SimulationParams{};
  EXPECT_EQ(refusal([&] { validateParameters(g, s); }), "");
  EXPECT_LT(estimateMemoryBytes(g, s), 1e9);
  s.memory_limit_gb = 0.0;
  EXPECT_TRUE(contains(refusal([&] { validateParameters(g, s); }), "'memory_limit_gb' = 0")) ;
}

TEST(Validation, ExtremeFiniteValuesAreRefusedNamingTheirParameters)
{
  struct Case
  {
    std::function<void(GridParams&)> change;
    std::string named;
  };
  const std::vector<Case> cases{
      {[](GridParams& g) { g.mass = 1e300; }, "'structural_stiffness / mass'"},
      {[](GridParams& g) { g.structural_stiffness = 1e-300; }, "'structural_stiffness / mass'"},
      {[](GridParams& g) { g.shear_stiffness = 1e300; }, "'shear_stiffness"},
      {[](GridParams& g) { g.spacing = 1e-300; }, "'spacing'"},
      {[](GridParams& g) { g.spacing = 1e200; }, "'spacing'"},
      {[](GridParams& g) {
         g.bending = true;
         g.bending_stiffness = 1e-250;
       },
       "'bending_stiffness"},
  };
  for (const Case& c : cases)
  {
    GridParams g;
    c.change(g);
    const std::string message = refusal([&] { Simulation sim(g, SimulationParams{}); });
    EXPECT_TRUE(contains(message, c.named)) << "expected " << c.named << " in: " << message;
  }
}

TEST(Validation, SimulationParametersAreRefusedByName)
{
  auto refused = [](const std::function<void(SimulationParams&)>& change) {
    SimulationParams s;
    change(s);
    return refusal([&] { validateParameters(GridParams{}, s); });
  };
  EXPECT_TRUE(contains(refused([](SimulationParams& s) { s.num_modes = 41; }), "'num_modes' = 41: must be in [1, 40]"));
  EXPECT_TRUE(contains(refused([](SimulationParams& s) { s.hht_alpha = -0.5; }), "'hht_alpha' = -0.5"));
  EXPECT_TRUE(contains(refused([](SimulationParams& s) { s.hht_alpha = 0.1; }), "'hht_alpha' = 0.1"));
  EXPECT_TRUE(contains(refused([](SimulationParams& s) { s.energy_tolerance = 0.0; }), "'energy_tolerance' = 0"));
  EXPECT_TRUE(contains(refused([](SimulationParams& s) { s.newton_max_iterations = 0; }), "'newton_max_iterations' = 0"));
  EXPECT_TRUE(contains(refused([](SimulationParams& s) { s.time_step = -1.0; }), "'time_step' = -1"));
}

TEST(Divergence, ImplicitFullGainingEnergyIsCaughtWhereItStartsAndHhtAlphaPreventsIt)
{
  // The paper's 2D grid at a 0.1 s step: Newmark average acceleration (hht_alpha 0) lets the
  // nonlinear springs gain energy without bound (measured: -0.49 J to over 300 J in 10000 steps).
  SimulationParams s = params(Method::Full, 0.1, IntegratorKind::Implicit);
  s.hht_alpha = 0.0;
  Simulation average(paper2D(), s);
  const StepResult result = average.step(10000);
  ASSERT_TRUE(result.diverged);
  EXPECT_TRUE(contains(result.message, "energy")) << result.message;
  // What is kept is a state a user would call good: its energy within the tolerance of the start,
  // its particles within the grid's size of where they started.
  EXPECT_LE(average.methodEnergy(), average.startEnergy() + s.energy_tolerance * average.energyScale());
  EXPECT_LT(largestParticleDistance(average, average.startPositions()), 0.5);

  // With the default HHT alpha the same run stays bounded and its energy never rises.
  s.hht_alpha = SimulationParams{}.hht_alpha;
  Simulation hht(paper2D(), s);
  const double start = hht.methodEnergy();
  double highest = start;
  for (int k = 0; k < 10000; ++k)
  {
    ASSERT_FALSE(hht.step().diverged) << "step " << k;
    highest = std::max(highest, hht.methodEnergy());
  }
  EXPECT_LE(highest, start + 1e-3 * hht.energyScale());
}

TEST(Divergence, ExplicitBlowUpKeepsAGoodStateAndASwitchGoesOnFromIt)
{
  // Explicit full is unstable at 0.04 s on the paper's grid (its bound is about 0.036 s).
  Simulation sim(paper2D(), params(Method::Full, 0.04));
  const StepResult result = sim.step(5000);
  ASSERT_TRUE(result.diverged);
  EXPECT_LE(sim.methodEnergy(), sim.startEnergy() + 0.01 * sim.energyScale());
  EXPECT_LT(largestParticleDistance(sim, sim.startPositions()), 0.5);  // the grid is 0.4 m tall
  const double energy = sim.totalEnergy();

  // physical is stable at this step: it goes on from the kept state, not from a blown-up one.
  sim.setMethod(Method::Physical);
  EXPECT_NEAR(sim.totalEnergy(), energy, 0.05 * sim.energyScale());
  const StepResult after = sim.step(2000);
  EXPECT_FALSE(after.diverged) << after.message;
  EXPECT_LE(sim.methodEnergy(), sim.startEnergy() + 0.01 * sim.energyScale());
}

TEST(Divergence, IsMeasuredFromTheStartNotFromTheLinearizationPoint)
{
  // Weak springs sag far: the equilibrium lies further from the unloaded grid than the limit, yet a
  // grid that starts unloaded has not diverged by being there.
  GridParams g = paper2D();
  g.structural_stiffness = 0.5;
  g.shear_stiffness = 0.25;
  SimulationParams s = params(Method::Full, 1e-3);
  s.linearization = Linearization::Equilibrium;
  Simulation sim(g, s);
  const double sag = (sim.startPositions() - sim.linearizationPositions()).cwiseAbs().maxCoeff();
  ASSERT_GT(sag, 0.1);
  s.divergence_limit = 0.1 * sag;
  Simulation limited(g, s);
  const StepResult first = limited.step(10);
  EXPECT_FALSE(first.diverged) << first.message;
  // The limit still trips once the grid has moved that far from its start.
  const StepResult later = limited.step(100000);
  ASSERT_TRUE(later.diverged);
  EXPECT_TRUE(contains(later.message, "divergence_limit")) << later.message;
}

TEST(Divergence, IsMeasuredFromTheStartAsTheModesHoldIt)
{
  // Very weak springs hang hundreds of metres below the unloaded grid: projected onto four modes
  // about that equilibrium, the unloaded start lands far from itself (the projection error). A modal
  // method that starts there has not diverged by being there.
  GridParams g = paper2D();
  g.structural_stiffness = 1e-4;
  g.shear_stiffness = 1e-4;
  for (Method method : {Method::Linear, Method::Physical})
  {
    SimulationParams s = params(method, 1e-3);
    s.linearization = Linearization::Equilibrium;
    Simulation sim(g, s);
    ASSERT_GT(sim.projectionError(), 100.0) << toString(method);  // beyond the default limit (50 m)
    const StepResult first = sim.step(10);
    EXPECT_FALSE(first.diverged) << toString(method) << ": " << first.message;
  }
}

TEST(Implicit, NewtonFailureSplitsTheStepAndRefusesItWhenSplittingDoesNotHelp)
{
  // At 0.1 s on the paper's grid, 3 Newton iterations are not enough for a whole step but are for
  // its halves; 1 is not enough even in 1/16 of it.
  SimulationParams s = params(Method::Full, 0.1, IntegratorKind::Implicit);
  s.newton_max_iterations = 3;
  Simulation split(paper2D(), s);
  int most_substeps = 0;
  for (int k = 0; k < 300; ++k)
  {
    ASSERT_FALSE(split.step().diverged) << "step " << k;
    most_substeps = std::max(most_substeps, split.lastImplicitSubsteps());
  }
  EXPECT_GT(most_substeps, 1);

  s.newton_max_iterations = 1;
  Simulation refused(paper2D(), s);
  const Eigen::VectorXd start = refused.positions();
  const StepResult result = refused.step();
  ASSERT_TRUE(result.diverged);
  EXPECT_TRUE(contains(result.message, "newton_max_iterations = 1, even in 1/16 of the step")) << result.message;
  EXPECT_EQ(refused.stepCount(), 0);
  EXPECT_EQ(refused.positions(), start);
}

TEST(Implicit, LargeStepsConvergeWhereTheGridRestsAtTheLinearizationPoint)
{
  // At the equilibrium basis's own linearization point the forces balance to the round-off of the
  // spring forces, and q = 0: a convergence test relative to the forces or to q has nothing to
  // measure against. The grid starts there at rest; at a step far past the explicit bound every
  // method must go on standing still, not be refused.
  for (Method method : {Method::Full, Method::Linear, Method::Physical})
    for (const double dt : {1e-3, 0.5})
    {
      SimulationParams s = params(method, dt, IntegratorKind::Implicit);
      s.linearization = Linearization::Equilibrium;
      s.initial_state = InitialState::Equilibrium;
      Simulation sim(paper2D(), s);
      const StepResult result = sim.step(200);
      EXPECT_FALSE(result.diverged) << toString(method) << " at " << dt << " s: " << result.message;
      EXPECT_LT(largestParticleDistance(sim, sim.startPositions()), 1e-9) << toString(method) << " at " << dt;
    }
}

TEST(Simulation, SetTimeStepKeepsTheStateAndTheNewStepIsUsed)
{
  Simulation sim(paper2D(), params(Method::Physical, 1e-3));
  sim.step(300);
  const Eigen::VectorXd x = sim.positions(), v = sim.velocity();
  sim.setTimeStep(2e-3);
  EXPECT_EQ(sim.positions(), x);
  EXPECT_EQ(sim.velocity(), v);
  EXPECT_EQ(sim.params().time_step, 2e-3);
  // Two steps of 2 ms land close to four of 1 ms, far from where two of 1 ms would.
  Simulation reference(paper2D(), params(Method::Physical, 1e-3));
  reference.step(304);
  sim.step(2);
  EXPECT_LT((sim.positions() - reference.positions()).cwiseAbs().maxCoeff(), 1e-4);
  EXPECT_TRUE(contains(refusal([&] { sim.setTimeStep(0.0); }), "'time_step' = 0"));
  EXPECT_EQ(sim.params().time_step, 2e-3);
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

// Central differences of energy and force for the modal force models, at a large deformation.
TEST(ForceModels, ModalForceIsMinusEnergyGradientAndTangentIsMinusForceJacobian)
{
  GridParams g = paper3D();
  g.bending = true;
  SimulationParams s;
  s.num_modes = 12;
  s.linearization = Linearization::Equilibrium;
  Simulation sim(g, s);
  const Eigen::VectorXd& x_ref = sim.linearizationPositions();
  LinearModalForceModel linear(sim.grid(), sim.basis(), x_ref);
  PhysicalModalForceModel physical(sim.grid(), sim.basis(), x_ref);
  std::srand(3);
  // Modal amplitudes that move particles by several centimetres on a 0.9 m sheet.
  const Eigen::VectorXd q = 0.02 * Eigen::VectorXd::Random(s.num_modes);
  for (ForceModel* model : std::vector<ForceModel*>{&linear, &physical})
  {
    Eigen::VectorXd f, f_plus, f_minus;
    model->force(q, f);
    SparseMatrix k;
    model->tangentStiffness(q, k);
    const Eigen::MatrixXd tangent(k);
    const double h = 1e-6;
    for (int i = 0; i < s.num_modes; ++i)
    {
      Eigen::VectorXd plus = q, minus = q;
      plus[i] += h;
      minus[i] -= h;
      const double gradient = (model->energy(plus) - model->energy(minus)) / (2.0 * h);
      EXPECT_NEAR(-gradient, f[i], 1e-6 * (f.norm() + 1.0)) << "coordinate " << i;
      model->force(plus, f_plus);
      model->force(minus, f_minus);
      const Eigen::VectorXd column = -(f_plus - f_minus) / (2.0 * h);
      EXPECT_LT((column - tangent.col(i)).norm(), 1e-5 * (tangent.norm() + 1.0)) << "coordinate " << i;
    }
    // The energy a force evaluation leaves behind is the energy at that q, not the last one asked for.
    model->force(q, f);
    const double cached = model->energy(q);
    model->force(0.5 * q, f);
    EXPECT_EQ(model->energy(q), cached);
  }
}
