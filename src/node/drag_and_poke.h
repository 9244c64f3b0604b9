// Dragging and poking a grid by hand (rviz's interactive marker and Publish Point tool): which
// particle a point takes, the spring that pulls it, the direction and size of a poke, and the force
// they add to a track's external force at each step. ROS-free, so that it is tested without a master.
#pragma once

#include "modal_mass_spring/grid.h"

#include <Eigen/Core>

#include <optional>
#include <vector>

namespace modal_mass_spring
{

// The free particle (neither fixed nor held by a handle) nearest to `point` among `points` (3 x N),
// or -1 when the grid has none.
int nearestFreeParticle(const Grid& grid, const Eigen::Matrix3Xd& points, const Eigen::Vector3d& point);

// The drag spring's force on the particle it holds (N): stiffness (target - position) - damping velocity.
Eigen::Vector3d dragForce(double stiffness, double damping, const Eigen::Vector3d& target,
                          const Eigen::Vector3d& position, const Eigen::Vector3d& velocity);

// The damping of a drag spring (N s/m): sqrt(stiffness mass), half the critical damping of the
// particle alone on the spring. The spring is computed from the state at the start of a step and
// held over it; that lag feeds energy in at about stiffness dt / 2 per unit velocity, which this
// damping exceeds while stiffness <= 4 mass / dt^2 (maxDragStiffness is a quarter of that).
double dragDamping(double stiffness, double mass);

// The stiffest drag spring a step of `time_step` takes (N/m): mass / time_step^2, where the particle
// alone on it would swing one radian per step.
double maxDragStiffness(const GridParams& grid, double time_step);
// The default (N/m): the grid's weight over 0.1 m (a 10 cm pull holds the whole grid up), at most
// half of maxDragStiffness.
double defaultDragStiffness(const GridParams& grid, double time_step);

// The default poke (N s): the grid's momentum at 0.05 m/s, so that the reduced methods, which spread
// it over their modes, sway visibly; and the largest one taken, the grid's momentum at 10 m/s.
double defaultPokeImpulse(const GridParams& grid);
double maxPokeImpulse(const GridParams& grid);

// The unit direction a poke pushes `particle`: in 3D the sheet's normal there,
// (x[r][c+1] - x[r][c-1]) x (x[r+1][c] - x[r-1][c]) (one-sided at the edges), +y for the unturned
// sheet in the x-z plane, away from the shipped rviz views; in 2D, where nothing moves across the
// x-z plane, the normal of the particle's row within it, -z (down the grid) for the unturned grid.
// A degenerate neighbourhood (all neighbours at one point) gives the unturned grid's direction.
Eigen::Vector3d pokeDirection(const Grid& grid, const Eigen::Matrix3Xd& points, int particle);

// A 3-vector from one particle's `dimension` values (x, z in 2D), a particle's from a flat all-dof
// vector (positions()), and one added into it (in 2D the y component is dropped: the grid cannot move
// across its plane).
Eigen::Vector3d gridPoint(const Grid& grid, const Eigen::VectorXd& value);
Eigen::Vector3d particleVector(const Grid& grid, const Eigen::VectorXd& all, int particle);
void addParticleVector(const Grid& grid, int particle, const Eigen::Vector3d& value, Eigen::VectorXd& all);

// What the hand does to the tracks of a node: one drag (a particle pulled toward a target in grid
// coordinates, the same on every track) and the pokes not yet stepped. Each track's external force
// at a step is the applied forces plus these; a track is told once when they end.
class HandForces
{
public:
  HandForces(const Grid& grid, size_t tracks);

  // The drag spring's stiffness (N/m), the particles' mass (kg, for the damping) and the step (s, for
  // the pokes): set at start-up and by live tuning.
  void configure(double stiffness, double mass, double time_step);
  double stiffness() const { return stiffness_; }

  // Starts (or moves) the drag of `particle` toward `target` (grid coordinates), or ends it.
  void grab(int particle, const Eigen::Vector3d& target);
  void moveTarget(const Eigen::Vector3d& target);
  void release() { drag_.reset(); }
  bool dragging() const { return drag_.has_value(); }
  int draggedParticle() const { return drag_ ? drag_->particle : -1; }

  // Adds an impulse (N s, a 3-vector) on `particle` to the next step of every track, as a force of
  // impulse / time_step over that step.
  void poke(int particle, const Eigen::Vector3d& impulse);

  // The external force of `track` for its next step, from `applied` (the ~apply_force total) and the
  // track's position and velocity of the dragged particle (grid coordinates; read only while a drag
  // is on), or nothing when the track's force is already right (no hand force now, none at its last
  // step). Takes the track's pending poke.
  std::optional<Eigen::VectorXd> nextForce(size_t track, const Eigen::VectorXd& applied,
                                           const Eigen::Vector3d& position, const Eigen::Vector3d& velocity);
  // A track that does not step (diverged) lets its pending poke go.
  void skip(size_t track);
  // True when nextForce needs the dragged particle's state: a drag is on.
  bool needsState() const { return drag_.has_value(); }
  // True when the track's next step has a hand force, or its last one had (nextForce will answer).
  bool active(size_t track) const;

private:
  struct Drag
  {
    int particle;
    Eigen::Vector3d target;
  };
  Grid grid_;
  double stiffness_ = 0.0;
  double mass_ = 0.0;
  double time_step_ = 0.0;
  std::optional<Drag> drag_;
  Eigen::VectorXd poke_force_;       // over every dof, until every track has stepped it
  std::vector<bool> poke_pending_;   // per track
  std::vector<bool> forced_;         // per track: its last force had a hand force in it
};

}  // namespace modal_mass_spring
