// What the experiments' sources share (experiments.cpp, accuracy_experiment.cpp): wall time, the
// median, progress reports, a setup's parameters under another method. Not the tool's API.
#pragma once

#include "experiments.h"

#include <algorithm>
#include <chrono>
#include <limits>
#include <string>
#include <vector>

namespace modal_mass_spring::experiment_support
{

using Clock = std::chrono::steady_clock;

inline double seconds(Clock::time_point start)
{
  return std::chrono::duration<double>(Clock::now() - start).count();
}

inline double median(std::vector<double> values)
{
  if (values.empty())
    return std::numeric_limits<double>::quiet_NaN();
  std::sort(values.begin(), values.end());
  const size_t n = values.size();
  return n % 2 ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
}

inline double mean(const std::vector<double>& values)
{
  if (values.empty())
    return std::numeric_limits<double>::quiet_NaN();
  double sum = 0.0;
  for (double v : values)
    sum += v;
  return sum / static_cast<double>(values.size());
}

inline void report(const ProgressFn& progress, const std::string& label, double fraction)
{
  if (progress)
    progress(label, fraction);
}

inline SimulationParams withMethod(SimulationParams params, Method method)
{
  params.method = method;
  return params;
}

}  // namespace modal_mass_spring::experiment_support
