// Handles: particles held rigidly at positions the caller prescribes (the boundary dofs b), and
// the Craig-Bampton constraint modes that carry their static influence into the interior dofs i
// (the grid's free dofs).
#pragma once

#include "modal_mass_spring/grid.h"
#include "modal_mass_spring/spring_forces.h"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <vector>

namespace modal_mass_spring
{

// The handle dofs' motion at one instant, each vector over Grid::handleDofs(): the displacement
// from the linearization point x_b,ref, the velocity and the acceleration. Empty vectors: at rest
// at the reference.
struct HandleMotion
{
  Eigen::VectorXd displacement, velocity, acceleration;
  bool atRest() const;
};

// K_ib at x (interior rows in the grid's free-dof numbering, columns over Grid::handleDofs()), with
// compressed springs' geometric part dropped as in the basis's stiffness.
SparseMatrix handleCoupling(const Grid& grid, const Eigen::VectorXd& x);

// The constraint modes Psi = -K_ii^-1 K_ib: the interior's static response to a unit displacement
// of each handle dof, one sparse solve per handle dof. Throws std::runtime_error naming `handles`
// when K_ii is singular (the fixed particles and handles do not hold the grid, or a 3D sheet at
// rest has no out-of-plane stiffness).
Eigen::MatrixXd constraintModes(const SparseMatrix& k_ii, const SparseMatrix& k_ib);

// A rigid handle: particles at fixed offsets in a moving frame. The frame moves from pose 0 to pose 1
// over a duration T, translation linearly and rotation by slerp (constant angular velocity); the
// particles' positions, velocities and accelerations at the fraction s in [0, 1] of that interval.
struct FramePose
{
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
  Eigen::Quaterniond rotation = Eigen::Quaterniond::Identity();
};

struct RigidPointMotion
{
  Eigen::Matrix3Xd position, velocity, acceleration;
};

// `offsets`: the particles in the frame (3 x N). The rotation takes the shorter way (slerp).
RigidPointMotion interpolateRigidMotion(const Eigen::Matrix3Xd& offsets, const FramePose& from, const FramePose& to,
                                        double duration, double s);

}  // namespace modal_mass_spring
