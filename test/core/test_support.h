// Helpers shared by the core's gtests.
#pragma once

#include "modal_mass_spring/contact.h"
#include "modal_mass_spring/grid.h"
#include "modal_mass_spring/simulation.h"

#include <gtest/gtest.h>

#include <functional>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

// The message of the std::invalid_argument that `build` throws, or "" when it throws none.
inline std::string refusal(const std::function<void()>& build)
{
  try
  {
    build();
  }
  catch (const std::invalid_argument& e)
  {
    return e.what();
  }
  return "";
}

inline bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

// The paper's 3D experiment: a 10 x 10 sheet turned 45 degrees about x (config/compare/paper_3d.yaml).
inline modal_mass_spring::GridParams paper3D()
{
  modal_mass_spring::GridParams g;
  g.rows = g.cols = 10;
  g.dimension = 3;
  g.rotation_deg = 45.0;
  return g;
}

// The sheet of config/cloth.yaml (unturned): n x n (20), 0.05 m, 5 g a particle, springs 50/20/5 N/m
// with bending, top row fixed.
inline modal_mass_spring::GridParams clothSheet(int n = 20)
{
  modal_mass_spring::GridParams g;
  g.rows = g.cols = n;
  g.spacing = 0.05;
  g.dimension = 3;
  g.mass = 0.005;
  g.structural_stiffness = 50.0;
  g.shear_stiffness = 20.0;
  g.bending = true;
  g.bending_stiffness = 5.0;
  return g;
}

// The cloth of config/compare/held_cloth.yaml: that sheet with nothing fixed, hanging at rest from its
// handles.
inline modal_mass_spring::GridParams heldCloth(std::vector<std::vector<int>> handles, int n = 20)
{
  modal_mass_spring::GridParams g = clothSheet(n);
  g.fixed = {};
  g.handles = std::move(handles);
  return g;
}

// The paper's 3D sheet at the 2D grid's size: 5 x 5, top row fixed, turned 45 degrees about x.
inline modal_mass_spring::GridParams turnedSheet()
{
  modal_mass_spring::GridParams g;
  g.dimension = 3;
  g.rotation_deg = 45.0;
  return g;
}

// A method with r modes at a time step (s) under an integrator; the other parameters their defaults.
inline modal_mass_spring::SimulationParams methodParams(
    modal_mass_spring::Method method, int r, double dt,
    modal_mass_spring::IntegratorKind integrator = modal_mass_spring::IntegratorKind::Explicit)
{
  modal_mass_spring::SimulationParams s;
  s.method = method;
  s.num_modes = r;
  s.time_step = dt;
  s.integrator = integrator;
  return s;
}

// A horizontal plane (the default friction) `gap` m below the lowest particle of the grid's initial positions.
inline modal_mass_spring::Collider tableBelow(const modal_mass_spring::GridParams& g, double gap)
{
  const modal_mass_spring::Grid grid(g);
  modal_mass_spring::Collider table;
  table.type = modal_mass_spring::ColliderType::Plane;
  table.point = Eigen::Vector3d(0.0, 0.0, grid.toPoints(grid.initialPositions()).row(2).minCoeff() - gap);
  return table;
}

// Prescribes a 3D grid's handles for the end of step k from their positions `start`: a rigid slide
// along x from rest at `acceleration` (m/s^2) and down at 0.1 m/s, the same for every run.
inline void slideHandles(modal_mass_spring::Simulation& sim, const Eigen::VectorXd& start, long k, double acceleration)
{
  const double t = (k + 1) * sim.params().time_step;
  Eigen::VectorXd x = start, v = Eigen::VectorXd::Zero(start.size()), a = v;
  for (Eigen::Index d = 0; d < x.size(); d += 3)
  {
    x[d] += 0.5 * acceleration * t * t, v[d] = acceleration * t, a[d] = acceleration;
    x[d + 2] -= 0.1 * t, v[d + 2] = -0.1;
  }
  sim.setHandleMotion(x, v, a);
}

// The largest distance (m) of a particle from where `positions` (a flat vector, as positions()) put it.
inline double largestParticleDistance(const modal_mass_spring::Simulation& sim, const Eigen::VectorXd& positions)
{
  return (sim.grid().toPoints(sim.positions()) - sim.grid().toPoints(positions)).colwise().norm().maxCoeff();
}

// The last implicit solve's Newton iterations of each method of expectPhysicalMatchesFull.
struct NewtonIterations
{
  int full = 0, physical = 0;
};

// Builds `full` and `physical` from parameters `s` (its method replaced) and steps them side by side:
// neither diverges, and with every mode kept they stay within 1e-7 m of each other while the grid
// moves by more than a centimetre.
inline void expectPhysicalMatchesFull(const modal_mass_spring::GridParams& g, modal_mass_spring::SimulationParams s,
                                      int steps, NewtonIterations& newton)
{
  s.method = modal_mass_spring::Method::Full;
  modal_mass_spring::Simulation full(g, s);
  s.method = modal_mass_spring::Method::Physical;
  modal_mass_spring::Simulation physical(g, s);
  for (int k = 0; k < steps; ++k)
  {
    ASSERT_FALSE(full.step().diverged);
    ASSERT_FALSE(physical.step().diverged);
  }
  newton = {full.lastNewtonIterations(), physical.lastNewtonIterations()};
  EXPECT_LT((full.positions() - physical.positions()).cwiseAbs().maxCoeff(), 1e-7);
  EXPECT_GT((full.positions() - full.grid().initialPositions()).cwiseAbs().maxCoeff(), 1e-2);
}
