// XmlRpc values to the YAML tree, typed; the handles and colliders, which only the node reads in this
// shape, read from it.
#include "xmlrpc_parameter_source.h"

#include <cstdio>
#include <stdexcept>

namespace modal_mass_spring
{

using XmlRpc::XmlRpcValue;

YAML::Node toYaml(const XmlRpcValue& constant)
{
  XmlRpcValue& value = const_cast<XmlRpcValue&>(constant);  // XmlRpcValue's accessors are not const
  YAML::Node node;
  switch (value.getType())
  {
    case XmlRpcValue::TypeStruct:
      node = YAML::Node(YAML::NodeType::Map);
      for (auto it = value.begin(); it != value.end(); ++it)
        node[it->first] = toYaml(it->second);
      node.SetTag(kMapTag);
      break;
    case XmlRpcValue::TypeArray:
      node = YAML::Node(YAML::NodeType::Sequence);
      for (int k = 0; k < value.size(); ++k)
        node.push_back(toYaml(value[k]));
      node.SetTag(kListTag);
      break;
    case XmlRpcValue::TypeString:
      node = static_cast<std::string>(value);
      node.SetTag(kStringTag);
      break;
    case XmlRpcValue::TypeBoolean:
      node = static_cast<bool>(value) ? "true" : "false";
      node.SetTag(kBoolTag);
      break;
    case XmlRpcValue::TypeInt:
      node = std::to_string(static_cast<int>(value));
      node.SetTag(kIntTag);
      break;
    case XmlRpcValue::TypeDouble:
    {
      char text[32];  // every digit: the number read back is the one the server holds
      std::snprintf(text, sizeof text, "%.17g", static_cast<double>(value));
      node = std::string(text);
      node.SetTag(kFloatTag);
      break;
    }
    default:
      node = "XmlRpc type " + std::to_string(value.getType());
      node.SetTag(kOtherTag);
  }
  return node;
}

namespace
{

XmlRpcValue structOrEmpty(const XmlRpcValue& params)
{
  if (params.getType() == XmlRpcValue::TypeStruct)
    return params;
  XmlRpcValue empty;
  empty.begin();  // makes it an empty struct
  return empty;
}

[[noreturn]] void throwWrongType(const std::string& key, const std::string& expected, const YAML::Node& value)
{
  throw std::invalid_argument(wrongType(key, expected) + ", got " + describeValue(value));
}

// A list parameter, given as a list or as its YAML text (on the rosrun command line); anything else
// is refused naming `key` and what was expected.
YAML::Node asList(const std::string& key, const YAML::Node& found, const std::string& expected)
{
  const std::optional<YAML::Node> list = listNode(found);
  if (!list)
    throwWrongType(key, expected, found);
  return *list;
}

HandleParam readHandle(const std::string& name, const YAML::Node& item)
{
  if (!item.IsMap())
    throwWrongType(name, "a map {frame: <tf frame>, particles: [indices]}", item);
  for (const auto& entry : item)
    if (entry.first.Scalar() != "frame" && entry.first.Scalar() != "particles")
      throw std::invalid_argument(wrongType(name, "a map with the keys frame and particles only") + ", got the key '" +
                                  entry.first.Scalar() + "'");
  const YAML::Node frame = item["frame"], particles = item["particles"];
  if (!frame.IsDefined() || !particles.IsDefined())
    throw std::invalid_argument(wrongType(name, "a map with both keys frame and particles") + ", got " +
                                (frame.IsDefined() ? "no particles" : "no frame"));
  HandleParam handle;
  const std::optional<std::string> frame_id = scalarString(frame);
  if (!frame_id)
    throwWrongType(name + ".frame", "a string (a tf frame id)", frame);
  handle.frame = *frame_id;
  const std::string expected = "a list of integers (row * cols + col)";
  if (!particles.IsSequence())
    throwWrongType(name + ".particles", expected, particles);
  for (size_t k = 0; k < particles.size(); ++k)
  {
    const std::optional<int> index = scalarInt(particles[k]);
    if (!index)
      throw std::invalid_argument(wrongType(name + ".particles", expected) + ", element " + std::to_string(k) +
                                  " is " + describeValue(particles[k]));
    handle.particles.push_back(*index);
  }
  return handle;
}

Collider readCollider(const std::string& name, const YAML::Node& item)
{
  if (!item.IsMap())
    throwWrongType(name, "a map such as {type: sphere, center: [0, 0, 0], radius: 0.1}", item);
  ColliderFields fields;
  for (const auto& entry : item)
  {
    const std::string key = entry.first.Scalar();
    const YAML::Node field = entry.second;
    const bool named = key == "type" || key == "frame" || key == "id";
    if (const auto number = named ? std::nullopt : scalarNumber(field))
    {
      fields.numbers[key] = {*number};
      continue;
    }
    if (const auto text = scalarString(field))
    {
      fields.text[key] = *text;
      continue;
    }
    if (named || !field.IsSequence())
      throwWrongType(name + "." + key, colliderFieldExpected(key), field);
    std::vector<double> numbers;
    for (const YAML::Node& element : field)
    {
      const auto number = scalarNumber(element);
      if (!number)
        throwWrongType(name + "." + key, colliderFieldExpected(key), field);
      numbers.push_back(*number);
    }
    fields.numbers[key] = numbers;
  }
  return colliderFromFields(fields, name);
}

}  // namespace

XmlRpcParameterSource::XmlRpcParameterSource(const XmlRpcValue& params)
  : yaml_(YamlParameterSource::fromNode(toYaml(structOrEmpty(params)), "the node's parameters"))
{
}

std::optional<std::vector<HandleParam>> XmlRpcParameterSource::getHandleList(const std::string& key) const
{
  const YAML::Node found = yaml_.getNode(key);
  if (!found.IsDefined())
    return std::nullopt;
  const std::string example = "[{frame: gripper, particles: [0, 4]}]";
  const std::string expected = "a list of maps {frame: <tf frame>, particles: [indices]}, e.g. " + example +
                               " (on the rosrun command line: _" + key + ":='" + example + "')";
  const YAML::Node list = asList(key, found, expected);
  std::vector<HandleParam> handles;
  for (size_t h = 0; h < list.size(); ++h)
    handles.push_back(readHandle(key + "[" + std::to_string(h) + "]", list[h]));
  return handles;
}

std::optional<std::vector<Collider>> XmlRpcParameterSource::getColliderList(const std::string& key) const
{
  const YAML::Node found = yaml_.getNode(key);
  if (!found.IsDefined())
    return std::nullopt;
  const std::string example = "[{type: plane, point: [0, 0, 0], normal: [0, 0, 1]}]";
  const YAML::Node list = asList(key, found, "a list of collider maps, e.g. " + example);
  std::vector<Collider> colliders;
  for (size_t i = 0; i < list.size(); ++i)
    colliders.push_back(readCollider(key + "[" + std::to_string(i) + "]", list[i]));
  return colliders;
}

}  // namespace modal_mass_spring
