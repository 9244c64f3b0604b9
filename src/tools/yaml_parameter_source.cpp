// Reads parameters from YAML with yaml-cpp; wrong types are reported with the core's wording.
#include "yaml_parameter_source.h"

#include "parameter_values.h"
#include "modal_mass_spring/validation.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <sstream>
#include <stdexcept>
#include <type_traits>

namespace modal_mass_spring
{

const std::set<std::string> kNodeParameters{
    "real_time_factor", "publish_rate", "markers_rate", "fixed_frame", "grid_frame", "tf_particles", "offset",
    "color_by_strain", "strain_scale", "particle_diameter", "spring_width", "detail_max_particles",
    "surface_max_cells", "show_surface", "show_particles", "show_springs", "show_labels", "show_shadow",
    "methods", "method_spacing", "shadow_full", "status_log_period", "diagnostic_period", "drag_stiffness",
    "poke_impulse", "cache_dir", "rollout_threads", "rollout_max_horizon", "rollout_max_candidates",
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

YamlParameterSource YamlParameterSource::fromNode(YAML::Node root, const std::string& origin)
{
  return YamlParameterSource(checkedRoot(root, origin), origin);
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

const std::string kStringTag = "tag:yaml.org,2002:str";
const std::string kIntTag = "tag:yaml.org,2002:int";
const std::string kFloatTag = "tag:yaml.org,2002:float";
const std::string kBoolTag = "tag:yaml.org,2002:bool";
const std::string kListTag = "tag:yaml.org,2002:seq";
const std::string kMapTag = "tag:yaml.org,2002:map";
const std::string kOtherTag = "tag:yaml.org,2002:binary";

namespace
{

bool typed(const YAML::Node& node)
{
  const std::string& tag = node.Tag();
  return tag == kStringTag || tag == kIntTag || tag == kFloatTag || tag == kBoolTag || tag == kListTag ||
         tag == kMapTag || tag == kOtherTag;
}

// A decoded YAML file's scalar, or nothing.
template <typename T>
std::optional<T> decoded(const YAML::Node& node)
{
  T value{};
  if (!node.IsScalar() || !YAML::convert<T>::decode(node, value))
    return std::nullopt;
  return value;
}

// A list's YAML text, typed as the rest of its tree: scalars are strings, as rosrun hands them over.
void typeAsStrings(YAML::Node node)
{
  if (node.IsScalar())
    node.SetTag(kStringTag);
  else if (node.IsMap())
  {
    node.SetTag(kMapTag);
    for (auto entry : node)
      typeAsStrings(entry.second);
  }
  else if (node.IsSequence())
  {
    node.SetTag(kListTag);
    for (auto item : node)
      typeAsStrings(item);
  }
}

}  // namespace

std::optional<int> scalarInt(const YAML::Node& node)
{
  if (!typed(node))
    return decoded<int>(node);
  if (node.Tag() != kIntTag && node.Tag() != kStringTag)
    return std::nullopt;
  return parseInteger(node.Scalar());
}

std::optional<double> scalarNumber(const YAML::Node& node)
{
  if (!typed(node))
    return decoded<double>(node);
  if (node.Tag() != kIntTag && node.Tag() != kFloatTag && node.Tag() != kStringTag)
    return std::nullopt;
  return parseNumber(node.Scalar());
}

std::optional<bool> scalarBool(const YAML::Node& node)
{
  if (!typed(node))
    return decoded<bool>(node);
  if (node.Tag() != kBoolTag)
    return std::nullopt;
  return node.Scalar() == "true";
}

std::optional<std::string> scalarString(const YAML::Node& node)
{
  if (!typed(node))
    return decoded<std::string>(node);
  if (node.Tag() != kStringTag)
    return std::nullopt;
  return node.Scalar();
}

std::optional<YAML::Node> listNode(const YAML::Node& node)
{
  if (node.IsSequence())
    return node;
  if (node.Tag() != kStringTag)
    return std::nullopt;
  YAML::Node list;
  try
  {
    list = YAML::Load(node.Scalar());
  }
  catch (const YAML::Exception&)
  {
    return std::nullopt;
  }
  if (!list.IsSequence())
    return std::nullopt;
  typeAsStrings(list);
  return list;
}

std::string describeValue(const YAML::Node& node)
{
  std::ostringstream out;
  const std::string& tag = node.Tag();
  if (!typed(node))
  {
    // As written, cut short, so that a message shows what was wrong.
    std::string text = YAML::Dump(node);
    std::replace(text.begin(), text.end(), '\n', ' ');
    if (text.size() > 60)
      text = text.substr(0, 57) + "...";
    out << "'" << text << "'";
  }
  else if (tag == kStringTag)
    out << "'" << node.Scalar() << "' (a string)";
  else if (tag == kBoolTag)
    out << node.Scalar() << " (a bool)";
  else if (tag == kIntTag)
    out << node.Scalar() << " (an integer)";
  else if (tag == kFloatTag)
    out << parseNumber(node.Scalar()).value_or(0.0) << " (a floating-point number)";
  else if (tag == kListTag)
    out << "a list of " << node.size() << " values";
  else if (tag == kMapTag)
    out << "a map";
  else
    out << "a value of another type (" << node.Scalar() << ")";
  return out.str();
}

namespace
{

// ", got 'abc'": the value, so that a message shows what was wrong.
std::string got(const YAML::Node& node)
{
  return ", got " + describeValue(node);
}

template <typename T>
std::optional<T> scalarAs(const YAML::Node& node)
{
  if constexpr (std::is_same_v<T, int>)
    return scalarInt(node);
  else if constexpr (std::is_same_v<T, double>)
    return scalarNumber(node);
  else if constexpr (std::is_same_v<T, bool>)
    return scalarBool(node);
  else
    return scalarString(node);
}

// An integer parameter given a whole number beyond int: said with the range, not as a wrong type.
template <typename T>
void refuseOutOfRange(const std::string& key, const YAML::Node& node)
{
  if constexpr (std::is_same_v<T, int>)
  {
    const std::optional<double> value = scalarNumber(node);
    if (value && std::isfinite(*value) && *value == std::floor(*value) &&
        (*value < std::numeric_limits<int>::min() || *value > std::numeric_limits<int>::max()))
    {
      std::ostringstream text;  // a typed number as the server holds it, a file's as written
      text.precision(17);
      text << *value;
      throw std::invalid_argument(intOutOfRange(key, typed(node) ? text.str() : node.Scalar()));
    }
  }
}

}  // namespace

template <typename T>
std::optional<T> YamlParameterSource::scalar(const std::string& key, const std::string& expected) const
{
  const YAML::Node node = lookup(key);
  if (!node.IsDefined())
    return std::nullopt;
  const std::optional<T> value = scalarAs<T>(node);
  if (!value)
  {
    refuseOutOfRange<T>(key, node);
    throw std::invalid_argument(wrongType(key, expected) + got(node));
  }
  return value;
}

template <typename T>
std::optional<std::vector<T>> YamlParameterSource::list(const std::string& key, const std::string& expected,
                                                        const std::string& example) const
{
  const YAML::Node node = lookup(key);
  if (!node.IsDefined())
    return std::nullopt;
  // A typed source's list may come as text from the command line: say how to give one there.
  const std::string hint =
      typed(node) ? expected + ", e.g. " + example + " (on the rosrun command line: _" + key + ":='" + example + "')"
                  : expected;
  const std::optional<YAML::Node> items = listNode(node);
  if (!items)
    throw std::invalid_argument(wrongType(key, hint) + got(node));
  std::vector<T> values;
  for (size_t k = 0; k < items->size(); ++k)
  {
    const YAML::Node item = (*items)[k];
    const std::optional<T> value = scalarAs<T>(item);
    if (value)
    {
      values.push_back(*value);
      continue;
    }
    if (typed(node))
      throw std::invalid_argument(wrongType(key, hint) + ", element " + std::to_string(k) + " is " +
                                  describeValue(item));
    refuseOutOfRange<T>(key, item);
    throw std::invalid_argument(wrongType(key, expected) + got(node));
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
  return list<int>(key, "a list of integers", "[20, 24]");
}

std::optional<std::vector<double>> YamlParameterSource::getDoubleList(const std::string& key) const
{
  return list<double>(key, "a list of numbers", "[0.0, 0.0, -9.81]");
}

std::optional<std::vector<std::string>> YamlParameterSource::getStringList(const std::string& key) const
{
  return list<std::string>(key, "a list of names", "[linear, full, physical]");
}

}  // namespace modal_mass_spring
