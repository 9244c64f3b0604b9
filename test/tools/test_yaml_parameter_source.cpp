// The YAML parameter source: the node's names and types, wrong types refused, unknown keys ignored.
#include "yaml_colliders.h"
#include "yaml_parameter_source.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <stdexcept>

using namespace modal_mass_spring;

namespace
{

// The message of the std::invalid_argument `f` throws; fails the test when it throws nothing.
template <typename F>
std::string invalidArgument(F f)
{
  try
  {
    f();
  }
  catch (const std::invalid_argument& e)
  {
    return e.what();
  }
  ADD_FAILURE() << "no std::invalid_argument thrown";
  return "";
}

}  // namespace

TEST(YamlParameterSource, ReadsEveryParameterTheCoreKnows)
{
  const auto source = YamlParameterSource::fromString(R"(
rows: 6
cols: 4
spacing: 0.05
dimension: 3
mass: 0.02
structural_stiffness: 20
shear_stiffness: 7.5
bending: true
bending_stiffness: 2
fixed: [0, 3]
gravity: [0, 0, -1.62]
rotation_deg: 30
method: linear
num_modes: 12
alpha: 0.5
beta: 0.001
time_step: 0.002
divergence_limit: 50
publish_rate: 30      # a node-only key: ignored
frame_id: world
)");
  const GridParams g = loadGridParams(source);
  const SimulationParams s = loadSimulationParams(source);
  EXPECT_EQ(g.rows, 6);
  EXPECT_EQ(g.cols, 4);
  EXPECT_DOUBLE_EQ(g.spacing, 0.05);
  EXPECT_EQ(g.dimension, 3);
  EXPECT_DOUBLE_EQ(g.mass, 0.02);
  EXPECT_DOUBLE_EQ(g.structural_stiffness, 20.0);  // an integer where a number is expected
  EXPECT_DOUBLE_EQ(g.shear_stiffness, 7.5);
  EXPECT_TRUE(g.bending);
  EXPECT_DOUBLE_EQ(g.bending_stiffness, 2.0);
  EXPECT_EQ(g.fixed, (std::vector<int>{0, 3}));
  EXPECT_DOUBLE_EQ(g.gravity.z(), -1.62);
  EXPECT_DOUBLE_EQ(g.rotation_deg, 30.0);
  EXPECT_EQ(s.method, Method::Linear);
  EXPECT_EQ(s.num_modes, 12);
  EXPECT_DOUBLE_EQ(s.alpha, 0.5);
  EXPECT_DOUBLE_EQ(s.beta, 0.001);
  EXPECT_DOUBLE_EQ(s.time_step, 0.002);
  EXPECT_DOUBLE_EQ(s.divergence_limit, 50.0);
  EXPECT_TRUE(source.queried().count("num_modes"));
  EXPECT_FALSE(source.queried().count("publish_rate"));
}

TEST(YamlParameterSource, AbsentKeysKeepTheDefaults)
{
  const auto source = YamlParameterSource::fromString("");
  const GridParams g = loadGridParams(source);
  const SimulationParams s = loadSimulationParams(source);
  EXPECT_EQ(g.rows, GridParams{}.rows);
  EXPECT_EQ(s.num_modes, SimulationParams{}.num_modes);
}

TEST(YamlParameterSource, WrongTypesNameTheKey)
{
  struct Case
  {
    const char* yaml;
    const char* key;
  };
  for (const Case& c : {Case{"rows: 5.5", "rows"}, Case{"rows: five", "rows"}, Case{"mass: heavy", "mass"},
                        Case{"bending: 3", "bending"}, Case{"fixed: 0", "fixed"}, Case{"fixed: [0, a]", "fixed"},
                        Case{"gravity: {z: -9.81}", "gravity"}, Case{"method: [full]", "method"},
                        Case{"num_modes: [4]", "num_modes"}, Case{"time_step: true", "time_step"}})
  {
    const auto source = YamlParameterSource::fromString(c.yaml);
    const std::string message = invalidArgument([&] {
      loadGridParams(source);
      loadSimulationParams(source);
    });
    EXPECT_NE(message.find(std::string("'") + c.key + "'"), std::string::npos) << c.yaml << ": " << message;
    EXPECT_NE(message.find("wrong type"), std::string::npos) << c.yaml << ": " << message;
  }
}

TEST(YamlParameterSource, UnreadableFilesNameTheFile)
{
  EXPECT_NE(invalidArgument([] { YamlParameterSource::fromFile("/nonexistent/grid.yaml"); })
                .find("/nonexistent/grid.yaml"),
            std::string::npos);
  EXPECT_NE(invalidArgument([] { YamlParameterSource::fromString("rows: [1, 2", "broken.yaml"); }).find("broken.yaml"),
            std::string::npos);
  EXPECT_NE(invalidArgument([] { YamlParameterSource::fromString("- 1\n- 2\n", "list.yaml"); }).find("map"),
            std::string::npos);
}

TEST(YamlParameterSource, OverridesTakeTheirTypeFromYamlAndClonesAreIndependent)
{
  auto source = YamlParameterSource::fromString("num_modes: 4\nmethod: full\n");
  auto copy = source.clone();
  source.set("num_modes", "30");
  source.set("fixed", "[0, 4]");
  source.set("method", "physical");
  EXPECT_EQ(loadSimulationParams(source).num_modes, 30);
  EXPECT_EQ(loadSimulationParams(source).method, Method::Physical);
  EXPECT_EQ(loadGridParams(source).fixed, (std::vector<int>{0, 4}));
  EXPECT_EQ(loadSimulationParams(copy).num_modes, 4);
  source.set("num_modes", "many");
  EXPECT_NE(invalidArgument([&] { loadSimulationParams(source); }).find("num_modes"), std::string::npos);
}

// The node's shipped configs and the tool's own: every one loads, passes the core's checks and has
// no key that neither the core nor the node reads, so the two really share one set of names.
TEST(YamlParameterSource, EveryShippedConfigLoads)
{
  std::vector<std::string> found;
  for (const char* folder : {"/config", "/config/compare"})
    for (const auto& entry : std::filesystem::directory_iterator(std::string(MODAL_SOURCE_DIR) + folder))
      if (entry.path().extension() == ".yaml")
        found.push_back(entry.path().string());
  std::sort(found.begin(), found.end());
  const std::string dir = MODAL_SOURCE_DIR;
  for (const char* name : {"/config/cloth.yaml", "/config/paper_2d.yaml", "/config/paper_3d.yaml",
                           "/config/compare/paper_2d.yaml", "/config/compare/paper_3d.yaml",
                           "/config/compare/cloth_50.yaml", "/config/compare/held_cloth.yaml"})
    EXPECT_TRUE(std::binary_search(found.begin(), found.end(), dir + name)) << name << " is missing";
  for (const std::string& path : found)
  {
    SCOPED_TRACE(path);
    const auto source = YamlParameterSource::fromFile(path);
    GridParams g;
    SimulationParams s;
    ASSERT_NO_THROW(g = loadGridParams(source));
    ASSERT_NO_THROW(s = loadSimulationParams(source));
    EXPECT_NO_THROW(validateParameters(g, s));
    EXPECT_EQ(source.unknownKeys(), std::vector<std::string>{});
  }
}

TEST(YamlParameterSource, RefusesAKeyGivenTwice)
{
  const std::string message =
      invalidArgument([] { YamlParameterSource::fromString("rows: 5\ncols: 4\nrows: 6\n", "twice.yaml"); });
  EXPECT_NE(message.find("'rows'"), std::string::npos) << message;
  EXPECT_NE(message.find("lines 1 and 3"), std::string::npos) << message;
  EXPECT_NE(message.find("twice.yaml"), std::string::npos) << message;
}

TEST(YamlParameterSource, UnknownKeysAreThoseNeitherTheCoreNorTheNodeReads)
{
  const auto source = YamlParameterSource::fromString("rows: 5\nstifness: 3\npublish_rate: 30\nnum_mode: 4\n");
  loadGridParams(source);
  loadSimulationParams(source);
  EXPECT_EQ(source.unknownKeys(), (std::vector<std::string>{"stifness", "num_mode"}));
}

// An integer beyond 32 bits is refused with the range, not as a wrong type; a whole number written as
// a float in range is still a wrong type.
TEST(YamlParameterSource, AnIntegerBeyondIntNamesTheRange)
{
  for (const std::string value : {"2147483648", "-99999999999", "1e12"})
  {
    const auto source = YamlParameterSource::fromString("rows: " + value + "\nfixed: [0, " + value + "]\n");
    const std::string why = invalidArgument([&] { source.getInt("rows"); });
    EXPECT_NE(why.find("'rows' = " + value + ": must be an integer in [-2147483648, 2147483647]"), std::string::npos)
        << why;
    const std::string list = invalidArgument([&] { source.getIntList("fixed"); });
    EXPECT_NE(list.find("[-2147483648, 2147483647]"), std::string::npos) << list;
  }
  const auto real = YamlParameterSource::fromString("rows: 5.5\n");
  EXPECT_NE(invalidArgument([&] { real.getInt("rows"); }).find("wrong type"), std::string::npos);
}

// A collider map: a key given twice is refused with both lines (not resolved to the last); a type
// given as a number is named as such (not "absent"); a value of the wrong shape says what its key takes.
TEST(YamlParameterSource, CollidersRefuseDuplicateKeysAndSayWhatEachKeyTakes)
{
  auto colliders = [](const std::string& text) {
    return parseColliders(YAML::Load(text), "colliders");
  };
  std::string why = invalidArgument([&] {
    colliders("- type: sphere\n  center: [0, 0, 0]\n  radius: 0.1\n  radius: 0.2\n");
  });
  EXPECT_NE(why.find("'colliders[0].radius' = (given twice): on lines 3 and 4"), std::string::npos) << why;
  why = invalidArgument([&] { colliders("[{type: 5}]"); });
  EXPECT_NE(why.find("'colliders[0].type' = 5: must be a string: plane, box, sphere or capsule"), std::string::npos)
      << why;
  why = invalidArgument([&] { colliders("[{type: sphere, center: [0, 0, 0], radius: 0.1, friction: {a: 1}}]"); });
  EXPECT_NE(why.find("'colliders[0].friction'"), std::string::npos) << why;
  EXPECT_NE(why.find("must be a number"), std::string::npos) << why;
  EXPECT_EQ(why.find("a string"), std::string::npos) << why;
  why = invalidArgument([&] { colliders("[{type: sphere, center: [0, 0, 1e300], radius: 0.1}]"); });
  EXPECT_NE(why.find("'colliders[0].center'"), std::string::npos) << why;
  EXPECT_NE(why.find("[-1e+06, 1e+06]"), std::string::npos) << why;
  EXPECT_EQ(colliders("[{type: sphere, center: [0, 0, 1e6], radius: 0.1}]").size(), 1u);
}
