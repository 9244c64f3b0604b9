// The parameter `colliders` of a YAML config, read into the core's ColliderFields.
#include "yaml_colliders.h"

#include "modal_mass_spring/validation.h"

#include <map>

namespace modal_mass_spring
{
namespace
{

std::string shown(const YAML::Node& node)
{
  std::string text = YAML::Dump(node);
  for (char& c : text)
    if (c == '\n')
      c = ' ';
  return text.size() > 60 ? text.substr(0, 57) + "..." : text;
}

}  // namespace

std::vector<Collider> parseColliders(const YAML::Node& node, const std::string& key)
{
  const std::string example = "[{type: plane, point: [0, 0, 0], normal: [0, 0, 1]}]";
  if (!node.IsSequence())
    rejectParameter(key, "'" + shown(node) + "'", "must be a list of collider maps, e.g. " + example);
  std::vector<Collider> colliders;
  for (size_t i = 0; i < node.size(); ++i)
  {
    const std::string name = key + "[" + std::to_string(i) + "]";
    const YAML::Node item = node[i];
    if (!item.IsMap())
      rejectParameter(name, "'" + shown(item) + "'", "must be a map such as " + example.substr(1, example.size() - 2));
    ColliderFields fields;
    std::map<std::string, int> lines;  // key -> line (1-based) where it first appears
    for (const auto& entry : item)
    {
      const std::string field = entry.first.as<std::string>();
      const int line = entry.first.Mark().line + 1;
      const auto [first, inserted] = lines.insert({field, line});
      if (!inserted)
        rejectParameter(name + "." + field, "(given twice)",
                        "on lines " + std::to_string(first->second) + " and " + std::to_string(line) +
                            "; each key of a collider must be given once");
      const YAML::Node value = entry.second;
      if (value.IsScalar())
      {
        double number = 0.0;
        if (field != "id" && YAML::convert<double>::decode(value, number))
          fields.numbers[field] = {number};
        else
          fields.text[field] = value.as<std::string>();
        continue;
      }
      if (!value.IsSequence())
        rejectParameter(name + "." + field, "'" + shown(value) + "'", "must be " + colliderFieldExpected(field));
      std::vector<double> numbers;
      for (const YAML::Node& element : value)
      {
        double number = 0.0;
        if (!element.IsScalar() || !YAML::convert<double>::decode(element, number))
          rejectParameter(name + "." + field, "'" + shown(value) + "'", "must be " + colliderFieldExpected(field));
        numbers.push_back(number);
      }
      fields.numbers[field] = numbers;
    }
    colliders.push_back(colliderFromFields(fields, name));
  }
  return colliders;
}

}  // namespace modal_mass_spring
