// The live parameters: every one that cfg/Simulation.cfg lists has its place in the node's
// configuration, goes into the parameters with the type the loader reads, and comes back unchanged.
#include "live_parameters.h"
#include "xmlrpc_parameter_source.h"

#include <gtest/gtest.h>

#include <string>

namespace
{

using namespace modal_mass_spring;

// A configuration with every live value away from its default, each a different number.
NodeConfiguration changed()
{
  const XmlRpcParameterSource none{XmlRpc::XmlRpcValue()};
  NodeConfiguration c = loadNodeConfiguration(none, {});
  c.node.real_time_factor = 0.5;
  c.node.publish_rate = 20.0;
  c.node.strain_scale = 0.2;
  c.node.show_surface = false;
  c.node.show_labels = false;
  c.node.drag_stiffness = 3.0;
  c.node.poke_impulse = 0.004;
  c.simulation.self_collision_thickness = 0.003;
  c.simulation.self_friction = 0.25;
  c.simulation.alpha = 0.1;
  c.simulation.beta = 0.002;
  c.grid.structural_stiffness = 12.0;
  c.grid.shear_stiffness = 6.0;
  c.grid.bending_stiffness = 1.5;
  c.grid.mass = 0.02;
  c.simulation.num_modes = 6;
  c.simulation.linearization = Linearization::Equilibrium;
  return c;
}

TEST(LiveParameters, ReportedAsTheConfigurationHoldsThem)
{
  const NodeConfiguration c = changed();
  const SimulationConfig config = liveValues(c);
  EXPECT_EQ(config.publish_rate, 20.0);
  EXPECT_FALSE(config.show_surface);
  EXPECT_TRUE(config.show_particles);
  EXPECT_EQ(config.self_friction, 0.25);
  EXPECT_EQ(config.beta, 0.002);
  EXPECT_EQ(config.mass, 0.02);
  EXPECT_EQ(config.num_modes, 6);
  EXPECT_EQ(config.linearization, "equilibrium");
}

// Written into the parameters and loaded as at start-up, every live value comes back: each name
// reaches the field the loader fills from it, with a type the loader accepts.
TEST(LiveParameters, WrittenAndLoadedAgainTheyAreUnchanged)
{
  const NodeConfiguration c = changed();
  XmlRpc::XmlRpcValue params;
  params.begin();
  writeLiveValues(liveValues(c), params);
  EXPECT_EQ(params.size(), static_cast<int>(SimulationConfig::__getParamDescriptions__().size()));
  EXPECT_EQ(params["show_surface"].getType(), XmlRpc::XmlRpcValue::TypeBoolean);
  EXPECT_EQ(params["num_modes"].getType(), XmlRpc::XmlRpcValue::TypeInt);
  EXPECT_EQ(params["mass"].getType(), XmlRpc::XmlRpcValue::TypeDouble);
  EXPECT_EQ(params["linearization"].getType(), XmlRpc::XmlRpcValue::TypeString);
  const XmlRpcParameterSource source(params);
  const NodeConfiguration loaded = loadNodeConfiguration(source, source.keys());
  EXPECT_TRUE(loaded.unknown_keys.empty());
  EXPECT_FALSE(liveValuesDiffer(c, loaded, kLiveLevel));
  EXPECT_FALSE(liveValuesDiffer(c, loaded, kRebuildLevel));
  EXPECT_EQ(loaded.grid.shear_stiffness, 6.0);
  EXPECT_EQ(loaded.simulation.linearization, Linearization::Equilibrium);

  XmlRpc::XmlRpcValue rebuild_only;
  rebuild_only.begin();
  writeLiveValues(liveValues(c), rebuild_only, kRebuildLevel);
  EXPECT_TRUE(rebuild_only.hasMember("alpha"));
  EXPECT_FALSE(rebuild_only.hasMember("publish_rate"));
}

// Copying a level copies exactly the parameters of that level.
TEST(LiveParameters, CopiedAndComparedByLevel)
{
  const NodeConfiguration c = changed();
  const XmlRpcParameterSource none{XmlRpc::XmlRpcValue()};
  NodeConfiguration live = loadNodeConfiguration(none, {});
  EXPECT_TRUE(liveValuesDiffer(c, live, kLiveLevel));
  EXPECT_TRUE(liveValuesDiffer(c, live, kRebuildLevel));
  copyLiveValues(c, live, kLiveLevel);
  EXPECT_FALSE(liveValuesDiffer(c, live, kLiveLevel));
  EXPECT_TRUE(liveValuesDiffer(c, live, kRebuildLevel));
  EXPECT_EQ(live.node.drag_stiffness, 3.0);
  EXPECT_EQ(live.simulation.self_friction, 0.25) << "self-collision is live too";
  EXPECT_EQ(live.simulation.alpha, 0.0);
  copyLiveValues(c, live, kRebuildLevel);
  EXPECT_FALSE(liveValuesDiffer(c, live, kRebuildLevel));
  EXPECT_EQ(live.simulation.num_modes, 6);
}

TEST(LiveParameters, RebuildValuesDescribedInTheCfgsOrder)
{
  EXPECT_EQ(describeLiveValues(changed(), kRebuildLevel),
            "alpha 0.1, beta 0.002, structural_stiffness 12, shear_stiffness 6, bending_stiffness 1.5, mass 0.02, "
            "num_modes 6, linearization equilibrium");
}

}  // namespace
