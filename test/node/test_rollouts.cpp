// Rollouts without a master: a rollout from the live state with the live handle poses is the live
// trajectory; bad goals refused by name before any work; a cancel stops the workers.
#include "rollouts.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <cmath>
#include <limits>
#include <string>

using namespace modal_mass_spring;

namespace
{

// A 6 x 6 cloth held at two corners by the frames "left" and "right", over a table it is lowered onto.
struct HeldCloth
{
  GridParams grid;
  SimulationParams params;
  std::vector<HandleParam> handles{{"left", {0}}, {"right", {5}}};
  Eigen::Vector3d offset{1.0, 2.0, 0.5};  // the grid's origin in the fixed frame
  HeldCloth()
  {
    grid.rows = grid.cols = 6;
    grid.spacing = 0.05;
    grid.dimension = 3;
    grid.mass = 0.005;
    grid.structural_stiffness = 50.0;
    grid.shear_stiffness = 20.0;
    grid.handles = {{0}, {5}};
    params.method = Method::Full;
    params.time_step = 1e-3;
    params.alpha = 0.5;
    Collider table;
    table.type = ColliderType::Plane;
    table.point = Eigen::Vector3d(0.0, 0.0, Grid(grid).toPoints(Grid(grid).initialPositions()).row(2).minCoeff() - 0.03);
    params.colliders = {table};
  }
};

// Where the frames are at time t (fixed frame): they come down, apart and turn a little.
std::vector<std::optional<FramePose>> framePoses(const HandleFrames& frames, const std::vector<FramePose>& start, double t)
{
  std::vector<std::optional<FramePose>> poses(frames.size());
  for (size_t h = 0; h < frames.size(); ++h)
  {
    FramePose p = start[h];
    p.translation += Eigen::Vector3d((h == 0 ? -0.02 : 0.02) * t, 0.0, -0.08 * t);
    p.rotation = Eigen::Quaterniond(Eigen::AngleAxisd(0.3 * t, Eigen::Vector3d::UnitZ()));
    poses[h] = p;
  }
  return poses;
}

std::vector<HandleWaypoint> waypointsOf(const std::vector<double>& times,
                                        const std::vector<std::vector<std::optional<FramePose>>>& poses, size_t h)
{
  std::vector<HandleWaypoint> waypoints;
  for (size_t k = 0; k < times.size(); ++k)
    waypoints.push_back(HandleWaypoint{times[k], *poses[k][h]});
  return waypoints;
}

}  // namespace

// The live node's ticks (each a handful of steps, the handles interpolated between the frames'
// poses at the ticks) reproduced by a rollout whose waypoints are those poses at those times, on a
// worker simulation that never saw the live run.
TEST(Rollouts, RolloutFromLiveStateIsTheLiveTrajectory)
{
  const HeldCloth cloth;
  Simulation live(cloth.grid, cloth.params);
  HandleFrames frames(cloth.handles, live.grid(), live.linearizationPositions(), cloth.offset);
  // The frames' first lookup (at the particles' centroid, turned nowhere), then a few live ticks.
  std::vector<FramePose> start(frames.size());
  const Eigen::Matrix3Xd points = live.points();
  start[0].translation = points.col(0) + cloth.offset;
  start[1].translation = points.col(5) + cloth.offset;
  const double dt = cloth.params.time_step;
  frames.setTargets({start[0], start[1]});
  frames.finishTick(dt, 1.0);
  auto tick = [&](Simulation& sim, HandleFrames& f, int steps, double t) {
    f.setTargets(framePoses(f, start, t));
    for (int k = 1; k <= steps; ++k)
    {
      f.drive(sim, steps * dt, static_cast<double>(k) / steps);
      ASSERT_FALSE(sim.step().diverged);
    }
    f.finishTick(steps * dt, 1.0);
  };
  double t = 0.0;
  for (int steps : {33, 34, 33})
    tick(live, frames, steps, t += steps * dt);

  RolloutRequest request;
  request.state = live.saveState();
  request.frames = frames;
  request.method = Method::Full;
  request.time_step = dt;
  request.grid_offset = cloth.offset;
  // The live run goes on: ticks of uneven length, as a loaded machine's.
  std::vector<double> times;
  std::vector<std::vector<std::optional<FramePose>>> poses;
  std::vector<Eigen::Matrix3Xd> live_positions;
  const double t0 = t;
  for (int steps : {33, 40, 27, 33, 50, 17, 33, 100, 33, 34})
  {
    t += steps * dt;
    tick(live, frames, steps, t);
    times.push_back(t - t0);
    poses.push_back(framePoses(frames, start, t));
    live_positions.push_back(live.points().colwise() + cloth.offset);
  }
  ASSERT_GT(live.contact()->report().touching[0], 0) << "the cloth must reach the table for the test to mean much";
  request.horizon = times.back();
  request.sample_times = times;
  CandidateMotion replay;
  replay.frames = {{"left", waypointsOf(times, poses, 0)}, {"right", waypointsOf(times, poses, 1)}};
  CandidateMotion still;  // both frames hold where they are
  request.candidates = {still, replay, still};

  Simulation worker_a(cloth.grid, cloth.params), worker_b(cloth.grid, cloth.params);
  std::atomic<bool> cancel{false};
  int told = 0;
  const std::vector<CandidateOutcome> outcomes =
      runRollouts({&worker_a, &worker_b}, request, cancel, [&](const CandidateOutcome&) { ++told; });
  ASSERT_EQ(outcomes.size(), 3u);
  EXPECT_EQ(told, 3);
  const CandidateOutcome& outcome = outcomes[1];
  EXPECT_EQ(outcome.candidate, 1);
  EXPECT_FALSE(outcome.diverged) << outcome.message;
  ASSERT_EQ(outcome.samples.size(), times.size());
  double largest = 0.0;
  for (size_t k = 0; k < times.size(); ++k)
    largest = std::max(largest, (outcome.samples[k].positions - live_positions[k]).colwise().norm().maxCoeff());
  EXPECT_LT(largest, 1e-9);
  // The held candidates differ from the live run by the handles' motion, and are alike.
  EXPECT_GT((outcomes[0].samples.back().positions - live_positions.back()).colwise().norm().maxCoeff(), 1e-2);
  EXPECT_EQ(outcomes[0].samples.back().positions, outcomes[2].samples.back().positions);
  ASSERT_EQ(outcome.samples.back().handle_forces.size(), 2u);
  ASSERT_EQ(outcome.samples.back().contact_forces.size(), 1u);
  EXPECT_GT(outcome.samples.back().contact_forces[0].norm(), 0.0);
}

// A rollout that diverges says where in the rollout, not only at which step of the live run.
TEST(Rollouts, ADivergedCandidateSaysWhenInTheRollout)
{
  const HeldCloth cloth;
  Simulation live(cloth.grid, cloth.params);
  ASSERT_FALSE(live.step(100).diverged);
  RolloutRequest request;
  request.state = live.saveState();
  request.frames = HandleFrames(cloth.handles, live.grid(), live.linearizationPositions(), cloth.offset);
  const Eigen::Matrix3Xd points = live.points();
  FramePose left, right;
  left.translation = points.col(0) + cloth.offset;
  right.translation = points.col(5) + cloth.offset;
  request.frames.setTargets({left, right});
  request.frames.finishTick(cloth.params.time_step, 1.0);
  request.method = Method::Full;
  request.time_step = 0.05;  // far above this cloth's explicit limit (about 7 ms)
  request.horizon = 1.0;
  request.candidates = {CandidateMotion{}};
  Simulation worker(cloth.grid, cloth.params);
  std::atomic<bool> cancel{false};
  const CandidateOutcome outcome = runCandidate(worker, rolloutStart(worker, request), request, 0, cancel);
  ASSERT_TRUE(outcome.diverged);
  EXPECT_LT(outcome.simulated_time, request.horizon);
  ASSERT_EQ(outcome.message.rfind("at ", 0), 0u) << outcome.message;
  EXPECT_NEAR(std::stod(outcome.message.substr(3)), outcome.simulated_time + request.time_step, 1e-9);
  EXPECT_NE(outcome.message.find(" s of the rollout: method 'full' diverged at step "), std::string::npos)
      << outcome.message;
}

namespace
{

// A request that passes, on a cloth whose handle frames were looked up.
struct ValidRequest
{
  HeldCloth cloth;
  Grid grid{cloth.grid};
  RolloutRequest request;
  RolloutLimits limits;
  ValidRequest()
  {
    request.frames = HandleFrames(cloth.handles, grid, grid.initialPositions(), cloth.offset);
    request.frames.setTargets({FramePose{}, FramePose{}});
    request.horizon = 1.0;
    request.time_step = 1e-3;
    CandidateMotion motion;
    FramePose lowered;
    lowered.translation.z() = -0.1;
    motion.frames = {{"left", {HandleWaypoint{0.5, lowered}}}};
    request.candidates = {motion};
    limits.max_horizon = 5.0;
    limits.max_candidates = 4;
  }
  std::string refusal() const
  {
    try
    {
      checkRolloutRequest(request, limits, cloth.grid, cloth.params);
    }
    catch (const std::invalid_argument& error)
    {
      return error.what();
    }
    return "";
  }
};

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

}  // namespace

// With no time step in the goal: the live one, which `coarse` spans coarseStepMultiple times, as many
// as fit in the horizon.
TEST(Rollouts, DefaultTimeStepIsTheLiveOneCoarseSpansAMultipleOfIt)
{
  GridParams grid = HeldCloth().grid;
  grid.rows = grid.cols = 16;  // 16 x 16 on 6 x 6: 7.1 fine particles a coarse one
  grid.handles = {{0}, {15}};
  SimulationParams params = HeldCloth().params;
  params.coarse_cols = 6;
  EXPECT_DOUBLE_EQ(defaultRolloutTimeStep(Method::Full, 1.0, grid, params), 1e-3);
  EXPECT_DOUBLE_EQ(defaultRolloutTimeStep(Method::Cubature, 1.0, grid, params), 1e-3);
  EXPECT_DOUBLE_EQ(defaultRolloutTimeStep(Method::Coarse, 1.0, grid, params), 2e-3);
  EXPECT_DOUBLE_EQ(defaultRolloutTimeStep(Method::Coarse, 1.5e-3, grid, params), 1e-3);
  params.coarse_cols = 4;  // 16 fine particles a coarse one
  EXPECT_DOUBLE_EQ(defaultRolloutTimeStep(Method::Coarse, 1.0, grid, params), 4e-3);
  EXPECT_DOUBLE_EQ(defaultRolloutTimeStep(Method::Coarse, 3.5e-3, grid, params), 3e-3);
  EXPECT_DOUBLE_EQ(defaultRolloutTimeStep(Method::Coarse, 9e-3, grid, params), 3e-3);  // 4 does not divide 9
  // A live `coarse` steps at its own step already.
  params.method = Method::Coarse;
  EXPECT_DOUBLE_EQ(defaultRolloutTimeStep(Method::Coarse, 1.0, grid, params), 1e-3);
}

TEST(Rollouts, BadGoalsRefusedByNameWithTheirRange)
{
  EXPECT_EQ(ValidRequest().refusal(), "");
  ValidRequest r;
  r.request.candidates.clear();
  EXPECT_TRUE(contains(r.refusal(), "candidates")) << r.refusal();
  EXPECT_TRUE(contains(r.refusal(), "rollout_max_candidates = 4")) << r.refusal();
  r = ValidRequest();
  r.request.candidates.resize(5);
  EXPECT_TRUE(contains(r.refusal(), "rollout_max_candidates = 4")) << r.refusal();
  for (double horizon : {0.0, -1.0, 6.0, std::numeric_limits<double>::quiet_NaN()})
  {
    r = ValidRequest();
    r.request.horizon = horizon;
    EXPECT_TRUE(contains(r.refusal(), "horizon")) << r.refusal();
    EXPECT_TRUE(contains(r.refusal(), "rollout_max_horizon = 5 s")) << r.refusal();
  }
  r = ValidRequest();
  r.request.candidates[0].frames[0].first = "elbow";
  EXPECT_TRUE(contains(r.refusal(), "candidates[0].handles[0].frame")) << r.refusal();
  EXPECT_TRUE(contains(r.refusal(), "'left', 'right'")) << r.refusal();
  r = ValidRequest();
  r.request.candidates[0].frames[0].second[0].pose.translation.x() = std::nan("");
  EXPECT_TRUE(contains(r.refusal(), "candidates[0].handles[0].poses[0]")) << r.refusal();
  r = ValidRequest();
  r.request.candidates[0].frames[0].second[0].time = std::nan("");
  EXPECT_TRUE(contains(r.refusal(), "candidates[0].handles[0].times[0]")) << r.refusal();
  r = ValidRequest();
  r.request.candidates[0].frames[0].second[0].pose.translation.z() = -2.0;  // farther than a tick may go
  EXPECT_TRUE(contains(r.refusal(), "add waypoints")) << r.refusal();
  r = ValidRequest();
  r.request.sample_times = {0.5, 0.4};
  EXPECT_TRUE(contains(r.refusal(), "sample_times[1]")) << r.refusal();
  r = ValidRequest();
  r.limits.memory_limit_gb = 1e-6;
  EXPECT_TRUE(contains(r.refusal(), "memory_limit_gb")) << r.refusal();
  r = ValidRequest();
  r.request.time_step = -1.0;
  EXPECT_TRUE(contains(r.refusal(), "time_step")) << r.refusal();
}

// A cancel after the first candidate: the workers stop within a step and what finished is returned.
TEST(Rollouts, CancelStopsTheWorkersAndKeepsWhatFinished)
{
  ValidRequest r;
  Simulation live(r.cloth.grid, r.cloth.params);
  r.request.state = live.saveState();
  r.request.frames = HandleFrames(r.cloth.handles, live.grid(), live.linearizationPositions(), r.cloth.offset);
  r.request.frames.setTargets({FramePose{}, FramePose{}});
  r.request.frames.finishTick(r.cloth.params.time_step, 1.0);
  r.request.candidates.assign(40, r.request.candidates[0]);
  Simulation worker_a(r.cloth.grid, r.cloth.params), worker_b(r.cloth.grid, r.cloth.params);
  std::atomic<bool> cancel{false};
  const std::vector<CandidateOutcome> outcomes =
      runRollouts({&worker_a, &worker_b}, r.request, cancel, [&](const CandidateOutcome&) { cancel = true; });
  EXPECT_GE(outcomes.size(), 1u);
  EXPECT_LE(outcomes.size(), 2u);  // at most the one each worker was finishing
  for (const CandidateOutcome& outcome : outcomes)
    EXPECT_NEAR(outcome.simulated_time, 1.0, 1e-12);
}
