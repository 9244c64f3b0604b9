// One set of parameter names for the node (ROS parameter server) and the tools (YAML files).
#pragma once

#include "modal_mass_spring/grid.h"
#include "modal_mass_spring/simulation.h"

#include <optional>
#include <string>
#include <vector>

namespace modal_mass_spring
{

// Where parameters come from. Each getter returns nothing when the key is absent and throws
// std::invalid_argument naming the key when it is present with the wrong type.
class ParameterSource
{
public:
  virtual ~ParameterSource() = default;
  virtual std::optional<int> getInt(const std::string& key) const = 0;
  virtual std::optional<double> getDouble(const std::string& key) const = 0;  // accepts integers too
  virtual std::optional<bool> getBool(const std::string& key) const = 0;
  virtual std::optional<std::string> getString(const std::string& key) const = 0;
  virtual std::optional<std::vector<int>> getIntList(const std::string& key) const = 0;
  virtual std::optional<std::vector<double>> getDoubleList(const std::string& key) const = 0;
};

// Reads every model and simulation parameter, defaults (GridParams{}, SimulationParams{}) where a key
// is absent. Throws std::invalid_argument naming the parameter, its value and what is allowed;
// the ranges themselves are checked when the Simulation is built.
//   rows, cols, spacing, dimension, mass, structural_stiffness, shear_stiffness, bending,
//   bending_stiffness, fixed, gravity, rotation_deg, method, num_modes, alpha, beta, time_step,
//   divergence_limit, linearization, integrator, initial_state, newton_max_iterations, implicit_solver,
//   equilibrium_max_iterations, hht_alpha, energy_tolerance,
//   memory_limit_gb, basis, num_derivative_modes, num_skinning_weights, cubature_tolerance, cubature_max_springs,
//   cubature_training_poses, cubature_max_training_poses, cubature_pose_size, cubature_seed,
//   contact_thickness, self_collision, self_collision_thickness, self_friction, coarse_cols
GridParams loadGridParams(const ParameterSource& source);
SimulationParams loadSimulationParams(const ParameterSource& source);

// The message for a present key of the wrong type, shared by the sources.
std::string wrongType(const std::string& key, const std::string& expected);
// The message for an integer parameter given a whole number outside int's range (`value` as
// written), shared by the sources: the range, not a wrong type.
std::string intOutOfRange(const std::string& key, const std::string& value);

}  // namespace modal_mass_spring
