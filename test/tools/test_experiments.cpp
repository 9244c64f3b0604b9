// The experiments against closed forms and the paper's central claim on the shipped 2D config.
#include "experiments.h"
#include "yaml_parameter_source.h"

#include "modal_mass_spring/parameters.h"

#include <gtest/gtest.h>

#include <cmath>
#include <map>

using namespace modal_mass_spring;

namespace
{

ExperimentSetup loadSetup(const std::string& config)
{
  const auto source = YamlParameterSource::fromFile(std::string(MODAL_SOURCE_DIR) + "/" + config);
  ExperimentSetup setup;
  setup.grid = loadGridParams(source);
  setup.sim = loadSimulationParams(source);
  return setup;
}

// Mean over the samples after step 0 of one column of one method.
double meanOf(const std::vector<ErrorSample>& samples, const std::string& method, double ErrorSample::*column)
{
  double sum = 0.0;
  int n = 0;
  for (const ErrorSample& e : samples)
    if (e.method == method && e.step > 0)
    {
      sum += e.*column;
      ++n;
    }
  return sum / n;
}

}  // namespace

// The explicit scheme on X'' = -omega^2 X is stable exactly for omega dt <= 2. One undamped mode
// under `linear` is that equation, so the bisection must land on 2 / omega.
TEST(Stability, SingleUndampedModeUnderLinearIsTwoOverOmega)
{
  ExperimentSetup setup;  // the paper's 5 x 5 grid, top row fixed, under gravity: the mode starts moving
  setup.sim.num_modes = 1;
  setup.sim.alpha = setup.sim.beta = 0.0;
  StabilityOptions options;
  options.methods = {Method::Linear};
  options.steps = 20000;
  options.tolerance = 1e-5;
  const std::vector<StabilityRow> rows = runStability(setup, options);
  ASSERT_EQ(rows.size(), 1u);
  const StabilityRow& r = rows[0];
  const double omega = Simulation(setup.grid, setup.sim).basis().frequencies[0];
  ASSERT_GT(omega, 0.0);
  EXPECT_DOUBLE_EQ(r.modal_bound, 2.0 / omega);
  // Just above 2 / omega the growth per step is only 1 + 2 sqrt(omega dt / 2 - 1), so a finite run
  // of S steps sees divergence a hair late: (ln(limit / amplitude) / 2S)^2, about 1e-7 here.
  EXPECT_NEAR(r.stable_dt, 2.0 / omega, 2e-5 * (2.0 / omega));
  EXPECT_LE(r.unstable_dt - r.stable_dt, options.tolerance * r.stable_dt);
  EXPECT_TRUE(r.below_stable);
}

TEST(Stability, ModalMethodsAllowLargerStepsThanFullOnThePaper2dSetup)
{
  const ExperimentSetup setup = loadSetup("config/compare/paper_2d.yaml");
  StabilityOptions options;
  options.steps = 3000;
  options.tolerance = 1e-2;
  std::map<std::string, StabilityRow> by_method;
  for (const StabilityRow& r : runStability(setup, options))
    by_method[r.method] = r;
  ASSERT_EQ(by_method.size(), 3u);
  // full is bounded by the highest frequency of all dofs, the modal methods by the basis.
  EXPECT_LT(by_method["full"].stable_dt, by_method["linear"].stable_dt);
  EXPECT_LT(by_method["full"].stable_dt, by_method["physical"].stable_dt);
  EXPECT_NEAR(by_method["linear"].stable_dt, by_method["linear"].modal_bound, 0.02 * by_method["linear"].modal_bound);
}

// The paper's claim: with forces computed in physical coordinates the modal simulation follows the
// reference, while the linear approximation drifts. Checked on the shipped 2D config, where gravity
// stretches the grid by more than its spacing.
TEST(Accuracy, PhysicalHasSmallerErrorThanLinearOnThePaper2dSetupAtLargeDeformation)
{
  const ExperimentSetup setup = loadSetup("config/compare/paper_2d.yaml");
  ASSERT_EQ(setup.grid.rows, 5);
  ASSERT_EQ(setup.grid.cols, 5);
  ASSERT_EQ(setup.sim.num_modes, 4);
  AccuracyOptions options;  // 5000 steps, as in the paper's figures
  const AccuracyResult result = runAccuracy(setup, options);
  ASSERT_TRUE(result.messages.empty()) << result.messages.front();

  double largest = 0.0;
  for (const ErrorSample& e : result.errors)
    if (e.method == "full")
      largest = std::max(largest, e.max_displacement);
  EXPECT_GT(largest, setup.grid.spacing) << "not a large deformation";

  const double linear = meanOf(result.errors, "linear", &ErrorSample::rms_distance);
  const double physical = meanOf(result.errors, "physical", &ErrorSample::rms_distance);
  EXPECT_LT(physical, 0.5 * linear) << "mean RMS distance to full: physical " << physical << " m, linear " << linear
                                    << " m";
  EXPECT_LT(meanOf(result.errors, "physical", &ErrorSample::max_distance),
            meanOf(result.errors, "linear", &ErrorSample::max_distance));
}

TEST(Accuracy, SamplesEveryMethodFromTheSameStateWithFullAsReference)
{
  ExperimentSetup setup;
  AccuracyOptions options;
  options.steps = 200;
  options.interval = 100;
  options.sample = 20;
  const AccuracyResult result = runAccuracy(setup, options);
  EXPECT_EQ(result.errors.size(), 3u * (200 / 20 + 1));
  EXPECT_EQ(result.snapshots.size(), 3u * 3u);  // steps 0, 100, 200
  for (const ErrorSample& e : result.errors)
  {
    if (e.method == "full" || e.step == 0)
    {
      EXPECT_EQ(e.max_distance, 0.0);
      EXPECT_EQ(e.rms_distance, 0.0);
    }
    EXPECT_LE(e.rms_distance, e.max_distance);
  }
  for (const Snapshot& s : result.snapshots)
    EXPECT_EQ(s.points.cols(), 25);
}

// Beyond the paper: against a converged reference (full, explicit, at a tenth of the step), `full` at the
// configured step is close to it, the reference agrees with itself at half its step, the modal
// methods are further off, and every compared method carries its wall time per step.
TEST(Accuracy, ConvergedReferenceMeasuresFullAndTheModalMethodsAlike)
{
  ExperimentSetup setup = loadSetup("config/compare/paper_2d.yaml");
  AccuracyOptions options;
  options.methods = {Method::Full, Method::Linear, Method::Physical};
  options.steps = 1000;
  options.interval = 500;
  options.sample = 50;
  options.reference_time_step = setup.sim.time_step / 10;
  const AccuracyResult result = runAccuracy(setup, options);
  ASSERT_TRUE(result.messages.empty()) << result.messages.front();
  std::map<std::string, AccuracySummary> by_method;
  for (const AccuracySummary& s : summarizeAccuracy(result.errors))
    by_method[s.method] = s;
  ASSERT_EQ(by_method.size(), 4u);  // reference, full, linear, physical
  EXPECT_EQ(by_method["reference"].max_rms, 0.0);
  EXPECT_GT(by_method["full"].max_rms, 0.0) << "full must be a separate run at the configured step";
  EXPECT_LT(by_method["full"].max_rms, 1e-3);
  EXPECT_LT(result.reference_check_max_rms, 0.1 * by_method["full"].max_rms + 1e-12);
  EXPECT_GT(by_method["physical"].mean_rms, 10.0 * by_method["full"].mean_rms);
  EXPECT_GT(by_method["linear"].mean_rms, by_method["physical"].mean_rms);
  for (const char* m : {"full", "linear", "physical"})
    EXPECT_GT(by_method[m].step_seconds_median, 0.0) << m;
  EXPECT_EQ(result.reference_check.size(), 1000u / 50 + 1);
  EXPECT_EQ(result.snapshots.size(), 4u * 3u);  // steps 0, 500, 1000

  options.reference_time_step = setup.sim.time_step / 2.5;
  EXPECT_THROW(runAccuracy(setup, options), std::invalid_argument);
}

// Beyond the paper: implicit physical stays stable at ten times the largest stable step of explicit physical.
TEST(Stability, ImplicitPhysicalIsStableAtTenTimesTheExplicitStepOnThePaper2dSetup)
{
  ExperimentSetup setup = loadSetup("config/compare/paper_2d.yaml");
  StabilityOptions options;
  options.methods = {Method::Physical};
  options.steps = 1000;
  options.tolerance = 0.05;
  const std::vector<StabilityRow> rows = runStability(setup, options);
  ASSERT_EQ(rows.size(), 1u);
  ASSERT_GT(rows[0].stable_dt, 0.0);
  ASSERT_TRUE(std::isfinite(rows[0].unstable_dt));
  EXPECT_FALSE(checkStableAt(setup, Method::Physical, rows[0].unstable_dt * 1.5, options.steps))
      << "the explicit scheme must diverge above its bound";
  setup.sim.integrator = IntegratorKind::Implicit;
  EXPECT_TRUE(checkStableAt(setup, Method::Physical, 10.0 * rows[0].stable_dt, options.steps));
}

TEST(Accuracy, RejectsASampleThatDoesNotDivideTheInterval)
{
  AccuracyOptions options;
  options.interval = 1000;
  options.sample = 300;
  EXPECT_THROW(runAccuracy(ExperimentSetup{}, options), std::invalid_argument);
}

// Cost rows are only checked for shape: speed is measured by the tool, never asserted.
TEST(Cost, ReportsEveryMethodAndSize)
{
  ExperimentSetup setup;
  CostOptions options;
  options.sizes = {4, 6};
  options.repeats = 2;
  options.min_repeat_seconds = 1e-3;
  options.build_repeats = 1;
  const std::vector<CostRow> rows = runCost(setup, options);
  ASSERT_EQ(rows.size(), 6u);
  EXPECT_EQ(rows[0].particles, 16);
  EXPECT_EQ(rows[3].particles, 36);
  EXPECT_EQ(rows[3].free_dofs, 2 * 30);
  for (const CostRow& r : rows)
  {
    EXPECT_GT(r.step_seconds, 0.0);
    EXPECT_GT(r.build_seconds, 0.0);
    EXPECT_GE(r.steps_per_repeat, 10);
  }
}
