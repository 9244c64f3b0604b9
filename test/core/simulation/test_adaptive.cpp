// The adaptive stepper: reduced where the span follows the motion, `full` where it does not.
#include "test_support.h"

#include "modal_mass_spring/adaptive.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <string>
#include <utility>
#include <vector>

using namespace modal_mass_spring;

namespace
{

// A 10 x 10 cloth held by its top row at its hanging equilibrium, as modal_compare's held cloth.
GridParams topRowHeld()
{
  std::vector<int> top;
  for (int col = 0; col < 10; ++col)
    top.push_back(col);
  return heldCloth({top}, 10);
}

SimulationParams heldParams(Method method, BasisKind basis)
{
  SimulationParams s = methodParams(method, 6, 5e-3, IntegratorKind::Implicit);
  s.alpha = 0.5;
  s.linearization = Linearization::Equilibrium;
  s.initial_state = InitialState::Equilibrium;
  s.basis = basis;
  s.num_skinning_weights = basis == BasisKind::Skinning ? 8 : 0;
  return s;
}

// The defaults at the tests' 5 ms step: a check every 20 steps.
AdaptiveSettings stepsOf5ms()
{
  SimulationParams p;
  p.time_step = 5e-3;
  return adaptiveSettings(p);
}

// Settings whose first check fails (a tolerance no estimate meets): `full` from the start, the
// steps before it taken again.
AdaptiveSettings fullFromTheStart(Method reduced)
{
  AdaptiveSettings settings = stepsOf5ms();
  settings.reduced = reduced;
  settings.tolerance = 1e-15;
  return settings;
}

// The top row's positions at step k of a motion `move(start, k)`.
using Motion = std::function<Eigen::VectorXd(const Eigen::VectorXd& start, int k)>;

// Turns the row 60 degrees about the vertical through its middle over 100 steps, then holds it.
Eigen::VectorXd turn(const Eigen::VectorXd& start, int k)
{
  Eigen::Vector3d middle = Eigen::Vector3d::Zero();
  for (Eigen::Index i = 0; i < start.size(); i += 3)
    middle += start.segment<3>(i) / 10.0;
  const double angle = 0.5 * (1.0 - std::cos(M_PI * std::min(k, 100) / 100.0)) * M_PI / 3.0;
  const Eigen::Matrix3d r = Eigen::AngleAxisd(angle, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  Eigen::VectorXd x = start;
  for (Eigen::Index i = 0; i < start.size(); i += 3)
    x.segment<3>(i) = middle + r * (start.segment<3>(i) - middle);
  return x;
}

// The turn where a simulation's next step ends (Simulation::nextStepTime), counted in the tests' 5 ms
// steps: a Drive for steps that span several of them.
Drive driveTurn(const Eigen::VectorXd& start)
{
  return [start](Simulation& sim) {
    sim.setHandleMotion(turn(start, static_cast<int>(std::lround(sim.nextStepTime() / 5e-3))));
  };
}

// Moves the row 5 cm along x over 100 steps, then holds it.
Eigen::VectorXd translate(const Eigen::VectorXd& start, int k)
{
  Eigen::VectorXd x = start;
  const double s = 0.5 * (1.0 - std::cos(M_PI * std::min(k, 100) / 100.0));
  for (Eigen::Index i = 0; i < start.size(); i += 3)
    x[i] += 0.05 * s;
  return x;
}

// Steps `sim` (through `adaptive` when given) `steps` steps of `motion`.
void run(Simulation& sim, const Motion& motion, int steps, AdaptiveStepper* adaptive = nullptr)
{
  const Eigen::VectorXd start = sim.handlePositions();
  for (int k = 1; k <= steps; ++k)
  {
    sim.setHandleMotion(motion(start, k));
    const StepResult r = adaptive ? adaptive->step() : sim.step();
    ASSERT_FALSE(r.diverged) << "step " << k << ": " << r.message;
  }
}

// The largest swing (swingDistance) of `physical` alone on `basis` over `steps` steps of `motion`,
// read every `every` steps; NaN if a step diverges.
double largestSwing(BasisKind basis, const Motion& motion, int steps, int every)
{
  Simulation physical(topRowHeld(), heldParams(Method::Physical, basis));
  const Eigen::VectorXd start = physical.handlePositions();
  double largest = 0.0;
  for (int k = 1; k <= steps; ++k)
  {
    physical.setHandleMotion(motion(start, k));
    if (const StepResult r = physical.step(); r.diverged)
    {
      ADD_FAILURE() << "step " << k << ": " << r.message;
      return std::nan("");
    }
    if (k % every == 0)
      largest = std::max(largest, swingDistance(physical));
  }
  return largest;
}

}  // namespace

TEST(Adaptive, BadSettingsAreRefusedByName)
{
  Simulation sim(topRowHeld(), heldParams(Method::Full, BasisKind::Skinning));
  auto refusedSetting = [&](const std::function<void(AdaptiveSettings&)>& change) {
    AdaptiveSettings s = stepsOf5ms();
    change(s);
    return refusal([&] { AdaptiveStepper stepper(sim, s); });
  };
  EXPECT_TRUE(contains(refusedSetting([](AdaptiveSettings& s) { s.tolerance = 0.0; }), "'error_tolerance' = 0"));
  EXPECT_TRUE(contains(refusedSetting([](AdaptiveSettings& s) { s.tolerance = NAN; }), "'error_tolerance'"));
  EXPECT_TRUE(contains(refusedSetting([](AdaptiveSettings& s) { s.dwell = -1.0; }), "'adaptive_dwell' = -1"));
  EXPECT_TRUE(contains(refusedSetting([](AdaptiveSettings& s) { s.check_steps = 0; }), "'adaptive_check_steps' = 0"));
  EXPECT_TRUE(contains(refusedSetting([](AdaptiveSettings& s) { s.swing_drift = -1.0; }), "'swing_drift' = -1"));
  EXPECT_TRUE(contains(refusedSetting([](AdaptiveSettings& s) { s.swing_drift = INFINITY; }), "'swing_drift'"));
  EXPECT_TRUE(contains(refusedSetting([](AdaptiveSettings& s) { s.safe_share = 0.0; }), "'safe_share' = 0"));
  EXPECT_TRUE(contains(refusedSetting([](AdaptiveSettings& s) { s.max_rollback_checks = 0; }), "'max_rollback_checks' = 0"));
  EXPECT_TRUE(contains(refusedSetting([](AdaptiveSettings& s) { s.max_check_stretch = 0; }), "'max_check_stretch' = 0"));
  EXPECT_TRUE(contains(refusedSetting([](AdaptiveSettings& s) { s.reduced_step_span = 0; }), "'reduced_step_span' = 0"));
  // Several time steps a reduced step only with a drive: the caller's motions come a step at a time.
  EXPECT_TRUE(contains(refusedSetting([](AdaptiveSettings& s) { s.reduced_step_span = 2; }), "without a drive"));
  EXPECT_TRUE(
      contains(refusedSetting([](AdaptiveSettings& s) { s.reduced = Method::Linear; }), "must be one of physical, cubature, coarse"));
  EXPECT_EQ(sim.method(), Method::Full);  // nothing changed

  // adaptive_check_steps 0: a check every 0.1 s of simulated time.
  SimulationParams p;
  p.time_step = 5e-3;
  EXPECT_EQ(adaptiveSettings(p).check_steps, 20);
  p.time_step = 8e-4;
  EXPECT_EQ(adaptiveSettings(p).check_steps, 125);
  p.adaptive_check_steps = 7;
  EXPECT_EQ(adaptiveSettings(p).check_steps, 7);
  EXPECT_EQ(adaptiveSettings(p).swing_drift, swingDrift(Method::Coarse));
  p.adaptive_method = Method::Physical;
  EXPECT_EQ(adaptiveSettings(p).swing_drift, 0.0);
  p.adaptive_check_steps = -1;
  EXPECT_TRUE(contains(refusal([&] { validateAdaptiveSettings(adaptiveSettings(p)); }), "'adaptive_check_steps' = -1"));
}

TEST(Adaptive, FallsBackToFullWhereTheSpanCannotTurnTheCloth)
{
  // Six linear modes cannot turn the cloth: `physical` alone ends far from `full`, the adaptive
  // stepper switches to `full` early in the turn and ends close to it.
  Simulation full(topRowHeld(), heldParams(Method::Full, BasisKind::LinearModes));
  Simulation modes(topRowHeld(), heldParams(Method::Physical, BasisKind::LinearModes));
  Simulation adaptive_sim(topRowHeld(), heldParams(Method::Physical, BasisKind::LinearModes));
  AdaptiveSettings settings = stepsOf5ms();
  settings.reduced = Method::Physical;
  settings.tolerance = 0.01;
  AdaptiveStepper adaptive(adaptive_sim, settings);
  run(full, turn, 200);
  run(modes, turn, 200);
  run(adaptive_sim, turn, 200, &adaptive);
  const double modes_distance = largestParticleDistance(modes, full.positions());
  const double adaptive_distance = largestParticleDistance(adaptive_sim, full.positions());
  std::cout << "physical alone " << modes_distance << " m from full, adaptive " << adaptive_distance << " m ("
            << adaptive.reducedShare() * 100 << "% of its steps reduced, " << adaptive.switches()
            << " switches: " << adaptive.lastSwitch() << ")\n";
  EXPECT_GE(adaptive.switches(), 1);
  EXPECT_FALSE(adaptive.reduced());
  EXPECT_TRUE(contains(adaptive.lastSwitch(), "to full at t = ")) << adaptive.lastSwitch();
  EXPECT_TRUE(contains(adaptive.lastSwitch(), "steps taken again under full")) << adaptive.lastSwitch();
  EXPECT_GT(modes_distance, 0.05);
  EXPECT_LT(adaptive_distance, 0.2 * modes_distance);
}

namespace
{
// The steps a fallback took again, from its message ("its last N steps taken again under full").
int stepsTakenAgain(const std::string& message)
{
  const std::string key = "its last ";
  const size_t at = message.find(key);
  return at == std::string::npos ? -1 : std::stoi(message.substr(at + key.size()));
}
}  // namespace

TEST(Adaptive, AFallBackGoesBackToTheLastCheckSafelyWithinTheTolerance)
{
  // The turn that six linear modes cannot follow: the estimate rises over several checks before it
  // crosses the tolerance, so how far back a fallback goes depends on the safe share.
  auto stepsAgain = [](double safe_share, int max_rollback_checks, int max_check_stretch = 1) {
    Simulation sim(topRowHeld(), heldParams(Method::Physical, BasisKind::LinearModes));
    AdaptiveSettings settings = stepsOf5ms();
    settings.reduced = Method::Physical;
    settings.tolerance = 0.01;
    settings.check_steps = 5;
    settings.safe_share = safe_share;
    settings.max_rollback_checks = max_rollback_checks;
    settings.max_check_stretch = max_check_stretch;
    AdaptiveStepper adaptive(sim, settings);
    run(sim, turn, 200, &adaptive);
    EXPECT_GE(adaptive.switches(), 1);
    return stepsTakenAgain(adaptive.lastSwitch());
  };
  EXPECT_EQ(stepsAgain(1.0, 10), 5);     // every passed check is safe: the last one
  EXPECT_GT(stepsAgain(1e-9, 1000), 5);  // no check after the start is: back further
  const int bounded = stepsAgain(1e-9, 2);
  EXPECT_GE(bounded, 5);
  EXPECT_LE(bounded, 10);                // but never more than two checks back
  // Safe checks after the first stretch the steps between them (checks at 5, 10, 20, ...): the turn
  // passes the first two and falls back at the third, 10 steps back.
  EXPECT_EQ(stepsAgain(1.0, 10, 4), 10);
}

// A fallback after safe checks takes its steps again from motions recorded over earlier ones: with
// a push on one of them, it ends where `full` from the last safe check ends.
TEST(Adaptive, AFallBackAfterSafeChecksRetakesTheStepsAsFullTakesThem)
{
  AdaptiveSettings settings = stepsOf5ms();
  settings.reduced = Method::Physical;
  settings.tolerance = 0.01;
  settings.check_steps = 5;
  settings.safe_share = 1.0;  // checks at 5, 10, 20: the turn passes the first two, safely
  Simulation adaptive_sim(topRowHeld(), heldParams(Method::Physical, BasisKind::LinearModes));
  Simulation reference(topRowHeld(), heldParams(Method::Physical, BasisKind::LinearModes));
  AdaptiveStepper adaptive(adaptive_sim, settings);
  const Eigen::VectorXd start = adaptive_sim.handlePositions();
  const Eigen::VectorXd none = Eigen::VectorXd::Zero(adaptive_sim.externalForce().size());
  Eigen::VectorXd push = none;
  push[3 * 95 + 1] = 0.5;  // N on a particle of the bottom row, along y, at step 15
  for (int k = 1; k <= 35; ++k)
  {
    if (k == 11)
      reference.setMethod(Method::Full);  // where the last safe check leaves the reduced method
    for (Simulation* sim : {&adaptive_sim, &reference})
    {
      sim->setHandleMotion(turn(start, k));
      sim->setExternalForce(k == 15 ? push : none);
    }
    ASSERT_FALSE(reference.step().diverged);
    ASSERT_FALSE(adaptive.step().diverged);
  }
  ASSERT_EQ(adaptive.switches(), 1) << adaptive.lastSwitch();
  EXPECT_FALSE(adaptive.reduced());
  EXPECT_EQ(stepsTakenAgain(adaptive.lastSwitch()), 10) << adaptive.lastSwitch();
  EXPECT_LT(largestParticleDistance(adaptive_sim, reference.positions()), 1e-9);
}

TEST(Adaptive, ChecksFarFromASwitchComeLessOften)
{
  // 200 steps, a check every 5 at the least: 40 checks unstretched. Stretched to at most four times
  // from the second reading since the state was set (at 5, 10, 20, 40, 60, ...): 12 checks where
  // every check is far from a switch, 12 under `full` too (its first check falls back, and the
  // stretch starts again: 5, 10, 20, 40, ...).
  auto checks = [](const AdaptiveSettings& settings, BasisKind basis, const Motion& move) {
    Simulation sim(topRowHeld(), heldParams(settings.reduced, basis));
    AdaptiveStepper adaptive(sim, settings);
    run(sim, move, 200, &adaptive);
    return std::make_pair(adaptive.checks(), adaptive.reduced());
  };
  AdaptiveSettings reduced = stepsOf5ms();  // reduced throughout: the skinning span follows the translation
  reduced.reduced = Method::Physical;
  reduced.check_steps = 5;
  AdaptiveSettings full = fullFromTheStart(Method::Physical);  // under `full`, never within 1e-15 m of the span
  full.check_steps = 5;
  // Under `full` within the safe share of the 1 m tolerance of the span, but with a scale (1e15)
  // that puts any indicator above it: the dwell (0.2 s) counts from the check at step 10 without the
  // estimate, then each check reads it and, not back, stretches the next: 5 (the fallback), 10, ...,
  // 50 (9), then 60, 80, ..., 200 (8): 18.
  AdaptiveSettings near = stepsOf5ms();
  near.reduced = Method::Physical;
  near.check_steps = 5;
  near.tolerance = 1.0;
  near.indicator_scale = 1e15;
  for (AdaptiveSettings* settings : {&reduced, &full, &near})
  {
    settings->max_check_stretch = 1;
    EXPECT_EQ(checks(*settings, BasisKind::Skinning, translate), std::make_pair(40, settings == &reduced));
    settings->max_check_stretch = 4;
    EXPECT_EQ(checks(*settings, BasisKind::Skinning, translate),
              std::make_pair(settings == &reduced ? 12 : settings == &full ? 12 : 18, settings == &reduced));
  }
  // Checks within the tolerance but not safely (six linear modes leave a force outside their span
  // on the turn, above 1e-9 of a 10 m tolerance, and within it) do not stretch.
  reduced.tolerance = 10.0;
  reduced.safe_share = 1e-9;
  EXPECT_EQ(checks(reduced, BasisKind::LinearModes, turn), std::make_pair(40, true));
}

TEST(Adaptive, ChecksWithinTheToleranceStretchWhereTheSwingsDriftLeavesTheIndicatorRoom)
{
  // Six linear modes on the turn, checked every 5 steps at the least, with a 10 m tolerance whose
  // safe share (1e-9 of it) the swing's drift (a tenth of the tolerance at the largest swing)
  // exceeds from the second check on (the first never stretches).
  const double largest_swing = largestSwing(BasisKind::LinearModes, turn, 200, 1);
  ASSERT_GT(largest_swing, 1e-3);
  AdaptiveSettings settings = stepsOf5ms();
  settings.reduced = Method::Physical;
  settings.check_steps = 5;
  settings.tolerance = 10.0;
  settings.safe_share = 1e-9;
  settings.swing_drift = 0.1 * settings.tolerance / largest_swing;
  settings.indicator_scale = 1e-30;  // the indicator's part scaled to nothing
  struct Checked
  {
    int checks = 0, switches = 0;
    double largest_estimate = 0.0, smallest_estimate = INFINITY;  // read at the checks after the first
    std::string why;
  };
  auto checked = [](const AdaptiveSettings& with) {
    Simulation sim(topRowHeld(), heldParams(Method::Physical, BasisKind::LinearModes));
    const Eigen::VectorXd start = sim.handlePositions();
    AdaptiveStepper adaptive(sim, with);
    Checked c;
    for (int k = 1; k <= 200 && adaptive.reduced(); ++k)
    {
      sim.setHandleMotion(turn(start, k));
      EXPECT_FALSE(adaptive.step().diverged);
      if (adaptive.checks() > c.checks && adaptive.checks() > 1 && adaptive.reduced())
      {
        c.largest_estimate = std::max(c.largest_estimate, adaptive.lastEstimate());
        c.smallest_estimate = std::min(c.smallest_estimate, adaptive.lastEstimate());
      }
      c.checks = adaptive.checks();
    }
    c.switches = adaptive.switches();
    c.why = adaptive.lastSwitch();
    return c;
  };
  // Within the tolerance but not safely, the indicator's part within the safe share of what the
  // drift leaves: they stretch as safe checks do (5, 10, 20, 40, 60, ...: 12), where before only the
  // safe ones did (40).
  const Checked stretched = checked(settings);
  EXPECT_GT(stretched.smallest_estimate, settings.safe_share * settings.tolerance);
  EXPECT_LE(stretched.largest_estimate, settings.tolerance);
  EXPECT_EQ(stretched.checks, 12);
  EXPECT_EQ(stretched.switches, 0) << stretched.why;
  // A tolerance a quarter above every drift those stretched checks read, below the largest swing's
  // between them: the drift foreseen at the next check (the fastest swing read since the set, for
  // the time until then) reaches it first, the checks come every 5 steps again, and one finds the
  // swing above it, before the unstretched checks would have (40 in all). With the drift read at
  // the check's own time instead, the run takes the stretched checks' course and never switches.
  settings.tolerance = 1.25 * stretched.largest_estimate;
  ASSERT_GT(settings.swing_drift * largest_swing, settings.tolerance);
  const Checked near = checked(settings);
  EXPECT_EQ(near.switches, 1);
  EXPECT_TRUE(contains(near.why, "estimated distance")) << near.why;
  EXPECT_GT(near.checks, 5);  // stretched before (5, 10, 20, 40, 60 at the least)
  EXPECT_LT(near.checks, 40);
}

TEST(Adaptive, StaysReducedWhereTheSpanFollows)
{
  // The skinning span moves the cloth along with its row: every step reduced, the same run as
  // `physical` alone to the bit.
  Simulation physical(topRowHeld(), heldParams(Method::Physical, BasisKind::Skinning));
  Simulation adaptive_sim(topRowHeld(), heldParams(Method::Physical, BasisKind::Skinning));
  AdaptiveSettings settings = stepsOf5ms();
  settings.reduced = Method::Physical;
  AdaptiveStepper adaptive(adaptive_sim, settings);
  run(physical, translate, 200);
  run(adaptive_sim, translate, 200, &adaptive);
  std::cout << "last estimate " << adaptive.lastEstimate() << " m\n";
  EXPECT_EQ(adaptive.switches(), 0) << adaptive.lastSwitch();
  EXPECT_EQ(adaptive.reducedShare(), 1.0);
  EXPECT_EQ(adaptive_sim.positions(), physical.positions());
}

TEST(Adaptive, TheSwingsDriftSendsToFullASwingTheIndicatorAloneWouldKeep)
{
  // The same translation as above, whose indicator never nears the tolerance, checked every
  // check_steps: a drift that puts the largest swing at a check at twice the tolerance sends it to
  // `full`, one that puts it at half does not.
  AdaptiveSettings settings = stepsOf5ms();
  settings.reduced = Method::Physical;
  settings.max_check_stretch = 1;
  const double largest_swing = largestSwing(BasisKind::Skinning, translate, 200, settings.check_steps);
  ASSERT_GT(largest_swing, 0.0);
  auto switchesWithDrift = [&](double drift) {
    Simulation sim(topRowHeld(), heldParams(Method::Physical, BasisKind::Skinning));
    AdaptiveSettings with = settings;
    with.swing_drift = drift;
    AdaptiveStepper adaptive(sim, with);
    run(sim, translate, 200, &adaptive);
    return std::make_pair(adaptive.switches(), adaptive.lastSwitch());
  };
  const auto [kept, none] = switchesWithDrift(0.5 * settings.tolerance / largest_swing);
  EXPECT_EQ(kept, 0) << none;
  const auto [sent, why] = switchesWithDrift(2.0 * settings.tolerance / largest_swing);
  EXPECT_GE(sent, 1);
  EXPECT_TRUE(contains(why, "estimated distance")) << why;
}

namespace
{

// Sends `sim` (six linear modes) to `full` with the turn they cannot follow, and returns settings whose
// tolerance's safe share (a third) is five times the state's distance to their span and the estimate
// their indicator would make there (both swing up and down as the cloth does, the distance to more
// than three times where it was here), with a dwell of 0.1 s.
AdaptiveSettings sentToFullByTheTurn(Simulation& sim)
{
  AdaptiveSettings settings = stepsOf5ms();
  settings.reduced = Method::Physical;
  settings.tolerance = 0.01;
  AdaptiveStepper first(sim, settings);
  run(sim, turn, 100, &first);
  EXPECT_FALSE(first.reduced());
  const double distance = sim.spanDistance(Method::Physical);
  EXPECT_GT(distance, settings.tolerance);
  settings.tolerance = 5.0 / settings.safe_share *
                       std::max(distance, settings.indicator_scale * sim.errorIndicator(Method::Physical));
  settings.dwell = 0.1;
  return settings;
}

}  // namespace

TEST(Adaptive, GoesBackToTheSpanOnceTheStateIsWithinToleranceForTheDwell)
{
  // Held still after the turn: after the dwell it is reduced again, the state carried over (no
  // particle jumps at the switch).
  Simulation sim(topRowHeld(), heldParams(Method::Physical, BasisKind::LinearModes));
  const AdaptiveSettings settings = sentToFullByTheTurn(sim);
  AdaptiveStepper second(sim, settings);
  sim.setMethod(Method::Full);  // the stepper starts reduced: back to where the first one left it
  const Eigen::VectorXd held = sim.handlePositions();
  int switched_at = -1;
  double jump = 0.0;
  for (int k = 1; k <= 100 && switched_at < 0; ++k)
  {
    sim.setHandleMotion(held);
    const Eigen::VectorXd before = sim.positions();
    ASSERT_FALSE(second.step().diverged);
    jump = (sim.positions() - before).cwiseAbs().maxCoeff();
    if (second.reduced())
      switched_at = k;
  }
  ASSERT_GT(switched_at, 0) << "never went back; last distance to the span " << second.lastEstimate() << " m";
  EXPECT_GE(switched_at * 5e-3, settings.dwell - 1e-9);
  EXPECT_TRUE(contains(second.lastSwitch(), "to physical at t = ")) << second.lastSwitch();
  EXPECT_LT(jump, 0.01);  // the step's own motion: the switch moved nothing
}

TEST(Adaptive, GoesBackOnlyWithinTheSafeShareOfTheTolerance)
{
  // The same hold, with the state's distance to the span within the tolerance but not within the
  // (now tiny) safe share of it, then with the distance within the safe share and the estimate not
  // (a scale that puts any indicator above the tolerance): over 100 steps (five times the dwell)
  // `full` keeps it either way.
  auto heldUnder = [](const std::function<void(AdaptiveSettings&)>& change) {
    Simulation sim(topRowHeld(), heldParams(Method::Physical, BasisKind::LinearModes));
    AdaptiveSettings settings = sentToFullByTheTurn(sim);
    change(settings);
    AdaptiveStepper second(sim, settings);
    sim.setMethod(Method::Full);
    const Eigen::VectorXd held = sim.handlePositions();
    for (int k = 1; k <= 100; ++k)
    {
      sim.setHandleMotion(held);
      EXPECT_FALSE(second.step().diverged);
    }
    EXPECT_FALSE(second.reduced()) << second.lastSwitch();
    EXPECT_EQ(second.switches(), 0);
    return std::make_pair(second.lastEstimate(), settings);
  };
  const auto [distance, by_distance] = heldUnder([](AdaptiveSettings& s) {
    s.safe_share = 1e-9;
    s.indicator_scale = 1e-15;
  });
  EXPECT_LE(distance, by_distance.tolerance);
  const auto [close, by_estimate] = heldUnder([](AdaptiveSettings& s) { s.indicator_scale = 1e15; });
  EXPECT_LE(close, by_estimate.safe_share * by_estimate.tolerance);
}

// A return whose fallback takes every reduced step since it again kept nothing: the dwell before
// the next doubles (its reason counts such returns in a row), whichever check fell back. The coarse
// grid held still after the turn leaves the state within its first check, or within its second.
TEST(Adaptive, AReturnThatKeepsNoReducedStepDoublesTheDwell)
{
  SimulationParams params = heldParams(Method::Coarse, BasisKind::LinearModes);
  params.coarse_cols = 4;
  Simulation sim(topRowHeld(), params);
  AdaptiveSettings settings = stepsOf5ms();
  settings.reduced = Method::Coarse;
  settings.indicator_scale = indicatorScale(Method::Coarse);
  settings.tolerance = 0.01;
  settings.dwell = 0.1;
  AdaptiveStepper adaptive(sim, settings);
  const Eigen::VectorXd start = sim.handlePositions();
  int switches = 0, returned_at = -1, futile_in_a_row = 0;
  bool passed_a_check = false;  // one of the futile returns in a row fell back after passing a check
  int returns_after_such = 0;
  for (int k = 1; k <= 1400; ++k)
  {
    sim.setHandleMotion(turn(start, k));
    ASSERT_FALSE(adaptive.step().diverged) << "step " << k;
    if (adaptive.switches() == switches)
      continue;
    switches = adaptive.switches();
    const std::string& why = adaptive.lastSwitch();
    if (adaptive.reduced())
    {
      const double dwell = settings.dwell * std::pow(2.0, futile_in_a_row);
      const double within = std::stod(why.substr(why.find(" for ") + 5));
      EXPECT_GE(within, dwell - 1e-9) << why;
      EXPECT_EQ(contains(why, "(" + std::to_string(futile_in_a_row) + " return"), futile_in_a_row > 0) << why;
      returns_after_such += passed_a_check ? 1 : 0;
      returned_at = k;
      continue;
    }
    if (returned_at < 0)
      continue;  // the first fallback, from the start
    const bool futile = stepsTakenAgain(why) == k - returned_at;
    futile_in_a_row = futile ? futile_in_a_row + 1 : 0;
    passed_a_check = futile && (passed_a_check || k - returned_at > settings.check_steps);
  }
  EXPECT_GE(returns_after_such, 1);
}

// A fall back takes its steps again with the external force each had: a push on one step of the
// window is neither lost (the checkpoint's force is none) nor repeated on every step.
TEST(Adaptive, AFallBackRetakesEachStepWithItsExternalForce)
{
  Simulation full(topRowHeld(), heldParams(Method::Full, BasisKind::LinearModes));
  Simulation unpushed(topRowHeld(), heldParams(Method::Full, BasisKind::LinearModes));
  Simulation adaptive_sim(topRowHeld(), heldParams(Method::Physical, BasisKind::LinearModes));
  AdaptiveStepper adaptive(adaptive_sim, fullFromTheStart(Method::Physical));
  const Eigen::VectorXd none = Eigen::VectorXd::Zero(full.externalForce().size());
  Eigen::VectorXd push = none;
  push[3 * 95 + 1] = 0.5;  // N on a particle of the bottom row, along y
  for (int k = 1; k <= 20; ++k)
  {
    const Eigen::VectorXd& force = k == 3 ? push : none;
    full.setExternalForce(force);
    adaptive_sim.setExternalForce(force);
    ASSERT_FALSE(full.step().diverged);
    ASSERT_FALSE(unpushed.step().diverged);
    ASSERT_FALSE(adaptive.step().diverged);
  }
  EXPECT_EQ(adaptive.reducedShare(), 0.0);
  EXPECT_GT(largestParticleDistance(full, unpushed.positions()), 1e-3) << "the push must move the cloth";
  EXPECT_LT(largestParticleDistance(adaptive_sim, full.positions()), 1e-9);
}

// Under the implicit scheme too, with the handles turning the cloth: the steps taken again carry the
// integrator on from step to step as `full` does (setting an unchanged external force again would
// start it afresh at each step, from the state's forces alone).
TEST(Adaptive, AnImplicitFallBackRetakesTheStepsAsFullTakesThem)
{
  Simulation full(topRowHeld(), heldParams(Method::Full, BasisKind::LinearModes));
  Simulation adaptive_sim(topRowHeld(), heldParams(Method::Physical, BasisKind::LinearModes));
  AdaptiveStepper adaptive(adaptive_sim, fullFromTheStart(Method::Physical));
  run(full, turn, 60);
  run(adaptive_sim, turn, 60, &adaptive);
  EXPECT_EQ(adaptive.reducedShare(), 0.0);
  EXPECT_LT(largestParticleDistance(adaptive_sim, full.positions()), 1e-9);
}

// `coarse` as the reduced method. Its indicator sees what the grid's springs leave unbalanced at
// the interpolated positions, not how its swing differs from the grid's (docs/results.md): zero at
// rest, where the start keeps what the interpolation misses. With a tolerance below its estimate
// 0.1 s into the turn the stepper falls back at its first check and follows `full` from there; on
// the grid's own columns nothing is outside the span, and it never leaves `coarse`.
TEST(Adaptive, FallsBackFromACoarseGridAndStaysOnTheGridsOwn)
{
  auto heldCoarse = [](int coarse_cols) {
    SimulationParams s = heldParams(Method::Coarse, BasisKind::LinearModes);
    s.coarse_cols = coarse_cols;
    return s;
  };
  Simulation full(topRowHeld(), heldParams(Method::Full, BasisKind::LinearModes));
  Simulation coarse(topRowHeld(), heldCoarse(4));
  Simulation adaptive_sim(topRowHeld(), heldCoarse(4));
  Simulation same_sim(topRowHeld(), heldCoarse(10));
  AdaptiveSettings settings = stepsOf5ms();
  settings.reduced = Method::Coarse;
  settings.indicator_scale = indicatorScale(Method::Coarse);
  EXPECT_LT(coarse.errorIndicator(), 1e-9);
  run(coarse, turn, settings.check_steps);
  const double at_first_check = settings.indicator_scale * coarse.errorIndicator();
  ASSERT_GT(at_first_check, 1e-4);
  settings.tolerance = 0.5 * at_first_check;
  AdaptiveStepper adaptive(adaptive_sim, settings);
  AdaptiveStepper same(same_sim, settings);
  run(full, turn, 200);
  coarse.reset();
  run(coarse, turn, 200);
  run(adaptive_sim, turn, 200, &adaptive);
  run(same_sim, turn, 200, &same);
  const double coarse_distance = largestParticleDistance(coarse, full.positions());
  const double adaptive_distance = largestParticleDistance(adaptive_sim, full.positions());
  std::cout << "estimate at the first check " << at_first_check << " m; coarse alone " << coarse_distance << " m from full, adaptive "
            << adaptive_distance << " m (" << adaptive.reducedShare() * 100 << "% of its steps reduced: "
            << adaptive.lastSwitch() << ")\n";
  EXPECT_EQ(adaptive.switches(), 1);
  EXPECT_EQ(adaptive.reducedShare(), 0.0);
  EXPECT_TRUE(contains(adaptive.lastSwitch(), "to full at t = 0.1 s")) << adaptive.lastSwitch();
  EXPECT_GT(coarse_distance, 0.03);
  EXPECT_LT(adaptive_distance, 0.1 * coarse_distance);
  EXPECT_EQ(same.switches(), 0) << same.lastSwitch();
  EXPECT_EQ(same.reducedShare(), 1.0);
  EXPECT_LT(largestParticleDistance(same_sim, full.positions()), 1e-9);
}

// A coarse grid cannot bend round a table's edge: a sheet dropped flat half over a box hangs over
// its edge, and its particles between the coarse ones cut into the box. Whatever the tolerance, the
// stepper falls back once a particle is further inside than the contact thickness, and `full` keeps
// them out.
TEST(Adaptive, FallsBackWhereTheCoarseGridCutsIntoACollider)
{
  GridParams g = clothSheet(13);
  g.rotation_deg = 90.0;  // lying flat
  const Eigen::Matrix3Xd start = Grid(g).toPoints(Grid(g).initialPositions());
  Collider box;
  box.type = ColliderType::Box;
  const double edge = 0.5 * (start.row(1).minCoeff() + start.row(1).maxCoeff()) + 0.01;  // between particles
  box.half_extents = Eigen::Vector3d(1.0, 0.5, 0.5);
  box.center = Eigen::Vector3d(start.row(0).mean(), edge - 0.5, start.row(2).minCoeff() - 0.02 - 0.5);
  SimulationParams s = methodParams(Method::Coarse, 4, 5e-4);
  s.alpha = 0.5;
  s.coarse_cols = 4;
  s.colliders = {box};
  Simulation coarse(g, s);
  Simulation adaptive_sim(g, s);
  AdaptiveSettings settings = stepsOf5ms();
  settings.reduced = Method::Coarse;
  settings.indicator_scale = indicatorScale(Method::Coarse);
  settings.tolerance = 1.0;  // the estimate never decides
  AdaptiveStepper adaptive(adaptive_sim, settings);
  const double thickness = coarse.contact()->thickness();
  double coarse_deepest = 0.0, adaptive_deepest_after = 0.0;
  for (int k = 1; k <= 2000; ++k)
  {
    ASSERT_FALSE(coarse.step().diverged) << "step " << k;
    ASSERT_FALSE(adaptive.step().diverged) << "step " << k;
    coarse_deepest = std::max(coarse_deepest, deepestInside(coarse.grid(), coarse.points(), *coarse.contact()));
    if (!adaptive.reduced())
      adaptive_deepest_after =
          std::max(adaptive_deepest_after, deepestInside(adaptive_sim.grid(), adaptive_sim.points(), *adaptive_sim.contact()));
  }
  std::cout << "coarse alone " << coarse_deepest << " m deep at most; adaptive: " << adaptive.lastSwitch()
            << "; under full " << adaptive_deepest_after << " m\n";
  EXPECT_GT(coarse_deepest, 2.0 * thickness) << "the coarse grid must cut into the box for the test to mean anything";
  EXPECT_GE(adaptive.switches(), 1);
  EXPECT_TRUE(contains(adaptive.lastSwitch(), "inside a collider, deeper than the contact thickness")) << adaptive.lastSwitch();
  EXPECT_LT(adaptive_deepest_after, thickness);
}

// A fall back onto a table takes its steps again as `full` takes them, under either scheme: the
// colliders' poses it replays leave the contact as it was.
TEST(Adaptive, AFallBackOntoATableRetakesTheStepsAsFullTakesThem)
{
  for (IntegratorKind integrator : {IntegratorKind::Explicit, IntegratorKind::Implicit})
  {
    GridParams g = clothSheet(10);
    g.rotation_deg = 90.0;  // lying flat
    SimulationParams s = methodParams(Method::Full, 4, 1e-3, integrator);
    s.alpha = 0.5;
    s.colliders = {tableBelow(g, 0.01)};
    Simulation full(g, s);
    s.method = Method::Coarse;
    s.coarse_cols = 4;
    Simulation adaptive_sim(g, s);
    AdaptiveStepper adaptive(adaptive_sim, fullFromTheStart(Method::Coarse));
    for (int k = 1; k <= 200; ++k)
    {
      ASSERT_FALSE(full.step().diverged);
      ASSERT_FALSE(adaptive.step().diverged);
    }
    EXPECT_EQ(adaptive.reducedShare(), 0.0);
    ASSERT_GT(full.contact()->report().touching[0], 0) << "the cloth must reach the table for the test to mean anything";
    EXPECT_LT(largestParticleDistance(adaptive_sim, full.positions()), 1e-9) << toString(integrator);
  }
}

// A step too long for the coarse grid's explicit integrator: with a drive the stepper takes it again
// under `full` from its checkpoint, as it takes a failed check's steps; `full` then follows the turn
// as if it had run alone.
TEST(Adaptive, AReducedStepThatDivergesIsTakenAgainUnderFull)
{
  const int span = 40;  // 0.2 s: the coarse grid's explicit step diverges within a few, `full`'s 5 ms does not
  auto params = [](Method method) {
    SimulationParams s = heldParams(method, BasisKind::LinearModes);
    s.integrator = IntegratorKind::Explicit;
    s.coarse_cols = 4;
    s.time_step = 5e-3;
    return s;
  };
  int diverges_at = 0;  // the coarse grid's steps up to the one that diverges
  {
    Simulation alone(topRowHeld(), params(Method::Coarse));
    alone.setStepSpan(span);
    const Drive drive = driveTurn(alone.handlePositions());
    for (bool diverged = false; !diverged && diverges_at < 10; ++diverges_at)
    {
      drive(alone);
      diverged = alone.step().diverged;
    }
  }
  const int steps = 200;
  ASSERT_LE(diverges_at * span, steps) << "the coarse grid must diverge within the run for the test to mean anything";
  Simulation full(topRowHeld(), params(Method::Full));
  const Drive full_drive = driveTurn(full.handlePositions());
  for (int k = 0; k < steps; ++k)
  {
    full_drive(full);
    ASSERT_FALSE(full.step().diverged);
  }
  Simulation sim(topRowHeld(), params(Method::Coarse));
  AdaptiveSettings settings = stepsOf5ms();
  settings.reduced = Method::Coarse;
  settings.tolerance = 1e9;      // no estimate sends it to `full`
  settings.check_steps = 10000;  // nor a check: the checkpoint stays the start
  settings.reduced_step_span = span;
  AdaptiveStepper adaptive(sim, settings, driveTurn(sim.handlePositions()));
  while (sim.stepCount() < steps)
  {
    const StepResult result = adaptive.step();
    ASSERT_FALSE(result.diverged) << result.message;
  }
  EXPECT_EQ(adaptive.switches(), 1);
  EXPECT_FALSE(adaptive.reduced());
  EXPECT_EQ(adaptive.reducedShare(), 0.0);
  EXPECT_TRUE(contains(adaptive.lastSwitch(), "its coarse step of 0.2 s from there diverged")) << adaptive.lastSwitch();
  EXPECT_TRUE(contains(adaptive.lastSwitch(), "its last " + std::to_string(diverges_at * span) + " steps taken again"))
      << adaptive.lastSwitch();
  EXPECT_DOUBLE_EQ(sim.time(), steps * 5e-3);
  EXPECT_LT(largestParticleDistance(sim, full.positions()), 1e-9);
  // Without a drive (and so one time step a step, here of 0.2 s) the step the caller set is
  // returned as it diverged.
  SimulationParams long_steps = params(Method::Coarse);
  long_steps.time_step = span * 5e-3;
  Simulation undriven(topRowHeld(), long_steps);
  settings.reduced_step_span = 1;
  AdaptiveStepper recording(undriven, settings);
  const Eigen::VectorXd start = undriven.handlePositions();
  bool diverged = false;
  for (int k = 1; k <= 10 && !diverged; ++k)
  {
    undriven.setHandleMotion(turn(start, span * k));
    diverged = recording.step().diverged;
  }
  EXPECT_TRUE(diverged);
  EXPECT_EQ(recording.switches(), 0);
  EXPECT_TRUE(recording.reduced());
}

// `coarse` at its own step: each reduced step takes reduced_step_span time steps, driven at its end
// and ending on a multiple of the span. Where it stays reduced the run is the coarse grid's alone at
// that larger step; a fallback takes each time step again under `full`, as `full` takes them.
TEST(Adaptive, AReducedStepTakesSeveralTimeStepsOnFullsClock)
{
  const int span = 3;
  auto params = [](Method method, double time_step) {
    SimulationParams s = heldParams(method, BasisKind::LinearModes);
    s.coarse_cols = 4;
    s.time_step = time_step;
    return s;
  };
  Simulation alone(topRowHeld(), params(Method::Coarse, span * 5e-3));
  const Drive alone_drive = driveTurn(alone.handlePositions());
  for (int k = 0; k < 66; ++k)
  {
    alone_drive(alone);
    ASSERT_FALSE(alone.step().diverged);
  }
  Simulation full(topRowHeld(), params(Method::Full, 5e-3));
  const Drive full_drive = driveTurn(full.handlePositions());
  for (int k = 0; k < 198; ++k)
  {
    full_drive(full);
    ASSERT_FALSE(full.step().diverged);
  }
  for (const bool falls_back : {false, true})
  {
    Simulation sim(topRowHeld(), params(Method::Coarse, 5e-3));
    AdaptiveSettings settings = falls_back ? fullFromTheStart(Method::Coarse) : stepsOf5ms();
    settings.reduced = Method::Coarse;
    if (!falls_back)
      settings.tolerance = 1.0;
    settings.reduced_step_span = span;
    AdaptiveStepper adaptive(sim, settings, driveTurn(sim.handlePositions()));
    while (sim.stepCount() < 198)
    {
      const bool was_reduced = adaptive.reduced();
      ASSERT_FALSE(adaptive.step().diverged);
      if (was_reduced && adaptive.reduced())
      {
        ASSERT_EQ(sim.stepCount() % span, 0);
      }
    }
    EXPECT_DOUBLE_EQ(sim.time(), 198 * 5e-3);
    if (falls_back)
    {
      // The first check, at 21 time steps (7 reduced steps), goes back to the start.
      EXPECT_EQ(adaptive.reducedShare(), 0.0);
      EXPECT_TRUE(contains(adaptive.lastSwitch(), "its last 21 steps taken again")) << adaptive.lastSwitch();
      EXPECT_LT(largestParticleDistance(sim, full.positions()), 1e-9);
    }
    else
    {
      EXPECT_EQ(adaptive.switches(), 0) << adaptive.lastSwitch();
      EXPECT_EQ(adaptive.reducedShare(), 1.0);
      EXPECT_LT(largestParticleDistance(sim, alone.positions()), 1e-12);
      // and not `full`'s: the coarse grid does not follow the turn.
      EXPECT_GT(largestParticleDistance(sim, full.positions()), 1e-3);
    }
  }
  // Back and forth (the coarse grid held still after the turn, as in the dwell's test): every
  // reduced step ends on a multiple of the span, and a fallback from a return retakes, a time step
  // at a time, the steps since the return at most.
  {
    Simulation sim(topRowHeld(), params(Method::Coarse, 5e-3));
    AdaptiveSettings settings = stepsOf5ms();
    settings.reduced = Method::Coarse;
    settings.tolerance = 0.01;
    settings.dwell = 0.1;
    settings.reduced_step_span = span;
    AdaptiveStepper adaptive(sim, settings, driveTurn(sim.handlePositions()));
    int switches = 0, returns = 0, fallbacks_after_a_return = 0;
    long returned_at = -1;
    while (sim.stepCount() < 1400)
    {
      const bool was_reduced = adaptive.reduced();
      ASSERT_FALSE(adaptive.step().diverged);
      if (was_reduced && adaptive.reduced())
      {
        ASSERT_EQ(sim.stepCount() % span, 0);
      }
      if (adaptive.switches() == switches)
        continue;
      switches = adaptive.switches();
      if (adaptive.reduced())
      {
        ++returns;
        returned_at = sim.stepCount();
      }
      else if (returned_at >= 0)
      {
        ++fallbacks_after_a_return;
        EXPECT_LE(stepsTakenAgain(adaptive.lastSwitch()), sim.stepCount() - returned_at) << adaptive.lastSwitch();
        EXPECT_GT(stepsTakenAgain(adaptive.lastSwitch()), 0) << adaptive.lastSwitch();
      }
    }
    EXPECT_GE(returns, 1);
    EXPECT_GE(fallbacks_after_a_return, 1);
    EXPECT_GT(adaptive.reducedShare(), 0.0);
    EXPECT_LT(adaptive.reducedShare(), 1.0);
  }
  // Reduced from a time step between multiples of the span, as a return may be: a shorter step to
  // the next multiple first.
  Simulation late(topRowHeld(), params(Method::Coarse, 5e-3));
  late.step();
  AdaptiveSettings settings = stepsOf5ms();
  settings.reduced = Method::Coarse;
  settings.tolerance = 1.0;
  settings.reduced_step_span = span;
  AdaptiveStepper adaptive(late, settings, driveTurn(late.handlePositions()));
  ASSERT_FALSE(adaptive.step().diverged);
  EXPECT_EQ(late.stepCount(), 3);
  ASSERT_FALSE(adaptive.step().diverged);
  EXPECT_EQ(late.stepCount(), 6);
}
