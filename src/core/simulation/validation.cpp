// The checks of a simulation's parameters, before anything is built, and the memory estimate they
// hold against memory_limit_gb.
#include "modal_mass_spring/validation.h"

#include "modal_mass_spring/adaptive.h"
#include "modal_mass_spring/simulation.h"
#include "reduction/coarse_grid.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

namespace modal_mass_spring
{

namespace
{

void requireNonNegative(const std::string& name, double value)
{
  if (!std::isfinite(value) || value < 0.0)
    rejectParameter(name, value, "must be a finite number >= 0");
}

void validateTimeStep(double dt)
{
  if (!std::isfinite(dt) || dt <= 0.0)
    rejectParameter("time_step", dt, "must be a finite number of seconds > 0");
}

// A derived scale must be a number the physics can square and sum without overflow or underflow.
bool representable(double value)
{
  return std::isfinite(value) && value > 0.0 && value >= 1e-100 && value <= 1e100;
}

// Refuses parameters whose combinations would give infinite or vanishing frequencies, forces or
// energies later on (for example mass 1e300: lambda^2 = k / m underflows; spacing 1e-300: lengths
// squared underflow), naming the parameters responsible.
void validateScales(const GridParams& g)
{
  const double side = g.spacing * std::max(g.rows, g.cols);
  if (!representable(g.spacing * g.spacing) || !representable(side * side))
    rejectParameter("spacing", g.spacing,
                    "must keep spacing^2 and the grid's side squared within [1e-100, 1e100] m^2 (lengths are squared)");
  std::vector<std::pair<std::string, double>> stiffnesses{{"structural_stiffness", g.structural_stiffness},
                                                          {"shear_stiffness", g.shear_stiffness}};
  if (g.bending)
    stiffnesses.emplace_back("bending_stiffness", g.bending_stiffness);
  for (const auto& [name, k] : stiffnesses)
  {
    std::ostringstream value;
    value << k << " with mass = " << g.mass << " and spacing = " << g.spacing;
    if (!representable(k / g.mass))
      rejectParameter(name + " / mass", value.str(),
                      "lambda^2 = stiffness / mass must be within [1e-100, 1e100] s^-2 (frequencies would overflow or vanish)");
    if (!representable(k * g.spacing * g.spacing * static_cast<double>(g.rows) * g.cols))
      rejectParameter(name + " * spacing^2", value.str(),
                      "spring energies (stiffness * spacing^2 per spring) must be within [1e-100, 1e100] J");
  }
  const double weight = g.mass * g.gravity.norm();
  if (weight > 0.0 && !representable(weight * side * static_cast<double>(g.rows) * g.cols))
  {
    std::ostringstream value;
    value << g.mass << " with gravity " << g.gravity.norm() << " m/s^2 and spacing = " << g.spacing;
    rejectParameter("mass", value.str(), "the grid's weight times its size must be within [1e-100, 1e100] J");
  }
}

// basis and num_derivative_modes: checks that need no build (the derivatives' own span is checked
// when they are computed).
void validateBasis(const GridParams& grid, const SimulationParams& p, long long n)
{
  const long long d = p.num_derivative_modes;
  if (d < 0)
    rejectParameter("num_derivative_modes", d, "must be an integer >= 0");
  const long long w = p.num_skinning_weights;
  const long long particles = static_cast<long long>(grid.rows) * grid.cols;
  if (p.basis == BasisKind::Skinning)
  {
    // One weight per held group (each handle, the fixed particles), then at most one per particle
    // neither held nor fixed (skinningWeights); nothing held, at most one per particle.
    const long long fixed = static_cast<long long>(effectiveFixed(grid).size());
    long long held = fixed;
    for (const std::vector<int>& handle : grid.handles)
      held += static_cast<long long>(handle.size());
    const long long groups = static_cast<long long>(grid.handles.size()) + (fixed > 0 ? 1 : 0);
    const long long lowest = std::max(1LL, groups);
    const long long highest = held == 0 ? particles : particles - held + groups;
    if (w < lowest || w > highest)
      rejectParameter("num_skinning_weights", w,
                      "must be an integer in [" + std::to_string(lowest) + ", " + std::to_string(highest) +
                          "] with basis: skinning (one weight per handle and one for the fixed particles, then at "
                          "most one per particle neither held nor fixed)");
    if (d != 0)
      rejectParameter("num_derivative_modes", d, "must be 0 with basis: skinning");
    return;
  }
  if (w != 0)
    rejectParameter("num_skinning_weights", w,
                    "must be 0 unless basis is skinning (weights are used only by the skinning subspace)");
  if (p.basis == BasisKind::LinearModes)
  {
    if (d != 0)
      rejectParameter("num_derivative_modes", d,
                      "must be 0 with basis: linear_modes (derivative directions are added only with basis: "
                      "modal_derivatives)");
    return;
  }
  if (grid.dimension == 3 && p.linearization == Linearization::Rest)
    rejectParameter("basis", "modal_derivatives",
                    "needs a stiffness without zero modes, and a 3D sheet at rest has none out of its plane; use "
                    "linearization: equilibrium, or basis: linear_modes");
  const long long r = p.num_modes;
  const long long pairs = r * (r + 1) / 2;
  if (d < 1 || d > pairs || r + d > n)
    rejectParameter("num_derivative_modes", d,
                    "must be in [1, " + std::to_string(std::min(pairs, n - r)) + "] with basis: modal_derivatives: at most the " +
                        std::to_string(pairs) + " pairs of the num_modes = " + std::to_string(r) +
                        " linear modes, and num_modes + num_derivative_modes at most the " + std::to_string(n) +
                        " free degrees of freedom");
}

// The damping, the time step, the divergence checks and the integrators' settings.
void validateIntegration(const SimulationParams& p)
{
  requireNonNegative("alpha", p.alpha);
  requireNonNegative("beta", p.beta);
  validateTimeStep(p.time_step);
  requireNonNegative("divergence_limit", p.divergence_limit);
  if (!std::isfinite(p.energy_tolerance) || p.energy_tolerance <= 0.0)
    rejectParameter("energy_tolerance", p.energy_tolerance,
                    "must be a finite number > 0 (the energy rise, relative to the grid's energy scale, that counts as divergence)");
  if (p.newton_max_iterations < 1)
    rejectParameter("newton_max_iterations", p.newton_max_iterations, "must be an integer >= 1");
  validateAdaptiveSettings(adaptiveSettings(p));
  if (p.tangent_refresh_steps < 1)
    rejectParameter("tangent_refresh_steps", p.tangent_refresh_steps, "must be an integer >= 1");
  if (p.equilibrium_max_iterations < 1)
    rejectParameter("equilibrium_max_iterations", p.equilibrium_max_iterations, "must be an integer >= 1");
  if (!std::isfinite(p.hht_alpha) || p.hht_alpha < -1.0 / 3.0 || p.hht_alpha > 0.0)
    rejectParameter("hht_alpha", p.hht_alpha, "must be in [-1/3, 0] (0: Newmark average acceleration)");
}

// The cubature's training settings.
void validateCubatureSettings(const GridParams& grid, const SimulationParams& p)
{
  if (!std::isfinite(p.cubature_tolerance) || p.cubature_tolerance <= 0.0 || p.cubature_tolerance >= 1.0)
    rejectParameter("cubature_tolerance", p.cubature_tolerance,
                    "must be in (0, 1) (the relative force error on the training and validation poses)");
  const long long springs = countSprings(grid);
  if (p.cubature_max_springs < 0 || p.cubature_max_springs > springs)
    rejectParameter("cubature_max_springs", p.cubature_max_springs,
                    "must be 0 (up to min(number of springs, " + std::to_string(kDefaultMaxSprings) +
                        ")) or in [1, " + std::to_string(springs) + "], the number of springs");
  if (p.cubature_training_poses < 1)
    rejectParameter("cubature_training_poses", p.cubature_training_poses, "must be an integer >= 1");
  if (p.cubature_max_training_poses != 0 && p.cubature_max_training_poses < p.cubature_training_poses)
    rejectParameter("cubature_max_training_poses", p.cubature_max_training_poses,
                    "must be 0 (up to " + std::to_string(kDefaultPoseGrowth) +
                        " times cubature_training_poses) or an integer >= cubature_training_poses (" +
                        std::to_string(p.cubature_training_poses) + ")");
  if (!std::isfinite(p.cubature_pose_size) || p.cubature_pose_size <= 0.0)
    rejectParameter("cubature_pose_size", p.cubature_pose_size,
                    "must be a finite number of metres > 0 (the largest particle displacement of a training pose)");
  if (p.cubature_seed < 0)
    rejectParameter("cubature_seed", p.cubature_seed, "must be an integer >= 0");
}

// The moving frame needs handles moved as one body and no fixed particle.
void validateMovingFrame(const GridParams& grid, const SimulationParams& p)
{
  if (p.handle_formulation == HandleFormulation::MovingFrame)
  {
    const std::string value = "moving_frame";
    if (grid.handles.empty())
      rejectParameter("handle_formulation", value,
                      "needs handles (the grid has none); allowed without handles: auto or constraint_modes");
    const std::vector<int> fixed = effectiveFixed(grid);
    if (!fixed.empty())
      rejectParameter("handle_formulation", value,
                      "needs a grid with no fixed particles (it has " + std::to_string(fixed.size()) +
                          "): a fixed particle cannot move with the frame; hold it with the handle (fixed: [] and "
                          "handles) or use constraint_modes or auto");
    if (!p.handles_one_body)
      rejectParameter("handle_formulation", value,
                      "needs every handle moved as one rigid body (handles_one_body; in the node: every handle on "
                      "one TF frame); handles moving apart need constraint_modes or auto");
  }
}

// The colliders, their thickness, and self-collision, with the formulations and methods they allow.
void validateContactSettings(const GridParams& grid, const SimulationParams& p)
{
  for (size_t i = 0; i < p.colliders.size(); ++i)
    validateCollider(p.colliders[i], "colliders[" + std::to_string(i) + "]", grid.dimension);
  validateContactThickness(p.contact_thickness, grid.spacing);
  if (!p.colliders.empty() && p.handle_formulation == HandleFormulation::MovingFrame)
    rejectParameter("handle_formulation", "moving_frame",
                    "cannot be used with colliders (contact is resolved in world coordinates); use auto or constraint_modes");
  validateSelfCollision(grid, p.self_collision, p.self_collision_thickness, p.self_friction);
  if (p.self_collision && p.method != Method::Full)
    rejectParameter("method", toString(p.method), kSelfCollisionMethods);
}

// The memory estimate against memory_limit_gb.
void validateMemory(const GridParams& grid, const SimulationParams& p)
{
  if (!std::isfinite(p.memory_limit_gb) || p.memory_limit_gb <= 0.0)
    rejectParameter("memory_limit_gb", p.memory_limit_gb, "must be a finite number of GB > 0");
  const double needed_gb = estimateMemoryBytes(grid, p) / 1e9;
  if (needed_gb > p.memory_limit_gb)
  {
    // Blame what takes most of it: the cubature's training poses, or the grid and its modes.
    const double training_gb = p.method == Method::Cubature ? cubatureTrainingBytes(grid, p) / 1e9 : 0.0;
    const bool training = training_gb > 0.5 * needed_gb;
    std::ostringstream value;
    std::ostringstream allowed;
    allowed.precision(3);
    if (training)
    {
      value << p.cubature_training_poses << " training poses, up to " << effectiveMaxTrainingPoses(cubatureParams(p))
            << " grown, num_modes = " << p.num_modes;
      allowed << "the cubature's training would need about " << training_gb << " GB of the " << needed_gb << " GB estimated, ";
    }
    else
    {
      value << grid.rows << " x " << grid.cols << " grid (" << grid.dimension << "D), num_modes = " << p.num_modes;
      allowed << "needs about " << needed_gb << " GB";
      if (training_gb > 0.0)
        allowed << " (the cubature's training about " << training_gb << " GB of it)";
      allowed << ", ";
    }
    allowed << "above memory_limit_gb = " << p.memory_limit_gb << " GB; "
            << (training ? "use fewer cubature_training_poses or a smaller cubature_max_training_poses or cubature_max_springs"
                         : "use a smaller grid or fewer modes")
            << ", or raise memory_limit_gb if the machine has the memory";
    rejectParameter(training ? "cubature_training_poses, cubature_max_training_poses" : "rows, cols, num_modes",
                    value.str(), allowed.str());
  }
}

}  // namespace

// Refuses a particle index outside [0, num_particles - 1] or listed twice.
void validateParameters(const GridParams& grid, const SimulationParams& p)
{
  validateGridParams(grid);
  validateScales(grid);
  const long long n = countFreeDofs(grid);
  if (p.num_modes < 1 || p.num_modes > n)
    rejectParameter("num_modes", p.num_modes,
                    "must be in [1, " + std::to_string(n) + "], the number of free degrees of freedom");
  validateBasis(grid, p, n);
  validateIntegration(p);
  validateCubatureSettings(grid, p);
  validateMovingFrame(grid, p);
  validateContactSettings(grid, p);
  // A coarse_cols given for a later switch to `coarse` is checked now.
  if (p.method == Method::Coarse || p.coarse_cols != 0)
    coarseGridParams(grid, p.coarse_cols);
  validateMemory(grid, p);
}

// The most columns of the basis of the methods but `linear`.
static double physicalBasisSize(const GridParams& g, const SimulationParams& p)
{
  if (p.basis == BasisKind::Skinning)
    return static_cast<double>(skinningCoordinatesPerWeight(g.dimension)) * p.num_skinning_weights + p.num_modes;
  return static_cast<double>(p.num_modes) + (p.basis == BasisKind::ModalDerivatives ? p.num_derivative_modes : 0);
}

// The training and validation sets (poses and targets), the residual and the fit (basis size x poses
// each), the selected springs' factors (D_s^T: basis size x dim per spring; F_s: dim x poses per
// spring, on the training set, the validation set and in the fit's and the Gram update's products), the NNLS
// Gram matrix and factor (with the Gram's spare capacity), and Phi^T (with basis: skinning, the
// skinning map B the pose sampler's projection is made from, as large).
double cubatureTrainingBytes(const GridParams& g, const SimulationParams& p)
{
  const double springs = effectiveMaxSprings(cubatureParams(p), static_cast<int>(std::min<long long>(countSprings(g), 1 << 30)));
  const double poses = static_cast<double>(effectiveMaxTrainingPoses(cubatureParams(p)));
  const double coordinates = physicalBasisSize(g, p);
  const double dim = g.dimension;
  const double dofs = static_cast<double>(g.rows) * g.cols * dim;
  return 8.0 * (6.0 * coordinates * poses + 4.0 * dim * springs * poses + coordinates * dim * springs +
                3.0 * springs * springs + (p.basis == BasisKind::Skinning ? 2.0 : 1.0) * dofs * coordinates);
}

double estimateMemoryBytes(const GridParams& g, const SimulationParams& p)
{
  const double particles = static_cast<double>(g.rows) * g.cols;
  const double dim = g.dimension;
  const double n = static_cast<double>(countFreeDofs(g));
  const double r = p.num_modes;
  // Stiffness: a dim x dim block per particle and neighbour (8 structural and shear, 4 bending),
  // 12 bytes an entry, held three times at once while the basis is built (K, M^-1/2 K M^-1/2,
  // and the shifted copy).
  const double blocks = 1.0 + 8.0 + (g.bending ? 4.0 : 0.0);
  double bytes = 3.0 * 12.0 * blocks * dim * dim * particles;
  // A sparse LDLT of a grid's stiffness with a fill-reducing ordering has about c n log2 n entries;
  // one is alive at a time (basis, equilibrium Newton, implicit full).
  const double fill = dim == 3 ? 8.0 : 5.0;
  bytes += 12.0 * fill * n * std::log2(std::max(n, 2.0));
  // The basis: Phi, the physical model's Phi^T and (K Phi)^T, the Lanczos vectors and the Ritz
  // vectors of deflated passes; a dense eigensolver when r is close to n.
  bytes += 8.0 * n * (3.0 * r + std::min(n, static_cast<double>(maxLanczosVectors(p.num_modes))) + 2.0 * r);
  // The physical basis (a copy, or the modes and their derivative directions, three times for the
  // force model), and while it is built the derivatives of every pair with their right-hand sides.
  bytes += 8.0 * n * 3.0 * physicalBasisSize(g, p);
  if (p.basis == BasisKind::Skinning)
  {
    // The weights' eigensolver over the particles, and B with its interior copies (all dofs x
    // coordinates, four at once) and the skinning constraint modes.
    const double coordinates = physicalBasisSize(g, p);
    bytes += 8.0 * particles * (3.0 * p.num_skinning_weights + maxLanczosVectors(p.num_skinning_weights));
    bytes += 8.0 * 4.0 * dim * particles * coordinates + 8.0 * 4.0 * coordinates * coordinates;
  }
  if (p.basis == BasisKind::ModalDerivatives)
  {
    // Derivatives, right-hand sides and weighted copies (n x pairs), and the mass-PCA's Gram matrix
    // with its eigenvectors (pairs x pairs, twice).
    const double pairs = r * (r + 1.0) / 2.0;
    bytes += 8.0 * n * 3.0 * pairs + 8.0 * 2.0 * pairs * pairs;
  }
  if (r + 1.0 >= n)
    bytes += 3.0 * 8.0 * n * n;
  // Only `cubature` trains (a switch to it checks again: Simulation::trainCubatureAside).
  if (p.method == Method::Cubature)
    bytes += cubatureTrainingBytes(g, p);
  // The constraint modes Psi (interior dofs x handle dofs), Phi^T M Psi, and a right-hand side.
  long long handle_particles = 0;
  for (const std::vector<int>& handle : g.handles)
    handle_particles += static_cast<long long>(handle.size());
  bytes += 8.0 * 2.0 * n * dim * static_cast<double>(handle_particles);
  // Positions, forces, states and scratch vectors over all dofs, and the springs.
  bytes += 8.0 * 40.0 * dim * particles + 24.0 * (blocks - 1.0) / 2.0 * particles;
  return bytes;
}

}  // namespace modal_mass_spring
