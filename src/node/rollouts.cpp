// Rollouts of candidate handle motions on worker simulations.
#include "rollouts.h"

#include "modal_mass_spring/cpu_time.h"

#include "modal_mass_spring/parameter_error.h"

#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <thread>

namespace modal_mass_spring
{
namespace
{

std::string number(double value)
{
  std::ostringstream text;
  text << value;
  return text.str();
}

// Where a frame is at time t along its waypoints, starting from `start` at time 0: as the live node
// moves it between two ticks (translation linearly, rotation by slerp), held after the last.
FramePose poseAt(const FramePose& start, const std::vector<HandleWaypoint>& waypoints, double t)
{
  FramePose from = start;
  double from_time = 0.0;
  for (const HandleWaypoint& w : waypoints)
  {
    if (t < w.time)
    {
      const double s = (t - from_time) / (w.time - from_time);
      FramePose pose;
      pose.translation = (1.0 - s) * from.translation + s * w.pose.translation;
      pose.rotation = from.rotation.slerp(s, w.pose.rotation);
      return pose;
    }
    from = w.pose;
    from_time = w.time;
  }
  return from;
}

long stepIndex(double t, double dt) { return std::lround(t / dt); }

// The candidates' number, the horizon, the time step (`rollout`: the live parameters in the
// request's method and time step) and the sample times.
void checkRolloutTimes(const RolloutRequest& request, const RolloutLimits& limits, const GridParams& grid,
                       const SimulationParams& rollout)
{
  const size_t candidates = request.candidates.size();
  const std::string candidate_range =
      "must have 1 to rollout_max_candidates = " + std::to_string(limits.max_candidates) + " candidates";
  if (candidates == 0)
    rejectParameter("candidates", "none", candidate_range);
  if (candidates > static_cast<size_t>(limits.max_candidates))
    rejectParameter("candidates", std::to_string(candidates), candidate_range);
  if (!std::isfinite(request.horizon) || request.horizon <= 0.0 || request.horizon > limits.max_horizon)
    rejectParameter("horizon", number(request.horizon) + " s",
                    "must be > 0 and <= rollout_max_horizon = " + number(limits.max_horizon) + " s");
  validateParameters(grid, rollout);  // names time_step and its range
  if (request.time_step > request.horizon)
    rejectParameter("time_step", number(request.time_step) + " s",
                    "must be <= horizon = " + number(request.horizon) + " s");
  double last = 0.0;
  for (size_t k = 0; k < request.sample_times.size(); ++k)
  {
    const double t = request.sample_times[k];
    if (!std::isfinite(t) || t <= last || t > request.horizon)
      rejectParameter("sample_times[" + std::to_string(k) + "]", number(t) + " s",
                      "must be increasing, > 0 and <= horizon = " + number(request.horizon) + " s");
    last = t;
  }
}

// One handle frame's waypoints (`name`: candidates[c].handles[j]), from where the frame is now.
void checkWaypoints(const std::string& name, const std::vector<HandleWaypoint>& waypoints, FramePose previous)
{
  if (waypoints.empty())
    rejectParameter(name + ".poses", "none", "must have one pose per time, at least one");
  double previous_time = 0.0;
  for (size_t i = 0; i < waypoints.size(); ++i)
  {
    const HandleWaypoint& w = waypoints[i];
    const std::string at = "[" + std::to_string(i) + "]";
    if (!std::isfinite(w.time) || w.time <= previous_time)
      rejectParameter(name + ".times" + at, number(w.time) + " s", "must be finite, > 0 and increasing");
    if (!w.pose.translation.allFinite() || !w.pose.rotation.coeffs().allFinite())
      rejectParameter(name + ".poses" + at, "a non-finite value", "must be finite");
    if (std::abs(w.pose.rotation.norm() - 1.0) > 1e-3)
      rejectParameter(name + ".poses" + at + ".orientation", "norm " + number(w.pose.rotation.norm()),
                      "must be a unit quaternion (norm within 1e-3 of 1)");
    // The live node refuses a frame that moves this far between two ticks (a glitch): so do waypoints.
    const double jump = (w.pose.translation - previous.translation).norm();
    const double turn = previous.rotation.angularDistance(w.pose.rotation.normalized());
    if (jump > HandleFrames::kMaxJumpPerTick || turn > HandleFrames::kMaxTurnPerTick)
      rejectParameter(name + ".poses" + at, "a move of " + number(jump) + " m and " + number(turn) + " rad",
                      "must move at most " + number(HandleFrames::kMaxJumpPerTick) + " m and turn at most " +
                          number(HandleFrames::kMaxTurnPerTick) + " rad from the pose before (add waypoints)");
    previous = w.pose;
    previous_time = w.time;
  }
}

// Every candidate's handle frames: each a handle frame the node has looked up, its waypoints checked.
void checkCandidateFrames(const RolloutRequest& request)
{
  std::string frames;
  for (size_t h = 0; h < request.frames.size(); ++h)
    if (frames.find("'" + request.frames.frame(h) + "'") == std::string::npos)
      frames += (frames.empty() ? "'" : ", '") + request.frames.frame(h) + "'";
  for (size_t c = 0; c < request.candidates.size(); ++c)
    for (size_t j = 0; j < request.candidates[c].frames.size(); ++j)
    {
      const auto& [frame, waypoints] = request.candidates[c].frames[j];
      const std::string name = "candidates[" + std::to_string(c) + "].handles[" + std::to_string(j) + "]";
      std::optional<size_t> handle;
      for (size_t h = 0; h < request.frames.size() && !handle; ++h)
        if (request.frames.frame(h) == frame)
          handle = h;
      if (!handle)
        rejectParameter(name + ".frame", "'" + frame + "'",
                        frames.empty() ? std::string("the node has no handles") : "must be a handle frame: " + frames);
      if (!request.frames.everFound(*handle))
        rejectParameter(name + ".frame", "'" + frame + "'",
                        "must be a handle frame the node has looked up (it has no pose yet to start from)");
      checkWaypoints(name, waypoints, request.frames.current(*handle));
    }
}

}  // namespace

void checkRolloutRequest(const RolloutRequest& request, const RolloutLimits& limits, const GridParams& grid,
                         const SimulationParams& params)
{
  SimulationParams rollout = params;
  rollout.method = request.method;
  rollout.time_step = request.time_step;
  checkRolloutTimes(request, limits, grid, rollout);
  checkCandidateFrames(request);

  // Each worker holds a simulation; the samples hold every particle, handle and collider.
  const size_t candidates = request.candidates.size();
  const Grid g(grid);
  const double per_sample = 8.0 * 3.0 * (g.numParticles() + grid.handles.size() + params.colliders.size());
  const double samples = std::max<size_t>(request.sample_times.size(), 1);
  const double bytes = limits.threads * estimateMemoryBytes(grid, rollout) + candidates * samples * per_sample;
  if (bytes > limits.memory_limit_gb * 1e9)
    rejectParameter("candidates", std::to_string(candidates) + " candidates of " + number(samples) + " samples",
                    "need an estimated " + number(bytes / 1e9) + " GB (" + std::to_string(limits.threads) +
                        " worker simulations and the samples), above memory_limit_gb = " +
                        number(limits.memory_limit_gb) + " GB: fewer candidates, sample times or rollout_threads");
}

double defaultRolloutTimeStep(Method method, double horizon, const GridParams& grid, SimulationParams params)
{
  // A live `coarse` steps at its own step already.
  if (method != Method::Coarse || params.method == Method::Coarse)
    return params.time_step;
  params.method = method;
  // A whole number of steps to the horizon (one out of range is refused later): the multiple divides
  // the live steps in it, and a step is never past it.
  const double steps = std::floor(horizon / params.time_step + 1e-9);
  if (!(steps >= 1.0 && steps < 1e9))
    return params.time_step;
  return std::min(params.time_step * coarseStepMultiple(grid, params, static_cast<long>(steps)), horizon);
}

SimulationState rolloutStart(Simulation& simulation, const RolloutRequest& request)
{
  simulation.restoreState(request.state);
  if (simulation.method() != request.method)
    simulation.setMethod(request.method);
  if (simulation.params().time_step != request.time_step)
    simulation.setTimeStep(request.time_step);
  return simulation.saveState();
}

namespace
{

// The times a candidate's frames are placed at: every waypoint and sample time within the horizon,
// and the horizon.
std::vector<double> candidateTicks(const RolloutRequest& request, const CandidateMotion& motion)
{
  std::vector<double> ticks = request.sample_times;
  ticks.push_back(request.horizon);
  for (const auto& [frame, path] : motion.frames)
    for (const HandleWaypoint& w : path)
      if (w.time < request.horizon)
        ticks.push_back(w.time);
  std::sort(ticks.begin(), ticks.end());
  return ticks;
}

GridSample gridSample(const Simulation& simulation, double time, const Eigen::Vector3d& grid_offset)
{
  GridSample sample;
  sample.time = time;
  sample.positions = simulation.points().colwise() + grid_offset;
  sample.handle_forces = simulation.handleForces();
  if (simulation.contact())
    sample.contact_forces = simulation.contact()->report().force;
  return sample;
}

}  // namespace

CandidateOutcome runCandidate(Simulation& simulation, const SimulationState& start, const RolloutRequest& request,
                            int candidate, const std::atomic<bool>& cancel)
{
  CandidateOutcome outcome;
  outcome.candidate = candidate;
  simulation.restoreState(start);
  HandleFrames frames = request.frames;
  const double dt = request.time_step;
  // Each handle's waypoints (none: it holds still), and where its frame starts.
  const CandidateMotion& motion = request.candidates[static_cast<size_t>(candidate)];
  std::vector<const std::vector<HandleWaypoint>*> waypoints(frames.size(), nullptr);
  std::vector<FramePose> start_poses(frames.size());
  for (size_t h = 0; h < frames.size(); ++h)
  {
    start_poses[h] = frames.current(h);
    for (const auto& [frame, path] : motion.frames)
      if (frame == frames.frame(h))
        waypoints[h] = &path;
  }
  const std::vector<double> samples =
      request.sample_times.empty() ? std::vector<double>{request.horizon} : request.sample_times;
  size_t next_sample = 0;
  const long first_step = simulation.stepCount();
  long step = 0;  // since the start
  for (const double tick : candidateTicks(request, motion))
  {
    const long steps = stepIndex(tick, dt) - step;
    if (steps > 0)
    {
      std::vector<std::optional<FramePose>> targets(frames.size());
      for (size_t h = 0; h < frames.size(); ++h)
        if (waypoints[h])
          targets[h] = poseAt(start_poses[h], *waypoints[h], stepIndex(tick, dt) * dt);
        else if (frames.everFound(h))
          targets[h] = frames.current(h);  // held still
      frames.setTargets(targets);
      for (const std::string& refusal : frames.refusals())
        outcome.message += (outcome.message.empty() ? "" : "; ") + refusal;
      for (long k = 1; k <= steps; ++k)
      {
        if (cancel)
        {
          outcome.message = "cancelled";
          outcome.simulated_time = (simulation.stepCount() - first_step) * dt;
          return outcome;
        }
        frames.drive(simulation, steps * dt, static_cast<double>(k) / steps);
        const StepResult result = simulation.step(1);
        if (result.diverged)
        {
          outcome.diverged = true;
          outcome.simulated_time = (simulation.stepCount() - first_step) * dt;
          // The core counts the steps from the live run's start: say where in the rollout it was.
          outcome.message = "at " + number(outcome.simulated_time + dt) + " s of the rollout: " + result.message;
          return outcome;
        }
      }
      frames.finishTick(steps * dt, 1.0);
      step += steps;
    }
    // Every sample due by now (a sample within half a step of the last one lands on its step).
    while (next_sample < samples.size() && stepIndex(samples[next_sample], dt) <= step)
    {
      outcome.samples.push_back(gridSample(simulation, samples[next_sample], request.grid_offset));
      ++next_sample;
    }
  }
  outcome.simulated_time = step * dt;
  return outcome;
}

std::vector<CandidateOutcome> runRollouts(const std::vector<Simulation*>& workers, const RolloutRequest& request,
                                        const std::atomic<bool>& cancel,
                                        const std::function<void(const CandidateOutcome&)>& on_finished,
                                        double* cpu_seconds)
{
  std::atomic<size_t> next{0};
  std::mutex mutex;
  std::vector<CandidateOutcome> finished;
  std::string failure;
  auto work = [&](Simulation& simulation) {
    // Below the live simulation's thread: the live rate comes first on a busy machine.
    setpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid)), 10);
    const double cpu_start = threadCpuSeconds();
    try
    {
      const SimulationState start = rolloutStart(simulation, request);
      for (size_t c = next++; c < request.candidates.size() && !cancel; c = next++)
      {
        CandidateOutcome outcome = runCandidate(simulation, start, request, static_cast<int>(c), cancel);
        if (cancel && outcome.message == "cancelled")
          break;
        std::lock_guard<std::mutex> lock(mutex);
        if (on_finished)
          on_finished(outcome);
        finished.push_back(std::move(outcome));
      }
    }
    catch (const std::exception& error)
    {
      std::lock_guard<std::mutex> lock(mutex);
      failure = error.what();
    }
    std::lock_guard<std::mutex> lock(mutex);
    if (cpu_seconds)
      *cpu_seconds += threadCpuSeconds() - cpu_start;
  };
  std::vector<std::thread> threads;
  for (Simulation* simulation : workers)
    threads.emplace_back(work, std::ref(*simulation));
  for (std::thread& thread : threads)
    thread.join();
  if (!failure.empty())
    throw std::runtime_error("a rollout worker failed: " + failure);
  std::sort(finished.begin(), finished.end(),
            [](const CandidateOutcome& a, const CandidateOutcome& b) { return a.candidate < b.candidate; });
  return finished;
}

}  // namespace modal_mass_spring
