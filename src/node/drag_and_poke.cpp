#include "drag_and_poke.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <limits>

namespace modal_mass_spring
{
namespace
{

// The pull that holds the whole grid up at the default drag stiffness (m).
constexpr double kDefaultDragStretch = 0.1;
// The grid's speed (m/s) whose momentum is the default poke, and the largest one taken.
constexpr double kDefaultPokeSpeed = 0.05;
constexpr double kMaxPokeSpeed = 10.0;

double totalMass(const GridParams& grid)
{
  return grid.mass * grid.rows * grid.cols;
}

}  // namespace

int nearestFreeParticle(const Grid& grid, const Eigen::Matrix3Xd& points, const Eigen::Vector3d& point)
{
  int nearest = -1;
  double best = std::numeric_limits<double>::infinity();
  for (int p = 0; p < static_cast<int>(points.cols()); ++p)
  {
    if (grid.isFixed(p) || grid.isHandle(p))
      continue;
    const double d = (points.col(p) - point).squaredNorm();
    if (d < best)
    {
      best = d;
      nearest = p;
    }
  }
  return nearest;
}

Eigen::Vector3d dragForce(double stiffness, double damping, const Eigen::Vector3d& target,
                          const Eigen::Vector3d& position, const Eigen::Vector3d& velocity)
{
  return stiffness * (target - position) - damping * velocity;
}

double dragDamping(double stiffness, double mass)
{
  return std::sqrt(stiffness * mass);
}

double maxDragStiffness(const GridParams& grid, double time_step)
{
  return grid.mass / (time_step * time_step);
}

double defaultDragStiffness(const GridParams& grid, double time_step)
{
  return std::min(totalMass(grid) * grid.gravity.norm() / kDefaultDragStretch, 0.5 * maxDragStiffness(grid, time_step));
}

double defaultPokeImpulse(const GridParams& grid)
{
  return kDefaultPokeSpeed * totalMass(grid);
}

double maxPokeImpulse(const GridParams& grid)
{
  return kMaxPokeSpeed * totalMass(grid);
}

Eigen::Vector3d pokeDirection(const Grid& grid, const Eigen::Matrix3Xd& points, int particle)
{
  const int rows = grid.params().rows, cols = grid.params().cols;
  const int r = particle / cols, c = particle % cols;
  auto at = [&](int row, int col) -> Eigen::Vector3d {
    return points.col(grid.particleIndex(std::clamp(row, 0, rows - 1), std::clamp(col, 0, cols - 1)));
  };
  const Eigen::Vector3d along_row = at(r, c + 1) - at(r, c - 1);
  const Eigen::Vector3d down_column = at(r + 1, c) - at(r - 1, c);
  Eigen::Vector3d direction;
  if (grid.dimension() == 3)
  {
    direction = along_row.cross(down_column);
    if (!(direction.norm() > 1e-12 * (along_row.norm() * down_column.norm() + 1e-300)))
      direction = Eigen::Vector3d::UnitY();
  }
  else
  {
    // The row turned by -90 degrees about y: x becomes -z.
    direction = Eigen::Vector3d(along_row.z(), 0.0, -along_row.x());
    if (!(direction.norm() > 0.0))
      direction = -Eigen::Vector3d::UnitZ();
  }
  return direction.normalized();
}

Eigen::Vector3d gridPoint(const Grid& grid, const Eigen::VectorXd& value)
{
  if (grid.dimension() == 2)
    return Eigen::Vector3d(value[0], 0.0, value[1]);
  return value.head<3>();
}

Eigen::Vector3d particleVector(const Grid& grid, const Eigen::VectorXd& all, int particle)
{
  return gridPoint(grid, all.segment(grid.dimension() * particle, grid.dimension()));
}

void addParticleVector(const Grid& grid, int particle, const Eigen::Vector3d& value, Eigen::VectorXd& all)
{
  if (grid.dimension() == 2)
  {
    all[2 * particle] += value.x();
    all[2 * particle + 1] += value.z();
  }
  else
    all.segment<3>(3 * particle) += value;
}

HandForces::HandForces(const Grid& grid, size_t tracks)
  : grid_(grid), poke_force_(Eigen::VectorXd::Zero(grid.numDofs())), poke_pending_(tracks, false), forced_(tracks, false)
{
}

void HandForces::configure(double stiffness, double mass, double time_step)
{
  stiffness_ = stiffness;
  mass_ = mass;
  time_step_ = time_step;
}

void HandForces::grab(int particle, const Eigen::Vector3d& target)
{
  drag_ = Drag{particle, target};
}

void HandForces::moveTarget(const Eigen::Vector3d& target)
{
  if (drag_)
    drag_->target = target;
}

void HandForces::poke(int particle, const Eigen::Vector3d& impulse)
{
  addParticleVector(grid_, particle, impulse / time_step_, poke_force_);
  std::fill(poke_pending_.begin(), poke_pending_.end(), true);
}

bool HandForces::active(size_t track) const
{
  return drag_ || poke_pending_[track] || forced_[track];
}

std::optional<Eigen::VectorXd> HandForces::nextForce(size_t track, const Eigen::VectorXd& applied,
                                                     const Eigen::Vector3d& position, const Eigen::Vector3d& velocity)
{
  if (!active(track))
    return std::nullopt;
  Eigen::VectorXd force = applied;
  if (drag_)
  {
    const Eigen::Vector3d f = dragForce(stiffness_, dragDamping(stiffness_, mass_), drag_->target, position, velocity);
    addParticleVector(grid_, drag_->particle, f, force);
  }
  const bool poked = poke_pending_[track];
  if (poked)
  {
    force += poke_force_;
    skip(track);
  }
  forced_[track] = drag_ || poked;
  return force;
}

void HandForces::skip(size_t track)
{
  poke_pending_[track] = false;
  if (std::none_of(poke_pending_.begin(), poke_pending_.end(), [](bool pending) { return pending; }))
    poke_force_.setZero();
}

}  // namespace modal_mass_spring
