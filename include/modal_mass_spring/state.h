// A method's generalized state: u for `full`, the coordinates X for the modal methods.
#pragma once

#include <Eigen/Core>

namespace modal_mass_spring
{

// Displacement, velocity, acceleration.
struct State
{
  Eigen::VectorXd q, v, a;
};

}  // namespace modal_mass_spring
