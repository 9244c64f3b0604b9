// A simulation: the linearization point and basis, and the current method stepped with its divergence
// checks (its parameters are checked in validation.cpp).
#include "modal_mass_spring/cpu_time.h"
#include "modal_mass_spring/simulation.h"

#include "modal_mass_spring/spring_forces.h"
#include "modal_mass_spring/validation.h"
#include "contact/collider_shapes.h"
#include "dynamics/method_model.h"
#include "reduction/coarse_grid.h"
#include "reduction/error_indicator.h"
#include "solvers/equilibrium.h"

#include <algorithm>
#include <chrono>
#include <time.h>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace modal_mass_spring
{

namespace
{

// Whether a free particle at `positions` (all dofs) lies inside an active collider of `contact` at its
// pose, deeper than round-off (as checkStartOutsideColliders counts it).
bool insideCollider(const Grid& grid, const Contact& contact, const Eigen::VectorXd& positions)
{
  return deepestInside(grid, grid.toPoints(positions), contact) > kSurfaceRoundOffFraction * contact.thickness();
}

}  // namespace

HandleFormulation resolveHandleFormulation(const GridParams& grid, const SimulationParams& params)
{
  // The skinning span holds the handles' rigid motion itself: auto needs no moving frame there.
  if (params.handle_formulation == HandleFormulation::Auto)
    return !grid.handles.empty() && params.basis != BasisKind::Skinning && params.colliders.empty() &&
                   effectiveFixed(grid).empty() && params.handles_one_body
               ? HandleFormulation::MovingFrame
               : HandleFormulation::ConstraintModes;
  return params.handle_formulation;
}

CubatureParams cubatureParams(const SimulationParams& p)
{
  CubatureParams c;
  c.tolerance = p.cubature_tolerance;
  c.max_springs = p.cubature_max_springs;
  c.training_poses = p.cubature_training_poses;
  c.max_training_poses = p.cubature_max_training_poses;
  c.pose_size = p.cubature_pose_size;
  c.seed = p.cubature_seed;
  return c;
}

int coarseStepMultiple(const GridParams& grid, const SimulationParams& params, long divides)
{
  // The springs keep their constants, so the highest frequency goes as one over the square root of
  // the particle mass: the fine particles per coarse one.
  const GridParams coarse = coarseGridParams(grid, params.coarse_cols);
  const double mass_ratio = (static_cast<double>(grid.rows) * grid.cols) / (static_cast<double>(coarse.rows) * coarse.cols);
  int multiple = std::max(1, static_cast<int>(std::floor(std::sqrt(mass_ratio) + 1e-9)));
  if (params.integrator == IntegratorKind::Explicit && params.alpha > 0.0)
  {
    const double damping_limit = std::floor(2.0 / (params.alpha * params.time_step));  // may exceed int
    if (damping_limit < multiple)
      multiple = std::max(1, static_cast<int>(damping_limit));
  }
  if (divides > 0)
  {
    multiple = static_cast<int>(std::min<long>(multiple, divides));
    while (divides % multiple != 0)
      --multiple;
  }
  return multiple;
}

Simulation::Simulation(const GridParams& grid_params, const SimulationParams& params, const StageFn& on_stage,
                       const CacheOptions& cache, const IterationFn& on_iteration)
  : grid_((validateParameters(grid_params, params), grid_params)), params_(params), cache_(cache)
{
  const GridParams& g = grid_.params();
  formulation_ = resolveHandleFormulation(g, params_);
  limit_ = params_.divergence_limit > 0.0 ? params_.divergence_limit
                                          : 100.0 * g.spacing * std::max(g.rows, g.cols);
  precompute(on_stage, on_iteration);
  if (!params_.colliders.empty())
    contact_ = std::make_unique<Contact>(grid_, params_.colliders,
                                         resolveContactThickness(params_.contact_thickness, g.spacing));

  if (grid_.numHandleDofs() > 0)
    handle_coupling_ = modal_mass_spring::handleCoupling(grid_, x_ref_);
  u_start_ = grid_.gatherFree(x_start_ - x_ref_);
  external_force_ = Eigen::VectorXd::Zero(x_ref_.size());
  double stretched = 0.0;
  for (const Spring& spring : grid_.springs())
    stretched += 0.5 * spring.stiffness * std::pow(0.01 * spring.rest_length, 2);
  base_energy_scale_ = total_mass_ * g.gravity.norm() * g.spacing * std::max(g.rows, g.cols) + stretched;
  if (params_.method == Method::Cubature)
  {
    prepareConstraintModes(params_.method);  // a held set it cannot follow: refused before any training
    if (on_stage)
      on_stage("cubature");
    prepareCubature(on_iteration);
  }
  if (params_.self_collision)
    self_collision_ = std::make_unique<SelfCollision>(grid_, params_.self_collision_thickness, params_.self_friction);
  reset();
}

void Simulation::precompute(const StageFn& on_stage, const IterationFn& on_iteration)
{
  auto stage = [&](const std::string& name) {
    if (on_stage)
      on_stage(name);
  };
  using Clock = std::chrono::steady_clock;
  auto since = [](Clock::time_point start) { return std::chrono::duration<double>(Clock::now() - start).count(); };
  const int n = grid_.numFreeDofs();
  const GridParams& g = grid_.params();

  // The cache holds everything here but the stiffness, which is assembled again from x_ref.
  const std::string key = basisKey(g, params_);
  const bool needs_equilibrium =
      params_.linearization == Linearization::Equilibrium || params_.initial_state == InitialState::Equilibrium;
  std::optional<Precomputed> cached;
  if (!cache_.directory.empty())
  {
    const auto start = Clock::now();
    cache_report_.basis_file = cacheFile(cache_.directory, "basis", key);
    cached = loadPrecomputed(cache_report_.basis_file, key, n, needs_equilibrium ? grid_.numDofs() : 0, cache_);
    cache_report_.basis_loaded = cached.has_value();
    cache_report_.basis_load_seconds = since(start);
  }
  Precomputed data = cached ? std::move(*cached) : Precomputed{};

  x_ref_ = x_start_ = grid_.initialPositions();
  if (needs_equilibrium)
    linearizeAtEquilibrium(data, cached.has_value(), on_stage, on_iteration);
  // A start inside a collider is refused before the basis is built.
  if (!params_.colliders.empty())
    checkStartOutsideColliders(grid_, x_start_, params_.colliders,
                               resolveContactThickness(params_.contact_thickness, g.spacing),
                               "initial_state " + toString(params_.initial_state));
  // At a hanging equilibrium compressed springs would make K indefinite: their geometric part is
  // dropped so that no mode has a negative lambda^2. At rest no spring is compressed.
  stage("stiffness");
  const auto stiffness_start = Clock::now();
  stiffness_ = tangentStiffness(grid_, x_ref_, CompressedSprings::Drop, &linearization_.dropped_compressed_springs);
  linearization_.stiffness_seconds = since(stiffness_start);
  mass_ = Eigen::VectorXd::Constant(n, grid_.particleMass());
  total_mass_ = mass_.sum();
  if (cached)
  {
    // The start-up's times are this start's: loading took the place of the solves.
    data.basis.build_seconds = data.basis.factorization_seconds = 0.0;
    data.physical_basis.build_seconds = data.physical_basis.factorization_seconds = 0.0;
    data.derivative_info.seconds = 0.0;
    data.skinning_info.seconds = 0.0;
    adoptBasis(std::move(data));
  }
  // `full` needs no basis: it is built at the first switch to a modal method, so that a run of `full`
  // alone does not wait for it.
  else if (isModal(params_.method))
    buildBasis(on_stage, on_iteration);
}

void Simulation::linearizeAtEquilibrium(Precomputed& data, bool cached, const StageFn& on_stage,
                                        const IterationFn& on_iteration)
{
  using Clock = std::chrono::steady_clock;
  if (!cached)
  {
    if (on_stage)
      on_stage("equilibrium");
    const auto start = Clock::now();
    EquilibriumProgress progress;
    if (on_iteration)
      progress = [&on_iteration](int iteration, double residual, double target) {
        on_iteration("equilibrium", iteration, residual, target);
      };
    Equilibrium equilibrium = solveEquilibrium(grid_, grid_.initialPositions(), params_.equilibrium_max_iterations,
                                               kEquilibriumTolerance, progress);
    data.equilibrium_seconds = std::chrono::duration<double>(Clock::now() - start).count();
    data.equilibrium_iterations = equilibrium.iterations;
    data.equilibrium_residual = equilibrium.residual;
    data.equilibrium = std::move(equilibrium.positions);
  }
  linearization_.equilibrium_solved = true;
  linearization_.equilibrium_seconds = cached ? 0.0 : data.equilibrium_seconds;
  linearization_.equilibrium_iterations = data.equilibrium_iterations;
  linearization_.equilibrium_residual = data.equilibrium_residual;
  if (params_.linearization == Linearization::Equilibrium)
    x_ref_ = data.equilibrium;
  if (params_.initial_state == InitialState::Equilibrium)
    x_start_ = data.equilibrium;
  equilibrium_ = data.equilibrium;
}

Simulation::~Simulation() = default;

const Grid* Simulation::coarseGrid() const { return coarse_ ? &coarse_->grid : nullptr; }

Method Simulation::method() const { return model_->method(); }
int Simulation::lastNewtonIterations() const { return model_->integrator().lastIterations(); }
int Simulation::lastImplicitSubsteps() const { return model_->integrator().lastSubsteps(); }
const State& Simulation::state() const { return model_->state(); }
Eigen::VectorXd Simulation::bodyDisplacement() const { return model_->displacement(model_->state()); }
Eigen::VectorXd Simulation::bodyVelocity() const { return model_->velocity(model_->state()); }

void Simulation::buildBasis(const StageFn& on_stage, const IterationFn& on_iteration)
{
  if (basis_built_)
    return;
  auto stage = [&](const std::string& name) {
    if (on_stage)
      on_stage(name);
  };
  const GridParams& g = grid_.params();
  Precomputed data;
  {
    data.basis = computeModalBasis(stiffness_, mass_, params_.num_modes, on_stage, on_iteration);
    if (!data.basis.phi.allFinite() || !data.basis.eigenvalues.allFinite() || !data.basis.frequencies.allFinite())
    {
      std::ostringstream value;
      value << "mass = " << g.mass << ", structural_stiffness = " << g.structural_stiffness
            << ", shear_stiffness = " << g.shear_stiffness << ", spacing = " << g.spacing;
      rejectParameter("mass, stiffnesses, spacing", value.str(),
                      "give a modal basis that is not finite; keep stiffness / mass and spacing in a range where "
                      "frequencies and lengths are representable");
    }
    if (params_.basis == BasisKind::Skinning)
    {
      stage("skinning");
      SkinningBasis skinning =
          buildSkinningBasis(grid_, x_ref_, stiffness_, mass_, params_.num_skinning_weights, data.basis.phi);
      if (!skinning.basis.phi.allFinite() || !skinning.constraint_modes.allFinite())
        throw std::runtime_error("skinning: the subspace is not finite");
      data.physical_basis = std::move(skinning.basis);
      data.skinning_constraint_modes = std::move(skinning.constraint_modes);
      data.skinning_info = skinning.info;
    }
    else if (params_.basis == BasisKind::ModalDerivatives)
    {
      stage("modal derivatives");
      data.physical_basis = buildDerivativeBasis(grid_, x_ref_, stiffness_, mass_, data.basis,
                                                 params_.num_derivative_modes, &data.derivative_info);
      if (!data.physical_basis.phi.allFinite() || !data.physical_basis.reduced_stiffness.allFinite())
        throw std::runtime_error("modal derivatives: the basis is not finite");
    }
    else
    {
      data.physical_basis = data.basis;
    }
    if (!cache_report_.basis_file.empty())
    {
      data.equilibrium = equilibrium_;
      data.equilibrium_iterations = linearization_.equilibrium_iterations;
      data.equilibrium_residual = linearization_.equilibrium_residual;
      data.equilibrium_seconds = linearization_.equilibrium_seconds;
      cache_report_.basis_stored = storePrecomputed(cache_report_.basis_file, basisKey(g, params_), data, cache_);
    }
  }
  adoptBasis(std::move(data));
}

void Simulation::adoptBasis(Precomputed&& data)
{
  basis_ = std::move(data.basis);
  physical_basis_ = std::move(data.physical_basis);
  derivative_info_ = data.derivative_info;
  skinning_info_ = data.skinning_info;
  skinning_constraint_modes_ = std::move(data.skinning_constraint_modes);
  basis_built_ = true;
}

void Simulation::prepareCubature(const IterationFn& on_iteration)
{
  if (!loadCachedCubature())
    setCubature(cubatureTraining()(on_iteration));
}

bool Simulation::loadCachedCubature()
{
  if (cubature_)
    return true;
  if (cache_.directory.empty())
    return false;
  const std::string key = cubatureKey(grid_.params(), params_);
  cache_report_.cubature_file = cacheFile(cache_.directory, "cubature", key);
  cubature_ = loadCubature(cache_report_.cubature_file, key, static_cast<int>(grid_.springs().size()), cache_);
  cache_report_.cubature_loaded = cubature_.has_value();
  return cubature_.has_value();
}

Simulation::CubatureTraining Simulation::cubatureTraining() const
{
  if (!basis_built_)
    throw std::logic_error("cubatureTraining: the basis is not built (buildBasis first)");
  // The training's memory counts now, whatever the method the parameters were checked with.
  SimulationParams training = params_;
  training.method = Method::Cubature;
  validateParameters(grid_.params(), training);
  // On the skinning span the poses turn the cloth (its motions are large rotations), else the modes'.
  // The job refers to what never changes after the basis is built and copies the parameters.
  PoseSampler sampler;
  if (params_.basis == BasisKind::Skinning)
  {
    const Eigen::MatrixXd projection =
        skinningProjection(grid_, x_ref_, physical_basis_, mass_, params_.num_skinning_weights);
    sampler = [this, projection, size = params_.cubature_pose_size](int count, std::mt19937_64& rng) {
      return skinningTrainingPoses(grid_, physical_basis_, x_ref_, projection, count, size, rng);
    };
  }
  return [this, sampler, params = cubatureParams(params_)](const IterationFn& on_iteration) {
    return trainCubature(grid_, physical_basis_, x_ref_, params, sampler, on_iteration);
  };
}

void Simulation::setCubature(Cubature cubature)
{
  cubature_ = std::move(cubature);
  if (cache_.directory.empty())
    return;
  const std::string key = cubatureKey(grid_.params(), params_);
  cache_report_.cubature_file = cacheFile(cache_.directory, "cubature", key);
  cache_report_.cubature_loaded = false;
  cache_report_.cubature_stored = storeCubature(cache_report_.cubature_file, key, *cubature_, cache_);
}

IntegratorSettings Simulation::integratorSettings() const
{
  return IntegratorSettings{params_.integrator, params_.time_step * step_span_, params_.newton_max_iterations,
                            params_.hht_alpha,  params_.alpha,     params_.beta,
                            params_.implicit_solver, params_.tangent_refresh_steps};
}

void Simulation::prepareConstraintModes(Method method)
{
  // The modal methods carry the handles' static influence with the constraint modes; in the moving
  // frame the handles never leave x_ref and the fixed-interface modes are the whole basis.
  // With basis: skinning the methods but `linear` carry them in the skinning span instead.
  const bool handles = grid_.numHandleDofs() > 0;
  const bool moving_frame = formulation_ == HandleFormulation::MovingFrame;
  const bool skinning = params_.basis == BasisKind::Skinning && method != Method::Linear;
  if (!handles || moving_frame || !isModal(method) || skinning || constraint_modes_.size() > 0)
    return;
  try
  {
    constraint_modes_ = modal_mass_spring::constraintModes(stiffness_, handle_coupling_);
  }
  catch (const std::runtime_error& error)
  {
    if (params_.linearization != Linearization::Equilibrium)
      throw;
    // Already at the equilibrium: the advice to linearize there does not apply. What is left is
    // cloth that hangs slack from these handles, with no stiffness across it.
    throw std::runtime_error(
        "handles: the stiffness of the interior dofs with the handles held is singular at the hanging equilibrium "
        "(linearization: equilibrium), so the constraint modes Psi = -K_ii^-1 K_ib do not exist: cloth hanging "
        "slack from these handles (small grips far apart) has no stiffness across it there; use basis: skinning "
        "(physical or cubature), hold it by larger grips (e.g. a whole row, or the top row's outer particles), fix "
        "some particles, or hold it by one handle with handle_formulation: moving_frame");
  }
}

void Simulation::buildFor(Method method)
{
  if (isModal(method))
    buildBasis();
  if (method == Method::Coarse && !coarse_)
  {
    // Unfitted where the fit fails (a rest length that would not stay positive): `coarse` as before.
    auto coarse = std::make_unique<CoarseGrid>(grid_, params_.coarse_cols);
    if (equilibrium_.size() > 0)
      coarse->fitRestLengths(equilibrium_);
    coarse_ = std::move(coarse);
  }
}

void Simulation::install(Method method, const Eigen::VectorXd& u, const Eigen::VectorXd& v, Remainder remainder)
{
  // `linear` needs the eigenbasis (F = -Lambda X); every other modal method uses the physical basis,
  // and the cubature is trained on it.
  buildFor(method);
  const ModalBasis& basis = method == Method::Linear ? basis_ : physical_basis_;
  // Before a cubature's training: a held set the method cannot follow is refused at once.
  prepareConstraintModes(method);
  if (method == Method::Cubature)
    prepareCubature();
  const bool handles = grid_.numHandleDofs() > 0;
  const bool moving_frame = formulation_ == HandleFormulation::MovingFrame;
  const bool skinning = params_.basis == BasisKind::Skinning && method != Method::Linear;
  const Eigen::MatrixXd& psi = skinning ? skinning_constraint_modes_ : constraint_modes_;
  LinearizedGrid linearized{grid_,
                            basis,
                            x_ref_,
                            stiffness_,
                            mass_,
                            cubature_ ? &*cubature_ : nullptr,
                            handles ? &handle_coupling_ : nullptr,
                            handles && !moving_frame && psi.size() > 0 ? &psi : nullptr};
  linearized.static_constraint_modes = !skinning;
  linearized.coarse = coarse_.get();
  model_ = makeMethod(method, linearized, integratorSettings());
  params_.method = method;
  if (handles)
    model_->setHandleMotion(handle_current_);
  if (moving_frame)
    model_->setFrameForces(frameForcesOf(frame_current_));
  model_->setExternalForce(grid_.gatherFree(external_force_));
  projection_error_ = model_->assign(u, v, remainder);
  ++state_sets_;
  time_since_set_ = 0.0;
  model_->setAnchor(anchor_, anchor_handles_);
  diverged_ = false;
  divergence_message_.clear();
}

void Simulation::setMethod(Method method)
{
  if (self_collision_ && method != Method::Full)
    rejectParameter("method", toString(method), kSelfCollisionMethods);
  // The energy measures differ between methods (linear conserves its quadratic model's): the rise
  // since the start carries over, so that switching back and forth never resets the check.
  const double rise = methodEnergy() - start_energy_;
  install(method, bodyDisplacement(), bodyVelocity(), Remainder::Keep);
  start_energy_ = methodEnergy() - rise;
}

void Simulation::setPhysicalState(const Eigen::VectorXd& u_world, const Eigen::VectorXd& v_world)
{
  Eigen::VectorXd u = u_world, v = v_world;
  toBody(u, v);
  anchor_ = u;
  anchor_handles_ = handle_current_.displacement;
  install(params_.method, u, v, Remainder::Drop);
  // Distances are measured from the start as this method holds it: a modal method's projection of a
  // start far outside its modes has not diverged by being where the projection put it.
  anchor_ = bodyDisplacement();
  model_->setAnchor(anchor_, anchor_handles_);
  handles_moved_ = !handle_current_.atRest() || !frame_current_.atRest();
  start_energy_ = methodEnergy();
  energy_scale_ = base_energy_scale_ + kineticEnergy() + springEnergy(grid_, positions());
}

void Simulation::setTimeStep(double dt)
{
  SimulationParams changed = params_;
  changed.time_step = dt;
  validateParameters(grid_.params(), changed);
  params_.time_step = dt;
  model_->configure(integratorSettings());
}

void Simulation::setStepSpan(int time_steps)
{
  if (time_steps < 1)
    rejectParameter("step_span", time_steps, "must be an integer >= 1 (time steps a step takes)");
  if (time_steps == step_span_)
    return;
  step_span_ = time_steps;
  model_->configure(integratorSettings());
}

void Simulation::reset()
{
  step_span_ = 1;  // installed with the start below
  // The handles go back to rest at the linearization point with the grid.
  handle_current_ = handle_target_ = HandleMotion{};
  handle_pending_ = false;
  frame_current_ = frame_target_ = FrameMotion{};
  frame_pending_ = false;
  setPhysicalState(u_start_, Eigen::VectorXd::Zero(u_start_.size()));
  if (contact_)
  {
    contact_->reset();
    // A collider set or moved since may stand where the grid started: the first step pushes the grid
    // out, work done on it that the energy check must not take for a divergence.
    handles_moved_ = handles_moved_ || insideCollider(grid_, *contact_, positions());
  }
  step_count_ = 0;
}

std::string Simulation::divergence(bool integrator_ok, const State& next)
{
  if (!integrator_ok && params_.integrator == IntegratorKind::Explicit)
    return "the explicit scheme's velocity with the Coriolis forces of the turning handle frame did not converge: "
           "the frame turns too fast for time_step (time_step times its angular velocity must stay well below 1)";
  if (!integrator_ok)
    return "the implicit Newton iteration did not converge in newton_max_iterations = " +
           std::to_string(params_.newton_max_iterations) + ", even in 1/16 of the step";
  if (!next.q.allFinite() || !next.v.allFinite() || !next.a.allFinite())
    return "non-finite state";
  // O(r) for a modal method, like the energy below (the force evaluation of the step left it cached):
  // nothing here grows with the grid. The message is built only for a step that fails.
  const double distance = std::sqrt(model_->anchorDistanceSquared(next.q) / total_mass_);
  if (distance > limit_)
  {
    std::ostringstream msg;
    msg << "mass-weighted RMS displacement from the start " << distance << " m beyond divergence_limit " << limit_
        << " m";
    return msg.str();
  }
  // Damping only removes energy and gravity is conservative: a rise is the integrator's doing. Moving
  // handles do work on the grid, which this measure does not count: the check is off then.
  if (handles_moved_)
    return "";
  const double energy = model_->energy(next);
  if (!std::isfinite(energy) || energy > start_energy_ + params_.energy_tolerance * energy_scale_)
  {
    std::ostringstream msg;
    msg << "energy " << energy << " J rose above its start " << start_energy_ << " J by more than energy_tolerance "
        << params_.energy_tolerance << " x the energy scale " << energy_scale_ << " J";
    return msg.str();
  }
  return "";
}

StepResult Simulation::step(int steps)
{
  StepResult result;
  if (diverged_)
  {
    result.diverged = true;
    result.message = divergence_message_ + " (step " + std::to_string(step_count_) +
                     "); reset or switch method to go on";
    return result;
  }
  for (int k = 0; k < steps; ++k)
  {
    // The forces at the end of the step see the handles where the step takes them.
    const bool moving = handle_pending_;
    if (moving)
    {
      model_->setHandleMotion(handle_target_);
      handles_moved_ = handles_moved_ || !handle_target_.atRest();
    }
    const bool turning = frame_pending_;
    if (turning)
    {
      model_->setFrameForces(frameForcesOf(frame_target_));
      handles_moved_ = handles_moved_ || !frame_target_.atRest();
    }
    bool ok = model_->step();
    if (ok && contact_)
    {
      // CPU time, which a loaded machine does not inflate as it does wall time.
      const double start = processCpuSeconds();
      model_->correctContacts(*contact_);
      contact_seconds_ = processCpuSeconds() - start;
      handles_moved_ = handles_moved_ || contact_->moved();
    }
    // After the colliders: a particle they hold does not move for self-collision (the layer above
    // rests on it; see SelfCollision::correct).
    if (ok && self_collision_)
    {
      const double start = processCpuSeconds();
      model_->correctSelfCollision(*self_collision_, contact_.get());
      self_collision_seconds_ = processCpuSeconds() - start;
    }
    const std::string why = divergence(ok, model_->next());
    if (!why.empty())
    {
      if (moving)
        model_->setHandleMotion(handle_current_);  // the last good state, with its handles
      if (turning)
        model_->setFrameForces(frameForcesOf(frame_current_));
      diverged_ = true;
      result.diverged = true;
      std::ostringstream msg;
      msg << "method '" << toString(method()) << "' diverged at step " << step_count_ + step_span_ << " with time_step "
          << params_.time_step * step_span_ << " s (" << why << "); the last good state is kept; a smaller time_step"
          << (params_.integrator == IntegratorKind::Explicit ? ", the implicit integrator" : "")
          << (params_.integrator == IntegratorKind::Implicit && params_.hht_alpha == 0.0
                  ? ", hht_alpha below 0 (it damps the highest frequencies that gain energy at large steps)"
                  : "")
          << " or more damping may help";
      divergence_message_ = result.message = msg.str();
      return result;
    }
    model_->commit();
    if (contact_)
      contact_->commit();
    if (moving)
    {
      handle_current_ = handle_target_;
      handle_pending_ = false;
    }
    if (turning)
    {
      frame_current_ = frame_target_;
      frame_pending_ = false;
    }
    step_count_ += step_span_;
    time_since_set_ += params_.time_step * step_span_;
    ++result.steps_taken;
  }
  return result;
}

}  // namespace modal_mass_spring
