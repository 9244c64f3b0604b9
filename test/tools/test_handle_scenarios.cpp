// Handle scenarios: the ramp and the rigid motion against their derivatives and closed forms, the
// YAML refused by name, and every interior mode under `physical` against `full` moved the same way.
#include "experiments.h"
#include "handle_scenarios.h"

#include <gtest/gtest.h>

#include <cmath>
#include <algorithm>
#include <functional>
#include <map>
#include <sstream>
#include <stdexcept>
#include <string>

using namespace modal_mass_spring;

namespace
{

std::string invalidArgument(const std::function<void()>& f)
{
  try
  {
    f();
  }
  catch (const std::invalid_argument& e)
  {
    return e.what();
  }
  return "(no std::invalid_argument)";
}

std::vector<HandleScenario> parse(const std::string& yaml)
{
  return parseHandleScenarios(YAML::Load(yaml), "handle_scenarios");
}

// A 4 x 4 sheet in 3D held by its top row, hanging at rest: small enough to keep every interior mode.
ExperimentSetup heldSheet(const HandleScenario& scenario)
{
  ExperimentSetup setup;
  setup.grid.rows = 4;
  setup.grid.cols = 4;
  setup.grid.dimension = 3;
  setup.grid.spacing = 0.1;
  setup.grid.mass = 0.005;
  setup.grid.structural_stiffness = 50.0;
  setup.grid.shear_stiffness = 20.0;
  setup.grid.bending = true;
  setup.grid.bending_stiffness = 5.0;
  setup.sim.linearization = Linearization::Equilibrium;
  setup.sim.initial_state = InitialState::Equilibrium;
  setup.sim.integrator = IntegratorKind::Explicit;
  setup.sim.time_step = 5e-4;
  setup.sim.alpha = 0.5;
  setup.grid = gridWithHandles(setup.grid, scenario);
  setup.sim.num_modes = 3 * 12;  // every interior dof
  setup.handle_scenario = scenario;
  setup.variant = scenario.name;
  return setup;
}

// The largest distance to the reference of `physical` and of `linear`, and the largest displacement
// of the reference, over a run's samples; fails on a divergence.
struct Worst
{
  double physical = 0.0, linear = 0.0, moved = 0.0;
};

Worst worstOf(const AccuracyResult& result)
{
  Worst w;
  for (const ErrorSample& e : result.errors)
  {
    EXPECT_FALSE(e.diverged) << e.method << " at step " << e.step;
    if (e.method == "physical")
      w.physical = std::max(w.physical, e.max_distance);
    else if (e.method == "linear")
      w.linear = std::max(w.linear, e.max_distance);
    else
      w.moved = std::max(w.moved, e.max_displacement);
  }
  return w;
}

}  // namespace

TEST(HandleScenarios, RampStartsAndEndsAtRestAndItsRatesAreItsDerivatives)
{
  const double move = 0.8, h = 1e-5;
  EXPECT_EQ(moveRamp(0.0, move).s, 0.0);
  EXPECT_EQ(moveRamp(-1.0, move).s, 0.0);
  EXPECT_NEAR(moveRamp(move, move).s, 1.0, 1e-15);
  EXPECT_NEAR(moveRamp(5.0, move).s, 1.0, 1e-15);
  for (double t : {0.0, move})
  {
    EXPECT_NEAR(moveRamp(t, move).ds, 0.0, 1e-15);
    EXPECT_NEAR(moveRamp(t, move).dds, 0.0, 1e-12);
  }
  EXPECT_NEAR(moveRamp(0.5 * move, move).s, 0.5, 1e-15);  // symmetric
  for (double t : {0.05, 0.2, 0.4, 0.61, 0.79})
  {
    const Ramp r = moveRamp(t, move);
    EXPECT_NEAR(r.ds, (moveRamp(t + h, move).s - moveRamp(t - h, move).s) / (2 * h), 1e-7) << t;
    EXPECT_NEAR(r.dds, (moveRamp(t + h, move).ds - moveRamp(t - h, move).ds) / (2 * h), 1e-5) << t;
  }
}

TEST(HandleScenarios, ParticlesOnAMovingFrameHaveTheDerivativesOfTheirPathAndEndWhereTheFrameWent)
{
  HandlePath path;
  path.translation = Eigen::Vector3d(0.3, -0.1, 0.2);
  path.rotation_axis = Eigen::Vector3d(1.0, 1.0, 0.5).normalized();
  path.rotation_deg = 120.0;
  const Eigen::Vector3d start(0.1, 0.2, -0.3);
  Eigen::Matrix3Xd offsets(3, 3);
  offsets << 0.1, -0.2, 0.0,  //
      0.0, 0.05, 0.3,         //
      -0.1, 0.0, 0.2;
  const double move = 1.0, h = 1e-5;
  auto at = [&](double t) { return pointsOnFrame(frameMotion(path, start, move, t), offsets); };
  for (double t : {0.1, 0.37, 0.5, 0.83})
  {
    const RigidPointMotion m = at(t);
    const Eigen::Matrix3Xd velocity = (at(t + h).position - at(t - h).position) / (2 * h);
    const Eigen::Matrix3Xd acceleration = (at(t + h).velocity - at(t - h).velocity) / (2 * h);
    EXPECT_LT((m.velocity - velocity).cwiseAbs().maxCoeff(), 1e-7) << t;
    EXPECT_LT((m.acceleration - acceleration).cwiseAbs().maxCoeff(), 1e-6) << t;
    // A rigid motion keeps the distances between the particles.
    EXPECT_NEAR((m.position.col(0) - m.position.col(2)).norm(), (offsets.col(0) - offsets.col(2)).norm(), 1e-14);
  }

  // A quarter turn about z ends with (x, y) -> (-y, x) about the moved origin, and then holds still.
  HandlePath turn;
  turn.translation = Eigen::Vector3d(0.5, 0.0, 0.0);
  turn.rotation_deg = 90.0;
  for (double t : {1.0, 2.5})
  {
    const RigidPointMotion m = pointsOnFrame(frameMotion(turn, start, move, t), offsets);
    for (int k = 0; k < 3; ++k)
    {
      const Eigen::Vector3d expected =
          start + turn.translation + Eigen::Vector3d(-offsets(1, k), offsets(0, k), offsets(2, k));
      EXPECT_LT((m.position.col(k) - expected).norm(), 1e-14);
      EXPECT_LT(m.velocity.col(k).norm(), 1e-14);
      EXPECT_LT(m.acceleration.col(k).norm(), 1e-12);
    }
  }
}

TEST(HandleScenarios, ParsesEveryKeyWithItsDefaults)
{
  const auto scenarios = parse(R"(
- name: turn
  move_time: 0.5
  hold_time: 0
  handles:
    - {particles: [0, 1], translation: [0.1, 0, -0.2], rotation_axis: [0, 0, 2], rotation_deg: -45}
- name: still
  handles:
    - particles: [3]
)");
  ASSERT_EQ(scenarios.size(), 2u);
  EXPECT_EQ(scenarios[0].name, "turn");
  EXPECT_EQ(scenarios[0].move_time, 0.5);
  EXPECT_EQ(scenarios[0].hold_time, 0.0);
  ASSERT_EQ(scenarios[0].handles.size(), 1u);
  EXPECT_EQ(scenarios[0].handles[0].particles, (std::vector<int>{0, 1}));
  EXPECT_EQ(scenarios[0].handles[0].translation, Eigen::Vector3d(0.1, 0.0, -0.2));
  EXPECT_EQ(scenarios[0].handles[0].rotation_axis, Eigen::Vector3d::UnitZ());  // normalised
  EXPECT_EQ(scenarios[0].handles[0].rotation_deg, -45.0);
  EXPECT_EQ(scenarios[1].move_time, 1.0);
  EXPECT_EQ(scenarios[1].hold_time, 2.0);
  EXPECT_EQ(scenarios[1].handles[0].translation, Eigen::Vector3d::Zero());
  EXPECT_EQ(scenarios[1].handles[0].rotation_deg, 0.0);
}

TEST(HandleScenarios, BadScenariosAreRefusedNamingTheElement)
{
  struct Case
  {
    std::string yaml, named;
  };
  const std::string h = "handles: [{particles: [0]}]";
  for (const Case& c : {
           Case{"{name: a, " + h + "}", "'handle_scenarios'"},  // not a list
           Case{"[]", "'handle_scenarios'"},
           Case{"[5]", "'handle_scenarios[0]'"},
           Case{"[{" + h + "}]", "'handle_scenarios[0].name'"},
           Case{"[{name: 'a,b', " + h + "}]", "'handle_scenarios[0].name'"},
           Case{"[{name: a, " + h + "}, {name: a, " + h + "}]", "'handle_scenarios[1].name'"},
           Case{"[{name: a, " + h + ", speed: 3}]", "'handle_scenarios[0].speed'"},
           Case{"[{name: a}]", "'handle_scenarios[0].handles'"},
           Case{"[{name: a, handles: []}]", "'handle_scenarios[0].handles'"},
           Case{"[{name: a, handles: [[0, 1]]}]", "'handle_scenarios[0].handles[0]'"},
           Case{"[{name: a, handles: [{translation: [0, 0, 1]}]}]", "'handle_scenarios[0].handles[0]'"},
           Case{"[{name: a, handles: [{particles: []}]}]", "'handle_scenarios[0].handles[0].particles'"},
           Case{"[{name: a, handles: [{particles: [0.5]}]}]", "'handle_scenarios[0].handles[0].particles'"},
           Case{"[{name: a, handles: [{particles: [0], particle: [1]}]}]", "'handle_scenarios[0].handles[0].particle'"},
           Case{"[{name: a, handles: [{particles: [0], translation: [1, 2]}]}]",
                "'handle_scenarios[0].handles[0].translation'"},
           Case{"[{name: a, handles: [{particles: [0], translation: [1, .nan, 2]}]}]",
                "'handle_scenarios[0].handles[0].translation'"},
           Case{"[{name: a, handles: [{particles: [0], rotation_axis: [0, 0, 0]}]}]",
                "'handle_scenarios[0].handles[0].rotation_axis'"},
           Case{"[{name: a, handles: [{particles: [0], rotation_deg: 400}]}]",
                "'handle_scenarios[0].handles[0].rotation_deg'"},
           Case{"[{name: a, handles: [{particles: [0], rotation_deg: quarter}]}]",
                "'handle_scenarios[0].handles[0].rotation_deg'"},
           Case{"[{name: a, move_time: 0, " + h + "}]", "'handle_scenarios[0].move_time'"},
           Case{"[{name: a, hold_time: -1, " + h + "}]", "'handle_scenarios[0].hold_time'"},
       })
  {
    const std::string message = invalidArgument([&] { parse(c.yaml); });
    EXPECT_NE(message.find("invalid parameter " + c.named), std::string::npos) << c.yaml << "\n" << message;
  }
}

TEST(HandleScenarios, TheCoreChecksTheParticleGroupsAgainstTheGrid)
{
  GridParams grid;  // 5 x 5 in 2D, the top row fixed
  grid.fixed = {20, 21, 22, 23, 24};
  auto message = [&](const std::string& yaml) {
    return invalidArgument([&] { gridWithHandles(grid, parse(yaml).front()); });
  };
  std::string m = message("[{name: twice, handles: [{particles: [0, 1]}, {particles: [1]}]}]");
  EXPECT_NE(m.find("handle scenario 'twice'"), std::string::npos) << m;
  EXPECT_NE(m.find("'handles[1]' = 1"), std::string::npos) << m;
  m = message("[{name: outside, handles: [{particles: [25]}]}]");
  EXPECT_NE(m.find("'handles[0]' = 25"), std::string::npos) << m;
  m = message("[{name: fixed, handles: [{particles: [20]}]}]");
  EXPECT_NE(m.find("also be fixed"), std::string::npos) << m;
  m = message("[{name: off_plane, handles: [{particles: [0], translation: [0, 0.1, 0]}]}]");
  EXPECT_NE(m.find("'handles[0].translation'"), std::string::npos) << m;
  m = message("[{name: tilt, handles: [{particles: [0], rotation_axis: [1, 0, 0], rotation_deg: 10}]}]");
  EXPECT_NE(m.find("'handles[0].rotation_axis'"), std::string::npos) << m;
  // In the plane it is taken, with the groups as the grid's handles.
  const GridParams ok =
      gridWithHandles(grid, parse("[{name: ok, handles: [{particles: [0, 1], rotation_axis: [0, 1, 0], "
                                  "rotation_deg: 30}, {particles: [4]}]}]")
                                .front());
  EXPECT_EQ(ok.handles, (std::vector<std::vector<int>>{{0, 1}, {4}}));
}

// With every interior mode, `physical` is `full` in other coordinates: moved by the same handles (a
// turn about the vertical and a translation at once), it must follow full closely, while `linear`
// (forces linearized at the hanging equilibrium) visibly cannot follow a quarter turn.
TEST(HandleScenarios, EveryInteriorModeUnderPhysicalFollowsFullThroughALargeMove)
{
  HandleScenario scenario = parse(R"(
- name: turn_and_shift
  move_time: 0.5
  hold_time: 0.25
  handles:
    - {particles: [0, 1, 2, 3], translation: [0.1, 0.0, 0.05], rotation_axis: [0, 0, 1], rotation_deg: 90}
)")
                                .front();
  const ExperimentSetup setup = heldSheet(scenario);
  AccuracyOptions options;
  options.methods = {Method::Linear, Method::Physical};
  options.sample = 50;
  options.steps = options.interval = 1500;  // move and hold
  options.snapshots = false;
  const AccuracyResult result = runAccuracy(setup, options);
  ASSERT_TRUE(result.messages.empty()) << result.messages.front();
  const auto [physical, linear, moved] = worstOf(result);
  EXPECT_GT(moved, 0.25) << "the handles did not move the sheet far";
  EXPECT_LT(physical, 1e-6) << "physical with every interior mode against full (m)";
  EXPECT_GT(linear, 1e-3) << "linear with every interior mode against full (m)";
}

TEST(HandleScenarios, TheBodyFrameCarriesTheHandleParticlesAlongTheirPath)
{
  const HandleScenario scenario = parse(R"(
- name: turn_and_shift
  move_time: 0.5
  handles:
    - {particles: [0, 1, 2, 3], translation: [0.1, -0.2, 0.05], rotation_axis: [1, 0, 1], rotation_deg: 120}
)")
                                      .front();
  ExperimentSetup setup = heldSheet(scenario);
  setup.sim.handles_one_body = true;
  Simulation sim(setup.grid, setup.sim);
  ASSERT_EQ(sim.handleFormulation(), HandleFormulation::MovingFrame);
  const HandleDriver driver(scenario, sim);
  const Eigen::Matrix3Xd start = sim.grid().toPoints(sim.positions()).leftCols(4);
  for (double t : {0.0, 0.13, 0.25, 0.41, 0.5, 0.7})
  {
    Eigen::VectorXd x, v, a;
    driver.particleMotion(t, x, v, a);
    const RigidPointMotion body = pointMotion(driver.bodyFrameMotion(t), start);
    for (int k = 0; k < 4; ++k)
    {
      EXPECT_LT((body.position.col(k) - x.segment<3>(3 * k)).norm(), 1e-12) << "t = " << t << ", particle " << k;
      EXPECT_LT((body.velocity.col(k) - v.segment<3>(3 * k)).norm(), 1e-12) << "t = " << t << ", particle " << k;
      EXPECT_LT((body.acceleration.col(k) - a.segment<3>(3 * k)).norm(), 1e-10) << "t = " << t << ", particle " << k;
    }
  }
}

TEST(HandleScenarios, InTheMovingFrameEveryInteriorModeUnderPhysicalFollowsFullThroughALargeTurn)
{
  const HandleScenario scenario = parse(R"(
- name: turn_and_shift
  move_time: 0.5
  hold_time: 0.25
  handles:
    - {particles: [0, 1, 2, 3], translation: [0.1, 0.0, 0.05], rotation_axis: [0, 0, 1], rotation_deg: 90}
)")
                                      .front();
  ExperimentSetup setup = heldSheet(scenario);
  setup.sim.handles_one_body = true;  // auto: the moving frame
  AccuracyOptions options;
  options.methods = {Method::Linear, Method::Physical};
  options.sample = 50;
  options.steps = options.interval = 1500;
  options.snapshots = false;
  const AccuracyResult result = runAccuracy(setup, options);
  ASSERT_TRUE(result.messages.empty()) << result.messages.front();
  const auto [physical, linear, moved] = worstOf(result);
  EXPECT_GT(moved, 0.25) << "the frame did not move the sheet far";
  EXPECT_LT(physical, 1e-6) << "physical with every interior mode against full, both in the frame (m)";
  // The frame's forces swing the sheet far from its linearization: the linear force is not enough.
  EXPECT_GT(linear, 1e-3) << "linear with every interior mode against full in the frame (m)";
}

// A shake: out along x while turning, back past the start, and home; each leg a ramp from rest to rest.
TEST(HandleScenarios, AWaypointPathStartsAndEndsAtRestAtEachWaypointAndItsRatesAreItsDerivatives)
{
  const HandleScenario scenario = parse(R"(
- name: shake
  move_time: 0.45
  handles:
    - particles: [0]
      rotation_axis: [0, 0, 1]
      waypoints: [{translation: [0.15, 0, 0], rotation_deg: 30}, {translation: [-0.1, 0.05, 0]}, {}]
)")
                                      .front();
  const HandlePath& path = scenario.handles[0];
  ASSERT_EQ(path.waypoints.size(), 3u);
  const Eigen::Vector3d start(0.1, 0.2, -0.3);
  Eigen::Matrix3Xd offsets(3, 2);
  offsets << 0.1, -0.2,  //
      0.0, 0.05,         //
      -0.1, 0.2;
  const double move = scenario.move_time, leg = move / 3, h = 1e-6;
  auto at = [&](double t) { return pointsOnFrame(frameMotion(path, start, move, t), offsets); };
  // At rest where it starts, at each waypoint, and after; there at the waypoint's pose.
  const Eigen::Vector3d expected_origin[] = {start, start + Eigen::Vector3d(0.15, 0, 0),
                                             start + Eigen::Vector3d(-0.1, 0.05, 0), start, start};
  const double expected_deg[] = {0.0, 30.0, 0.0, 0.0, 0.0};
  const double times[] = {0.0, leg, 2 * leg, move, move + 1.0};
  for (int k = 0; k < 5; ++k)
  {
    const RigidFrameMotion f = frameMotion(path, start, move, times[k]);
    EXPECT_LT((f.origin - expected_origin[k]).norm(), 1e-14) << "t = " << times[k];
    EXPECT_NEAR(Eigen::AngleAxisd(f.rotation).angle() * 180.0 / 3.14159265358979323846, expected_deg[k], 1e-9)
        << "t = " << times[k];
    const RigidPointMotion m = at(times[k]);
    EXPECT_LT(m.velocity.cwiseAbs().maxCoeff(), 1e-12) << "t = " << times[k];
    EXPECT_LT(m.acceleration.cwiseAbs().maxCoeff(), 1e-9) << "t = " << times[k];
  }
  // Within each leg, and just across a waypoint, the rates are the derivatives of the positions
  // (central differences), and a rigid motion keeps the particles' distance.
  double fastest = 0.0;
  for (double t : {0.01, 0.07, 0.12, leg - 1e-4, leg + 1e-4, 0.2, 0.27, 2 * leg + 1e-4, 0.38, 0.44})
  {
    const RigidPointMotion m = at(t);
    const Eigen::Matrix3Xd velocity = (at(t + h).position - at(t - h).position) / (2 * h);
    const Eigen::Matrix3Xd acceleration = (at(t + h).velocity - at(t - h).velocity) / (2 * h);
    EXPECT_LT((m.velocity - velocity).cwiseAbs().maxCoeff(), 1e-6) << t;
    EXPECT_LT((m.acceleration - acceleration).cwiseAbs().maxCoeff(), 1e-4) << t;
    EXPECT_NEAR((m.position.col(0) - m.position.col(1)).norm(), (offsets.col(0) - offsets.col(1)).norm(), 1e-14);
    fastest = std::max(fastest, m.velocity.cwiseAbs().maxCoeff());
  }
  EXPECT_GT(fastest, 0.5) << "the path did not move";
}

TEST(HandleScenarios, BadWaypointsAreRefusedNamingTheElement)
{
  struct Case
  {
    std::string yaml, named;
  };
  auto handle = [](const std::string& keys) { return "[{name: a, handles: [{particles: [0], " + keys + "}]}]"; };
  const std::string w = "'handle_scenarios[0].handles[0].waypoints";
  for (const Case& c : {
           Case{handle("waypoints: []"), w + "'"},
           Case{handle("waypoints: {translation: [0, 0, 1]}"), w + "'"},
           Case{handle("waypoints: [[0, 0, 1]]"), w + "[0]'"},
           Case{handle("waypoints: [{}, {translation: [0, 1]}]"), w + "[1].translation'"},
           Case{handle("waypoints: [{translation: [0, .inf, 1]}]"), w + "[0].translation'"},
           Case{handle("waypoints: [{translation: [0, 2000, 1]}]"), w + "[0].translation'"},
           Case{handle("waypoints: [{rotation_deg: 400}]"), w + "[0].rotation_deg'"},
           Case{handle("waypoints: [{rotation_deg: half}]"), w + "[0].rotation_deg'"},
           Case{handle("waypoints: [{rotation_axis: [1, 0, 0]}]"), w + "[0].rotation_axis'"},
           Case{handle("translation: [0, 0, 1], waypoints: [{}]"), w + "'"},
           Case{handle("rotation_deg: 10, waypoints: [{}]"), w + "'"},
       })
  {
    const std::string message = invalidArgument([&] { parse(c.yaml); });
    EXPECT_NE(message.find("invalid parameter " + c.named), std::string::npos) << c.yaml << "\n" << message;
  }
  // A 2D grid moves in its x-z plane at every waypoint.
  GridParams grid;
  grid.fixed = {20, 21, 22, 23, 24};
  const std::string m = invalidArgument([&] {
    gridWithHandles(grid, parse(handle("waypoints: [{translation: [0.1, 0, 0]}, {translation: [0, 0.1, 0]}]")).front());
  });
  EXPECT_NE(m.find("'handles[0].waypoints.translation'"), std::string::npos) << m;
}

// Two single-particle grips on a flat 3D sheet with nothing fixed, linearized at rest: K_ii is singular
// (no out-of-plane stiffness), so no modal method can be built; `full` still runs, and the experiment
// says why the others did not.
TEST(HandleScenarios, AMethodThatCannotBeBuiltIsReportedAndTheOthersRun)
{
  const HandleScenario scenario =
      parse("[{name: grips, move_time: 0.1, hold_time: 0, handles: [{particles: [0], translation: [0.05, 0, 0]}, "
            "{particles: [3], translation: [-0.05, 0, 0]}]}]")
          .front();
  ExperimentSetup setup = heldSheet(scenario);
  setup.sim.linearization = Linearization::Rest;
  setup.sim.initial_state = InitialState::Initial;
  setup.sim.num_modes = 6;
  AccuracyOptions options;
  options.methods = {Method::Linear, Method::Physical};
  options.sample = 10;
  options.steps = options.interval = 200;
  options.snapshots = false;
  const AccuracyResult result = runAccuracy(setup, options);
  ASSERT_EQ(result.not_built.size(), 2u);
  EXPECT_EQ(result.not_built[0].first, "linear");
  EXPECT_EQ(result.not_built[1].first, "physical");
  EXPECT_NE(result.not_built[0].second.find("singular"), std::string::npos) << result.not_built[0].second;
  int full_samples = 0;
  for (const ErrorSample& e : result.errors)
  {
    EXPECT_EQ(e.method, "full");
    full_samples += !e.diverged;
  }
  EXPECT_EQ(full_samples, 21);
  const std::vector<AccuracySummary> rows = notBuiltSummaries("grips", result);
  ASSERT_EQ(rows.size(), 2u);
  EXPECT_EQ(rows[1].method, "physical");
  EXPECT_TRUE(std::isnan(rows[1].mean_rms));
  std::ostringstream csv;
  writeAccuracySummaryCsv(csv, rows);
  EXPECT_NE(csv.str().find(",not_built,indicator_rank_correlation,reduced_share,switches,time_step,deepest,mean_surface\n"), std::string::npos) << csv.str();
  EXPECT_NE(csv.str().find("grips,linear,,,,,,,,,,,0,\"handles: "), std::string::npos) << csv.str();
}

// The converged reference is `full` at rest linearization whatever basis the methods use: an enriched
// basis, which needs the equilibrium, must not be asked of it.
TEST(HandleScenarios, TheConvergedReferenceRunsWhateverTheMethodsBasis)
{
  const HandleScenario scenario =
      parse("[{name: lift, move_time: 0.05, hold_time: 0, handles: [{particles: [0, 1, 2, 3], translation: [0, 0, 0.01]}]}]")
          .front();
  ExperimentSetup setup = heldSheet(scenario);
  setup.sim.basis = BasisKind::ModalDerivatives;
  setup.sim.num_modes = 3;
  setup.sim.num_derivative_modes = 3;
  AccuracyOptions options;
  options.methods = {Method::Physical};
  options.sample = 10;
  options.steps = options.interval = 100;
  options.snapshots = false;
  options.reference_time_step = setup.sim.time_step / 2;
  const AccuracyResult result = runAccuracy(setup, options);
  EXPECT_TRUE(result.not_built.empty());
  ASSERT_FALSE(result.errors.empty());
  EXPECT_EQ(result.errors.front().method, "reference");
  EXPECT_EQ(result.errors.back().method, "physical");
  EXPECT_FALSE(result.errors.back().diverged);
  EXPECT_EQ(result.reference_check.size(), result.errors.size() / 2);
}

// Method "adaptive" runs beside the others: with a tolerance no step exceeds it is its reduced
// method step for step; with one every step exceeds it is `full` from the start.
TEST(HandleScenarios, AdaptiveRunsBesideTheMethodsAndReportsItsShareOfReducedSteps)
{
  const HandleScenario scenario =
      parse("[{name: lift, move_time: 0.1, hold_time: 0.1, handles: [{particles: [0, 1, 2, 3], translation: [0, 0, 0.05]}]}]")
          .front();
  ExperimentSetup setup = heldSheet(scenario);
  setup.sim.num_modes = 3;
  setup.sim.adaptive_method = Method::Physical;
  AccuracyOptions options;
  options.methods = {Method::Physical};
  options.adaptive = true;
  options.sample = 10;
  options.steps = options.interval = 200;
  options.snapshots = false;
  auto summaryOf = [](const AccuracyResult& result, const std::string& method) {
    for (const AccuracySummary& s : summarizeAccuracy(result.errors))
      if (s.method == method)
        return s;
    ADD_FAILURE() << "no summary for " << method;
    return AccuracySummary{};
  };
  setup.sim.error_tolerance = 1.0;
  const AccuracyResult loose = runAccuracy(setup, options);
  const AccuracySummary physical = summaryOf(loose, "physical"), adaptive = summaryOf(loose, "adaptive");
  EXPECT_EQ(adaptive.reduced_share, 1.0);
  EXPECT_EQ(adaptive.switches, 0);
  EXPECT_EQ(adaptive.mean_rms, physical.mean_rms);
  EXPECT_GT(physical.mean_rms, 0.0);
  EXPECT_EQ(physical.switches, -1);

  setup.sim.error_tolerance = 1e-30;  // below even the indicator's round-off where the span holds the lift
  setup.sim.adaptive_check_steps = options.sample;  // its first check before the first sample
  const AccuracySummary tight = summaryOf(runAccuracy(setup, options), "adaptive");
  // Its first check fails: its steps are taken again under `full` from the start, which makes it
  // `full` throughout.
  EXPECT_EQ(tight.switches, 1);
  EXPECT_EQ(tight.reduced_share, 0.0);
  EXPECT_LT(tight.mean_rms, 1e-12);
}

// Method "coarse" runs as the others, with its error indicator: on as many columns as the grid it is
// `full` to round-off (and nothing is outside its span), on fewer it is further from the reference.
TEST(HandleScenarios, CoarseRunsBesideTheMethodsAndOnTheGridItselfIsFull)
{
  const HandleScenario scenario =
      parse("[{name: lift, move_time: 0.1, hold_time: 0.1, handles: [{particles: [0, 1, 2, 3], translation: [0, 0.05, 0.05]}]}]")
          .front();
  ExperimentSetup setup = heldSheet(scenario);
  AccuracyOptions options;
  options.methods = {Method::Full, Method::Coarse};
  options.sample = 10;
  options.steps = options.interval = 400;
  options.snapshots = false;
  options.reference_time_step = setup.sim.time_step / 5;
  // The mean RMS of `full` and of `coarse` on coarse_cols columns.
  auto meanRms = [&](int coarse_cols) {
    setup.sim.coarse_cols = coarse_cols;
    const AccuracyResult result = runAccuracy(setup, options);
    for (const ErrorSample& e : result.errors)
      if (e.method == "coarse")
      {
        EXPECT_FALSE(std::isnan(e.error_indicator));
        if (coarse_cols == setup.grid.cols)
        {
          EXPECT_LT(e.error_indicator, 1e-12);
        }
      }
    std::map<std::string, double> mean;
    for (const AccuracySummary& s : summarizeAccuracy(result.errors))
    {
      mean[s.method] = s.mean_rms;
      // `coarse` on 2 x 2 spans two steps (the square root of 4 fine particles a coarse one), on the
      // grid itself one; the CPU per simulated second is over its own step.
      const double time_step = setup.sim.time_step * (s.method == "coarse" && coarse_cols == 2 ? 2 : 1);
      if (s.method != "reference")
      {
        EXPECT_DOUBLE_EQ(s.time_step, time_step) << s.method;
        EXPECT_DOUBLE_EQ(s.cpu_per_simulated_second, s.step_cpu_seconds_median / time_step) << s.method;
      }
    }
    EXPECT_EQ(mean.count("full") + mean.count("coarse"), 2u);
    return std::make_pair(mean["full"], mean["coarse"]);
  };
  const auto [full, same] = meanRms(4);
  EXPECT_GT(full, 0.0);
  EXPECT_NEAR(same, full, 1e-12);
  const auto [full_again, coarser] = meanRms(2);
  EXPECT_EQ(full_again, full);
  EXPECT_GT(coarser, 2 * full);
  EXPECT_LT(coarser, 0.05);
}
