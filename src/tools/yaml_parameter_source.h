// A ParameterSource over a flat YAML map, so the tools read the node's parameter names from files.
#pragma once

#include "modal_mass_spring/parameters.h"

#include <yaml-cpp/yaml.h>

#include <optional>
#include <set>
#include <string>
#include <vector>

namespace modal_mass_spring
{

// The node's own parameters (README, "Parameters"): a config shared with the node holds them, and
// the tools ignore them without a warning.
extern const std::set<std::string> kNodeParameters;
// Keys only the tools read, in shapes of their own (modal_compare's handle_scenarios).
extern const std::set<std::string> kToolParameters;

// Scalars that came typed (the node's parameters, converted from the parameter server's XmlRpc values:
// xmlrpc_parameter_source.h) carry their type as a tag and are read as that type only, as the
// parameter server gives them; a string still stands for a number or a list where one is expected
// (rosrun's command line and YAML 1.1 hand `3.0e6` and `[0, 0, -9.81]` over as strings). A YAML
// file's scalars carry none of these tags and are read as whatever is asked.
extern const std::string kStringTag, kIntTag, kFloatTag, kBoolTag, kListTag, kMapTag, kOtherTag;

// One value as the getters read it, or nothing when it is not of that type.
std::optional<int> scalarInt(const YAML::Node& node);
std::optional<double> scalarNumber(const YAML::Node& node);  // integers too
std::optional<bool> scalarBool(const YAML::Node& node);
std::optional<std::string> scalarString(const YAML::Node& node);
// A list, or a typed string that is the YAML text of one (its scalars then typed strings).
std::optional<YAML::Node> listNode(const YAML::Node& node);
// The value as a message shows it: "'abc'" (a YAML file's, as written), "'abc' (a string)",
// "3 (an integer)", "a list of 2 values" (typed).
std::string describeValue(const YAML::Node& node);

// Keys the core does not ask for (the node's publish_rate, frame names, ...) are ignored, so one file
// serves the node and the tools; keys() and queried() tell which those were. A key given twice is
// refused (yaml-cpp would let the first one win silently).
class YamlParameterSource : public ParameterSource
{
public:
  // Throws std::invalid_argument naming the file when it cannot be read, is not YAML, is not a map or
  // gives a key twice.
  static YamlParameterSource fromFile(const std::string& path);
  // `origin` names the text in messages.
  static YamlParameterSource fromString(const std::string& text, const std::string& origin = "<string>");
  // Over a tree already built (a map; null counts as empty).
  static YamlParameterSource fromNode(YAML::Node root, const std::string& origin);

  // An independent copy (yaml-cpp nodes share their data when copied).
  YamlParameterSource clone() const;

  // Adds or replaces one key; `value` is read as YAML, so "30", "0.5", "[0, 4]" and "rest" all get
  // the type they would have in the file. Throws std::invalid_argument when it is not valid YAML.
  void set(const std::string& key, const std::string& value);

  const std::string& origin() const { return origin_; }

  // The top-level keys, in file order.
  std::vector<std::string> keys() const;

  // The keys that neither the core asked for (queried(), so after loadGridParams and
  // loadSimulationParams) nor the node (kNodeParameters) nor the tools (kToolParameters) read: most
  // likely misspelled.
  std::vector<std::string> unknownKeys() const;

  std::optional<int> getInt(const std::string& key) const override;
  std::optional<double> getDouble(const std::string& key) const override;
  std::optional<bool> getBool(const std::string& key) const override;
  std::optional<std::string> getString(const std::string& key) const override;
  std::optional<std::vector<int>> getIntList(const std::string& key) const override;
  std::optional<std::vector<double>> getDoubleList(const std::string& key) const override;
  std::optional<std::vector<std::string>> getStringList(const std::string& key) const;
  // The YAML of a key the tools read in a shape of their own (handle_scenarios); undefined when absent.
  YAML::Node getNode(const std::string& key) const { return lookup(key); }

  // Every key a getter was asked for: after loadGridParams/loadSimulationParams these are the names
  // the core knows, which tells a mistyped override from a real parameter.
  const std::set<std::string>& queried() const { return queried_; }

private:
  YamlParameterSource(YAML::Node root, std::string origin);
  // The root of a loaded text: a map (an empty text is an empty map) without a key given twice.
  static YAML::Node checkedRoot(YAML::Node root, const std::string& origin);
  // The node of a present key, or an undefined node; records the query.
  YAML::Node lookup(const std::string& key) const;
  template <typename T>
  std::optional<T> scalar(const std::string& key, const std::string& expected) const;
  // `example` shows a typed list's source how to give one.
  template <typename T>
  std::optional<std::vector<T>> list(const std::string& key, const std::string& expected,
                                     const std::string& example) const;

  YAML::Node root_;
  std::string origin_;
  mutable std::set<std::string> queried_;
};

}  // namespace modal_mass_spring
