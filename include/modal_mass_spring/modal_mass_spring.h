// The core library's API in one include: build a Simulation from GridParams and SimulationParams (or
// from a parameter source, parameters.h), step it, switch methods, move handles and colliders, read
// positions, energies and forces. Everything here is ROS-free (Eigen only).
#pragma once

#include "modal_mass_spring/adaptive.h"
#include "modal_mass_spring/contact.h"
#include "modal_mass_spring/grid.h"
#include "modal_mass_spring/handles.h"
#include "modal_mass_spring/options.h"
#include "modal_mass_spring/parameters.h"
#include "modal_mass_spring/simulation.h"
#include "modal_mass_spring/spring_forces.h"
#include "modal_mass_spring/spring_law.h"
#include "modal_mass_spring/surface_distance.h"
#include "modal_mass_spring/validation.h"
