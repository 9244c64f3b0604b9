// The cloth by hand in rviz: an interactive marker that grabs the nearest free particle and pulls it
// with a spring while dragged, and rviz's Publish Point tool (/clicked_point) poking the nearest free
// particle. Both act through the tracks' external force, as ~apply_force does, so every method and a
// lockstep comparison take them; the spring is recomputed before every step from the particle's state.
#include "simulation_node.h"

#include <interactive_markers/tools.h>
#include <visualization_msgs/InteractiveMarker.h>

#include <Eigen/Geometry>

#include <cstdio>
#include <limits>

namespace modal_mass_spring
{
namespace
{

const char kDragMarker[] = "drag";
// A click farther than this many spacings from every free particle missed the cloth.
constexpr double kPokeReach = 3.0;
// The marker follows its particle once it has moved this far (m): none sent while the cloth rests.
constexpr double kMarkerFollowDistance = 1e-4;

bool placingControl(const std::string& control_name)
{
  return control_name.rfind("move_", 0) == 0;
}

visualization_msgs::InteractiveMarkerControl moveAxis(const std::string& name, double w, double x, double y, double z)
{
  visualization_msgs::InteractiveMarkerControl control;
  control.name = name;
  control.interaction_mode = visualization_msgs::InteractiveMarkerControl::MOVE_AXIS;
  const double norm = std::sqrt(w * w + x * x + y * y + z * z);
  control.orientation.w = w / norm;
  control.orientation.x = x / norm;
  control.orientation.y = y / norm;
  control.orientation.z = z / norm;
  return control;
}

}  // namespace

void SimulationNode::startInteraction()
{
  const NodeParams& params = config_.node;
  const Grid& grid = primary().simulation->grid();
  hand_forces_ = std::make_unique<HandForces>(grid, tracks_.size());
  hand_forces_->configure(params.drag_stiffness, config_.grid.mass, config_.simulation.time_step);
  // The marker starts on the free particle nearest the middle of the bottom row.
  const int bottom_middle = grid.particleIndex(grid.params().rows - 1, grid.params().cols / 2);
  selected_particle_ = nearestFreeParticle(grid, primary().last_points, primary().last_points.col(bottom_middle));
  selected_track_ = 0;
  drag_server_ = std::make_unique<interactive_markers::InteractiveMarkerServer>(private_nh_.resolveName("drag"));
  showDragMarker();
  clicked_point_sub_ = nh_.subscribe("/clicked_point", 10, &SimulationNode::onClickedPoint, this);
}

void SimulationNode::showDragMarker()
{
  const bool shown = config_.node.drag_stiffness > 0.0 && selected_particle_ >= 0;
  if (!shown)
  {
    hand_forces_->release();
    placing_ = false;
    drag_server_->erase(kDragMarker);
    drag_server_->applyChanges();
    return;
  }
  visualization_msgs::InteractiveMarker existing;
  if (drag_server_->get(kDragMarker, existing))
    return;
  const Grid& grid = primary().simulation->grid();
  const double spacing = grid.params().spacing;
  visualization_msgs::InteractiveMarker marker;
  marker.header.frame_id = config_.node.fixed_frame;
  marker.name = kDragMarker;
  marker.description = "drag the ball to pull; the arrows move it without pulling";
  marker.scale = static_cast<float>(4.0 * spacing);
  const Track& track = tracks_[selected_track_];
  const Eigen::Vector3d at = track.last_points.col(selected_particle_) + track.offset;
  marker.pose.position.x = at.x();
  marker.pose.position.y = at.y();
  marker.pose.position.z = at.z();
  marker.pose.orientation.w = 1.0;
  marker_position_ = at;

  // The ball: dragged in the view plane (shift: along the view), it pulls.
  visualization_msgs::InteractiveMarkerControl pull;
  pull.name = "pull";
  pull.interaction_mode = visualization_msgs::InteractiveMarkerControl::MOVE_3D;
  pull.always_visible = true;
  visualization_msgs::Marker ball;
  ball.type = visualization_msgs::Marker::SPHERE;
  ball.scale.x = ball.scale.y = ball.scale.z = 1.2 * spacing;
  ball.color.r = 1.0f;
  ball.color.g = 0.5f;
  ball.color.b = 0.0f;
  ball.color.a = 0.9f;
  pull.markers.push_back(ball);
  marker.controls.push_back(pull);
  // The arrows: they place the marker on another particle without pulling.
  marker.controls.push_back(moveAxis("move_x", 1, 1, 0, 0));
  marker.controls.push_back(moveAxis("move_z", 1, 0, 1, 0));
  if (grid.dimension() == 3)
    marker.controls.push_back(moveAxis("move_y", 1, 0, 0, 1));
  interactive_markers::autoComplete(marker);
  drag_server_->insert(marker, [this](const visualization_msgs::InteractiveMarkerFeedbackConstPtr& feedback) {
    onDragFeedback(feedback);
  });
  drag_server_->applyChanges();
}

bool SimulationNode::toFixedFrame(const std::string& frame_id, const geometry_msgs::Point& point,
                                  Eigen::Vector3d& result, std::string& why)
{
  const std::string& fixed_frame = config_.node.fixed_frame;
  const std::string frame = frame_id.empty() ? fixed_frame : frame_id;
  result = Eigen::Vector3d(point.x, point.y, point.z);
  if (!result.allFinite())
  {
    why = "the point " + vectorText(result) + " is not finite";
    return false;
  }
  if (frame == fixed_frame)
    return true;
  try
  {
    const auto t = tf_buffer_.lookupTransform(fixed_frame, frame, ros::Time(0)).transform;
    const Eigen::Quaterniond rotation(t.rotation.w, t.rotation.x, t.rotation.y, t.rotation.z);
    result = rotation.normalized() * result + Eigen::Vector3d(t.translation.x, t.translation.y, t.translation.z);
  }
  catch (const tf2::TransformException& error)
  {
    why = "frame '" + frame + "' cannot be turned into '" + fixed_frame + "': " + error.what();
    return false;
  }
  if (!result.allFinite())
  {
    why = "frame '" + frame + "' has a non-finite transform to '" + fixed_frame + "'";
    return false;
  }
  return true;
}

int SimulationNode::nearestOnTracks(const Eigen::Vector3d& point, size_t& track, double& distance) const
{
  int nearest = -1;
  distance = std::numeric_limits<double>::infinity();
  for (size_t k = 0; k < tracks_.size(); ++k)
  {
    if (tracks_[k].shadow)
      continue;  // drawn faintly where its method is: a point on it means the method
    const Eigen::Vector3d local = point - tracks_[k].offset;
    const int p = nearestFreeParticle(tracks_[k].simulation->grid(), tracks_[k].last_points, local);
    if (p < 0)
      continue;
    const double d = (tracks_[k].last_points.col(p) - local).norm();
    if (d < distance)
    {
      distance = d;
      nearest = p;
      track = k;
    }
  }
  return nearest;
}

void SimulationNode::onDragFeedback(const visualization_msgs::InteractiveMarkerFeedbackConstPtr& feedback)
{
  using Feedback = visualization_msgs::InteractiveMarkerFeedback;
  const uint8_t event = feedback->event_type;
  if (event != Feedback::MOUSE_DOWN && event != Feedback::POSE_UPDATE && event != Feedback::MOUSE_UP)
    return;
  Eigen::Vector3d point;
  std::string why;
  const bool known = toFixedFrame(feedback->header.frame_id, feedback->pose.position, point, why);
  std::lock_guard<std::mutex> lock(mutex_);
  if (config_.node.drag_stiffness <= 0.0)
    return;
  if (!known)
  {
    warnDropped("drag: marker pose dropped: " + why + (event == Feedback::MOUSE_UP ? "; the drag ends" : ""));
    if (event == Feedback::MOUSE_UP)
    {
      hand_forces_->release();
      placing_ = false;
    }
    // The server took the pose as it came: the marker goes back onto its particle.
    marker_position_ = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
    return;
  }
  size_t track = 0;
  double distance = 0.0;
  if (placingControl(feedback->control_name))
  {
    // Moved by an arrow: no pull; let go, the marker takes the nearest free particle.
    hand_forces_->release();
    placing_ = event != Feedback::MOUSE_UP;
    if (!placing_)
    {
      const int p = nearestOnTracks(point, track, distance);
      if (p >= 0)
      {
        selected_particle_ = p;
        selected_track_ = track;
        marker_position_ = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());  // re-placed next tick
      }
    }
    return;
  }
  if (event == Feedback::MOUSE_UP)
  {
    if (hand_forces_->dragging())
      ROS_INFO("drag: particle %d let go", hand_forces_->draggedParticle());
    hand_forces_->release();
    marker_position_ = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
    return;
  }
  if (!hand_forces_->dragging())
  {
    const int p = nearestOnTracks(point, track, distance);
    if (p < 0)
    {
      warnDropped("drag: the grid has no free particle to grab");
      return;
    }
    selected_particle_ = p;
    selected_track_ = track;
    hand_forces_->grab(p, point - tracks_[track].offset);
    ROS_INFO("drag: particle %d grabbed (%.3g m from the marker) on %s, pulled with drag_stiffness %g N/m", p, distance,
             tracks_[track].name.c_str(), config_.node.drag_stiffness);
    return;
  }
  hand_forces_->moveTarget(point - tracks_[selected_track_].offset);
}

void SimulationNode::onClickedPoint(const geometry_msgs::PointStamped::ConstPtr& message)
{
  Eigen::Vector3d point;
  std::string why;
  const bool known = toFixedFrame(message->header.frame_id, message->point, point, why);
  std::lock_guard<std::mutex> lock(mutex_);
  const double impulse = config_.node.poke_impulse;
  if (impulse <= 0.0)
  {
    ROS_WARN_THROTTLE(5.0, "/clicked_point: poke_impulse is 0: pokes are off");
    return;
  }
  if (!known)
  {
    warnDropped("/clicked_point: point dropped: " + why);
    return;
  }
  size_t track = 0;
  double distance = 0.0;
  const int p = nearestOnTracks(point, track, distance);
  if (p < 0)
  {
    warnDropped("/clicked_point: point dropped: the grid has no free particle to poke");
    return;
  }
  const Grid& grid = tracks_[track].simulation->grid();
  const double reach = kPokeReach * grid.params().spacing;
  if (distance > reach)
  {
    char text[160];
    std::snprintf(text, sizeof text, " in '%s' is %.3g m from the nearest free particle, beyond the %.3g m (3 spacings)",
                  config_.node.fixed_frame.c_str(), distance, reach);
    warnDropped("/clicked_point: point dropped: " + vectorText(point) + text + " a poke reaches: click on the cloth");
    return;
  }
  const Eigen::Vector3d direction = pokeDirection(grid, tracks_[track].last_points, p);
  hand_forces_->poke(p, impulse * direction);
  ROS_INFO("/clicked_point: particle %d poked with %g N s along (%.3f, %.3f, %.3f)", p, impulse, direction.x(),
           direction.y(), direction.z());
}

void SimulationNode::applyHandForce(size_t k)
{
  if (!hand_forces_->active(k))
    return;
  Simulation& simulation = *tracks_[k].simulation;
  try
  {
    // Only the dragged particle's state: reading the whole grid's every step would cost more than
    // the step itself on a large grid.
    Eigen::Vector3d position = Eigen::Vector3d::Zero(), velocity = Eigen::Vector3d::Zero();
    if (hand_forces_->needsState())
    {
      Eigen::VectorXd x, v;
      simulation.particleState(hand_forces_->draggedParticle(), x, v);
      position = gridPoint(simulation.grid(), x);
      velocity = gridPoint(simulation.grid(), v);
    }
    if (const auto force = hand_forces_->nextForce(k, external_force_, position, velocity))
      simulation.setExternalForce(*force);
  }
  catch (const std::invalid_argument& error)
  {
    // Only a state gone non-finite (or a particle no longer free) could do it; the core keeps the last
    // good state.
    ROS_WARN_THROTTLE(1.0, "drag: the hand's force was refused (%s); the drag ends", error.what());
    hand_forces_->release();
  }
}

std::optional<Eigen::Vector3d> SimulationNode::dragMarkerTarget()
{
  if (!hand_forces_ || config_.node.drag_stiffness <= 0.0 || hand_forces_->dragging() || placing_ ||
      selected_particle_ < 0)
    return std::nullopt;
  const Track& track = tracks_[selected_track_];
  const Eigen::Vector3d at = track.last_points.col(selected_particle_) + track.offset;
  if ((at - marker_position_).norm() < kMarkerFollowDistance)
    return std::nullopt;
  marker_position_ = at;
  return at;
}

void SimulationNode::placeDragMarker(const Eigen::Vector3d& position)
{
  geometry_msgs::Pose pose;
  pose.position.x = position.x();
  pose.position.y = position.y();
  pose.position.z = position.z();
  pose.orientation.w = 1.0;
  std_msgs::Header header;
  header.frame_id = config_.node.fixed_frame;
  if (drag_server_->setPose(kDragMarker, pose, header))
    drag_server_->applyChanges();
}

}  // namespace modal_mass_spring
