// The moving-frame formulation of handles: the grid simulated in the frame of the one rigid body
// that holds every handle. Checked against `full` driven in world coordinates (setHandleMotion with
// the handle particles' rigid path), against the same methods with constraint modes, against a
// frame at rest (today's results) and, for the inertial forces themselves, against finite
// differences of known motions seen from a moving frame.
#include "modal_mass_spring/handles.h"
#include "modal_mass_spring/simulation.h"

#include <Eigen/Geometry>
#include "test_support.h"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <limits>
#include <string>

using namespace modal_mass_spring;

namespace
{

// A sheet hanging from a handle that holds its top row, nothing fixed.
GridParams topHeld(int dimension, int size = 5)
{
  GridParams g;
  g.rows = g.cols = size;
  g.dimension = dimension;
  g.fixed.clear();
  std::vector<int> top;
  for (int c = 0; c < size; ++c)
    top.push_back(c);
  g.handles = {top};
  return g;
}

SimulationParams frameParams(Method method, int num_modes, HandleFormulation formulation, double dt,
                             double alpha = 0.0, double beta = 0.0)
{
  SimulationParams s;
  s.method = method;
  s.num_modes = num_modes;
  s.alpha = alpha;
  s.beta = beta;
  s.time_step = dt;
  s.handle_formulation = formulation;
  s.handles_one_body = true;
  return s;
}

// A smooth 0 -> 1 over [0, 1] with zero velocity and acceleration at both ends, and its derivatives.
struct Ramp
{
  double s, ds, dds;
};
Ramp ramp(double t)
{
  if (t >= 1.0)
    return {1.0, 0.0, 0.0};
  return {t * t * t * (10.0 - 15.0 * t + 6.0 * t * t), 30.0 * t * t * (1.0 - t) * (1.0 - t),
          60.0 * t * (1.0 - t) * (1.0 - 2.0 * t)};
}

// The handle's path in 1 s: a translation by `shift`, or a turn by `angle` about `axis` through
// `pivot`, along the ramp. Closed forms: x = p + R y with p = c + shift s - R c.
FrameMotion path(double t, const Eigen::Vector3d& shift, const Eigen::Vector3d& axis, double angle,
                 const Eigen::Vector3d& pivot)
{
  const Ramp r = ramp(t);
  FrameMotion m;
  m.rotation = Eigen::AngleAxisd(angle * r.s, axis).toRotationMatrix();
  m.angular_velocity = angle * r.ds * axis;
  m.angular_acceleration = angle * r.dds * axis;
  const Eigen::Vector3d turned = m.rotation * pivot;
  const Eigen::Vector3d& w = m.angular_velocity;
  m.translation = pivot + r.s * shift - turned;
  m.velocity = r.ds * shift - w.cross(turned);
  m.acceleration = r.dds * shift - m.angular_acceleration.cross(turned) - w.cross(w.cross(turned));
  return m;
}

using Path = std::function<FrameMotion(double)>;

// The handle particles' world positions, velocities and accelerations under B's motion, as
// setHandleMotion takes them (x, z in 2D).
void handleMotion(const Simulation& sim, const FrameMotion& m, Eigen::VectorXd& x, Eigen::VectorXd& v,
                  Eigen::VectorXd& a)
{
  const int dim = sim.grid().dimension();
  const std::vector<int> rows = gridAxes(dim);
  const std::vector<int>& dofs = sim.grid().handleDofs();
  const Eigen::Matrix3Xd points = sim.grid().toPoints(sim.linearizationPositions());
  x.resize(dofs.size());
  v.resize(dofs.size());
  a.resize(dofs.size());
  for (size_t k = 0; k < dofs.size(); k += dim)
  {
    const Eigen::Vector3d r = m.rotation * points.col(dofs[k] / dim);
    const Eigen::Vector3d& w = m.angular_velocity;
    const Eigen::Vector3d xp = m.translation + r, vp = m.velocity + w.cross(r),
                          ap = m.acceleration + m.angular_acceleration.cross(r) + w.cross(w.cross(r));
    for (int c = 0; c < dim; ++c)
    {
      x[k + c] = xp[rows[c]];
      v[k + c] = vp[rows[c]];
      a[k + c] = ap[rows[c]];
    }
  }
}

// Steps to time `duration`, the motion at the end of each step: world `full` through setHandleMotion,
// a moving frame through setHandleFrameMotion.
void drive(Simulation& sim, const Path& motion, double duration, bool world)
{
  const double dt = sim.params().time_step;
  const int steps = static_cast<int>(std::lround(duration / dt));
  for (int k = 0; k < steps; ++k)
  {
    const FrameMotion m = motion(sim.time() + dt);
    if (world)
    {
      Eigen::VectorXd x, v, a;
      handleMotion(sim, m, x, v, a);
      sim.setHandleMotion(x, v, a);
    }
    else
    {
      sim.setHandleFrameMotion(m);
    }
    ASSERT_EQ(sim.step().steps_taken, 1) << "step " << k;
  }
}

double largestDifference(const Eigen::VectorXd& a, const Eigen::VectorXd& b) { return (a - b).cwiseAbs().maxCoeff(); }

// World `full` against a moving-frame method at dt and dt / 2 over 1.5 s (the motion and 0.5 s
// after): the two solve the same equations, so their difference is the time discretisation's and
// shrinks by 4 when dt halves (second order). Returns the difference at dt / 2.
double convergesToWorldFull(const GridParams& g, Method method, int num_modes, const Path& motion, double alpha,
                            double beta, double dt, const std::string& what)
{
  double difference[2];
  for (int halving = 0; halving < 2; ++halving)
  {
    const double h = dt / (1 << halving);
    Simulation world(g, frameParams(Method::Full, num_modes, HandleFormulation::ConstraintModes, h, alpha, beta));
    Simulation frame(g, frameParams(method, num_modes, HandleFormulation::MovingFrame, h, alpha, beta));
    drive(world, motion, 1.5, true);
    drive(frame, motion, 1.5, false);
    EXPECT_GT(largestDifference(world.positions(), world.startPositions()), 0.15) << what;
    difference[halving] = largestDifference(frame.positions(), world.positions());
    const double velocity = largestDifference(frame.velocity(), world.velocity());
    EXPECT_LT(velocity, 1e-3) << what;
    // Both hold the handle particles on the path exactly.
    Eigen::VectorXd x, v, a;
    handleMotion(world, motion(frame.time()), x, v, a);
    for (int k = 0; k < g.dimension * g.cols; ++k)
      EXPECT_NEAR(frame.positions()[frame.grid().handleDofs()[k]], x[k], 1e-12) << what;
    EXPECT_TRUE(frame.energyCheckSuspended());
  }
  EXPECT_GT(difference[0], 1e-9) << what;  // not identical: two discretisations
  EXPECT_GT(difference[0] / difference[1], 3.5) << what << ": " << difference[0] << " then " << difference[1];
  EXPECT_LT(difference[0] / difference[1], 4.5) << what << ": " << difference[0] << " then " << difference[1];
  return difference[1];
}

}  // namespace

TEST(MovingFrame, TranslatingFrameMatchesWorldFull)
{
  // The top edge moves 0.5 m in 1 s (diagonally; in 2D within its plane), then holds.
  for (int dim : {2, 3})
  {
    const Eigen::Vector3d shift = dim == 3 ? Eigen::Vector3d(0.3, 0.3, 0.3) : Eigen::Vector3d(0.4, 0.0, 0.3);
    const Path motion = [&](double t) { return path(t, shift, Eigen::Vector3d::UnitZ(), 0.0, Eigen::Vector3d::Zero()); };
    for (Method method : {Method::Full, Method::Physical})
      convergesToWorldFull(topHeld(dim), method, dim * 20, motion, 0.5, 1e-3, 1e-3,
                           toString(method) + " " + std::to_string(dim) + "D");
  }
}

TEST(MovingFrame, TurningFrameMatchesWorldFull)
{
  // A quarter turn in 1 s about z (out of the hanging sheet's plane) about the middle of the held
  // top edge, and about x (tilting it) about a point 0.2 m above it, which swings the edge
  // forward; 2D: about y, the plane's normal.
  GridParams g = topHeld(3);
  const Eigen::Vector3d pivot(0.2, 0.0, 0.0);
  for (const Eigen::Vector3d& axis : {Eigen::Vector3d::UnitZ().eval(), Eigen::Vector3d::UnitX().eval()})
  {
    const Eigen::Vector3d centre = axis.z() > 0 ? pivot : Eigen::Vector3d(0.2, 0.0, 0.2);
    const Path motion = [&](double t) { return path(t, Eigen::Vector3d::Zero(), axis, M_PI / 2, centre); };
    for (Method method : {Method::Full, Method::Physical})
      convergesToWorldFull(g, method, 60, motion, 0.5, 0.0, 1e-3,
                           toString(method) + " turning about " + (axis.z() > 0 ? "z" : "x"));
  }
  const Path planar = [&](double t) { return path(t, Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitY(), M_PI / 2, pivot); };
  convergesToWorldFull(topHeld(2), Method::Physical, 40, planar, 0.5, 0.0, 1e-3, "physical 2D turning about y");
}

TEST(MovingFrame, HoldsASlowQuarterTurnAboutTheVerticalWhereConstraintModesDistort)
{
  // A 6 x 6 cloth hanging at its equilibrium from a handle on its top row, turned a quarter about the
  // vertical through the row's middle in 2 s: the cloth turns nearly rigidly. Psi is linear in the
  // handles' displacement, (R - I) x_b, which at 90 degrees squeezes the row it spans; in the frame
  // the turn is exact and only its slow inertial forces are left to the modes. r = 10 of 90 interior
  // dofs, the implicit integrator; measured: 4.7 cm in the frame, 36 cm with constraint modes.
  GridParams g = topHeld(3, 6);
  g.bending = true;
  g.structural_stiffness = 50.0;
  g.shear_stiffness = 20.0;
  g.bending_stiffness = 5.0;
  auto params = [](Method method, HandleFormulation formulation) {
    SimulationParams s = frameParams(method, 10, formulation, 1e-3, 0.5);
    s.linearization = Linearization::Equilibrium;
    s.initial_state = InitialState::Equilibrium;
    s.integrator = IntegratorKind::Implicit;
    return s;
  };
  const Path motion = [](double t) {
    FrameMotion m = path(0.5 * t, Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitZ(), M_PI / 2,
                         Eigen::Vector3d(0.25, 0.0, 0.0));
    // Half the pace: velocities and accelerations scale by 1/2 and 1/4.
    m.velocity *= 0.5;
    m.angular_velocity *= 0.5;
    m.acceleration *= 0.25;
    m.angular_acceleration *= 0.25;
    return m;
  };
  Simulation world(g, params(Method::Full, HandleFormulation::ConstraintModes));
  Simulation modes(g, params(Method::Physical, HandleFormulation::ConstraintModes));
  Simulation frame(g, params(Method::Physical, HandleFormulation::MovingFrame));
  double modes_error = 0.0, frame_error = 0.0;
  const int steps = 2500;
  for (int k = 0; k < steps; ++k)
  {
    const FrameMotion m = motion((k + 1) * 1e-3);
    for (Simulation* sim : {&world, &modes, &frame})
    {
      sim->setHandleFrameMotion(m);
      ASSERT_EQ(sim->step().steps_taken, 1);
    }
    modes_error = std::max(modes_error, (modes.points() - world.points()).colwise().norm().maxCoeff());
    frame_error = std::max(frame_error, (frame.points() - world.points()).colwise().norm().maxCoeff());
  }
  EXPECT_GT((world.points() - world.grid().toPoints(world.startPositions()))
                .colwise()
                .norm()
                .maxCoeff(),
            0.3);
  EXPECT_GT(modes_error, 0.2);
  EXPECT_LT(frame_error, 0.25 * modes_error) << frame_error << " m in the frame, " << modes_error << " m with constraint modes";
}

TEST(MovingFrame, EveryInteriorModeIsFullInTheFrame)
{
  // `physical` spanning the interior and `full` solve the same equations in B with the same scheme:
  // round-off apart, under the turning frame's every term, both integrators, with Rayleigh damping
  // whose stiffness part makes the explicit scheme's velocity solve a factorisation, not a division.
  const Path motion = [](double t) {
    return path(t, Eigen::Vector3d(0.2, 0.1, 0.1), Eigen::Vector3d(1.0, 0.0, 1.0).normalized(), M_PI / 2,
                Eigen::Vector3d(0.2, 0.0, 0.0));
  };
  for (IntegratorKind integrator : {IntegratorKind::Explicit, IntegratorKind::Implicit})
  {
    SimulationParams s = frameParams(Method::Full, 60, HandleFormulation::MovingFrame, 2e-3, 0.5, 1e-3);
    s.integrator = integrator;
    s.hht_alpha = 0.0;
    Simulation full(topHeld(3), s);
    s.method = Method::Physical;
    Simulation physical(topHeld(3), s);
    drive(full, motion, 1.2, false);
    drive(physical, motion, 1.2, false);
    EXPECT_GT(largestDifference(full.positions(), full.startPositions()), 0.2);
    EXPECT_LT(largestDifference(physical.positions(), full.positions()), 1e-9) << toString(integrator);
    EXPECT_LT(largestDifference(physical.velocity(), full.velocity()), 1e-8) << toString(integrator);
  }
}

TEST(MovingFrame, ImplicitFrameMatchesImplicitWorldFull)
{
  // The gyroscopic and non-symmetric terms through Newton: second order still (HHT alpha 0).
  const Path motion = [](double t) {
    return path(t, Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitZ(), M_PI / 2, Eigen::Vector3d(0.2, 0.0, 0.0));
  };
  double difference[2];
  for (int halving = 0; halving < 2; ++halving)
  {
    SimulationParams s = frameParams(Method::Full, 60, HandleFormulation::ConstraintModes, 4e-3 / (1 << halving), 0.5);
    s.integrator = IntegratorKind::Implicit;
    s.hht_alpha = 0.0;
    Simulation world(topHeld(3), s);
    s.handle_formulation = HandleFormulation::MovingFrame;
    s.method = Method::Physical;
    Simulation frame(topHeld(3), s);
    drive(world, motion, 1.5, true);
    drive(frame, motion, 1.5, false);
    difference[halving] = largestDifference(frame.positions(), world.positions());
  }
  EXPECT_GT(difference[0] / difference[1], 3.5) << difference[0] << " then " << difference[1];
  EXPECT_LT(difference[0] / difference[1], 4.5) << difference[0] << " then " << difference[1];
}

TEST(MovingFrame, TranslationMatchesConstraintModesForEveryMethod)
{
  // A translation is a constraint mode exactly (Psi carries a uniform shift uniformly), and its
  // inertial load is B's: with constraint modes or in B every method solves the same modal
  // equations, to round-off, few modes or many.
  const Path motion = [](double t) {
    return path(t, Eigen::Vector3d(0.3, 0.0, 0.4), Eigen::Vector3d::UnitY(), 0.0, Eigen::Vector3d::Zero());
  };
  for (Method method : {Method::Linear, Method::Physical, Method::Cubature})
  {
    Simulation modes(topHeld(2), frameParams(method, 6, HandleFormulation::ConstraintModes, 1e-3, 0.5, 1e-3));
    Simulation frame(topHeld(2), frameParams(method, 6, HandleFormulation::MovingFrame, 1e-3, 0.5, 1e-3));
    drive(modes, motion, 1.2, false);
    drive(frame, motion, 1.2, false);
    EXPECT_GT(largestDifference(frame.positions(), frame.startPositions()), 0.3) << toString(method);
    EXPECT_LT(largestDifference(frame.positions(), modes.positions()), 1e-11) << toString(method);
    EXPECT_LT(largestDifference(frame.velocity(), modes.velocity()), 1e-9) << toString(method);
  }
}

TEST(MovingFrame, FrameAtRestGivesTodaysResults)
{
  GridParams fixed = topHeld(2);
  fixed.handles.clear();  // today: the top row fixed
  for (Method method : {Method::Full, Method::Linear, Method::Physical, Method::Cubature})
  {
    Simulation today(fixed, frameParams(method, 6, HandleFormulation::Auto, 1e-3, 0.2));
    Simulation modes(topHeld(2), frameParams(method, 6, HandleFormulation::ConstraintModes, 1e-3, 0.2));
    Simulation frame(topHeld(2), frameParams(method, 6, HandleFormulation::Auto, 1e-3, 0.2));
    EXPECT_EQ(frame.handleFormulation(), HandleFormulation::MovingFrame);
    EXPECT_EQ(today.handleFormulation(), HandleFormulation::ConstraintModes);
    for (int k = 0; k < 300; ++k)
    {
      frame.setHandleFrameMotion(FrameMotion{});
      frame.step();
      modes.step();
      today.step();
    }
    EXPECT_GT(largestDifference(frame.positions(), frame.startPositions()), 1e-3) << toString(method);
    EXPECT_EQ(frame.positions(), modes.positions()) << toString(method);
    EXPECT_LT(largestDifference(frame.positions(), today.positions()), 1e-12) << toString(method);
    EXPECT_FALSE(frame.energyCheckSuspended());
    EXPECT_EQ(frame.totalEnergy(), modes.totalEnergy());
  }
}

TEST(MovingFrame, InertialForcesMatchFiniteDifferences)
{
  // A known turning, accelerating frame; a particle seen from it whose world motion is known in
  // closed form: falling under gravity against drag alpha (x'' = g - alpha x'). In B its
  // acceleration must be what the frame's forces say, with the force models' g and the damping's
  // -alpha y' added: y'' = g + uniform - position y - 2 spin y' - alpha y'.
  const Eigen::Vector3d gravity(0.0, 0.0, -9.81), axis = Eigen::Vector3d(0.3, -0.5, 0.8).normalized();
  const double alpha = 0.7;
  auto frame = [&](double t) {
    FrameMotion m;
    const double angle = 0.8 * t + 1.5 * t * t, rate = 0.8 + 3.0 * t;
    m.rotation = Eigen::AngleAxisd(angle, axis).toRotationMatrix();
    m.angular_velocity = rate * axis;
    m.angular_acceleration = 3.0 * axis;
    m.translation = Eigen::Vector3d(0.5 * t * t, std::sin(t), 0.2 * t * t * t);
    m.velocity = Eigen::Vector3d(t, std::cos(t), 0.6 * t * t);
    m.acceleration = Eigen::Vector3d(1.0, -std::sin(t), 1.2 * t);
    return m;
  };
  const Eigen::Vector3d x0(0.3, -0.2, 0.5), v0(0.1, 0.4, -0.3);
  auto world = [&](double t) {
    const Eigen::Vector3d terminal = gravity / alpha;
    return Eigen::Vector3d(x0 + terminal * t + (v0 - terminal) * (1.0 - std::exp(-alpha * t)) / alpha);
  };
  auto body = [&](double t) {
    const FrameMotion m = frame(t);
    return Eigen::Vector3d(m.rotation.transpose() * (world(t) - m.translation));
  };
  for (double t : {0.0, 0.4, 1.3})
  {
    const double h = 1e-4;
    const Eigen::Vector3d y = body(t), dy = (body(t + h) - body(t - h)) / (2.0 * h),
                          ddy = (body(t + h) - 2.0 * y + body(t - h)) / (h * h);
    const FrameForces f = frameForces(frame(t), 3, gravity, alpha);
    const Eigen::Vector3d predicted = gravity + f.uniform - f.position * y - 2.0 * f.spin * dy - alpha * dy;
    EXPECT_LT((predicted - ddy).norm(), 1e-5 * (1.0 + ddy.norm())) << "t " << t;
    EXPECT_GT((ddy - gravity).norm(), 1.0);  // the frame's forces matter here
    // The world rotation of B's vectors, and the Coriolis term's skew form.
    EXPECT_LT((f.rotation - frame(t).rotation).norm(), 1e-15);
    EXPECT_LT((f.spin + f.spin.transpose()).norm(), 1e-15);
  }
  // A 2D grid keeps x and z of a turn about y.
  FrameMotion planar;
  planar.rotation = Eigen::AngleAxisd(0.4, Eigen::Vector3d::UnitY()).toRotationMatrix();
  planar.angular_velocity = Eigen::Vector3d(0.0, 2.0, 0.0);
  const FrameForces f2 = frameForces(planar, 2, gravity, 0.0);
  const FrameForces f3 = frameForces(planar, 3, gravity, 0.0);
  EXPECT_EQ(f2.position, f3.position(std::vector<int>{0, 2}, std::vector<int>{0, 2}));
  EXPECT_TRUE(f3.position.row(1).isZero(0.0) && f3.position.col(1).isZero(0.0));
  EXPECT_TRUE(frameForces(FrameMotion{}, 3, gravity, alpha).none);
  EXPECT_TRUE(frameForces(FrameMotion{}, 3, gravity, alpha).uniform.isZero(0.0));
}

TEST(MovingFrame, InterpolatedFrameIsTheHandlesSlerpedPath)
{
  // The node's frame path: B's motion from the frame's start pose, along a tick from `from` to `to`,
  // moves the offsets as interpolateRigidMotion moves them, and its velocities are the path's.
  FramePose start, from, to;
  start.translation << 0.1, 0.0, 0.5;
  start.rotation = Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitY());
  from.translation << 0.3, 0.1, 0.4;
  from.rotation = Eigen::AngleAxisd(0.5, Eigen::Vector3d::UnitX());
  to.translation << 0.5, 0.3, 0.2;
  to.rotation = Eigen::AngleAxisd(1.2, Eigen::Vector3d(1.0, 1.0, 0.0).normalized());
  Eigen::Matrix3Xd points(3, 3);
  points << 0.0, 0.2, 0.4, 0.0, 0.1, -0.1, 0.5, 0.5, 0.3;  // where the particles are at the start pose
  const Eigen::Matrix3Xd offsets = start.rotation.conjugate().toRotationMatrix() * (points.colwise() - start.translation);
  const double duration = 0.1;
  for (double s : {0.0, 0.3, 1.0})
  {
    const RigidPointMotion expected = interpolateRigidMotion(offsets, from, to, duration, s);
    const RigidPointMotion moved = pointMotion(interpolateFrameMotion(start, from, to, duration, s), points);
    EXPECT_LT((moved.position - expected.position).norm(), 1e-14) << s;
    EXPECT_LT((moved.velocity - expected.velocity).norm(), 1e-13) << s;
    EXPECT_LT((moved.acceleration - expected.acceleration).norm(), 1e-12) << s;
  }
  // Slerp turns at a constant rate: no angular acceleration.
  EXPECT_TRUE(interpolateFrameMotion(start, from, to, duration, 0.5).angular_acceleration.isZero(0.0));
  // From the start pose, at rest, B is at rest.
  EXPECT_TRUE(interpolateFrameMotion(start, start, start, duration, 0.7).atRest() ||
              interpolateFrameMotion(start, start, start, duration, 0.7).translation.norm() < 1e-15);
}

TEST(MovingFrame, BadFormulationsAndMotionsAreNamed)
{
  auto build = [](const GridParams& g, SimulationParams s) { return refusal([&] { Simulation sim(g, s); }); };
  SimulationParams s = frameParams(Method::Physical, 4, HandleFormulation::MovingFrame, 1e-3);
  GridParams none = topHeld(2);
  none.handles.clear();
  EXPECT_TRUE(contains(build(none, s), "'handle_formulation' = moving_frame: needs handles (the grid has none)"));
  GridParams fixed = topHeld(2);
  fixed.handles = {{24}};
  fixed.fixed = {0, 1, 2, 3, 4};
  EXPECT_TRUE(contains(build(fixed, s), "'handle_formulation' = moving_frame: needs a grid with no fixed particles (it has 5)"));
  s.handles_one_body = false;
  EXPECT_TRUE(contains(build(topHeld(2), s), "needs every handle moved as one rigid body"));
  EXPECT_TRUE(contains(refusal([] { parseHandleFormulation("frame"); }),
                       "'handle_formulation' = 'frame': must be one of auto, constraint_modes, moving_frame"));
  // auto: the moving frame only where it applies.
  s.handle_formulation = HandleFormulation::Auto;
  EXPECT_EQ(resolveHandleFormulation(topHeld(2), s), HandleFormulation::ConstraintModes);  // not one body
  s.handles_one_body = true;
  EXPECT_EQ(resolveHandleFormulation(topHeld(2), s), HandleFormulation::MovingFrame);
  EXPECT_EQ(resolveHandleFormulation(fixed, s), HandleFormulation::ConstraintModes);
  EXPECT_EQ(resolveHandleFormulation(none, s), HandleFormulation::ConstraintModes);

  Simulation sim(topHeld(2), s);
  Eigen::VectorXd x, v, a;
  handleMotion(sim, FrameMotion{}, x, v, a);
  EXPECT_TRUE(contains(refusal([&] { sim.setHandleMotion(x); }), "prescribe that body's motion with setHandleFrameMotion"));
  FrameMotion turn;
  turn.rotation = Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  EXPECT_TRUE(contains(refusal([&] { sim.setHandleFrameMotion(turn); }), "a 2D grid's frame may only turn about y"));
  FrameMotion spin;
  spin.angular_velocity.x() = 1.0;
  EXPECT_TRUE(contains(refusal([&] { sim.setHandleFrameMotion(spin); }), "a 2D grid's frame may only turn about y"));
  FrameMotion sheared;
  sheared.rotation(0, 2) = 0.1;
  EXPECT_TRUE(contains(refusal([&] { sim.setHandleFrameMotion(sheared); }), "'handle frame rotation'"));
  FrameMotion nan;
  nan.acceleration.z() = std::numeric_limits<double>::quiet_NaN();
  EXPECT_TRUE(contains(refusal([&] { sim.setHandleFrameMotion(nan); }), "'handle frame acceleration' = a non-finite value"));
  Simulation plain(none, frameParams(Method::Physical, 4, HandleFormulation::Auto, 1e-3));
  EXPECT_TRUE(contains(refusal([&] { plain.setHandleFrameMotion(FrameMotion{}); }), "the grid has no handles"));
  // Nothing changed: the grid hangs on as before.
  sim.step(10);
  EXPECT_FALSE(sim.energyCheckSuspended());
  EXPECT_TRUE(sim.positions().allFinite());
  // A frame turning so fast that the explicit step's Coriolis iteration cannot converge (dt |omega|
  // = 3): the step is refused with why, the last good state kept.
  FrameMotion fast;
  fast.angular_velocity.y() = 3000.0;
  const Eigen::VectorXd before = sim.positions();
  sim.setHandleFrameMotion(fast);
  const StepResult result = sim.step();
  EXPECT_TRUE(result.diverged);
  EXPECT_TRUE(contains(result.message, "the frame turns too fast for time_step")) << result.message;
  EXPECT_EQ(sim.positions(), before);
}

TEST(MovingFrame, ConstraintModesTakeTheFrameAsTheHandlesRigidPath)
{
  // With constraint modes, setHandleFrameMotion is setHandleMotion with the particles' rigid motion.
  const Path motion = [](double t) {
    return path(t, Eigen::Vector3d(0.1, 0.0, 0.2), Eigen::Vector3d::UnitY(), 0.5, Eigen::Vector3d(0.2, 0.0, 0.0));
  };
  Simulation by_frame(topHeld(2), frameParams(Method::Physical, 6, HandleFormulation::ConstraintModes, 1e-3, 0.5));
  Simulation by_particles(topHeld(2), frameParams(Method::Physical, 6, HandleFormulation::ConstraintModes, 1e-3, 0.5));
  drive(by_frame, motion, 0.5, false);
  drive(by_particles, motion, 0.5, true);
  EXPECT_LT(largestDifference(by_frame.positions(), by_particles.positions()), 1e-13);
}

TEST(MovingFrame, SwitchesResetsAndExternalForcesInAMovedFrame)
{
  const Path motion = [](double t) {
    return path(t, Eigen::Vector3d(0.2, 0.1, 0.0), Eigen::Vector3d::UnitZ(), M_PI / 2, Eigen::Vector3d(0.2, 0.0, 0.0));
  };
  Simulation sim(topHeld(3), frameParams(Method::Physical, 10, HandleFormulation::MovingFrame, 1e-3, 0.5));
  drive(sim, motion, 0.6, false);
  // A switch moves no particle, in world coordinates, and the state's world velocity carries over.
  for (Method method : {Method::Full, Method::Linear, Method::Cubature, Method::Physical})
  {
    const Eigen::VectorXd before = sim.positions(), velocity = sim.velocity();
    sim.setMethod(method);
    EXPECT_LT(largestDifference(sim.positions(), before), 1e-12) << toString(method);
    if (method == Method::Full)
    {
      EXPECT_LT(largestDifference(sim.velocity(), velocity), 1e-12);
    }
    sim.setHandleFrameMotion(sim.frameMotion());
    sim.step(10);
    EXPECT_FALSE(sim.diverged()) << toString(method);
  }
  // setPhysicalState takes world coordinates in a moved frame: giving back the state changes nothing.
  sim.setMethod(Method::Full);
  const Eigen::VectorXd u = sim.displacement(), v = sim.velocity();
  sim.setPhysicalState(u, v);
  EXPECT_LT(largestDifference(sim.displacement(), u), 1e-12);
  EXPECT_LT(largestDifference(sim.velocity(), v), 1e-12);
  // An external force acts in world coordinates: a force along world +y on the bottom corner pulls it
  // along world +y, though B has turned a quarter about z (B's y is world -x there).
  drive(sim, motion, 0.6, false);
  Simulation pushed(topHeld(3), frameParams(Method::Full, 10, HandleFormulation::MovingFrame, 1e-3, 0.5));
  Simulation free(topHeld(3), frameParams(Method::Full, 10, HandleFormulation::MovingFrame, 1e-3, 0.5));
  for (Simulation* s : {&pushed, &free})
    drive(*s, motion, 1.0, false);
  Eigen::VectorXd force = Eigen::VectorXd::Zero(3 * 25);
  force[3 * 24 + 1] = 0.05;
  pushed.setExternalForce(force);
  for (Simulation* s : {&pushed, &free})
    drive(*s, motion, 0.1, false);
  const Eigen::Vector3d moved = (pushed.points() - free.points()).col(24);
  EXPECT_GT(moved.y(), 1e-3);
  EXPECT_LT(std::abs(moved.x()), 0.2 * moved.y());
  // Another simulation takes the state over in the frame where it has gone (a live rebuild).
  Simulation rebuilt(topHeld(3), frameParams(Method::Full, 10, HandleFormulation::MovingFrame, 1e-3, 0.5));
  rebuilt.placeFrame(sim.frameMotion());
  rebuilt.setPhysicalState(sim.displacement(), sim.velocity());
  EXPECT_LT(largestDifference(rebuilt.positions(), sim.positions()), 1e-12);
  EXPECT_LT(largestDifference(rebuilt.velocity(), sim.velocity()), 1e-12);
  EXPECT_TRUE(rebuilt.energyCheckSuspended());
  // A reset puts B back at its start.
  sim.reset();
  EXPECT_TRUE(sim.frameMotion().atRest());
  EXPECT_LT(largestDifference(sim.positions(), sim.startPositions()), 1e-15);
  EXPECT_FALSE(sim.energyCheckSuspended());
}

TEST(MovingFrame, OneParticlesStateIsWhatTheWholeGridsSays)
{
  // particleState reads one particle in O(r); it must agree with positions() and velocity() in both
  // formulations, with the handles moved and the frame turning, for every method.
  const Path motion = [](double t) {
    return path(t, Eigen::Vector3d(0.2, 0.1, 0.0), Eigen::Vector3d::UnitZ(), M_PI / 2, Eigen::Vector3d(0.2, 0.0, 0.0));
  };
  for (int dimension : {2, 3})
    for (HandleFormulation formulation : {HandleFormulation::ConstraintModes, HandleFormulation::MovingFrame})
      for (Method method : {Method::Full, Method::Linear, Method::Physical, Method::Cubature})
      {
        SimulationParams params = frameParams(method, 10, formulation, 1e-3, 0.5);
        params.linearization = Linearization::Equilibrium;  // a 3D sheet at rest has no Psi
        Simulation sim(topHeld(dimension), params);
        // 2D: a turn about z would leave the x-z plane; the frame turns about y there.
        const Path planar = [&](double t) {
          return dimension == 3 ? motion(t)
                                : path(t, Eigen::Vector3d(0.2, 0.0, 0.1), Eigen::Vector3d::UnitY(), M_PI / 4,
                                       Eigen::Vector3d(0.2, 0.0, 0.0));
        };
        drive(sim, planar, 0.5, formulation == HandleFormulation::ConstraintModes);
        // A while under `full` leaves the modes; the switch back keeps what they cannot hold as an
        // offset, to be read with the rest.
        const bool world = formulation == HandleFormulation::ConstraintModes;
        sim.setMethod(method == Method::Full ? Method::Physical : Method::Full);
        drive(sim, planar, 0.05, world);
        sim.setMethod(method);
        drive(sim, planar, 0.05, world);
        const std::string what = std::to_string(dimension) + "D " + toString(method) +
                                 (formulation == HandleFormulation::MovingFrame ? " moving frame" : " constraint modes");
        // One particle first, before positions() and velocity() could have brought anything up to date.
        const Grid& grid = sim.grid();
        std::vector<Eigen::VectorXd> positions(grid.numParticles()), velocities(grid.numParticles());
        for (int p = 0; p < grid.numParticles(); ++p)
        {
          if (grid.isHandle(p))
            EXPECT_THROW(sim.particleState(p, positions[p], velocities[p]), std::invalid_argument) << what << " " << p;
          else
            sim.particleState(p, positions[p], velocities[p]);
        }
        const Eigen::VectorXd x = sim.positions(), v = sim.velocity();
        ASSERT_GT(v.cwiseAbs().maxCoeff(), 1e-3) << what << ": the grid moves";
        for (int p = 0; p < grid.numParticles(); ++p)
        {
          if (grid.isHandle(p))
            continue;
          const Eigen::VectorXd& position = positions[p];
          const Eigen::VectorXd& velocity = velocities[p];
          EXPECT_LT(largestDifference(position, x.segment(dimension * p, dimension)), 1e-12) << what << " particle " << p;
          EXPECT_LT(largestDifference(velocity, v.segment(grid.freeIndex(dimension * p), dimension)), 1e-12)
              << what << " particle " << p;
        }
        Eigen::VectorXd position, velocity;
        EXPECT_THROW(sim.particleState(-1, position, velocity), std::invalid_argument);
        EXPECT_THROW(sim.particleState(grid.numParticles(), position, velocity), std::invalid_argument);
      }
  // A fixed particle has no state of its own to read.
  Simulation paper(GridParams{}, frameParams(Method::Physical, 4, HandleFormulation::Auto, 1e-3));
  Eigen::VectorXd position, velocity;
  EXPECT_THROW(paper.particleState(2, position, velocity), std::invalid_argument);
  paper.particleState(12, position, velocity);
  EXPECT_LT(largestDifference(position, paper.positions().segment(2 * 12, 2)), 1e-15);
}
