// Names of the simulation's choices.
#include "modal_mass_spring/options.h"

#include <stdexcept>

namespace modal_mass_spring
{
namespace
{

// Finds `name` among `names` (the enum's values in order) or throws naming the parameter.
int parseName(const std::string& parameter, const std::string& name, const std::vector<std::string>& names)
{
  for (size_t k = 0; k < names.size(); ++k)
    if (names[k] == name)
      return static_cast<int>(k);
  std::string allowed;
  for (size_t k = 0; k < names.size(); ++k)
    allowed += (k ? ", " : "") + names[k];
  throw std::invalid_argument("invalid parameter '" + parameter + "' = '" + name + "': must be one of " + allowed);
}

const std::vector<std::string> kLinearizations{"rest", "equilibrium"};
const std::vector<std::string> kIntegrators{"explicit", "implicit"};
const std::vector<std::string> kInitialStates{"initial", "equilibrium"};
const std::vector<std::string> kImplicitSolvers{"newton", "constant_matrix", "lagged_tangent"};
const std::vector<std::string> kBases{"linear_modes", "modal_derivatives", "skinning"};
const std::vector<std::string> kHandleFormulations{"auto", "constraint_modes", "moving_frame"};

}  // namespace

const std::vector<std::string>& methodNames()
{
  static const std::vector<std::string> names{"full", "linear", "physical", "cubature", "coarse"};
  return names;
}

std::string methodList()
{
  std::string list;
  for (const std::string& name : methodNames())
    list += (list.empty() ? "" : ", ") + name;
  return list;
}

bool isModal(Method method)
{
  return method == Method::Linear || method == Method::Physical || method == Method::Cubature;
}

std::string toString(Method method) { return methodNames()[static_cast<int>(method)]; }
Method parseMethod(const std::string& name) { return static_cast<Method>(parseName("method", name, methodNames())); }

std::string toString(Linearization value) { return kLinearizations[static_cast<int>(value)]; }
Linearization parseLinearization(const std::string& name)
{
  return static_cast<Linearization>(parseName("linearization", name, kLinearizations));
}
std::string toString(IntegratorKind value) { return kIntegrators[static_cast<int>(value)]; }
IntegratorKind parseIntegrator(const std::string& name)
{
  return static_cast<IntegratorKind>(parseName("integrator", name, kIntegrators));
}
std::string toString(ImplicitSolver value) { return kImplicitSolvers[static_cast<int>(value)]; }
ImplicitSolver parseImplicitSolver(const std::string& name)
{
  return static_cast<ImplicitSolver>(parseName("implicit_solver", name, kImplicitSolvers));
}
std::string toString(InitialState value) { return kInitialStates[static_cast<int>(value)]; }
InitialState parseInitialState(const std::string& name)
{
  return static_cast<InitialState>(parseName("initial_state", name, kInitialStates));
}

std::string toString(BasisKind value) { return kBases[static_cast<int>(value)]; }
BasisKind parseBasis(const std::string& name) { return static_cast<BasisKind>(parseName("basis", name, kBases)); }

std::string toString(HandleFormulation value) { return kHandleFormulations[static_cast<int>(value)]; }
HandleFormulation parseHandleFormulation(const std::string& name)
{
  return static_cast<HandleFormulation>(parseName("handle_formulation", name, kHandleFormulations));
}

}  // namespace modal_mass_spring
