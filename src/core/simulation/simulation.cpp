// A simulation: the linearization point and basis, and the current method stepped with its divergence
// checks (its parameters are checked in validation.cpp).
#include "modal_mass_spring/cpu_time.h"
#include "modal_mass_spring/simulation.h"

#include "modal_mass_spring/spring_forces.h"
#include "modal_mass_spring/validation.h"
#include "dynamics/method_model.h"
#include "reduction/error_indicator.h"
#include "solvers/equilibrium.h"

#include <chrono>
#include <time.h>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace modal_mass_spring
{

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
    if (on_stage)
      on_stage("cubature");
    prepareCubature(on_iteration);
  }
  if (!params_.colliders.empty())
    contact_ = std::make_unique<Contact>(grid_, params_.colliders,
                                         params_.contact_thickness > 0.0 ? params_.contact_thickness
                                                                         : kDefaultThicknessFraction * g.spacing);
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
  {
    if (!cached)
    {
      stage("equilibrium");
      const auto start = Clock::now();
      EquilibriumProgress progress;
      if (on_iteration)
        progress = [&on_iteration](int iteration, double residual, double target) {
          on_iteration("equilibrium", iteration, residual, target);
        };
      Equilibrium equilibrium = solveEquilibrium(grid_, grid_.initialPositions(), params_.equilibrium_max_iterations,
                                                 kEquilibriumTolerance, progress);
      data.equilibrium_seconds = since(start);
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
  // `full` needs no basis: it is built at the first switch to a modal method (on a 200 x 200 grid it
  // took minutes).
  else if (params_.method != Method::Full)
    buildBasis(on_stage, on_iteration);
}

Simulation::~Simulation() = default;

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
  return IntegratorSettings{params_.integrator, params_.time_step, params_.newton_max_iterations,
                            params_.hht_alpha,  params_.alpha,     params_.beta,
                            params_.implicit_solver, params_.tangent_refresh_steps};
}

void Simulation::install(Method method, const Eigen::VectorXd& u, const Eigen::VectorXd& v, Remainder remainder)
{
  // `linear` needs the eigenbasis (F = -Lambda X); every other modal method uses the physical basis,
  // and the cubature is trained on it.
  if (method != Method::Full)
    buildBasis();
  const ModalBasis& basis = method == Method::Linear ? basis_ : physical_basis_;
  if (method == Method::Cubature)
    prepareCubature();
  // The modal methods carry the handles' static influence with the constraint modes; in the moving
  // frame the handles never leave x_ref and the fixed-interface modes are the whole basis.
  // With basis: skinning the methods but `linear` carry them in the skinning span instead.
  const bool handles = grid_.numHandleDofs() > 0;
  const bool moving_frame = formulation_ == HandleFormulation::MovingFrame;
  const bool skinning = params_.basis == BasisKind::Skinning && method != Method::Linear;
  if (handles && !moving_frame && method != Method::Full && !skinning && constraint_modes_.size() == 0)
  {
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
  model_ = makeMethod(method, linearized, integratorSettings());
  params_.method = method;
  if (handles)
    model_->setHandleMotion(handle_current_);
  if (moving_frame)
    model_->setFrameForces(frameForcesOf(frame_current_));
  model_->setExternalForce(grid_.gatherFree(external_force_));
  projection_error_ = model_->assign(u, v, remainder);
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

void Simulation::setExternalForce(const Eigen::VectorXd& force)
{
  if (force.size() != external_force_.size())
    rejectParameter("external force", std::to_string(force.size()) + " values",
                    "must have " + std::to_string(external_force_.size()) + " values, " +
                        std::to_string(grid_.dimension()) + " per particle");
  for (int k = 0; k < force.size(); ++k)
    if (!std::isfinite(force[k]))
      rejectParameter("external force", "a non-finite value on particle " + std::to_string(k / grid_.dimension()),
                      "must be finite");
  // A constant force is conservative: its potential joins the method's energy, and the rise since
  // the start carries over the change, as over a method switch.
  const double rise = methodEnergy() - start_energy_;
  external_force_ = force;
  model_->setExternalForce(grid_.gatherFree(external_force_));
  start_energy_ = methodEnergy() - rise;
}

void Simulation::setHandleMotion(const Eigen::VectorXd& positions, const Eigen::VectorXd& velocities,
                                 const Eigen::VectorXd& accelerations)
{
  const int nb = grid_.numHandleDofs();
  const std::string allowed = "must have " + std::to_string(nb) + " values, " + std::to_string(grid_.dimension()) +
                              " per handle particle, handle by handle";
  auto check = [&](const std::string& name, const Eigen::VectorXd& values, bool may_be_empty) {
    if (values.size() != nb && !(may_be_empty && values.size() == 0))
      rejectParameter(name, std::to_string(values.size()) + " values",
                      nb == 0 ? std::string("the grid has no handles") : allowed + (may_be_empty ? " (or none: 0)" : ""));
    for (Eigen::Index k = 0; k < values.size(); ++k)
      if (!std::isfinite(values[k]))
        rejectParameter(name, "a non-finite value on handle dof " + std::to_string(k), "must be finite");
  };
  if (formulation_ == HandleFormulation::MovingFrame)
    rejectParameter("handle positions", std::to_string(positions.size()) + " values",
                    "the handles move as one rigid body in the moving frame (handle_formulation: moving_frame): "
                    "prescribe that body's motion with setHandleFrameMotion");
  check("handle positions", positions, false);
  check("handle velocities", velocities, true);
  check("handle accelerations", accelerations, true);
  HandleMotion target;
  target.displacement.resize(nb);
  for (int k = 0; k < nb; ++k)
    target.displacement[k] = positions[k] - x_ref_[grid_.handleDofs()[k]];
  target.velocity = velocities.size() > 0 ? velocities : Eigen::VectorXd::Zero(nb);
  target.acceleration = accelerations.size() > 0 ? accelerations : Eigen::VectorXd::Zero(nb);
  handle_target_ = target;
  handle_pending_ = true;
}

void Simulation::placeFrame(const FrameMotion& m)
{
  if (formulation_ != HandleFormulation::MovingFrame)
    return;
  checkFrameMotion(m);
  frame_current_ = frame_target_ = m;
  frame_pending_ = false;
  // The same state in B, its acceleration from B's new forces.
  install(params_.method, bodyDisplacement(), bodyVelocity(), Remainder::Keep);
  handles_moved_ = handles_moved_ || !m.atRest();
}

void Simulation::checkFrameMotion(const FrameMotion& m) const
{
  if (grid_.numHandleDofs() == 0)
    rejectParameter("handle frame motion", "a frame", "the grid has no handles to move");
  const std::vector<std::pair<std::string, Eigen::VectorXd>> parts{
      {"translation", m.translation},         {"velocity", m.velocity},
      {"acceleration", m.acceleration},       {"angular velocity", m.angular_velocity},
      {"angular acceleration", m.angular_acceleration}, {"rotation", m.rotation.reshaped()}};
  for (const auto& [name, values] : parts)
    if (!values.allFinite())
      rejectParameter("handle frame " + name, "a non-finite value", "must be finite");
  const double orthogonality = (m.rotation.transpose() * m.rotation - Eigen::Matrix3d::Identity()).norm();
  if (orthogonality > 1e-9 || m.rotation.determinant() <= 0.0)
  {
    std::ostringstream value;
    value << "|R^T R - I| = " << orthogonality << ", det R = " << m.rotation.determinant();
    rejectParameter("handle frame rotation", value.str(), "must be a rotation (R^T R = I to 1e-9, det R = 1)");
  }
  if (grid_.dimension() == 2)
  {
    // Only a turn about y keeps the x-z plane; a 2D grid has no y to move along, which is dropped.
    const double scale = 1.0 + m.angular_velocity.norm() + m.angular_acceleration.norm();
    const double off_plane = std::abs(m.rotation(0, 1)) + std::abs(m.rotation(1, 0)) + std::abs(m.rotation(1, 2)) +
                             std::abs(m.rotation(2, 1)) +
                             (std::abs(m.angular_velocity.x()) + std::abs(m.angular_velocity.z()) +
                              std::abs(m.angular_acceleration.x()) + std::abs(m.angular_acceleration.z())) /
                                 scale;
    if (off_plane > 1e-9)
      rejectParameter("handle frame rotation", "a turn out of the x-z plane",
                      "a 2D grid's frame may only turn about y (its plane's normal)");
  }
}

void Simulation::setHandleFrameMotion(const FrameMotion& m)
{
  checkFrameMotion(m);
  if (formulation_ == HandleFormulation::MovingFrame)
  {
    frame_target_ = m;
    frame_pending_ = true;
    return;
  }
  // Constraint modes: the handle particles' rigid motion.
  const int dim = grid_.dimension();
  const std::vector<int> rows = gridAxes(dim);
  const std::vector<int>& dofs = grid_.handleDofs();
  const Eigen::Index n = static_cast<Eigen::Index>(dofs.size()) / dim;
  const Eigen::Matrix3Xd all = grid_.toPoints(x_ref_);
  Eigen::Matrix3Xd points(3, n);
  for (Eigen::Index p = 0; p < n; ++p)
    points.col(p) = all.col(dofs[dim * p] / dim);
  const RigidPointMotion motion = pointMotion(m, points);
  Eigen::VectorXd x(dofs.size()), v(dofs.size()), a(dofs.size());
  for (Eigen::Index p = 0; p < n; ++p)
    for (int c = 0; c < dim; ++c)
    {
      x[dim * p + c] = motion.position(rows[c], p);
      v[dim * p + c] = motion.velocity(rows[c], p);
      a[dim * p + c] = motion.acceleration(rows[c], p);
    }
  setHandleMotion(x, v, a);
}

FrameForces Simulation::frameForcesOf(const FrameMotion& motion) const
{
  return frameForces(motion, grid_.dimension(), grid_.params().gravity, params_.alpha);
}

Eigen::VectorXd Simulation::handlePositions() const
{
  const std::vector<int>& dofs = grid_.handleDofs();
  Eigen::VectorXd x(static_cast<Eigen::Index>(dofs.size()));
  for (size_t k = 0; k < dofs.size(); ++k)
    x[static_cast<Eigen::Index>(k)] = x_ref_[dofs[k]];
  if (handle_current_.displacement.size() > 0)
    x += handle_current_.displacement;
  return x;
}

void Simulation::setHandleState(const Eigen::VectorXd& positions, const Eigen::VectorXd& velocities,
                                const Eigen::VectorXd& accelerations)
{
  setHandleMotion(positions, velocities, accelerations);  // checks them
  const Eigen::VectorXd u = displacement(), v = velocity();
  handle_current_ = handle_target_;
  handle_pending_ = false;
  // Once a handle has moved it can do work on the grid: the energy check stays off.
  handles_moved_ = handles_moved_ || !handle_current_.atRest();
  // The method splits the same free-dof motion again around the handles' new place (a divergence
  // stays: only a reset or a method switch clears it).
  const double rise = methodEnergy() - start_energy_;
  const bool diverged = diverged_;
  const std::string message = divergence_message_;
  install(params_.method, u, v, Remainder::Keep);
  diverged_ = diverged;
  divergence_message_ = message;
  start_energy_ = methodEnergy() - rise;
}

void Simulation::reset()
{
  // The handles go back to rest at the linearization point with the grid.
  handle_current_ = handle_target_ = HandleMotion{};
  handle_pending_ = false;
  frame_current_ = frame_target_ = FrameMotion{};
  frame_pending_ = false;
  setPhysicalState(u_start_, Eigen::VectorXd::Zero(u_start_.size()));
  if (contact_)
    contact_->reset();
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
      msg << "method '" << toString(method()) << "' diverged at step " << step_count_ + 1 << " with time_step "
          << params_.time_step << " s (" << why << "); the last good state is kept; a smaller time_step"
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
    ++step_count_;
    ++result.steps_taken;
  }
  return result;
}

SimulationState Simulation::saveState() const
{
  SimulationState s;
  s.method = method();
  s.time_step = params_.time_step;
  s.step_count = step_count_;
  s.coordinates = model_->state();
  s.offset = model_->offset();
  s.handles = handle_current_;
  s.frame = frame_current_;
  if (contact_)
  {
    for (int i = 0; i < static_cast<int>(contact_->colliders().size()); ++i)
    {
      s.collider_poses.push_back(contact_->pose(i));
      s.colliders_active.push_back(contact_->active(i));
    }
    s.colliders_moved = contact_->moved();
  }
  s.external_force = external_force_;
  s.anchor = anchor_;
  s.anchor_handles = anchor_handles_;
  s.start_energy = start_energy_;
  s.energy_scale = energy_scale_;
  s.handles_moved = handles_moved_;
  s.diverged = diverged_;
  s.divergence_message = divergence_message_;
  return s;
}

void Simulation::restoreState(const SimulationState& s)
{
  // Everything is checked before anything changes.
  SimulationParams changed = params_;
  changed.time_step = s.time_step;
  validateParameters(grid_.params(), changed);
  if (self_collision_ && s.method != Method::Full)
    rejectParameter("state.method", toString(s.method), kSelfCollisionMethods);
  if (s.method != Method::Full)
    buildBasis();
  const Eigen::Index free_dofs = u_start_.size();
  const Eigen::Index coordinates = s.method == Method::Full  ? free_dofs
                                   : s.method == Method::Linear ? basis_.phi.cols()
                                                                 : physical_basis_.phi.cols();
  auto check = [](const std::string& name, const Eigen::VectorXd& values, Eigen::Index size, bool may_be_empty) {
    if (values.size() != size && !(may_be_empty && values.size() == 0))
      rejectParameter("state." + name, std::to_string(values.size()) + " values",
                      "must have " + std::to_string(size) + " values" + (may_be_empty ? " (or none)" : ""));
    if (!values.allFinite())
      rejectParameter("state." + name, "a non-finite value", "must be finite");
  };
  check("coordinates", s.coordinates.q, coordinates, false);
  check("velocities", s.coordinates.v, coordinates, false);
  check("accelerations", s.coordinates.a, coordinates, false);
  check("offset", s.offset, s.method == Method::Full ? 0 : free_dofs, true);
  const Eigen::Index handle_dofs = grid_.numHandleDofs();
  check("handles.displacement", s.handles.displacement, handle_dofs, true);
  check("handles.velocity", s.handles.velocity, handle_dofs, true);
  check("handles.acceleration", s.handles.acceleration, handle_dofs, true);
  check("external_force", s.external_force, external_force_.size(), false);
  check("anchor", s.anchor, free_dofs, false);
  check("anchor_handles", s.anchor_handles, handle_dofs, true);
  const size_t colliders = contact_ ? contact_->colliders().size() : 0;
  if (s.collider_poses.size() != colliders || s.colliders_active.size() != colliders)
    rejectParameter("state.collider_poses", std::to_string(s.collider_poses.size()) + " poses",
                    "must have one per collider: " + std::to_string(colliders));
  for (size_t i = 0; i < colliders; ++i)
    if (!s.collider_poses[i].matrix().allFinite())
      rejectParameter("state.collider_poses[" + std::to_string(i) + "]", "a non-finite value", "must be finite");
  if (s.step_count < 0)
    rejectParameter("state.step_count", s.step_count, "must be >= 0");

  if (s.time_step != params_.time_step)
    setTimeStep(s.time_step);
  handle_current_ = handle_target_ = s.handles;
  handle_pending_ = false;
  frame_current_ = frame_target_ = s.frame;
  frame_pending_ = false;
  external_force_ = s.external_force;
  if (contact_)
    contact_->restore(s.collider_poses, s.colliders_active, s.colliders_moved);
  if (s.method != method())
    setMethod(s.method);
  // The method's forces see the state's handles, frame and load before its coordinates go back:
  // setting them recomputes the acceleration, which restore() then replaces with the saved one.
  model_->setExternalForce(grid_.gatherFree(external_force_));
  if (grid_.numHandleDofs() > 0)
    model_->setHandleMotion(handle_current_);
  if (formulation_ == HandleFormulation::MovingFrame)
    model_->setFrameForces(frameForcesOf(frame_current_));
  model_->restore(s.coordinates, s.offset);
  anchor_ = s.anchor;
  anchor_handles_ = s.anchor_handles;
  model_->setAnchor(anchor_, anchor_handles_);
  start_energy_ = s.start_energy;
  energy_scale_ = s.energy_scale;
  handles_moved_ = s.handles_moved;
  step_count_ = s.step_count;
  diverged_ = s.diverged;
  divergence_message_ = s.divergence_message;
}

namespace
{

// B's translation, its velocity and the angular velocity in the grid's coordinates (x, z in 2D).
struct PlanarFrame
{
  Eigen::MatrixXd rotation, spin;
  Eigen::VectorXd translation, velocity;

  // Where a point at y in B, moving at y' there, is in the world and how fast it goes:
  // x = p + R y, x' = p' + omega x R y + R y'.
  Eigen::VectorXd worldPosition(const Eigen::VectorXd& y) const { return translation + rotation * y; }
  Eigen::VectorXd worldVelocity(const Eigen::VectorXd& y, const Eigen::VectorXd& y_dot) const
  {
    return velocity + spin * (rotation * y) + rotation * y_dot;
  }
};

PlanarFrame restrict(const FrameMotion& m, int dim)
{
  const std::vector<int> rows = gridAxes(dim);
  const Eigen::Matrix3d spin = crossMatrix(m.angular_velocity);
  return PlanarFrame{m.rotation(rows, rows), spin(rows, rows), m.translation(rows), m.velocity(rows)};
}

}  // namespace

void Simulation::toBody(Eigen::VectorXd& u, Eigen::VectorXd& v) const
{
  if (!frameMoved())
    return;
  // y = R^T (x - p), y' = R^T (x' - p' - omega x (x - p)).
  const int dim = grid_.dimension();
  const PlanarFrame f = restrict(frame_current_, dim);
  const Eigen::VectorXd x_ref = grid_.gatherFree(x_ref_);
  for (Eigen::Index p = 0; p + dim <= u.size(); p += dim)
  {
    const Eigen::VectorXd r = x_ref.segment(p, dim) + u.segment(p, dim) - f.translation;
    u.segment(p, dim) = f.rotation.transpose() * r - x_ref.segment(p, dim);
    v.segment(p, dim) = f.rotation.transpose() * (v.segment(p, dim) - f.velocity - f.spin * r);
  }
}

Eigen::VectorXd Simulation::displacement() const
{
  if (!frameMoved())
    return bodyDisplacement();
  return grid_.gatherFree(positions() - x_ref_);
}

Eigen::VectorXd Simulation::velocity() const
{
  if (!frameMoved())
    return bodyVelocity();
  // x' = p' + omega x R y + R y'.
  const int dim = grid_.dimension();
  const PlanarFrame f = restrict(frame_current_, dim);
  const Eigen::VectorXd y = grid_.gatherFree(x_ref_) + bodyDisplacement();
  Eigen::VectorXd v = bodyVelocity();
  for (Eigen::Index p = 0; p + dim <= v.size(); p += dim)
    v.segment(p, dim) = f.worldVelocity(y.segment(p, dim), v.segment(p, dim));
  return v;
}

Eigen::VectorXd Simulation::positions() const
{
  Eigen::VectorXd x = x_ref_;
  if (handle_current_.displacement.size() > 0)
    for (int k = 0; k < grid_.numHandleDofs(); ++k)
      x[grid_.handleDofs()[k]] += handle_current_.displacement[k];
  grid_.addFree(bodyDisplacement(), x);
  if (frameMoved())
  {
    // x = p + R y, every particle (the handles' with them).
    const int dim = grid_.dimension();
    const PlanarFrame f = restrict(frame_current_, dim);
    for (Eigen::Index p = 0; p + dim <= x.size(); p += dim)
      x.segment(p, dim) = f.worldPosition(x.segment(p, dim));
  }
  return x;
}

double Simulation::errorIndicator()
{
  if (params_.method == Method::Full)
    return 0.0;
  if (!error_indicator_)
    error_indicator_ = std::make_unique<ErrorIndicator>(grid_, mass_);
  // In the body frame where one moves: the springs do not see the frame, and the basis lives there.
  Eigen::VectorXd x = x_ref_;
  if (handle_current_.displacement.size() > 0)
    for (int k = 0; k < grid_.numHandleDofs(); ++k)
      x[grid_.handleDofs()[k]] += handle_current_.displacement[k];
  grid_.addFree(bodyDisplacement(), x);
  const ModalBasis& basis = params_.method == Method::Linear ? basis_ : physical_basis_;
  return error_indicator_->estimate(x, basis.phi, external_force_);
}

double Simulation::spanDistance(Method reduced) const
{
  if (!basis_built_ || reduced == Method::Full)
    throw std::logic_error("spanDistance: needs a modal method whose basis is built");
  const bool skinning = params_.basis == BasisKind::Skinning && reduced != Method::Linear;
  const ModalBasis& basis = reduced == Method::Linear ? basis_ : physical_basis_;
  const Eigen::MatrixXd& psi = skinning ? skinning_constraint_modes_ : constraint_modes_;
  Eigen::VectorXd u = bodyDisplacement();
  if (formulation_ != HandleFormulation::MovingFrame && psi.size() > 0 && handle_current_.displacement.size() > 0)
    u -= psi * handle_current_.displacement;
  const Eigen::VectorXd rest = u - basis.phi * (basis.phi.transpose() * mass_.cwiseProduct(u));
  return std::sqrt(rest.dot(mass_.cwiseProduct(rest)) * grid_.dimension() / mass_.sum());
}

void Simulation::particleState(int particle, Eigen::VectorXd& position, Eigen::VectorXd& velocity) const
{
  const int dim = grid_.dimension();
  if (particle < 0 || particle >= grid_.numParticles() || grid_.isFixed(particle) || grid_.isHandle(particle))
    rejectParameter("particle", std::to_string(particle),
                    "must be a free particle (neither fixed nor held by a handle) in [0, " +
                        std::to_string(grid_.numParticles()) + ")");
  position.resize(dim);
  velocity.resize(dim);
  for (int c = 0; c < dim; ++c)
  {
    const int k = grid_.freeIndex(particle * dim + c);
    position[c] = x_ref_[particle * dim + c] + model_->displacementAt(model_->state(), k);
    velocity[c] = model_->velocityAt(model_->state(), k);
  }
  if (frameMoved())
  {
    // As positions() and velocity(): x = p + R y, x' = p' + omega x R y + R y'.
    const PlanarFrame f = restrict(frame_current_, dim);
    const Eigen::VectorXd y = position;
    position = f.worldPosition(y);
    velocity = f.worldVelocity(y, velocity);
  }
}

double Simulation::kineticEnergy() const
{
  if (!frameMoved())
    return model_->kineticEnergy(model_->state());
  return 0.5 * velocity().cwiseAbs2().dot(mass_);
}

double Simulation::methodEnergy() const { return model_->energy(model_->state()); }

double Simulation::totalEnergy() const { return totalEnergy(positions()); }

double Simulation::totalEnergy(const Eigen::VectorXd& x) const
{
  return kineticEnergy() + springEnergy(grid_, x) + gravityEnergy(grid_, x);
}

void Simulation::setSelfCollision(bool enabled, double thickness, double friction)
{
  validateSelfCollision(grid_.params(), enabled, thickness, friction);
  if (enabled && method() != Method::Full)
    rejectParameter("self_collision", "true",
                    "needs method full (now '" + toString(method()) + "'): " + std::string(kSelfCollisionMethods));
  params_.self_collision = enabled;
  params_.self_collision_thickness = thickness;
  params_.self_friction = friction;
  if (!enabled)
  {
    self_collision_.reset();
    self_collision_seconds_ = 0.0;
  }
  else if (!self_collision_)
    self_collision_ = std::make_unique<SelfCollision>(grid_, thickness, friction);
  else
  {
    self_collision_->setThickness(thickness);
    self_collision_->setFriction(friction);
  }
}

void Simulation::checkColliderPose(int i, const Eigen::Isometry3d& pose) const
{
  const int count = contact_ ? static_cast<int>(contact_->colliders().size()) : 0;
  if (i < 0 || i >= count)
    throw std::invalid_argument("collider index " + std::to_string(i) + " is out of range: there are " +
                                std::to_string(count) + " colliders");
  if (!pose.matrix().allFinite())
    throw std::invalid_argument("the pose of collider " + std::to_string(i) + " is not finite");
}

void Simulation::setColliderPose(int i, const Eigen::Isometry3d& pose)
{
  checkColliderPose(i, pose);
  contact_->setPose(i, pose);
}

void Simulation::placeCollider(int i, const Eigen::Isometry3d& pose)
{
  checkColliderPose(i, pose);
  contact_->place(i, pose);
}

std::vector<Eigen::Vector3d> Simulation::handleForces() const
{
  std::vector<Eigen::Vector3d> origins(grid_.handles().size(), Eigen::Vector3d::Zero());
  std::vector<Eigen::Vector3d> forces;
  for (const Wrench& w : handleWrenches(origins))
    forces.push_back(w.force);
  return forces;
}

std::vector<Simulation::Wrench> Simulation::handleWrenches(const std::vector<Eigen::Vector3d>& origins) const
{
  if (origins.size() != grid_.handles().size())
    rejectParameter("origins", origins.size(),
                    "must hold one point per handle (" + std::to_string(grid_.handles().size()) + ")");
  const int dim = grid_.dimension();
  const Eigen::VectorXd x = positions();
  std::vector<int> handle_of(grid_.numParticles(), -1);
  for (size_t h = 0; h < grid_.handles().size(); ++h)
    for (int p : grid_.handles()[h])
      handle_of[p] = static_cast<int>(h);
  auto point = [&](const Eigen::VectorXd& v, int particle) {
    return dim == 3 ? Eigen::Vector3d(v.segment<3>(3 * particle))
                    : Eigen::Vector3d(v[2 * particle], 0.0, v[2 * particle + 1]);
  };
  std::vector<Wrench> wrenches(grid_.handles().size());
  auto add = [&](int particle, const Eigen::VectorXd& f) {
    const int h = handle_of[particle];
    if (h < 0)
      return;
    const Eigen::Vector3d f3 = dim == 3 ? Eigen::Vector3d(f.head<3>()) : Eigen::Vector3d(f[0], 0.0, f[1]);
    wrenches[h].force += f3;
    wrenches[h].torque += (point(x, particle) - origins[h]).cross(f3);
  };
  // Only the springs that touch a handle particle.
  for (const Spring& s : grid_.springs())
  {
    if (handle_of[s.i] < 0 && handle_of[s.j] < 0)
      continue;
    const Eigen::VectorXd d = x.segment(dim * s.j, dim) - x.segment(dim * s.i, dim);
    const double length = d.norm();
    if (length <= 0.0)
      continue;
    const Eigen::VectorXd f = springForce(s.stiffness, s.rest_length, d);  // on i, towards j
    add(s.i, f);
    add(s.j, -f);
  }
  const std::vector<int>& dofs = grid_.handleDofs();
  for (size_t k = 0; k < dofs.size(); k += dim)
  {
    const int particle = dofs[k] / dim;
    Eigen::VectorXd f = grid_.gravityForce().segment(dofs[k], dim) + external_force_.segment(dofs[k], dim);
    if (handle_current_.acceleration.size() > 0)
      f -= grid_.particleMass() * handle_current_.acceleration.segment(k, dim);
    add(particle, f);
  }
  return wrenches;
}

}  // namespace modal_mass_spring
