#include "modal_mass_spring/adaptive.h"

#include "modal_mass_spring/parameter_error.h"

#include <algorithm>
#include <cmath>
#include <sstream>

namespace modal_mass_spring
{

double indicatorScale(Method reduced)
{
  // The median ratio of the distance to `full` to the indicator (its largest since the state was set)
  // over the shipped scenarios (docs/results.md, "The largest since the state was set whole").
  switch (reduced)
  {
    case Method::Coarse:
      return 50.0;
    case Method::Cubature:
      return 19.0;
    default:
      return 14.0;
  }
}

double swingDrift(Method reduced)
{
  // Fitted on the shipped scenarios with the scale above kept (docs/results.md, "The swing's drift").
  return reduced == Method::Coarse ? 0.02 : 0.0;
}

namespace
{
// Time t (s) since the state was set as the mass damping alpha remembers it (swingDistance).
double rememberedTime(double alpha, double t) { return alpha > 0.0 ? -std::expm1(-0.5 * alpha * t) * 2.0 / alpha : t; }
}  // namespace

double swingDistance(const Simulation& sim)
{
  return sim.deformationSpeed() * rememberedTime(sim.params().alpha, sim.timeSinceStateSet());
}

double errorEstimate(const Simulation& sim, double largest_indicator, double scale, double drift)
{
  // A coarse grid that is the grid itself swings as the grid does.
  const Grid* coarse = sim.method() == Method::Coarse ? sim.coarseGrid() : nullptr;
  if (coarse && coarse->numParticles() == sim.grid().numParticles())
    drift = 0.0;
  return scale * largest_indicator + (drift > 0.0 ? drift * swingDistance(sim) : 0.0);
}

double errorEstimate(const Simulation& sim, double largest_indicator)
{
  return errorEstimate(sim, largest_indicator, indicatorScale(sim.method()), swingDrift(sim.method()));
}

double IndicatorMaximum::operator()(const Simulation& sim, double value)
{
  if (sim.stateSets() != sets_)
  {
    sets_ = sim.stateSets();
    largest_ = 0.0;
  }
  if (!std::isfinite(value))
    return value;
  largest_ = std::max(largest_, value);
  return largest_;
}

AdaptiveSettings adaptiveSettings(const SimulationParams& p)
{
  AdaptiveSettings s;
  s.reduced = p.adaptive_method;
  s.tolerance = p.error_tolerance;
  s.dwell = p.adaptive_dwell;
  s.check_steps = p.adaptive_check_steps;
  if (s.check_steps == 0)
    s.check_steps = p.time_step > 0.0 ? std::max(1, static_cast<int>(std::lround(kAdaptiveCheckPeriod / p.time_step))) : 1;
  s.indicator_scale = indicatorScale(p.adaptive_method);
  s.swing_drift = swingDrift(p.adaptive_method);
  return s;
}

void validateAdaptiveSettings(const AdaptiveSettings& s)
{
  if (!std::isfinite(s.tolerance) || s.tolerance <= 0.0)
    rejectParameter("error_tolerance", s.tolerance, "must be a finite number > 0 (m, the RMS distance to full accepted)");
  if (!std::isfinite(s.dwell) || s.dwell < 0.0)
    rejectParameter("adaptive_dwell", s.dwell, "must be a finite number >= 0 (s)");
  if (s.check_steps < 1)
  {
    std::ostringstream allowed;
    allowed << "must be an integer >= 1 (in the parameters also 0: every " << kAdaptiveCheckPeriod
            << " s of simulated time)";
    rejectParameter("adaptive_check_steps", s.check_steps, allowed.str());
  }
  if (s.reduced != Method::Physical && s.reduced != Method::Cubature && s.reduced != Method::Coarse)
    rejectParameter("adaptive_method", "'" + toString(s.reduced) + "'", "must be one of physical, cubature, coarse");
  if (!std::isfinite(s.indicator_scale) || s.indicator_scale <= 0.0)
    rejectParameter("indicator_scale", s.indicator_scale, "must be a finite number > 0");
  if (!std::isfinite(s.swing_drift) || s.swing_drift < 0.0)
    rejectParameter("swing_drift", s.swing_drift, "must be a finite number >= 0");
  if (!(s.safe_share > 0.0 && s.safe_share <= 1.0))
    rejectParameter("safe_share", s.safe_share, "must be in (0, 1]");
  if (s.max_rollback_checks < 1)
    rejectParameter("max_rollback_checks", s.max_rollback_checks, "must be an integer >= 1");
  if (s.max_check_stretch < 1)
    rejectParameter("max_check_stretch", s.max_check_stretch, "must be an integer >= 1");
  if (s.reduced_step_span < 1)
    rejectParameter("reduced_step_span", s.reduced_step_span, "must be an integer >= 1 (time steps)");
}

AdaptiveStepper::AdaptiveStepper(Simulation& sim, const AdaptiveSettings& settings, Drive drive)
  : sim_(sim), settings_(settings), drive_(std::move(drive))
{
  validateAdaptiveSettings(settings_);
  if (settings_.reduced_step_span > 1 && !drive_)
    rejectParameter("reduced_step_span", settings_.reduced_step_span,
                    "must be 1 without a drive: a fallback takes each time step again with its own motion");
  if (sim_.method() != settings_.reduced)
    sim_.setMethod(settings_.reduced);
  sim_.errorIndicator();  // built with the rest of the setup, not in the first check's step
  handle_reference_ = sim_.handlePositions();
  if (sim_.handleMotion().displacement.size() > 0)
    handle_reference_ -= sim_.handleMotion().displacement;
  setCheckpoint();
  scheduleNextCheck(false);
}

void AdaptiveStepper::record()
{
  if (!recorded_force_ || recorded_force_changes_ != sim_.externalForceChanges())
  {
    recorded_force_ = std::make_shared<const Eigen::VectorXd>(sim_.externalForce());
    recorded_force_changes_ = sim_.externalForceChanges();
  }
  if (recorded_ == since_check_.size())
    since_check_.emplace_back();
  // Over the one recorded there before: the same sizes, so no allocation.
  Motion& m = since_check_[recorded_++];
  m.handles = sim_.handleMotion();
  m.frame = sim_.frameMotion();
  m.colliders.clear();
  m.active.clear();
  if (const Contact* contact = sim_.contact())
    for (int i = 0; i < static_cast<int>(contact->colliders().size()); ++i)
    {
      m.colliders.push_back(contact->pose(i));
      m.active.push_back(contact->active(i));
    }
  m.external_force = recorded_force_;
}

void AdaptiveStepper::apply(const Motion& m)
{
  if (sim_.handleFormulation() == HandleFormulation::MovingFrame)
    sim_.setHandleFrameMotion(m.frame);
  else if (handle_reference_.size() > 0)
  {
    const Eigen::VectorXd at = m.handles.displacement.size() > 0
                                   ? Eigen::VectorXd(handle_reference_ + m.handles.displacement)
                                   : handle_reference_;
    sim_.setHandleMotion(at, m.handles.velocity, m.handles.acceleration);
  }
  for (size_t i = 0; i < m.colliders.size(); ++i)
    if (m.active[i])
      sim_.setColliderPose(static_cast<int>(i), m.colliders[i]);
  // Not when the simulation holds that force already (recorded, unchanged since): setting a force
  // starts the integrator afresh from the state's forces, and the implicit one would no longer take
  // the steps as `full` did; it also evaluates the energy twice, as much as a step of a small grid.
  if (m.external_force != recorded_force_ || sim_.externalForceChanges() != recorded_force_changes_)
  {
    sim_.setExternalForce(*m.external_force);
    recorded_force_ = m.external_force;
    recorded_force_changes_ = sim_.externalForceChanges();
  }
}

StepResult AdaptiveStepper::step()
{
  const bool was_reduced = reduced();
  if (was_reduced)
  {
    const long span = settings_.reduced_step_span;
    const int to_multiple = static_cast<int>(span - sim_.stepCount() % span);
    if (sim_.stepSpan() != to_multiple)
      sim_.setStepSpan(to_multiple);
  }
  if (drive_)
    drive_(sim_);
  const long before = sim_.stepCount();
  const long time_steps = sim_.stepSpan();
  StepResult result = sim_.step();
  if (result.diverged)
  {
    // With a drive its time steps can be taken again: a reduced step that diverges goes to `full`
    // as a failed check does. Without one the step's motion was the caller's and is not recorded
    // (a step is recorded once taken), so the divergence is returned, the last good state kept.
    if (!was_reduced || !drive_)
      return result;
    std::ostringstream why;
    why << "to full at t = " << sim_.time() << " s: its " << toString(settings_.reduced) << " step of "
        << time_steps * sim_.params().time_step << " s from there diverged";
    steps_ += time_steps;
    reduced_steps_ += time_steps;  // taken again under `full` below
    return toFull(why, before + time_steps);
  }
  const long taken = sim_.stepCount() - before;
  steps_ += taken;
  if (was_reduced)
  {
    reduced_steps_ += taken;
    if (!drive_)
      record();
  }
  if (steps_ >= next_check_)
    result = check();
  return result;
}

long AdaptiveStepper::stretchedCheckInterval() const
{
  return std::min(2 * check_interval_, static_cast<long>(settings_.max_check_stretch) * settings_.check_steps);
}

void AdaptiveStepper::scheduleNextCheck(bool far)
{
  check_interval_ = far ? stretchedCheckInterval() : settings_.check_steps;
  next_check_ = steps_ + check_interval_;
}

void AdaptiveStepper::forgetMotions()
{
  for (size_t k = 0; k < recorded_; ++k)
    since_check_[k].external_force.reset();
  recorded_ = 0;
}

void AdaptiveStepper::setCheckpoint()
{
  checkpoint_ = sim_.saveState();
  forgetMotions();
  checks_since_ = 0;
}

double AdaptiveStepper::insideColliders() const
{
  const Contact* contact = sim_.contact();
  return contact ? deepestInside(sim_.grid(), sim_.points(), *contact) : 0.0;
}

double AdaptiveStepper::dwell() const
{
  if (futile_returns_ == 0)
    return settings_.dwell;
  const double check_period = settings_.check_steps * sim_.params().time_step;
  return std::max(settings_.dwell, check_period) * std::pow(2.0, std::min(futile_returns_, kMaxBackOff));
}

bool AdaptiveStepper::touching() const
{
  const Contact* contact = sim_.contact();
  if (!contact)
    return false;
  const std::vector<int>& touching = contact->report().touching;
  return std::any_of(touching.begin(), touching.end(), [](int n) { return n > 0; });
}

StepResult AdaptiveStepper::toFull(std::ostringstream& why, long until)
{
  if (at_return_)
    ++futile_returns_;
  at_return_ = false;
  const StepResult result = fallBack(why, until);
  within_since_ = -1.0;
  scheduleNextCheck(false);
  ++switches_;
  last_switch_ = why.str();
  return result;
}

StepResult AdaptiveStepper::fallBack(std::ostringstream& why, long until)
{
  sim_.restoreState(checkpoint_);
  sim_.setStepSpan(1);  // before `full` is installed: it takes the time step
  sim_.setMethod(Method::Full);
  StepResult result;
  const long again = drive_ ? std::max(0L, until - sim_.stepCount()) : static_cast<long>(recorded_);
  long taken = 0;
  for (; taken < again && !result.diverged; ++taken)
  {
    if (drive_)
      drive_(sim_);
    else
      apply(since_check_[static_cast<size_t>(taken)]);
    result = sim_.step();
    --reduced_steps_;
  }
  why << "; its last " << again << " steps taken again under full";
  if (result.diverged)
    why << " (`full` diverged at step " << taken << " of them)";
  since_check_.clear();  // none recorded under `full`
  recorded_ = 0;
  checks_since_ = 0;
  return result;
}

StepResult AdaptiveStepper::check()
{
  ++checks_;
  std::ostringstream why;
  StepResult result;
  if (reduced())
  {
    const double largest = indicator_max_(sim_, sim_.errorIndicator());
    last_estimate_ = errorEstimate(sim_, largest, settings_.indicator_scale, settings_.swing_drift);
    const double inside = insideColliders();
    const double thickness = sim_.contact() ? sim_.contact()->thickness() : 0.0;
    // The first reading since the state was set tells nothing of how fast the estimate grows.
    const bool first = sim_.stateSets() != sets_checked_;
    sets_checked_ = sim_.stateSets();
    // The swing's drift is its rate (drift times the swing's speed) times the remembered time; the
    // fastest rate read at a check since the set is what the drift at the next check is foreseen from.
    const double alpha = sim_.params().alpha;
    const double since_set = sim_.timeSinceStateSet();
    const double indicator_part = settings_.indicator_scale * largest;
    const double remembered = rememberedTime(alpha, since_set);
    if (first)
      drift_rate_ = 0.0;
    if (remembered > 0.0)
      drift_rate_ = std::max(drift_rate_, (last_estimate_ - indicator_part) / remembered);
    if (last_estimate_ <= settings_.tolerance && inside <= thickness)
    {
      const bool safe = last_estimate_ <= settings_.safe_share * settings_.tolerance;
      if (safe || ++checks_since_ >= settings_.max_rollback_checks)
      {
        if (at_return_)
          futile_returns_ = 0;
        at_return_ = false;
        setCheckpoint();
      }
      // Within the tolerance but not safely, a check is far from a switch too where the indicator's
      // part is safely within what the swing's drift, foreseen at the next check (which a reduced
      // step spanning several time steps may end up to span - 1 of them later), leaves of the
      // tolerance: the indicator is what comes and goes; the drift grows with the time swung, and
      // the foresight holds while the swing is no faster than the fastest read (without a drift,
      // only the safe checks stretch).
      const long next = stretchedCheckInterval() + settings_.reduced_step_span - 1;
      const double drift_next = drift_rate_ * rememberedTime(alpha, since_set + next * sim_.params().time_step);
      const bool room = indicator_part <= settings_.safe_share * (settings_.tolerance - drift_next);
      scheduleNextCheck((safe || room) && !first);
      return result;
    }
    why << "to full at t = " << sim_.time() << " s: ";
    if (!(last_estimate_ <= settings_.tolerance))
      why << "estimated distance " << last_estimate_ << " m above error_tolerance " << settings_.tolerance << " m";
    else
      why << "a particle " << inside << " m inside a collider, deeper than the contact thickness " << thickness
          << " m";
    return toFull(why, sim_.stepCount());
  }
  else
  {
    // Back only where the reduced method could pass its first check: close to its span, and with
    // its estimate there safely within the tolerance, since that check reads it a check later, after
    // the reduced method has drifted from the state. The dwell counts from a check that finds the
    // state close; the estimate, which costs about a step of `full`, is read only once it is over.
    // A check that finds the state far, or after the dwell the estimate above the safe share,
    // stretches the next.
    const double safe = settings_.safe_share * settings_.tolerance;
    last_estimate_ = sim_.spanDistance(settings_.reduced);
    if (!(last_estimate_ <= safe) || touching())
    {
      within_since_ = -1.0;
      scheduleNextCheck(true);
      return result;
    }
    if (within_since_ < 0.0)
      within_since_ = sim_.time();
    const bool dwelt = sim_.time() - within_since_ >= dwell();
    const bool back = dwelt && settings_.indicator_scale * sim_.errorIndicator(settings_.reduced) <= safe;
    scheduleNextCheck(dwelt && !back);
    if (!back)
      return result;
    why << "to " << toString(settings_.reduced) << " at t = " << sim_.time() << " s: within "
        << last_estimate_ << " m of its span for " << sim_.time() - within_since_ << " s";
    if (futile_returns_ > 0)
      why << " (" << futile_returns_ << " return" << (futile_returns_ == 1 ? "" : "s")
          << " before took every reduced step again under full)";
    sim_.setMethod(settings_.reduced);
    at_return_ = true;
    setCheckpoint();
  }
  ++switches_;
  last_switch_ = why.str();
  return result;
}

}  // namespace modal_mass_spring
