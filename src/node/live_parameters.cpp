// The cfg's descriptions drive every step; the one table here says where each name is kept.
#include "live_parameters.h"

#include <dynamic_reconfigure/config_tools.h>

#include <functional>
#include <map>
#include <sstream>
#include <stdexcept>
#include <variant>

namespace modal_mass_spring
{
namespace
{

using LiveField = std::variant<double*, int*, bool*, Linearization*>;
using LiveValue = std::variant<double, int, bool, std::string>;

// Where the node keeps each parameter of cfg/Simulation.cfg.
LiveField field(NodeConfiguration& c, const std::string& name)
{
  using Where = std::function<LiveField(NodeConfiguration&)>;
  static const std::map<std::string, Where> where{
      {"real_time_factor", [](NodeConfiguration& c) -> LiveField { return &c.node.real_time_factor; }},
      {"publish_rate", [](NodeConfiguration& c) -> LiveField { return &c.node.publish_rate; }},
      {"markers_rate", [](NodeConfiguration& c) -> LiveField { return &c.node.markers_rate; }},
      {"strain_scale", [](NodeConfiguration& c) -> LiveField { return &c.node.strain_scale; }},
      {"show_surface", [](NodeConfiguration& c) -> LiveField { return &c.node.show_surface; }},
      {"show_particles", [](NodeConfiguration& c) -> LiveField { return &c.node.show_particles; }},
      {"show_springs", [](NodeConfiguration& c) -> LiveField { return &c.node.show_springs; }},
      {"show_labels", [](NodeConfiguration& c) -> LiveField { return &c.node.show_labels; }},
      {"show_shadow", [](NodeConfiguration& c) -> LiveField { return &c.node.show_shadow; }},
      {"drag_stiffness", [](NodeConfiguration& c) -> LiveField { return &c.node.drag_stiffness; }},
      {"poke_impulse", [](NodeConfiguration& c) -> LiveField { return &c.node.poke_impulse; }},
      {"self_collision", [](NodeConfiguration& c) -> LiveField { return &c.simulation.self_collision; }},
      {"self_collision_thickness",
       [](NodeConfiguration& c) -> LiveField { return &c.simulation.self_collision_thickness; }},
      {"self_friction", [](NodeConfiguration& c) -> LiveField { return &c.simulation.self_friction; }},
      {"contact_thickness", [](NodeConfiguration& c) -> LiveField { return &c.simulation.contact_thickness; }},
      {"alpha", [](NodeConfiguration& c) -> LiveField { return &c.simulation.alpha; }},
      {"beta", [](NodeConfiguration& c) -> LiveField { return &c.simulation.beta; }},
      {"structural_stiffness", [](NodeConfiguration& c) -> LiveField { return &c.grid.structural_stiffness; }},
      {"shear_stiffness", [](NodeConfiguration& c) -> LiveField { return &c.grid.shear_stiffness; }},
      {"bending_stiffness", [](NodeConfiguration& c) -> LiveField { return &c.grid.bending_stiffness; }},
      {"mass", [](NodeConfiguration& c) -> LiveField { return &c.grid.mass; }},
      {"num_modes", [](NodeConfiguration& c) -> LiveField { return &c.simulation.num_modes; }},
      {"linearization", [](NodeConfiguration& c) -> LiveField { return &c.simulation.linearization; }},
  };
  const auto it = where.find(name);
  if (it == where.end())
    throw std::logic_error("cfg/Simulation.cfg's parameter '" + name +
                           "' has no place in the node's configuration (live_parameters.cpp)");
  return it->second(c);
}

LiveValue value(const NodeConfiguration& c, const std::string& name)
{
  // Read only: the table gives write access, which reading does not use.
  const LiveField where = field(const_cast<NodeConfiguration&>(c), name);
  return std::visit(
      [](auto* kept) -> LiveValue {
        if constexpr (std::is_same_v<decltype(kept), Linearization*>)
          return toString(*kept);
        else
          return *kept;
      },
      where);
}

const std::vector<SimulationConfig::AbstractParamDescriptionConstPtr>& descriptions()
{
  return SimulationConfig::__getParamDescriptions__();
}

}  // namespace

SimulationConfig liveValues(const NodeConfiguration& configuration)
{
  dynamic_reconfigure::Config message;
  for (const auto& description : descriptions())
    std::visit([&](const auto& v) { dynamic_reconfigure::ConfigTools::appendParameter(message, description->name, v); },
               value(configuration, description->name));
  SimulationConfig config = SimulationConfig::__getDefault__();
  config.__fromMessage__(message);
  return config;
}

void writeLiveValues(const SimulationConfig& config, XmlRpc::XmlRpcValue& params, std::optional<uint32_t> level)
{
  std::map<std::string, uint32_t> levels;
  for (const auto& description : descriptions())
    levels[description->name] = description->level;
  dynamic_reconfigure::Config message;
  config.__toMessage__(message);
  const auto write = [&](const auto& entries, auto typed) {
    for (const auto& entry : entries)
      if (!level || levels.at(entry.name) == *level)
        params[entry.name] = XmlRpc::XmlRpcValue(typed(entry.value));
  };
  write(message.bools, [](uint8_t v) { return static_cast<bool>(v); });  // the message keeps a bool as a byte
  write(message.ints, [](int v) { return v; });
  write(message.doubles, [](double v) { return v; });
  write(message.strs, [](const std::string& v) { return v; });
}

void copyLiveValues(const NodeConfiguration& from, NodeConfiguration& to, uint32_t level)
{
  for (const auto& description : descriptions())
    if (description->level == level)
    {
      const LiveField source = field(const_cast<NodeConfiguration&>(from), description->name);
      std::visit([&](auto* target) { *target = *std::get<decltype(target)>(source); }, field(to, description->name));
    }
}

bool liveValuesDiffer(const NodeConfiguration& a, const NodeConfiguration& b, uint32_t level)
{
  for (const auto& description : descriptions())
    if (description->level == level && value(a, description->name) != value(b, description->name))
      return true;
  return false;
}

std::string describeLiveValues(const NodeConfiguration& configuration, uint32_t level)
{
  std::ostringstream text;
  text << std::boolalpha;
  for (const auto& description : descriptions())
    if (description->level == level)
    {
      text << (text.tellp() > 0 ? ", " : "") << description->name << " ";
      std::visit([&](const auto& v) { text << v; }, value(configuration, description->name));
    }
  return text.str();
}

}  // namespace modal_mass_spring
