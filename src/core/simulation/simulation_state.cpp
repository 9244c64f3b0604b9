// A simulation's state: saved and restored whole, and read in the grid's coordinates (positions,
// velocities, energies, the error indicators) through the moving frame (simulation.h).
#include "modal_mass_spring/cpu_time.h"
#include "modal_mass_spring/simulation.h"

#include "modal_mass_spring/spring_forces.h"
#include "modal_mass_spring/validation.h"
#include "dynamics/method_model.h"
#include "reduction/error_indicator.h"
#include "solvers/equilibrium.h"

#include <Eigen/QR>

#include <chrono>
#include <time.h>

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <vector>

namespace modal_mass_spring
{
SimulationState Simulation::saveState() const
{
  SimulationState s;
  s.method = method();
  s.time_step = params_.time_step;
  s.step_span = step_span_;
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
  buildFor(s.method);
  const Eigen::Index free_dofs = u_start_.size();
  const Eigen::Index coordinates = s.method == Method::Full     ? free_dofs
                                   : s.method == Method::Coarse ? coarse_->grid.numFreeDofs()
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
  if (s.step_span < 1)
    rejectParameter("state.step_span", s.step_span, "must be an integer >= 1");

  if (s.time_step != params_.time_step || s.step_span != step_span_)
  {
    params_.time_step = s.time_step;  // validated above
    step_span_ = s.step_span;
    model_->configure(integratorSettings());
  }
  handle_current_ = handle_target_ = s.handles;
  handle_pending_ = false;
  frame_current_ = frame_target_ = s.frame;
  frame_pending_ = false;
  external_force_ = s.external_force;
  ++external_force_changes_;
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
  ++state_sets_;
  time_since_set_ = 0.0;
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

std::vector<int> Simulation::particleContacts() const
{
  std::vector<int> contacts(static_cast<size_t>(grid_.numParticles()), -1);
  if (!contact_)
    return contacts;
  const std::vector<int> touched = model_->touchedBy(*contact_);
  const int dim = grid_.dimension();
  for (size_t p = 0; p < touched.size(); ++p)
    contacts[static_cast<size_t>(grid_.freeDofs()[dim * p] / dim)] = touched[p];
  return contacts;
}

Eigen::VectorXd Simulation::positions() const { return worldPositions(bodyPositions()); }

Eigen::VectorXd Simulation::bodyPositions() const
{
  Eigen::VectorXd x = x_ref_;
  if (handle_current_.displacement.size() > 0)
    for (int k = 0; k < grid_.numHandleDofs(); ++k)
      x[grid_.handleDofs()[k]] += handle_current_.displacement[k];
  grid_.addFree(bodyDisplacement(), x);
  return x;
}

Eigen::VectorXd Simulation::worldPositions(Eigen::VectorXd x) const
{
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

double Simulation::errorIndicator() { return errorIndicator(params_.method); }

double Simulation::errorIndicator(Method span)
{
  if (span == Method::Full)
    return 0.0;
  if (span == Method::Coarse ? !coarse_ : !basis_built_)
    throw std::logic_error("errorIndicator: the span of method '" + toString(span) + "' is not built");
  // In the body frame where one moves: the springs do not see the frame, and the span lives there.
  if (span == Method::Coarse)
  {
    if (!coarse_indicator_)
      coarse_indicator_ = std::make_unique<CoarseErrorIndicator>(grid_, *coarse_, mass_, x_ref_, equilibrium_);
    if (params_.method != Method::Coarse || !coarse_indicator_->viewed())
      return (*coarse_indicator_)(bodyPositions(), external_force_);
    // Read on the view from the coarse state: the grid's every particle is not reconstructed.
    const auto& method = static_cast<const CoarseMethod&>(*model_);
    if (coarse_indicator_->missedSets() != state_sets_)
      coarse_indicator_->setMissed(method.offset(), state_sets_);
    return (*coarse_indicator_)(method.coarsePositions(model_->state().q), handle_current_.displacement,
                                external_force_);
  }
  if (!error_indicator_)
    error_indicator_ = std::make_unique<ErrorIndicator>(grid_, mass_);
  const Eigen::VectorXd f = error_indicator_->force(bodyPositions(), external_force_);
  const ModalBasis& basis = span == Method::Linear ? basis_ : physical_basis_;
  return error_indicator_->balance(f - mass_.cwiseProduct(basis.phi * (basis.phi.transpose() * f)));
}

double Simulation::spanDistance(Method reduced) const
{
  Eigen::VectorXd rest;
  if (reduced == Method::Coarse && coarse_)
    rest = coarse_->missed(bodyPositions());
  else if (basis_built_ && isModal(reduced))
  {
    const bool skinning = params_.basis == BasisKind::Skinning && reduced != Method::Linear;
    const ModalBasis& basis = reduced == Method::Linear ? basis_ : physical_basis_;
    const Eigen::MatrixXd& psi = skinning ? skinning_constraint_modes_ : constraint_modes_;
    Eigen::VectorXd u = bodyDisplacement();
    if (formulation_ != HandleFormulation::MovingFrame && psi.size() > 0 && handle_current_.displacement.size() > 0)
      u -= psi * handle_current_.displacement;
    rest = u - basis.phi * (basis.phi.transpose() * mass_.cwiseProduct(u));
  }
  else
    throw std::logic_error("spanDistance: needs a modal method whose basis is built, or `coarse` whose grid is");
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

double Simulation::deformationSpeed() const
{
  // On a grid of more than kSpeedSamples x kSpeedSamples particles, over a lattice of at most that
  // many: a swing's speed varies over the cloth's size, and reconstructing every particle of a large
  // grid costs half as much as the indicator (docs/benchmarks.md, "With the swing's drift"). On a
  // smaller one, over every particle, reconstructed at once: one at a time costs more.
  static constexpr int kSpeedSamples = 32;
  const GridParams& g = grid_.params();
  const int dim = grid_.dimension();
  // The particles' positions and velocities, one a column (z = 0 on a 2D grid).
  Eigen::Matrix3Xd x, v;
  if (g.rows <= kSpeedSamples && g.cols <= kSpeedSamples)
  {
    const Eigen::VectorXd all_v = velocity();
    const Eigen::VectorXd all_x = grid_.gatherFree(positions());
    const Eigen::Index n = all_v.size() / dim;
    x = v = Eigen::Matrix3Xd::Zero(3, n);
    x.topRows(dim) = all_x.reshaped(dim, n);
    v.topRows(dim) = all_v.reshaped(dim, n);
  }
  else
  {
    // At most kSpeedSamples evenly spaced indices from the first to the last; every one of fewer.
    auto lattice = [](int count) {
      const int m = std::min(count, kSpeedSamples);
      std::vector<int> indices;
      for (int k = 0; k < m; ++k)
        indices.push_back(m > 1 ? static_cast<int>(std::lround(k * (count - 1.0) / (m - 1))) : 0);
      return indices;
    };
    const std::vector<int> rows = lattice(g.rows), cols = lattice(g.cols);
    std::vector<int> particles, dofs;  // the lattice's free particles, and their free dofs
    for (int i : rows)
      for (int j : cols)
        if (const int particle = i * g.cols + j; !grid_.isFixed(particle) && !grid_.isHandle(particle))
        {
          particles.push_back(particle);
          for (int c = 0; c < dim; ++c)
            dofs.push_back(grid_.freeIndex(particle * dim + c));
        }
    Eigen::VectorXd u, at_velocity;
    model_->statesAt(model_->state(), dofs, u, at_velocity);
    const Eigen::Index n = static_cast<Eigen::Index>(particles.size());
    x = v = Eigen::Matrix3Xd::Zero(3, n);
    for (Eigen::Index p = 0; p < n; ++p)
    {
      x.col(p).head(dim) = x_ref_.segment(particles[static_cast<size_t>(p)] * dim, dim) + u.segment(p * dim, dim);
      v.col(p).head(dim) = at_velocity.segment(p * dim, dim);
    }
    if (frameMoved())
    {
      // As particleState: in the world, x = p + R y, x' = p' + omega x R y + R y'.
      const PlanarFrame f = restrict(frame_current_, dim);
      for (Eigen::Index p = 0; p < n; ++p)
      {
        const Eigen::VectorXd y = x.col(p).head(dim);
        v.col(p).head(dim) = f.worldVelocity(y, v.col(p).head(dim));
        x.col(p).head(dim) = f.worldPosition(y);
      }
    }
  }
  if (x.cols() == 0)
    return 0.0;
  // The particles weigh the same: the rigid motion that fits best moves their centre at their mean
  // velocity and turns about it at omega, I omega = L.
  x.colwise() -= x.rowwise().mean();
  v.colwise() -= v.rowwise().mean();
  const Eigen::Vector3d momentum(x.row(1).dot(v.row(2)) - x.row(2).dot(v.row(1)),
                                 x.row(2).dot(v.row(0)) - x.row(0).dot(v.row(2)),
                                 x.row(0).dot(v.row(1)) - x.row(1).dot(v.row(0)));
  const Eigen::Matrix3d second = x * x.transpose();
  const Eigen::Matrix3d inertia = second.trace() * Eigen::Matrix3d::Identity() - second;
  // Least squares: particles on one line do not fix the rotation about it.
  const Eigen::Vector3d omega = inertia.completeOrthogonalDecomposition().solve(momentum);
  Eigen::Matrix3d turn;  // turn * r = omega x r
  turn << 0.0, -omega.z(), omega.y(), omega.z(), 0.0, -omega.x(), -omega.y(), omega.x(), 0.0;
  return std::sqrt((v - turn * x).squaredNorm() / x.cols());
}

double Simulation::methodEnergy() const { return model_->energy(model_->state()); }

double Simulation::totalEnergy() const { return totalEnergy(positions()); }

double Simulation::totalEnergy(const Eigen::VectorXd& x) const
{
  return kineticEnergy() + springEnergy(grid_, x) + gravityEnergy(grid_, x);
}

}  // namespace modal_mass_spring
