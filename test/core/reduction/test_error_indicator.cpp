// The reduced methods' error indicator (Simulation::errorIndicator): zero where nothing of the full
// force lies outside the span, large where the span cannot hold the deformation.
#include "test_support.h"

#include "modal_mass_spring/adaptive.h"
#include "modal_mass_spring/simulation.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <iostream>
#include <vector>

using namespace modal_mass_spring;

TEST(ErrorIndicator, ZeroWhereTheSpanHoldsEveryDisplacement)
{
  // The 5 x 5 sheet swinging down from 45 degrees: with every mode nothing of the full force is
  // outside the span; with four modes much is.
  const int free_dofs = 60;
  SimulationParams s = methodParams(Method::Physical, free_dofs, 5e-3, IntegratorKind::Implicit);
  Simulation every(turnedSheet(), s);
  s.num_modes = 4;
  Simulation few(turnedSheet(), s);
  ASSERT_FALSE(every.step(40).diverged);
  ASSERT_FALSE(few.step(40).diverged);
  EXPECT_LT(every.errorIndicator(), 1e-10);
  EXPECT_GT(few.errorIndicator(), 1e-6);
  s.method = Method::Full;
  EXPECT_EQ(Simulation(turnedSheet(), s).errorIndicator(), 0.0);
}

TEST(ErrorIndicator, ZeroAtTheHangingEquilibrium)
{
  // Forces balance there: whatever the span, nothing is left for it to miss.
  SimulationParams s = methodParams(Method::Cubature, 6, 5e-3, IntegratorKind::Implicit);
  s.linearization = Linearization::Equilibrium;
  s.initial_state = InitialState::Equilibrium;
  Simulation sim(clothSheet(10), s);
  EXPECT_LT(sim.errorIndicator(), 1e-9);
}

TEST(ErrorIndicator, SeesTheTurnSixModesCannotHoldAndTheSkinningSpanCan)
{
  // A 10 x 10 cloth held by its top row, turned 60 degrees about the vertical through the row's
  // middle and held: the springs of six linear modes are strained by the turn, which they cannot
  // follow; the skinning span turns the cloth rigidly and leaves no force outside itself.
  std::vector<int> top;
  for (int col = 0; col < 10; ++col)
    top.push_back(col);
  const GridParams g = heldCloth({top}, 10);
  SimulationParams s = methodParams(Method::Physical, 6, 5e-3, IntegratorKind::Implicit);
  s.alpha = 0.5;
  s.linearization = Linearization::Equilibrium;
  s.initial_state = InitialState::Equilibrium;
  Simulation modes(g, s);
  s.basis = BasisKind::Skinning;
  s.num_skinning_weights = 8;
  Simulation skinning(g, s);
  EXPECT_LT(modes.errorIndicator(), 1e-9);  // at rest in the equilibrium
  const Eigen::VectorXd start = modes.handlePositions();
  Eigen::Vector3d middle = Eigen::Vector3d::Zero();
  for (Eigen::Index k = 0; k < start.size(); k += 3)
    middle += start.segment<3>(k) / 10.0;
  for (int k = 1; k <= 100; ++k)
  {
    const double angle = 0.5 * (1.0 - std::cos(M_PI * k / 100.0)) * M_PI / 3.0;
    const Eigen::Matrix3d turn = Eigen::AngleAxisd(angle, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    Eigen::VectorXd target = start;
    for (Eigen::Index i = 0; i < start.size(); i += 3)
      target.segment<3>(i) = middle + turn * (start.segment<3>(i) - middle);
    for (Simulation* sim : {&modes, &skinning})
    {
      sim->setHandleMotion(target);
      ASSERT_FALSE(sim->step().diverged) << "step " << k;
    }
  }
  for (Simulation* sim : {&modes, &skinning})
    ASSERT_FALSE(sim->step(200).diverged);  // held 1 s: the swing damped out
  std::cout << "indicator, six modes: " << modes.errorIndicator() << " m, skinning: " << skinning.errorIndicator()
            << " m\n";
  EXPECT_GT(modes.errorIndicator(), 1e-3);
  EXPECT_LT(skinning.errorIndicator(), 1e-3 * modes.errorIndicator());
}

TEST(ErrorIndicator, ItsMaximumIsTheLargestSinceTheStateWasLastSetWhole)
{
  // Four modes on the sheet swinging down: the force outside the span comes and goes with the swing,
  // the maximum keeps its largest until a reset, a switch or a restored state sets the state anew.
  SimulationParams s = methodParams(Method::Physical, 4, 5e-3, IntegratorKind::Implicit);
  Simulation sim(turnedSheet(), s);
  IndicatorMaximum maximum;
  double largest = 0.0;
  bool fell = false;
  for (int k = 0; k < 60; ++k)
  {
    ASSERT_FALSE(sim.step(5).diverged);
    const double now = sim.errorIndicator();
    fell = fell || now < largest;
    largest = std::max(largest, now);
    EXPECT_EQ(maximum(sim, now), largest) << "after " << 5 * (k + 1) << " steps";
  }
  ASSERT_TRUE(fell) << "the force outside the span never fell: the test would not tell a maximum from the value";
  // Another reader keeps its own: reading more often changes nothing for the first.
  IndicatorMaximum other;
  EXPECT_EQ(other(sim, sim.errorIndicator()), sim.errorIndicator());
  EXPECT_EQ(maximum(sim, 0.0), largest);
  // A value that is not finite is not hidden behind the maximum.
  EXPECT_TRUE(std::isnan(maximum(sim, std::nan(""))));
  EXPECT_EQ(maximum(sim, 0.0), largest);

  const SimulationState saved = sim.saveState();
  for (auto set : std::vector<std::function<void()>>{[&] { sim.reset(); }, [&] { sim.restoreState(saved); },
                                                     [&] { sim.setMethod(Method::Full); }})
  {
    const long sets = sim.stateSets();
    set();
    EXPECT_GT(sim.stateSets(), sets);
    EXPECT_EQ(maximum(sim, 0.25 * largest), 0.25 * largest);
    EXPECT_EQ(maximum(sim, 0.0), 0.25 * largest);
  }
  // Stepping does not set the state.
  const long sets = sim.stateSets();
  ASSERT_FALSE(sim.step(5).diverged);
  EXPECT_EQ(sim.stateSets(), sets);
}

TEST(ErrorIndicator, TheSwingIsTheSpeedLessARigidMotionTimesTheTimeTheDampingRemembers)
{
  // The sheet's 20 free particles (4 rows of 5 below the fixed one) given a rigid motion, a
  // translation and a turn about an axis through a point off the sheet: no swing. Then, on top, the
  // rows moving +w, -w, -w, +w along z: a motion with no mean and no angular momentum about the
  // centre of mass (the rows' positions are linear in their index), so all of it swings at w.
  SimulationParams s = methodParams(Method::Full, 6, 5e-3, IntegratorKind::Implicit);
  s.alpha = 0.0;
  Simulation sim(turnedSheet(), s);
  const Eigen::Index free_dofs = sim.displacement().size();
  ASSERT_EQ(free_dofs, 60);
  const Eigen::VectorXd x = sim.grid().gatherFree(sim.positions());
  const Eigen::Vector3d velocity(0.5, -0.2, 0.1), omega(0.3, -1.1, 0.7), pivot(0.2, 1.0, -0.4);
  const double w = 0.3;
  const double rows[4] = {1.0, -1.0, -1.0, 1.0};
  Eigen::VectorXd rigid(free_dofs), swinging(free_dofs);
  Eigen::Vector3d moment = Eigen::Vector3d::Zero();
  for (Eigen::Index p = 0; p < free_dofs / 3; ++p)
  {
    const Eigen::Vector3d at = x.segment<3>(3 * p);
    rigid.segment<3>(3 * p) = velocity + omega.cross(at - pivot);
    swinging.segment<3>(3 * p) = rigid.segment<3>(3 * p) + Eigen::Vector3d(0.0, 0.0, rows[p / 5] * w);
    moment += rows[p / 5] * at;
  }
  ASSERT_LT(moment.norm(), 1e-12) << "the rows' pattern has a moment: the particles are not in the order assumed";
  sim.setPhysicalState(sim.displacement(), rigid);
  EXPECT_NEAR(sim.deformationSpeed(), 0.0, 1e-12);
  sim.setPhysicalState(sim.displacement(), swinging);
  EXPECT_NEAR(sim.deformationSpeed(), w, 1e-12);
  EXPECT_EQ(sim.timeSinceStateSet(), 0.0);
  EXPECT_EQ(swingDistance(sim), 0.0);

  // A grid of more than 32 x 32 (40 rows of 50) is read over a lattice of 32 x 32 of its particles
  // (rows round(k 39 / 31), columns round(k 49 / 31)): a rigid motion still does not swing, nor
  // does one with a particle off the lattice (row 22, column 23) moved, while one on it (row 19,
  // column 24) does.
  GridParams large = turnedSheet();
  large.rows = 40;
  large.cols = 50;
  Simulation wide(large, methodParams(Method::Full, 6, 5e-3, IntegratorKind::Implicit));
  const Eigen::VectorXd wide_x = wide.grid().gatherFree(wide.positions());
  Eigen::VectorXd wide_v(wide_x.size());
  for (Eigen::Index p = 0; p < wide_x.size() / 3; ++p)
    wide_v.segment<3>(3 * p) = velocity + omega.cross(wide_x.segment<3>(3 * p) - pivot);
  auto withMoved = [&](int row, int col) {
    Eigen::VectorXd moved = wide_v;
    moved[wide.grid().freeIndex(3 * (row * large.cols + col) + 2)] += 1.0;
    wide.setPhysicalState(wide.displacement(), moved);
    return wide.deformationSpeed();
  };
  wide.setPhysicalState(wide.displacement(), wide_v);
  EXPECT_NEAR(wide.deformationSpeed(), 0.0, 1e-12);
  EXPECT_NEAR(withMoved(22, 23), 0.0, 1e-12);
  EXPECT_GT(withMoved(19, 24), 0.01);

  // In 2D the rigid motion turns in the plane.
  SimulationParams flat = methodParams(Method::Full, 6, 5e-3, IntegratorKind::Implicit);
  Simulation plane(GridParams{}, flat);
  ASSERT_EQ(plane.grid().dimension(), 2);
  const Eigen::VectorXd plane_x = plane.grid().gatherFree(plane.positions());
  Eigen::VectorXd plane_v(plane_x.size());
  for (Eigen::Index p = 0; p < plane_x.size() / 2; ++p)
    plane_v.segment<2>(2 * p) = Eigen::Vector2d(0.4, -0.3) + 0.8 * Eigen::Vector2d(-plane_x[2 * p + 1], plane_x[2 * p]);
  plane.setPhysicalState(plane.displacement(), plane_v);
  EXPECT_NEAR(plane.deformationSpeed(), 0.0, 1e-12);
  plane_v[0] += 1.0;
  plane.setPhysicalState(plane.displacement(), plane_v);
  EXPECT_GT(plane.deformationSpeed(), 0.01);

  // Without damping the time counts whole; with alpha it counts up to 2 / alpha.
  ASSERT_FALSE(sim.step(40).diverged);
  EXPECT_NEAR(sim.timeSinceStateSet(), 0.2, 1e-12);
  EXPECT_GT(sim.deformationSpeed(), 0.0);
  EXPECT_NEAR(swingDistance(sim), 0.2 * sim.deformationSpeed(), 1e-12);
  s.alpha = 2.0;
  Simulation damped(turnedSheet(), s);
  ASSERT_FALSE(damped.step(400).diverged);
  EXPECT_NEAR(swingDistance(damped), (1.0 - std::exp(-2.0)) * damped.deformationSpeed(), 1e-12);
  // A damping too light for 1 - exp(-alpha t / 2) to be told from 0 in doubles still counts the time.
  s.alpha = 1e-17;
  Simulation light(turnedSheet(), s);
  ASSERT_FALSE(light.step(40).diverged);
  EXPECT_NEAR(swingDistance(light), 0.2 * light.deformationSpeed(), 1e-12);

  // Every set of the state starts the time again; a step does not.
  const SimulationState saved = sim.saveState();
  for (auto set : std::vector<std::function<void()>>{[&] { sim.reset(); }, [&] { sim.restoreState(saved); },
                                                     [&] { sim.setMethod(Method::Physical); }})
  {
    ASSERT_FALSE(sim.step(3).diverged);
    set();
    EXPECT_EQ(sim.timeSinceStateSet(), 0.0);
  }

  // The estimate: the indicator's largest times its scale, plus the drift times the swing.
  ASSERT_FALSE(damped.step(10).diverged);
  EXPECT_EQ(errorEstimate(damped, 2e-4, 50.0, 0.0), 50.0 * 2e-4);
  EXPECT_NEAR(errorEstimate(damped, 2e-4, 50.0, 0.01), 50.0 * 2e-4 + 0.01 * swingDistance(damped), 1e-15);
  EXPECT_GT(swingDrift(Method::Coarse), 0.0);
  EXPECT_EQ(swingDrift(Method::Physical), 0.0);
  EXPECT_EQ(swingDrift(Method::Cubature), 0.0);
}
