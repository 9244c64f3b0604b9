// XmlRpc types to the ParameterSource getters; wrong types are errors, never guesses.
#include "ros_parameter_source.h"

#include <sstream>
#include <stdexcept>

namespace modal_mass_spring
{
namespace
{

std::string describe(XmlRpc::XmlRpcValue& value)
{
  std::ostringstream out;
  switch (value.getType())
  {
    case XmlRpc::XmlRpcValue::TypeString:
      out << "'" << static_cast<std::string>(value) << "' (a string)";
      break;
    case XmlRpc::XmlRpcValue::TypeBoolean:
      out << (static_cast<bool>(value) ? "true" : "false") << " (a bool)";
      break;
    case XmlRpc::XmlRpcValue::TypeInt:
      out << static_cast<int>(value) << " (an integer)";
      break;
    case XmlRpc::XmlRpcValue::TypeDouble:
      out << static_cast<double>(value) << " (a floating-point number)";
      break;
    case XmlRpc::XmlRpcValue::TypeArray:
      out << "a list of " << value.size() << " values";
      break;
    case XmlRpc::XmlRpcValue::TypeStruct:
      out << "a map";
      break;
    default:
      out << "a value of XmlRpc type " << value.getType();
  }
  return out.str();
}

[[noreturn]] void throwWrongType(const std::string& key, const std::string& expected, XmlRpc::XmlRpcValue& value)
{
  throw std::invalid_argument(wrongType(key, expected) + ", got " + describe(value));
}

}  // namespace

bool RosParameterSource::lookup(const std::string& key, XmlRpc::XmlRpcValue& value) const
{
  queried_.insert(key);
  return nh_.getParam(key, value);
}

std::optional<int> RosParameterSource::getInt(const std::string& key) const
{
  XmlRpc::XmlRpcValue value;
  if (!lookup(key, value))
    return std::nullopt;
  if (value.getType() != XmlRpc::XmlRpcValue::TypeInt)
    throwWrongType(key, "an integer", value);
  return static_cast<int>(value);
}

std::optional<double> RosParameterSource::getDouble(const std::string& key) const
{
  XmlRpc::XmlRpcValue value;
  if (!lookup(key, value))
    return std::nullopt;
  if (value.getType() == XmlRpc::XmlRpcValue::TypeInt)
    return static_cast<double>(static_cast<int>(value));
  if (value.getType() != XmlRpc::XmlRpcValue::TypeDouble)
    throwWrongType(key, "a number", value);
  return static_cast<double>(value);
}

std::optional<bool> RosParameterSource::getBool(const std::string& key) const
{
  XmlRpc::XmlRpcValue value;
  if (!lookup(key, value))
    return std::nullopt;
  if (value.getType() != XmlRpc::XmlRpcValue::TypeBoolean)
    throwWrongType(key, "true or false", value);
  return static_cast<bool>(value);
}

std::optional<std::string> RosParameterSource::getString(const std::string& key) const
{
  XmlRpc::XmlRpcValue value;
  if (!lookup(key, value))
    return std::nullopt;
  if (value.getType() != XmlRpc::XmlRpcValue::TypeString)
    throwWrongType(key, "a string", value);
  return static_cast<std::string>(value);
}

std::optional<std::vector<int>> RosParameterSource::getIntList(const std::string& key) const
{
  XmlRpc::XmlRpcValue value;
  if (!lookup(key, value))
    return std::nullopt;
  if (value.getType() != XmlRpc::XmlRpcValue::TypeArray)
    throwWrongType(key, "a list of integers", value);
  std::vector<int> list;
  for (int k = 0; k < value.size(); ++k)
  {
    if (value[k].getType() != XmlRpc::XmlRpcValue::TypeInt)
      throw std::invalid_argument(wrongType(key, "a list of integers") + ", element " + std::to_string(k) +
                                  " is " + describe(value[k]));
    list.push_back(static_cast<int>(value[k]));
  }
  return list;
}

std::optional<std::vector<double>> RosParameterSource::getDoubleList(const std::string& key) const
{
  XmlRpc::XmlRpcValue value;
  if (!lookup(key, value))
    return std::nullopt;
  if (value.getType() != XmlRpc::XmlRpcValue::TypeArray)
    throwWrongType(key, "a list of numbers", value);
  std::vector<double> list;
  for (int k = 0; k < value.size(); ++k)
  {
    if (value[k].getType() == XmlRpc::XmlRpcValue::TypeInt)
      list.push_back(static_cast<int>(value[k]));
    else if (value[k].getType() == XmlRpc::XmlRpcValue::TypeDouble)
      list.push_back(static_cast<double>(value[k]));
    else
      throw std::invalid_argument(wrongType(key, "a list of numbers") + ", element " + std::to_string(k) +
                                  " is " + describe(value[k]));
  }
  return list;
}

std::vector<std::string> RosParameterSource::unqueried() const
{
  std::vector<std::string> names, unknown;
  nh_.getParamNames(names);
  const std::string prefix = nh_.getNamespace() + "/";
  std::set<std::string> seen;
  for (const auto& name : names)
  {
    if (name.compare(0, prefix.size(), prefix) != 0)
      continue;
    const std::string key = name.substr(prefix.size(), name.find('/', prefix.size()) - prefix.size());
    if (!queried_.count(key) && seen.insert(key).second)
      unknown.push_back(key);
  }
  return unknown;
}

}  // namespace modal_mass_spring
