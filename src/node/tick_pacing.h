// How many steps a tick of the node's timer takes, without ROS: a fixed simulated time per tick, so
// that how late a tick is never changes the simulated time.
#pragma once

namespace modal_mass_spring
{

class TickPacing
{
public:
  // The whole steps of `time_step` a tick owes for real_time_factor / publish_rate simulated seconds,
  // the fraction of a step left carried to the next tick.
  int stepsOwed(double real_time_factor, double publish_rate, double time_step);
  // Nothing owed any more: after a reset or a restored state, and when a lockstep tick drops the steps
  // it could not take within its period.
  void dropOwed() { owed_steps_ = 0.0; }
  double owedSteps() const { return owed_steps_; }

  // The real-time factor a tick achieved: `steps` of `time_step` over the wall time since the previous
  // tick at `wall_now` (s on any monotonic clock); the first tick counts one `period`.
  double achievedFactor(int steps, double time_step, double wall_now, double period);

private:
  double owed_steps_ = 0.0;
  double last_tick_ = 0.0;
  bool ticked_ = false;
};

}  // namespace modal_mass_spring
