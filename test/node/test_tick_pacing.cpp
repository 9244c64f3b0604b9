// The steps of the node's ticks: a fixed simulated time per tick in whole steps, the fraction carried.
#include "tick_pacing.h"

#include <gtest/gtest.h>

#include <cmath>

namespace
{

using modal_mass_spring::TickPacing;

// 1 s per s at 30 Hz with 1 ms steps is 33 1/3 steps a tick: 33 or 34, never a step lost or gained
// over any number of ticks.
TEST(TickPacing, AFractionOfAStepIsCarriedToTheNextTick)
{
  TickPacing pacing;
  const double per_tick = 1.0 / (30.0 * 0.001);
  long total = 0;
  for (int tick = 1; tick <= 3000; ++tick)
  {
    const int steps = pacing.stepsOwed(1.0, 30.0, 0.001);
    EXPECT_TRUE(steps == 33 || steps == 34) << "tick " << tick << ": " << steps;
    total += steps;
    EXPECT_NEAR(static_cast<double>(total), tick * per_tick, 1.0) << "tick " << tick;
    EXPECT_NEAR(pacing.owedSteps(), tick * per_tick - static_cast<double>(total), 1e-6);
  }
  EXPECT_EQ(total, 100000);  // 100 s simulated in 3000 ticks of 1/30 s
}

// A whole number of steps per tick that floating point cannot hold exactly is still whole.
TEST(TickPacing, AWholeNumberOfStepsLosesNoneToRounding)
{
  TickPacing pacing;
  const double time_step = 1.0 / 300.0;  // 1 / (30 * time_step) is 10 up to rounding
  for (int tick = 0; tick < 1000; ++tick)
    ASSERT_EQ(pacing.stepsOwed(1.0, 30.0, time_step), 10) << "tick " << tick;
  // Slower than real time: a step every fourth tick.
  TickPacing slow;
  int taken = 0;
  for (int tick = 0; tick < 40; ++tick)
    taken += slow.stepsOwed(0.25, 100.0, 0.01);
  EXPECT_EQ(taken, 10);
}

TEST(TickPacing, DroppedStepsAreNotOwedAgain)
{
  TickPacing pacing;
  pacing.stepsOwed(1.0, 30.0, 0.001);
  EXPECT_GT(pacing.owedSteps(), 0.0);
  pacing.dropOwed();
  EXPECT_EQ(pacing.owedSteps(), 0.0);
  EXPECT_EQ(pacing.stepsOwed(1.0, 30.0, 0.001), 33);
}

// The factor achieved is the simulated time over the wall time between ticks; the first tick, with no
// previous one, counts one period.
TEST(TickPacing, AchievedFactorOverTheWallTimeBetweenTicks)
{
  TickPacing pacing;
  EXPECT_NEAR(pacing.achievedFactor(30, 0.001, 100.0, 1.0 / 30.0), 0.9, 1e-12);
  EXPECT_NEAR(pacing.achievedFactor(20, 0.001, 100.1, 1.0 / 30.0), 0.2, 1e-9);
  EXPECT_EQ(pacing.achievedFactor(0, 0.001, 100.2, 1.0 / 30.0), 0.0);
}

}  // namespace
