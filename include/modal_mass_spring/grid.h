// The spring-mass grid: particles, springs, fixed particles and the free degrees of freedom.
#pragma once

#include <Eigen/Core>

#include <string>
#include <vector>

namespace modal_mass_spring
{

// Everything that defines a grid. Defaults are the paper's 2D experiment (5 x 5, top row fixed).
struct GridParams
{
  int rows = 5;                 // particles along -z; row 0 is the top
  int cols = 5;                 // particles along x
  double spacing = 0.1;         // m, rest distance between structural neighbours
  int dimension = 2;            // 2: planar model in the x-z plane; 3: x, y, z
  double mass = 0.01;           // kg, every particle
  double structural_stiffness = 10.0;  // N/m, horizontal and vertical neighbours
  double shear_stiffness = 5.0;        // N/m, both diagonals of every cell
  bool bending = false;                // springs to the neighbour two away
  double bending_stiffness = 1.0;      // N/m
  std::vector<int> fixed;              // particle indices held in place; empty: the top row (none when there are handles)
  // Groups of particles held rigidly by handles that the caller moves (Simulation::setHandleMotion);
  // each particle in at most one handle and not also fixed.
  std::vector<std::vector<int>> handles;
  Eigen::Vector3d gravity{0.0, 0.0, -9.81};  // m/s^2; in 2D the y component must be 0
  double rotation_deg = 0.0;           // initial rotation of the sheet about the x axis (3D only)
};

// The largest grid: its stiffness matrix (about 120 entries per particle in 3D with bending springs)
// must stay within the 32-bit indices of Eigen's sparse matrices.
constexpr long long kMaxParticles = 10000000;

// Throws std::invalid_argument (rejectParameter) for the first invalid grid parameter, naming it, its
// value and what is allowed. Sizes are counted in 64 bits. Builds nothing.
void validateGridParams(const GridParams& params);
// The particles a grid with these parameters holds fixed: `fixed`, or when it is empty the top row
// unless there are handles (not validated).
std::vector<int> effectiveFixed(const GridParams& params);
// The number of free degrees of freedom of a grid with these parameters (64 bits, not validated):
// neither fixed nor held by a handle.
long long countFreeDofs(const GridParams& params);
// The number of springs of a grid with these parameters (64 bits, not validated).
long long countSprings(const GridParams& params);

struct Spring
{
  int i;
  int j;
  double stiffness;
  double rest_length;
};

// Topology and initial state of a grid. Positions are flat vectors, `dimension` values per particle
// (x, z in 2D; x, y, z in 3D). Construction validates the parameters and throws
// std::invalid_argument naming the parameter, its value and what is allowed (validateGridParams).
class Grid
{
public:
  explicit Grid(const GridParams& params);

  const GridParams& params() const { return params_; }
  int dimension() const { return params_.dimension; }
  int numParticles() const { return params_.rows * params_.cols; }
  int numDofs() const { return dimension() * numParticles(); }
  int numFreeDofs() const { return static_cast<int>(free_dofs_.size()); }
  int particleIndex(int row, int col) const { return row * params_.cols + col; }

  const std::vector<Spring>& springs() const { return springs_; }
  // Spring s's rest length changed (a coarse grid fitted to a finer grid's shape).
  void setRestLength(int s, double rest_length) { springs_[static_cast<size_t>(s)].rest_length = rest_length; }
  int numStructuralSprings() const { return num_structural_; }
  int numShearSprings() const { return num_shear_; }
  int numBendingSprings() const { return num_bending_; }

  const Eigen::VectorXd& initialPositions() const { return x0_; }
  bool isFixed(int particle) const { return fixed_mask_[particle]; }
  const std::vector<int>& fixedParticles() const { return fixed_; }
  // Handle particles are neither fixed nor free: their positions are prescribed (the boundary dofs).
  bool isHandle(int particle) const { return handle_of_[particle] >= 0; }
  const std::vector<std::vector<int>>& handles() const { return params_.handles; }
  // The global dofs of every handle particle, handle by handle, particle by particle, dimension
  // values each: the order of the handle motion's vectors.
  const std::vector<int>& handleDofs() const { return handle_dofs_; }
  int numHandleDofs() const { return static_cast<int>(handle_dofs_.size()); }

  // Free degrees of freedom: free_dofs()[k] is the global dof of free dof k; freeIndex(dof) is -1 for
  // a fixed dof.
  const std::vector<int>& freeDofs() const { return free_dofs_; }
  int freeIndex(int dof) const { return free_index_[dof]; }

  // Gravity force on every dof (m g), the diagonal of the mass matrix, both over all dofs.
  const Eigen::VectorXd& gravityForce() const { return gravity_force_; }
  double particleMass() const { return params_.mass; }

  // Add a free-dof vector into an all-dof vector (fixed dofs untouched), and gather one back.
  void addFree(const Eigen::VectorXd& free, Eigen::VectorXd& all) const;
  Eigen::VectorXd gatherFree(const Eigen::VectorXd& all) const;

  // Positions as 3 x N (y = 0 for 2D grids), the form markers and TF want.
  Eigen::Matrix3Xd toPoints(const Eigen::VectorXd& x) const;

private:
  void addSpring(int i, int j, double stiffness);

  GridParams params_;
  std::vector<Spring> springs_;
  int num_structural_ = 0;
  int num_shear_ = 0;
  int num_bending_ = 0;
  Eigen::VectorXd x0_;
  Eigen::VectorXd gravity_force_;
  std::vector<int> fixed_;
  std::vector<bool> fixed_mask_;
  std::vector<int> handle_of_;    // per particle: its handle, -1 for none
  std::vector<int> handle_dofs_;
  std::vector<int> free_dofs_;
  std::vector<int> free_index_;
};

}  // namespace modal_mass_spring
