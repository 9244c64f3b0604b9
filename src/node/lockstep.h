// The methods of a live comparison without ROS: full ones started from the state of a reduced one, and
// each grid's distance to the reference.
#pragma once

#include "modal_mass_spring/simulation.h"

#include <Eigen/Core>

#include <vector>

namespace modal_mass_spring
{

// Puts every `full` simulation at the state of the source (the same displacement and velocity), so that
// the distances between them measure the methods, not their start. The source is the first reduced
// simulation or, when `first_is_source` (a single method with its shadow full), the first. Returns the
// indices of the simulations set; none when there is no source (every method full).
std::vector<size_t> synchroniseFull(const std::vector<Simulation*>& simulations, bool first_is_source);

// How far a grid's particles are from the same particles of the reference (3 x n each, m).
struct ParticleDistances
{
  double rms = 0.0;
  double max = 0.0;
};
ParticleDistances particleDistances(const Eigen::Matrix3Xd& points, const Eigen::Matrix3Xd& reference);

}  // namespace modal_mass_spring
