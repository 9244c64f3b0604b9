// The setups of a modal_compare run: every combination of the --vary values on the config, the
// handle scenarios on them, each checked and built once before any experiment runs. Each function
// throws std::invalid_argument naming the config, the setup and what is wrong.
#pragma once

#include "compare_options.h"
#include "experiments.h"

#include <vector>

namespace modal_mass_spring::compare
{

// Every combination of the --vary values, each loaded from its own copy of the config; the config's
// handle scenarios (none when it has no handle_scenarios) go to `scenarios`.
std::vector<ExperimentSetup> buildSetups(const Options& o, std::vector<HandleScenario>& scenarios);

// The handles experiment's setups: every scenario on every setup, the grid's handles the scenario's,
// the variant the scenario's name followed by the setup's varied settings.
std::vector<ExperimentSetup> handleSetups(const Options& o, const std::vector<ExperimentSetup>& setups,
                                          const std::vector<HandleScenario>& scenarios);

// Steps a handle scenario runs on a setup: its move and hold (or its move alone), rounded up to whole
// samples.
int handleSteps(const Options& o, const ExperimentSetup& setup, bool move_only = false);

// Fails before any experiment runs. The setups as configured run in cost, accuracy and stability
// only: the handles experiment runs them with its scenarios' handles (validateHandleSetups).
void validate(const Options& o, const std::vector<ExperimentSetup>& setups);
void validateHandleSetups(const Options& o, const std::vector<ExperimentSetup>& handle_setups);

// Builds what each setup's runs build (the equilibrium, both bases, the constraint modes of its
// handles, the cubature's training) once, one setup at a time, before the first simulation steps:
// a setup that cannot be built is refused in seconds, not after the setups before it ran. With the
// cache on, the runs load them again.
// Builds every setup with the method that builds the most. A handle scenario on which that method
// cannot be built (two small grips leave no constraint modes) still runs when `full` builds: the
// handles experiment reports the methods that cannot as "did not build" and goes on.
void buildEverySetup(const Options& o, const std::vector<ExperimentSetup>& setups, bool methods_may_fail);

// Refuses a --tag (or config file name) that makes a file name longer than file systems allow.
void checkOutputNames(const Options& o);

// Creates the output folder and makes sure a file can be written there, before any work.
void prepareOutput(const Options& o);

}  // namespace modal_mass_spring::compare
