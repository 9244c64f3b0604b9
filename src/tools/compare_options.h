// modal_compare's command line: its options, checked as they are read (parseArguments), and the
// number format of its messages and tables.
#pragma once

#include "experiments.h"

#include "modal_mass_spring/cache.h"

#include <algorithm>
#include <string>
#include <utility>
#include <vector>

namespace modal_mass_spring::compare
{

// A number as the tool prints it: `precision` significant digits, "-" for NaN, "inf" for infinity.
std::string fmt(double value, int precision = 3);

// `all`: the paper's experiments. `handles` needs handle_scenarios in the config, so it runs only when named.
inline const std::vector<std::string> kExperiments{"cost", "accuracy", "stability"};
inline const std::vector<std::string> kAllExperiments{"cost", "accuracy", "stability", "handles"};

struct Options
{
  std::string config;
  std::vector<std::string> experiments = kExperiments;
  std::string output = ".";
  std::string tag;
  std::vector<Method> methods{Method::Full, Method::Linear, Method::Physical, Method::Cubature};
  bool adaptive = false;  // --methods named `adaptive`
  std::vector<std::pair<std::string, std::string>> sets;
  std::vector<std::pair<std::string, std::vector<std::string>>> varies;
  bool quiet = false;
  std::string cache_dir = defaultCacheDirectory();
  bool no_cache = false;
  double check_factor = 0.0;
  AccuracyOptions accuracy;
  StabilityOptions stability;
  CostOptions cost;

  bool runs(const std::string& experiment) const
  {
    return std::find(experiments.begin(), experiments.end(), experiment) != experiments.end();
  }
};

// The options of the command line, each checked as it is read and then together (before the
// config is read); --help prints the usage and exits 0. Throws std::invalid_argument
// (rejectParameter) naming the option and what it allows.
Options parseArguments(int argc, char** argv);

}  // namespace modal_mass_spring::compare
