// A ParameterSource over a ROS node handle, so the node reads the same parameter names as the tools.
#pragma once

#include "modal_mass_spring/parameters.h"

#include <ros/node_handle.h>

#include <set>
#include <string>

namespace modal_mass_spring
{

// Reads from the parameter server under the handle's namespace (the node passes its private handle).
// A present key of the wrong XmlRpc type throws std::invalid_argument naming the key, the expected
// type and the value found.
class RosParameterSource : public ParameterSource
{
public:
  explicit RosParameterSource(const ros::NodeHandle& nh) : nh_(nh) {}

  std::optional<int> getInt(const std::string& key) const override;
  std::optional<double> getDouble(const std::string& key) const override;
  std::optional<bool> getBool(const std::string& key) const override;
  std::optional<std::string> getString(const std::string& key) const override;
  std::optional<std::vector<int>> getIntList(const std::string& key) const override;
  std::optional<std::vector<double>> getDoubleList(const std::string& key) const override;

  // Every key a getter was asked for, so the node can warn about keys nobody reads (typos).
  const std::set<std::string>& queried() const { return queried_; }
  // Keys present under the namespace (first level below it) that were never asked for.
  std::vector<std::string> unqueried() const;

private:
  bool lookup(const std::string& key, XmlRpc::XmlRpcValue& value) const;

  ros::NodeHandle nh_;
  mutable std::set<std::string> queried_;
};

}  // namespace modal_mass_spring
