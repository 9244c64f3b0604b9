// The forces applied to a grid through ~apply_force: each checked when it arrives, summed into one
// external force vector, and dropped when its duration has passed. ROS-free, so that it is tested
// without a master; the node turns the messages' vectors into the grid's frame first.
#pragma once

#include "modal_mass_spring/grid.h"

#include <Eigen/Core>

#include <cstdint>
#include <string>
#include <vector>

namespace modal_mass_spring
{

// "(x, y, z)" for a message about a vector, with NaN as "nan" whatever its sign bit (printf gives "-nan").
std::string vectorText(const Eigen::Vector3d& v);

class AppliedForces
{
public:
  // Keeps a copy of the grid: the simulations it serves may be rebuilt.
  explicit AppliedForces(const Grid& grid) : grid_(grid) {}

  // Adds a force on `particles` (one vector per particle, or one for all, in the grid's frame, N)
  // for `duration` simulated seconds from `now` (0: until cleared). Returns "" when it was taken,
  // otherwise why not (naming the index, the vector or the count that is wrong), adding nothing.
  std::string add(const std::vector<uint32_t>& particles, const std::vector<Eigen::Vector3d>& forces,
                  double duration, double now);
  // Drops every force; returns how many there were.
  size_t clear();
  size_t size() const { return forces_.size(); }

  // Drops the forces whose time is up at `now`; true when the total has changed since the last call
  // (an add, a clear or an expiry), and then `total` is the sum over every dof (as Grid positions).
  bool update(double now, Eigen::VectorXd& total);

private:
  struct Applied
  {
    Eigen::VectorXd force;  // over every dof
    double until;           // simulated time it ends; infinity: until cleared
  };
  Grid grid_;
  std::vector<Applied> forces_;
  bool changed_ = true;
};

}  // namespace modal_mass_spring
