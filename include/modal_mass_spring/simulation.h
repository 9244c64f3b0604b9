// A simulation: a grid, its modal basis and the chosen method, stepped by an integrator.
#pragma once

#include "modal_mass_spring/cache.h"
#include "modal_mass_spring/contact.h"
#include "modal_mass_spring/cubature.h"
#include "modal_mass_spring/grid.h"
#include "modal_mass_spring/modal_basis.h"
#include "modal_mass_spring/modal_derivatives.h"
#include "modal_mass_spring/options.h"
#include "modal_mass_spring/self_collision.h"
#include "modal_mass_spring/skinning.h"
#include "modal_mass_spring/state.h"
#include "modal_mass_spring/validation.h"  // validateParameters, estimateMemoryBytes

#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace modal_mass_spring
{

// The method objects and what builds them are internal (src/core/dynamics/method_model.h).
class ErrorIndicator;
class CoarseErrorIndicator;
class MethodModel;
struct CoarseGrid;
struct IntegratorSettings;
enum class Remainder;

// The simulated time between two checks of the adaptive stepper unless adaptive_check_steps says
// otherwise: 20 steps at 5 ms, the motions' time scale rather than a count of steps, so that a
// small step does not check more often for nothing (docs/results.md, "The adaptive method").
constexpr double kAdaptiveCheckPeriod = 0.1;  // s

struct SimulationParams
{
  Method method = Method::Physical;
  int num_modes = 4;        // r
  double alpha = 0.0;       // Rayleigh damping C = alpha M + beta K(x0)
  double beta = 0.0;
  double time_step = 1e-3;  // s
  // A step diverges when the state is not finite, when the mass-weighted RMS displacement from the
  // start of the run exceeds divergence_limit (m; 0: 100 times the grid's larger side), or when
  // the energy rises above its start by more than energy_tolerance times the grid's energy scale
  // (energyScale()): with gravity the only load and non-negative damping, it may not rise at all.
  double divergence_limit = 0.0;
  double energy_tolerance = 0.01;
  Linearization linearization = Linearization::Rest;
  IntegratorKind integrator = IntegratorKind::Explicit;
  InitialState initial_state = InitialState::Initial;
  int newton_max_iterations = 50;  // per implicit solve (Newton's or the constant matrix's iterations)
  ImplicitSolver implicit_solver = ImplicitSolver::Newton;
  int tangent_refresh_steps = 20;  // lagged_tangent: steps between two factorisations of the tangent
  // The adaptive stepper's (adaptive.h): the reduced method, the RMS distance to `full` it accepts
  // (m), the time within it of the span before going back to it (s), the steps between checks.
  // `coarse`: the one reduced method cheaper than `full` with contact, and built in no time
  // (docs/results.md, "On the coarse grid").
  Method adaptive_method = Method::Coarse;
  // Parameter `method: adaptive`: the simulation runs adaptive_method (its `method`), stepped by an
  // AdaptiveStepper that falls back to `full` (the node's single method; the tools' --methods).
  bool adaptive = false;
  double error_tolerance = 0.015;
  double adaptive_dwell = 0.2;
  int adaptive_check_steps = 0;  // 0: as many as make kAdaptiveCheckPeriod
  // Newton iterations of the static equilibrium before it is refused (linearization or
  // initial_state 'equilibrium'): a 100 x 100 cloth hanging from its flat vertical sheet takes 3 to
  // 20; config/cloth.yaml, released at 30 degrees and buckling as it hangs, 60 to 400 (its path hangs
  // on round-off).
  int equilibrium_max_iterations = 1000;
  // The implicit integrator's Hilber-Hughes-Taylor alpha in [-1/3, 0]: 0 is Newmark average
  // acceleration, which lets stiff nonlinear springs gain energy without bound at large steps;
  // negative values damp the highest frequencies and keep those steps bounded (see ImplicitNewmark).
  double hht_alpha = -0.1;
  // Refuse a problem whose build would need more memory than this (GB, estimated before anything is
  // allocated): the default leaves room on a 24 GB machine.
  double memory_limit_gb = 12.0;
  // The basis of `physical` and `cubature`: the num_modes lowest modes, or those plus
  // num_derivative_modes directions from their modal derivatives (0 unless basis is
  // modal_derivatives), or the skinning subspace of num_skinning_weights weights (0 unless basis is
  // skinning; see skinning.h) together with the num_modes modes. `linear` always keeps the num_modes
  // lowest modes.
  BasisKind basis = BasisKind::LinearModes;
  int num_derivative_modes = 0;
  int num_skinning_weights = 0;
  // `cubature`'s training (see CubatureParams): the relative force error to reach, in (0, 1); the
  // most springs (0: min(number of springs, 1000)); the random poses, and the most they may grow to
  // (0: 8 times as many); the largest particle displacement of a pose (m); the seed of the poses and
  // candidate sets.
  double cubature_tolerance = 0.01;
  int cubature_max_springs = 0;
  int cubature_training_poses = 100;
  int cubature_max_training_poses = 0;
  double cubature_pose_size = 0.4;
  int cubature_seed = 1;
  // `coarse`'s grid: its columns, its rows following from the spacing (0: about a third of cols, at
  // most 20; see reduction/coarse_grid.h).
  int coarse_cols = 0;
  // How the modal methods follow moving handles. constraint_modes: Craig-Bampton (see
  // setHandleMotion), linear in the handles' displacement, so large turns distort it. moving_frame:
  // every method simulates the grid in the frame B of the one rigid body that holds every handle
  // (setHandleFrameMotion), with B's inertial forces and gravity turned into B: exact at any turn,
  // needs no constraint modes; it needs handles, no fixed particles and handles_one_body. auto: the
  // moving frame where it applies, else constraint modes.
  HandleFormulation handle_formulation = HandleFormulation::Auto;
  // The caller moves every handle together as one rigid body, through setHandleFrameMotion (the node:
  // all handles name one TF frame).
  bool handles_one_body = false;
  // Rigid colliders the free particles stay contact_thickness off, with Coulomb friction (contact.h);
  // contact_thickness 0: a tenth of the spacing. With colliders, auto resolves to constraint_modes
  // (contact is corrected in world coordinates; moving_frame is refused).
  std::vector<Collider> colliders;
  double contact_thickness = 0.0;
  // Self-collision (self_collision.h): the free particles kept self_collision_thickness (m, in
  // (0, spacing]) apart from the cloth more than two springs away, with Coulomb friction self_friction
  // between the layers. 3D grids and `full` only: the modal methods are refused (docs/design.md says why).
  bool self_collision = false;
  double self_collision_thickness = 0.005;
  double self_friction = 0.5;
};

// The formulation a simulation with these parameters uses: auto resolved (ConstraintModes or
// MovingFrame; ConstraintModes also when there are no handles).
HandleFormulation resolveHandleFormulation(const GridParams& grid, const SimulationParams& params);

// The cubature training parameters of a simulation's.
CubatureParams cubatureParams(const SimulationParams& params);

// The whole number of time steps one step of `coarse` can span with the margin to its explicit
// stability limit that time_step has on the grid: the square root of the fine particles per coarse
// one, rounded down (the springs keep their constants, so the limit grows as the square root of the
// particle mass), and under the explicit integrator at most 2 / (alpha time_step), the damping's own
// limit. Where the caller picks the step (~rollout's time_step 0, modal_compare) `coarse` steps
// time_step times it; with `divides` > 0, the largest such number that divides `divides` (the steps
// between samples, or to a horizon). Throws as coarse_cols does.
int coarseStepMultiple(const GridParams& grid, const SimulationParams& params, long divides = 0);

// What building the linearization point found.
struct LinearizationInfo
{
  bool equilibrium_solved = false;
  int equilibrium_iterations = 0;
  double equilibrium_residual = 0.0;  // N
  int dropped_compressed_springs = 0; // springs whose compressive geometric stiffness was left out of K
  double equilibrium_seconds = 0.0;   // time of the static equilibrium solve (0 when not solved)
  double stiffness_seconds = 0.0;     // time to assemble K at the linearization point
};

struct StepResult
{
  int steps_taken = 0;
  bool diverged = false;
  std::string message;  // why a step was refused, empty otherwise
};

// Everything a simulation's next steps depend on besides its parameters, as values: what
// Simulation::saveState copies out and restoreState puts back, into the same simulation or another one
// built with the same grid and parameters (a planner's rollouts, a replay).
struct SimulationState
{
  Method method = Method::Full;
  double time_step = 0.0;  // s
  int step_span = 1;       // time steps a step takes (Simulation::setStepSpan)
  long step_count = 0;     // the time is step_count x time_step
  State coordinates;       // the method's q, v, a
  Eigen::VectorXd offset;  // a modal method's or `coarse`'s frozen offset (free dofs); empty for `full`
  HandleMotion handles;    // the handles' motion the state was stepped to
  FrameMotion frame;       // B's (at rest without a moving frame)
  // Per collider: its pose (grid coordinates), whether it is active (a frame's before its first pose
  // is not); and whether one moved since the start of the run.
  std::vector<Eigen::Isometry3d> collider_poses;
  std::vector<bool> colliders_active;
  bool colliders_moved = false;
  Eigen::VectorXd external_force;  // on every dof
  // The divergence check's reference: the start of the run (free-dof and handle displacement), its
  // energy and energy scale, whether handles moved since; and whether the state diverged, and why.
  Eigen::VectorXd anchor, anchor_handles;
  double start_energy = 0.0, energy_scale = 0.0;
  bool handles_moved = false;
  bool diverged = false;
  std::string divergence_message;
};

class Simulation
{
public:
  // Validates both parameter sets (validateParameters) before building anything, then builds the
  // linearization point and, unless the method is `full` (which needs none: buildBasis() builds it at
  // the first switch to a modal method), the basis, telling on_stage as each stage starts
  // ("equilibrium", "stiffness", "factorisation", "eigensolver", "modal derivatives" or "skinning"
  // with that basis, and "cubature" when the method is `cubature`) and on_iteration how the
  // equilibrium's Newton iterations and the eigensolver's Lanczos steps go. Throws
  // std::invalid_argument naming the offending parameter, std::runtime_error when a stage fails.
  // With a cache directory (CacheOptions), the equilibrium, the bases and the cubature are loaded
  // from it when it holds them for these parameters, and written to it when they are computed
  // (including a cubature trained at a later switch); a file that is unusable or cannot be written
  // is a warning, never an error (see cache.h).
  Simulation(const GridParams& grid_params, const SimulationParams& params, const StageFn& on_stage = {},
             const CacheOptions& cache = {}, const IterationFn& on_iteration = {});

  // The force models and integrators refer to the grid, basis and matrices held here: a Simulation
  // stays where it was built.
  Simulation(const Simulation&) = delete;
  Simulation& operator=(const Simulation&) = delete;
  Simulation(Simulation&&) = delete;
  Simulation& operator=(Simulation&&) = delete;
  ~Simulation();

  const Grid& grid() const { return grid_; }
  // Builds the bases (and stores them in the cache) unless they are built: what the first switch to
  // a modal method does, here with the stages and iterations told, so that a caller can build them
  // before it switches (the node, while the old method runs on). Throws as the constructor.
  void buildBasis(const StageFn& on_stage = {}, const IterationFn& on_iteration = {});
  // False for `full` until a modal method was first set (or buildBasis called): basis() and
  // physicalBasis() are empty until then.
  bool basisBuilt() const { return basis_built_; }
  // The eigenbasis: the num_modes lowest modes, `linear`'s basis.
  const ModalBasis& basis() const { return basis_; }
  // The basis of every modal method that computes spring forces (all but `linear`): the eigenbasis
  // itself, or with basis: modal_derivatives the modes plus their derivative directions.
  const ModalBasis& physicalBasis() const { return physical_basis_; }
  // What building the derivative directions did (all zero with basis: linear_modes).
  const DerivativeBasisInfo& derivativeInfo() const { return derivative_info_; }
  // What building the skinning subspace did (all zero unless basis: skinning).
  const SkinningInfo& skinningInfo() const { return skinning_info_; }
  // `coarse`'s grid (reduction/coarse_grid.h): null until the method is first used.
  const Grid* coarseGrid() const;
  const SimulationParams& params() const { return params_; }
  Method method() const;

  // Switches method, carrying the motion over without moving a particle: going to a modal method,
  // X = Phi^T M u and the rest of u, which the modes cannot carry, stays frozen as an offset of the
  // modal reference configuration (until reset); going to full, u = offset + Phi X. Clears a
  // divergence: the last good state goes on under the new method. The first switch to a modal
  // method builds the bases (buildBasis) unless they are built; the first to `cubature` trains it
  // (trainCubature, seconds on a large grid). With self-collision on, a modal method is refused
  // (std::invalid_argument, nothing changed).
  void setMethod(Method method);
  // The trained cubature (springs, weights, training report), or null before `cubature` was first used.
  const Cubature* cubature() const { return cubature_ ? &*cubature_ : nullptr; }
  // The cubature's training apart from the switch, for a caller that steps on meanwhile (the node):
  // loadCachedCubature() takes it from the cache when it holds it (true: cubature() is set);
  // cubatureTraining() checks the training's memory against memory_limit_gb as validateParameters
  // does for `cubature` (std::invalid_argument) and returns the training as a job to run on another
  // thread (on_iteration as trainCubature's, which may throw to stop it). The job copies the
  // parameters and reads the grid, the physical basis and the linearization point, which stepping,
  // reset(), setMethod() and setTimeStep() never change: this simulation must outlive it and not
  // build its basis meanwhile (buildBasis first: std::logic_error otherwise). setCubature() then
  // takes the result (and stores it in the cache) for the next setMethod(Method::Cubature).
  using CubatureTraining = std::function<Cubature(const IterationFn& on_iteration)>;
  bool loadCachedCubature();
  CubatureTraining cubatureTraining() const;
  // Builds the constraint modes `method` needs with handles (none for full, the moving frame, or a
  // method other than `linear` on the skinning span). Throws std::runtime_error where they do not
  // exist (cloth hanging slack from small grips): called before a cubature's training, so that a
  // method that cannot follow the handles is refused before any.
  void prepareConstraintModes(Method method);
  void setCubature(Cubature cubature);
  // What the cache did: whether the basis and the cubature were loaded or stored, and where.
  const CacheReport& cacheReport() const { return cache_report_; }
  // Rebuilds the integrators for a new time step (validated as at construction); keeps the state.
  void setTimeStep(double dt);
  // How many time steps each step() takes at once (1 unless set): the adaptive method steps
  // `coarse` at its own larger step while keeping `full`'s clock. Rebuilds the integrator when it
  // changes (an implicit one starts afresh) and keeps the state; stepCount() and time() go on
  // counting time steps. Part of the saved state; reset() sets it back to 1. Throws
  // std::invalid_argument below 1. The caller keeps it within the method's stability.
  void setStepSpan(int time_steps);
  int stepSpan() const { return step_span_; }
  // Back to the initial positions, at rest, time 0, the handles at rest at the linearization point.
  // The external force stays.
  void reset();
  // Sets the external force on every particle (N, a vector of dimension values per particle, as
  // positions()), replacing the previous one; zero clears it. It acts on every method in physical
  // coordinates (the modal methods project the touched particles' rows of Phi) and stays through
  // method switches and resets until changed. Forces on fixed particles do nothing. Throws
  // std::invalid_argument for a vector of the wrong size or with a non-finite entry, changing nothing.
  void setExternalForce(const Eigen::VectorXd& force);
  const Eigen::VectorXd& externalForce() const { return external_force_; }
  // How many times the external force was set (or restored): equal counts, the same force.
  long externalForceChanges() const { return external_force_changes_; }
  // Prescribes the handle particles' positions (absolute, m), velocities and accelerations at the
  // end of the next step, each vector over grid().handleDofs() (dimension values per handle
  // particle, handle by handle); velocity and acceleration may be empty (zero). The next step()
  // takes them; step(k) holds them for all k steps, so a moving handle is given once per step.
  // Every method holds the handle particles there exactly: `full` simulates the interior with them,
  // the modal methods add the constraint modes Psi (x_b - x_b,ref) and the interface's inertial load
  // (Craig-Bampton, see ModalMethod). Once a handle has moved, handles can do work on the grid, so
  // the energy check of a step is off until the next reset(); the state and displacement checks
  // stay. Throws std::invalid_argument for a vector of the wrong size or with a non-finite entry,
  // changing nothing.
  // With handle_formulation moving_frame the handles move with B only: refused (use
  // setHandleFrameMotion).
  void setHandleMotion(const Eigen::VectorXd& positions, const Eigen::VectorXd& velocities = {},
                       const Eigen::VectorXd& accelerations = {});
  // Moves every handle with the one rigid body B that holds them, relative to B's pose at the start
  // (the handle particles at the linearization point), for the end of the next step, like
  // setHandleMotion. In the moving frame (handleFormulation()) the grid is simulated in B; with
  // constraint modes this is setHandleMotion with the handle particles' rigid motion. A 2D grid's
  // frame may only move in its x-z plane (turn about y). Throws std::invalid_argument for a grid
  // without handles, a non-finite value, a rotation that is not one (|R^T R - I| or det) or leaves
  // the plane, changing nothing.
  void setHandleFrameMotion(const FrameMotion& motion);
  // B's motion the current state was stepped to (at rest without a moving frame).
  const FrameMotion& frameMotion() const { return frame_current_; }
  // Puts B where `motion` says now, for the current state, without a step (the particles move with
  // it): to carry a state over from another simulation in its frame before setPhysicalState. Without
  // a moving frame it does nothing; else checked as setHandleFrameMotion.
  void placeFrame(const FrameMotion& motion);
  HandleFormulation handleFormulation() const { return formulation_; }
  // The handles' motion the current state was stepped to (displacements from the linearization
  // point); empty vectors: at rest at the linearization point.
  const HandleMotion& handleMotion() const { return handle_current_; }
  // Where the handle particles are now (absolute, m), over grid().handleDofs().
  Eigen::VectorXd handlePositions() const;
  // Puts the handles at these positions, velocities and accelerations now, in the current state (not
  // at the end of the next step, as setHandleMotion): the free particles stay where they are, and
  // the next step starts from there. For a simulation that takes over another's run (a rebuild),
  // before setPhysicalState places the grid around them. Throws as setHandleMotion, changing nothing.
  void setHandleState(const Eigen::VectorXd& positions, const Eigen::VectorXd& velocities = {},
                      const Eigen::VectorXd& accelerations = {});
  // The constraint modes Psi = -K_ii^-1 K_ib (built when a modal method is first used with handles;
  // empty before), and K_ib at the linearization point. With basis: skinning the methods but `linear`
  // use skinningConstraintModes() instead: the handles' part in the skinning span (no K_ii solve, so
  // grips that do not hold the cloth alone work).
  const Eigen::MatrixXd& constraintModes() const { return constraint_modes_; }
  const Eigen::MatrixXd& skinningConstraintModes() const { return skinning_constraint_modes_; }
  const SparseMatrix& handleCoupling() const { return handle_coupling_; }
  // True while the energy check is off because handles moved since the start of the run.
  bool energyCheckSuspended() const { return handles_moved_; }
  // Sets the state from free-dof displacements (from the linearization point) and velocities. A
  // modal method takes their M-orthogonal projection, with no frozen offset; projectionError() then
  // says how far (m, the largest particle distance) the projected positions are from the requested
  // ones. `coarse` keeps what its interpolation misses frozen, and is where it is put.
  void setPhysicalState(const Eigen::VectorXd& displacement, const Eigen::VectorXd& velocity);
  double projectionError() const { return projection_error_; }
  // How far the current state is estimated to be from what `full` would do from it (m, an RMS over
  // the free particles): the displacement that balances the full model's force outside the
  // method's span, the modes' or the coarse grid's interpolation (reduction/error_indicator.h), at
  // the current state; its users keep its largest since the state was set (IndicatorMaximum,
  // adaptive.h), and errorEstimate makes of that an estimate. 0 for `full`. O(springs + n r)
  // (`coarse`: O(springs)) and sparse solves; the first call factorises the springs' Laplacian.
  double errorIndicator();
  // The same for the span of method `span` at the current positions, whatever the method: what that
  // method's indicator would be right after a switch to it (which moves no particle). Its basis or
  // coarse grid must be built (std::logic_error).
  double errorIndicator(Method span);
  // How far the current state is from the span of method `reduced` (m, an RMS over the free
  // particles): for a modal method the part of the displacement (less the handles' constraint modes)
  // that its M-orthogonal projection onto the basis leaves, for `coarse` the part its interpolation
  // of the state sampled at its particles misses; either is what a switch to it keeps frozen. The
  // basis or the coarse grid must be built (std::logic_error).
  double spanDistance(Method reduced) const;
  // How many times the state has been set whole: at the start, a reset, a method switch, a state set
  // or restored, a handle set teleported (every install of a method's state). A maximum of the error
  // indicator is taken since the last.
  long stateSets() const { return state_sets_; }
  // The simulated time stepped since then (s).
  double timeSinceStateSet() const { return time_since_set_; }
  const LinearizationInfo& linearization() const { return linearization_; }
  // x_ref: the initial positions (rest) or the static equilibrium.
  const Eigen::VectorXd& linearizationPositions() const { return x_ref_; }
  // The positions a reset returns to.
  const Eigen::VectorXd& startPositions() const { return x_start_; }
  // Newton iterations of the last implicit solve, and the solves the last step took (1 unless
  // Newton failed and the step was split); both 0 under the explicit integrator.
  int lastNewtonIterations() const;
  int lastImplicitSubsteps() const;

  // Takes up to `steps` steps; stops at the first that diverges and keeps the state before it.
  StepResult step(int steps = 1);

  // The whole state (SimulationState), and that state put back: the steps that follow are those
  // that followed it (bit for bit with the same handle and collider motions). restoreState switches
  // method, time step and step span to the state's (building the basis when needed) and throws
  // std::invalid_argument naming the field, changing nothing, for one whose size does not fit this
  // grid and method, a non-finite value or a time step validateParameters refuses.
  SimulationState saveState() const;
  void restoreState(const SimulationState& state);

  // The colliders' contact (null without colliders): their poses, and what the last step did.
  const Contact* contact() const { return contact_.get(); }
  // Per particle of the grid: the collider it touched in the last step (the first, where several), or
  // -1 (none, a fixed or held particle, no colliders).
  std::vector<int> particleContacts() const;
  // Places collider i (its frame in the grid's coordinates) for the end of the next step; a moved
  // collider can do work on the grid, so the energy check is then off until the next reset(). A
  // collider with a `frame` touches nothing until its first pose, which places it (Contact::setPose).
  // Throws std::invalid_argument for an index out of range or a non-finite pose.
  void setColliderPose(int i, const Eigen::Isometry3d& pose);
  // Places collider i at `pose` without a motion over the next step (Contact::place): the node's
  // answer to a collider frame that jumped and stayed. The same refusals as setColliderPose.
  void placeCollider(int i, const Eigen::Isometry3d& pose);
  // Replaces the colliders from the next step on (live: the node's ~set_colliders). keep[i]: the
  // collider of the current set that new collider i continues (its pose, and whether it is active,
  // carried over), or -1: a new one, placed at its pose (a frame's inactive until its first pose); the
  // cloth inside a new one is pushed out by the next step's contact, as when a frame's collider
  // appears. Throws std::invalid_argument, changing nothing, for what validateCollider refuses (naming
  // colliders[i]), a keep out of range or of the wrong size, and colliders under the moving frame.
  void setColliders(const std::vector<Collider>& colliders, const std::vector<int>& keep);
  // contact_thickness from the next step on (live tuning); throws what validateContactThickness
  // refuses, changing nothing.
  void setContactThickness(double thickness);
  // The CPU time the last step's contact correction took (s, the process's; 0 without colliders).
  double lastContactSeconds() const { return contact_seconds_; }
  // Self-collision (null when off): its thickness, friction and what the last step did.
  const SelfCollision* selfCollision() const { return self_collision_.get(); }
  // Turns self-collision on or off and sets its thickness and friction, from the next step on (live
  // tuning). Throws std::invalid_argument, changing nothing, for what validateSelfCollision refuses
  // and for turning it on under a modal method.
  void setSelfCollision(bool enabled, double thickness, double friction);
  // The CPU time the last step's self-collision took (s, the process's; 0 when off).
  double lastSelfCollisionSeconds() const { return self_collision_seconds_; }
  // The force the grid puts on each handle (N, grid coordinates), what holding it takes reversed:
  // the springs' pull on its particles plus their weight and external force minus their mass times
  // their prescribed acceleration. A grid hanging at rest pulls its whole weight.
  std::vector<Eigen::Vector3d> handleForces() const;
  // The same forces with their torque about a point per handle (grid coordinates, N m): the sum over
  // its particles of (x_p - origin) x f_p, what a force-torque sensor at the gripper's origin reads
  // reversed. `origins` holds one point per handle (std::invalid_argument otherwise).
  struct Wrench
  {
    Eigen::Vector3d force = Eigen::Vector3d::Zero(), torque = Eigen::Vector3d::Zero();
  };
  std::vector<Wrench> handleWrenches(const std::vector<Eigen::Vector3d>& origins) const;

  bool diverged() const { return diverged_; }
  long stepCount() const { return step_count_; }
  double time() const { return step_count_ * params_.time_step; }
  // Where the next step ends (s): stepSpan() time steps on, the time a motion handed over for it is at.
  double nextStepTime() const { return static_cast<double>(step_count_ + step_span_) * params_.time_step; }

  // The generalized state of the current method (u for full, X for the modal methods).
  const State& state() const;
  // Free-dof displacement (from the linearization point) and velocity, whatever the method, in the
  // grid's (world) coordinates also in a moving frame.
  Eigen::VectorXd displacement() const;
  Eigen::VectorXd velocity() const;
  // One free particle's position and velocity (dimension values each), what positions() and velocity()
  // say of it, in O(r) rather than O(n r): for following a particle every step (a drag). A particle
  // that is out of range, fixed or held is an std::invalid_argument naming it.
  void particleState(int particle, Eigen::VectorXd& position, Eigen::VectorXd& velocity) const;
  // All particle positions as a flat vector (dimension values per particle), and as 3 x N points.
  Eigen::VectorXd positions() const;
  Eigen::Matrix3Xd points() const { return grid_.toPoints(positions()); }

  // Of the world velocities.
  double kineticEnergy() const;
  // The free particles' RMS speed less the rigid motion that fits their velocities best (m/s): less
  // their centre's velocity and the rotation about it that carries their angular momentum. On a
  // grid with more than 32 rows or columns, over a lattice of at most 32 x 32 of them.
  double deformationSpeed() const;
  // Kinetic + spring + gravity potential energy, from the physical positions; the second form takes
  // positions() already reconstructed (O(n r) for a modal method).
  double totalEnergy() const;
  double totalEnergy(const Eigen::VectorXd& positions) const;
  // The energy the divergence check measures growth against (J): the grid's weight times its
  // larger side, plus the spring and kinetic energy of the start (the last reset or
  // setPhysicalState), plus the energy of every spring stretched by 1% (so that it is never 0).
  double energyScale() const { return energy_scale_; }
  // The energy the current method's dynamics conserve without damping (see MethodModel::energy),
  // and its value at the start of the run (moved by a method switch so that the growth since the
  // start carries over).
  double methodEnergy() const;
  double startEnergy() const { return start_energy_; }

private:
  IntegratorSettings integratorSettings() const;
  // Throws what setColliderPose and placeCollider refuse.
  void checkColliderPose(int i, const Eigen::Isometry3d& pose) const;
  // Replaces the method object, carrying (u, v) over; Keep: no particle moves (a switch).
  void install(Method method, const Eigen::VectorXd& u, const Eigen::VectorXd& v, Remainder remainder);
  // The equilibrium and the bases: from the cache when it holds them, else computed (and stored).
  void precompute(const StageFn& on_stage, const IterationFn& on_iteration);
  // precompute's step: the static equilibrium, solved into `data` unless `cached` holds it, taken as
  // the linearization point and the start where the parameters ask.
  void linearizeAtEquilibrium(Precomputed& data, bool cached, const StageFn& on_stage, const IterationFn& on_iteration);
  // Takes the bases and what they report, loaded or built.
  void adoptBasis(Precomputed&& data);
  // Loads, or trains and stores, the cubature on the physical basis.
  void prepareCubature(const IterationFn& on_iteration = {});
  // What `method` steps on, unless built: the bases for a modal method, the coarse grid for `coarse`.
  void buildFor(Method method);
  // The grid is simulated in a moving frame that has left its start: B's coordinates are not the world's.
  bool frameMoved() const { return formulation_ == HandleFormulation::MovingFrame && !frame_current_.atRest(); }
  // In a moving frame: a world free-dof displacement and velocity in B and back (identity else).
  void toBody(Eigen::VectorXd& u, Eigen::VectorXd& v) const;
  Eigen::VectorXd bodyDisplacement() const;
  // Positions in B (any grid's, every dof) in the world: themselves unless a moving frame moved.
  Eigen::VectorXd worldPositions(Eigen::VectorXd x) const;
  // Every dof's position in the body frame (the world's unless a frame moves): positions() before
  // worldPositions().
  Eigen::VectorXd bodyPositions() const;
  Eigen::VectorXd bodyVelocity() const;
  FrameForces frameForcesOf(const FrameMotion& motion) const;
  // Throws std::invalid_argument for a frame motion setHandleFrameMotion refuses.
  void checkFrameMotion(const FrameMotion& motion) const;
  // Why `next` may not be taken, or empty.
  std::string divergence(bool integrator_ok, const State& next);

  Grid grid_;
  SimulationParams params_;
  LinearizationInfo linearization_;
  Eigen::VectorXd x_ref_;    // linearization point: u measures displacement from here
  Eigen::VectorXd x_start_;  // where reset() puts the grid
  Eigen::VectorXd u_start_;  // the same as a free-dof displacement from x_ref_
  Eigen::VectorXd anchor_;   // the run's start as its method held it: divergence is measured from here
  Eigen::VectorXd anchor_handles_;  // the handle dofs' displacement then (empty: at rest)
  bool basis_built_ = false;
  Eigen::VectorXd equilibrium_;  // all dofs, when it was solved: stored in the cache with the bases
  ModalBasis basis_;            // the eigenbasis (`linear`)
  ModalBasis physical_basis_;   // the basis of the modal methods other than `linear`
  DerivativeBasisInfo derivative_info_;
  SkinningInfo skinning_info_;
  Eigen::MatrixXd skinning_constraint_modes_;  // with basis: skinning and handles
  SparseMatrix stiffness_;  // K at x_ref on the free dofs
  Eigen::VectorXd mass_;    // diagonal of M on the free dofs
  std::optional<Cubature> cubature_;  // trained at the linearization point when first needed
  CacheOptions cache_;
  CacheReport cache_report_;
  double total_mass_ = 0.0;  // weighs the divergence check into an RMS displacement in metres
  std::unique_ptr<MethodModel> model_;
  long step_count_ = 0;
  int step_span_ = 1;  // stepSpan()
  bool diverged_ = false;
  std::string divergence_message_;
  double limit_ = 0.0;
  double base_energy_scale_ = 0.0;  // the grid's weight times its side, plus every spring stretched by 1%
  double energy_scale_ = 0.0;       // the base plus the start's spring and kinetic energy
  double start_energy_ = 0.0;  // the method's energy at the start of the run, carried over switches
  double projection_error_ = 0.0;
  std::unique_ptr<ErrorIndicator> error_indicator_;  // built at the first errorIndicator()
  std::unique_ptr<CoarseErrorIndicator> coarse_indicator_;  // built at the first errorIndicator(Method::Coarse)
  long state_sets_ = 0;  // stateSets()
  double time_since_set_ = 0.0;  // timeSinceStateSet()
  std::unique_ptr<CoarseGrid> coarse_;               // built at the first use of `coarse`
  Eigen::VectorXd external_force_;  // on every dof; zero: none
  long external_force_changes_ = 0;
  SparseMatrix handle_coupling_;        // K_ib at x_ref (interior x handle dofs)
  Eigen::MatrixXd constraint_modes_;    // Psi; empty until a modal method needs it
  HandleMotion handle_current_;         // where the handles are in the current state
  HandleMotion handle_target_;          // where the next step takes them
  bool handle_pending_ = false;         // the target differs from the current motion
  bool handles_moved_ = false;          // a handle left its rest at x_ref since the start of the run
  HandleFormulation formulation_ = HandleFormulation::ConstraintModes;  // resolved
  FrameMotion frame_current_, frame_target_;  // B's motion: where the state is, where the next step goes
  bool frame_pending_ = false;
  std::unique_ptr<Contact> contact_;  // null without colliders
  double contact_seconds_ = 0.0;
  std::unique_ptr<SelfCollision> self_collision_;  // null when off
  double self_collision_seconds_ = 0.0;
};

}  // namespace modal_mass_spring
