// Reads parameters from YAML with yaml-cpp; wrong types are reported with the core's wording.
#include "yaml_parameter_source.h"

#include <fstream>
#include <stdexcept>

namespace modal_mass_spring
{

YamlParameterSource::YamlParameterSource(YAML::Node root, std::string origin)
  : root_(std::move(root)), origin_(std::move(origin))
{
}

YamlParameterSource YamlParameterSource::fromFile(const std::string& path)
{
  std::ifstream file(path);
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
  if (root.IsNull())
    root = YAML::Node(YAML::NodeType::Map);  // an empty file: every parameter at its default
  if (!root.IsMap())
    throw std::invalid_argument("cannot read config '" + path + "': must be a map of parameter names to values");
  return YamlParameterSource(root, path);
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
  if (root.IsNull())
    root = YAML::Node(YAML::NodeType::Map);
  if (!root.IsMap())
    throw std::invalid_argument("cannot read " + origin + ": must be a map of parameter names to values");
  return YamlParameterSource(root, origin);
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

template <typename T>
std::optional<T> YamlParameterSource::scalar(const std::string& key, const std::string& expected) const
{
  const YAML::Node node = lookup(key);
  if (!node.IsDefined())
    return std::nullopt;
  if (!node.IsScalar())
    throw std::invalid_argument(wrongType(key, expected));
  try
  {
    return node.as<T>();
  }
  catch (const YAML::Exception&)
  {
    throw std::invalid_argument(wrongType(key, expected));
  }
}

template <typename T>
std::optional<std::vector<T>> YamlParameterSource::list(const std::string& key, const std::string& expected) const
{
  const YAML::Node node = lookup(key);
  if (!node.IsDefined())
    return std::nullopt;
  if (!node.IsSequence())
    throw std::invalid_argument(wrongType(key, expected));
  std::vector<T> values;
  for (const YAML::Node& item : node)
  {
    if (!item.IsScalar())
      throw std::invalid_argument(wrongType(key, expected));
    try
    {
      values.push_back(item.as<T>());
    }
    catch (const YAML::Exception&)
    {
      throw std::invalid_argument(wrongType(key, expected));
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
