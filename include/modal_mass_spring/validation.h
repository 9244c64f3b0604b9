// The one form of a refused parameter, shared by the core, the node and the tools.
#pragma once

#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace modal_mass_spring
{

// Throws std::invalid_argument "invalid parameter 'NAME' = VALUE: ALLOWED".
template <typename T>
[[noreturn]] void rejectParameter(const std::string& name, const T& value, const std::string& allowed)
{
  std::ostringstream msg;
  msg << "invalid parameter '" << name << "' = " << value << ": " << allowed;
  throw std::invalid_argument(msg.str());
}

// Refuses a particle index outside [0, num_particles - 1] or listed twice.
inline void checkParticleIndices(const std::string& name, const std::vector<int>& indices, int num_particles)
{
  std::vector<bool> seen(num_particles > 0 ? num_particles : 0, false);
  for (int index : indices)
  {
    if (index < 0 || index >= num_particles)
      rejectParameter(name, index,
                      "particle indices must be in [0, " + std::to_string(num_particles - 1) + "] (row * cols + col)");
    if (seen[index])
      rejectParameter(name, index, "each particle index must be listed once");
    seen[index] = true;
  }
}

}  // namespace modal_mass_spring
