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
void checkParticleIndices(const std::string& name, const std::vector<int>& indices, int num_particles);

}  // namespace modal_mass_spring
