// The parameter `colliders` of a YAML config (contact.h): a list of maps, one per collider.
#pragma once

#include "modal_mass_spring/contact.h"

#include <yaml-cpp/yaml.h>

#include <string>
#include <vector>

namespace modal_mass_spring
{

// Throws std::invalid_argument naming `key[i].field` for an element that is not a map, a key given
// twice in one, a value that is neither a scalar nor a list of numbers, and whatever
// colliderFromFields refuses.
std::vector<Collider> parseColliders(const YAML::Node& node, const std::string& key);

}  // namespace modal_mass_spring
