// Text that stands for a number or a list: what rosparam and the rosrun command line hand over as strings.
#pragma once

#include <optional>
#include <string>
#include <vector>

namespace modal_mass_spring
{

// The number a whole string spells ("3.0e6", " -2 ", "inf"), or nothing when any of it is not part of
// one. rosparam reads YAML 1.1, where 3.0e6 (no sign after the e) is a string, not a number.
std::optional<double> parseNumber(const std::string& text);
// The integer a whole string spells ("20", "-3"), or nothing (also for "2.5" and for overflow).
std::optional<int> parseInteger(const std::string& text);
// The scalars of a YAML flow or block list ("[0, 0, -9.81]"), or nothing when the text is not a list
// of scalars. rosrun hands `_gravity:=[0,0,-9.81]` to the node as that string.
std::optional<std::vector<std::string>> parseListText(const std::string& text);

}  // namespace modal_mass_spring
