// Bad and extreme parameters refused by name before anything is built (validateParameters), and the
// memory estimate held against memory_limit_gb.
#include "modal_mass_spring/simulation.h"
#include "modal_mass_spring/validation.h"

#include "test_support.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cctype>
#include <functional>
#include <string>
#include <utility>
#include <vector>

using namespace modal_mass_spring;

TEST(Validation, GridSizesAreCountedIn64Bits)
{
  for (const auto& [rows, cols] : {std::pair{65538, 65536}, std::pair{46341, 46341}, std::pair{2, 536870912}})
  {
    GridParams g;
    g.rows = rows;
    g.cols = cols;
    const std::string message = refusal([&] { validateParameters(g, SimulationParams{}); });
    EXPECT_TRUE(contains(message, "'rows x cols' = " + std::to_string(rows) + " x " + std::to_string(cols)))
        << message;
    EXPECT_TRUE(contains(message, std::to_string(static_cast<long long>(rows) * cols) + " particles")) << message;
    const auto negative = std::adjacent_find(message.begin(), message.end(),
                                             [](char a, char b) { return a == '-' && std::isdigit(b); });
    EXPECT_EQ(negative, message.end()) << "a negative count: " << message;
  }
}

TEST(Validation, ProblemTooLargeForTheMemoryLimitIsRefusedBeforeBuilding)
{
  GridParams g;
  g.rows = g.cols = 2000;
  SimulationParams s;
  s.num_modes = 30;
  const std::string message = refusal([&] { Simulation sim(g, s); });
  EXPECT_TRUE(contains(message, "'rows, cols, num_modes' = 2000 x 2000 grid (2D), num_modes = 30")) << message;
  EXPECT_TRUE(contains(message, "memory_limit_gb = 12")) << message;
  // The same problem passes with a limit above its estimate, and a small one below the default.
  s.memory_limit_gb = 2.0 * estimateMemoryBytes(g, s) / 1e9;
  EXPECT_EQ(refusal([&] { validateParameters(g, s); }), "");
  g.rows = g.cols = 100;
  s = SimulationParams{};
  EXPECT_EQ(refusal([&] { validateParameters(g, s); }), "");
  EXPECT_LT(estimateMemoryBytes(g, s), 1e9);
  s.memory_limit_gb = 0.0;
  EXPECT_TRUE(contains(refusal([&] { validateParameters(g, s); }), "'memory_limit_gb' = 0")) ;
}

TEST(Validation, ExtremeFiniteValuesAreRefusedNamingTheirParameters)
{
  struct Case
  {
    std::function<void(GridParams&)> change;
    std::string named;
  };
  const std::vector<Case> cases{
      {[](GridParams& g) { g.mass = 1e300; }, "'structural_stiffness / mass'"},
      {[](GridParams& g) { g.structural_stiffness = 1e-300; }, "'structural_stiffness / mass'"},
      {[](GridParams& g) { g.shear_stiffness = 1e300; }, "'shear_stiffness"},
      {[](GridParams& g) { g.spacing = 1e-300; }, "'spacing'"},
      {[](GridParams& g) { g.spacing = 1e200; }, "'spacing'"},
      {[](GridParams& g) {
         g.bending = true;
         g.bending_stiffness = 1e-250;
       },
       "'bending_stiffness"},
  };
  for (const Case& c : cases)
  {
    GridParams g;
    c.change(g);
    const std::string message = refusal([&] { Simulation sim(g, SimulationParams{}); });
    EXPECT_TRUE(contains(message, c.named)) << "expected " << c.named << " in: " << message;
  }
}

TEST(Validation, SimulationParametersAreRefusedByName)
{
  auto refused = [](const std::function<void(SimulationParams&)>& change) {
    SimulationParams s;
    change(s);
    return refusal([&] { validateParameters(GridParams{}, s); });
  };
  EXPECT_TRUE(contains(refused([](SimulationParams& s) { s.num_modes = 41; }), "'num_modes' = 41: must be in [1, 40]"));
  EXPECT_TRUE(contains(refused([](SimulationParams& s) { s.hht_alpha = -0.5; }), "'hht_alpha' = -0.5"));
  EXPECT_TRUE(contains(refused([](SimulationParams& s) { s.hht_alpha = 0.1; }), "'hht_alpha' = 0.1"));
  EXPECT_TRUE(contains(refused([](SimulationParams& s) { s.energy_tolerance = 0.0; }), "'energy_tolerance' = 0"));
  EXPECT_TRUE(contains(refused([](SimulationParams& s) { s.newton_max_iterations = 0; }), "'newton_max_iterations' = 0"));
  EXPECT_TRUE(contains(refused([](SimulationParams& s) { s.tangent_refresh_steps = 0; }), "'tangent_refresh_steps' = 0"));
  { const std::string m = refused([](SimulationParams& s) { s.error_tolerance = -0.01; }); EXPECT_TRUE(contains(m, "'error_tolerance' = -0.01")) << m; }
  EXPECT_TRUE(contains(refused([](SimulationParams& s) { s.adaptive_dwell = INFINITY; }), "'adaptive_dwell' = inf"));
  EXPECT_TRUE(contains(refused([](SimulationParams& s) { s.adaptive_method = Method::Full; }),
                       "'adaptive_method' = 'full': must be one of physical, cubature, coarse"));
  EXPECT_TRUE(contains(refused([](SimulationParams& s) { s.equilibrium_max_iterations = 0; }),
                       "'equilibrium_max_iterations' = 0"));
  EXPECT_TRUE(contains(refused([](SimulationParams& s) { s.time_step = -1.0; }), "'time_step' = -1"));
}
