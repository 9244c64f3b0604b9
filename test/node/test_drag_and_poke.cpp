// Dragging and poking by hand, without a master: the particle a point takes, the drag spring and its
// stability when held over a step, the poke's direction, the forces each track gets, the parameters.
#include "drag_and_poke.h"
#include "node_params.h"
#include "xmlrpc_parameter_source.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <cmath>
#include <limits>

using namespace modal_mass_spring;

namespace
{

GridParams sheet3D(double rotation_deg = 0.0)
{
  GridParams g;
  g.dimension = 3;  // 5 x 5, top row (particles 0-4) fixed
  g.rotation_deg = rotation_deg;
  return g;
}

// The message of the std::invalid_argument that loading the node's parameters throws, or "".
std::string refusal(XmlRpc::XmlRpcValue values)
{
  try
  {
    const XmlRpcParameterSource source(values);
    loadNodeConfiguration(source, source.keys());
  }
  catch (const std::invalid_argument& error)
  {
    return error.what();
  }
  return "";
}

}  // namespace

TEST(DragAndPoke, NearestFreeParticleSkipsFixedAndHandleParticles)
{
  GridParams params = sheet3D();
  params.fixed = {0, 1, 2, 3, 4};
  params.handles = {{5, 6}};
  const Grid grid(params);
  const Eigen::Matrix3Xd points = grid.toPoints(grid.initialPositions());
  // On a fixed particle, on a handle particle: the free ones nearest to them.
  EXPECT_EQ(nearestFreeParticle(grid, points, points.col(2)), 7);
  EXPECT_EQ(nearestFreeParticle(grid, points, points.col(5)), 10);
  // Among free ones, the nearest: every other free particle is farther.
  const Eigen::Vector3d point = points.col(18) + Eigen::Vector3d(0.02, 0.3, -0.01);
  const int nearest = nearestFreeParticle(grid, points, point);
  EXPECT_EQ(nearest, 18);
  for (int p = 0; p < grid.numParticles(); ++p)
  {
    if (!grid.isFixed(p) && !grid.isHandle(p))
    {
      EXPECT_LE((points.col(nearest) - point).norm(), (points.col(p) - point).norm());
    }
  }
}

TEST(DragAndPoke, DragSpringIsTheGradientOfItsPotentialPlusDamping)
{
  const double k = 40.0, c = 0.3;
  const Eigen::Vector3d target(0.3, -0.2, 0.5), x(0.1, 0.4, -0.2), v(1.0, -2.0, 0.5);
  // Without velocity it is -grad of k/2 |target - x|^2, by central differences.
  auto potential = [&](const Eigen::Vector3d& y) { return 0.5 * k * (target - y).squaredNorm(); };
  const Eigen::Vector3d f = dragForce(k, c, target, x, Eigen::Vector3d::Zero());
  const double h = 1e-6;
  for (int d = 0; d < 3; ++d)
  {
    const Eigen::Vector3d e = h * Eigen::Vector3d::Unit(d);
    EXPECT_NEAR(f[d], -(potential(x + e) - potential(x - e)) / (2 * h), 1e-6);
  }
  EXPECT_TRUE(dragForce(k, c, target, target, Eigen::Vector3d::Zero()).isZero(0.0));
  // The damping opposes the velocity, linearly.
  EXPECT_TRUE((dragForce(k, c, target, x, v) - f).isApprox(-c * v));
}

// The spring is computed at the start of a step and held over it; a particle alone on it, moved by
// that constant force exactly over each step, must lose energy with the damping and gains it without.
TEST(DragAndPoke, DampingKeepsTheHeldSpringStableUpToTheLargestStiffness)
{
  const GridParams grid = sheet3D();
  const double dt = 0.005, m = grid.mass;
  const double k_max = maxDragStiffness(grid, dt);
  EXPECT_DOUBLE_EQ(k_max * dt * dt / m, 1.0) << "one radian per step for the particle alone";
  auto amplitude = [&](double k, double c) {
    double x = 0.1, v = 0.0;  // from the target
    for (int step = 0; step < 2000; ++step)
    {
      const double a = (-k * x - c * v) / m;
      x += v * dt + 0.5 * a * dt * dt;
      v += a * dt;
    }
    return std::hypot(x, v * std::sqrt(m / k));
  };
  for (const double k : {0.01 * k_max, 0.5 * k_max, k_max})
  {
    EXPECT_LT(amplitude(k, dragDamping(k, m)), 1e-3) << "k = " << k;
    EXPECT_GT(amplitude(k, 0.0), 0.1) << "k = " << k << ": without damping the held spring does not decay";
  }
}

TEST(DragAndPoke, DefaultsScaleWithTheGridAndStayInRange)
{
  GridParams grid = sheet3D();
  const double weight = grid.mass * grid.rows * grid.cols * grid.gravity.norm();
  EXPECT_DOUBLE_EQ(defaultDragStiffness(grid, 0.001), weight / 0.1) << "well below the step's limit";
  // Many light particles at a long step: the limit decides.
  grid.rows = grid.cols = 50;
  grid.mass = 1e-4;
  EXPECT_DOUBLE_EQ(defaultDragStiffness(grid, 0.01), 0.5 * maxDragStiffness(grid, 0.01));
  EXPECT_GT(defaultPokeImpulse(grid), 0.0);
  EXPECT_LT(defaultPokeImpulse(grid), maxPokeImpulse(grid));
  // Heavier grids get proportionally more.
  GridParams heavy = grid;
  heavy.mass *= 3.0;
  EXPECT_DOUBLE_EQ(defaultPokeImpulse(heavy), 3.0 * defaultPokeImpulse(grid));
}

TEST(DragAndPoke, PokeDirectionIsTheSheetsNormal)
{
  // The unturned 3D sheet lies in the x-z plane; its rows along +x, its columns down -z.
  const Grid flat(sheet3D());
  const Eigen::Matrix3Xd flat_points = flat.toPoints(flat.initialPositions());
  for (const int p : {6, 12, 24, 20})
    EXPECT_TRUE(pokeDirection(flat, flat_points, p).isApprox(Eigen::Vector3d::UnitY())) << p;
  // Turned about x, the normal turns with it: unit and across both tangents.
  const Grid turned(sheet3D(30.0));
  const Eigen::Matrix3Xd points = turned.toPoints(turned.initialPositions());
  const Eigen::Vector3d n = pokeDirection(turned, points, 12);
  EXPECT_NEAR(n.norm(), 1.0, 1e-12);
  EXPECT_NEAR(n.dot(points.col(13) - points.col(11)), 0.0, 1e-12);
  EXPECT_NEAR(n.dot(points.col(17) - points.col(7)), 0.0, 1e-12);
  EXPECT_TRUE(n.isApprox(Eigen::AngleAxisd(M_PI / 6, Eigen::Vector3d::UnitX()) * Eigen::Vector3d::UnitY()) ||
              n.isApprox(Eigen::AngleAxisd(-M_PI / 6, Eigen::Vector3d::UnitX()) * Eigen::Vector3d::UnitY()))
      << n.transpose();
  // A 2D grid cannot move across its plane: in the plane, across the particle's row (down the grid).
  const Grid net{GridParams{}};
  const Eigen::Matrix3Xd net_points = net.toPoints(net.initialPositions());
  EXPECT_TRUE(pokeDirection(net, net_points, 12).isApprox(-Eigen::Vector3d::UnitZ()));
  // All neighbours at one point: still a unit direction.
  const Eigen::Matrix3Xd collapsed = Eigen::Matrix3Xd::Zero(3, flat.numParticles());
  EXPECT_NEAR(pokeDirection(flat, collapsed, 12).norm(), 1.0, 1e-12);
}

TEST(DragAndPoke, ParticleVectorsInTwoAndThreeDimensions)
{
  const Grid net{GridParams{}};
  Eigen::VectorXd all = Eigen::VectorXd::Zero(net.numDofs());
  addParticleVector(net, 7, Eigen::Vector3d(1.0, 5.0, -2.0), all);
  EXPECT_EQ(particleVector(net, all, 7), Eigen::Vector3d(1.0, 0.0, -2.0)) << "y dropped in 2D";
  EXPECT_DOUBLE_EQ(all.cwiseAbs().sum(), 3.0);
  EXPECT_EQ(gridPoint(net, Eigen::Vector2d(3.0, -4.0)), Eigen::Vector3d(3.0, 0.0, -4.0)) << "x, z in 2D";
  const Grid sheet(sheet3D());
  EXPECT_EQ(gridPoint(sheet, Eigen::Vector3d(3.0, 5.0, -4.0)), Eigen::Vector3d(3.0, 5.0, -4.0));
  all = Eigen::VectorXd::LinSpaced(sheet.numDofs(), 1.0, sheet.numDofs());
  EXPECT_EQ(particleVector(sheet, all, 21), all.segment<3>(63));
}

TEST(DragAndPoke, EachTrackIsPulledFromItsOwnStateAndPokedOnce)
{
  const Grid grid(sheet3D());
  const double k = 20.0, dt = 0.005;
  HandForces hand(grid, 2);
  hand.configure(k, grid.particleMass(), dt);
  const Eigen::VectorXd applied = Eigen::VectorXd::Constant(grid.numDofs(), 0.25);
  const Eigen::VectorXd x0 = grid.initialPositions();
  const Eigen::Vector3d at_rest = Eigen::Vector3d::Zero();
  EXPECT_FALSE(hand.nextForce(0, applied, at_rest, at_rest)) << "nothing by hand: the applied force stands";

  const int p = 22;
  const Eigen::Vector3d x0p = particleVector(grid, x0, p);
  hand.grab(p, x0p + Eigen::Vector3d(0.0, 0.1, 0.0));
  const Eigen::Vector3d x1p = x0p + Eigen::Vector3d(0.0, 0.04, 0.0);  // track 1's particle is further along
  const auto f0 = hand.nextForce(0, applied, x0p, at_rest);
  const auto f1 = hand.nextForce(1, applied, x1p, Eigen::Vector3d(0.0, 0.5, 0.0));
  ASSERT_TRUE(f0 && f1);
  const double c = dragDamping(k, grid.particleMass());
  EXPECT_TRUE((*f0 - applied).segment<3>(3 * p).isApprox(Eigen::Vector3d(0.0, k * 0.1, 0.0)));
  EXPECT_TRUE((*f1 - applied).segment<3>(3 * p).isApprox(Eigen::Vector3d(0.0, k * 0.06 - c * 0.5, 0.0)));
  EXPECT_DOUBLE_EQ((*f0 - applied).cwiseAbs().sum(), k * 0.1) << "on the grabbed particle only";

  // A poke is a force impulse / dt on the next step of each track, once.
  hand.release();
  hand.poke(12, Eigen::Vector3d(0.0, 0.02, 0.0));
  for (size_t track : {0, 1})
  {
    const auto poked = hand.nextForce(track, applied, at_rest, at_rest);
    ASSERT_TRUE(poked);
    EXPECT_NEAR(((*poked - applied) * dt).segment<3>(3 * 12).y(), 0.02, 1e-15);
    EXPECT_DOUBLE_EQ((*poked - applied).cwiseAbs().sum() * dt, 0.02);
    // The step after: the applied force alone, once, then nothing more to set.
    const auto after = hand.nextForce(track, applied, at_rest, at_rest);
    ASSERT_TRUE(after);
    EXPECT_EQ(*after, applied);
    EXPECT_FALSE(hand.nextForce(track, applied, at_rest, at_rest));
  }
  // A track that cannot step lets its poke go; the other still gets it.
  hand.poke(12, Eigen::Vector3d(0.0, 0.02, 0.0));
  hand.skip(1);
  EXPECT_TRUE(hand.active(0));
  EXPECT_FALSE(hand.active(1));
  EXPECT_NE(*hand.nextForce(0, applied, at_rest, at_rest), applied);
}

TEST(DragAndPoke, ParametersAreCheckedByName)
{
  auto with = [](const std::string& key, double value) {
    XmlRpc::XmlRpcValue values;
    values[key] = value;
    return values;
  };
  // The paper's grid: 0.01 kg particles, 1 ms steps, 0.25 kg in all.
  EXPECT_EQ(refusal(with("drag_stiffness", 0.0)), "");
  EXPECT_EQ(refusal(with("drag_stiffness", 9999.0)), "");
  EXPECT_EQ(refusal(with("poke_impulse", 0.0)), "");
  EXPECT_EQ(refusal(with("poke_impulse", 2.4)), "");
  const std::vector<std::pair<XmlRpc::XmlRpcValue, std::string>> cases{
      {with("drag_stiffness", -1.0), "invalid parameter 'drag_stiffness' = -1: must be a number >= 0 and <= 10000 N/m"},
      {with("drag_stiffness", 1.0001e4), "invalid parameter 'drag_stiffness' = 10001"},
      {with("drag_stiffness", std::numeric_limits<double>::quiet_NaN()), "invalid parameter 'drag_stiffness' = nan"},
      {with("poke_impulse", -0.1), "invalid parameter 'poke_impulse' = -0.1: must be a number >= 0 and <= 2.5 N s"},
      {with("poke_impulse", 3.0), "invalid parameter 'poke_impulse' = 3"},
      {with("poke_impulse", std::numeric_limits<double>::infinity()), "invalid parameter 'poke_impulse' = inf"},
  };
  for (const auto& [values, expected] : cases)
  {
    const std::string message = refusal(values);
    EXPECT_EQ(message.substr(0, expected.size()), expected) << "got: " << message;
  }
  // Defaults come from the grid.
  XmlRpc::XmlRpcValue none;
  none["rows"] = 5;
  const XmlRpcParameterSource source(none);
  const NodeConfiguration c = loadNodeConfiguration(source, source.keys());
  EXPECT_DOUBLE_EQ(c.node.drag_stiffness, defaultDragStiffness(c.grid, c.simulation.time_step));
  EXPECT_DOUBLE_EQ(c.node.poke_impulse, defaultPokeImpulse(c.grid));
}
