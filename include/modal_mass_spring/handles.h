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

// The handle dofs' motions that are one affine map of the handle particles, x -> A (x - c) + t about
// their centroid c: H (handle dofs x dim (dim + 1)) and its least-squares inverse H^+. A linear map P
// of handle motions (the constraint modes) then splits as P dx_b = (P H) (H^+ dx_b) + P (dx_b - H H^+
// dx_b), and for a rigid or affine motion of all handles together (a turned clamp) the second term
// is zero: precomputing P H makes P dx_b cost O(rows of P x dim (dim + 1)) instead of
// O(rows x handle dofs).
struct AffineHandleFit
{
  AffineHandleFit() = default;
  // x: the positions the map is taken about (x_ref). Empty without handles.
  AffineHandleFit(const Grid& grid, const Eigen::VectorXd& x);
  Eigen::MatrixXd h, h_plus;
  // The affine coordinates a = H^+ dx and the rest dx - H a; false when the rest is zero to
  // round-off (below 1e-12 of |dx|), so that P (dx - H a) may be left out.
  bool split(const Eigen::VectorXd& dx, Eigen::VectorXd& a, Eigen::VectorXd& rest) const;
};

// A rigid handle: particles at fixed offsets in a moving frame. The frame moves from pose 0 to pose 1
// over a duration T, translation linearly and rotation by slerp (constant angular velocity); the
// particles' positions, velocities and accelerations at the fraction s in [0, 1] of that interval.
struct FramePose
{
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
  Eigen::Quaterniond rotation = Eigen::Quaterniond::Identity();
};

// A frame (a handle's or a collider's) that turns more than this within one tick is flipping or
// glitching: no gripper turns a quarter turn between two ticks.
constexpr double kMaxFrameTurnPerTick = EIGEN_PI / 2.0;  // rad (90 degrees)
// Likewise a frame that moves farther than this within one tick (15 m/s at 30 Hz): swept that far over
// one tick's steps it would throw the cloth.
constexpr double kMaxFrameJumpPerTick = 0.5;  // m

struct RigidPointMotion
{
  Eigen::Matrix3Xd position, velocity, acceleration;
};

// A frame's velocity (m/s) and angular velocity (rad/s), world.
struct FrameVelocity
{
  Eigen::Vector3d linear = Eigen::Vector3d::Zero();
  Eigen::Vector3d angular = Eigen::Vector3d::Zero();
};

// What interpolateRigidMotion moves a frame at from pose `from` to pose `to` over `duration` seconds:
// straight at a constant velocity, and a slerp's constant turn (the shorter way).
FrameVelocity interpolationVelocity(const FramePose& from, const FramePose& to, double duration);

// `offsets`: the particles in the frame (3 x N). The rotation takes the shorter way (slerp).
RigidPointMotion interpolateRigidMotion(const Eigen::Matrix3Xd& offsets, const FramePose& from, const FramePose& to,
                                        double duration, double s);

// Which of x, y, z a grid's coordinates are: all three in 3D, x and z in 2D (the grid's plane).
std::vector<int> gridAxes(int dimension);
// The matrix [w]x of the cross product w x v.
Eigen::Matrix3d crossMatrix(const Eigen::Vector3d& w);

// The motion of a rigid frame B relative to its pose at the start, where it coincides with the grid's
// coordinates: the point at y in B is at x = translation + rotation y. The velocity and acceleration
// are those of `translation` (the point of B at the origin), the angular velocity and acceleration
// the frame's; all in the grid's (world) coordinates. The default is B at rest at its start.
struct FrameMotion
{
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d velocity = Eigen::Vector3d::Zero(), acceleration = Eigen::Vector3d::Zero();
  Eigen::Vector3d angular_velocity = Eigen::Vector3d::Zero(), angular_acceleration = Eigen::Vector3d::Zero();
  bool atRest() const;
};

// The motion of the points that sit at `points` (3 x N, world) when B is at its start.
RigidPointMotion pointMotion(const FrameMotion& frame, const Eigen::Matrix3Xd& points);

// A frame moving from pose `from` to pose `to` over `duration` seconds as interpolateRigidMotion
// moves it (translation linearly, rotation by slerp: a constant angular velocity, no angular
// acceleration), at the fraction s, relative to its pose `start`: the FrameMotion of B = the frame
// at `start`. Poses in the grid's coordinates.
FrameMotion interpolateFrameMotion(const FramePose& start, const FramePose& from, const FramePose& to,
                                   double duration, double s);

// What the motion of B adds to the equations of a grid simulated in B (positions y, x = p + R y), per
// unit mass and in B's coordinates restricted to the grid's (x, z in 2D): the force on a particle is
//   m (uniform - position y - 2 spin y')
// with uniform = R^T g - g - R^T (a_0 + alpha v_0) (gravity rotated into B, minus the g the force
// models already add, the frame's acceleration and the drag of mass-proportional damping alpha on
// the frame's velocity), position = [alpha_B]x + [omega_B]x^2 + alpha [omega_B]x (Euler,
// centrifugal and drag of the turning), spin = [omega_B]x (Coriolis, through the damping). Spring
// forces are invariant under rigid motion and need nothing; the stiffness-proportional damping
// beta K acts on the velocity y' relative to B.
struct FrameForces
{
  Eigen::MatrixXd rotation;  // dim x dim: R, world = R body
  Eigen::VectorXd uniform;   // dim
  Eigen::MatrixXd position;  // dim x dim
  Eigen::MatrixXd spin;      // dim x dim, skew
  bool none = true;          // B at rest at its start: no term at all
};

// For a 2D grid the motion must stay in its x-z plane (checked by the caller); its y components
// are dropped.
FrameForces frameForces(const FrameMotion& motion, int dimension, const Eigen::Vector3d& gravity, double alpha);

}  // namespace modal_mass_spring
