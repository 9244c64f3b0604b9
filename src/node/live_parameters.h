// The parameters dynamic_reconfigure changes while the node runs. cfg/Simulation.cfg is their one list
// (name, type, level, description); this maps each name to where the node keeps it, and every step of
// live tuning (the values reported, a change written into the parameters, what it changes, whether it
// needs a rebuild) walks the cfg's descriptions.
#pragma once

#include "node_params.h"

#include "modal_mass_spring/SimulationConfig.h"

#include <xmlrpcpp/XmlRpcValue.h>

#include <cstdint>
#include <optional>
#include <string>

namespace modal_mass_spring
{

// cfg/Simulation.cfg's levels: applied at the next tick, or needing a new basis.
constexpr uint32_t kLiveLevel = 0;
constexpr uint32_t kRebuildLevel = 1;

// The values of `configuration` as dynamic_reconfigure reports them (those in force, defaults that
// depend on the grid included). Throws std::logic_error when the cfg names a parameter that the node
// does not keep (a cfg changed without this file).
SimulationConfig liveValues(const NodeConfiguration& configuration);

// Writes the values of `config` into `params` (the node's private parameters as one struct) with the
// types the parameter server would give them: all of them, or those of `level` only.
void writeLiveValues(const SimulationConfig& config, XmlRpc::XmlRpcValue& params,
                     std::optional<uint32_t> level = std::nullopt);

// Copies the live parameters of `level` from `from` to `to`.
void copyLiveValues(const NodeConfiguration& from, NodeConfiguration& to, uint32_t level);

// Whether a live parameter of `level` differs between `a` and `b`.
bool liveValuesDiffer(const NodeConfiguration& a, const NodeConfiguration& b, uint32_t level);

// "alpha 0, beta 0, structural_stiffness 10, ..." for the live parameters of `level`, in the cfg's order.
std::string describeLiveValues(const NodeConfiguration& configuration, uint32_t level);

}  // namespace modal_mass_spring
