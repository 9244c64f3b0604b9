// XmlRpc types to the ParameterSource getters; wrong types are errors naming the key, never guesses.
#include "xmlrpc_parameter_source.h"

#include "parameter_values.h"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <functional>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace modal_mass_spring
{
namespace
{

using XmlRpc::XmlRpcValue;

std::string describe(const XmlRpcValue& constant)
{
  XmlRpcValue value = constant;  // XmlRpcValue's conversions are not const
  std::ostringstream out;
  switch (value.getType())
  {
    case XmlRpcValue::TypeString:
      out << "'" << static_cast<std::string>(value) << "' (a string)";
      break;
    case XmlRpcValue::TypeBoolean:
      out << (static_cast<bool>(value) ? "true" : "false") << " (a bool)";
      break;
    case XmlRpcValue::TypeInt:
      out << static_cast<int>(value) << " (an integer)";
      break;
    case XmlRpcValue::TypeDouble:
      out << static_cast<double>(value) << " (a floating-point number)";
      break;
    case XmlRpcValue::TypeArray:
      out << "a list of " << value.size() << " values";
      break;
    case XmlRpcValue::TypeStruct:
      out << "a map";
      break;
    default:
      out << "a value of XmlRpc type " << value.getType();
  }
  return out.str();
}

[[noreturn]] void throwWrongType(const std::string& key, const std::string& expected, const XmlRpcValue& value)
{
  throw std::invalid_argument(wrongType(key, expected) + ", got " + describe(value));
}

std::string asString(const XmlRpcValue& value)
{
  return static_cast<std::string>(const_cast<XmlRpcValue&>(value));
}

std::optional<int> toInt(const XmlRpcValue& value)
{
  if (value.getType() == XmlRpcValue::TypeInt)
    return static_cast<int>(const_cast<XmlRpcValue&>(value));
  if (value.getType() == XmlRpcValue::TypeString)
    return parseInteger(asString(value));
  return std::nullopt;
}

std::optional<double> toDouble(const XmlRpcValue& value)
{
  auto& v = const_cast<XmlRpcValue&>(value);
  if (value.getType() == XmlRpcValue::TypeInt)
    return static_cast<double>(static_cast<int>(v));
  if (value.getType() == XmlRpcValue::TypeDouble)
    return static_cast<double>(v);
  if (value.getType() == XmlRpcValue::TypeString)
    return parseNumber(asString(value));
  return std::nullopt;
}

// A list from an XmlRpc array or from the text of a YAML list; `convert` turns one element (an
// XmlRpc value, or a string from the text) into T.
template <typename T, typename Convert>
std::vector<T> toList(const std::string& key, const XmlRpcValue& value, const std::string& expected,
                      const std::string& example, Convert convert)
{
  const std::string hint = expected + ", e.g. " + example + " (on the rosrun command line: _" + key + ":='" +
                           example + "')";
  std::vector<XmlRpcValue> items;
  if (value.getType() == XmlRpcValue::TypeArray)
  {
    for (int k = 0; k < value.size(); ++k)
      items.push_back(value[k]);
  }
  else if (value.getType() == XmlRpcValue::TypeString)
  {
    const auto texts = parseListText(asString(value));
    if (!texts)
      throwWrongType(key, hint, value);
    for (const auto& text : *texts)
      items.emplace_back(text);
  }
  else
  {
    throwWrongType(key, hint, value);
  }
  std::vector<T> list;
  for (size_t k = 0; k < items.size(); ++k)
  {
    const std::optional<T> item = convert(items[k]);
    if (!item)
      throw std::invalid_argument(wrongType(key, hint) + ", element " + std::to_string(k) + " is " +
                                  describe(items[k]));
    list.push_back(*item);
  }
  return list;
}

// YAML text as the XmlRpc value rosparam would have made of it, scalars as strings (the getters
// read numbers from strings); nothing when the text is not YAML.
std::optional<XmlRpcValue> fromYamlText(const std::string& text)
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
  std::function<XmlRpcValue(const YAML::Node&)> convert = [&](const YAML::Node& n) {
    XmlRpcValue value;
    if (n.IsSequence())
    {
      value.setSize(static_cast<int>(n.size()));
      for (size_t k = 0; k < n.size(); ++k)
        value[static_cast<int>(k)] = convert(n[k]);
    }
    else if (n.IsMap())
    {
      value.begin();  // makes it an empty struct
      for (const auto& entry : n)
        value[entry.first.as<std::string>()] = convert(entry.second);
    }
    else if (n.IsScalar())
    {
      value = n.Scalar();
    }
    return value;
  };
  return convert(node);
}

}  // namespace

XmlRpcParameterSource::XmlRpcParameterSource(const XmlRpc::XmlRpcValue& params) : params_(params)
{
  if (params_.getType() != XmlRpcValue::TypeStruct)
    params_ = XmlRpcValue();
}

const XmlRpc::XmlRpcValue* XmlRpcParameterSource::find(const std::string& key) const
{
  if (params_.getType() != XmlRpcValue::TypeStruct || !params_.hasMember(key))
    return nullptr;
  return &params_[key];
}

std::vector<std::string> XmlRpcParameterSource::keys() const
{
  std::vector<std::string> names;
  if (params_.getType() == XmlRpcValue::TypeStruct)
    for (auto it = params_.begin(); it != params_.end(); ++it)
      names.push_back(it->first);
  return names;
}

std::optional<int> XmlRpcParameterSource::getInt(const std::string& key) const
{
  const XmlRpcValue* value = find(key);
  if (!value)
    return std::nullopt;
  const auto result = toInt(*value);
  if (!result)
  {
    // A whole number beyond int (roscpp reads one on the command line as a double): the range.
    const auto number = toDouble(*value);
    if (number && std::isfinite(*number) && *number == std::floor(*number) &&
        (*number < std::numeric_limits<int>::min() || *number > std::numeric_limits<int>::max()))
    {
      std::ostringstream text;
      text.precision(17);
      text << *number;
      throw std::invalid_argument(intOutOfRange(key, text.str()));
    }
    throwWrongType(key, "an integer", *value);
  }
  return result;
}

std::optional<double> XmlRpcParameterSource::getDouble(const std::string& key) const
{
  const XmlRpcValue* value = find(key);
  if (!value)
    return std::nullopt;
  const auto result = toDouble(*value);
  if (!result)
    throwWrongType(key, "a number", *value);
  return result;
}

std::optional<bool> XmlRpcParameterSource::getBool(const std::string& key) const
{
  const XmlRpcValue* value = find(key);
  if (!value)
    return std::nullopt;
  if (value->getType() != XmlRpcValue::TypeBoolean)
    throwWrongType(key, "true or false", *value);
  return static_cast<bool>(const_cast<XmlRpcValue&>(*value));
}

std::optional<std::string> XmlRpcParameterSource::getString(const std::string& key) const
{
  const XmlRpcValue* value = find(key);
  if (!value)
    return std::nullopt;
  if (value->getType() != XmlRpcValue::TypeString)
    throwWrongType(key, "a string", *value);
  return asString(*value);
}

std::optional<std::vector<int>> XmlRpcParameterSource::getIntList(const std::string& key) const
{
  const XmlRpcValue* value = find(key);
  if (!value)
    return std::nullopt;
  return toList<int>(key, *value, "a list of integers", "[20, 24]", toInt);
}

std::optional<std::vector<double>> XmlRpcParameterSource::getDoubleList(const std::string& key) const
{
  const XmlRpcValue* value = find(key);
  if (!value)
    return std::nullopt;
  return toList<double>(key, *value, "a list of numbers", "[0.0, 0.0, -9.81]", toDouble);
}

std::optional<std::vector<std::string>> XmlRpcParameterSource::getStringList(const std::string& key) const
{
  const XmlRpcValue* value = find(key);
  if (!value)
    return std::nullopt;
  return toList<std::string>(key, *value, "a list of names", "[linear, full, physical]",
                             [](const XmlRpcValue& item) -> std::optional<std::string> {
                               if (item.getType() != XmlRpcValue::TypeString)
                                 return std::nullopt;
                               return asString(item);
                             });
}

namespace
{
// A list parameter, given as a list or as its YAML text (on the rosrun command line); anything else
// is refused naming `key` and what was expected.
XmlRpcValue asList(const std::string& key, const XmlRpcValue& found, const std::string& expected)
{
  XmlRpcValue value = found;
  if (value.getType() == XmlRpcValue::TypeString)
  {
    const auto parsed = fromYamlText(asString(value));
    if (!parsed || parsed->getType() != XmlRpcValue::TypeArray)
      throwWrongType(key, expected, value);
    value = *parsed;
  }
  if (value.getType() != XmlRpcValue::TypeArray)
    throwWrongType(key, expected, value);
  return value;
}
}  // namespace

std::optional<std::vector<HandleParam>> XmlRpcParameterSource::getHandleList(const std::string& key) const
{
  const XmlRpcValue* found = find(key);
  if (!found)
    return std::nullopt;
  const std::string example = "[{frame: gripper, particles: [0, 4]}]";
  const std::string expected = "a list of maps {frame: <tf frame>, particles: [indices]}, e.g. " + example +
                               " (on the rosrun command line: _" + key + ":='" + example + "')";
  XmlRpcValue value = asList(key, *found, expected);
  std::vector<HandleParam> handles;
  for (int h = 0; h < value.size(); ++h)
  {
    const std::string name = key + "[" + std::to_string(h) + "]";
    XmlRpcValue& item = value[h];
    if (item.getType() != XmlRpcValue::TypeStruct)
      throwWrongType(name, "a map {frame: <tf frame>, particles: [indices]}", item);
    for (auto it = item.begin(); it != item.end(); ++it)
      if (it->first != "frame" && it->first != "particles")
        throw std::invalid_argument(wrongType(name, "a map with the keys frame and particles only") +
                                    ", got the key '" + it->first + "'");
    if (!item.hasMember("frame") || !item.hasMember("particles"))
      throw std::invalid_argument(wrongType(name, "a map with both keys frame and particles") + ", got " +
                                  (item.hasMember("frame") ? "no particles" : "no frame"));
    if (item["frame"].getType() != XmlRpcValue::TypeString)
      throwWrongType(name + ".frame", "a string (a tf frame id)", item["frame"]);
    HandleParam handle;
    handle.frame = asString(item["frame"]);
    XmlRpcValue& particles = item["particles"];
    if (particles.getType() != XmlRpcValue::TypeArray)
      throwWrongType(name + ".particles", "a list of integers (row * cols + col)", particles);
    for (int k = 0; k < particles.size(); ++k)
    {
      const auto index = toInt(particles[k]);
      if (!index)
        throw std::invalid_argument(wrongType(name + ".particles", "a list of integers (row * cols + col)") +
                                    ", element " + std::to_string(k) + " is " + describe(particles[k]));
      handle.particles.push_back(*index);
    }
    handles.push_back(handle);
  }
  return handles;
}

std::optional<std::vector<Collider>> XmlRpcParameterSource::getColliderList(const std::string& key) const
{
  const XmlRpcValue* found = find(key);
  if (!found)
    return std::nullopt;
  const std::string example = "[{type: plane, point: [0, 0, 0], normal: [0, 0, 1]}]";
  const std::string expected = "a list of collider maps, e.g. " + example;
  XmlRpcValue value = asList(key, *found, expected);
  std::vector<Collider> colliders;
  for (int i = 0; i < value.size(); ++i)
  {
    const std::string name = key + "[" + std::to_string(i) + "]";
    XmlRpcValue& item = value[i];
    if (item.getType() != XmlRpcValue::TypeStruct)
      throwWrongType(name, "a map such as {type: sphere, center: [0, 0, 0], radius: 0.1}", item);
    ColliderFields fields;
    for (auto it = item.begin(); it != item.end(); ++it)
    {
      XmlRpcValue& field = it->second;
      const bool named = it->first == "type" || it->first == "frame";
      if (const auto number = named ? std::nullopt : toDouble(field))
      {
        fields.numbers[it->first] = {*number};
        continue;
      }
      if (field.getType() == XmlRpcValue::TypeString)
      {
        fields.text[it->first] = asString(field);
        continue;
      }
      if (named || field.getType() != XmlRpcValue::TypeArray)
        throwWrongType(name + "." + it->first, colliderFieldExpected(it->first), field);
      std::vector<double> numbers;
      for (int k = 0; k < field.size(); ++k)
      {
        const auto number = toDouble(field[k]);
        if (!number)
          throwWrongType(name + "." + it->first, colliderFieldExpected(it->first), field);
        numbers.push_back(*number);
      }
      fields.numbers[it->first] = numbers;
    }
    colliders.push_back(colliderFromFields(fields, name));
  }
  return colliders;
}

}  // namespace modal_mass_spring
