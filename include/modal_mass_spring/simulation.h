// A simulation: a grid, its modal basis and the chosen method, stepped by an integrator.
#pragma once

#include "modal_mass_spring/force_model.h"
#include "modal_mass_spring/grid.h"
#include "modal_mass_spring/integrator.h"
#include "modal_mass_spring/modal_basis.h"

#include <memory>
#include <string>
#include <vector>

namespace modal_mass_spring
{

enum class Method
{
  Full,      // no reduction: the reference
  Linear,    // modal, F = -Lambda X
  Physical,  // modal, F = Phi^T f(x0 + Phi X)
};

// "full", "linear", "physical"
std::string toString(Method method);
// Throws std::invalid_argument naming the valid methods.
Method parseMethod(const std::string& name);
const std::vector<std::string>& methodNames();

struct SimulationParams
{
  Method method = Method::Physical;
  int num_modes = 4;        // r
  double alpha = 0.0;       // Rayleigh damping C = alpha M + beta K(x0)
  double beta = 0.0;
  double time_step = 1e-3;  // s
  // A step diverges when the state is not finite or the mass-weighted RMS displacement exceeds this
  // (m). 0: 100 times the grid's larger side.
  double divergence_limit = 0.0;
};

struct StepResult
{
  int steps_taken = 0;
  bool diverged = false;
  std::string message;  // why a step was refused, empty otherwise
};

class Simulation
{
public:
  // Validates both parameter sets and builds the basis; throws std::invalid_argument naming the
  // offending parameter.
  Simulation(const GridParams& grid_params, const SimulationParams& params);

  const Grid& grid() const { return grid_; }
  const ModalBasis& basis() const { return basis_; }
  const SimulationParams& params() const { return params_; }
  Method method() const { return params_.method; }

  // Switches method, carrying the motion over (X = Phi^T M u to a modal method, u = Phi X to full).
  // Clears a divergence: the last good state goes on under the new method.
  void setMethod(Method method);
  // Rebuilds the integrators for a new time step (validated as at construction); keeps the state.
  void setTimeStep(double dt);
  // Back to the initial positions, at rest, time 0.
  void reset();
  // Sets the state from free-dof displacements (from the initial positions) and velocities.
  void setPhysicalState(const Eigen::VectorXd& displacement, const Eigen::VectorXd& velocity);

  // Takes up to `steps` steps; stops at the first that diverges and keeps the state before it.
  StepResult step(int steps = 1);

  bool diverged() const { return diverged_; }
  long stepCount() const { return step_count_; }
  double time() const { return step_count_ * params_.time_step; }

  // The generalized state of the current method (u for full, X for the modal methods).
  const State& state() const { return state_; }
  // Free-dof displacement and velocity from the initial positions, whatever the method.
  Eigen::VectorXd displacement() const;
  Eigen::VectorXd velocity() const;
  // All particle positions as a flat vector (dimension values per particle), and as 3 x N points.
  Eigen::VectorXd positions() const;
  Eigen::Matrix3Xd points() const { return grid_.toPoints(positions()); }

  double kineticEnergy() const;
  // Kinetic + spring + gravity potential energy, from the physical positions.
  double totalEnergy() const;

private:
  bool isModal() const { return params_.method != Method::Full; }
  ForceModel& forceModel();
  Integrator& integrator();
  void buildIntegrators();
  void initializeAcceleration();

  Grid grid_;
  SimulationParams params_;
  ModalBasis basis_;
  SparseMatrix stiffness_;  // K at x0 on the free dofs
  Eigen::VectorXd mass_;    // diagonal of M on the free dofs
  std::unique_ptr<FullForceModel> full_force_;
  std::unique_ptr<LinearModalForceModel> linear_force_;
  std::unique_ptr<PhysicalModalForceModel> physical_force_;
  std::unique_ptr<Integrator> full_integrator_, modal_integrator_;
  State state_, next_;
  long step_count_ = 0;
  bool diverged_ = false;
  double limit_ = 0.0;
};

}  // namespace modal_mass_spring
