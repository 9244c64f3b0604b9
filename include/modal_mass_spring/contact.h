// Contact between the grid's particles and rigid colliders (plane, box, sphere, capsule) with
// Coulomb friction, as a correction of each step's end state.
//
// After the integrator's step, every free particle closer to a collider than the contact thickness,
// or whose straight path over the step (relative to the collider) entered a box, sphere or capsule
// (then with the entry's normal and distance: a thin plate is not passed through), is corrected
// twice, with a Coulomb cone each time:
//   positions: pushed out along the normal to the thickness (the normal "impulse" is the push); the
//     tangential slip over the step (relative to the collider's surface) is undone where mu times the
//     push covers it (static friction), else shortened by mu times the push;
//   velocities: the approaching normal velocity is removed (normal impulse jn), and the tangential
//     velocity is cancelled where mu jn covers it, else reduced by mu jn.
// For `full` each particle is corrected on its own (exact: a particle's dofs are its own
// coordinates). For the modal methods the impulses act through the basis: a particle's impulse p
// changes the modal velocity by Phi_p^T p (Phi is mass-orthonormal), so the touching particles'
// impulses are solved together by projected Gauss-Seidel in reduced coordinates, a few sweeps, each
// constraint (normal, then the tangential cone) against its own diagonal |Phi_p^T e|^2.
// Not modelled here: self-collision (self_collision.h), collider-collider contact, rolling or torsional friction, and the
// cloth pushing the colliders (they move only as they are told).
#pragma once

#include "modal_mass_spring/grid.h"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <map>
#include <string>
#include <vector>

namespace modal_mass_spring
{

enum class ColliderType
{
  Plane,
  Box,
  Sphere,
  Capsule
};

std::string toString(ColliderType type);
// Throws std::invalid_argument for an unknown name (naming `name`, the parameter).
ColliderType parseColliderType(const std::string& text, const std::string& name);

// One rigid collider, in its own frame (which its pose places in the grid's coordinates).
struct Collider
{
  ColliderType type = ColliderType::Plane;
  Eigen::Vector3d point = Eigen::Vector3d::Zero();   // plane: a point on it
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ(); // plane: the side the cloth stays on (any length > 0)
  Eigen::Vector3d center = Eigen::Vector3d::Zero();  // box, sphere
  Eigen::Vector3d half_extents = Eigen::Vector3d::Constant(0.5);  // box, axis-aligned in its frame
  double radius = 0.1;                               // sphere, capsule
  Eigen::Vector3d a = Eigen::Vector3d::Zero(), b = Eigen::Vector3d::UnitX();  // capsule's segment
  double friction = 0.5;                             // Coulomb coefficient mu >= 0
  std::string frame;  // a TF frame it follows (the node; its geometry is given in that frame); empty: fixed
  // Where a collider without a frame stands: its frame in the grid's coordinates (the node's
  // ~set_colliders places a shape at a pose; the parameter's colliders are given in place).
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  std::string id;  // the name the node's ~set_colliders knows it by (empty: the node names it)
};

// The default contact thickness, as a fraction of the grid's spacing.
constexpr double kDefaultThicknessFraction = 0.1;
// The largest contact thickness, as a fraction of the grid's spacing: a particle that touches is
// pushed out by up to the thickness in one step, and a push longer than a spring's rest length can
// fold the cloth through itself.
constexpr double kMaxThicknessFraction = 1.0;
// Collider coordinates and sizes (m) beyond this are typing mistakes, as the node's `offset`.
constexpr double kMaxColliderCoordinate = 1e6;

// Throws std::invalid_argument (rejectParameter) naming `name` (e.g. "colliders[1].radius") for a
// non-finite value or a coordinate or size beyond kMaxColliderCoordinate, a zero plane normal, a size
// <= 0 (radius, half_extents), a capsule with a = b, a negative friction; on a 2D grid (dimension 2,
// particles in the x-z plane y = 0) also a collider that is not symmetric about that plane (a plane
// whose normal has a y part, a sphere or capsule off it, a box off it or thinner along y than its
// smaller half extent in the plane): its surface would push the particles along y, which a 2D grid
// does not have. A pose must be finite and rigid, and on a 2D grid turn about y only with its
// origin's y 0 (what the geometry's checks then say holds of the placed collider too).
void validateCollider(const Collider& collider, const std::string& name, int dimension = 3);
// What the key `key` of a collider map takes ("a number (...)", "a list of three numbers ..."), for
// the sources' messages; for a key no collider has, the keys there are.
std::string colliderFieldExpected(const std::string& key);
// One element of the parameter `colliders` as a source read it: text values (type, frame) and
// numeric ones (a scalar is a list of one), so that the node's and the tools' sources share one
// reading. Keys: type (required); plane: point, normal; box: center, half_extents; sphere: center,
// radius; capsule: a, b, radius; friction (default 0.5), frame (the node; a non-empty TF frame id
// without a leading '/' or spaces), id (the node's name of it). Throws
// std::invalid_argument naming `name.key` for an unknown key, a key of another shape, a missing one,
// and then whatever validateCollider refuses.
struct ColliderFields
{
  std::map<std::string, std::string> text;
  std::map<std::string, std::vector<double>> numbers;
};
Collider colliderFromFields(const ColliderFields& fields, const std::string& name);

// contact_thickness: finite, >= 0 (0: kDefaultThicknessFraction of the spacing) and at most
// kMaxThicknessFraction of the spacing.
void validateContactThickness(double thickness, double spacing);
// The thickness contact_thickness gives (its default where it is 0).
inline double resolveContactThickness(double thickness, double spacing)
{
  return thickness > 0.0 ? thickness : kDefaultThicknessFraction * spacing;
}
// Refuses (std::invalid_argument naming the collider, the particle and its depth) a start where a
// free particle (neither fixed nor held) at `positions` (all dofs) lies inside a collider (at its
// pose; a collider with a `frame` is not placed yet and is skipped) by more than
// a hundredth of `thickness`: the first step would throw it out, which is no motion of the cloth.
// `start` says where the positions come from, for the message (e.g. "initial_state equilibrium").
void checkStartOutsideColliders(const Grid& grid, const Eigen::VectorXd& positions,
                                const std::vector<Collider>& colliders, double thickness, const std::string& start);

// Signed distance from x (grid coordinates, 3D) to the collider's surface, at the collider's pose,
// and the outward unit normal there.
double signedDistance(const Collider& collider, const Eigen::Isometry3d& pose, const Eigen::Vector3d& x,
                      Eigen::Vector3d& normal);

class Contact;

// How deep the free particle (neither fixed nor held) of `points` (3 x particles, grid coordinates)
// deepest inside an active collider of `contact`, at its pose, is inside it (m; 0: none is inside).
double deepestInside(const Grid& grid, const Eigen::Matrix3Xd& points, const Contact& contact);

// What the last step's contact did.
struct ContactReport
{
  // Per collider: the force the cloth puts on it over the step (N, grid coordinates, the velocity
  // impulses divided by the time step), and the particles touching it (`coarse`: its grid's).
  std::vector<Eigen::Vector3d> force;
  std::vector<int> touching;
  // Per free particle (in free-dof order): the first collider it touched over the step, -1 none
  // (empty under `coarse`: Simulation::particleContacts() says it).
  std::vector<int> touched_by;
  // The deepest a free particle was below a surface before and after the correction (m, >= 0).
  double penetration_before = 0.0;
  double penetration_after = 0.0;
};

// The colliders of a simulation, their poses, and the correction of a step's end state.
class Contact
{
public:
  // Colliders validated by the caller; thickness > 0 (resolved).
  Contact(const Grid& grid, std::vector<Collider> colliders, double thickness);

  const std::vector<Collider>& colliders() const { return colliders_; }
  double thickness() const { return thickness_; }
  // From the next step on (thickness > 0, resolved).
  void setThickness(double thickness) { thickness_ = thickness; }
  // The pose of collider i at the end of the next step (the collider frame in the grid's
  // coordinates); its motion over the step moves the surface the particles touch, and carries the
  // particles touching it (their slip and velocity are measured relative to the moving surface).
  // A collider with a `frame` is inactive (touches nothing) until its first pose, which places it
  // there without a motion over the step (it appears; nothing is swept from the identity pose).
  void setPose(int i, const Eigen::Isometry3d& pose);
  // Puts collider i at `pose` for the next step without a motion over it (as a first pose does): a
  // frame that jumped and stayed there is placed, not swept through the cloth. Activates it.
  void place(int i, const Eigen::Isometry3d& pose);
  const Eigen::Isometry3d& pose(int i) const { return poses_[i]; }
  bool active(int i) const { return active_[i]; }
  // True once a collider moved since the last reset(): it can then do work on the grid.
  bool moved() const { return moved_; }
  // The step was taken: the poses it went to are now the current ones.
  void commit();
  void reset() { moved_ = false; }
  // A saved contact state put back (Simulation::restoreState): each collider's pose, at rest over the
  // next step, whether it is active, and whether one moved since the reset. Sizes checked by the caller.
  void restore(const std::vector<Eigen::Isometry3d>& poses, const std::vector<bool>& active, bool moved);
  const ContactReport& report() const { return report_; }
  // Takes `other`'s colliders, thickness and poses (the next step's start and end, which are active):
  // a second grid against the same colliders (method `coarse`'s grid for the simulation's).
  void follow(const Contact& other);
  // The last step's report, from a caller that corrected a grid standing for this one.
  void setReport(ContactReport report) { report_ = std::move(report); }

  // `full`: corrects the free dofs' end positions x (absolute) and velocities v, given the start
  // positions x_start, the free dofs' masses and the step dt. Returns the largest correction.
  void correctParticles(const Eigen::VectorXd& x_start, Eigen::VectorXd& x, Eigen::VectorXd& v,
                        const Eigen::VectorXd& mass, double dt);
  // The modal methods: positions x, start positions x_start and velocities v of the free dofs
  // (absolute, from the basis); corrects the modal coordinates q and velocities qv through the
  // free-dof basis phi (mass-orthonormal) by projected Gauss-Seidel.
  void correctModal(const Eigen::VectorXd& x_start, const Eigen::VectorXd& x, const Eigen::VectorXd& v,
                    const Eigen::VectorXd& mass, const Eigen::MatrixXd& phi, Eigen::VectorXd& q, Eigen::VectorXd& qv, double dt);

  // Projected Gauss-Seidel sweeps of the modal correction.
  static constexpr int kSweeps = 20;
  // A touch's compliance in the modal correction, times 1 / (particle mass).
  static constexpr double kCompliance = 0.05;

private:
  struct Touch;  // one particle against one collider
  // The touches of the free particles at positions x (free dofs) that started the step at x_start,
  // with the collider's surface velocity; fills penetration_before.
  std::vector<Touch> detect(const Eigen::VectorXd& x_start, const Eigen::VectorXd& x);
  Eigen::Vector3d point(const Eigen::VectorXd& x, int particle) const;

  const Grid& grid_;
  std::vector<Collider> colliders_;
  double thickness_;
  std::vector<Eigen::Isometry3d> poses_, start_poses_;  // the end of the next step, its start
  std::vector<bool> active_;                             // false: a frame's collider before its first pose
  bool moved_ = false;
  ContactReport report_;
};

}  // namespace modal_mass_spring
