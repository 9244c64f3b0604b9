// modal_compare: runs the paper's experiments on a YAML config and writes CSV files and a summary.
// Its command line: compare_options.h; its setups, checked before any run: compare_setups.h; the
// experiments: compare_experiments.h.
#include "compare_experiments.h"
#include "compare_options.h"
#include "compare_setups.h"

#include <stdlib.h>

#include <filesystem>
#include <iostream>
#include <new>
#include <optional>
#include <stdexcept>
#include <string>
#include <system_error>
#include <vector>

using namespace modal_mass_spring;
using namespace modal_mass_spring::compare;

namespace
{

// With --no-cache, a cache folder of this run alone: what the check before the runs builds (the
// equilibrium, bases, cubature) is built once and the runs load it; removed when the run ends.
class RunCache
{
public:
  explicit RunCache(Options& o)
  {
    if (!o.no_cache)
      return;
    std::string pattern = (std::filesystem::temp_directory_path() / "modal_compare_cache.XXXXXX").string();
    if (!mkdtemp(pattern.data()))
      throw std::runtime_error("--no-cache: cannot create a temporary folder in " +
                               std::filesystem::temp_directory_path().string() + " for this run's precomputation");
    directory_ = pattern;
    o.accuracy.cache.directory = o.stability.cache.directory = directory_;
  }
  ~RunCache()
  {
    std::error_code ignored;
    if (!directory_.empty())
      std::filesystem::remove_all(directory_, ignored);
  }
  RunCache(const RunCache&) = delete;
  RunCache& operator=(const RunCache&) = delete;

private:
  std::string directory_;
};

}  // namespace

int main(int argc, char** argv)
{
  Options options;
  std::vector<ExperimentSetup> setups, handle_setups;
  std::optional<RunCache> run_cache;
  try
  {
    options = parseArguments(argc, argv);
    run_cache.emplace(options);
    std::vector<HandleScenario> scenarios;
    setups = buildSetups(options, scenarios);
    validate(options, setups);
    if (options.runs("handles"))
    {
      handle_setups = handleSetups(options, setups, scenarios);
      validateHandleSetups(options, handle_setups);
    }
    checkOutputNames(options);
    if (options.runs("accuracy") || options.runs("stability"))
      buildEverySetup(options, setups, false);
    buildEverySetup(options, handle_setups, true);
    prepareOutput(options);
  }
  catch (const std::bad_alloc&)
  {
    std::cerr << "modal_compare: error: out of memory while checking the input\n";
    return 2;
  }
  catch (const std::exception& e)
  {
    std::cerr << "modal_compare: error: " << e.what() << "\n";
    return 2;
  }

  try
  {
    Progress progress(!options.quiet);
    std::cout << "config " << options.config << ", " << setups.size() << " variant(s)\n";
    for (const std::string& experiment : options.experiments)
    {
      if (experiment == "cost")
        runCostExperiment(options, setups, progress);
      else if (experiment == "accuracy")
        runAccuracyExperiment(options, setups, progress);
      else if (experiment == "handles")
        runHandlesExperiment(options, handle_setups, progress);
      else
        runStabilityExperiment(options, setups, progress);
    }
  }
  catch (const std::bad_alloc&)
  {
    // The memory estimate (memory_limit_gb) passed, but the machine had less than that to give.
    std::cerr << "modal_compare: failed: out of memory (std::bad_alloc): the machine could not provide what this "
                 "grid needs; use a smaller grid or fewer modes, or lower memory_limit_gb to what is free\n";
    return 1;
  }
  catch (const std::exception& e)
  {
    std::cerr << "modal_compare: failed: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
