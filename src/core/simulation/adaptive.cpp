#include "modal_mass_spring/adaptive.h"

#include "modal_mass_spring/parameter_error.h"

#include <cmath>
#include <sstream>

namespace modal_mass_spring
{

AdaptiveSettings adaptiveSettings(const SimulationParams& p)
{
  AdaptiveSettings s;
  s.reduced = p.adaptive_method;
  s.tolerance = p.error_tolerance;
  s.dwell = p.adaptive_dwell;
  s.check_steps = p.adaptive_check_steps;
  return s;
}

void validateAdaptiveSettings(const AdaptiveSettings& s)
{
  if (!std::isfinite(s.tolerance) || s.tolerance <= 0.0)
    rejectParameter("error_tolerance", s.tolerance, "must be a finite number > 0 (m, the RMS distance to full accepted)");
  if (!std::isfinite(s.dwell) || s.dwell < 0.0)
    rejectParameter("adaptive_dwell", s.dwell, "must be a finite number >= 0 (s)");
  if (s.check_steps < 1)
    rejectParameter("adaptive_check_steps", s.check_steps, "must be an integer >= 1");
  if (s.reduced != Method::Physical && s.reduced != Method::Cubature)
    rejectParameter("adaptive_method", "'" + toString(s.reduced) + "'", "must be one of physical, cubature");
  if (!std::isfinite(s.indicator_scale) || s.indicator_scale <= 0.0)
    rejectParameter("indicator_scale", s.indicator_scale, "must be a finite number > 0");
}

AdaptiveStepper::AdaptiveStepper(Simulation& sim, const AdaptiveSettings& settings) : sim_(sim), settings_(settings)
{
  validateAdaptiveSettings(settings_);
  if (sim_.method() != settings_.reduced)
    sim_.setMethod(settings_.reduced);
}

StepResult AdaptiveStepper::step()
{
  const bool was_reduced = reduced();
  const StepResult result = sim_.step();
  if (result.diverged)
    return result;
  ++steps_;
  reduced_steps_ += was_reduced ? 1 : 0;
  if (steps_ % settings_.check_steps == 0)
    check();
  return result;
}

void AdaptiveStepper::check()
{
  std::ostringstream why;
  if (reduced())
  {
    last_estimate_ = settings_.indicator_scale * sim_.errorIndicator();
    if (last_estimate_ <= settings_.tolerance)
      return;
    why << "to full at t = " << sim_.time() << " s: estimated distance " << last_estimate_
        << " m above error_tolerance " << settings_.tolerance << " m";
    sim_.setMethod(Method::Full);
    within_since_ = -1.0;
  }
  else
  {
    last_estimate_ = sim_.spanDistance(settings_.reduced);
    if (last_estimate_ > settings_.tolerance)
    {
      within_since_ = -1.0;
      return;
    }
    if (within_since_ < 0.0)
      within_since_ = sim_.time();
    if (sim_.time() - within_since_ < settings_.dwell)
      return;
    why << "to " << toString(settings_.reduced) << " at t = " << sim_.time() << " s: within "
        << last_estimate_ << " m of its span for " << sim_.time() - within_since_ << " s";
    sim_.setMethod(settings_.reduced);
  }
  ++switches_;
  last_switch_ = why.str();
}

}  // namespace modal_mass_spring
