// modal_compare's experiments over the setups (cost, accuracy, handles, stability): each writes its
// CSV files to the output folder after every setup, so that a failure late in a run keeps what
// finished before, and prints its summary tables on stdout. A failure throws std::runtime_error
// naming the experiment and the setup.
#pragma once

#include "compare_options.h"
#include "experiments.h"

#include <chrono>
#include <string>
#include <vector>

namespace modal_mass_spring::compare
{

// One line on stderr, rewritten in place on a terminal, a few lines a minute otherwise.
class Progress
{
public:
  explicit Progress(bool enabled);
  void operator()(const std::string& label, double fraction);

private:
  bool enabled_, tty_;
  std::chrono::steady_clock::time_point last_{};
};

void runCostExperiment(const Options& o, const std::vector<ExperimentSetup>& setups, Progress& progress);
void runAccuracyExperiment(const Options& o, const std::vector<ExperimentSetup>& setups, Progress& progress);
// Runs the handle scenarios' setups (handleSetups).
void runHandlesExperiment(const Options& o, const std::vector<ExperimentSetup>& setups, Progress& progress);
void runStabilityExperiment(const Options& o, const std::vector<ExperimentSetup>& setups, Progress& progress);

}  // namespace modal_mass_spring::compare
