// Method adaptive in the node: the single method's track stepped by an AdaptiveStepper (the reduced
// method where its error estimate allows, full where it does not), and every reduced track's error
// estimate for ~status and /diagnostics.
#include "simulation_node.h"

#include <cmath>

namespace modal_mass_spring
{
namespace
{

// Wall seconds between two refreshes of a reduced method's error estimate outside adaptive.
constexpr double kEstimatePeriod = 1.0;

}  // namespace

StepResult SimulationNode::stepTrack(Track& track)
{
  if (!adaptiveTrack(track))
  {
    track.adaptive.reset();
    return track.simulation->step(1);
  }
  if (!track.adaptive)
  {
    // Made once the reduced method can run without a training (a cubature may still be training in
    // the background): in it, or with its basis and cubature at hand, as after a reset under full.
    Simulation& simulation = *track.simulation;
    const Method reduced = config_.simulation.adaptive_method;
    if (simulation.method() != reduced && reduced != Method::Coarse &&
        !(simulation.basisBuilt() && (reduced != Method::Cubature || simulation.cubature())))
      return simulation.step(1);
    try
    {
      track.adaptive = std::make_unique<AdaptiveStepper>(simulation, adaptiveSettings(config_.simulation));
    }
    catch (const std::exception& error)
    {
      adaptive_ = false;
      ROS_ERROR("adaptive: cannot step %s: %s; method %s steps on", toString(reduced).c_str(), error.what(),
                toString(simulation.method()).c_str());
      return simulation.step(1);
    }
    track.logged_switches = 0;
  }
  StepResult result;
  try
  {
    result = track.adaptive->step();
  }
  catch (const std::exception& error)
  {
    // What the stepper cannot do (a checkpoint the simulation refuses): the method it runs steps on.
    track.restartAdaptive();
    adaptive_ = false;
    ROS_ERROR("adaptive: %s; method %s steps on (~set_method adaptive starts it again)", error.what(),
              toString(track.simulation->method()).c_str());
    return StepResult{};
  }
  const double estimate = track.adaptive->lastEstimate();
  track.error_estimate = std::isfinite(estimate) ? estimate : 0.0;
  if (track.adaptive->switches() != track.logged_switches)
  {
    track.logged_switches = track.adaptive->switches();
    ROS_INFO("adaptive: %s", track.adaptive->lastSwitch().c_str());
  }
  return result;
}

void SimulationNode::refreshErrorEstimate(Track& track)
{
  Simulation& simulation = *track.simulation;
  if (adaptiveTrack(track) || track.shadow)
    return;
  // `full` is its own reference.
  if (simulation.method() == Method::Full || simulation.diverged())
  {
    track.error_estimate = 0.0;
    return;
  }
  const double now = ros::WallTime::now().toSec();
  if (track.estimate_wall >= 0.0 && now - track.estimate_wall < kEstimatePeriod)
    return;
  track.estimate_wall = now;
  try
  {
    const double estimate =
        errorEstimate(simulation, track.indicator_max(simulation, simulation.errorIndicator()));
    track.error_estimate = std::isfinite(estimate) ? estimate : 0.0;
  }
  catch (const std::exception& error)
  {
    track.error_estimate = 0.0;
    warnDropped("no error estimate for " + track.name + ": " + error.what());
  }
}

}  // namespace modal_mass_spring
