// Rostest checks of a running modal_mass_spring_node: markers, TF, services, divergence. Each .test
// file runs the node on one config and picks the cases that fit it with --gtest_filter.
#include "modal_mass_spring/ApplyForce.h"
#include "modal_mass_spring/SetMethod.h"
#include "modal_mass_spring/Status.h"
#include "modal_mass_spring/Step.h"

#include <Eigen/Core>
#include <diagnostic_msgs/DiagnosticArray.h>
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <rosgraph_msgs/Clock.h>
#include <rosgraph_msgs/Log.h>
#include <sensor_msgs/PointCloud2.h>
#include <sensor_msgs/point_cloud2_iterator.h>
#include <std_srvs/SetBool.h>
#include <std_srvs/Trigger.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/static_transform_broadcaster.h>
#include <tf2_ros/transform_listener.h>
#include <geometry_msgs/PointStamped.h>
#include <visualization_msgs/InteractiveMarkerFeedback.h>
#include <visualization_msgs/MarkerArray.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <functional>
#include <limits>
#include <map>
#include <mutex>
#include <string>
#include <vector>

namespace
{

using visualization_msgs::MarkerArray;
using modal_mass_spring::Status;

template <typename T>
T param(const std::string& name, const T& fallback)
{
  T value;
  return ros::param::get(name, value) ? value : fallback;
}

// The first message on `topic` (published after the call) that satisfies `accept`, or fails the test.
template <typename Msg>
typename Msg::ConstPtr waitFor(const std::string& topic, const std::function<bool(const Msg&)>& accept = {},
                               double timeout = 15.0)
{
  ros::NodeHandle nh;
  typename Msg::ConstPtr found;
  ros::Subscriber sub = nh.subscribe<Msg>(topic, 100, [&](const typename Msg::ConstPtr& msg) {
    if (!found && (!accept || accept(*msg)))
      found = msg;
  });
  const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(timeout);
  while (!found && ros::ok() && ros::WallTime::now() < end)
    ros::WallDuration(0.005).sleep();
  EXPECT_TRUE(found) << "no matching message on " << topic << " within " << timeout << " s";
  return found;
}

// The marker of namespace `ns` in an array, or null.
const visualization_msgs::Marker* findMarker(const MarkerArray& array, const std::string& ns)
{
  for (const auto& marker : array.markers)
    if (marker.ns == ns)
      return &marker;
  return nullptr;
}

// Particle positions of a marker array (the SPHERE_LIST).
std::vector<geometry_msgs::Point> particles(const MarkerArray& array, const std::string& ns = "particles")
{
  if (const auto* marker = findMarker(array, ns))
    return marker->points;
  ADD_FAILURE() << "no " << ns << " marker";
  return {};
}

double maxDistance(const std::vector<geometry_msgs::Point>& a, const std::vector<geometry_msgs::Point>& b)
{
  EXPECT_EQ(a.size(), b.size());
  double d = 0.0;
  for (size_t k = 0; k < std::min(a.size(), b.size()); ++k)
    d = std::max(d, std::hypot(a[k].x - b[k].x, a[k].y - b[k].y, a[k].z - b[k].z));
  return d;
}

// One node under test, by its name (its private topics and services live below it).
struct NodeUnderTest
{
  explicit NodeUnderTest(const std::string& name) : name(name) {}
  std::string name;
  std::string topic(const std::string& leaf) const { return name + "/" + leaf; }

  MarkerArray::ConstPtr markers() const { return waitFor<MarkerArray>(topic("markers")); }
  Status::ConstPtr status(const std::function<bool(const Status&)>& accept = {}, double timeout = 15.0) const
  {
    return waitFor<Status>(topic("status"), accept, timeout);
  }

  // The markers published at the same tick as a status that satisfies `accept` (same stamp).
  std::pair<MarkerArray::ConstPtr, Status::ConstPtr> tick(const std::function<bool(const Status&)>& accept = {}) const
  {
    ros::NodeHandle nh;
    std::vector<MarkerArray::ConstPtr> markers;
    ros::Subscriber sub = nh.subscribe<MarkerArray>(
        topic("markers"), 100, [&](const MarkerArray::ConstPtr& msg) { markers.push_back(msg); });
    ros::WallDuration(0.2).sleep();  // connected before the status we pick
    const Status::ConstPtr status = this->status(accept);
    const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(5.0);
    while (status && ros::ok() && ros::WallTime::now() < end)
    {
      for (const auto& m : markers)
        if (!m->markers.empty() && m->markers[0].header.stamp == status->header.stamp)
          return {m, status};
      ros::WallDuration(0.005).sleep();
    }
    ADD_FAILURE() << "no markers with the stamp of the status";
    return {nullptr, status};
  }

  template <typename Srv>
  Srv call(const std::string& service, const typename Srv::Request& request) const
  {
    Srv srv;
    srv.request = request;
    EXPECT_TRUE(ros::service::waitForService(topic(service), ros::Duration(15.0))) << topic(service);
    EXPECT_TRUE(ros::service::call(topic(service), srv)) << topic(service);
    return srv;
  }
  bool pause(bool hold) const
  {
    std_srvs::SetBool::Request request;
    request.data = hold;
    return call<std_srvs::SetBool>("pause", request).response.success;
  }
  modal_mass_spring::SetMethod::Response setMethod(const std::string& method) const
  {
    modal_mass_spring::SetMethod::Request request;
    request.method = method;
    return call<modal_mass_spring::SetMethod>("set_method", request).response;
  }
  std_srvs::Trigger::Response reset() const
  {
    return call<std_srvs::Trigger>("reset", std_srvs::Trigger::Request()).response;
  }
};

std::vector<std::string> nodeNames()
{
  return param<std::vector<std::string>>("~nodes", {"/modal_mass_spring"});
}

// Where a node's parameters are: its own name, or, for a method of a lockstep comparison
// (/compare_methods/linear), the comparison node (~config_node).
std::string configNode(const std::string& name)
{
  return param<std::string>("~config_node", name);
}

// The prefix of a node's marker namespaces: <method>/ for a method of a comparison.
std::string markerPrefix(const std::string& name)
{
  return configNode(name) == name ? "" : name.substr(name.rfind('/') + 1) + "/";
}

// The grid frame of a node, or of a method of a comparison: <method>/<grid_frame>.
std::string gridFrame(const std::string& name)
{
  const std::string config = configNode(name);
  const std::string frame = param<std::string>(config + "/grid_frame", "grid");
  return config == name ? frame : name.substr(name.rfind('/') + 1) + "/" + frame;
}

// ---------------------------------------------------------------- topology and frames, any config

TEST(Topology, MarkersHaveTheGridsParticlesAndSprings)
{
  const int expected_particles = param("~expected_particles", -1);
  const int expected_springs = param("~expected_springs", -1);
  const int expected_fixed = param("~expected_fixed", -1);
  const std::string fixed_frame = param<std::string>("~fixed_frame", "world");
  ASSERT_GT(expected_particles, 0) << "the .test file must set ~expected_particles";
  for (const auto& name : nodeNames())
  {
    SCOPED_TRACE(name);
    const auto array = NodeUnderTest(name).markers();
    ASSERT_TRUE(array);
    const std::string prefix = markerPrefix(name);
    ASSERT_TRUE(findMarker(*array, prefix + "particles"));
    ASSERT_TRUE(findMarker(*array, prefix + "springs"));
    ASSERT_TRUE(findMarker(*array, prefix + "surface"));
    const auto& spheres = *findMarker(*array, prefix + "particles");
    const auto& lines = *findMarker(*array, prefix + "springs");
    const auto& surface = *findMarker(*array, prefix + "surface");
    EXPECT_EQ(spheres.id, 0);
    EXPECT_EQ(spheres.type, visualization_msgs::Marker::SPHERE_LIST);
    EXPECT_EQ(lines.id, 0);
    EXPECT_EQ(surface.type, visualization_msgs::Marker::TRIANGLE_LIST);
    EXPECT_EQ(surface.colors.size(), surface.points.size()) << "a strain colour per vertex";
    // Two triangles per cell, both windings, at every size a shipped config has.
    const int rows = param(configNode(name) + "/rows", 0), cols = param(configNode(name) + "/cols", 0);
    EXPECT_EQ(static_cast<int>(surface.points.size()), 12 * (rows - 1) * (cols - 1));
    EXPECT_EQ(lines.type, visualization_msgs::Marker::LINE_LIST);
    EXPECT_EQ(spheres.header.frame_id, fixed_frame);
    EXPECT_EQ(lines.header.frame_id, fixed_frame);
    EXPECT_EQ(static_cast<int>(spheres.points.size()), expected_particles);
    EXPECT_EQ(spheres.colors.size(), spheres.points.size());
    EXPECT_EQ(static_cast<int>(lines.points.size()), 2 * expected_springs);
    // Fixed particles have their own colour: count the particles drawn in the top row's colour.
    int fixed = 0;
    for (const auto& c : spheres.colors)
      fixed += (c.r == spheres.colors[0].r && c.g == spheres.colors[0].g && c.b == spheres.colors[0].b);
    if (expected_fixed > 0)
    {
      EXPECT_EQ(fixed, expected_fixed);
    }
    for (const auto* marker : {&spheres, &lines, &surface})
    {
      for (const auto& p : marker->points)
      {
        ASSERT_TRUE(std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z));
      }
    }
  }
}

TEST(Topology, ConfiguredFramesAreBroadcastWhereTheParticlesAre)
{
  const std::string fixed_frame = param<std::string>("~fixed_frame", "world");
  tf2_ros::Buffer buffer(ros::Duration(30.0));
  tf2_ros::TransformListener listener(buffer);
  for (const auto& name : nodeNames())
  {
    SCOPED_TRACE(name);
    const std::string grid_frame = gridFrame(name);
    // From the .test file when it names them (paper_3d relies on the default, the bottom corners).
    const auto tf_particles = param<std::vector<int>>(
        "~expected_tf_particles", param<std::vector<int>>(configNode(name) + "/tf_particles", {}));
    ASSERT_FALSE(tf_particles.empty()) << "set ~expected_tf_particles or the node's tf_particles";
    std::string error;
    EXPECT_TRUE(buffer.canTransform(fixed_frame, grid_frame, ros::Time(0), ros::Duration(10.0), &error)) << error;
    for (int particle : tf_particles)
    {
      const std::string frame = grid_frame + "/particle_" + std::to_string(particle);
      ASSERT_TRUE(buffer.canTransform(fixed_frame, frame, ros::Time(0), ros::Duration(10.0), &error))
          << frame << ": " << error;
    }
    // The transform at a marker's stamp puts the particle frame on the particle drawn.
    const auto array = NodeUnderTest(name).markers();
    ASSERT_TRUE(array);
    const auto& spheres = *findMarker(*array, markerPrefix(name) + "particles");
    for (int particle : tf_particles)
    {
      const std::string frame = grid_frame + "/particle_" + std::to_string(particle);
      ASSERT_TRUE(buffer.canTransform(fixed_frame, frame, spheres.header.stamp, ros::Duration(5.0), &error)) << error;
      const auto t = buffer.lookupTransform(fixed_frame, frame, spheres.header.stamp).transform.translation;
      const auto& p = spheres.points.at(particle);
      EXPECT_NEAR(t.x, p.x, 1e-9) << frame;
      EXPECT_NEAR(t.y, p.y, 1e-9) << frame;
      EXPECT_NEAR(t.z, p.z, 1e-9) << frame;
    }
  }
}

// ---------------------------------------------------------------- the timer, any config

// Every tick advances real_time_factor / publish_rate simulated seconds in whole steps, carrying the
// fraction: however late the ticks are (behind.test makes them very late).
TEST(Timer, StepsAFixedSimulatedTimePerTick)
{
  const std::string name = nodeNames().front();
  const double rate = param(name + "/publish_rate", 0.0);
  const double factor = param(name + "/real_time_factor", 1.0);
  const double dt = param(name + "/time_step", 0.0);
  ASSERT_GT(rate * dt, 0.0);
  const double per_tick = factor / (rate * dt);
  const int ticks = param("~ticks", 30);

  std::vector<Status::ConstPtr> statuses;
  ros::NodeHandle nh;
  ros::Subscriber sub = nh.subscribe<Status>(name + "/status", 1000, [&](const Status::ConstPtr& s) {
    if (s->state == Status::RUNNING && statuses.size() < static_cast<size_t>(ticks) + 1)
      statuses.push_back(s);
  });
  const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(ticks / rate * 100 + 30);
  while (statuses.size() < static_cast<size_t>(ticks) + 1 && ros::ok() && ros::WallTime::now() < end)
    ros::WallDuration(0.01).sleep();
  sub.shutdown();
  ASSERT_EQ(statuses.size(), static_cast<size_t>(ticks) + 1);

  for (size_t k = 1; k < statuses.size(); ++k)
  {
    const auto& s = *statuses[k];
    EXPECT_TRUE(s.tick_steps == static_cast<uint32_t>(std::floor(per_tick)) ||
                s.tick_steps == static_cast<uint32_t>(std::ceil(per_tick)))
        << s.tick_steps << " steps in a tick, expected " << per_tick;
    EXPECT_EQ(s.step_count - statuses[k - 1]->step_count, s.tick_steps) << "a tick without a status";
    EXPECT_NEAR(s.sim_time, s.step_count * dt, 1e-9 * s.sim_time);
    // What a simulated second costs: the step's CPU time over the time step.
    EXPECT_GT(s.step_cpu_seconds, 0.0);
    EXPECT_NEAR(s.cpu_per_simulated_second, s.step_cpu_seconds / dt, 1e-12 * s.cpu_per_simulated_second);
  }
  // The fraction is carried: over many ticks the steps add up to the simulated time asked for.
  const double steps = static_cast<double>(statuses.back()->step_count - statuses.front()->step_count);
  EXPECT_NEAR(steps, ticks * per_tick, 1.0);
}

// Each tick's stepping takes longer than the period (behind.test): diagnostics warn, and count those
// ticks as late (the timer's own lateness says nothing when ticks run back to back).
TEST(Timer, FallingBehindRealTimeWarnsInDiagnostics)
{
  int late = -1, ticks = -1;
  const auto is_warn = [&](const diagnostic_msgs::DiagnosticArray& a) {
    for (const auto& s : a.status)
      if (s.name.find("simulation") != std::string::npos && s.level == diagnostic_msgs::DiagnosticStatus::WARN &&
          s.message.find("falling behind") != std::string::npos)
      {
        const auto of = s.message.find(" ticks late");
        const auto start = s.message.rfind(", ", of);
        if (of == std::string::npos || start == std::string::npos ||
            std::sscanf(s.message.c_str() + start + 2, "%d of %d", &late, &ticks) != 2)
          ADD_FAILURE() << "no 'N of M ticks late' in: " << s.message;
        return true;
      }
    return false;
  };
  ASSERT_TRUE(waitFor<diagnostic_msgs::DiagnosticArray>("/diagnostics", is_warn, 30.0));
  EXPECT_GT(ticks, 0);
  EXPECT_EQ(late, ticks) << "every tick's stepping takes longer than the period here";
  // The console says it too, as a warning with what costs (the step and the steps a tick asks for);
  // throttled to one every 10 s, so wait past that.
  const auto warning = waitFor<rosgraph_msgs::Log>(
      "/rosout",
      [](const rosgraph_msgs::Log& log) {
        return log.level == rosgraph_msgs::Log::WARN && log.msg.find("falling behind real time") != std::string::npos;
      },
      25.0);
  ASSERT_TRUE(warning);
  EXPECT_NE(warning->msg.find("method full takes"), std::string::npos) << warning->msg;
  EXPECT_NE(warning->msg.find("ms a step and a tick asks for 10000.0 steps"), std::string::npos) << warning->msg;
}

// A service call is answered between two steps of a slow tick, not after the tick (behind.test: each
// tick takes thousands of steps): a pause cuts the tick short, so the first PAUSED status reports
// some steps but fewer than a whole tick's. Served only between ticks, it would report none.
TEST(Timer, ServicesAreAnsweredInTheMiddleOfASlowTick)
{
  NodeUnderTest node(nodeNames().front());
  const double rate = param(node.name + "/publish_rate", 0.0);
  const double factor = param(node.name + "/real_time_factor", 1.0);
  const double dt = param(node.name + "/time_step", 0.0);
  ASSERT_GT(rate * dt, 0.0);
  const uint32_t whole_tick = static_cast<uint32_t>(std::floor(factor / (rate * dt)));
  int cut_short = 0;
  for (int attempt = 0; attempt < 3; ++attempt)
  {
    // Listen before the call: the cut tick's status goes out as soon as the call is answered.
    std::mutex mutex;
    std::vector<Status::ConstPtr> statuses;
    ros::NodeHandle nh;
    ros::Subscriber sub = nh.subscribe<Status>(node.topic("status"), 1000, [&](const Status::ConstPtr& s) {
      std::lock_guard<std::mutex> lock(mutex);
      statuses.push_back(s);
    });
    ASSERT_TRUE(node.status([](const Status& s) { return s.state == Status::RUNNING && s.tick_steps > 0; }, 60.0));
    ros::WallDuration(0.1).sleep();  // into the next tick's stepping
    ASSERT_TRUE(node.pause(true));
    Status::ConstPtr paused;
    const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(60.0);
    while (!paused && ros::ok() && ros::WallTime::now() < end)
    {
      ros::WallDuration(0.01).sleep();
      std::lock_guard<std::mutex> lock(mutex);
      for (const auto& s : statuses)
        if (s->state == Status::PAUSED)
        {
          paused = s;
          break;
        }
    }
    sub.shutdown();
    ASSERT_TRUE(paused) << "no PAUSED status after the pause";
    cut_short += paused->tick_steps > 0 && paused->tick_steps < whole_tick;
    ASSERT_TRUE(node.pause(false));
  }
  EXPECT_GE(cut_short, 1) << "no pause landed inside a tick of " << whole_tick << " steps";
}

// ---------------------------------------------------------------- services (paper_2d, running)

// Switching method while paused moves no particle: the positions are rebuilt from the same Phi X and
// frozen offset, so they differ by round-off only; far less than one step's motion.
constexpr double kCarriedOver = 1e-9;  // m

class Services : public ::testing::Test
{
protected:
  void SetUp() override
  {
    ASSERT_TRUE(node.pause(false));
    ASSERT_TRUE(node.setMethod(param<std::string>("~start_method", "physical")).success);
    ASSERT_TRUE(node.reset().success);
  }
  void TearDown() override { node.pause(false); }

  // The largest distance a particle moves in one step, measured over two consecutive ticks.
  double stepMotion() const
  {
    const auto first = node.tick([](const Status& s) { return s.state == Status::RUNNING && s.tick_steps > 0; });
    const long steps = first.second->step_count;
    const auto second = node.tick([&](const Status& s) { return s.step_count > static_cast<uint64_t>(steps); });
    return maxDistance(particles(*first.first), particles(*second.first)) /
           static_cast<double>(second.second->step_count - steps);
  }

  // Pauses, and returns the particles as they are held.
  std::vector<geometry_msgs::Point> pauseAndHold() const
  {
    EXPECT_TRUE(node.pause(true));
    return particles(*node.tick([](const Status& s) { return s.state == Status::PAUSED; }).first);
  }

  NodeUnderTest node{"/modal_mass_spring"};
};

TEST_F(Services, PauseHoldsTheParticlesAndResumeGoesOn)
{
  ros::WallDuration(0.5).sleep();  // some motion first
  const auto held = pauseAndHold();
  const auto before = node.tick([](const Status& s) { return s.state == Status::PAUSED; });
  ros::WallDuration(0.5).sleep();
  const auto after = node.tick([](const Status& s) { return s.state == Status::PAUSED; });
  EXPECT_EQ(before.second->step_count, after.second->step_count);
  EXPECT_EQ(after.second->tick_steps, 0u);
  EXPECT_LT(before.first->markers[0].header.stamp, after.first->markers[0].header.stamp)
      << "markers keep publishing while paused";
  EXPECT_EQ(maxDistance(held, particles(*after.first)), 0.0);

  ASSERT_TRUE(node.pause(false));
  const auto running = node.status([&](const Status& s) { return s.state == Status::RUNNING; });
  ASSERT_TRUE(running);
  const auto later = node.status([&](const Status& s) { return s.step_count > running->step_count; });
  EXPECT_TRUE(later);
}

TEST_F(Services, SetMethodKeepsTheParticlesWhereTheyWere)
{
  ros::WallDuration(0.5).sleep();
  ASSERT_GT(stepMotion(), 100 * kCarriedOver) << "the grid must move for this test to mean anything";
  // From a modal method to another and to full the positions carry over exactly (same Phi X).
  for (const std::string method : {"linear", "cubature", "full"})
  {
    SCOPED_TRACE(method);
    const auto held = pauseAndHold();
    const uint64_t held_step = node.status()->step_count;
    const auto response = node.setMethod(method);
    EXPECT_TRUE(response.success) << response.message;
    const auto next = node.tick([&](const Status& s) { return s.method == method; });
    ASSERT_TRUE(next.first);
    EXPECT_EQ(next.second->state, Status::PAUSED);
    EXPECT_EQ(next.second->step_count, held_step) << "paused: no step between";
    EXPECT_LE(maxDistance(held, particles(*next.first)), kCarriedOver);
    ASSERT_TRUE(node.pause(false));
    ros::WallDuration(0.3).sleep();
  }
}

// Leaving `full` for a modal method: X = Phi^T M u, and what the r modes cannot carry stays as a
// frozen offset, so no particle jumps.
TEST_F(Services, SetMethodFromFullToModalKeepsTheParticles)
{
  ASSERT_TRUE(node.setMethod("full").success);
  ros::WallDuration(0.5).sleep();
  ASSERT_GT(stepMotion(), 100 * kCarriedOver) << "the grid must move for this test to mean anything";
  const auto held = pauseAndHold();
  ASSERT_TRUE(node.setMethod("physical").success);
  const auto next = node.tick([&](const Status& s) { return s.method == "physical"; });
  ASSERT_TRUE(next.first);
  EXPECT_EQ(next.second->state, Status::PAUSED);
  EXPECT_LE(maxDistance(held, particles(*next.first)), kCarriedOver);
}

// The first switch to `cubature` trains it; ~status then carries its training report.
TEST_F(Services, SetMethodToCubatureReportsItsTraining)
{
  const auto response = node.setMethod("cubature");
  ASSERT_TRUE(response.success) << response.message;
  const auto next = node.tick([](const Status& s) { return s.method == "cubature"; });
  ASSERT_TRUE(next.second);
  const Status& s = *next.second;
  const int rows = param("/modal_mass_spring/rows", 0), cols = param("/modal_mass_spring/cols", 0);
  const unsigned springs = static_cast<unsigned>(rows * (cols - 1) + (rows - 1) * cols + 2 * (rows - 1) * (cols - 1));
  EXPECT_GT(s.cubature_springs, 0u);
  EXPECT_LE(s.cubature_springs, springs);
  EXPECT_GT(s.cubature_training_error, 0.0);
  EXPECT_LT(s.cubature_training_error, 1.0);
  EXPECT_GT(s.cubature_heldout_error, 0.0);
  EXPECT_LT(s.cubature_heldout_error, 1.0);
  EXPECT_GT(s.cubature_training_seconds, 0.0);
  const auto later = node.status([&](const Status& t) { return t.step_count > s.step_count; });
  ASSERT_TRUE(later) << "cubature steps";
  EXPECT_EQ(later->state, Status::RUNNING);
}

TEST_F(Services, UnknownMethodIsRefusedAndChangesNothing)
{
  ros::WallDuration(0.3).sleep();
  const auto held = pauseAndHold();
  const auto before = node.status();
  const auto response = node.setMethod("implicit");
  EXPECT_FALSE(response.success);
  for (const char* word : {"implicit", "full", "linear", "physical", "cubature"})
    EXPECT_NE(response.message.find(word), std::string::npos) << response.message;
  const auto after = node.tick([](const Status&) { return true; });
  EXPECT_EQ(after.second->method, before->method);
  EXPECT_EQ(after.second->step_count, before->step_count);
  EXPECT_EQ(maxDistance(held, particles(*after.first)), 0.0);
}

TEST_F(Services, ResetRestoresTheInitialPositions)
{
  ros::WallDuration(0.5).sleep();
  pauseAndHold();
  const auto before = node.status();
  ASSERT_TRUE(before);
  ASSERT_GT(before->step_count, 0u);
  const auto response = node.reset();
  EXPECT_TRUE(response.success) << response.message;
  const auto after = node.tick([](const Status& s) { return s.step_count == 0; });
  ASSERT_TRUE(after.first);
  EXPECT_EQ(after.second->sim_time, 0.0);
  EXPECT_GT(after.second->header.stamp, before->header.stamp) << "a reset does not touch the ROS clock";

  // The initial grid, from the config: rows along -z, columns along x, drawn at offset (2D: y = 0).
  const int rows = param("/modal_mass_spring/rows", 0), cols = param("/modal_mass_spring/cols", 0);
  const double spacing = param("/modal_mass_spring/spacing", 0.0);
  const auto offset = param<std::vector<double>>("/modal_mass_spring/offset", {0.0, 0.0, 0.0});
  ASSERT_EQ(param("/modal_mass_spring/dimension", 0), 2) << "this case assumes a 2D config";
  const auto points = particles(*after.first);
  ASSERT_EQ(static_cast<int>(points.size()), rows * cols);
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c)
    {
      const auto& p = points[r * cols + c];
      EXPECT_NEAR(p.x, offset[0] + c * spacing, 1e-12);
      EXPECT_NEAR(p.y, offset[1], 1e-12);
      EXPECT_NEAR(p.z, offset[2] - r * spacing, 1e-12);
    }
  // ... and the motion starts again from there.
  ASSERT_TRUE(node.pause(false));
  EXPECT_TRUE(node.status([](const Status& s) { return s.step_count > 0 && s.state == Status::RUNNING; }));
}

// ---------------------------------------------------------------- divergence (a time step too large for full)

TEST(Divergence, HoldsTheLastGoodStateReportsErrorAndRecovers)
{
  NodeUnderTest node("/modal_mass_spring");
  const auto diverged = node.status([](const Status& s) { return s.state == Status::DIVERGED; }, 30.0);
  ASSERT_TRUE(diverged);
  EXPECT_NE(diverged->message.find("diverged"), std::string::npos) << diverged->message;

  const auto first = node.tick([](const Status& s) { return s.state == Status::DIVERGED; });
  ros::WallDuration(0.3).sleep();
  const auto second = node.tick([](const Status& s) { return s.state == Status::DIVERGED; });
  ASSERT_TRUE(first.first && second.first);
  EXPECT_EQ(first.second->step_count, second.second->step_count) << "no stepping after a divergence";
  EXPECT_EQ(first.second->total_energy, second.second->total_energy) << "the energy of the held state";
  EXPECT_EQ(maxDistance(particles(*first.first), particles(*second.first)), 0.0);
  for (const auto& marker : second.first->markers)
  {
    for (const auto& p : marker.points)
    {
      ASSERT_TRUE(std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z));
    }
  }

  const auto is_error = [](const diagnostic_msgs::DiagnosticArray& a) {
    for (const auto& s : a.status)
      if (s.name.find("simulation") != std::string::npos && s.level == diagnostic_msgs::DiagnosticStatus::ERROR)
        return true;
    return false;
  };
  EXPECT_TRUE(waitFor<diagnostic_msgs::DiagnosticArray>("/diagnostics", is_error));

  // A method with a larger stable time step recovers from the last good state.
  const auto response = node.setMethod(param<std::string>("~recover_method", "linear"));
  EXPECT_TRUE(response.success) << response.message;
  const auto running = node.status([](const Status& s) { return s.state == Status::RUNNING && s.tick_steps > 0; });
  ASSERT_TRUE(running);
  EXPECT_GT(running->step_count, diverged->step_count);
  // No longer ERROR; a WARN may remain (the recovering method's estimated distance to full).
  const auto is_recovered = [](const diagnostic_msgs::DiagnosticArray& a) {
    for (const auto& s : a.status)
      if (s.name.find("simulation") != std::string::npos && s.level < diagnostic_msgs::DiagnosticStatus::ERROR &&
          s.message.find("diverged") == std::string::npos)
        return true;
    return false;
  };
  EXPECT_TRUE(waitFor<diagnostic_msgs::DiagnosticArray>("/diagnostics", is_recovered));

  // A reset recovers too: back to step 0 and running, under the method that diverged.
  ASSERT_TRUE(node.setMethod(diverged->method).success);
  ASSERT_TRUE(node.status([](const Status& s) { return s.state == Status::DIVERGED; }, 30.0));
  // It may diverge again within a few ticks, so listen before the call.
  std::vector<Status::ConstPtr> statuses;
  ros::NodeHandle nh;
  ros::Subscriber sub = nh.subscribe<Status>(node.topic("status"), 100,
                                             [&](const Status::ConstPtr& s) { statuses.push_back(s); });
  ros::WallDuration(0.5).sleep();
  const ros::Time called = ros::Time::now();
  EXPECT_TRUE(node.reset().success);
  ros::WallDuration(1.0).sleep();
  sub.shutdown();
  bool running_again = false;
  for (const auto& s : statuses)
    running_again |= s->header.stamp > called && s->state == Status::RUNNING && s->step_count < 100;
  EXPECT_TRUE(running_again) << "no RUNNING status from the start after the reset";
}

// ---------------------------------------------------------------- the point cloud, any config

// Collects messages of one type on a topic from a background subscription.
template <typename Msg>
class Recorder
{
public:
  explicit Recorder(const std::string& topic)
  {
    ros::NodeHandle nh;
    sub_ = nh.subscribe<Msg>(topic, 1000, [this](const typename Msg::ConstPtr& msg) {
      std::lock_guard<std::mutex> lock(mutex_);
      messages_.push_back(msg);
    });
  }
  std::vector<typename Msg::ConstPtr> messages() const
  {
    std::lock_guard<std::mutex> lock(mutex_);
    return messages_;
  }
  // Waits until `count` messages are in, or fails.
  std::vector<typename Msg::ConstPtr> wait(size_t count, double timeout = 30.0) const
  {
    const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(timeout);
    while (messages().size() < count && ros::ok() && ros::WallTime::now() < end)
      ros::WallDuration(0.01).sleep();
    EXPECT_GE(messages().size(), count) << sub_.getTopic();
    return messages();
  }
  void clear()
  {
    std::lock_guard<std::mutex> lock(mutex_);
    messages_.clear();
  }

private:
  mutable std::mutex mutex_;
  std::vector<typename Msg::ConstPtr> messages_;
  ros::Subscriber sub_;
};

TEST(PointCloud, OnePointPerParticleFiniteWhereTheMarkersAre)
{
  const std::string fixed_frame = param<std::string>("~fixed_frame", "world");
  for (const auto& name : nodeNames())
  {
    SCOPED_TRACE(name);
    NodeUnderTest node(name);
    Recorder<sensor_msgs::PointCloud2> clouds(node.topic("points"));
    Recorder<MarkerArray> markers(node.topic("markers"));
    clouds.wait(5);
    markers.wait(5);
    // A cloud and markers of the same tick (same stamp).
    sensor_msgs::PointCloud2::ConstPtr cloud;
    std::vector<geometry_msgs::Point> drawn;
    for (const auto& c : clouds.messages())
      for (const auto& m : markers.messages())
        if (!m->markers.empty() && m->markers[0].header.stamp == c->header.stamp)
        {
          cloud = c;
          drawn = particles(*m, markerPrefix(name) + "particles");
        }
    ASSERT_TRUE(cloud) << "no cloud with the stamp of a marker array";
    EXPECT_EQ(cloud->header.frame_id, fixed_frame);
    EXPECT_GT(cloud->header.stamp, ros::Time(0));
    ASSERT_EQ(cloud->width * cloud->height, drawn.size());
    ASSERT_EQ(cloud->fields.size(), 5u);
    EXPECT_EQ(cloud->fields[3].name, "strain");
    EXPECT_EQ(cloud->fields[4].name, "contact");
    sensor_msgs::PointCloud2ConstIterator<float> x(*cloud, "x"), y(*cloud, "y"), z(*cloud, "z"), strain(*cloud, "strain");
    sensor_msgs::PointCloud2ConstIterator<int32_t> contact(*cloud, "contact");
    for (size_t k = 0; k < drawn.size(); ++k, ++x, ++y, ++z, ++strain, ++contact)
    {
      ASSERT_TRUE(std::isfinite(*x) && std::isfinite(*y) && std::isfinite(*z) && std::isfinite(*strain)) << k;
      EXPECT_EQ(*contact, -1) << k << ": no collider here";
      // float32 of the same positions
      EXPECT_NEAR(*x, drawn[k].x, 1e-6 * (1.0 + std::abs(drawn[k].x))) << k;
      EXPECT_NEAR(*y, drawn[k].y, 1e-6 * (1.0 + std::abs(drawn[k].y))) << k;
      EXPECT_NEAR(*z, drawn[k].z, 1e-6 * (1.0 + std::abs(drawn[k].z))) << k;
    }
  }
}

// ---------------------------------------------------------------- simulated time and ~step (use_sim_time)

modal_mass_spring::Step::Response stepBy(const NodeUnderTest& node, uint32_t steps)
{
  modal_mass_spring::Step::Request request;
  request.steps = steps;
  return node.call<modal_mass_spring::Step>("step", request).response;
}

// The node is the clock: every status is stamped with /clock, which advances by the simulated time of
// each tick's steps and stops while paused.
TEST(SimTime, ClockFollowsSimulatedTimeAndStopsWhenPaused)
{
  NodeUnderTest node(nodeNames().front());
  const double dt = param(node.name + "/time_step", 0.0);
  ASSERT_GT(dt, 0.0);
  ASSERT_TRUE(param("/use_sim_time", false)) << "sim_time.test sets /use_sim_time";
  ASSERT_TRUE(node.pause(false));
  Recorder<rosgraph_msgs::Clock> clocks("/clock");
  Recorder<Status> statuses(node.topic("status"));
  statuses.wait(20);
  const auto running = statuses.messages();
  const auto seen = clocks.messages();
  ASSERT_GE(seen.size(), 10u);
  std::vector<ros::Time> clock_values;
  for (const auto& c : seen)
    clock_values.push_back(c->clock);
  for (size_t k = 1; k < clock_values.size(); ++k)
    EXPECT_GE(clock_values[k], clock_values[k - 1]) << "the clock never goes back";
  EXPECT_GT(clock_values.back(), clock_values.front());
  int checked = 0, looked_up = 0;
  for (size_t k = 1; k < running.size(); ++k)
  {
    const auto &a = *running[k - 1], &b = *running[k];
    if (a.state != Status::RUNNING || b.state != Status::RUNNING)
      continue;
    // Stamped with the simulated time: the stamps differ by the tick's steps, exactly.
    EXPECT_NEAR((b.header.stamp - a.header.stamp).toSec(), b.tick_steps * dt, 1e-8);
    EXPECT_NEAR((b.header.stamp - a.header.stamp).toSec(), b.sim_time - a.sim_time, 1e-8);
    // A status stamped before the first /clock message recorded here (the two subscriptions connect
    // one after the other) cannot be looked up.
    if (b.header.stamp >= clock_values.front())
    {
      EXPECT_TRUE(std::find(clock_values.begin(), clock_values.end(), b.header.stamp) != clock_values.end() ||
                  b.header.stamp > clock_values.back())
          << "a status stamp that was never on /clock: " << b.header.stamp << " (clock recorded from "
          << clock_values.front() << " to " << clock_values.back() << ")";
      ++looked_up;
    }
    ++checked;
  }
  EXPECT_GT(checked, 5);
  EXPECT_GT(looked_up, 3);

  // Paused: the clock stops, the status goes on with the same stamp.
  ASSERT_TRUE(node.pause(true));
  ros::WallDuration(0.3).sleep();
  clocks.clear();
  statuses.clear();
  statuses.wait(10);
  const auto held = clocks.messages();
  ASSERT_GE(held.size(), 5u) << "the clock is still published while paused";
  for (const auto& c : held)
    EXPECT_EQ(c->clock, held.front()->clock);
  for (const auto& s : statuses.messages())
  {
    EXPECT_EQ(s->state, Status::PAUSED);
    EXPECT_EQ(s->header.stamp, held.front()->clock);
  }
  ASSERT_TRUE(node.pause(false));
}

TEST(SimTime, StepAdvancesExactlyNStepsAndIsRefusedWhileRunning)
{
  NodeUnderTest node(nodeNames().front());
  const double dt = param(node.name + "/time_step", 0.0);
  ASSERT_TRUE(node.pause(false));
  ASSERT_TRUE(node.status([](const Status& s) { return s.state == Status::RUNNING && s.tick_steps > 0; }));
  const auto refused = stepBy(node, 10);
  EXPECT_FALSE(refused.success);
  EXPECT_NE(refused.message.find("running"), std::string::npos) << refused.message;

  ASSERT_TRUE(node.pause(true));
  const auto before = node.status([](const Status& s) { return s.state == Status::PAUSED; });
  ASSERT_TRUE(before);
  Recorder<rosgraph_msgs::Clock> clocks("/clock");
  ros::WallDuration(0.3).sleep();
  const auto response = stepBy(node, 10);
  EXPECT_TRUE(response.success) << response.message;
  EXPECT_EQ(response.step_count, before->step_count + 10);
  EXPECT_NEAR(response.sim_time, before->sim_time + 10 * dt, 1e-9);
  const auto after = node.status([](const Status& s) { return s.state == Status::PAUSED; });
  ASSERT_TRUE(after);
  EXPECT_EQ(after->step_count, before->step_count + 10) << "exactly 10 steps, and none while paused";
  EXPECT_NEAR((after->header.stamp - before->header.stamp).toSec(), 10 * dt, 1e-8) << "the clock moved by 10 steps";
  bool clock_moved = false;
  for (const auto& c : clocks.messages())
    clock_moved |= std::abs((c->clock - before->header.stamp).toSec() - 10 * dt) < 1e-8;
  EXPECT_TRUE(clock_moved);

  for (uint32_t bad : {0u, 10001u})
  {
    const auto out_of_range = stepBy(node, bad);
    EXPECT_FALSE(out_of_range.success) << bad;
    EXPECT_NE(out_of_range.message.find("must be in [1, 10000]"), std::string::npos) << out_of_range.message;
    EXPECT_EQ(out_of_range.step_count, after->step_count) << "nothing changed";
  }
  ASSERT_TRUE(node.pause(false));
}

// ---------------------------------------------------------------- shadow_full (paper_2d, method full)

TEST(Shadow, DistancesAreZeroForFullPositiveForLinearAndResynchroniseOnReset)
{
  NodeUnderTest node(nodeNames().front());
  ASSERT_TRUE(node.pause(false));
  ASSERT_TRUE(node.setMethod("full").success);
  const auto full = node.status([](const Status& s) { return s.method == "full" && s.step_count > 200; });
  ASSERT_TRUE(full);
  EXPECT_EQ(full->reference, "full");
  EXPECT_EQ(full->rms_distance, 0.0) << "the same method from the same state";
  EXPECT_EQ(full->max_distance, 0.0);
  const auto markers = node.markers();
  ASSERT_TRUE(markers);
  ASSERT_TRUE(findMarker(*markers, "shadow_full/surface")) << "the ghost of the reference";
  EXPECT_LT(findMarker(*markers, "shadow_full/surface")->color.a, 0.5f) << "faint";

  const auto switched = node.setMethod("linear");
  ASSERT_TRUE(switched.success) << switched.message;
  const auto linear = node.status([](const Status& s) { return s.method == "linear"; });
  ASSERT_TRUE(linear);
  const auto moved = node.status([&](const Status& s) { return s.step_count > linear->step_count + 500; });
  ASSERT_TRUE(moved);
  EXPECT_EQ(moved->reference, "full");
  EXPECT_GT(moved->rms_distance, 1e-6) << "linear leaves full as the grid moves";
  EXPECT_GE(moved->max_distance, moved->rms_distance);
  EXPECT_LT(moved->max_distance, 1.0) << "a distance, not a divergence";

  ASSERT_TRUE(node.pause(true));
  ASSERT_TRUE(node.reset().success);
  const auto reset = node.status([](const Status& s) { return s.step_count == 0; });
  ASSERT_TRUE(reset);
  EXPECT_LT(reset->rms_distance, 1e-12) << "the shadow starts again from the method's state";
  EXPECT_LT(reset->max_distance, 1e-12);
  ASSERT_TRUE(node.pause(false));
}

// ---------------------------------------------------------------- the comparison in lockstep

// Every method of the comparison reports the same step count and simulated time at every tick,
// also when full falls behind and the ticks are cut (lockstep.test runs cloth.yaml faster than full
// can follow).
TEST(Lockstep, MethodsAreAtTheSameMomentAtEveryTick)
{
  const auto names = nodeNames();
  ASSERT_GE(names.size(), 2u);
  const std::string config = configNode(names.front());
  const double dt = param(config + "/time_step", 0.0);
  const double per_tick = param(config + "/real_time_factor", 1.0) / (param(config + "/publish_rate", 0.0) * dt);
  std::vector<std::unique_ptr<Recorder<Status>>> recorders;
  for (const auto& name : names)
    recorders.push_back(std::make_unique<Recorder<Status>>(name + "/status"));
  for (auto& recorder : recorders)
    recorder->wait(40, 120.0);
  std::map<ros::Time, std::vector<Status::ConstPtr>> ticks;
  for (auto& recorder : recorders)
    for (const auto& s : recorder->messages())
      ticks[s->header.stamp].push_back(s);
  int compared = 0, cut = 0;
  for (const auto& [stamp, statuses] : ticks)
  {
    if (statuses.size() != names.size())
      continue;  // the recording started or ended inside this tick
    ++compared;
    uint64_t low = statuses[0]->step_count, high = low;
    for (const auto& s : statuses)
    {
      low = std::min(low, s->step_count);
      high = std::max(high, s->step_count);
      EXPECT_NEAR(s->sim_time, statuses[0]->sim_time, 1.001 * dt) << s->method;
      EXPECT_EQ(s->real_time_factor, statuses[0]->real_time_factor) << "one pace for all";
    }
    EXPECT_LE(high - low, 1u) << "at " << stamp;
    cut += statuses[0]->state == Status::RUNNING && statuses[0]->tick_steps + 1 < per_tick;
  }
  EXPECT_GE(compared, 30);
  EXPECT_GT(cut, 0) << "full kept up with real time here, so this run did not test falling behind";
  std::printf("%d ticks compared, %d cut short (full behind real time)\n", compared, cut);
}

TEST(Lockstep, EachGridHasALabelAndReducedMethodsTheirDistanceToFull)
{
  for (const auto& name : nodeNames())
  {
    SCOPED_TRACE(name);
    const std::string method = name.substr(name.rfind('/') + 1);
    NodeUnderTest node(name);
    const auto status = node.status([](const Status& s) { return s.step_count > 100; }, 60.0);
    ASSERT_TRUE(status);
    EXPECT_EQ(status->method, method);
    const auto markers = node.markers();
    ASSERT_TRUE(markers);
    const auto* label = findMarker(*markers, method + "/label");
    ASSERT_TRUE(label);
    EXPECT_EQ(label->type, visualization_msgs::Marker::TEXT_VIEW_FACING);
    EXPECT_EQ(label->text.rfind(method, 0), 0u) << label->text;
    EXPECT_NE(label->text.find("/step"), std::string::npos) << "its cost per step: " << label->text;
    if (method == "full")
    {
      EXPECT_EQ(status->reference, "");
      EXPECT_EQ(status->rms_distance, 0.0);
    }
    else
    {
      EXPECT_EQ(status->reference, "full");
      EXPECT_GT(status->rms_distance, 0.0);
      EXPECT_GE(status->max_distance, status->rms_distance);
      EXPECT_NE(label->text.find("to full"), std::string::npos) << label->text;
    }
  }
}

}  // namespace

// ---------------------------------------------------------------- external forces (paper_2d)

// Particle positions after `steps` steps from the reset state, with whatever forces are applied,
// taken with ~step on the paused node: deterministic, so two runs can be compared exactly.
std::vector<geometry_msgs::Point> afterSteps(const NodeUnderTest& node, uint32_t steps)
{
  EXPECT_TRUE(node.pause(true));
  EXPECT_TRUE(node.reset().success);
  const auto response = stepBy(node, steps);
  EXPECT_TRUE(response.success) << response.message;
  const auto tick = node.tick([&](const Status& s) { return s.state == Status::PAUSED && s.step_count == steps; });
  return tick.first ? particles(*tick.first) : std::vector<geometry_msgs::Point>{};
}

modal_mass_spring::ApplyForce force(const std::string& frame, std::vector<uint32_t> particles,
                                    std::vector<std::array<double, 3>> vectors)
{
  modal_mass_spring::ApplyForce message;
  message.header.frame_id = frame;
  message.particles = std::move(particles);
  for (const auto& v : vectors)
  {
    geometry_msgs::Vector3 f;
    f.x = v[0];
    f.y = v[1];
    f.z = v[2];
    message.forces.push_back(f);
  }
  return message;
}

// Whether `text` was logged at `level`, waiting up to 3 s for /rosout to bring it.
bool loggedWithin(const Recorder<rosgraph_msgs::Log>& log, uint8_t level, const std::string& text)
{
  for (const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(3.0); ros::WallTime::now() < end;)
  {
    for (const auto& entry : log.messages())
      if (entry->level == level && entry->msg.find(text) != std::string::npos)
        return true;
    ros::WallDuration(0.05).sleep();
  }
  return false;
}

class ExternalForces : public ::testing::Test
{
protected:
  void SetUp() override
  {
    ros::NodeHandle nh;
    publisher = nh.advertise<modal_mass_spring::ApplyForce>(node.topic("apply_force"), 10);
    const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(10.0);
    while (publisher.getNumSubscribers() == 0 && ros::WallTime::now() < end)
      ros::WallDuration(0.02).sleep();
    ASSERT_GT(publisher.getNumSubscribers(), 0u);
    clear();
  }
  void TearDown() override
  {
    clear();
    node.pause(false);
  }
  void clear() const { ASSERT_TRUE(node.call<std_srvs::Trigger>("clear_forces", {}).response.success); }
  // Publishes and waits for the node to have taken it (the next tick).
  void apply(const modal_mass_spring::ApplyForce& message) const
  {
    publisher.publish(message);
    ros::WallDuration(0.3).sleep();
  }

  NodeUnderTest node{"/modal_mass_spring"};
  ros::Publisher publisher;
  const uint32_t corner = 24;  // the bottom-right corner of the 5 x 5 grid
};

TEST_F(ExternalForces, ApplyForceMovesTheParticleAlongItWithEveryMethod)
{
  for (const std::string method : {"full", "linear", "physical", "cubature"})
  {
    ASSERT_TRUE(node.setMethod(method).success) << method;
    clear();
    const auto free = afterSteps(node, 300);
    apply(force("", {corner}, {{0.05, 0.0, 0.0}}));
    const auto pushed = afterSteps(node, 300);
    ASSERT_EQ(free.size(), 25u);
    ASSERT_EQ(pushed.size(), 25u);
    EXPECT_GT(pushed[corner].x - free[corner].x, 1e-3) << method << ": the corner moves along +x";
    EXPECT_LT(std::abs(pushed[corner].z - free[corner].z), pushed[corner].x - free[corner].x) << method;
    // Cleared, the run is the unforced one again.
    clear();
    EXPECT_LT(maxDistance(afterSteps(node, 300), free), 1e-12) << method;
  }
}

TEST_F(ExternalForces, ForcesAreTurnedIntoTheGridsFrameWithTf)
{
  // A frame turned 90 degrees about y: its x axis is the world's -z.
  tf2_ros::StaticTransformBroadcaster broadcaster;
  geometry_msgs::TransformStamped turned;
  turned.header.stamp = ros::Time::now();
  turned.header.frame_id = param<std::string>(node.name + "/fixed_frame", "world");
  turned.child_frame_id = "turned";
  turned.transform.rotation.y = std::sin(M_PI / 4);
  turned.transform.rotation.w = std::cos(M_PI / 4);
  broadcaster.sendTransform(turned);
  ros::WallDuration(0.5).sleep();
  ASSERT_TRUE(node.setMethod("physical").success);
  apply(force("", {corner}, {{0.0, 0.0, -0.05}}));
  const auto in_world = afterSteps(node, 300);
  clear();
  apply(force("turned", {corner}, {{0.05, 0.0, 0.0}}));
  const auto in_turned = afterSteps(node, 300);
  ASSERT_EQ(in_turned.size(), 25u);
  EXPECT_LT(maxDistance(in_turned, in_world), 1e-9);
  clear();
  EXPECT_GT(maxDistance(afterSteps(node, 300), in_world), 1e-4) << "the force did something";
}

TEST_F(ExternalForces, BadMessagesAreDroppedWithAWarningNamingTheProblem)
{
  ASSERT_TRUE(node.setMethod("physical").success);
  const auto free = afterSteps(node, 100);
  Recorder<rosgraph_msgs::Log> log("/rosout");
  ros::WallDuration(0.3).sleep();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const std::vector<std::pair<modal_mass_spring::ApplyForce, std::string>> cases{
      {force("no_such_frame", {corner}, {{1, 0, 0}}), "frame 'no_such_frame'"},
      {force("", {999}, {{1, 0, 0}}), "particle 999 is out of range"},
      {force("", {corner}, {{nan, 0, 0}}), "is not finite"},
      {force("", {20, 21, corner}, {{1, 0, 0}, {1, 0, 0}}), "3 particles but 2 forces"},
      {force("", {2}, {{1, 0, 0}}), "particle 2 is fixed"},
  };
  for (const auto& [message, expected] : cases)
  {
    apply(message);  // each different warning is told at once (throttled per text)
    EXPECT_TRUE(loggedWithin(log, rosgraph_msgs::Log::WARN, expected)) << "no warning naming: " << expected;
  }
  // Nothing of them was taken, and the node runs on.
  EXPECT_LT(maxDistance(afterSteps(node, 100), free), 1e-12);
  ASSERT_TRUE(node.pause(false));
  EXPECT_TRUE(node.status([](const Status& s) { return s.state == Status::RUNNING && s.tick_steps > 0; }));
}

TEST_F(ExternalForces, ADivergenceUnderAForceNamesItAndAResetSaysItActsOn)
{
  ASSERT_TRUE(node.setMethod("physical").success);
  ASSERT_TRUE(node.pause(true));
  ASSERT_TRUE(node.reset().success);
  apply(force("", {corner}, {{1e12, 0.0, 0.0}}));  // finite, and far more than any step holds
  EXPECT_TRUE(node.status([](const Status& s) { return s.applied_forces == 1; }));
  Recorder<rosgraph_msgs::Log> log("/rosout");
  ros::WallDuration(0.3).sleep();
  stepBy(node, 100);
  const auto diverged = node.status([](const Status& s) { return s.state == Status::DIVERGED; });
  ASSERT_TRUE(diverged);
  EXPECT_NE(diverged->message.find("forces from outside were acting (1 from ~apply_force)"), std::string::npos)
      << diverged->message;
  EXPECT_NE(diverged->message.find("~clear_forces"), std::string::npos) << diverged->message;
  // The console has it as an error with the step and the force, also when ~step took it.
  EXPECT_TRUE(loggedWithin(log, rosgraph_msgs::Log::ERROR, "diverged at step"));
  EXPECT_TRUE(loggedWithin(log, rosgraph_msgs::Log::ERROR, "forces from outside were acting (1 from ~apply_force)"));
  // A method switch recovers, and says that the force acts on, as a reset does.
  const auto switched = node.setMethod("linear");
  EXPECT_TRUE(switched.success) << switched.message;
  EXPECT_NE(switched.message.find("recovering from the divergence; 1 force from ~apply_force acts on (~clear_forces ends them)"),
            std::string::npos)
      << switched.message;
  // The force acts on across a reset, and the reply says so; cleared, the run is an ordinary one.
  const auto reset = node.reset();
  EXPECT_TRUE(reset.success);
  EXPECT_NE(reset.message.find("1 force from ~apply_force acts on (~clear_forces ends them)"), std::string::npos)
      << reset.message;
  clear();
  EXPECT_TRUE(node.status([](const Status& s) { return s.applied_forces == 0; }));
  EXPECT_EQ(node.reset().message.find("~apply_force"), std::string::npos);
  ASSERT_TRUE(stepBy(node, 100).success);
  EXPECT_TRUE(node.status([](const Status& s) { return s.state == Status::PAUSED && s.step_count == 100; }));
}

TEST_F(ExternalForces, AForceLastsItsDurationOfSimulatedTimeAcrossAReset)
{
  ASSERT_TRUE(node.setMethod("linear").success);
  ASSERT_TRUE(node.pause(true));
  ASSERT_TRUE(node.reset().success);
  ASSERT_TRUE(stepBy(node, 300).success);
  modal_mass_spring::ApplyForce message = force("", {corner}, {{0.01, 0.0, 0.0}});
  message.duration = 0.1;
  apply(message);
  EXPECT_TRUE(node.status([](const Status& s) { return s.applied_forces == 1; }));
  // After a reset at 0.3 s and 0.2 s more of steps the force's 0.1 s are over, though the run's own
  // time (0.2 s) has not reached where it was applied.
  ASSERT_TRUE(node.reset().success);
  ASSERT_TRUE(stepBy(node, 200).success);
  EXPECT_TRUE(node.status([](const Status& s) { return s.applied_forces == 0; }));
}

// ---------------------------------------------------------------- by hand: the drag marker and pokes (drag_and_poke.test)
// A 5 x 5 sheet hanging at rest from its equilibrium; /modal_mass_spring runs one method at a time,
// /compare_methods the four in lockstep. Runs are stepped with ~step on the paused node, so a run with
// the hand and one without differ by the hand alone.

geometry_msgs::Point point(const Eigen::Vector3d& p)
{
  geometry_msgs::Point q;
  q.x = p.x();
  q.y = p.y();
  q.z = p.z();
  return q;
}

Eigen::Vector3d vec(const geometry_msgs::Point& p) { return Eigen::Vector3d(p.x, p.y, p.z); }

class ByHand : public ::testing::Test
{
protected:
  void SetUp() override
  {
    ros::NodeHandle nh;
    feedback_pub = nh.advertise<visualization_msgs::InteractiveMarkerFeedback>(node.topic("drag/feedback"), 10);
    compare_feedback_pub = nh.advertise<visualization_msgs::InteractiveMarkerFeedback>(compare.topic("drag/feedback"), 10);
    click_pub = nh.advertise<geometry_msgs::PointStamped>("/clicked_point", 10);
    const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(15.0);
    while ((feedback_pub.getNumSubscribers() == 0 || compare_feedback_pub.getNumSubscribers() == 0 ||
            click_pub.getNumSubscribers() < 2) &&
           ros::WallTime::now() < end)
      ros::WallDuration(0.02).sleep();
    ASSERT_GT(feedback_pub.getNumSubscribers(), 0u);
    ASSERT_GT(compare_feedback_pub.getNumSubscribers(), 0u);
    ASSERT_GE(click_pub.getNumSubscribers(), 2u);
  }
  void TearDown() override
  {
    drag(feedback_pub, visualization_msgs::InteractiveMarkerFeedback::MOUSE_UP, Eigen::Vector3d::Zero());
    drag(compare_feedback_pub, visualization_msgs::InteractiveMarkerFeedback::MOUSE_UP, Eigen::Vector3d::Zero());
    node.pause(false);
    compare.pause(false);
  }
  // As rviz sends it: the marker's pose in the fixed frame, from one client; waits for the node to take it.
  static void drag(const ros::Publisher& publisher, uint8_t event, const Eigen::Vector3d& at,
                   const std::string& frame = "world", const std::string& control = "pull")
  {
    visualization_msgs::InteractiveMarkerFeedback feedback;
    feedback.header.frame_id = frame;
    feedback.client_id = "/test_node/rviz";
    feedback.marker_name = "drag";
    feedback.control_name = control;
    feedback.event_type = event;
    feedback.pose.position = point(at);
    feedback.pose.orientation.w = 1.0;
    publisher.publish(feedback);
    ros::WallDuration(0.3).sleep();
  }
  void click(const Eigen::Vector3d& at, const std::string& frame = "world") const
  {
    geometry_msgs::PointStamped message;
    message.header.frame_id = frame;
    message.header.stamp = ros::Time::now();
    message.point = point(at);
    click_pub.publish(message);
    ros::WallDuration(0.3).sleep();
  }
  // The particles after `steps` steps from the reset state of the paused node, with `before` done
  // after the reset (a grab, a click).
  static std::vector<geometry_msgs::Point> run(const NodeUnderTest& node, uint32_t steps,
                                               const std::function<void()>& before = {},
                                               const std::vector<NodeUnderTest>& methods = {})
  {
    EXPECT_TRUE(node.pause(true));
    EXPECT_TRUE(node.reset().success);
    ros::WallDuration(0.2).sleep();  // a tick's snapshot of the reset state: what a grab sees
    if (before)
      before();
    const auto response = stepBy(node, steps);
    EXPECT_TRUE(response.success) << response.message;
    std::vector<geometry_msgs::Point> all;
    for (const NodeUnderTest& shown : methods.empty() ? std::vector<NodeUnderTest>{node} : methods)
    {
      const auto tick =
          shown.tick([&](const Status& s) { return s.state == Status::PAUSED && s.step_count == steps; });
      if (!tick.first)
        return {};
      const std::string method = shown.name.substr(shown.name.rfind('/') + 1);
      const auto points = particles(*tick.first, methods.empty() ? "particles" : method + "/particles");
      all.insert(all.end(), points.begin(), points.end());
    }
    return all;
  }
  bool logged(const Recorder<rosgraph_msgs::Log>& log, uint8_t level, const std::string& text) const
  {
    return loggedWithin(log, level, text);
  }

  NodeUnderTest node{"/modal_mass_spring"};
  NodeUnderTest compare{"/compare_methods"};
  ros::Publisher feedback_pub, compare_feedback_pub, click_pub;
  const int corner = 24;  // the bottom-right corner of the 5 x 5 sheet
};

TEST_F(ByHand, DragPullsTheNearestFreeParticleTowardTheMarkerWithEveryMethodUntilReleased)
{
  using Feedback = visualization_msgs::InteractiveMarkerFeedback;
  // Subscribed long before the first grab: the node's /rosout connects to a new subscriber late
  // under load.
  Recorder<rosgraph_msgs::Log> log("/rosout");
  for (const std::string method : {"full", "linear", "physical", "cubature"})
  {
    ASSERT_TRUE(node.setMethod(method).success) << method;
    const auto free = run(node, 100);
    ASSERT_EQ(free.size(), 25u);
    const Eigen::Vector3d start = vec(free[corner]);
    const Eigen::Vector3d target = start + Eigen::Vector3d(0.0, 0.1, 0.05);
    log.clear();
    const auto pulled = run(node, 100, [&] {
      drag(feedback_pub, Feedback::MOUSE_DOWN, start + Eigen::Vector3d(0.02, 0.01, -0.02));
      drag(feedback_pub, Feedback::POSE_UPDATE, target);
    });
    ASSERT_EQ(pulled.size(), 25u);
    EXPECT_TRUE(logged(log, rosgraph_msgs::Log::INFO, "particle 24 grabbed")) << method;
    const Eigen::Vector3d moved = vec(pulled[corner]) - start;
    EXPECT_LT((vec(pulled[corner]) - target).norm(), 0.7 * (start - target).norm()) << method << ": toward the marker";
    EXPECT_GT(moved.y(), 0.02) << method;
    EXPECT_GT(moved.dot(target - start), 0.7 * moved.norm() * (target - start).norm()) << method << ": along the pull";

    // Let go, the run is the one without the hand again, to the bit.
    drag(feedback_pub, Feedback::MOUSE_UP, target);
    EXPECT_LT(maxDistance(run(node, 100), free), 1e-12) << method;
  }
}

TEST_F(ByHand, DragGrabsOnlyFreeParticlesAndItsArrowsDoNotPull)
{
  using Feedback = visualization_msgs::InteractiveMarkerFeedback;
  ASSERT_TRUE(node.setMethod("physical").success);
  const auto free = run(node, 50);
  ASSERT_EQ(free.size(), 25u);
  // On particle 2, fixed in the top row: the free particle below it is taken.
  Recorder<rosgraph_msgs::Log> log("/rosout");
  ros::WallDuration(0.3).sleep();
  run(node, 1, [&] { drag(feedback_pub, Feedback::MOUSE_DOWN, vec(free[2]) + Eigen::Vector3d(0.0, 0.0, 0.01)); });
  EXPECT_TRUE(node.status([](const Status& s) { return s.dragged_particle == 7; }));
  drag(feedback_pub, Feedback::MOUSE_UP, vec(free[2]));
  EXPECT_TRUE(node.status([](const Status& s) { return s.dragged_particle == -1; }));
  EXPECT_TRUE(logged(log, rosgraph_msgs::Log::INFO, "particle 7 grabbed"));
  // Moved by an arrow, the marker pulls nothing.
  const auto placed = run(node, 50, [&] {
    drag(feedback_pub, Feedback::MOUSE_DOWN, vec(free[corner]), "world", "move_x");
    drag(feedback_pub, Feedback::POSE_UPDATE, vec(free[corner]) + Eigen::Vector3d(0.2, 0.0, 0.0), "world", "move_x");
  });
  drag(feedback_pub, Feedback::MOUSE_UP, vec(free[corner]) + Eigen::Vector3d(0.2, 0.0, 0.0), "world", "move_x");
  EXPECT_LT(maxDistance(placed, free), 1e-12);
}

TEST_F(ByHand, DragPullsEveryMethodOfALockstepComparison)
{
  using Feedback = visualization_msgs::InteractiveMarkerFeedback;
  std::vector<NodeUnderTest> methods;
  for (const std::string method : {"full", "linear", "physical", "cubature"})
    methods.emplace_back("/compare_methods/" + method);
  const auto free = run(compare, 100, {}, methods);
  ASSERT_EQ(free.size(), 100u);
  // Grabbed on physical's grid (the third); every grid is pulled toward the same place relative to it.
  const Eigen::Vector3d start = vec(free[2 * 25 + corner]);
  const Eigen::Vector3d pull(0.0, 0.1, 0.05);
  const auto pulled = run(compare, 100, [&] {
    drag(compare_feedback_pub, Feedback::MOUSE_DOWN, start);
    drag(compare_feedback_pub, Feedback::POSE_UPDATE, start + pull);
  }, methods);
  drag(compare_feedback_pub, Feedback::MOUSE_UP, start + pull);
  ASSERT_EQ(pulled.size(), 100u);
  for (size_t k = 0; k < methods.size(); ++k)
  {
    const Eigen::Vector3d before = vec(free[k * 25 + corner]), after = vec(pulled[k * 25 + corner]);
    EXPECT_LT((after - (before + pull)).norm(), 0.7 * pull.norm()) << methods[k].name;
    EXPECT_GT((after - before).y(), 0.02) << methods[k].name;
  }
}

TEST_F(ByHand, ClickedPointPokesTheNearestParticleAlongTheSheetsNormalWithEveryMethod)
{
  // A frame shifted from the world: the same click given in it pokes the same particle the same way.
  tf2_ros::StaticTransformBroadcaster broadcaster;
  geometry_msgs::TransformStamped shifted;
  shifted.header.stamp = ros::Time::now();
  shifted.header.frame_id = "world";
  shifted.child_frame_id = "shifted";
  shifted.transform.translation.x = 1.0;
  shifted.transform.translation.y = -2.0;
  shifted.transform.translation.z = 0.5;
  shifted.transform.rotation.w = 1.0;
  broadcaster.sendTransform(shifted);
  ros::WallDuration(0.5).sleep();
  const Eigen::Vector3d shift(1.0, -2.0, 0.5);
  const int centre = 12;
  for (const std::string method : {"full", "linear", "physical", "cubature"})
  {
    ASSERT_TRUE(node.setMethod(method).success) << method;
    const auto free = run(node, 6);
    ASSERT_EQ(free.size(), 25u);
    const Eigen::Vector3d on_cloth = vec(free[centre]) + Eigen::Vector3d(0.02, 0.01, -0.01);
    const auto poked = run(node, 6, [&] { click(on_cloth); });
    ASSERT_EQ(poked.size(), 25u);
    // The sheet hangs in the x-z plane: its normal is +y (drag_and_poke.h).
    const Eigen::Vector3d moved = vec(poked[centre]) - vec(free[centre]);
    EXPECT_GT(moved.y(), 1e-4) << method;
    EXPECT_GT(moved.y(), 0.9 * moved.norm()) << method << ": along the normal";
    EXPECT_LT(maxDistance(run(node, 6, [&] { click(on_cloth - shift, "shifted"); }), poked), 1e-9) << method;
  }
}

TEST_F(ByHand, BadClicksAndDragsAreDroppedWithAWarningNamingTheProblem)
{
  using Feedback = visualization_msgs::InteractiveMarkerFeedback;
  ASSERT_TRUE(node.setMethod("physical").success);
  const auto free = run(node, 50);
  ASSERT_EQ(free.size(), 25u);
  Recorder<rosgraph_msgs::Log> log("/rosout");
  ros::WallDuration(0.3).sleep();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const auto hit = run(node, 50, [&] {
    // One after another: warnings are throttled per text, so each different one is told at once.
    click(Eigen::Vector3d(nan, 0.0, 0.0));
    click(vec(free[corner]), "no_such_frame");
    click(vec(free[corner]) + Eigen::Vector3d(0.0, 1.0, 0.0));
    drag(feedback_pub, Feedback::MOUSE_DOWN, vec(free[corner]), "no_such_frame");
    drag(feedback_pub, Feedback::POSE_UPDATE, Eigen::Vector3d(nan, 0.0, 0.0));
  });
  drag(feedback_pub, Feedback::MOUSE_UP, vec(free[corner]));
  for (const std::string expected :
       {"/clicked_point: point dropped: the point (nan", "/clicked_point: point dropped: frame 'no_such_frame'",
        "from the nearest free particle, beyond the 0.3 m (3 spacings) a poke reaches",
        "drag: marker pose dropped: frame 'no_such_frame'", "drag: marker pose dropped: the point (nan, 0, 0)"})
    EXPECT_TRUE(logged(log, rosgraph_msgs::Log::WARN, expected)) << "no warning naming: " << expected;
  // None of them did anything, and the node runs on.
  EXPECT_LT(maxDistance(hit, free), 1e-12);
  ASSERT_TRUE(node.pause(false));
  EXPECT_TRUE(node.status([](const Status& s) { return s.state == Status::RUNNING && s.tick_steps > 0; }));
}

int main(int argc, char** argv)
{
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "test_node");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  const int result = RUN_ALL_TESTS();
  ros::shutdown();
  return result;
}
