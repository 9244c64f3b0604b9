// A ParameterSource over the node's private parameters as one XmlRpc struct, so the node reads the same
// names as the tools and its conversions can be tested without a ROS master.
#pragma once

#include "node_params.h"

#include <xmlrpcpp/XmlRpcValue.h>

#include <string>
#include <vector>

namespace modal_mass_spring
{

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

  std::optional<int> getInt(const std::string& key) const override;
  std::optional<double> getDouble(const std::string& key) const override;
  std::optional<bool> getBool(const std::string& key) const override;
  std::optional<std::string> getString(const std::string& key) const override;
  std::optional<std::vector<int>> getIntList(const std::string& key) const override;
  std::optional<std::vector<double>> getDoubleList(const std::string& key) const override;
  std::optional<std::vector<std::string>> getStringList(const std::string& key) const override;
  // From a list of structs, or from the YAML text of one (`_handles:='[{frame: f, particles: [0]}]'`).
  std::optional<std::vector<HandleParam>> getHandleList(const std::string& key) const override;
  // From a list of structs or the YAML text of one, as handles.
  std::optional<std::vector<Collider>> getColliderList(const std::string& key) const override;

  // Every key present (the first level below the namespace).
  std::vector<std::string> keys() const;

private:
  const XmlRpc::XmlRpcValue* find(const std::string& key) const;

  XmlRpc::XmlRpcValue params_;
};

}  // namespace modal_mass_spring
