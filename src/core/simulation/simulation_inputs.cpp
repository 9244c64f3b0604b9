// What a caller sets on a simulation between steps: the external force, the handles' and the moving
// frame's motions, the colliders' poses and self-collision; and the forces the handles feel (simulation.h).
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
  ++external_force_changes_;
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
  Eigen::Matrix3Xd points = Eigen::Matrix3Xd::Zero(3, n);  // the handle particles alone: no pass over the grid
  for (Eigen::Index p = 0; p < n; ++p)
    for (int c = 0; c < dim; ++c)
      points(rows[c], p) = x_ref_[dofs[dim * p + c]];
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

void Simulation::setColliders(const std::vector<Collider>& colliders, const std::vector<int>& keep)
{
  for (size_t i = 0; i < colliders.size(); ++i)
    validateCollider(colliders[i], "colliders[" + std::to_string(i) + "]", grid_.dimension());
  const int count = contact_ ? static_cast<int>(contact_->colliders().size()) : 0;
  if (keep.size() != colliders.size())
    throw std::invalid_argument("setColliders: " + std::to_string(keep.size()) + " entries of keep for " +
                                std::to_string(colliders.size()) + " colliders");
  for (int k : keep)
    if (k < -1 || k >= count)
      throw std::invalid_argument("setColliders: keep " + std::to_string(k) + " is not -1 or one of the " +
                                  std::to_string(count) + " colliders");
  if (!colliders.empty() && formulation_ == HandleFormulation::MovingFrame)
    rejectParameter("colliders", std::to_string(colliders.size()) + " colliders",
                    "need handle_formulation constraint_modes: under the moving frame (which this run resolved to) "
                    "contact cannot be corrected in world coordinates");
  params_.colliders = colliders;
  if (colliders.empty())
  {
    contact_.reset();
    contact_seconds_ = 0.0;
    return;
  }
  auto next = std::make_unique<Contact>(grid_, colliders,
                                        resolveContactThickness(params_.contact_thickness, grid_.params().spacing));
  std::vector<Eigen::Isometry3d> poses;
  std::vector<bool> active;
  bool moved = contact_ && contact_->moved();
  for (size_t i = 0; i < colliders.size(); ++i)
  {
    const bool kept = keep[i] >= 0;
    poses.push_back(kept ? contact_->pose(keep[i]) : next->pose(static_cast<int>(i)));
    active.push_back(kept ? contact_->active(keep[i]) : next->active(static_cast<int>(i)));
    // A collider that appears on the cloth pushes it out: work done on the grid (Contact::place).
    moved = moved || (!kept && active.back());
  }
  next->restore(poses, active, moved);
  contact_ = std::move(next);
}

void Simulation::setContactThickness(double thickness)
{
  validateContactThickness(thickness, grid_.params().spacing);
  params_.contact_thickness = thickness;
  if (contact_)
    contact_->setThickness(resolveContactThickness(thickness, grid_.params().spacing));
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

namespace
{

// The wrenches on a grid's handles, summed force by force at the particles' positions x (every dof).
class HandleWrenches
{
public:
  HandleWrenches(const Grid& grid, const Eigen::VectorXd& x, const std::vector<Eigen::Vector3d>& origins)
    : wrenches(origins.size()), grid_(grid), x_(x), origins_(origins), handle_of_(grid.numParticles(), -1)
  {
    for (size_t h = 0; h < grid.handles().size(); ++h)
      for (int p : grid.handles()[h])
        handle_of_[p] = static_cast<int>(h);
  }
  bool held(int particle) const { return handle_of_[particle] >= 0; }
  // A force (dimension values) on `particle`: nothing unless a handle holds it.
  void add(int particle, const Eigen::VectorXd& f)
  {
    const int h = handle_of_[particle];
    if (h < 0)
      return;
    const Eigen::Vector3d f3 = point(f, 0), at = point(x_, particle);
    wrenches[h].force += f3;
    wrenches[h].torque += (at - origins_[h]).cross(f3);
  }
  // The springs' pull on the handle particles, and on them the forces `loads` (every dof) less their
  // mass times the handles' prescribed acceleration (handle dofs; empty: none).
  void addSpringsAndLoads(const Eigen::VectorXd& loads, const Eigen::VectorXd& acceleration)
  {
    const int dim = grid_.dimension();
    // Only the springs that touch a handle particle.
    for (const Spring& s : grid_.springs())
    {
      if (!held(s.i) && !held(s.j))
        continue;
      const Eigen::VectorXd d = x_.segment(dim * s.j, dim) - x_.segment(dim * s.i, dim);
      if (d.norm() <= 0.0)
        continue;
      const Eigen::VectorXd f = springForce(s.stiffness, s.rest_length, d);  // on i, towards j
      add(s.i, f);
      add(s.j, -f);
    }
    const std::vector<int>& dofs = grid_.handleDofs();
    for (size_t k = 0; k < dofs.size(); k += dim)
    {
      Eigen::VectorXd f = loads.segment(dofs[k], dim);
      if (acceleration.size() > 0)
        f -= grid_.particleMass() * acceleration.segment(k, dim);
      add(dofs[k] / dim, f);
    }
  }

  std::vector<Simulation::Wrench> wrenches;

private:
  // Particle p's entries of v in 3D (a 2D grid's x-z plane is y = 0).
  Eigen::Vector3d point(const Eigen::VectorXd& v, int p) const
  {
    return grid_.dimension() == 3 ? Eigen::Vector3d(v.segment<3>(3 * p)) : Eigen::Vector3d(v[2 * p], 0.0, v[2 * p + 1]);
  }

  const Grid& grid_;
  const Eigen::VectorXd& x_;
  const std::vector<Eigen::Vector3d>& origins_;
  std::vector<int> handle_of_;  // per particle: its handle, -1 none
};

}  // namespace

std::vector<Simulation::Wrench> Simulation::handleWrenches(const std::vector<Eigen::Vector3d>& origins) const
{
  if (origins.size() != grid_.handles().size())
    rejectParameter("origins", origins.size(),
                    "must hold one point per handle (" + std::to_string(grid_.handles().size()) + ")");
  const Eigen::VectorXd x = positions();
  HandleWrenches own(grid_, x, origins);
  if (params_.method != Method::Coarse)
  {
    own.addSpringsAndLoads(grid_.gravityForce() + external_force_, handle_current_.acceleration);
    return own.wrenches;
  }
  // `coarse`: what its grid's springs pull on its handle particles (the grid's springs at the
  // interpolated positions would pull by a spring's share of a coarse cell's stretch), plus the
  // external force on the grid's handle particles themselves.
  const auto& method = static_cast<const CoarseMethod&>(*model_);
  const Eigen::VectorXd x_coarse = worldPositions(method.coarsePositions(model_->state().q));
  HandleWrenches coarse(coarse_->grid, x_coarse, origins);
  coarse.addSpringsAndLoads(coarse_->grid.gravityForce() +
                                coarse_->interpolation.transpose() * grid_.gatherFree(external_force_),
                            method.coarseHandleMotion().acceleration);
  own.wrenches = coarse.wrenches;
  const int dim = grid_.dimension();
  for (int dof : grid_.handleDofs())
    if (dof % dim == 0)
      own.add(dof / dim, external_force_.segment(dof, dim));
  return own.wrenches;
}

}  // namespace modal_mass_spring
