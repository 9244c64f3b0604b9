// The checks of a simulation's parameters, with the memory estimate they hold against memory_limit_gb.
#pragma once

#include "modal_mass_spring/parameter_error.h"

namespace modal_mass_spring
{

struct GridParams;
struct SimulationParams;

// Throws std::invalid_argument (rejectParameter) for the first invalid parameter of either set,
// naming it, its value and what is allowed: the grid's (validateGridParams), then the simulation's,
// num_modes against the grid's free degrees of freedom, the scales the physics derives from them
// (frequencies, forces, energies must stay far from overflow and underflow) and the memory the
// build would need against memory_limit_gb. Builds nothing: cheap on any grid size.
void validateParameters(const GridParams& grid, const SimulationParams& params);

// Peak memory (bytes) a Simulation with these (valid) parameters needs: the stiffness matrix, its
// sparse factorisations (basis, equilibrium, implicit full), the basis with the eigensolver's
// vectors and the force models' copies, the per-dof vectors, and with method `cubature` its
// training. An estimate, within a factor of about 1.5 of what was measured.
double estimateMemoryBytes(const GridParams& grid, const SimulationParams& params);
// What the cubature's training adds (whatever params.method), with its training set grown to the most.
double cubatureTrainingBytes(const GridParams& grid, const SimulationParams& params);

}  // namespace modal_mass_spring
