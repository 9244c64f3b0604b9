// Helpers shared by the core's gtests.
#pragma once

#include "modal_mass_spring/grid.h"

#include <functional>
#include <stdexcept>
#include <string>

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
