#include "tick_pacing.h"

#include <algorithm>
#include <cmath>

namespace modal_mass_spring
{

int TickPacing::stepsOwed(double real_time_factor, double publish_rate, double time_step)
{
  owed_steps_ += real_time_factor / (publish_rate * time_step);
  // 1e-9: a ratio meant to be whole (1 / (30 Hz * 1/30 s)) must not lose a step to rounding.
  const int steps = static_cast<int>(std::floor(owed_steps_ + 1e-9));
  owed_steps_ = std::max(0.0, owed_steps_ - steps);
  return steps;
}

double TickPacing::achievedFactor(int steps, double time_step, double wall_now, double period)
{
  const double wall = ticked_ ? wall_now - last_tick_ : period;
  last_tick_ = wall_now;
  ticked_ = true;
  return steps * time_step / std::max(wall, 1e-9);
}

}  // namespace modal_mass_spring
