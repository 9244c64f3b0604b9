// A ParameterSource over a flat YAML map, so the tools read the node's parameter names from files.
#pragma once

#include "modal_mass_spring/parameters.h"

#include <yaml-cpp/yaml.h>

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
  template <typename T>
  std::optional<std::vector<T>> list(const std::string& key, const std::string& expected) const;

  YAML::Node root_;
  std::string origin_;
  mutable std::set<std::string> queried_;
};

}  // namespace modal_mass_spring
