// The node's private parameters, converted once from the parameter server's XmlRpc struct to the YAML
// tree the tools read, so that the node and the tools read every parameter with one set of getters
// (yaml_parameter_source.h) and the conversions can be tested without a ROS master.
#pragma once

#include "node_params.h"
#include "yaml_parameter_source.h"

#include <xmlrpcpp/XmlRpcValue.h>
#include <yaml-cpp/yaml.h>

#include <string>
#include <vector>

namespace modal_mass_spring
{

// The YAML tree of an XmlRpc value, each node tagged with its XmlRpc type (kIntTag, kStringTag, ...):
// the getters then accept what the parameter server's types allow, and no more.
YAML::Node toYaml(const XmlRpc::XmlRpcValue& value);

// `params` is what the parameter server returns for the node's private namespace: a struct of
// name -> value (anything else counts as no parameters). Strings stand in where rosparam and the
// rosrun command line leave them: a string that spells a whole number where a number is expected
// ("3.0e6", which YAML 1.1 reads as a string), and a string that is a YAML list where a list is
// expected (`_gravity:=[0,0,-9.81]`). Any other type mismatch throws std::invalid_argument naming the
// key, the expected type and the value found.
class XmlRpcParameterSource : public NodeParameterSource
{
public:
  explicit XmlRpcParameterSource(const XmlRpc::XmlRpcValue& params);

  std::optional<int> getInt(const std::string& key) const override { return yaml_.getInt(key); }
  std::optional<double> getDouble(const std::string& key) const override { return yaml_.getDouble(key); }
  std::optional<bool> getBool(const std::string& key) const override { return yaml_.getBool(key); }
  std::optional<std::string> getString(const std::string& key) const override { return yaml_.getString(key); }
  std::optional<std::vector<int>> getIntList(const std::string& key) const override { return yaml_.getIntList(key); }
  std::optional<std::vector<double>> getDoubleList(const std::string& key) const override
  {
    return yaml_.getDoubleList(key);
  }
  std::optional<std::vector<std::string>> getStringList(const std::string& key) const override
  {
    return yaml_.getStringList(key);
  }
  // From a list of structs, or from the YAML text of one (`_handles:='[{frame: f, particles: [0]}]'`).
  std::optional<std::vector<HandleParam>> getHandleList(const std::string& key) const override;
  // From a list of structs or the YAML text of one, as handles.
  std::optional<std::vector<Collider>> getColliderList(const std::string& key) const override;

  // Every key present (the first level below the namespace).
  std::vector<std::string> keys() const { return yaml_.keys(); }

private:
  YamlParameterSource yaml_;
};

}  // namespace modal_mass_spring
