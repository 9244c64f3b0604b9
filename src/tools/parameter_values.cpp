// yaml-cpp reads lists the way modal_compare reads its config files, so both accept the same text.
#include "parameter_values.h"

#include <yaml-cpp/yaml.h>

#include <cerrno>
#include <climits>
#include <cstdlib>

namespace modal_mass_spring
{
namespace
{

std::string trimmed(const std::string& text)
{
  const auto first = text.find_first_not_of(" \t\n\r");
  if (first == std::string::npos)
    return "";
  return text.substr(first, text.find_last_not_of(" \t\n\r") - first + 1);
}

}  // namespace

std::optional<double> parseNumber(const std::string& text)
{
  const std::string t = trimmed(text);
  if (t.empty())
    return std::nullopt;
  char* end = nullptr;
  errno = 0;
  const double value = std::strtod(t.c_str(), &end);
  if (end != t.c_str() + t.size())
    return std::nullopt;
  if (errno == ERANGE && value != 0.0)  // overflow to +-HUGE_VAL: say what was written, not inf
    return std::nullopt;
  return value;
}

std::optional<int> parseInteger(const std::string& text)
{
  const std::string t = trimmed(text);
  if (t.empty())
    return std::nullopt;
  char* end = nullptr;
  errno = 0;
  const long value = std::strtol(t.c_str(), &end, 10);
  if (end != t.c_str() + t.size() || errno == ERANGE || value < INT_MIN || value > INT_MAX)
    return std::nullopt;
  return static_cast<int>(value);
}

std::optional<std::vector<std::string>> parseListText(const std::string& text)
{
  YAML::Node node;
  try
  {
    node = YAML::Load(text);
  }
  catch (const YAML::Exception&)
  {
    return std::nullopt;
  }
  if (!node.IsSequence())
    return std::nullopt;
  std::vector<std::string> items;
  for (const auto& item : node)
  {
    if (!item.IsScalar())
      return std::nullopt;
    items.push_back(item.Scalar());
  }
  return items;
}

}  // namespace modal_mass_spring
