#include "applied_forces.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <sstream>

namespace modal_mass_spring
{

std::string vectorText(const Eigen::Vector3d& v)
{
  std::string text = "(";
  for (int k = 0; k < 3; ++k)
  {
    char number[32];
    std::snprintf(number, sizeof number, "%g", v[k]);
    text += (k > 0 ? ", " : "") + std::string(std::isnan(v[k]) ? "nan" : number);
  }
  return text + ")";
}

std::string AppliedForces::add(const std::vector<uint32_t>& particles, const std::vector<Eigen::Vector3d>& forces,
                               double duration, double now)
{
  std::ostringstream why;
  if (particles.empty())
    return "no particles: 'particles' must list at least one index";
  if (forces.size() != particles.size() && forces.size() != 1)
  {
    why << particles.size() << (particles.size() == 1 ? " particle but " : " particles but ") << forces.size()
        << (forces.size() == 1 ? " force" : " forces") << ": give one force per particle, or one for all of them";
    return why.str();
  }
  if (!std::isfinite(duration) || duration < 0.0)
  {
    why << "duration " << duration << ": must be a finite number of seconds >= 0 (0: until ~clear_forces)";
    return why.str();
  }
  const int dim = grid_.dimension();
  Eigen::VectorXd total = Eigen::VectorXd::Zero(static_cast<Eigen::Index>(dim) * grid_.numParticles());
  std::vector<bool> seen(grid_.numParticles(), false);
  for (size_t k = 0; k < particles.size(); ++k)
  {
    const uint32_t p = particles[k];
    if (p >= static_cast<uint32_t>(grid_.numParticles()))
    {
      why << "particle " << p << " is out of range: indices are row * cols + col in [0, "
          << grid_.numParticles() - 1 << "]";
      return why.str();
    }
    if (grid_.isFixed(static_cast<int>(p)) || grid_.isHandle(static_cast<int>(p)))
    {
      why << "particle " << p << " is " << (grid_.isFixed(static_cast<int>(p)) ? "fixed" : "held by a handle")
          << ": a force on it does nothing";
      return why.str();
    }
    if (seen[p])
    {
      why << "particle " << p << " is listed twice: each particle at most once";
      return why.str();
    }
    seen[p] = true;
    const Eigen::Vector3d& f = forces.size() == 1 ? forces[0] : forces[k];
    if (!f.allFinite())
    {
      why << "the force on particle " << p << " is not finite: " << vectorText(f) << " N";
      return why.str();
    }
    // A 2D grid lies in the x-z plane: a force across it cannot act.
    if (dim == 2 && f.y() != 0.0)
    {
      why << "the force on particle " << p << " has a y component (" << f.y()
          << " N) but the grid is 2D in the x-z plane: it must be 0";
      return why.str();
    }
    if (dim == 2)
      total.segment<2>(2 * p) << f.x(), f.z();
    else
      total.segment<3>(3 * p) = f;
  }
  forces_.push_back({total, duration > 0.0 ? now + duration : std::numeric_limits<double>::infinity()});
  changed_ = true;
  return "";
}

size_t AppliedForces::clear()
{
  const size_t count = forces_.size();
  forces_.clear();
  changed_ = true;
  return count;
}

bool AppliedForces::update(double now, Eigen::VectorXd& total)
{
  const size_t before = forces_.size();
  forces_.erase(std::remove_if(forces_.begin(), forces_.end(), [now](const Applied& a) { return a.until <= now; }),
                forces_.end());
  if (forces_.size() == before && !changed_)
    return false;
  changed_ = false;
  total = Eigen::VectorXd::Zero(static_cast<Eigen::Index>(grid_.dimension()) * grid_.numParticles());
  for (const Applied& a : forces_)
    total += a.force;
  return true;
}

}  // namespace modal_mass_spring
