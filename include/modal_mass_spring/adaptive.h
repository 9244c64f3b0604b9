// A reduced method that falls back to `full` where its span cannot follow the motion (after Kim and
// James 2009): every check_steps time steps (up to max_check_stretch times as many far from a
// switch, as AdaptiveSettings::max_check_stretch says; the reduced method may take several at once,
// reduced_step_span), a reduced step's error estimate (errorEstimate: its indicator calibrated, plus
// the swing's drift) decides whether the motion is still within `tolerance` of `full`, and whether a
// particle is further inside a collider than the contact thickness (a span too coarse to bend round a
// table's edge); if not, the steps since the last check that was safely within it (a third of
// `tolerance`, at most max_rollback_checks checks back) are taken again under `full`, a time step at
// a time, from the state saved there (with the handle and collider motions they had, or as the Drive
// sets them again), so that the error that grew before the check found it is not carried into
// `full`. Under `full`, it switches back once the state has stayed safely within
// `tolerance` of the reduced span (Simulation::spanDistance) for `dwell` seconds (twice as long after
// each return in a row whose fallback took every reduced step since it again, up to 64 times),
// touching no collider, and an estimate for that span, read then, is safely within it too (else the
// first check, a check later, after the reduced method has drifted, would send it back); the part
// outside the span is then kept frozen, as every switch does (Simulation::setMethod), and a frozen
// part dragged along a collider would go into it.
#pragma once

#include "modal_mass_spring/options.h"
#include "modal_mass_spring/simulation.h"

#include <Eigen/Geometry>

#include <functional>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

namespace modal_mass_spring
{

// Its defaults are SimulationParams's: adaptiveSettings(SimulationParams{}).
struct AdaptiveSettings
{
  Method reduced;    // the reduced method it steps where it may
  double tolerance;  // m, the RMS distance to `full` it accepts
  double dwell;      // s within safe_share of the tolerance of the span before it goes back
  int check_steps;   // steps between two checks
  // The estimate is the largest indicator since the state was set times indicator_scale, plus
  // swing_drift times the swing since then (errorEstimate; indicatorScale(reduced), swingDrift(reduced)).
  double indicator_scale;
  double swing_drift;
  // A fallback goes back to the last check whose estimate was within this share of the tolerance:
  // the distance grows before the indicator shows it (docs/results.md, "The adaptive method"). A
  // return asks the same of the state's distance to the span and of the estimate at the state.
  double safe_share = 1.0 / 3.0;
  // And never more checks back than this: the motions kept are bounded (by this many stretched
  // intervals, since checks within the tolerance but not safely can be stretched too).
  int max_rollback_checks = 10;
  // A check far from a switch (reduced: not the first since the state was set, which tells nothing
  // of how fast the estimate grows, and either within safe_share of the tolerance or within the
  // tolerance with the indicator's part within safe_share of what the swing's drift, foreseen at the
  // next check from the fastest swing read since the set, leaves of it; `full`: the state's
  // distance to the span above safe_share of the tolerance, or touching a collider, so no dwell
  // counts, or, once the dwell is over, the estimate there above safe_share of it) doubles the steps
  // to the next, up to this many times check_steps; any other check, and a switch, resets them to
  // check_steps.
  int max_check_stretch = 4;
  // The time steps one reduced step takes (Simulation::setStepSpan): `coarse` at its own step,
  // coarseStepMultiple. Above 1 it needs a Drive; its steps end on multiples of it (stepCount()),
  // so that a caller sampling every so many of them finds none half taken.
  int reduced_step_span = 1;
};

// Hands `sim` the motion of its handles (and of whatever else the caller moves) at the end of its
// next step, Simulation::nextStepTime(). An AdaptiveStepper given one calls it
// before every step it takes, those a fallback takes again included, instead of recording what the
// caller set.
using Drive = std::function<void(Simulation& sim)>;

// The error indicator's calibration for method `reduced`: the distance to `full` it stands for per
// unit of the largest Simulation::errorIndicator since the state was set (IndicatorMaximum).
double indicatorScale(Method reduced);
// How far the reduced method's swing drifts from `full`'s per metre the particles swing
// (swingDistance): `coarse`'s lowest frequencies are not the grid's, so the two swings run out of
// phase. 0 for the modal methods: not fitted, their indicator alone ranks above the target.
double swingDrift(Method reduced);
// How far the free particles have swung since the state was set whole (m): their speed less a rigid
// motion (Simulation::deformationSpeed) times the time since the set, as the mass damping
// remembers it: a driven or decaying swing forgets where it started at the rate alpha / 2, so the
// time counts up to 2 / alpha at most.
double swingDistance(const Simulation& sim);
// The estimated distance to `full` (m) of `sim`'s reduced state: scale times the largest indicator
// since the state was set, plus drift times swingDistance(sim) (none on a coarse grid that is the
// grid itself).
double errorEstimate(const Simulation& sim, double largest_indicator, double scale, double drift);
// The same with the calibration of `sim`'s own method (indicatorScale, swingDrift).
double errorEstimate(const Simulation& sim, double largest_indicator);

// The largest error indicator read from a simulation since its state was last set whole
// (Simulation::stateSets): the force outside the span comes and goes with the swing, what it did to
// the motion stays (docs/results.md, "The largest since the state was set whole"). Each reader keeps
// its own, so that how often one reads does not change what another sees.
class IndicatorMaximum
{
public:
  // Takes `value`, read from `sim`'s current state, and returns the largest since that state was set
  // (a value that is not finite is returned as it is).
  double operator()(const Simulation& sim, double value);

private:
  long sets_ = -1;
  double largest_ = 0.0;
};

// The settings a simulation's parameters give (adaptive_method, error_tolerance, adaptive_dwell,
// adaptive_check_steps, 0 resolved to the steps of kAdaptiveCheckPeriod at time_step).
AdaptiveSettings adaptiveSettings(const SimulationParams& params);

// Throws std::invalid_argument naming a setting out of its range: a tolerance not positive and
// finite, a dwell negative or not finite, check_steps < 1, a reduced method that is `full` or
// `linear` (whose forces do not see the span's error), an indicator_scale not positive, a swing_drift
// negative or not finite, a safe_share outside (0, 1], max_rollback_checks, max_check_stretch or
// reduced_step_span < 1.
void validateAdaptiveSettings(const AdaptiveSettings& settings);

class AdaptiveStepper
{
public:
  // Puts `sim` in the reduced method (building its basis, or training its cubature, if needed).
  // Without a drive the caller sets each step's motion before step(), and the stepper records it;
  // a reduced_step_span above 1 is then refused (std::invalid_argument).
  AdaptiveStepper(Simulation& sim, const AdaptiveSettings& settings, Drive drive = {});
  // One step of the active method (with a drive: driven first; reduced: up to the next multiple of
  // reduced_step_span time steps), then the check when one is due (and the switch it calls for).
  // With a drive, a reduced step that diverges switches to `full` as a failed check does, and its
  // time steps are taken again with the others since the checkpoint; without one, it is returned.
  StepResult step();
  bool reduced() const { return sim_.method() != Method::Full; }
  // The share of the steps taken so far in the reduced method, the switches, the checks, the last check's
  // estimate (m: errorEstimate while reduced, the distance to the span under full).
  double reducedShare() const { return steps_ > 0 ? static_cast<double>(reduced_steps_) / steps_ : 1.0; }
  int switches() const { return switches_; }
  int checks() const { return checks_; }
  double lastEstimate() const { return last_estimate_; }
  // Why the last switch happened (empty before the first).
  const std::string& lastSwitch() const { return last_switch_; }

private:
  // What the caller gave a step: the handles' motion, B's, the colliders' poses, the external force
  // (shared between the steps it did not change in: a copy a step costs more than a coarse step).
  struct Motion
  {
    HandleMotion handles;
    FrameMotion frame;
    std::vector<Eigen::Isometry3d> colliders;
    std::vector<bool> active;
    std::shared_ptr<const Eigen::VectorXd> external_force;
  };
  // Records the motion of the step just taken (since_check_).
  void record();
  // At a checkpoint: no step since is needed any more (their external forces let go).
  void forgetMotions();
  // The state now is the checkpoint a fallback goes back to.
  void setCheckpoint();
  void apply(const Motion& m);
  // Back to the checkpoint, then the steps since again under `full` (with a drive, up to step count
  // `until`; without one, those recorded).
  StepResult fallBack(std::ostringstream& why, long until);
  // A fallback, counted as a switch for `why`, and the next check scheduled from it.
  StepResult toFull(std::ostringstream& why, long until);
  StepResult check();
  // The time within the safe share of the tolerance before a return: `dwell`, doubled (from a check
  // period at least) for each return in a row that kept no reduced step (its fallback took them all
  // again): a coarse grid left within its span drifts to its own hanging shape within a check or
  // two, and going back and forth costs both methods' steps.
  double dwell() const;
  // The next check after this one: `far` from a switch, twice as many steps as the last time (up to
  // the stretch), else check_steps.
  void scheduleNextCheck(bool far);
  long stretchedCheckInterval() const;  // twice the last interval, up to max_check_stretch times check_steps
  // How deep the particle deepest inside a collider is (m; 0: none, or no colliders).
  double insideColliders() const;
  // Whether a particle touched a collider in the last step.
  bool touching() const;

  Simulation& sim_;
  AdaptiveSettings settings_;
  Drive drive_;
  long steps_ = 0, reduced_steps_ = 0;  // time steps
  int switches_ = 0, checks_ = 0;
  double last_estimate_ = 0.0;
  // Under full: the time the state came within safe_share of the tolerance of the span (-1: not).
  double within_since_ = -1.0;
  std::string last_switch_;
  SimulationState checkpoint_;       // the reduced state at the last safe check
  // The motions of the reduced steps since: the first recorded_, the storage kept for the next
  // (at most max_rollback_checks intervals of max_check_stretch times check_steps) until a fallback.
  std::vector<Motion> since_check_;
  size_t recorded_ = 0;
  int checks_since_ = 0;             // checks passed since it
  long check_interval_ = 0;          // steps from a check to the next: check_steps, up to max_check_stretch times it
  long next_check_ = 0;              // the step count at which the next check is due
  bool at_return_ = false;           // the checkpoint is still the state a return to the reduced method set
  int futile_returns_ = 0;           // returns in a row whose fallback took every reduced step again
  long sets_checked_ = -1;           // Simulation::stateSets() at the last check while reduced
  // The swing's drift per remembered second (m/s): the fastest read at a check since the state was set.
  double drift_rate_ = 0.0;
  static constexpr int kMaxBackOff = 6;
  Eigen::VectorXd handle_reference_;  // the handle dofs' positions at zero displacement
  // The external force the simulation holds (the last motion kept, or the last applied), and
  // Simulation::externalForceChanges() then.
  std::shared_ptr<const Eigen::VectorXd> recorded_force_;
  long recorded_force_changes_ = -1;
  IndicatorMaximum indicator_max_;  // of the checks' readings
};

}  // namespace modal_mass_spring
