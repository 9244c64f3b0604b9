// How far apart two configurations of a grid are as surfaces, not particle by particle.
#pragma once

#include "modal_mass_spring/grid.h"

#include <Eigen/Core>

namespace modal_mass_spring
{

// The RMS over the free particles (neither fixed nor held) of `a` of their distance to the surface
// of `b` (the grid's triangles at b's positions), and of b's to a's, taken together (m). Where a
// cloth crumples, two runs that fold it alike with their particles slid along it are close by this
// measure and far apart particle by particle. A grid of one row or column has no surface: its
// polyline is used.
double surfaceDistance(const Grid& grid, const Eigen::Matrix3Xd& a, const Eigen::Matrix3Xd& b);

}  // namespace modal_mass_spring
