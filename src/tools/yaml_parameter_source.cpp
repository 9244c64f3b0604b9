// Reads parameters from YAML with yaml-cpp; wrong types are reported with the core's wording.
#include "yaml_parameter_source.h"

#include "modal_mass_spring/validation.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <stdexcept>
#include <type_traits>

namespace modal_mass_spring
{

const std::set<std::string> kNodeParameters{
    "real_time_factor", "publish_rate",    "fixed_frame",  "grid_frame",        "tf_particles",      "offset",
    "color_by_strain",  "strain_scale",    "particle_diameter", "spring_width", "status_log_period", "diagnostic_period",
    "cache_dir",        "rollout_threads", "rollout_max_horizon", "rollout_max_candidates", "show_particles",
    "show_springs",
    "handles"};  // the node moves their particles with TF frames; the tool does not read them

const std::set<std::string> kToolParameters{"handle_scenarios", "colliders"};

YamlParameterSource::YamlParameterSource(YAML::Node root, std::string origin)
  : root_(std::move(root)), origin_(std::move(origin))
{
}

YamlParameterSource YamlParameterSource::fromFile(const std::string& path)
{
  std::ifstream file(path);
  if (std::filesystem::is_directory(path))
    throw std::invalid_argument("cannot read config '" + path + "': is a folder, not a YAML file");
  if (!file)
    throw std::invalid_argument("cannot read config '" + path + "': no such file or not readable");
  YAML::Node root;
  try
  {
    root = YAML::LoadFile(path);
  }
  catch (const YAML::Exception& e)
  {
    throw std::invalid_argument("cannot read config '" + path + "': not valid YAML: " + e.what());
  }
  catch (const std::exception& e)  // a folder, a read error
  {
    throw std::invalid_argument("cannot read config '" + path + "': " + e.what());
  }
  return YamlParameterSource(checkedRoot(root, "config '" + path + "'"), path);
}

YamlParameterSource YamlParameterSource::fromString(const std::string& text, const std::string& origin)
{
  YAML::Node root;
  try
  {
    root = YAML::Load(text);
  }
  catch (const YAML::Exception& e)
  {
    throw std::invalid_argument("cannot read " + origin + ": not valid YAML: " + e.what());
  }
  return YamlParameterSource(checkedRoot(root, origin), origin);
}

YAML::Node YamlParameterSource::checkedRoot(YAML::Node root, const std::string& origin)
{
  if (root.IsNull())
    return YAML::Node(YAML::NodeType::Map);  // an empty text: every parameter at its default
  if (!root.IsMap())
    throw std::invalid_argument("cannot read " + origin + ": must be a map of parameter names to values");
  std::map<std::string, int> lines;  // key -> line (1-based) where it first appears
  for (const auto& entry : root)
  {
    const std::string key = entry.first.Scalar();
    const int line = entry.first.Mark().line + 1;
    const auto [first, inserted] = lines.insert({key, line});
    if (!inserted)
      rejectParameter(key, "(given twice)",
                      "in " + origin + " on lines " + std::to_string(first->second) + " and " + std::to_string(line) +
                          "; each parameter must be given once");
  }
  return root;
}

std::vector<std::string> YamlParameterSource::keys() const
{
  std::vector<std::string> names;
  for (const auto& entry : root_)
    names.push_back(entry.first.Scalar());
  return names;
}

std::vector<std::string> YamlParameterSource::unknownKeys() const
{
  std::vector<std::string> unknown;
  for (const std::string& key : keys())
    if (!queried_.count(key) && !kNodeParameters.count(key) && !kToolParameters.count(key))
      unknown.push_back(key);
  return unknown;
}

YamlParameterSource YamlParameterSource::clone() const
{
  return YamlParameterSource(YAML::Clone(root_), origin_);
}

void YamlParameterSource::set(const std::string& key, const std::string& value)
{
  try
  {
    root_[key] = YAML::Load(value);
  }
  catch (const YAML::Exception& e)
  {
    throw std::invalid_argument("invalid value '" + value + "' for parameter '" + key + "': not valid YAML: " + e.what());
  }
}

YAML::Node YamlParameterSource::lookup(const std::string& key) const
{
  queried_.insert(key);
  const YAML::Node& root = root_;  // const access: a missing key must not be inserted
  return root[key];
}

namespace
{

// ", got 'abc'": the value as written, cut short, so that a message shows what was wrong.
std::string got(const YAML::Node& node)
{
  std::string text = YAML::Dump(node);
  std::replace(text.begin(), text.end(), '\n', ' ');
  if (text.size() > 60)
    text = text.substr(0, 57) + "...";
  return ", got '" + text + "'";
}

// An integer parameter given a whole number beyond int: said with the range, not as a wrong type.
template <typename T>
void refuseOutOfRange(const std::string& key, const YAML::Node& node)
{
  if constexpr (std::is_same_v<T, int>)
  {
    double value = 0.0;
    if (node.IsScalar() && YAML::convert<double>::decode(node, value) && std::isfinite(value) &&
        value == std::floor(value) &&
        (value < std::numeric_limits<int>::min() || value > std::numeric_limits<int>::max()))
      throw std::invalid_argument(intOutOfRange(key, node.Scalar()));
  }
}

}  // namespace

template <typename T>
std::optional<T> YamlParameterSource::scalar(const std::string& key, const std::string& expected) const
{
  const YAML::Node node = lookup(key);
  if (!node.IsDefined())
    return std::nullopt;
  if (!node.IsScalar())
    throw std::invalid_argument(wrongType(key, expected) + got(node));
  try
  {
    return node.as<T>();
  }
  catch (const YAML::Exception&)
  {
    refuseOutOfRange<T>(key, node);
    throw std::invalid_argument(wrongType(key, expected) + got(node));
  }
}

template <typename T>
std::optional<std::vector<T>> YamlParameterSource::list(const std::string& key, const std::string& expected) const
{
  const YAML::Node node = lookup(key);
  if (!node.IsDefined())
    return std::nullopt;
  if (!node.IsSequence())
    throw std::invalid_argument(wrongType(key, expected) + got(node));
  std::vector<T> values;
  for (const YAML::Node& item : node)
  {
    if (!item.IsScalar())
      throw std::invalid_argument(wrongType(key, expected) + got(node));
    try
    {
      values.push_back(item.as<T>());
    }
    catch (const YAML::Exception&)
    {
      refuseOutOfRange<T>(key, item);
      throw std::invalid_argument(wrongType(key, expected) + got(node));
    }
  }
  return values;
}

std::optional<int> YamlParameterSource::getInt(const std::string& key) const
{
  return scalar<int>(key, "an integer");
}

std::optional<double> YamlParameterSource::getDouble(const std::string& key) const
{
  return scalar<double>(key, "a number");
}

std::optional<bool> YamlParameterSource::getBool(const std::string& key) const
{
  return scalar<bool>(key, "true or false");
}

std::optional<std::string> YamlParameterSource::getString(const std::string& key) const
{
  return scalar<std::string>(key, "a string");
}

std::optional<std::vector<int>> YamlParameterSource::getIntList(const std::string& key) const
{
  return list<int>(key, "a list of integers");
}

std::optional<std::vector<double>> YamlParameterSource::getDoubleList(const std::string& key) const
{
  return list<double>(key, "a list of numbers");
}

}  // namespace modal_mass_spring
