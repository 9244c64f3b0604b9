// Handle scenarios: read from YAML, checked against the grid, and their rigid motion per step.
#include "handle_scenarios.h"

#include "modal_mass_spring/validation.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <set>
#include <stdexcept>

namespace modal_mass_spring
{
namespace
{

constexpr double kPi = 3.14159265358979323846;
constexpr double kMaxSeconds = 1000.0;   // a move or hold longer than this is a typo, not an experiment
constexpr double kMaxTranslation = 1e3;  // m
constexpr size_t kMaxWaypoints = 1000;

// The value as written, on one line and cut short.
std::string shown(const YAML::Node& node)
{
  std::string text = YAML::Dump(node);
  std::replace(text.begin(), text.end(), '\n', ' ');
  return text.size() > 60 ? text.substr(0, 57) + "..." : text;
}

double number(const YAML::Node& node, const std::string& name)
{
  if (node.IsScalar())
    try
    {
      const double value = node.as<double>();
      if (std::isfinite(value))
        return value;
    }
    catch (const YAML::Exception&)
    {
    }
  rejectParameter(name, "'" + shown(node) + "'", "must be a finite number");
}

Eigen::Vector3d vector3(const YAML::Node& node, const std::string& name)
{
  if (!node.IsSequence() || node.size() != 3)
    rejectParameter(name, "'" + shown(node) + "'", "must be a list of three numbers [x, y, z] (grid coordinates)");
  Eigen::Vector3d v;
  for (int k = 0; k < 3; ++k)
    v[k] = number(node[k], name);
  return v;
}

std::vector<int> particleList(const YAML::Node& node, const std::string& name)
{
  if (!node.IsSequence() || node.size() == 0)
    rejectParameter(name, "'" + shown(node) + "'", "must be a non-empty list of particle indices (row * cols + col)");
  std::vector<int> particles;
  for (const YAML::Node& item : node)
  {
    try
    {
      if (item.IsScalar())
      {
        particles.push_back(item.as<int>());
        continue;
      }
    }
    catch (const YAML::Exception&)
    {
    }
    rejectParameter(name, "'" + shown(item) + "'", "particle indices must be integers (row * cols + col)");
  }
  return particles;
}

// Refuses a key of `map` outside `known`: most likely misspelled.
void checkKeys(const YAML::Node& map, const std::string& name, const std::set<std::string>& known)
{
  std::string allowed;
  for (const std::string& k : known)
    allowed += (allowed.empty() ? "" : ", ") + k;
  for (const auto& entry : map)
    if (!known.count(entry.first.Scalar()))
      rejectParameter(name + "." + entry.first.Scalar(), "'" + shown(entry.second) + "'",
                      "unknown key: the keys are " + allowed);
}

double rotationDeg(const YAML::Node& node, const std::string& name)
{
  const double deg = number(node, name);
  if (std::abs(deg) > 360.0)
    rejectParameter(name, deg, "must be in [-360, 360] degrees");
  return deg;
}

Eigen::Vector3d translation(const YAML::Node& node, const std::string& name)
{
  const Eigen::Vector3d t = vector3(node, name);
  if (t.cwiseAbs().maxCoeff() > kMaxTranslation)
    rejectParameter(name, "'" + shown(node) + "'",
                    "each component must be within +-" + std::to_string(static_cast<int>(kMaxTranslation)) + " m");
  return t;
}

std::vector<HandlePose> waypointList(const YAML::Node& node, const std::string& name)
{
  if (!node.IsSequence() || node.size() == 0 || node.size() > kMaxWaypoints)
    rejectParameter(name, "'" + shown(node) + "'",
                    "must be a list of 1 to " + std::to_string(kMaxWaypoints) +
                        " poses {translation: [x, y, z], rotation_deg: D}, visited in turn");
  std::vector<HandlePose> poses;
  for (size_t k = 0; k < node.size(); ++k)
  {
    const std::string item = name + "[" + std::to_string(k) + "]";
    if (!node[k].IsMap())
      rejectParameter(item, "'" + shown(node[k]) + "'", "must be a map {translation: [x, y, z], rotation_deg: D}");
    checkKeys(node[k], item, {"translation", "rotation_deg"});
    HandlePose pose;
    if (node[k]["translation"])
      pose.translation = translation(node[k]["translation"], item + ".translation");
    if (node[k]["rotation_deg"])
      pose.rotation_deg = rotationDeg(node[k]["rotation_deg"], item + ".rotation_deg");
    poses.push_back(pose);
  }
  return poses;
}

HandlePath parseHandle(const YAML::Node& node, const std::string& name)
{
  if (!node.IsMap())
    rejectParameter(name, "'" + shown(node) + "'",
                    "must be a map {particles: [...], translation: [x, y, z], rotation_axis: [x, y, z], rotation_deg: D}");
  checkKeys(node, name, {"particles", "translation", "rotation_axis", "rotation_deg", "waypoints"});
  HandlePath path;
  if (!node["particles"])
    rejectParameter(name, "'" + shown(node) + "'", "needs 'particles', the indices the handle holds");
  path.particles = particleList(node["particles"], name + ".particles");
  if (node["translation"])
    path.translation = translation(node["translation"], name + ".translation");
  if (node["rotation_axis"])
  {
    const Eigen::Vector3d axis = vector3(node["rotation_axis"], name + ".rotation_axis");
    if (!(axis.norm() > 1e-9))
      rejectParameter(name + ".rotation_axis", "'" + shown(node["rotation_axis"]) + "'", "must not be zero");
    path.rotation_axis = axis.normalized();
  }
  if (node["rotation_deg"])
    path.rotation_deg = rotationDeg(node["rotation_deg"], name + ".rotation_deg");
  if (node["waypoints"])
  {
    if (node["translation"] || node["rotation_deg"])
      rejectParameter(name + ".waypoints", "'" + shown(node["waypoints"]) + "'",
                      "give either waypoints or one target (translation, rotation_deg), not both");
    path.waypoints = waypointList(node["waypoints"], name + ".waypoints");
  }
  return path;
}

HandleScenario parseScenario(const YAML::Node& node, const std::string& name)
{
  if (!node.IsMap())
    rejectParameter(name, "'" + shown(node) + "'", "must be a map {name: ..., handles: [...], move_time: s, hold_time: s}");
  checkKeys(node, name, {"name", "handles", "move_time", "hold_time"});
  HandleScenario scenario;
  if (!node["name"] || !node["name"].IsScalar())
    rejectParameter(name + ".name", "'" + (node["name"] ? shown(node["name"]) : std::string()) + "'",
                    "each scenario needs a name");
  scenario.name = node["name"].Scalar();
  const bool word = !scenario.name.empty() && std::all_of(scenario.name.begin(), scenario.name.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) || c == '_';
  });
  if (!word)
    rejectParameter(name + ".name", "'" + scenario.name + "'", "must be a non-empty word of letters, digits and '_'");
  if (node["move_time"])
  {
    scenario.move_time = number(node["move_time"], name + ".move_time");
    if (!(scenario.move_time > 0.0 && scenario.move_time <= kMaxSeconds))
      rejectParameter(name + ".move_time", scenario.move_time, "must be in (0, 1000] s");
  }
  if (node["hold_time"])
  {
    scenario.hold_time = number(node["hold_time"], name + ".hold_time");
    if (!(scenario.hold_time >= 0.0 && scenario.hold_time <= kMaxSeconds))
      rejectParameter(name + ".hold_time", scenario.hold_time, "must be in [0, 1000] s");
  }
  const YAML::Node handles = node["handles"];
  if (!handles || !handles.IsSequence() || handles.size() == 0)
    rejectParameter(name + ".handles", "'" + (handles ? shown(handles) : std::string()) + "'",
                    "must be a non-empty list of handles {particles: [...], translation: ..., rotation_axis: ..., "
                    "rotation_deg: ...}");
  for (size_t h = 0; h < handles.size(); ++h)
    scenario.handles.push_back(parseHandle(handles[h], name + ".handles[" + std::to_string(h) + "]"));
  return scenario;
}

}  // namespace

Ramp moveRamp(double t, double move_time)
{
  const double tau = std::clamp(t / move_time, 0.0, 1.0);
  const double rest = 1.0 - tau;
  return {tau * tau * tau * (10.0 - 15.0 * tau + 6.0 * tau * tau), 30.0 * tau * tau * rest * rest / move_time,
          60.0 * tau * rest * (1.0 - 2.0 * tau) / (move_time * move_time)};
}

std::vector<HandlePose> pathLegs(const HandlePath& path)
{
  if (!path.waypoints.empty())
    return path.waypoints;
  return {HandlePose{path.translation, path.rotation_deg}};
}

RigidFrameMotion frameMotion(const HandlePath& path, const Eigen::Vector3d& start_origin, double move_time, double t)
{
  const std::vector<HandlePose> legs = pathLegs(path);
  const int n = static_cast<int>(legs.size());
  const double leg_time = move_time / n;
  const int k = std::clamp(static_cast<int>(std::floor(t / leg_time)), 0, n - 1);
  const HandlePose from = k > 0 ? legs[k - 1] : HandlePose{};
  const HandlePose& to = legs[k];
  const Ramp ramp = moveRamp(t - k * leg_time, leg_time);
  const Eigen::Vector3d shift = to.translation - from.translation;
  const double from_angle = from.rotation_deg * kPi / 180.0;
  const double angle = (to.rotation_deg - from.rotation_deg) * kPi / 180.0;
  RigidFrameMotion frame;
  frame.origin = start_origin + from.translation + ramp.s * shift;
  frame.velocity = ramp.ds * shift;
  frame.acceleration = ramp.dds * shift;
  // A fixed axis: the angular velocity and acceleration are the ramp's rates along it.
  frame.rotation = Eigen::Quaterniond(Eigen::AngleAxisd(from_angle + ramp.s * angle, path.rotation_axis));
  frame.angular_velocity = ramp.ds * angle * path.rotation_axis;
  frame.angular_acceleration = ramp.dds * angle * path.rotation_axis;
  return frame;
}

RigidPointMotion pointsOnFrame(const RigidFrameMotion& frame, const Eigen::Matrix3Xd& offsets)
{
  // The offsets are points of a frame whose translation is the origin: the core's rigid point motion.
  FrameMotion carried;
  carried.translation = frame.origin;
  carried.rotation = frame.rotation.toRotationMatrix();
  carried.velocity = frame.velocity;
  carried.acceleration = frame.acceleration;
  carried.angular_velocity = frame.angular_velocity;
  carried.angular_acceleration = frame.angular_acceleration;
  return pointMotion(carried, offsets);
}

std::vector<HandleScenario> parseHandleScenarios(const YAML::Node& node, const std::string& key)
{
  if (!node.IsSequence() || node.size() == 0)
    rejectParameter(key, "'" + shown(node) + "'",
                    "must be a non-empty list of scenarios {name: ..., handles: [...], move_time: s, hold_time: s}");
  std::vector<HandleScenario> scenarios;
  for (size_t k = 0; k < node.size(); ++k)
  {
    const std::string name = key + "[" + std::to_string(k) + "]";
    scenarios.push_back(parseScenario(node[k], name));
    for (size_t j = 0; j + 1 < scenarios.size(); ++j)
      if (scenarios[j].name == scenarios.back().name)
        rejectParameter(name + ".name", "'" + scenarios.back().name + "'",
                        "each scenario needs its own name (also " + key + "[" + std::to_string(j) + "])");
  }
  return scenarios;
}

GridParams gridWithHandles(const GridParams& grid, const HandleScenario& scenario)
{
  GridParams g = grid;
  g.handles.clear();
  for (const HandlePath& path : scenario.handles)
    g.handles.push_back(path.particles);
  try
  {
    validateGridParams(g);
    if (g.dimension == 2)
      for (size_t h = 0; h < scenario.handles.size(); ++h)
      {
        const HandlePath& path = scenario.handles[h];
        const std::string name = "handles[" + std::to_string(h) + "]";
        // A 2D grid lives in the x-z plane: it can move along x and z and turn about y only.
        for (const HandlePose& pose : pathLegs(path))
        {
          if (pose.translation.y() != 0.0)
            rejectParameter(name + (path.waypoints.empty() ? "" : ".waypoints") + ".translation", pose.translation.y(),
                            "a 2D grid moves in the x-z plane: y must be 0");
          if (pose.rotation_deg != 0.0 && std::abs(std::abs(path.rotation_axis.y()) - 1.0) > 1e-12)
            rejectParameter(name + ".rotation_axis", path.rotation_axis.transpose(),
                            "a 2D grid turns in the x-z plane: the axis must be [0, 1, 0]");
        }
      }
  }
  catch (const std::invalid_argument& e)
  {
    throw std::invalid_argument("handle scenario '" + scenario.name + "': " + e.what());
  }
  return g;
}

HandleDriver::HandleDriver(const HandleScenario& scenario, const Simulation& sim)
  : scenario_(scenario), dimension_(sim.grid().dimension())
{
  const Eigen::Matrix3Xd start = sim.grid().toPoints(sim.startPositions());
  for (const std::vector<int>& particles : sim.grid().handles())
  {
    Eigen::Matrix3Xd points(3, particles.size());
    for (size_t k = 0; k < particles.size(); ++k)
      points.col(k) = start.col(particles[k]);
    const Eigen::Vector3d origin = points.rowwise().mean();
    start_origins_.push_back(origin);
    offsets_.push_back(points.colwise() - origin);
  }
  if (offsets_.size() != scenario_.handles.size())
    throw std::invalid_argument("handle scenario '" + scenario_.name + "': the simulation's grid has " +
                                std::to_string(offsets_.size()) + " handles, the scenario " +
                                std::to_string(scenario_.handles.size()));
}

RigidFrameMotion HandleDriver::frame(int h, double t) const
{
  return frameMotion(scenario_.handles[h], start_origins_[h], scenario_.move_time, t);
}

void HandleDriver::particleMotion(double t, Eigen::VectorXd& positions, Eigen::VectorXd& velocities,
                                  Eigen::VectorXd& accelerations) const
{
  const std::vector<int> rows = gridAxes(dimension_);
  Eigen::Index size = 0;
  for (const Eigen::Matrix3Xd& o : offsets_)
    size += dimension_ * o.cols();
  positions.resize(size);
  velocities.resize(size);
  accelerations.resize(size);
  Eigen::Index at = 0;
  for (size_t h = 0; h < offsets_.size(); ++h)
  {
    const RigidPointMotion m = pointsOnFrame(frame(static_cast<int>(h), t), offsets_[h]);
    for (Eigen::Index k = 0; k < m.position.cols(); ++k)
      for (int row : rows)
      {
        positions[at] = m.position(row, k);
        velocities[at] = m.velocity(row, k);
        accelerations[at] = m.acceleration(row, k);
        ++at;
      }
  }
}

void HandleDriver::drive(Simulation& sim) const
{
  const double t = sim.nextStepTime();
  if (sim.handleFormulation() == HandleFormulation::MovingFrame)
  {
    sim.setHandleFrameMotion(bodyFrameMotion(t));
    return;
  }
  Eigen::VectorXd x_b, v_b, a_b;
  particleMotion(t, x_b, v_b, a_b);
  sim.setHandleMotion(x_b, v_b, a_b);
}

FrameMotion HandleDriver::bodyFrameMotion(double t) const
{
  // The handle's frame has its origin o at the particles' centroid: x = o + R (y - o_0) for a point
  // at y when it starts, so B, the frame that starts at the world's, has p = o - R o_0 and, with
  // c = R o_0, p' = o' - w x c and p'' = o'' - alpha x c - w x (w x c).
  const RigidFrameMotion f = frame(0, t);
  const Eigen::Matrix3d r = f.rotation.toRotationMatrix();
  const Eigen::Vector3d c = r * start_origins_[0];
  FrameMotion b;
  b.rotation = r;
  b.translation = f.origin - c;
  b.velocity = f.velocity - f.angular_velocity.cross(c);
  b.acceleration = f.acceleration - f.angular_acceleration.cross(c) - f.angular_velocity.cross(f.angular_velocity.cross(c));
  b.angular_velocity = f.angular_velocity;
  b.angular_acceleration = f.angular_acceleration;
  return b;
}

}  // namespace modal_mass_spring
