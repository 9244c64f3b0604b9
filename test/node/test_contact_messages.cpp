// ~set_colliders's messages as the core's colliders: each shape at its pose (the fixed frame turned
// into the grid's coordinates), the refusals by field name, the start-up colliders' ids, and what SET
// and UPDATE make of a set.
#include "contact_messages.h"
#include "node_params.h"
#include "xmlrpc_parameter_source.h"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <limits>
#include <stdexcept>
#include <string>

using namespace modal_mass_spring;

namespace
{

PlacedCollider box(const std::string& id, double x, double y, double z, double sx, double sy, double sz)
{
  PlacedCollider m;
  m.id = id;
  m.shape.type = shape_msgs::SolidPrimitive::BOX;
  m.shape.dimensions = {sx, sy, sz};
  m.pose.position.x = x;
  m.pose.position.y = y;
  m.pose.position.z = z;
  m.pose.orientation.w = 1.0;
  m.friction = 0.4;
  return m;
}

double distanceAt(const Collider& c, const Eigen::Vector3d& x)
{
  Eigen::Vector3d n;
  return signedDistance(c, c.pose, x, n);
}

// The message of what `convert` throws; empty when it does not throw.
template <typename F>
std::string refusal(F convert)
{
  try
  {
    convert();
  }
  catch (const std::invalid_argument& error)
  {
    return error.what();
  }
  return "";
}

const Eigen::Vector3d kOffset(1.0, 0.0, 0.5);  // the grid's origin in the fixed frame

}  // namespace

TEST(ColliderMessages, EachShapeStandsAtItsPoseInTheGridsCoordinates)
{
  // A 0.4 x 0.2 x 0.1 box centred at (1.5, 0, 0.5) in the fixed frame, turned 90 degrees about z.
  PlacedCollider m = box("table", 1.5, 0.0, 0.5, 0.4, 0.2, 0.1);
  m.pose.orientation.w = m.pose.orientation.z = std::sqrt(0.5);
  const Collider c = colliderFromMessage(m, "colliders[0]", kOffset, 3);
  EXPECT_EQ(c.type, ColliderType::Box);
  EXPECT_EQ(c.id, "table");
  EXPECT_EQ(c.friction, 0.4);
  EXPECT_TRUE(c.half_extents.isApprox(Eigen::Vector3d(0.2, 0.1, 0.05)));
  // In the grid's coordinates its centre is at (0.5, 0, 0); turned, its 0.4 m side lies along y.
  EXPECT_NEAR(distanceAt(c, Eigen::Vector3d(0.5, 0.0, 0.15)), 0.1, 1e-12);   // above its top
  EXPECT_NEAR(distanceAt(c, Eigen::Vector3d(0.5, 0.3, 0.0)), 0.1, 1e-12);    // beyond its long side's end
  EXPECT_NEAR(distanceAt(c, Eigen::Vector3d(0.7, 0.0, 0.0)), 0.1, 1e-12);    // beyond its short side
  EXPECT_LT(distanceAt(c, Eigen::Vector3d(0.5, 0.0, 0.0)), 0.0);

  PlacedCollider s = box("ball", 1.0, 0.2, 0.5, 0.0, 0.0, 0.0);
  s.shape.type = shape_msgs::SolidPrimitive::SPHERE;
  s.shape.dimensions = {0.1};
  const Collider ball = colliderFromMessage(s, "colliders[1]", kOffset, 3);
  EXPECT_EQ(ball.type, ColliderType::Sphere);
  EXPECT_NEAR(distanceAt(ball, Eigen::Vector3d(0.0, 0.2, 0.3)), 0.2, 1e-12);

  // The plane z = 0.1 of a frame 0.5 m up (the fixed frame): 0.1 m above the grid's origin height.
  PlacedCollider p = box("floor", 0.0, 0.0, 0.5, 0.0, 0.0, 0.0);
  p.shape.type = 0;
  p.shape.dimensions.clear();
  p.plane.coef = {0.0, 0.0, 2.0, -0.2};
  const Collider floor = colliderFromMessage(p, "colliders[2]", kOffset, 3);
  EXPECT_EQ(floor.type, ColliderType::Plane);
  EXPECT_NEAR(distanceAt(floor, Eigen::Vector3d(3.0, -2.0, 0.5)), 0.4, 1e-12);
  EXPECT_NEAR(distanceAt(floor, Eigen::Vector3d(0.0, 0.0, 0.0)), -0.1, 1e-12);

  // A cylinder 0.4 m high of radius 0.05 at (1.0, 0.3, 0.5), its axis turned from z onto x: the
  // capsule around it, its side 0.05 m from the axis, its round ends 0.05 m beyond the flat ones.
  PlacedCollider y = box("post", 1.0, 0.3, 0.5, 0.0, 0.0, 0.0);
  y.shape.type = shape_msgs::SolidPrimitive::CYLINDER;
  y.shape.dimensions = {0.4, 0.05};
  y.pose.orientation.w = y.pose.orientation.y = std::sqrt(0.5);
  const Collider post = colliderFromMessage(y, "colliders[3]", kOffset, 3);
  EXPECT_EQ(post.type, ColliderType::Capsule);
  EXPECT_NEAR(distanceAt(post, Eigen::Vector3d(0.1, 0.3, 0.15)), 0.1, 1e-12);  // beside its side
  EXPECT_NEAR(distanceAt(post, Eigen::Vector3d(0.3, 0.3, 0.0)), 0.05, 1e-12);  // beyond a flat end
  EXPECT_NEAR(distanceAt(post, Eigen::Vector3d(0.0, 0.3, 0.0)), -0.05, 1e-12);  // on its axis
}

TEST(ColliderMessages, EveryBadColliderIsRefusedByFieldNameWithWhatIsAllowed)
{
  const double nan = std::numeric_limits<double>::quiet_NaN();
  struct Case
  {
    std::string what;
    std::function<void(PlacedCollider&)> spoil;
    std::string field;
  };
  const std::vector<Case> cases{
      {"NaN position", [&](PlacedCollider& m) { m.pose.position.y = nan; }, "colliders[0] ('t').pose.position"},
      {"NaN orientation", [&](PlacedCollider& m) { m.pose.orientation.x = nan; }, ".pose.orientation"},
      {"zero quaternion", [](PlacedCollider& m) { m.pose.orientation.w = 0.0; }, "must be a unit quaternion"},
      {"far position", [](PlacedCollider& m) { m.pose.position.x = 2e6; }, ".pose.position"},
      {"negative size", [](PlacedCollider& m) { m.shape.dimensions[1] = -0.1; }, ".shape.dimensions"},
      {"zero size", [](PlacedCollider& m) { m.shape.dimensions[2] = 0.0; }, "each must be a number > 0"},
      {"NaN size", [&](PlacedCollider& m) { m.shape.dimensions[0] = nan; }, ".shape.dimensions"},
      {"two sizes", [](PlacedCollider& m) { m.shape.dimensions.pop_back(); }, "needs 3 numbers"},
      {"sphere of three", [](PlacedCollider& m) { m.shape.type = shape_msgs::SolidPrimitive::SPHERE; }, "needs 1 number"},
      {"cylinder of three", [](PlacedCollider& m) { m.shape.type = shape_msgs::SolidPrimitive::CYLINDER; }, "needs 2 numbers"},
      {"cone", [](PlacedCollider& m) { m.shape.type = shape_msgs::SolidPrimitive::CONE; }, ".shape.type = 4"},
      {"unknown type", [](PlacedCollider& m) { m.shape.type = 9; }, "must be BOX (1"},
      {"plane with sizes", [](PlacedCollider& m) { m.shape.type = 0; }, "takes none"},
      {"plane without normal", [](PlacedCollider& m) { m.shape.type = 0, m.shape.dimensions.clear(); }, ".plane.coef"},
      {"plane far away", [](PlacedCollider& m) { m.shape.type = 0, m.shape.dimensions.clear(), m.plane.coef = {0.0, 0.0, 1e-9, 1.0}; }, "within 1e6 m of the pose's origin"},
      {"negative friction", [](PlacedCollider& m) { m.friction = -0.1; }, ".friction = -0.1"},
      {"NaN friction", [&](PlacedCollider& m) { m.friction = nan; }, "finite Coulomb coefficient >= 0"},
      {"empty id", [](PlacedCollider& m) { m.id.clear(); }, "colliders[0].id"},
  };
  for (const Case& c : cases)
  {
    PlacedCollider m = box("t", 1.0, 0.0, 0.0, 0.4, 0.2, 0.1);
    c.spoil(m);
    const std::string why = refusal([&] { colliderFromMessage(m, "colliders[0]", kOffset, 3); });
    EXPECT_NE(why.find(c.field), std::string::npos) << c.what << ": '" << why << "'";
  }
  // A 2D grid (the x-z plane): a box off the plane, or turned out of it, would push along y.
  PlacedCollider off = box("t", 1.0, 0.1, 0.0, 0.4, 0.4, 0.1);
  EXPECT_NE(refusal([&] { colliderFromMessage(off, "colliders[0]", kOffset, 2); }).find("2D grid"), std::string::npos);
  PlacedCollider turned = box("t", 1.0, 0.0, 0.0, 0.4, 0.4, 0.1);
  turned.pose.orientation.w = turned.pose.orientation.z = std::sqrt(0.5);
  EXPECT_NE(refusal([&] { colliderFromMessage(turned, "colliders[0]", kOffset, 2); }).find("turn about y only"),
            std::string::npos);
  turned.pose.orientation.z = 0.0;
  turned.pose.orientation.y = std::sqrt(0.5);
  EXPECT_EQ(refusal([&] { colliderFromMessage(turned, "colliders[0]", kOffset, 2); }), "") << "a turn about y keeps the plane";
}

TEST(ColliderMessages, StartUpCollidersAreNamedByIndexUnlessGivenAnIdAndEachIdOnce)
{
  std::vector<Collider> colliders(3);
  colliders[1].id = "table";
  nameColliders(colliders);
  EXPECT_EQ(colliders[0].id, "collider_0");
  EXPECT_EQ(colliders[1].id, "table");
  EXPECT_EQ(colliders[2].id, "collider_2");
  colliders[2].id = "table";
  const std::string why = refusal([&] { nameColliders(colliders); });
  EXPECT_NE(why.find("colliders[2].id"), std::string::npos) << why;
  EXPECT_NE(why.find("colliders[1]"), std::string::npos) << why;
}

TEST(ColliderMessages, TheParametersCollidersAreReadWithTheirIds)
{
  const auto collider = [](const std::string& id) {
    XmlRpc::XmlRpcValue c;
    c["type"] = "plane";
    for (int k = 0; k < 3; ++k)
    {
      c["point"][k] = 0.0;
      c["normal"][k] = k == 2 ? 1.0 : 0.0;
    }
    c["point"][2] = -1.0;
    if (!id.empty())
      c["id"] = id;
    return c;
  };
  XmlRpc::XmlRpcValue params;
  params["dimension"] = 3;
  params["colliders"][0] = collider("floor");
  params["colliders"][1] = collider("");
  NodeConfiguration c = loadNodeConfiguration(XmlRpcParameterSource(params), {});
  ASSERT_EQ(c.simulation.colliders.size(), 2u);
  EXPECT_EQ(c.simulation.colliders[0].id, "floor");
  EXPECT_EQ(c.simulation.colliders[1].id, "collider_1");
  params["colliders"][1] = collider("floor");
  const std::string why = refusal([&] { loadNodeConfiguration(XmlRpcParameterSource(params), {}); });
  EXPECT_NE(why.find("'colliders[1].id' = 'floor'"), std::string::npos) << why;
}

TEST(ColliderMessages, SetReplacesTheWholeSetAndUpdateReplacesAddsAndRemovesById)
{
  std::vector<Collider> current(3);
  current[0].id = "floor";
  current[1].id = "table";
  current[2].id = "cup";
  SetColliders::Request request;
  request.operation = SetColliders::Request::SET;
  request.colliders = {box("box", 1.0, 0.0, 0.0, 0.4, 0.2, 0.1)};
  ColliderChange change = changeColliders(current, request, kOffset, 3);
  ASSERT_EQ(change.colliders.size(), 1u);
  EXPECT_EQ(change.colliders[0].id, "box");
  EXPECT_EQ(change.keep, std::vector<int>{-1});

  request.operation = SetColliders::Request::UPDATE;
  request.colliders = {box("table", 1.0, 0.0, 0.0, 0.4, 0.2, 0.1), box("shelf", 1.0, 0.0, 1.0, 0.4, 0.2, 0.1)};
  request.remove = {"floor"};
  change = changeColliders(current, request, kOffset, 3);
  ASSERT_EQ(change.colliders.size(), 3u);
  EXPECT_EQ(change.colliders[0].id, "table");
  EXPECT_EQ(change.colliders[0].type, ColliderType::Box) << "replaced in its place";
  EXPECT_EQ(change.colliders[1].id, "cup");
  EXPECT_EQ(change.colliders[2].id, "shelf");
  EXPECT_EQ(change.keep, (std::vector<int>{-1, 2, -1})) << "the cup goes on as it was";

  struct Bad
  {
    std::string what;
    std::function<void(SetColliders::Request&)> spoil;
    std::string said;
  };
  const std::vector<Bad> bad{
      {"unknown id", [](SetColliders::Request& r) { r.remove = {"chair"}; }, "remove[0] = 'chair': is not a collider's id (the colliders: 'floor', 'table', 'cup')"},
      {"removed twice", [](SetColliders::Request& r) { r.remove = {"cup", "cup"}; }, "remove[1] = 'cup': is listed twice"},
      {"replaced and removed", [](SetColliders::Request& r) { r.remove = {"table"}; }, "not both"},
      {"duplicate ids", [](SetColliders::Request& r) { r.colliders[1].id = "table"; }, "colliders[1].id = 'table': is also the id of colliders[0]"},
      {"remove with SET", [](SetColliders::Request& r) { r.operation = SetColliders::Request::SET; }, "must be empty with SET"},
      {"unknown operation", [](SetColliders::Request& r) { r.operation = 7; }, "operation = 7: must be SET (0"},
      {"a bad collider", [](SetColliders::Request& r) { r.colliders[1].shape.dimensions[0] = -1.0; }, "colliders[1] ('shelf').shape.dimensions"},
  };
  for (const Bad& b : bad)
  {
    SetColliders::Request r = request;
    b.spoil(r);
    const std::string why = refusal([&] { changeColliders(current, r, kOffset, 3); });
    EXPECT_NE(why.find(b.said), std::string::npos) << b.what << ": '" << why << "'";
  }
}
