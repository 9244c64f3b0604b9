// Parameter names and types shared by the node and the tools.
#include "modal_mass_spring/parameters.h"

#include "modal_mass_spring/parameter_error.h"

#include <limits>
#include <stdexcept>

namespace modal_mass_spring
{

std::string wrongType(const std::string& key, const std::string& expected)
{
  return "invalid parameter '" + key + "': wrong type, must be " + expected;
}

std::string intOutOfRange(const std::string& key, const std::string& value)
{
  return "invalid parameter '" + key + "' = " + value + ": must be an integer in [" +
         std::to_string(std::numeric_limits<int>::min()) + ", " + std::to_string(std::numeric_limits<int>::max()) +
         "] (a whole number beyond 32-bit int)";
}

GridParams loadGridParams(const ParameterSource& s)
{
  GridParams p;
  p.rows = s.getInt("rows").value_or(p.rows);
  p.cols = s.getInt("cols").value_or(p.cols);
  p.spacing = s.getDouble("spacing").value_or(p.spacing);
  p.dimension = s.getInt("dimension").value_or(p.dimension);
  p.mass = s.getDouble("mass").value_or(p.mass);
  p.structural_stiffness = s.getDouble("structural_stiffness").value_or(p.structural_stiffness);
  p.shear_stiffness = s.getDouble("shear_stiffness").value_or(p.shear_stiffness);
  p.bending = s.getBool("bending").value_or(p.bending);
  p.bending_stiffness = s.getDouble("bending_stiffness").value_or(p.bending_stiffness);
  p.fixed = s.getIntList("fixed").value_or(p.fixed);
  if (const auto gravity = s.getDoubleList("gravity"))
  {
    if (gravity->size() != 3)
      throw std::invalid_argument("invalid parameter 'gravity': has " + std::to_string(gravity->size()) +
                                  " values, must be a list of 3 numbers [x, y, z] in m/s^2");
    p.gravity = Eigen::Vector3d((*gravity)[0], (*gravity)[1], (*gravity)[2]);
  }
  p.rotation_deg = s.getDouble("rotation_deg").value_or(p.rotation_deg);
  return p;
}

SimulationParams loadSimulationParams(const ParameterSource& s)
{
  SimulationParams p;
  // `adaptive` runs adaptive_method, read below, through an AdaptiveStepper.
  const auto method = s.getString("method");
  p.adaptive = method && *method == "adaptive";
  if (method && !p.adaptive)
  {
    try
    {
      p.method = parseMethod(*method);
    }
    catch (const std::invalid_argument&)
    {
      rejectParameter("method", "'" + *method + "'", "must be one of " + methodList() + ", adaptive");
    }
  }
  p.num_modes = s.getInt("num_modes").value_or(p.num_modes);
  p.alpha = s.getDouble("alpha").value_or(p.alpha);
  p.beta = s.getDouble("beta").value_or(p.beta);
  p.time_step = s.getDouble("time_step").value_or(p.time_step);
  p.divergence_limit = s.getDouble("divergence_limit").value_or(p.divergence_limit);
  if (const auto name = s.getString("linearization"))
    p.linearization = parseLinearization(*name);
  if (const auto name = s.getString("integrator"))
    p.integrator = parseIntegrator(*name);
  if (const auto name = s.getString("initial_state"))
    p.initial_state = parseInitialState(*name);
  if (const auto name = s.getString("implicit_solver"))
    p.implicit_solver = parseImplicitSolver(*name);
  p.newton_max_iterations = s.getInt("newton_max_iterations").value_or(p.newton_max_iterations);
  p.tangent_refresh_steps = s.getInt("tangent_refresh_steps").value_or(p.tangent_refresh_steps);
  if (const auto name = s.getString("adaptive_method"))
    p.adaptive_method = parseMethod(*name);
  if (p.adaptive)
    p.method = p.adaptive_method;
  p.error_tolerance = s.getDouble("error_tolerance").value_or(p.error_tolerance);
  p.adaptive_dwell = s.getDouble("adaptive_dwell").value_or(p.adaptive_dwell);
  p.adaptive_check_steps = s.getInt("adaptive_check_steps").value_or(p.adaptive_check_steps);
  p.equilibrium_max_iterations = s.getInt("equilibrium_max_iterations").value_or(p.equilibrium_max_iterations);
  p.hht_alpha = s.getDouble("hht_alpha").value_or(p.hht_alpha);
  p.energy_tolerance = s.getDouble("energy_tolerance").value_or(p.energy_tolerance);
  p.contact_thickness = s.getDouble("contact_thickness").value_or(p.contact_thickness);
  p.self_collision = s.getBool("self_collision").value_or(p.self_collision);
  p.self_collision_thickness = s.getDouble("self_collision_thickness").value_or(p.self_collision_thickness);
  p.self_friction = s.getDouble("self_friction").value_or(p.self_friction);
  p.memory_limit_gb = s.getDouble("memory_limit_gb").value_or(p.memory_limit_gb);
  if (const auto name = s.getString("basis"))
    p.basis = parseBasis(*name);
  p.num_derivative_modes = s.getInt("num_derivative_modes").value_or(p.num_derivative_modes);
  p.num_skinning_weights = s.getInt("num_skinning_weights").value_or(p.num_skinning_weights);
  p.cubature_tolerance = s.getDouble("cubature_tolerance").value_or(p.cubature_tolerance);
  p.cubature_max_springs = s.getInt("cubature_max_springs").value_or(p.cubature_max_springs);
  p.cubature_training_poses = s.getInt("cubature_training_poses").value_or(p.cubature_training_poses);
  p.cubature_max_training_poses = s.getInt("cubature_max_training_poses").value_or(p.cubature_max_training_poses);
  p.cubature_pose_size = s.getDouble("cubature_pose_size").value_or(p.cubature_pose_size);
  p.cubature_seed = s.getInt("cubature_seed").value_or(p.cubature_seed);
  p.coarse_cols = s.getInt("coarse_cols").value_or(p.coarse_cols);
  if (const auto name = s.getString("handle_formulation"))
    p.handle_formulation = parseHandleFormulation(*name);
  return p;
}

}  // namespace modal_mass_spring
