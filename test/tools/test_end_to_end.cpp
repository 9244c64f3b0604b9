// The tool from the command line: a small run through the CSV files to the plotting script's PNGs,
// and bad input refused with a message naming it before any file is written.
#include <gtest/gtest.h>

#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <sstream>
#include <cstdlib>
#include <set>
#include <string>
#include <vector>

namespace fs = std::filesystem;

namespace
{

struct CommandResult
{
  int status = -1;
  std::string output;  // stdout and stderr
};

CommandResult run(const std::string& command)
{
  CommandResult result;
  FILE* pipe = popen((command + " 2>&1").c_str(), "r");
  if (!pipe)
    return result;
  std::array<char, 4096> buffer;
  size_t n;
  while ((n = fread(buffer.data(), 1, buffer.size(), pipe)) > 0)
    result.output.append(buffer.data(), n);
  const int status = pclose(pipe);
  result.status = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return result;
}

std::string firstLine(const fs::path& path)
{
  std::ifstream in(path);
  std::string line;
  std::getline(in, line);
  return line;
}

class ModalCompareTool : public ::testing::Test
{
protected:
  void SetUp() override
  {
    dir_ = fs::temp_directory_path() / ("modal_compare_test_" + std::to_string(getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    // The tool's default cache is under $ROS_HOME: keep it inside this test's folder.
    setenv("ROS_HOME", dir_.c_str(), 1);
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::string tool(const std::string& args) const
  {
    return std::string(MODAL_COMPARE_EXECUTABLE) + " --quiet --output " + (dir_ / "data").string() + " " + args;
  }
  std::string config(const std::string& name) const { return std::string(MODAL_SOURCE_DIR) + "/config/compare/" + name; }

  fs::path dir_;
};

}  // namespace

TEST_F(ModalCompareTool, SmallRunEndToEndToPngs)
{
  // A 2D and a 3D config, every experiment, small enough to take a few seconds.
  const CommandResult r2 = run(tool("--config " + config("paper_2d.yaml") +
                          " --experiment all --steps 400 --interval 200 --sample 20 --stability-steps 500"
                          " --tolerance 0.05 --sizes 4,6 --repeats 2 --min-repeat-seconds 0.001"));
  ASSERT_EQ(r2.status, 0) << r2.output;
  const CommandResult r3 = run(tool("--config " + config("paper_3d.yaml") +
                          " --set rows=5 --set cols=5 --set num_modes=6 --tag small_3d --experiment accuracy,cost"
                          " --steps 200 --interval 100 --sample 20 --sizes 5 --repeats 2 --min-repeat-seconds 0.001"));
  ASSERT_EQ(r3.status, 0) << r3.output;
  EXPECT_NE(r2.output.find("accuracy (paper_2d)"), std::string::npos) << r2.output;  // the summary table
  EXPECT_NE(r2.output.find("cubature (base): "), std::string::npos) << r2.output;  // its training report
  // Beyond the paper: the combinations against a converged reference, and the stability of both integrators
  // with the implicit one checked at ten times the explicit one's step.
  const CommandResult rc = run(tool("--config " + config("paper_2d.yaml") +
                          " --tag combinations_paper_2d_dt1ms --experiment accuracy --vary integrator=explicit,implicit"
                          " --steps 200 --interval 200 --sample 20 --reference-time-step 0.0005 --no-snapshots"));
  ASSERT_EQ(rc.status, 0) << rc.output;
  EXPECT_NE(rc.output.find("reference (integrator=implicit): full, explicit, dt = 0.0005 s"), std::string::npos)
      << rc.output;
  const CommandResult rs = run(tool("--config " + config("paper_2d.yaml") +
                          " --tag integrators --experiment stability --methods physical --vary integrator=explicit,implicit"
                          " --stability-steps 300 --tolerance 0.1 --check-factor 10"));
  ASSERT_EQ(rs.status, 0) << rs.output;
  EXPECT_NE(rs.output.find("check: integrator=implicit, physical at 10 x the explicit physical's largest stable step"),
            std::string::npos)
      << rs.output;

  const fs::path data = dir_ / "data";
  for (const char* name : {"cost_paper_2d.csv", "accuracy_paper_2d_error.csv", "accuracy_paper_2d_snapshots.csv",
                           "stability_paper_2d.csv", "cost_small_3d.csv", "accuracy_small_3d_snapshots.csv"})
    ASSERT_TRUE(fs::exists(data / name)) << name;
  EXPECT_EQ(firstLine(data / "accuracy_paper_2d_error.csv"),
            "variant,method,step,time,max_distance,rms_distance,max_displacement,energy,diverged,step_seconds,center_y,"
            "error_indicator,surface_distance,error_estimate");
  EXPECT_EQ(firstLine(data / "accuracy_paper_2d_cubature.csv"),
            "variant,springs,grid_springs,training_poses,tolerance,training_error,heldout_error,training_seconds");
  EXPECT_EQ(firstLine(data / "stability_integrators.csv"),
            "variant,method,stable_dt,unstable_dt,trials,steps,tolerance,modal_bound,full_bound,stable_windows,"
            "check_dt,check_stable");
  EXPECT_FALSE(fs::exists(data / "accuracy_combinations_paper_2d_dt1ms_snapshots.csv")) << "--no-snapshots";

  const fs::path figures = dir_ / "figures";
  const CommandResult plot = run("MPLBACKEND=Agg /usr/bin/python3 " + std::string(MODAL_SOURCE_DIR) +
                       "/scripts/plot_comparison.py --data " + data.string() + " --out " + figures.string());
  ASSERT_EQ(plot.status, 0) << plot.output;
  for (const char* name : {"cost.png", "snapshots_paper_2d.png", "error_paper_2d.png", "stability_paper_2d.png",
                           "snapshots_small_3d.png", "error_small_3d.png", "combinations.png",
                           "error_combinations_paper_2d_dt1ms.png", "stability_integrators.png"})
  {
    ASSERT_TRUE(fs::exists(figures / name)) << name << "\n" << plot.output;
    EXPECT_GT(fs::file_size(figures / name), 5000u) << name;
  }
}

// The accuracy experiment reads the bases and cubature it wrote: the same errors with or without the
// cache, and --no-cache writes none.
TEST_F(ModalCompareTool, CachedRunGivesTheSameResultsAndNoCacheWritesNone)
{
  const std::string args = "--config " + config("paper_3d.yaml") +
                           " --set rows=5 --set cols=5 --set num_modes=6 --experiment accuracy --steps 100"
                           " --interval 50 --sample 10 --no-snapshots";
  const fs::path cache = dir_ / "cache";
  auto errors = [&](const std::string& tag) {
    std::ifstream in(dir_ / "data" / ("accuracy_" + tag + "_error.csv"));
    std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    // Drop the wall time per step (the tenth column), which differs between runs.
    std::string kept;
    std::istringstream lines(text);
    for (std::string line; std::getline(lines, line);)
    {
      size_t start = 0;
      for (int column = 0; column < 9; ++column)
        start = line.find(',', start) + 1;
      kept += line.substr(0, start) + line.substr(line.find(',', start) + 1) + "\n";
    }
    return kept;
  };
  const CommandResult uncached = run(tool(args + " --no-cache --tag uncached"));
  ASSERT_EQ(uncached.status, 0) << uncached.output;
  EXPECT_FALSE(fs::exists(dir_ / "modal_mass_spring")) << "--no-cache wrote the default cache";
  EXPECT_FALSE(fs::exists(cache));
  const CommandResult first = run(tool(args + " --cache-dir " + cache.string() + " --tag first"));
  ASSERT_EQ(first.status, 0) << first.output;
  int files = 0;
  for (const auto& entry : fs::directory_iterator(cache))
    files += entry.path().extension() == ".bin";
  EXPECT_EQ(files, 2);  // the basis (every method's: the method is not part of the key) and the cubature
  const CommandResult second = run(tool(args + " --cache-dir " + cache.string() + " --tag second"));
  ASSERT_EQ(second.status, 0) << second.output;
  EXPECT_EQ(second.output.find("warning"), std::string::npos) << second.output;
  EXPECT_EQ(errors("uncached"), errors("first"));
  EXPECT_EQ(errors("uncached"), errors("second"));
  EXPECT_GT(errors("second").size(), 100u);
}

// --no-cache builds the precomputation once: the check before the runs trains the cubature, the run
// loads it from a folder of this run alone, removed at the end. The cubature's report says when the
// training stopped above its tolerance (here at a 5-spring cap).
TEST_F(ModalCompareTool, NoCacheTrainsTheCubatureOnceAndSaysWhenItsCapsStoppedIt)
{
  const fs::path scratch = dir_ / "tmp";
  fs::create_directories(scratch);
  const std::string args = "--config " + config("paper_3d.yaml") +
                           " --set rows=5 --set cols=5 --set num_modes=6 --experiment accuracy --methods physical,cubature"
                           " --steps 20 --interval 10 --sample 10 --no-snapshots --no-cache";
  const CommandResult r = run("TMPDIR=" + scratch.string() + " " + tool(args));
  ASSERT_EQ(r.status, 0) << r.output;
  const size_t line = r.output.find("cubature (base): ");
  ASSERT_NE(line, std::string::npos) << r.output;
  const std::string report = r.output.substr(line, r.output.find('\n', line) - line);
  EXPECT_NE(report.find("(loaded from the cache)"), std::string::npos) << report;
  EXPECT_EQ(report.find("above cubature_tolerance"), std::string::npos) << report;
  EXPECT_TRUE(fs::is_empty(scratch)) << "the run's cache folder is removed";
  EXPECT_FALSE(fs::exists(dir_ / "modal_mass_spring")) << "--no-cache wrote the default cache";

  const CommandResult capped = run(tool(args + " --set cubature_max_springs=5 --tag capped"));
  ASSERT_EQ(capped.status, 0) << capped.output;
  EXPECT_NE(capped.output.find("above cubature_tolerance"), std::string::npos) << capped.output;
  EXPECT_NE(capped.output.find("cubature_max_springs"), std::string::npos) << capped.output;
}

// A method that does not train the cubature is not refused for the training's memory.
TEST_F(ModalCompareTool, MemoryCheckCountsTheCubatureOnlyWhenAMethodTrainsIt)
{
  // 100000 training poses, growing to 800000: tens of GB for the training alone, nothing for the rest.
  const std::string args = "--config " + config("paper_3d.yaml") +
                           " --set cubature_training_poses=100000 --set memory_limit_gb=1"
                           " --experiment accuracy --steps 10 --interval 10 --sample 10 --no-snapshots --no-cache";
  const CommandResult without = run(tool(args + " --methods full,physical"));
  EXPECT_EQ(without.status, 0) << without.output;
  const CommandResult with = run(tool(args + " --methods physical,cubature --tag with"));
  EXPECT_EQ(with.status, 2) << with.output;
  EXPECT_NE(with.output.find("memory_limit_gb"), std::string::npos) << with.output;
  EXPECT_NE(with.output.find("cubature's training would need"), std::string::npos) << with.output;
}

// Item 9: a diverged sample and the bound of a basis of zero modes are empty fields, which the
// plotting script reads.
TEST_F(ModalCompareTool, CsvFilesHoldNoNanOrInfAndThePlotsReadThem)
{
  // paper_2d at 50 ms: above every explicit method's stable step, so every sample after a few diverges.
  const CommandResult diverging = run(tool("--config " + config("paper_2d.yaml") +
                                           " --tag diverging --experiment accuracy --set time_step=0.05"
                                           " --steps 200 --interval 100 --sample 10"));
  ASSERT_EQ(diverging.status, 0) << diverging.output;
  // A flat 3 x 3 sheet at rest: its 4 lowest modes are all zero modes, so 2 / omega is infinite.
  const CommandResult zero = run(tool("--config " + config("paper_3d.yaml") +
                                      " --tag zero_modes --experiment stability --methods linear --set rows=3"
                                      " --set cols=3 --set num_modes=4 --set rotation_deg=0 --stability-steps 100"
                                      " --max-time-step 0.01"));
  ASSERT_EQ(zero.status, 0) << zero.output;
  std::ifstream errors(dir_ / "data" / "accuracy_diverging_error.csv");
  std::string line;
  int diverged = 0;
  while (std::getline(errors, line))
  {
    EXPECT_EQ(line.find("nan"), std::string::npos) << line;
    EXPECT_EQ(line.find("inf"), std::string::npos) << line;
    if (line.find(",,,,1,") != std::string::npos)
      ++diverged;
  }
  EXPECT_GT(diverged, 0) << "no diverged sample: the run did not test the empty fields";
  std::ifstream stability(dir_ / "data" / "stability_zero_modes.csv");
  std::getline(stability, line);
  std::getline(stability, line);
  EXPECT_EQ(line.find("inf"), std::string::npos) << line;
  EXPECT_NE(line.find(",,"), std::string::npos) << "modal_bound must be empty: " << line;
  const CommandResult plot = run("/usr/bin/python3 " + std::string(MODAL_SOURCE_DIR) + "/scripts/plot_comparison.py --data " +
                                 (dir_ / "data").string() + " --out " + (dir_ / "figures").string());
  EXPECT_EQ(plot.status, 0) << plot.output;
  EXPECT_TRUE(fs::exists(dir_ / "figures" / "error_diverging.png")) << plot.output;
  EXPECT_TRUE(fs::exists(dir_ / "figures" / "stability_zero_modes.png")) << plot.output;
}

// Item 10: a key that neither the core nor the node reads is warned about; the node's keys are not.
TEST_F(ModalCompareTool, UnknownConfigKeysAreWarnedAbout)
{
  fs::create_directories(dir_);
  std::ofstream(dir_ / "typo.yaml") << "rows: 4\ncols: 4\nstifness: 30\npublish_rate: 30\n";
  const CommandResult r = run(tool("--config " + (dir_ / "typo.yaml").string() +
                                   " --experiment accuracy --steps 20 --interval 10 --sample 10 --no-snapshots"));
  EXPECT_EQ(r.status, 0) << r.output;
  EXPECT_NE(r.output.find("warning: config '" + (dir_ / "typo.yaml").string() + "': unknown parameter 'stifness'"),
            std::string::npos)
      << r.output;
  EXPECT_EQ(r.output.find("publish_rate"), std::string::npos) << r.output;
}

// A small held sheet for the handles experiment: 4 x 4 in 3D, hanging from its handles, two scenarios.
const char* const kHeldSheet = R"(rows: 4
cols: 4
dimension: 3
mass: 0.005
structural_stiffness: 50.0
shear_stiffness: 20.0
fixed: []
num_modes: 6
linearization: equilibrium
initial_state: equilibrium
alpha: 0.5
time_step: 0.002
handle_scenarios:
  - name: shift
    move_time: 0.2
    hold_time: 0.1
    handles:
      - {particles: [0, 1, 2, 3], translation: [0.1, 0.0, 0.0]}
  - name: apart
    move_time: 0.2
    hold_time: 0.1
    handles:
      - {particles: [0], translation: [-0.02, 0.0, 0.0]}
      - {particles: [3], translation: [0.02, 0.0, 0.0]}
)";

TEST_F(ModalCompareTool, HandlesExperimentMeasuresEveryScenarioAndMethodAgainstTheReference)
{
  std::ofstream(dir_ / "held.yaml") << kHeldSheet;
  const CommandResult r = run(tool("--config " + (dir_ / "held.yaml").string() +
                                   " --experiment handles --sample 10 --reference-time-step 0.0005"));
  ASSERT_EQ(r.status, 0) << r.output;
  std::ifstream in(dir_ / "data" / "handles_held_summary.csv");
  ASSERT_TRUE(in) << r.output;
  std::string line;
  std::getline(in, line);
  EXPECT_EQ(line.rfind("variant,method,mean_rms,max_rms", 0), 0u) << line;
  std::set<std::string> rows;
  while (std::getline(in, line))
    rows.insert(line.substr(0, line.find(',', line.find(',') + 1)));
  for (const char* scenario : {"shift", "apart"})
    for (const char* method : {"reference", "full", "linear", "physical", "cubature", "reference_half_step"})
      EXPECT_TRUE(rows.count(std::string(scenario) + "," + method)) << scenario << " " << method << "\n" << r.output;
  // Every timed method's CPU seconds per simulated second is its CPU time per step over the 2 ms
  // step, and the real-time factor its inverse; the printed table has both.
  {
    std::ifstream summary(dir_ / "data" / "handles_held_summary.csv");
    std::string header, row;
    std::getline(summary, header);
    auto split = [](const std::string& text) {
      std::vector<std::string> fields;
      std::stringstream stream(text);
      for (std::string field; std::getline(stream, field, ',');)
        fields.push_back(field);
      return fields;
    };
    const std::vector<std::string> names = split(header);
    auto column = [&](const std::string& name) {
      const auto it = std::find(names.begin(), names.end(), name);
      EXPECT_NE(it, names.end()) << name << " in " << header;
      return static_cast<size_t>(it - names.begin());
    };
    const size_t method = column("method"), cpu = column("step_cpu_seconds_median"),
                 per_second = column("cpu_per_simulated_second"), factor = column("real_time_factor");
    int timed = 0;
    while (std::getline(summary, row))
    {
      const std::vector<std::string> fields = split(row);
      ASSERT_GT(fields.size(), factor) << row;
      if (fields[method] == "reference" || fields[method] == "reference_half_step")
        continue;
      ++timed;
      const double step_cpu = std::stod(fields[cpu]);
      ASSERT_GT(step_cpu, 0.0) << row;
      EXPECT_NEAR(std::stod(fields[per_second]), step_cpu / 0.002, 1e-9 * step_cpu / 0.002) << row;
      EXPECT_NEAR(std::stod(fields[factor]) * std::stod(fields[per_second]), 1.0, 1e-9) << row;
    }
    EXPECT_EQ(timed, 2 * 4);  // full, linear, physical, cubature in each scenario
    EXPECT_NE(r.output.find("CPU s per simulated s"), std::string::npos) << r.output;
    EXPECT_NE(r.output.find("real-time factor"), std::string::npos) << r.output;
  }
  // 0.3 s of 2 ms steps, sampled every 10 steps: 15 samples and step 0 per scenario and run.
  std::ifstream errors(dir_ / "data" / "handles_held_error.csv");
  int samples = 0;
  while (std::getline(errors, line))
    samples += line.rfind("shift,physical,", 0) == 0;
  EXPECT_EQ(samples, 16);
  EXPECT_NE(r.output.find("handle scenario apart: 2 handle(s)"), std::string::npos) << r.output;
  // Every particle of every run (reference, full and the three modal methods) where the move ends, at
  // step 100 (0.2 s of 2 ms steps), and at the end of the hold, step 150 (0.3 s); the handle particles
  // where the frame put them at both.
  std::ifstream shapes(dir_ / "data" / "handles_held_snapshots.csv");
  std::getline(shapes, line);
  ASSERT_EQ(line, "variant,method,step,time,particle,row,col,fixed,x,y,z");
  int points = 0, handle_points = 0;
  while (std::getline(shapes, line))
  {
    ++points;
    const bool move_end = line.find(",100,0.2,") != std::string::npos;
    const bool hold_end = line.find(",150,0.3,") != std::string::npos;
    EXPECT_TRUE(move_end || hold_end) << line;
    // shift: particle 1 of the top row starts at x = 0.1 and moves by 0.1 with its handle.
    if (line.rfind("shift,", 0) == 0 && line.find(",1,0,1,0,") != std::string::npos)
    {
      ++handle_points;
      EXPECT_NE(line.find(",0,0.2,"), std::string::npos) << line;
    }
  }
  EXPECT_EQ(points, 2 * 2 * 5 * 16);
  EXPECT_EQ(handle_points, 2 * 5);

  const fs::path figures = dir_ / "figures";
  const CommandResult plot = run("MPLBACKEND=Agg /usr/bin/python3 " + std::string(MODAL_SOURCE_DIR) +
                                 "/scripts/plot_comparison.py --data " + (dir_ / "data").string() + " --out " +
                                 figures.string());
  ASSERT_EQ(plot.status, 0) << plot.output;
  for (const char* name : {"handles_held.png", "handles_held_shapes.png"})
  {
    ASSERT_TRUE(fs::exists(figures / name)) << name << "\n" << plot.output;
    EXPECT_GT(fs::file_size(figures / name), 5000u) << name;
  }
}

TEST_F(ModalCompareTool, BadHandleScenariosStopBeforeAnyWorkWithAMessageNamingThem)
{
  struct Case
  {
    std::string replace, with, named;
  };
  for (const Case& c : {Case{"translation: [0.1, 0.0, 0.0]", "translation: [0.1, 0.0]", "handle_scenarios[0].handles[0].translation"},
                        Case{"move_time: 0.2\n    hold", "move_tme: 0.2\n    hold", "handle_scenarios[0].move_tme"},
                        Case{"name: apart", "name: shift", "handle_scenarios[1].name"},
                        Case{"particles: [3]", "particles: [16]", "handles[1]' = 16"},
                        Case{"fixed: []", "fixed: [0]", "also be fixed"}})
  {
    std::string text = kHeldSheet;
    const size_t at = text.find(c.replace);
    ASSERT_NE(at, std::string::npos) << c.replace;
    text.replace(at, c.replace.size(), c.with);
    std::ofstream(dir_ / "bad.yaml") << text;
    const CommandResult r = run(tool("--config " + (dir_ / "bad.yaml").string() + " --experiment handles"));
    EXPECT_EQ(r.status, 2) << c.with << "\n" << r.output;
    EXPECT_NE(r.output.find(c.named), std::string::npos) << c.with << "\n" << r.output;
    EXPECT_FALSE(fs::exists(dir_ / "data")) << c.with << ": wrote output before refusing";
    fs::remove_all(dir_ / "data");
  }
  // The experiment needs scenarios.
  const CommandResult r = run(tool("--config " + config("paper_2d.yaml") + " --experiment handles"));
  EXPECT_EQ(r.status, 2) << r.output;
  EXPECT_NE(r.output.find("'handle_scenarios'"), std::string::npos) << r.output;
}

// When the memory estimate passes but the machine cannot give the memory, the tool says so: while it
// builds every setup before the first run, as bad input (exit code 2).
TEST_F(ModalCompareTool, OutOfMemoryIsAClearMessageNotACrash)
{
#ifdef __SANITIZE_ADDRESS__
  GTEST_SKIP() << "AddressSanitizer's shadow memory does not fit under ulimit -v; the plain build runs this test";
#endif
  // 300 MB of address space against a 1000 x 1000 grid that needs several GB.
  const CommandResult r = run("ulimit -v 300000; " + tool("--config " + config("paper_2d.yaml") +
                                                           " --set rows=1000 --set cols=1000 --set memory_limit_gb=100"
                                                           " --experiment accuracy --steps 10 --interval 10 --sample 10"));
  EXPECT_EQ(r.status, 2) << r.output;  // run() maps a signal to -1
  EXPECT_NE(r.output.find("out of memory"), std::string::npos) << r.output;
}

// A failure late in a run (here the machine's memory, taken by the second variant's snapshots of
// every particle at every step) names the variant and the cause, and the first variant's results,
// finished before it, are written.
TEST_F(ModalCompareTool, AFailureLateInARunKeepsWhatFinishedBeforeIt)
{
#ifdef __SANITIZE_ADDRESS__
  GTEST_SKIP() << "AddressSanitizer's shadow memory does not fit under ulimit -v; the plain build runs this test";
#endif
  const CommandResult r = run("ulimit -v 500000; " + tool("--config " + config("paper_2d.yaml") +
                                                           " --set cols=100 --set memory_limit_gb=100 --vary rows=5,100"
                                                           " --experiment accuracy --steps 1000 --interval 1 --sample 1"
                                                           " --methods linear"));
  EXPECT_EQ(r.status, 1) << r.output;
  EXPECT_NE(r.output.find("accuracy experiment, variant 'rows=100': out of memory"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("the results of the 1 accuracy setup(s) finished before it are written"), std::string::npos)
      << r.output;
  std::ifstream in(dir_ / "data" / "accuracy_paper_2d_error.csv");
  ASSERT_TRUE(in) << r.output;
  std::string line;
  int first = 0, second = 0;
  while (std::getline(in, line))
  {
    first += line.rfind("rows=5,linear,", 0) == 0;
    second += line.rfind("rows=100,", 0) == 0;
  }
  EXPECT_EQ(first, 1001);
  EXPECT_EQ(second, 0);
}

// A parameter the handles experiment needs (the moving frame holds one handle) is checked on its
// scenarios, not on the config's setup without handles: one scenario with one handle runs, and a
// scenario with two handles is refused by name before anything runs.
TEST_F(ModalCompareTool, HandleFormulationIsCheckedOnTheScenariosThatRunIt)
{
  std::string one = kHeldSheet;
  one = one.substr(0, one.find("  - name: apart"));
  std::ofstream(dir_ / "one.yaml") << one;
  const CommandResult r = run(tool("--config " + (dir_ / "one.yaml").string() +
                                   " --experiment handles --set handle_formulation=moving_frame --methods linear"));
  ASSERT_EQ(r.status, 0) << r.output;
  EXPECT_TRUE(fs::exists(dir_ / "data" / "handles_one_summary.csv")) << r.output;
  fs::remove_all(dir_ / "data");

  std::ofstream(dir_ / "two.yaml") << kHeldSheet;
  const CommandResult two = run(tool("--config " + (dir_ / "two.yaml").string() +
                                     " --experiment handles --set handle_formulation=moving_frame --methods linear"));
  EXPECT_EQ(two.status, 2) << two.output;
  EXPECT_NE(two.output.find("(apart): invalid parameter 'handle_formulation'"), std::string::npos) << two.output;
  EXPECT_FALSE(fs::exists(dir_ / "data")) << two.output;
}

TEST_F(ModalCompareTool, PlottingScriptRefusesACsvWithoutItsColumns)
{
  fs::create_directories(dir_ / "data");
  std::ofstream(dir_ / "data" / "stability_broken.csv") << "variant,method,dt\nbase,linear,0.1\n";
  const CommandResult plot = run("/usr/bin/python3 " + std::string(MODAL_SOURCE_DIR) + "/scripts/plot_comparison.py --data " +
                       (dir_ / "data").string() + " --out " + (dir_ / "figures").string());
  EXPECT_EQ(plot.status, 1);
  EXPECT_NE(plot.output.find("stable_dt"), std::string::npos) << plot.output;
}

TEST_F(ModalCompareTool, BadInputStopsBeforeAnyWorkWithAMessageNamingIt)
{
  struct Case
  {
    std::string args, named;
  };
  const std::string paper = "--config " + config("paper_2d.yaml");
  for (const Case& c : {Case{"--config /nonexistent/grid.yaml", "/nonexistent/grid.yaml"},
                        Case{paper + " --experiment speed", "speed"},
                        Case{paper + " --methods linear,quadratic", "quadratic"},
                        Case{paper + " --set num_modes=0", "num_modes"},
                        Case{paper + " --set num_modes=41", "num_modes"},
                        Case{paper + " --set time_step=-1", "time_step"},
                        Case{paper + " --set mass=heavy", "mass"},
                        Case{paper + " --set stifness=3", "stifness"},
                        Case{paper + " --vary integrator=explicit,sideways", "sideways"},
                        Case{paper + " --experiment cost --sizes 1,5", "--sizes"},
                        Case{paper + " --set num_modes=30 --experiment cost --sizes 5,3", "--sizes 3"},
                        Case{paper + " --sample 300", "--sample"},
                        Case{paper + " --experiment accuracy --reference-time-step 0.0003", "--reference-time-step"},
                        Case{paper + " --reference-time-step -1", "--reference-time-step"},
                        Case{paper + " --check-factor zero", "--check-factor"},
                        Case{paper + " --max-time-step 0", "--max-time-step"},
                        Case{paper + " --frobnicate", "--frobnicate"},
                        Case{paper + " --no-cache --cache-dir /tmp/x", "--cache-dir"},
                        Case{paper + " --cache-dir ''", "--cache-dir"},
                        Case{"--experiment accuracy", "--config"}})
  {
    const CommandResult r = run(tool(c.args));
    EXPECT_EQ(r.status, 2) << c.args << "\n" << r.output;
    EXPECT_NE(r.output.find(c.named), std::string::npos) << c.args << "\n" << r.output;
    EXPECT_FALSE(fs::exists(dir_ / "data")) << c.args << ": wrote output before refusing";
    fs::remove_all(dir_ / "data");
  }
}
