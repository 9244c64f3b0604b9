// The benchmarks' swinging cloth, one definition for core_benchmark and bullet_peer.
#pragma once

#include "modal_mass_spring/grid.h"

namespace modal_mass_spring
{

// The cloth of config/cloth_large.yaml at size x size particles: 0.99 m wide, 2 kg in all,
// structural/shear/bending springs of 200/80/20 N/m, top row fixed, released 60 degrees out of the
// vertical.
inline GridParams swingingCloth(int size)
{
  GridParams g;
  g.rows = g.cols = size;
  g.dimension = 3;
  g.spacing = 0.99 / (size - 1);
  g.mass = 2.0 / (size * size);
  g.structural_stiffness = 200.0;
  g.shear_stiffness = 80.0;
  g.bending = true;
  g.bending_stiffness = 20.0;
  g.rotation_deg = 60.0;
  return g;
}

}  // namespace modal_mass_spring
