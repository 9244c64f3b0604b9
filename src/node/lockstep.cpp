#include "lockstep.h"

#include <algorithm>
#include <cmath>

namespace modal_mass_spring
{

std::vector<size_t> synchroniseFull(const std::vector<Simulation*>& simulations, bool first_is_source)
{
  std::vector<size_t> set;
  size_t source = 0;
  while (source < simulations.size() && simulations[source]->method() == Method::Full &&
         !(first_is_source && source == 0))
    ++source;
  if (source == simulations.size())
    return set;
  const Eigen::VectorXd u = simulations[source]->displacement(), v = simulations[source]->velocity();
  for (size_t k = 0; k < simulations.size(); ++k)
    if (k != source && simulations[k]->method() == Method::Full)
    {
      simulations[k]->setPhysicalState(u, v);
      set.push_back(k);
    }
  return set;
}

ParticleDistances particleDistances(const Eigen::Matrix3Xd& points, const Eigen::Matrix3Xd& reference)
{
  const Eigen::VectorXd distances = (points - reference).colwise().norm();
  ParticleDistances d;
  d.rms = std::sqrt(distances.squaredNorm() / std::max<Eigen::Index>(1, distances.size()));
  d.max = distances.maxCoeff();
  return d;
}

}  // namespace modal_mass_spring
