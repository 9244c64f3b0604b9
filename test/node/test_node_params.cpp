// The node's parameters without a ROS master: every range check of loadNodeParams, the order of the
// checks (all of them before anything is built), the unknown-key report, and the conversions of
// the XmlRpc source (numbers and lists given as text).
#include "collider_frames.h"
#include "handle_frames.h"
#include "node_params.h"
#include "parameter_values.h"
#include "xmlrpc_parameter_source.h"
#include "yaml_parameter_source.h"

#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>

#include <filesystem>
#include <functional>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <set>
#include <stdexcept>
#include <cstdlib>
#include <string>
#include <variant>
#include <vector>

namespace
{

using namespace modal_mass_spring;

using Value = std::variant<int, double, bool, std::string, std::vector<int>, std::vector<double>, std::vector<std::string>,
                           std::vector<HandleParam>>;

// Parameters as the parameter server would hold them, without one.
class FakeSource : public NodeParameterSource
{
public:
  FakeSource(std::map<std::string, Value> values = {}) : values_(std::move(values)) {}

  std::optional<int> getInt(const std::string& key) const override { return get<int>(key, "an integer"); }
  std::optional<double> getDouble(const std::string& key) const override
  {
    asked_.insert(key);
    const auto it = values_.find(key);
    if (it != values_.end() && std::holds_alternative<int>(it->second))
      return std::get<int>(it->second);
    return get<double>(key, "a number");
  }
  std::optional<bool> getBool(const std::string& key) const override { return get<bool>(key, "true or false"); }
  std::optional<std::string> getString(const std::string& key) const override { return get<std::string>(key, "a string"); }
  std::optional<std::vector<int>> getIntList(const std::string& key) const override
  {
    return get<std::vector<int>>(key, "a list of integers");
  }
  std::optional<std::vector<double>> getDoubleList(const std::string& key) const override
  {
    return get<std::vector<double>>(key, "a list of numbers");
  }

  std::optional<std::vector<std::string>> getStringList(const std::string& key) const override
  {
    return get<std::vector<std::string>>(key, "a list of names");
  }
  std::optional<std::vector<HandleParam>> getHandleList(const std::string& key) const override
  {
    return get<std::vector<HandleParam>>(key, "a list of maps");
  }

  std::vector<std::string> keys() const
  {
    std::vector<std::string> names;
    for (const auto& entry : values_)
      names.push_back(entry.first);
    return names;
  }
  // Every key a getter was asked for.
  const std::set<std::string>& asked() const { return asked_; }

private:
  template <typename T>
  std::optional<T> get(const std::string& key, const std::string& expected) const
  {
    asked_.insert(key);
    const auto it = values_.find(key);
    if (it == values_.end())
      return std::nullopt;
    if (!std::holds_alternative<T>(it->second))
      throw std::invalid_argument(wrongType(key, expected));
    return std::get<T>(it->second);
  }
  std::map<std::string, Value> values_;
  mutable std::set<std::string> asked_;
};

// The message of the std::invalid_argument that loading `values` throws, or "" when it loads.
std::string refusal(const std::map<std::string, Value>& values)
{
  const FakeSource source(values);
  try
  {
    loadNodeConfiguration(source, source.keys());
  }
  catch (const std::invalid_argument& error)
  {
    return error.what();
  }
  return "";
}

const double kNaN = std::numeric_limits<double>::quiet_NaN();
const double kInf = std::numeric_limits<double>::infinity();

TEST(NodeParams, DefaultsOnThePaperGrid)
{
  const FakeSource source;
  const NodeConfiguration c = loadNodeConfiguration(source, source.keys());
  EXPECT_EQ(c.node.tf_particles, (std::vector<int>{20, 24}));  // the bottom corners of 5 x 5
  EXPECT_DOUBLE_EQ(c.node.particle_diameter, 0.3 * 0.1);
  EXPECT_DOUBLE_EQ(c.node.spring_width, 0.06 * 0.1);
  EXPECT_DOUBLE_EQ(c.node.publish_rate, 30.0);
  EXPECT_DOUBLE_EQ(c.node.diagnostic_period, 1.0);
  EXPECT_EQ(c.node.fixed_frame, "world");
  EXPECT_EQ(c.node.grid_frame, "grid");
  EXPECT_TRUE(c.unknown_keys.empty());
}

// The cache is under $ROS_HOME, else ~/.ros, and off when cache_dir is empty.
TEST(NodeParams, CacheDirDefaultsUnderRosHomeAndEmptyTurnsItOff)
{
  const char* saved = std::getenv("ROS_HOME");
  const std::string saved_value = saved ? saved : "";
  setenv("ROS_HOME", "/tmp/some_ros_home", 1);
  const FakeSource defaults;
  EXPECT_EQ(loadNodeConfiguration(defaults, defaults.keys()).node.cache_dir, "/tmp/some_ros_home/modal_mass_spring");
  unsetenv("ROS_HOME");
  EXPECT_EQ(loadNodeConfiguration(defaults, defaults.keys()).node.cache_dir,
            std::string(std::getenv("HOME")) + "/.ros/modal_mass_spring");
  if (saved)
    setenv("ROS_HOME", saved_value.c_str(), 1);
  const FakeSource off({{"cache_dir", std::string()}});
  EXPECT_EQ(loadNodeConfiguration(off, off.keys()).node.cache_dir, "");
  const FakeSource elsewhere({{"cache_dir", std::string("/var/cache/cloth")}});
  EXPECT_EQ(loadNodeConfiguration(elsewhere, elsewhere.keys()).node.cache_dir, "/var/cache/cloth");
}

// Particles and springs are sent up to detail_max_particles particles, and above unless told not to.
TEST(NodeParams, ParticlesAndSpringsAreOffByDefaultAboveTheDetailSize)
{
  const FakeSource small({{"rows", 50}, {"cols", 50}});
  const NodeParams a = loadNodeConfiguration(small, small.keys()).node;
  EXPECT_TRUE(a.show_particles && a.show_springs && a.show_surface);
  const FakeSource large({{"rows", 50}, {"cols", 51}});
  const NodeParams b = loadNodeConfiguration(large, large.keys()).node;
  EXPECT_FALSE(b.show_particles || b.show_springs);
  EXPECT_TRUE(b.show_surface);
  const FakeSource asked({{"rows", 50}, {"cols", 51}, {"show_springs", true}, {"detail_max_particles", 0}});
  const NodeParams c = loadNodeConfiguration(asked, asked.keys()).node;
  EXPECT_TRUE(c.show_springs);
  EXPECT_FALSE(c.show_particles);
}

// A comparison is centred on offset, method_spacing apart along x, in the order listed.
TEST(NodeParams, ComparedMethodsAreDrawnSideBySide)
{
  const FakeSource source({{"methods", std::vector<std::string>{"linear", "full", "physical"}},
                           {"offset", std::vector<double>{0.0, 1.0, 2.0}}});
  const NodeParams p = loadNodeConfiguration(source, source.keys()).node;
  ASSERT_EQ(p.methods, (std::vector<Method>{Method::Linear, Method::Full, Method::Physical}));
  EXPECT_DOUBLE_EQ(p.method_spacing, 0.7) << "paper grid: its width 0.4 m plus three spacings";
  EXPECT_TRUE(methodOffset(p, 0).isApprox(Eigen::Vector3d(-0.7, 1.0, 2.0)));
  EXPECT_TRUE(methodOffset(p, 1).isApprox(Eigen::Vector3d(0.0, 1.0, 2.0)));
  EXPECT_TRUE(methodOffset(p, 2).isApprox(Eigen::Vector3d(0.7, 1.0, 2.0)));
  // Every method the core names can be compared.
  const FakeSource all({{"methods", methodNames()}});
  EXPECT_EQ(loadNodeConfiguration(all, all.keys()).node.methods.size(), methodNames().size());
}

TEST(NodeParams, ValuesAtTheEndsOfTheirRangesLoad)
{
  const FakeSource source({{"publish_rate", 1000.0},
                           {"real_time_factor", 1000.0},
                           {"time_step", 0.01},
                           {"status_log_period", 0},
                           {"diagnostic_period", 3600.0},
                           {"offset", std::vector<double>{-1e6, 0.0, 1e6}},
                           {"tf_particles", std::vector<int>{}},
                           {"color_by_strain", false}});
  const NodeParams p = loadNodeConfiguration(source, source.keys()).node;
  EXPECT_DOUBLE_EQ(p.publish_rate, 1000.0);
  EXPECT_DOUBLE_EQ(p.real_time_factor, 1000.0);
  EXPECT_DOUBLE_EQ(p.status_log_period, 0.0);
  EXPECT_DOUBLE_EQ(p.diagnostic_period, 3600.0);
  EXPECT_EQ(p.offset, Eigen::Vector3d(-1e6, 0.0, 1e6));
  EXPECT_TRUE(p.tf_particles.empty());
  EXPECT_FALSE(p.color_by_strain);
}

struct BadCase
{
  std::map<std::string, Value> values;
  std::string expected;  // the start of the message: the parameter and its value
};

TEST(NodeParams, EveryNodeParameterHasARangeCheck)
{
  const std::vector<BadCase> cases{
      {{{"real_time_factor", 0.0}}, "invalid parameter 'real_time_factor' = 0: must be a number > 0 and <= 1000"},
      {{{"real_time_factor", -1.0}}, "invalid parameter 'real_time_factor' = -1"},
      {{{"real_time_factor", 1000.5}}, "invalid parameter 'real_time_factor' = 1000.5"},
      {{{"real_time_factor", kNaN}}, "invalid parameter 'real_time_factor' = nan"},
      {{{"real_time_factor", 500.0}, {"publish_rate", 1.0}},
       "invalid parameter 'real_time_factor, publish_rate, time_step' = real_time_factor 500, publish_rate 1 Hz, "
       "time_step 0.001 s: give real_time_factor / (publish_rate * time_step) = 500000"},
      {{{"time_step", 1e-300}}, "invalid parameter 'real_time_factor, publish_rate, time_step' = real_time_factor 1, "
                                "publish_rate 30 Hz, time_step 1e-300 s"},
      {{{"publish_rate", 0.0}}, "invalid parameter 'publish_rate' = 0: must be a number > 0 and <= 1000 Hz"},
      {{{"publish_rate", -5}}, "invalid parameter 'publish_rate' = -5"},
      {{{"publish_rate", 2000.0}}, "invalid parameter 'publish_rate' = 2000"},
      {{{"publish_rate", kInf}}, "invalid parameter 'publish_rate' = inf"},
      {{{"fixed_frame", std::string()}}, "invalid parameter 'fixed_frame' = '': must be a non-empty frame id"},
      {{{"fixed_frame", std::string("/world")}}, "invalid parameter 'fixed_frame' = '/world'"},
      {{{"grid_frame", std::string("my grid")}}, "invalid parameter 'grid_frame' = 'my grid'"},
      {{{"grid_frame", std::string("world")}}, "invalid parameter 'grid_frame' = 'world': must differ from fixed_frame"},
      {{{"tf_particles", std::vector<int>{25}}}, "invalid parameter 'tf_particles' = 25: particle indices must be in [0, 24]"},
      {{{"tf_particles", std::vector<int>{-1}}}, "invalid parameter 'tf_particles' = -1"},
      {{{"tf_particles", std::vector<int>{3, 3}}}, "invalid parameter 'tf_particles' = 3: each particle index must be listed once"},
      {{{"offset", std::vector<double>{1.0, 2.0}}}, "invalid parameter 'offset' = 2 values: must be a list of 3 numbers"},
      {{{"offset", std::vector<double>{0.0, kNaN, 0.0}}}, "invalid parameter 'offset' = nan"},
      {{{"offset", std::vector<double>{0.0, 0.0, 2e6}}}, "invalid parameter 'offset' = 2e+06"},
      {{{"strain_scale", 0.0}}, "invalid parameter 'strain_scale' = 0: must be a number > 0"},
      {{{"particle_diameter", -0.1}}, "invalid parameter 'particle_diameter' = -0.1"},
      {{{"spring_width", 0.0}}, "invalid parameter 'spring_width' = 0"},
      {{{"spring_width", 1e7}}, "invalid parameter 'spring_width' = 1e+07"},
      {{{"status_log_period", -1.0}}, "invalid parameter 'status_log_period' = -1: must be a number >= 0"},
      {{{"status_log_period", kInf}}, "invalid parameter 'status_log_period' = inf"},
      {{{"diagnostic_period", -1.0}}, "invalid parameter 'diagnostic_period' = -1: must be a number > 0 and <= 3600 s"},
      {{{"diagnostic_period", 0}}, "invalid parameter 'diagnostic_period' = 0"},
      {{{"detail_max_particles", -1}}, "invalid parameter 'detail_max_particles' = -1: must be an integer in [0, 10000000]"},
      {{{"surface_max_cells", 0}}, "invalid parameter 'surface_max_cells' = 0: must be an integer in [1, 1000000]"},
      {{{"surface_max_cells", 2000000}}, "invalid parameter 'surface_max_cells' = 2000000"},
      {{{"show_surface", 1}}, "invalid parameter 'show_surface': wrong type, must be true or false"},
      {{{"show_springs", std::string("no")}}, "invalid parameter 'show_springs': wrong type"},
      {{{"methods", std::vector<std::string>{}}}, "invalid parameter 'methods' = 0 names: must list 1 to"},
      {{{"methods", std::vector<std::string>{"linear", "bogus"}}}, "invalid parameter 'methods' = 'bogus': each must be one of full, linear, physical"},
      {{{"methods", std::vector<std::string>{"full", "full"}}}, "invalid parameter 'methods' = 'full': each method must be listed once"},
      {{{"method_spacing", 0.0}}, "invalid parameter 'method_spacing' = 0: must be a number > 0"},
      {{{"method_spacing", kNaN}}, "invalid parameter 'method_spacing' = nan"},
      {{{"methods", std::vector<std::string>{"linear", "full"}}, {"shadow_full", true}}, "invalid parameter 'shadow_full' = true: must be false when methods is set"},
      {{{"show_labels", 1}}, "invalid parameter 'show_labels': wrong type"},
      {{{"show_shadow", std::string("yes")}}, "invalid parameter 'show_shadow': wrong type"},
      {{{"methods", std::string("full")}}, "invalid parameter 'methods': wrong type, must be a list of names"},
      {{{"rollout_threads", 0}}, "invalid parameter 'rollout_threads' = 0: must be an integer in [1, 64]"},
      {{{"rollout_max_horizon", 0.0}}, "invalid parameter 'rollout_max_horizon' = 0: must be a number > 0 and <= 3600 s"},
      {{{"rollout_max_horizon", kNaN}}, "invalid parameter 'rollout_max_horizon' = nan"},
      {{{"rollout_max_candidates", 0}}, "invalid parameter 'rollout_max_candidates' = 0: must be an integer in [1, 100000]"},
      // Wrong types: the source names the key.
      {{{"color_by_strain", 1}}, "invalid parameter 'color_by_strain': wrong type, must be true or false"},
      {{{"fixed_frame", 3}}, "invalid parameter 'fixed_frame': wrong type, must be a string"},
      {{{"tf_particles", std::vector<double>{1.5}}}, "invalid parameter 'tf_particles': wrong type, must be a list of integers"},
      {{{"publish_rate", std::string("fast")}}, "invalid parameter 'publish_rate': wrong type, must be a number"},
  };
  for (const auto& c : cases)
  {
    const std::string message = refusal(c.values);
    EXPECT_EQ(message.substr(0, c.expected.size()), c.expected) << "got: " << message;
  }
}

// The core's checks come first (the node's rely on a valid grid), and all of them come before anything
// is built: a bad node parameter on a grid whose basis would take minutes fails in no time, which
// here means loading returns at all, since it builds nothing.
TEST(NodeParams, CoreParametersAreCheckedFirst)
{
  EXPECT_EQ(refusal({{"rows", 0}, {"publish_rate", -1.0}}).rfind("invalid parameter 'rows' = 0", 0), 0u);
  EXPECT_EQ(refusal({{"method", std::string("bogus")}}).rfind("invalid parameter 'method' = 'bogus'", 0), 0u);
  EXPECT_EQ(refusal({{"time_step", -1.0}, {"real_time_factor", 2000.0}}).rfind("invalid parameter 'time_step'", 0), 0u);
}

// `method: adaptive` runs adaptive_method through the adaptive stepper; its refusal lists it.
TEST(NodeParams, MethodAdaptiveRunsTheAdaptiveMethod)
{
  const SimulationParams p = loadSimulationParams(FakeSource({{"method", std::string("adaptive")},
                                                              {"adaptive_method", std::string("physical")}}));
  EXPECT_TRUE(p.adaptive);
  EXPECT_EQ(p.method, Method::Physical);
  EXPECT_FALSE(loadSimulationParams(FakeSource({{"method", std::string("cubature")}})).adaptive);
  EXPECT_EQ(refusal({{"method", std::string("adaptiv")}}),
            "invalid parameter 'method' = 'adaptiv': must be one of full, linear, physical, cubature, coarse, adaptive");
  EXPECT_EQ(refusal({{"method", std::string("adaptive")}, {"error_tolerance", 0.0}}).rfind("invalid parameter 'error_tolerance' = 0", 0), 0u);
}

TEST(NodeParams, HugeGridWithABadNodeParameterNamesTheNodeParameter)
{
  const std::map<std::string, Value> huge{{"rows", 600}, {"cols", 600}, {"dimension", 3}, {"num_modes", 30},
                                          {"linearization", std::string("equilibrium")}};
  EXPECT_EQ(refusal(huge), "") << "the grid itself must be valid for this test";
  auto bad_tf = huge;
  bad_tf["tf_particles"] = std::vector<int>{360000};
  EXPECT_EQ(refusal(bad_tf).rfind("invalid parameter 'tf_particles' = 360000: particle indices must be in [0, 359999]", 0), 0u)
      << refusal(bad_tf);
  auto bad_rate = huge;
  bad_rate["publish_rate"] = -1.0;
  EXPECT_EQ(refusal(bad_rate).rfind("invalid parameter 'publish_rate' = -1", 0), 0u) << refusal(bad_rate);
}

TEST(NodeParams, UnknownKeysAreReportedAndKnownOnesAreNot)
{
  // Every key of a shipped config, plus the node's keys the configs leave out.
  const FakeSource source({{"rows", 5}, {"cols", 5}, {"spacing", 0.1}, {"dimension", 2}, {"mass", 0.01},
                           {"structural_stiffness", 10.0}, {"shear_stiffness", 5.0}, {"bending", false},
                           {"bending_stiffness", 1.0}, {"fixed", std::vector<int>{}},
                           {"gravity", std::vector<double>{0.0, 0.0, -9.81}}, {"rotation_deg", 0.0},
                           {"method", std::string("physical")}, {"num_modes", 4}, {"alpha", 0.0}, {"beta", 0.0},
                           {"time_step", 0.001}, {"divergence_limit", 0.0}, {"linearization", std::string("rest")},
                           {"integrator", std::string("explicit")}, {"initial_state", std::string("initial")},
                           {"newton_max_iterations", 50}, {"memory_limit_gb", 12.0},
                           {"basis", std::string("linear_modes")}, {"num_derivative_modes", 0},
                           {"cubature_tolerance", 0.01}, {"cubature_max_springs", 0}, {"cubature_training_poses", 100},
                           {"cubature_max_training_poses", 0}, {"cubature_pose_size", 0.4}, {"cubature_seed", 1}, {"real_time_factor", 1.0},
                           {"publish_rate", 30.0}, {"fixed_frame", std::string("world")},
                           {"grid_frame", std::string("grid")}, {"tf_particles", std::vector<int>{20, 24}},
                           {"offset", std::vector<double>{0.0, 0.0, 0.0}}, {"color_by_strain", true},
                           {"strain_scale", 0.1}, {"particle_diameter", 0.03}, {"spring_width", 0.006},
                           {"status_log_period", 5.0}, {"diagnostic_period", 1.0}});
  EXPECT_EQ(loadNodeConfiguration(source, source.keys()).unknown_keys, std::vector<std::string>{});

  const FakeSource typos({{"publish_rat", 10.0}, {"rows", 6}, {"num_mode", 3}});
  EXPECT_EQ(loadNodeConfiguration(typos, typos.keys()).unknown_keys, (std::vector<std::string>{"num_mode", "publish_rat"}));
}

// ---------------------------------------------------------------- numbers and lists as text

TEST(ParameterValues, NumbersSpelledByTheWholeString)
{
  EXPECT_EQ(parseNumber("3.0e6"), 3.0e6);
  EXPECT_EQ(parseNumber(" -1e-3 "), -1e-3);
  EXPECT_EQ(parseNumber("5"), 5.0);
  EXPECT_FALSE(parseNumber("ten"));
  EXPECT_FALSE(parseNumber("3.0e6m"));
  EXPECT_FALSE(parseNumber(""));
  EXPECT_FALSE(parseNumber("1e999")) << "overflow is not a number written";
  EXPECT_EQ(parseInteger("20"), 20);
  EXPECT_FALSE(parseInteger("2.5"));
  EXPECT_FALSE(parseInteger("99999999999"));
}

TEST(ParameterValues, ListsAsYamlText)
{
  EXPECT_EQ(parseListText("[0,0,-9.81]"), (std::vector<std::string>{"0", "0", "-9.81"}));
  EXPECT_EQ(parseListText("[]"), std::vector<std::string>{});
  EXPECT_FALSE(parseListText("[0, 0"));
  EXPECT_FALSE(parseListText("0.5"));
  EXPECT_FALSE(parseListText("[[1], 2]"));
}

XmlRpc::XmlRpcValue params(const std::map<std::string, XmlRpc::XmlRpcValue>& values)
{
  XmlRpc::XmlRpcValue p;
  p.begin();  // an empty struct, not an invalid value
  for (const auto& entry : values)
    p[entry.first] = entry.second;
  return p;
}

XmlRpc::XmlRpcValue array(const std::vector<XmlRpc::XmlRpcValue>& items)
{
  XmlRpc::XmlRpcValue a;
  a.setSize(static_cast<int>(items.size()));
  for (size_t k = 0; k < items.size(); ++k)
    a[static_cast<int>(k)] = items[k];
  return a;
}

std::string thrown(const std::function<void()>& f)
{
  try
  {
    f();
  }
  catch (const std::invalid_argument& error)
  {
    return error.what();
  }
  return "";
}

TEST(XmlRpcParameterSource, AStringThatIsANumberIsANumber)
{
  const XmlRpcParameterSource source(params({{"structural_stiffness", XmlRpc::XmlRpcValue("3.0e6")},
                                             {"rows", XmlRpc::XmlRpcValue("20")},
                                             {"spacing", XmlRpc::XmlRpcValue("ten")},
                                             {"cols", XmlRpc::XmlRpcValue("2.5")},
                                             {"mass", XmlRpc::XmlRpcValue(2)}}));
  EXPECT_EQ(source.getDouble("structural_stiffness"), 3.0e6);
  EXPECT_EQ(source.getInt("rows"), 20);
  EXPECT_EQ(source.getDouble("mass"), 2.0);
  EXPECT_EQ(thrown([&] { source.getDouble("spacing"); }),
            "invalid parameter 'spacing': wrong type, must be a number, got 'ten' (a string)");
  EXPECT_EQ(thrown([&] { source.getInt("cols"); }),
            "invalid parameter 'cols': wrong type, must be an integer, got '2.5' (a string)");
  EXPECT_FALSE(source.getDouble("alpha"));
}

TEST(XmlRpcParameterSource, AStringThatIsAYamlListIsAList)
{
  const XmlRpcParameterSource source(
      params({{"gravity", XmlRpc::XmlRpcValue("[0,0,-9.81]")},
              {"tf_particles", XmlRpc::XmlRpcValue("[20, 24]")},
              {"offset", array({XmlRpc::XmlRpcValue(1), XmlRpc::XmlRpcValue("3.0e6"), XmlRpc::XmlRpcValue(0.5)})},
              {"fixed", XmlRpc::XmlRpcValue("[0, 1")},
              {"bad_items", XmlRpc::XmlRpcValue("[0, x, 1]")},
              {"scalar", XmlRpc::XmlRpcValue(4.0)}}));
  EXPECT_EQ(source.getDoubleList("gravity"), (std::vector<double>{0.0, 0.0, -9.81}));
  EXPECT_EQ(source.getIntList("tf_particles"), (std::vector<int>{20, 24}));
  EXPECT_EQ(source.getDoubleList("offset"), (std::vector<double>{1.0, 3.0e6, 0.5}));
  const std::string unparsed = thrown([&] { source.getIntList("fixed"); });
  EXPECT_EQ(unparsed.rfind("invalid parameter 'fixed': wrong type, must be a list of integers", 0), 0u) << unparsed;
  EXPECT_NE(unparsed.find("_fixed:='[20, 24]'"), std::string::npos) << "says how to give a list: " << unparsed;
  EXPECT_NE(thrown([&] { source.getDoubleList("bad_items"); }).find("element 1 is 'x' (a string)"), std::string::npos);
  EXPECT_NE(thrown([&] { source.getDoubleList("scalar"); }).find("got 4 (a floating-point number)"), std::string::npos);
}

TEST(XmlRpcParameterSource, OtherTypesAreRefusedAndKeysListed)
{
  const XmlRpcParameterSource source(params({{"bending", XmlRpc::XmlRpcValue("true")},
                                             {"method", XmlRpc::XmlRpcValue(1)},
                                             {"publish_rat", XmlRpc::XmlRpcValue(10.0)}}));
  EXPECT_EQ(thrown([&] { source.getBool("bending"); }),
            "invalid parameter 'bending': wrong type, must be true or false, got 'true' (a string)");
  EXPECT_EQ(thrown([&] { source.getString("method"); }),
            "invalid parameter 'method': wrong type, must be a string, got 1 (an integer)");
  EXPECT_EQ(source.keys(), (std::vector<std::string>{"bending", "method", "publish_rat"}));
  EXPECT_TRUE(XmlRpcParameterSource(XmlRpc::XmlRpcValue()).keys().empty()) << "no parameters at all";
}

// The whole path of the node without a master: a typo is reported, a number as text is read.
TEST(XmlRpcParameterSource, FeedsTheNodeConfiguration)
{
  const XmlRpcParameterSource source(params({{"structural_stiffness", XmlRpc::XmlRpcValue("3.0e3")},
                                             {"gravity", XmlRpc::XmlRpcValue("[0, 0, -1]")},
                                             {"publsh_rate", XmlRpc::XmlRpcValue(10.0)}}));
  const NodeConfiguration c = loadNodeConfiguration(source, source.keys());
  EXPECT_EQ(c.grid.structural_stiffness, 3.0e3);
  EXPECT_EQ(c.grid.gravity, Eigen::Vector3d(0.0, 0.0, -1.0));
  EXPECT_EQ(c.unknown_keys, std::vector<std::string>{"publsh_rate"});
}

// Handles: the frames are checked by the node, the particle groups by the core, each message naming
// the handle; a good list reaches GridParams::handles (and no top row is fixed by default then).
TEST(NodeParams, HandlesAreCheckedAndReachTheGrid)
{
  const auto handles = [](std::vector<HandleParam> list) {
    return std::map<std::string, Value>{{"handles", Value(list)}};
  };
  const FakeSource good(handles({{"gripper", {0, 4}}, {"finger", {2}}}));
  const NodeConfiguration c = loadNodeConfiguration(good, good.keys());
  EXPECT_EQ(c.grid.handles, (std::vector<std::vector<int>>{{0, 4}, {2}}));
  ASSERT_EQ(c.node.handles.size(), 2u);
  EXPECT_EQ(c.node.handles[1].frame, "finger");
  EXPECT_TRUE(c.unknown_keys.empty());

  EXPECT_EQ(refusal(handles({{"gripper", {0}}, {"finger", {25}}})),
            "invalid parameter 'handles[1]' = 25: particle indices must be in [0, 24] (row * cols + col)");
  EXPECT_EQ(refusal(handles({{"gripper", {0, 1}}, {"finger", {1}}})),
            "invalid parameter 'handles[1]' = 1: a particle may be in one handle only (it is also in handles[0])");
  auto fixed = handles({{"gripper", {0, 1}}});
  fixed["fixed"] = std::vector<int>{1};
  EXPECT_EQ(refusal(fixed), "invalid parameter 'handles[0]' = 1: a handle particle may not also be fixed");
  EXPECT_EQ(refusal(handles({{"gripper", {0}}, {"", {1}}})),
            "invalid parameter 'handles[1].frame' = '': must be a non-empty frame id without a leading '/' or spaces");
  EXPECT_EQ(refusal(handles({{"/gripper", {0}}})),
            "invalid parameter 'handles[0].frame' = '/gripper': must be a non-empty frame id without a leading '/' or "
            "spaces");
  EXPECT_EQ(refusal(handles({{"gripper", {}}})), "invalid parameter 'handles[0]' = []: a handle must hold at least one particle");
  EXPECT_NE(refusal(handles({{"world", {0}}})).find("invalid parameter 'handles[0].frame' = 'world': a handle's frame must differ"),
            std::string::npos);
}

// handle_formulation: the node tells the core whether every handle is on one frame (one rigid
// body); moving_frame with handles on two frames is refused naming them.
TEST(NodeParams, HandlesOnOneFrameAreOneBody)
{
  auto config = [](std::vector<HandleParam> list, const std::string& formulation) {
    std::map<std::string, Value> values{{"handles", Value(list)}, {"fixed", std::vector<int>{}}};
    if (!formulation.empty())
      values["handle_formulation"] = formulation;
    return values;
  };
  const FakeSource one(config({{"gripper", {0, 1}}, {"gripper", {3}}}, ""));
  const NodeConfiguration c = loadNodeConfiguration(one, one.keys());
  EXPECT_TRUE(c.simulation.handles_one_body);
  EXPECT_EQ(c.simulation.handle_formulation, HandleFormulation::Auto);
  EXPECT_EQ(resolveHandleFormulation(c.grid, c.simulation), HandleFormulation::MovingFrame);
  EXPECT_EQ(handleFrames(c.node.handles), std::vector<std::string>{"gripper"});
  const FakeSource two(config({{"gripper", {0, 1}}, {"finger", {3}}}, "auto"));
  const NodeConfiguration d = loadNodeConfiguration(two, two.keys());
  EXPECT_FALSE(d.simulation.handles_one_body);
  EXPECT_EQ(resolveHandleFormulation(d.grid, d.simulation), HandleFormulation::ConstraintModes);
  const FakeSource asked(config({{"gripper", {0, 1}}}, "constraint_modes"));
  EXPECT_EQ(loadNodeConfiguration(asked, asked.keys()).simulation.handle_formulation,
            HandleFormulation::ConstraintModes);

  EXPECT_EQ(refusal(config({{"gripper", {0, 1}}, {"finger", {3}}}, "moving_frame")),
            "invalid parameter 'handle_formulation' = moving_frame: needs every handle on one TF frame (one rigid "
            "body), but the handles name 2 frames: 'gripper', 'finger'; use auto or constraint_modes for handles "
            "that move apart");
  auto fixed = config({{"gripper", {0, 1}}}, "moving_frame");
  fixed["fixed"] = std::vector<int>{4};
  EXPECT_NE(refusal(fixed).find("invalid parameter 'handle_formulation' = moving_frame: needs a grid with no fixed "
                                "particles (it has 1)"),
            std::string::npos);
  EXPECT_EQ(refusal(config({{"gripper", {0}}}, "frame")),
            "invalid parameter 'handle_formulation' = 'frame': must be one of auto, constraint_modes, moving_frame");
}

// `handles` from the parameter server (a list of structs) or from the command line (YAML text),
// and every other shape refused naming the element.
TEST(XmlRpcParameterSource, HandlesAsListsOfMapsOrTheirText)
{
  XmlRpc::XmlRpcValue handle;
  handle["frame"] = "gripper";
  handle["particles"] = array({XmlRpc::XmlRpcValue(0), XmlRpc::XmlRpcValue(4)});
  XmlRpc::XmlRpcValue no_frame;
  no_frame["particles"] = array({XmlRpc::XmlRpcValue(1)});
  XmlRpc::XmlRpcValue extra = handle;
  extra["pose"] = 1;
  XmlRpc::XmlRpcValue numeric_frame = handle;
  numeric_frame["frame"] = 3;
  const XmlRpcParameterSource source(
      params({{"list", array({handle})},
              {"text", XmlRpc::XmlRpcValue("[{frame: gripper, particles: [0, 4]}, {frame: finger, particles: [2]}]")},
              {"not_a_list", XmlRpc::XmlRpcValue(3)},
              {"not_maps", array({XmlRpc::XmlRpcValue(0), XmlRpc::XmlRpcValue(4)})},
              {"bad_text", XmlRpc::XmlRpcValue("[{frame: gripper, particles: [0, 4]")},
              {"no_frame", array({handle, no_frame})},
              {"extra", array({extra})},
              {"numeric_frame", array({numeric_frame})},
              {"bad_particles", XmlRpc::XmlRpcValue("[{frame: f, particles: [0, x]}]")}}));
  const auto list = source.getHandleList("list");
  ASSERT_TRUE(list && list->size() == 1u);
  EXPECT_EQ((*list)[0].frame, "gripper");
  EXPECT_EQ((*list)[0].particles, (std::vector<int>{0, 4}));
  const auto text = source.getHandleList("text");
  ASSERT_TRUE(text && text->size() == 2u);
  EXPECT_EQ((*text)[1].frame, "finger");
  EXPECT_EQ((*text)[1].particles, std::vector<int>{2});
  EXPECT_FALSE(source.getHandleList("absent"));

  const std::string expected = "wrong type, must be a list of maps {frame: <tf frame>, particles: [indices]}";
  EXPECT_EQ(thrown([&] { source.getHandleList("not_a_list"); }).rfind("invalid parameter 'not_a_list': " + expected, 0), 0u);
  EXPECT_EQ(thrown([&] { source.getHandleList("bad_text"); }).rfind("invalid parameter 'bad_text': " + expected, 0), 0u);
  EXPECT_EQ(thrown([&] { source.getHandleList("not_maps"); }),
            "invalid parameter 'not_maps[0]': wrong type, must be a map {frame: <tf frame>, particles: [indices]}, got 0 "
            "(an integer)");
  EXPECT_EQ(thrown([&] { source.getHandleList("no_frame"); }),
            "invalid parameter 'no_frame[1]': wrong type, must be a map with both keys frame and particles, got no frame");
  EXPECT_EQ(thrown([&] { source.getHandleList("extra"); }),
            "invalid parameter 'extra[0]': wrong type, must be a map with the keys frame and particles only, got the key "
            "'pose'");
  EXPECT_EQ(thrown([&] { source.getHandleList("numeric_frame"); }),
            "invalid parameter 'numeric_frame[0].frame': wrong type, must be a string (a tf frame id), got 3 (an integer)");
  EXPECT_NE(thrown([&] { source.getHandleList("bad_particles"); })
                .find("invalid parameter 'bad_particles[0].particles': wrong type, must be a list of integers"),
            std::string::npos);
}

TEST(XmlRpcParameterSource, CollidersAsListsOfMapsOrTheirText)
{
  XmlRpc::XmlRpcValue sphere;
  sphere["type"] = "sphere";
  sphere["center"] = array({XmlRpc::XmlRpcValue(0.0), XmlRpc::XmlRpcValue(1), XmlRpc::XmlRpcValue(-0.5)});
  sphere["radius"] = 0.1;
  XmlRpc::XmlRpcValue negative = sphere;
  negative["radius"] = -0.1;
  XmlRpc::XmlRpcValue unknown = sphere;
  unknown["colour"] = "red";
  XmlRpc::XmlRpcValue on_frame = sphere, numeric_frame = sphere, empty_frame = sphere;
  on_frame["frame"] = "finger";
  numeric_frame["frame"] = 3;
  empty_frame["frame"] = "";
  const XmlRpcParameterSource source(
      params({{"list", array({sphere})},
              {"on_frame", array({on_frame})},
              {"numeric_frame", array({numeric_frame})},
              {"empty_frame", array({empty_frame})},
              {"text", XmlRpc::XmlRpcValue("[{type: plane, point: [0, 0, 0], normal: [0, 0, 1], friction: 0.3}]")},
              {"negative", array({negative})},
              {"unknown", array({unknown})},
              {"not_a_list", XmlRpc::XmlRpcValue(3)}}));
  const auto list = source.getColliderList("list");
  ASSERT_TRUE(list && list->size() == 1u);
  EXPECT_EQ((*list)[0].type, ColliderType::Sphere);
  EXPECT_TRUE((*list)[0].center.isApprox(Eigen::Vector3d(0.0, 1.0, -0.5)));
  const auto text = source.getColliderList("text");
  ASSERT_TRUE(text && text->size() == 1u);
  EXPECT_DOUBLE_EQ((*text)[0].friction, 0.3);
  EXPECT_FALSE(source.getColliderList("absent"));
  EXPECT_NE(thrown([&] { source.getColliderList("negative"); }).find("'negative[0].radius'"), std::string::npos);
  EXPECT_NE(thrown([&] { source.getColliderList("unknown"); }).find("'unknown[0].colour'"), std::string::npos);
  EXPECT_NE(thrown([&] { source.getColliderList("not_a_list"); }).find("'not_a_list'"), std::string::npos);
  // A collider on a TF frame: the frame a string, non-empty.
  const auto framed = source.getColliderList("on_frame");
  ASSERT_TRUE(framed && framed->size() == 1u);
  EXPECT_EQ((*framed)[0].frame, "finger");
  EXPECT_NE(thrown([&] { source.getColliderList("numeric_frame"); })
                .find("invalid parameter 'numeric_frame[0].frame': wrong type, must be a string (a TF frame id)"),
            std::string::npos);
  EXPECT_NE(thrown([&] { source.getColliderList("empty_frame"); }).find("invalid parameter 'empty_frame[0].frame' = ''"),
            std::string::npos);
}

// Colliders on TF frames: none before the frame's first pose, placed there for that tick (it
// appears), then interpolated over a tick towards the next pose, held where they are while missing.
TEST(ColliderFrames, CollidersFollowTheirFrames)
{
  Collider fixed, finger;
  finger.type = ColliderType::Sphere;
  finger.frame = "finger";
  const Eigen::Vector3d offset(1.0, 0.0, 0.5);
  ColliderFrames frames({fixed, finger}, offset);
  ASSERT_EQ(frames.size(), 1u);
  EXPECT_EQ(frames.collider(0), 1);
  EXPECT_EQ(frames.frame(0), "finger");
  frames.setTargets({std::nullopt}, {"not available"});
  EXPECT_FALSE(frames.pose(0, 1.0));
  EXPECT_NE(frames.status().find("collider 1 frame 'finger' not available (inactive until found)"), std::string::npos);

  FramePose first;
  first.translation = Eigen::Vector3d(1.0, 2.0, 3.0);
  frames.setTargets({first}, {""});
  EXPECT_TRUE(frames.following(0));
  EXPECT_TRUE(frames.status().empty());
  for (double s : {0.0, 0.5, 1.0})
    EXPECT_TRUE(frames.pose(0, s)->translation().isApprox(first.translation - offset)) << s;
  frames.finishTick(1.0);

  FramePose second;
  second.translation = Eigen::Vector3d(1.0, 2.2, 3.0);
  second.rotation = Eigen::Quaterniond(Eigen::AngleAxisd(0.4, Eigen::Vector3d::UnitZ()));
  frames.setTargets({second}, {""});
  const Eigen::Isometry3d half = *frames.pose(0, 0.5);
  EXPECT_TRUE(half.translation().isApprox(Eigen::Vector3d(0.0, 2.1, 2.5)));
  EXPECT_NEAR(Eigen::AngleAxisd(half.linear()).angle(), 0.2, 1e-12);
  frames.finishTick(0.5);  // the tick stopped half-way: the collider is there

  frames.setTargets({std::nullopt}, {"stale"});
  EXPECT_FALSE(frames.following(0));
  for (double s : {0.0, 1.0})
    EXPECT_TRUE(frames.pose(0, s)->isApprox(half)) << s;
  EXPECT_NE(frames.status().find("stale (kept at its last pose)"), std::string::npos);
}

// A collider frame that jumps farther than kMaxJumpPerTick or turns more than kMaxTurnPerTick within
// one tick (a glitch) is refused and held where it was, said in the status; one that comes back is
// followed again; a jump that stays is placed there at the next tick, without a sweep through the
// steps of the tick.
TEST(ColliderFrames, AJumpingFrameIsHeldAndAJumpThatStaysIsPlacedAnew)
{
  Collider finger;
  finger.type = ColliderType::Sphere;
  finger.frame = "finger";
  ColliderFrames frames({finger}, Eigen::Vector3d::Zero());
  auto at = [](double x, double y, double z, double turn = 0.0) {
    FramePose pose;
    pose.translation = Eigen::Vector3d(x, y, z);
    pose.rotation = Eigen::Quaterniond(Eigen::AngleAxisd(turn, Eigen::Vector3d::UnitZ()));
    return pose;
  };
  auto translation = [&](double s) { return Eigen::Vector3d(frames.pose(0, s)->translation()); };
  frames.setTargets({at(0.0, 0.0, 0.1)}, {""});
  frames.finishTick(1.0);
  frames.setTargets({at(0.0, 0.3, 0.1)}, {""});  // 0.3 m in a tick: followed
  EXPECT_TRUE(translation(0.5).isApprox(Eigen::Vector3d(0.0, 0.15, 0.1)));
  EXPECT_TRUE(frames.refusals().empty());
  frames.finishTick(1.0);

  frames.setTargets({at(3.0, 0.3, 0.1)}, {""});  // a glitch: 3 m in a tick
  for (double s : {0.0, 0.5, 1.0})
    EXPECT_TRUE(translation(s).isApprox(Eigen::Vector3d(0.0, 0.3, 0.1))) << s;
  EXPECT_FALSE(frames.placed(0));
  ASSERT_EQ(frames.refusals().size(), 1u);
  EXPECT_NE(frames.refusals()[0].find("collider 0 frame 'finger' refused: it jumped 3 m"), std::string::npos)
      << frames.refusals()[0];
  EXPECT_NE(frames.status().find("refused: it jumped 3 m"), std::string::npos) << frames.status();
  frames.finishTick(1.0);
  frames.setTargets({at(0.0, 0.32, 0.1)}, {""});  // back: followed from where it was held
  EXPECT_TRUE(frames.refusals().empty());
  EXPECT_TRUE(frames.status().empty());
  EXPECT_FALSE(frames.placed(0));
  EXPECT_TRUE(translation(1.0).isApprox(Eigen::Vector3d(0.0, 0.32, 0.1)));
  frames.finishTick(1.0);

  frames.setTargets({at(0.0, 0.32, 0.1, 3.0)}, {""});  // turned 172 degrees in a tick: refused
  ASSERT_EQ(frames.refusals().size(), 1u);
  EXPECT_NE(frames.refusals()[0].find("turned 172 degrees"), std::string::npos) << frames.refusals()[0];
  EXPECT_TRUE(frames.pose(0, 1.0)->linear().isApprox(Eigen::Matrix3d::Identity()));
  frames.finishTick(1.0);

  frames.setTargets({at(2.0, 0.0, 0.0)}, {""});  // a jump that stays (within the limits at the next tick)
  EXPECT_EQ(frames.refusals().size(), 1u);
  frames.finishTick(1.0);
  frames.setTargets({at(2.0, 0.05, 0.0)}, {""});
  EXPECT_TRUE(frames.refusals().empty());
  EXPECT_TRUE(frames.placed(0));
  for (double s : {0.0, 0.5, 1.0})
    EXPECT_TRUE(translation(s).isApprox(Eigen::Vector3d(2.0, 0.05, 0.0))) << s;
  frames.finishTick(1.0);
  frames.setTargets({at(2.0, 0.1, 0.0)}, {""});
  EXPECT_FALSE(frames.placed(0));
  EXPECT_TRUE(translation(0.5).isApprox(Eigen::Vector3d(2.0, 0.075, 0.0)));
}

// Particles held by a frame follow its motion applied to their offsets at the first lookup; the
// velocity is the derivative of the interpolated path; a missing frame holds them and says so.
TEST(HandleFrames, ParticlesFollowTheirFrame)
{
  GridParams grid_params;
  grid_params.rows = 3;
  grid_params.cols = 3;
  grid_params.dimension = 3;
  grid_params.handles = {{0, 2}};
  const Grid grid(grid_params);
  const Eigen::Vector3d grid_offset(1.0, 2.0, 3.0);
  HandleFrames frames({{"gripper", {0, 2}}}, grid, grid.initialPositions(), grid_offset);
  const auto pose = [](const Eigen::Vector3d& t, double angle, const Eigen::Vector3d& axis) {
    FramePose p;
    p.translation = t;
    p.rotation = Eigen::Quaterniond(Eigen::AngleAxisd(angle, axis.normalized()));
    return p;
  };
  const Eigen::Matrix3Xd points = grid.toPoints(grid.initialPositions());
  const auto expected = [&](const FramePose& from, const FramePose& to) {
    Eigen::VectorXd x(6);
    for (int k = 0; k < 2; ++k)
    {
      const Eigen::Vector3d start = points.col(k == 0 ? 0 : 2) + grid_offset;
      const Eigen::Vector3d in_frame = from.rotation.conjugate() * (start - from.translation);
      x.segment<3>(3 * k) = to.rotation * in_frame + to.translation - grid_offset;
    }
    return x;
  };
  Eigen::VectorXd x, v, a;
  frames.motion(0.1, 1.0, x, v, a);  // before any lookup: at the start
  EXPECT_LT((x - expected(FramePose(), FramePose())).norm(), 1e-12);
  EXPECT_EQ(frames.status(), "");

  const FramePose first = pose({0.5, 0.0, 1.0}, 0.3, {0, 0, 1});
  frames.setTargets({first});
  frames.motion(0.1, 1.0, x, v, a);
  EXPECT_LT((x - expected(first, first)).norm(), 1e-12) << "the first pose takes the offsets: no jump";
  EXPECT_LT(v.norm(), 1e-12);
  frames.finishTick(0.1, 1.0);

  const FramePose second = pose({0.6, 0.2, 0.9}, 0.8, {1, 1, 0});
  frames.setTargets({second});
  frames.motion(0.1, 1.0, x, v, a);
  EXPECT_LT((x - expected(first, second)).norm(), 1e-12);
  const double h = 1e-6;
  Eigen::VectorXd x_minus, x_plus, unused_v, unused_a;
  frames.motion(0.1, 0.5 - h, x_minus, unused_v, unused_a);
  frames.motion(0.1, 0.5 + h, x_plus, unused_v, unused_a);
  frames.motion(0.1, 0.5, x, v, a);
  EXPECT_LT((v - (x_plus - x_minus) / (2.0 * h * 0.1)).norm(), 1e-6) << "velocity along the interpolated path";
  frames.finishTick(0.1, 0.5);  // the tick stopped half way: the next one starts there
  Eigen::VectorXd half = x;

  frames.setTargets({std::nullopt});
  EXPECT_EQ(frames.status(), "held: frame 'gripper' not available");
  frames.motion(0.1, 1.0, x, v, a);
  EXPECT_LT((x - half).norm(), 1e-12) << "a missing frame holds the particles where they are";
  EXPECT_LT(v.norm(), 1e-12);

  frames.reset();
  frames.setTargets({std::nullopt});
  frames.motion(0.1, 1.0, x, v, a);
  EXPECT_LT((x - expected(first, first)).norm(), 1e-12) << "a reset puts them back at the start";
}

// On a 2D grid a frame that turns out of the x-z plane is refused, whatever the formulation: the
// particles hold where they are (they would be projected onto the plane, onto one point) and the
// status says why. A turn about y is followed.
TEST(HandleFrames, A2DGridRefusesAFrameTurnedOutOfItsPlane)
{
  GridParams grid_params;
  grid_params.rows = 3;
  grid_params.cols = 3;
  grid_params.dimension = 2;
  grid_params.fixed = {2};
  grid_params.handles = {{0, 1}};
  const Grid grid(grid_params);
  HandleFrames frames({{"gripper", {0, 1}}}, grid, grid.initialPositions(), Eigen::Vector3d::Zero());
  FramePose start;
  frames.setTargets({start});
  frames.finishTick(0.1, 1.0);
  Eigen::VectorXd x0, x, v, a;
  frames.motion(0.1, 1.0, x0, v, a);

  FramePose turned;
  turned.rotation = Eigen::Quaterniond(Eigen::AngleAxisd(0.5, Eigen::Vector3d::UnitZ()));
  frames.setTargets({turned});
  EXPECT_NE(frames.status().find("held: frame 'gripper' refused: it turns out of the 2D grid's x-z plane"),
            std::string::npos) << frames.status();
  ASSERT_EQ(frames.refusals().size(), 1u);
  frames.motion(0.1, 1.0, x, v, a);
  EXPECT_LT((x - x0).norm(), 1e-12) << "held where they were";
  EXPECT_LT(v.norm(), 1e-12);
  frames.finishTick(0.1, 1.0);
  frames.setTargets({turned});
  EXPECT_FALSE(frames.status().empty()) << "an out-of-plane pose is refused however long it stays";

  FramePose about_y;
  about_y.rotation = Eigen::Quaterniond(Eigen::AngleAxisd(0.5, Eigen::Vector3d::UnitY()));
  frames.setTargets({about_y});
  EXPECT_EQ(frames.status(), "");
  frames.motion(0.1, 1.0, x, v, a);
  EXPECT_GT((x - x0).norm(), 1e-3) << "a turn about y is followed";
}

// A frame that flips 180 degrees at every tick is refused and its particles hold still (a broken
// broadcaster, or faster than any cloth follows); a large turn that stays is a new grip: no jump, and
// the particles follow the frame from there.
TEST(HandleFrames, AFlippingFrameIsHeldAndALargeTurnThatStaysIsGrippedAnew)
{
  GridParams grid_params;
  grid_params.rows = 3;
  grid_params.cols = 3;
  grid_params.dimension = 3;
  grid_params.handles = {{0, 2}};
  const Grid grid(grid_params);
  HandleFrames frames({{"gripper", {0, 2}}}, grid, grid.initialPositions(), Eigen::Vector3d::Zero());
  FramePose upright, flipped;
  flipped.rotation = Eigen::Quaterniond(Eigen::AngleAxisd(3.14159, Eigen::Vector3d::UnitX()));
  frames.setTargets({upright});
  frames.finishTick(0.1, 1.0);
  Eigen::VectorXd x0, x, v, a;
  frames.motion(0.1, 1.0, x0, v, a);
  for (int tick = 0; tick < 6; ++tick)
  {
    frames.setTargets({tick % 2 ? upright : flipped});
    frames.motion(0.1, 1.0, x, v, a);
    EXPECT_LT((x - x0).norm(), 1e-12) << tick;
    EXPECT_LT(v.norm() + a.norm(), 1e-12) << tick;
    frames.finishTick(0.1, 1.0);
  }
  frames.setTargets({flipped});
  EXPECT_NE(frames.status().find("refused: it turned 180 degrees since the last tick"), std::string::npos)
      << frames.status();
  frames.finishTick(0.1, 1.0);
  frames.setTargets({flipped});  // it stays: gripped anew where the particles are
  EXPECT_EQ(frames.status(), "");
  frames.motion(0.1, 1.0, x, v, a);
  EXPECT_LT((x - x0).norm(), 1e-12) << "a new grip does not move the particles";
  frames.finishTick(0.1, 1.0);
  FramePose moved = flipped;
  moved.translation = Eigen::Vector3d(0.1, 0.0, 0.0);
  frames.setTargets({moved});
  frames.motion(0.1, 1.0, x, v, a);
  for (int p = 0; p < 2; ++p)
    EXPECT_NEAR(x[3 * p] - x0[3 * p], 0.1, 1e-12) << "and they follow the frame from there";
}

// A handle frame that jumps farther than kMaxJumpPerTick within one tick (a TF sample 1e12 m away)
// is refused and its particles hold; back where it was, it is followed again; a jump that stays (the
// next tick's pose within a tick's motion of it) is a new grip, without moving the particles.
TEST(HandleFrames, AJumpingFrameIsHeldAndAJumpThatStaysIsGrippedAnew)
{
  GridParams grid_params;
  grid_params.rows = 3;
  grid_params.cols = 3;
  grid_params.dimension = 3;
  grid_params.handles = {{0, 2}};
  const Grid grid(grid_params);
  HandleFrames frames({{"gripper", {0, 2}}}, grid, grid.initialPositions(), Eigen::Vector3d::Zero());
  auto at = [](double x) {
    FramePose pose;
    pose.translation = Eigen::Vector3d(x, 0.0, 0.0);
    return pose;
  };
  frames.setTargets({at(0.0)});
  frames.finishTick(0.1, 1.0);
  Eigen::VectorXd x0, x, v, a;
  frames.motion(0.1, 1.0, x0, v, a);
  frames.setTargets({at(0.4)});  // 0.4 m in a tick: followed
  EXPECT_EQ(frames.status(), "");
  frames.finishTick(0.1, 1.0);
  frames.motion(0.1, 1.0, x0, v, a);

  frames.setTargets({at(1e12)});  // a glitch
  EXPECT_NE(frames.status().find("held: frame 'gripper' refused: it jumped 1e+12 m since the last tick, above 0.5 m"),
            std::string::npos) << frames.status();
  ASSERT_EQ(frames.refusals().size(), 1u);
  frames.motion(0.1, 1.0, x, v, a);
  EXPECT_LT((x - x0).norm(), 1e-12) << "held where they were";
  EXPECT_LT(v.norm(), 1e-12);
  EXPECT_LT((a - Eigen::Vector3d(-40.0, 0.0, 0.0).replicate(2, 1)).norm(), 1e-9)
      << "they stop: the last tick's 4 m/s lost over this one";
  frames.finishTick(0.1, 1.0);
  frames.setTargets({at(0.45)});  // back: followed from where it was held
  EXPECT_EQ(frames.status(), "");
  frames.motion(0.1, 1.0, x, v, a);
  EXPECT_NEAR(x[0] - x0[0], 0.05, 1e-12);
  frames.finishTick(0.1, 1.0);
  frames.motion(0.1, 1.0, x0, v, a);

  frames.setTargets({at(5.0)});  // a jump that stays
  EXPECT_FALSE(frames.status().empty());
  frames.finishTick(0.1, 1.0);
  frames.setTargets({at(5.1)});
  EXPECT_EQ(frames.status(), "") << "gripped anew";
  frames.motion(0.1, 1.0, x, v, a);
  EXPECT_LT((x - x0).norm(), 1e-12) << "a new grip does not move the particles";
  frames.finishTick(0.1, 1.0);
  frames.setTargets({at(5.2)});
  frames.motion(0.1, 1.0, x, v, a);
  EXPECT_NEAR(x[0] - x0[0], 0.1, 1e-12) << "and they follow the frame from there";
}

// The one frame's motion for the moving-frame formulation moves the handle particles exactly as
// motion() does: the same lookups, the same interpolation, in grid coordinates.
TEST(HandleFrames, OneFrameMotionIsTheParticlesMotion)
{
  GridParams grid_params;
  grid_params.rows = 3;
  grid_params.cols = 3;
  grid_params.dimension = 3;
  grid_params.handles = {{0, 2}, {1}};
  const Grid grid(grid_params);
  const Eigen::Vector3d grid_offset(1.0, 2.0, 3.0);
  HandleFrames frames({{"gripper", {0, 2}}, {"gripper", {1}}}, grid, grid.initialPositions(), grid_offset);
  EXPECT_TRUE(frames.frameMotion(0.1, 0.5).atRest()) << "before the first lookup";
  const Eigen::Matrix3Xd all = grid.toPoints(grid.initialPositions());
  Eigen::Matrix3Xd held(3, 3);
  held << all.col(0), all.col(2), all.col(1);
  auto pose = [](const Eigen::Vector3d& t, double angle, const Eigen::Vector3d& axis) {
    FramePose p;
    p.translation = t;
    p.rotation = Eigen::Quaterniond(Eigen::AngleAxisd(angle, axis.normalized()));
    return p;
  };
  frames.setTargets({pose({0.5, 0.0, 1.0}, 0.3, {0, 0, 1}), pose({0.5, 0.0, 1.0}, 0.3, {0, 0, 1})});
  frames.finishTick(0.1, 1.0);
  EXPECT_LT(frames.frameMotion(0.1, 1.0).translation.norm(), 1e-15) << "the first pose is B's start";
  frames.setTargets({pose({0.7, 0.2, 0.8}, 1.1, {1, 1, 0}), pose({0.7, 0.2, 0.8}, 1.1, {1, 1, 0})});
  for (double s : {0.25, 1.0})
  {
    Eigen::VectorXd x, v, a;
    frames.motion(0.1, s, x, v, a);
    const RigidPointMotion m = pointMotion(frames.frameMotion(0.1, s), held);
    for (int k = 0; k < 3; ++k)
    {
      EXPECT_LT((m.position.col(k) - x.segment<3>(3 * k)).norm(), 1e-14) << s;
      EXPECT_LT((m.velocity.col(k) - v.segment<3>(3 * k)).norm(), 1e-12) << s;
      EXPECT_LT((m.acceleration.col(k) - a.segment<3>(3 * k)).norm(), 1e-10) << s;
    }
  }
}

// A tick moves a frame at a constant velocity; the change from one tick's to the next is the
// acceleration over the next: on a path of constant acceleration and angular acceleration, exactly
// those (the secants of a quadratic differ by a T), in the moving frame and for every held particle.
TEST(HandleFrames, ATickToTickChangeOfVelocityIsAnAcceleration)
{
  GridParams grid_params;
  grid_params.rows = 3;
  grid_params.cols = 3;
  grid_params.dimension = 3;
  grid_params.handles = {{0, 1, 2}};
  const Grid grid(grid_params);
  const Eigen::Vector3d grid_offset(1.0, 2.0, 3.0);
  HandleFrames frames({{"gripper", {0, 1, 2}}}, grid, grid.initialPositions(), grid_offset);
  const Eigen::Vector3d acceleration(0.4, -0.2, 0.1), origin(0.5, 2.0, 3.0);
  const double angular_acceleration = 0.7, tick = 0.1;
  auto poseAt = [&](double t) {
    FramePose p;
    p.translation = origin + 0.5 * acceleration * t * t;
    p.rotation = Eigen::Quaterniond(Eigen::AngleAxisd(0.5 * angular_acceleration * t * t, Eigen::Vector3d::UnitZ()));
    return p;
  };
  for (int k = 0; k <= 4; ++k)
  {
    frames.setTargets({poseAt(k * tick)});
    if (k >= 2)  // the first pose grips, the first move starts from rest
    {
      const FrameMotion m = frames.frameMotion(tick, 0.5);
      EXPECT_LT((m.angular_acceleration - angular_acceleration * Eigen::Vector3d::UnitZ()).norm(), 1e-9) << k;
      // The frame's origin (its start, grid coordinates) accelerates at `acceleration`.
      const Eigen::Matrix3Xd start_origin = origin - grid_offset;
      EXPECT_LT((pointMotion(m, start_origin).acceleration.col(0) - acceleration).norm(), 1e-9) << k;
      Eigen::VectorXd x, v, a;
      frames.motion(tick, 0.5, x, v, a);
      const RigidPointMotion held = pointMotion(m, grid.toPoints(grid.initialPositions()).leftCols(3));
      for (int p = 0; p < 3; ++p)
        EXPECT_LT((held.acceleration.col(p) - a.segment<3>(3 * p)).norm(), 1e-9) << k << " particle " << p;
    }
    frames.finishTick(tick, 1.0);
  }
  // Held (~step while paused): where they are, at rest, with no acceleration left over.
  Eigen::VectorXd before, x, v, a, unused;
  frames.motion(tick, 1.0, before, unused, unused);
  frames.hold();
  frames.motion(tick, 0.5, x, v, a);
  EXPECT_LT((x - before).norm(), 1e-12);
  EXPECT_LT(v.norm() + a.norm(), 1e-12);
  EXPECT_TRUE(frames.frameMotion(tick, 0.5).angular_acceleration.isZero(0.0));
}

// The same gripper motion, reaching the simulation as ticks of frame poses, gives the same cloth in
// the gripper's frame as in the world (constraint modes): the cloth feels the gripper's acceleration
// in both. Without it the moving frame carries the cloth along nearly rigidly: a fifth of the swing.
TEST(HandleFrames, TheMovingFrameFeelsTheGrippersAccelerationAsTheWorldDoes)
{
  GridParams grid_params;
  grid_params.rows = grid_params.cols = 6;
  grid_params.spacing = 0.05;
  grid_params.dimension = 3;
  grid_params.mass = 0.005;
  grid_params.structural_stiffness = 50.0;
  grid_params.shear_stiffness = 20.0;
  grid_params.fixed = {};
  grid_params.handles = {{0, 1, 2, 3, 4, 5}};
  SimulationParams params;
  params.method = Method::Full;
  params.handles_one_body = true;
  params.time_step = 1.0 / 600.0;
  params.alpha = 0.5;
  const double tick = 1.0 / 30.0;
  const int steps = 20;  // a tick
  const Eigen::Vector3d offset(0.0, 0.0, 1.0);
  // The cloth at every tick while the gripper moves 0.2 m along x in 1 s (rest to rest) and holds 0.5 s.
  auto run = [&](HandleFormulation formulation) {
    params.handle_formulation = formulation;
    Simulation simulation(grid_params, params);
    HandleFrames frames({{"gripper", {0, 1, 2, 3, 4, 5}}}, simulation.grid(), simulation.linearizationPositions(), offset);
    std::vector<Eigen::Matrix3Xd> ticks;
    for (int k = 0; k <= 45; ++k)
    {
      const double u = std::min(1.0, k * tick);
      FramePose pose;
      pose.translation = offset + Eigen::Vector3d(0.2 * u * u * (3.0 - 2.0 * u), 0.0, 0.0);
      frames.setTargets({pose});
      for (int j = 1; j <= steps; ++j)
      {
        frames.drive(simulation, tick, static_cast<double>(j) / steps);
        EXPECT_FALSE(simulation.step().diverged);
      }
      frames.finishTick(tick, 1.0);
      ticks.push_back(simulation.points());
    }
    return ticks;
  };
  const std::vector<Eigen::Matrix3Xd> world = run(HandleFormulation::ConstraintModes);
  const std::vector<Eigen::Matrix3Xd> moving = run(HandleFormulation::MovingFrame);
  // How far the bottom row trails a rigid translation with the gripper (the swing), and how far
  // the two formulations are apart, over every tick.
  double swing = 0.0, apart = 0.0;
  for (size_t k = 0; k < world.size(); ++k)
  {
    const double moved = world[k](0, 0) - world.front()(0, 0);
    for (int p = 30; p < 36; ++p)
      swing = std::max(swing, std::abs(world[k](0, p) - world.front()(0, p) - moved));
    apart = std::max(apart, (moving[k] - world[k]).colwise().norm().maxCoeff());
  }
  EXPECT_GT(swing, 0.01) << "the cloth swings behind the gripper";
  EXPECT_LT(apart, 0.25 * swing) << "the same cloth in the gripper's frame";
}

// A YAML node as the parameter server would hold it (scalars: integer, number, bool or string).
XmlRpc::XmlRpcValue toXmlRpc(const YAML::Node& node)
{
  if (node.IsMap())
  {
    XmlRpc::XmlRpcValue map;
    map.begin();
    for (const auto& item : node)
      map[item.first.as<std::string>()] = toXmlRpc(item.second);
    return map;
  }
  if (node.IsSequence())
  {
    XmlRpc::XmlRpcValue list;
    list.setSize(static_cast<int>(node.size()));
    for (size_t k = 0; k < node.size(); ++k)
      list[static_cast<int>(k)] = toXmlRpc(node[k]);
    return list;
  }
  const std::string text = node.Scalar();
  if (const auto i = parseInteger(text))
    return XmlRpc::XmlRpcValue(*i);
  if (const auto d = parseNumber(text))
    return XmlRpc::XmlRpcValue(*d);
  if (text == "true" || text == "false")
    return XmlRpc::XmlRpcValue(text == "true");
  return XmlRpc::XmlRpcValue(text);
}

// Every config the node ships loads and passes every check, core and node, with no key the node
// does not read.
TEST(NodeParams, EveryShippedNodeConfigLoads)
{
  std::vector<std::string> loaded;
  for (const auto& entry : std::filesystem::directory_iterator(std::string(MODAL_SOURCE_DIR) + "/config"))
  {
    if (entry.path().extension() != ".yaml")
      continue;
    SCOPED_TRACE(entry.path().string());
    XmlRpc::XmlRpcValue params;
    params.begin();
    for (const auto& item : YAML::LoadFile(entry.path().string()))
      params[item.first.as<std::string>()] = toXmlRpc(item.second);
    const XmlRpcParameterSource source(params);
    EXPECT_EQ(loadNodeConfiguration(source, source.keys()).unknown_keys, std::vector<std::string>{});
    loaded.push_back(entry.path().filename().string());
  }
  std::sort(loaded.begin(), loaded.end());
  EXPECT_EQ(loaded, (std::vector<std::string>{"cloth.yaml", "cloth_drag.yaml", "cloth_large.yaml", "cloth_table.yaml",
                                              "fold.yaml", "held_cloth.yaml", "paper_2d.yaml", "paper_3d.yaml",
                                              "rollout_demo.yaml"}));
}

}  // namespace

int main(int argc, char** argv)
{
  testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}

// Every key the node reads beyond the core's is one the tools know as the node's (kNodeParameters),
// so that modal_compare reads a config shared with the node without an unknown-key warning.
TEST(NodeParams, EveryKeyOnlyTheNodeReadsIsKnownToTheTools)
{
  const FakeSource node;
  loadNodeConfiguration(node, {});  // every key asked, each at its default
  const YamlParameterSource core = YamlParameterSource::fromString("{}");
  loadGridParams(core);
  loadSimulationParams(core);
  int node_only = 0;
  for (const std::string& key : node.asked())
    if (!core.queried().count(key))
    {
      ++node_only;
      EXPECT_TRUE(kNodeParameters.count(key) || kToolParameters.count(key)) << key << " is missing from kNodeParameters";
    }
  EXPECT_GT(node_only, 20) << "the node's own keys were asked";
}
