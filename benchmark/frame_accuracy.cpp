// Where each handle formulation holds: a cloth hanging from its top row, moved by one rigid handle
// (a translation, a quarter turn about the vertical, a quarter tilt), simulated by `linear` and
// `physical` with constraint modes and in the moving frame, and by `full` in the frame, each
// measured against `full` driven in world coordinates. Prints the largest particle distance over the
// motion and 0.5 s after.
//   frame_accuracy [size = 10] [duration T = 4 s] [num_modes = 30]
#include "modal_mass_spring/simulation.h"

#include <Eigen/Geometry>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>
#include <vector>

using namespace modal_mass_spring;

namespace
{

// B's motion along a smooth ramp over `duration` (zero velocity and acceleration at both ends): a
// shift, or a turn by `angle` about `axis` through `pivot`.
FrameMotion path(double t, double duration, const Eigen::Vector3d& shift, const Eigen::Vector3d& axis, double angle,
                 const Eigen::Vector3d& pivot)
{
  const double u = std::min(t / duration, 1.0);
  const double s = u * u * u * (10.0 - 15.0 * u + 6.0 * u * u);
  const double ds = 30.0 * u * u * (1.0 - u) * (1.0 - u) / duration;
  const double dds = 60.0 * u * (1.0 - u) * (1.0 - 2.0 * u) / (duration * duration);
  FrameMotion m;
  m.rotation = Eigen::AngleAxisd(angle * s, axis).toRotationMatrix();
  m.angular_velocity = angle * ds * axis;
  m.angular_acceleration = angle * dds * axis;
  const Eigen::Vector3d turned = m.rotation * pivot;
  const Eigen::Vector3d& w = m.angular_velocity;
  m.translation = pivot + s * shift - turned;
  m.velocity = ds * shift - w.cross(turned);
  m.acceleration = dds * shift - m.angular_acceleration.cross(turned) - w.cross(w.cross(turned));
  return m;
}

}  // namespace

int main(int argc, char** argv)
{
  const int size = argc > 1 ? std::atoi(argv[1]) : 10;
  const double duration = argc > 2 ? std::atof(argv[2]) : 4.0;
  const int num_modes = argc > 3 ? std::atoi(argv[3]) : 30;
  GridParams g;
  g.rows = g.cols = size;
  g.dimension = 3;
  g.bending = true;
  g.structural_stiffness = 50.0;
  g.shear_stiffness = 20.0;
  g.bending_stiffness = 5.0;
  g.fixed.clear();
  std::vector<int> top;
  for (int c = 0; c < size; ++c)
    top.push_back(c);
  g.handles = {top};
  const Eigen::Vector3d middle(0.5 * (size - 1) * g.spacing, 0.0, 0.0);
  struct Motion
  {
    std::string name;
    Eigen::Vector3d shift, axis, pivot;
    double angle;
  };
  const std::vector<Motion> motions{
      {"translation 0.5 m", Eigen::Vector3d(0.3, 0.3, 0.5 * std::sqrt(0.32)), Eigen::Vector3d::UnitZ(), middle, 0.0},
      {"quarter turn about z", Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitZ(), middle, M_PI / 2},
      {"quarter tilt about x, 0.2 m above", Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitX(),
       middle + Eigen::Vector3d(0.0, 0.0, 0.2), M_PI / 2}};
  auto make = [&](Method method, HandleFormulation formulation) {
    SimulationParams s;
    s.method = method;
    s.num_modes = num_modes;
    s.alpha = 0.5;
    s.time_step = 1e-3;
    s.linearization = Linearization::Equilibrium;
    s.initial_state = InitialState::Equilibrium;
    s.integrator = IntegratorKind::Implicit;
    s.hht_alpha = 0.0;
    s.handle_formulation = formulation;
    s.handles_one_body = true;
    return std::make_unique<Simulation>(g, s);
  };
  std::printf("%d x %d cloth, r = %d, T = %g s: largest particle distance to full in world coordinates\n", size, size,
              num_modes, duration);
  for (const Motion& motion : motions)
  {
    auto world = make(Method::Full, HandleFormulation::ConstraintModes);
    std::vector<std::pair<std::string, std::unique_ptr<Simulation>>> runs;
    for (Method method : {Method::Linear, Method::Physical})
      for (HandleFormulation formulation : {HandleFormulation::ConstraintModes, HandleFormulation::MovingFrame})
        runs.emplace_back(toString(method) + ", " + toString(formulation), make(method, formulation));
    runs.emplace_back("full, moving_frame", make(Method::Full, HandleFormulation::MovingFrame));
    std::vector<double> worst(runs.size(), 0.0);
    const Eigen::Matrix3Xd start = world->points();
    const int steps = static_cast<int>(std::lround((duration + 0.5) / 1e-3));
    for (int k = 0; k < steps; ++k)
    {
      const FrameMotion m = path((k + 1) * 1e-3, duration, motion.shift, motion.axis, motion.angle, motion.pivot);
      world->setHandleFrameMotion(m);
      world->step();
      for (size_t i = 0; i < runs.size(); ++i)
      {
        runs[i].second->setHandleFrameMotion(m);
        runs[i].second->step();
        worst[i] = std::max(worst[i], (runs[i].second->points() - world->points()).colwise().norm().maxCoeff());
      }
    }
    std::printf("%s (full moved up to %.3g m)\n", motion.name.c_str(),
                (world->points() - start).colwise().norm().maxCoeff());
    for (size_t i = 0; i < runs.size(); ++i)
      std::printf("  %-28s %.3g m%s\n", runs[i].first.c_str(), worst[i], runs[i].second->diverged() ? " (diverged)" : "");
  }
  return 0;
}
