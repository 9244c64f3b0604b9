// The named choices of a simulation, with the names the parameters use.
#pragma once

#include <string>
#include <vector>

namespace modal_mass_spring
{

enum class Method
{
  Full,      // no reduction: the reference
  Linear,    // modal, F = -Lambda X
  Physical,  // modal, F = Phi^T f(x0 + Phi X)
  Cubature,  // modal, F ~ sum over a few springs of w_s Phi_s^T f_s (An, Kim & James 2008)
  Coarse,    // the same cloth on a coarser grid, `full` there, interpolated onto the grid
};

// Where K is taken and the modal coordinates are measured from.
enum class Linearization
{
  Rest,         // the initial positions (the paper)
  Equilibrium,  // the static equilibrium under gravity
};

enum class IntegratorKind
{
  Explicit,  // the paper's scheme
  Implicit,  // Newmark average acceleration with Newton iterations
};

// How the implicit integrator solves a step.
enum class ImplicitSolver
{
  Newton,          // Newton with the exact tangent: few iterations, each a new tangent and factorisation
  ConstantMatrix,  // the springs' constant Laplacian in place of the tangent, factorised once: more
                   // iterations, each a force evaluation and two triangular solves
  LaggedTangent,   // the tangent of a recent state, factorised again every tangent_refresh_steps
                   // steps: a few iterations, each a force evaluation and two triangular solves
};

// Where a run (and a reset) starts.
enum class InitialState
{
  Initial,      // the initial, unloaded positions, at rest
  Equilibrium,  // the static equilibrium, at rest
};

// The basis of the modal methods that compute spring forces (`physical`); `linear` always keeps
// the eigenbasis, which its F = -Lambda X needs.
enum class BasisKind
{
  LinearModes,       // the r lowest modes (the paper)
  ModalDerivatives,  // the modes plus directions from their modal derivatives (Barbic & James)
  Skinning,          // linear-blend skinning: a few affine transforms blended by stiffness-derived weights
};

// How the modal methods follow moving handles.
enum class HandleFormulation
{
  Auto,             // the moving frame where it applies (see SimulationParams), else constraint modes
  ConstraintModes,  // Craig-Bampton: the fixed-interface modes plus Psi = -K_ii^-1 K_ib, linear in the handles
  MovingFrame,      // the grid simulated in the frame of the one rigid body that holds every handle
};

// "full", "linear", "physical", "cubature", "coarse"
std::string toString(Method method);
// Throws std::invalid_argument naming the valid methods.
Method parseMethod(const std::string& name);
const std::vector<std::string>& methodNames();
// methodNames() as a message lists them: "full, linear, physical, cubature, coarse".
std::string methodList();
// The methods that simulate in a modal basis (linear, physical, cubature).
bool isModal(Method method);
// "rest", "equilibrium"; "explicit", "implicit"; "initial", "equilibrium". The parsers throw
// std::invalid_argument naming the parameter and the valid values.
std::string toString(Linearization linearization);
Linearization parseLinearization(const std::string& name);
std::string toString(IntegratorKind integrator);
IntegratorKind parseIntegrator(const std::string& name);
std::string toString(InitialState initial_state);
// "newton", "constant_matrix", "lagged_tangent"
std::string toString(ImplicitSolver solver);
ImplicitSolver parseImplicitSolver(const std::string& name);
InitialState parseInitialState(const std::string& name);
// "linear_modes", "modal_derivatives", "skinning"
std::string toString(BasisKind basis);
BasisKind parseBasis(const std::string& name);
// "auto", "constraint_modes", "moving_frame"
std::string toString(HandleFormulation formulation);
HandleFormulation parseHandleFormulation(const std::string& name);

}  // namespace modal_mass_spring
