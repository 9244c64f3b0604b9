// Grid topology, initial positions and parameter validation.
#include "modal_mass_spring/grid.h"
#include "modal_mass_spring/simulation.h"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <string>

using namespace modal_mass_spring;

TEST(Grid, CountsSpringsAndDofs)
{
  GridParams p;
  p.rows = 4;
  p.cols = 3;
  p.dimension = 3;
  const Grid grid(p);
  EXPECT_EQ(grid.numParticles(), 12);
  EXPECT_EQ(grid.numStructuralSprings(), 4 * 2 + 3 * 3);
  EXPECT_EQ(grid.numShearSprings(), 2 * 3 * 2);
  EXPECT_EQ(grid.numBendingSprings(), 0);
  EXPECT_EQ(grid.springs().size(), 17u + 12u);
  EXPECT_EQ(grid.fixedParticles().size(), 3u);  // the top row
  EXPECT_EQ(grid.numFreeDofs(), 3 * 9);

  p.bending = true;
  EXPECT_EQ(Grid(p).numBendingSprings(), 4 * 1 + 3 * 2);
}

TEST(Grid, RowsHangAlongMinusZColumnsAlongX)
{
  GridParams p;
  p.rows = 3;
  p.cols = 2;
  p.spacing = 0.5;
  const Grid grid(p);
  const Eigen::Matrix3Xd points = grid.toPoints(grid.initialPositions());
  EXPECT_DOUBLE_EQ(points(0, grid.particleIndex(2, 1)), 0.5);
  EXPECT_DOUBLE_EQ(points(2, grid.particleIndex(2, 1)), -1.0);
  for (const Spring& s : grid.springs())
    EXPECT_NEAR(s.rest_length, (points.col(s.j) - points.col(s.i)).norm(), 1e-15);
}

TEST(Grid, RotationAboutXKeepsRestLengths)
{
  GridParams p;
  p.dimension = 3;
  p.rotation_deg = 45.0;
  const Grid grid(p);
  const Eigen::Matrix3Xd points = grid.toPoints(grid.initialPositions());
  const int bottom = grid.particleIndex(p.rows - 1, 0);
  const double depth = (p.rows - 1) * p.spacing;
  EXPECT_NEAR(points(1, bottom), depth * std::sqrt(0.5), 1e-12);
  EXPECT_NEAR(points(2, bottom), -depth * std::sqrt(0.5), 1e-12);
  EXPECT_NEAR(grid.springs()[0].rest_length, p.spacing, 1e-12);
}

TEST(Grid, ExplicitFixedParticles)
{
  GridParams p;
  p.fixed = {0, 4};
  const Grid grid(p);
  EXPECT_TRUE(grid.isFixed(4));
  EXPECT_FALSE(grid.isFixed(1));
  EXPECT_EQ(grid.numFreeDofs(), 2 * 23);
  EXPECT_EQ(grid.freeIndex(0), -1);
  EXPECT_EQ(grid.freeDofs()[0], 2);
}

// Each bad parameter is refused with a message that names it and the value.
void expectRejected(const std::function<void(GridParams&, SimulationParams&)>& spoil, const std::string& name,
                    const std::string& value)
{
  GridParams grid;
  SimulationParams sim;
  spoil(grid, sim);
  try
  {
    Simulation simulation(grid, sim);
    FAIL() << "accepted a bad '" << name << "'";
  }
  catch (const std::invalid_argument& e)
  {
    const std::string what = e.what();
    EXPECT_NE(what.find("'" + name + "'"), std::string::npos) << what;
    EXPECT_NE(what.find(value), std::string::npos) << what;
    EXPECT_NE(what.find("must"), std::string::npos) << what;
  }
}

TEST(Grid, BadParametersAreRefusedByName)
{
  const double nan = std::nan("");
  expectRejected([](GridParams& g, SimulationParams&) { g.rows = 0; }, "rows", "0");
  expectRejected([](GridParams& g, SimulationParams&) { g.cols = -2; }, "cols", "-2");
  expectRejected([](GridParams& g, SimulationParams&) { g.rows = 1; g.cols = 1; }, "rows x cols", "1 x 1");
  expectRejected([](GridParams& g, SimulationParams&) { g.spacing = 0.0; }, "spacing", "0");
  expectRejected([nan](GridParams& g, SimulationParams&) { g.mass = nan; }, "mass", "nan");
  expectRejected([](GridParams& g, SimulationParams&) { g.structural_stiffness = -1; }, "structural_stiffness", "-1");
  expectRejected([](GridParams& g, SimulationParams&) { g.shear_stiffness = 0; }, "shear_stiffness", "0");
  expectRejected([](GridParams& g, SimulationParams&) { g.bending = true; g.bending_stiffness = 0; },
                 "bending_stiffness", "0");
  expectRejected([](GridParams& g, SimulationParams&) { g.fixed = {0, 25}; }, "fixed", "25");
  expectRejected([](GridParams& g, SimulationParams&) { g.fixed = {3, 3}; }, "fixed", "3");
  expectRejected([](GridParams& g, SimulationParams&) {
    for (int i = 0; i < 25; ++i)
      g.fixed.push_back(i);
  }, "fixed", "25 of 25");
  expectRejected([](GridParams& g, SimulationParams&) { g.dimension = 4; }, "dimension", "4");
  expectRejected([](GridParams& g, SimulationParams&) { g.gravity.y() = 1.0; }, "gravity", "1");
  expectRejected([](GridParams& g, SimulationParams&) { g.rotation_deg = 45; }, "rotation_deg", "45");
  expectRejected([](GridParams&, SimulationParams& s) { s.num_modes = 0; }, "num_modes", "0");
  expectRejected([](GridParams&, SimulationParams& s) { s.num_modes = 41; }, "num_modes", "41");
  expectRejected([](GridParams&, SimulationParams& s) { s.time_step = 0; }, "time_step", "0");
  expectRejected([](GridParams&, SimulationParams& s) { s.time_step = -1e-3; }, "time_step", "-0.001");
  expectRejected([](GridParams&, SimulationParams& s) { s.alpha = -1; }, "alpha", "-1");
  expectRejected([](GridParams&, SimulationParams& s) { s.beta = std::nan(""); }, "beta", "nan");
}

TEST(Method, NamesRoundTripAndUnknownIsRefused)
{
  for (const std::string& name : methodNames())
    EXPECT_EQ(toString(parseMethod(name)), name);
  try
  {
    parseMethod("quadratic");
    FAIL();
  }
  catch (const std::invalid_argument& e)
  {
    EXPECT_NE(std::string(e.what()).find("quadratic"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("full, linear, physical"), std::string::npos);
  }
}
