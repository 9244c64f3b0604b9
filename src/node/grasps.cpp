// Grasps while the simulation runs: ~attach, ~detach, and the grasp that lets go beyond its force.
#include "simulation_node.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numeric>

namespace modal_mass_spring
{

namespace
{

// Every dof's velocity (world): the free dofs' from the state, the handles' from their motion.
Eigen::VectorXd dofVelocities(const Simulation& simulation)
{
  const Grid& grid = simulation.grid();
  Eigen::VectorXd v = Eigen::VectorXd::Zero(grid.numDofs());
  grid.addFree(simulation.velocity(), v);
  const std::vector<int>& dofs = grid.handleDofs();
  if (dofs.empty())
    return v;
  Eigen::VectorXd handle_velocity = Eigen::VectorXd::Zero(static_cast<Eigen::Index>(dofs.size()));
  if (simulation.handleFormulation() == HandleFormulation::MovingFrame)
  {
    // The handles ride on B: the rigid motion of their start positions.
    Eigen::VectorXd start(static_cast<Eigen::Index>(dofs.size()));
    for (size_t k = 0; k < dofs.size(); ++k)
      start[static_cast<Eigen::Index>(k)] = simulation.linearizationPositions()[dofs[k]];
    const std::vector<int> rows = gridAxes(grid.dimension());
    const Eigen::Index count = static_cast<Eigen::Index>(dofs.size() / rows.size());
    Eigen::Matrix3Xd points = Eigen::Matrix3Xd::Zero(3, count);
    for (Eigen::Index p = 0; p < count; ++p)
      for (size_t r = 0; r < rows.size(); ++r)
        points(rows[r], p) = start[p * static_cast<Eigen::Index>(rows.size()) + static_cast<Eigen::Index>(r)];
    const RigidPointMotion motion = pointMotion(simulation.frameMotion(), points);
    for (Eigen::Index p = 0; p < count; ++p)
      for (size_t r = 0; r < rows.size(); ++r)
        handle_velocity[p * static_cast<Eigen::Index>(rows.size()) + static_cast<Eigen::Index>(r)] =
            motion.velocity(rows[r], p);
  }
  else if (simulation.handleMotion().velocity.size() == handle_velocity.size())
    handle_velocity = simulation.handleMotion().velocity;
  for (size_t k = 0; k < dofs.size(); ++k)
    v[dofs[k]] = handle_velocity[static_cast<Eigen::Index>(k)];
  return v;
}

// `next` takes over `old`'s run: every particle where it is, with its velocity, in the new held set.
void carryOver(const Simulation& old, Simulation& next)
{
  const Eigen::VectorXd x = old.positions();
  const Eigen::VectorXd v = dofVelocities(old);
  const Grid& grid = next.grid();
  const std::vector<int>& dofs = grid.handleDofs();
  if (!dofs.empty())
  {
    Eigen::VectorXd hx(static_cast<Eigen::Index>(dofs.size())), hv(hx.size());
    for (size_t k = 0; k < dofs.size(); ++k)
    {
      hx[static_cast<Eigen::Index>(k)] = x[dofs[k]];
      hv[static_cast<Eigen::Index>(k)] = v[dofs[k]];
    }
    next.setHandleState(hx, hv);
  }
  next.setPhysicalState(grid.gatherFree(x - next.linearizationPositions()), grid.gatherFree(v));
}

XmlRpc::XmlRpcValue handleList(const std::vector<HandleParam>& handles)
{
  XmlRpc::XmlRpcValue list;
  list.setSize(static_cast<int>(handles.size()));
  for (size_t h = 0; h < handles.size(); ++h)
  {
    XmlRpc::XmlRpcValue particles;
    particles.setSize(static_cast<int>(handles[h].particles.size()));
    for (size_t k = 0; k < handles[h].particles.size(); ++k)
      particles[static_cast<int>(k)] = handles[h].particles[k];
    list[static_cast<int>(h)]["frame"] = handles[h].frame;
    list[static_cast<int>(h)]["particles"] = particles;
  }
  return list;
}

std::string joinParticles(const std::vector<int>& particles)
{
  std::string text;
  for (int p : particles)
    text += (text.empty() ? "" : ", ") + std::to_string(p);
  return "[" + text + "]";
}

// What is wrong with the request's own values (frame, radius, max_force, particles or radius), or empty.
std::string requestProblem(const Attach::Request& request, const std::vector<HandleParam>& handles)
{
  if (request.frame.empty())
    return "frame is empty: give the TF frame the particles are to follow";
  for (size_t h = 0; h < handles.size(); ++h)
    if (handles[h].frame == request.frame)
      return "frame '" + request.frame + "' already holds handle " + std::to_string(h) +
             "; ~detach it first, or grasp with another frame";
  if (!std::isfinite(request.radius) || request.radius < 0.0)
    return "radius = " + std::to_string(request.radius) + ": must be a finite number of metres >= 0 (0: the particles listed)";
  if (!std::isfinite(request.max_force) || request.max_force < 0.0)
    return "max_force = " + std::to_string(request.max_force) +
           ": must be a finite number of newtons >= 0 (0: the grasp never lets go)";
  if ((request.radius > 0.0) == !request.particles.empty())
    return "give either a radius > 0 or a list of particles, not both and not neither";
  return "";
}

// The free particles within `radius` of `origin` (grid coordinates) into `grasped`, or why none.
std::string particlesWithin(const Grid& grid, const Eigen::Matrix3Xd& points, const Eigen::Vector3d& origin,
                            double radius, const std::string& frame, std::vector<int>& grasped)
{
  double nearest = INFINITY;
  for (int p = 0; p < grid.numParticles(); ++p)
  {
    if (grid.isFixed(p) || grid.isHandle(p))
      continue;
    const double distance = (points.col(p) - origin).norm();
    nearest = std::min(nearest, distance);
    if (distance <= radius)
      grasped.push_back(p);
  }
  if (!grasped.empty())
    return "";
  char text[200];
  std::snprintf(text, sizeof text, "no free particle within radius %.4g m of frame '%s' (the nearest is %.4g m away)",
                radius, frame.c_str(), nearest);
  return text;
}

// The listed particles into `grasped`, each on the grid, free and listed once; or why not.
std::string listedParticles(const Grid& grid, const std::vector<int>& listed, std::vector<int>& grasped)
{
  for (int p : listed)
  {
    if (p < 0 || p >= grid.numParticles())
      return "particle " + std::to_string(p) + " is not on the grid (0 to " + std::to_string(grid.numParticles() - 1) + ")";
    if (grid.isFixed(p) || grid.isHandle(p))
      return "particle " + std::to_string(p) + " is " + (grid.isFixed(p) ? "fixed" : "held by another handle") +
             "; only free particles are grasped";
    if (std::find(grasped.begin(), grasped.end(), p) != grasped.end())
      return "particle " + std::to_string(p) + " is listed twice";
    grasped.push_back(p);
  }
  return "";
}

// Snapping moves the particles' centre onto the frame's origin in a tick: no farther than a frame may jump.
std::string snapProblem(const Eigen::Matrix3Xd& points, const std::vector<int>& grasped, const Eigen::Vector3d& origin)
{
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  for (int p : grasped)
    centre += points.col(p);
  centre /= static_cast<double>(grasped.size());
  const double distance = (centre - origin).norm();
  if (distance <= HandleFrames::kMaxJumpPerTick)
    return "";
  char text[200];
  std::snprintf(text, sizeof text, "snap would move the particles' centre %.3g m in a tick, above %.3g m; "
                "grasp closer or with snap false", distance, HandleFrames::kMaxJumpPerTick);
  return text;
}

}  // namespace

std::string SimulationNode::graspChangeRefusal() const
{
  if (rebuilding())
    return "a rebuild or a cubature training is under way (~status REBUILDING); call again after it";
  if (tracks_.front().simulation->diverged())
    return "the simulation diverged; ~reset first";
  if (config_.simulation.handle_formulation == HandleFormulation::MovingFrame)
    return "handle_formulation is moving_frame, which holds every handle on one body from the start; grasps "
           "while running need constraint_modes or auto";
  return "";
}

std::string SimulationNode::lookupGraspFrame(const std::string& frame, FramePose& pose)
{
  std::string problem;
  const std::optional<FramePose> found = lookupFrame(frame, true, problem);  // no grace: the frame must be there
  if (!found)
    return "frame '" + frame + "' is " + problem;
  pose = *found;
  return "";
}

bool SimulationNode::attach(Attach::Request& request, Attach::Response& response)
{
  boost::recursive_mutex::scoped_lock tuning(tuning_mutex_);  // no live rebuild starts meanwhile
  ServiceLock lock(*this);
  response.success = false;
  response.handle = -1;
  const Grid& grid = primary().simulation->grid();
  const Eigen::Matrix3Xd& points = primary().last_points;  // grid coordinates
  FramePose pose;
  std::vector<int> grasped;
  std::string why = graspChangeRefusal();
  if (why.empty())
    why = requestProblem(request, config_.node.handles);
  if (why.empty())
    why = lookupGraspFrame(request.frame, pose);
  const Eigen::Vector3d origin = pose.translation - config_.node.offset;
  if (why.empty())
    why = request.radius > 0.0 ? particlesWithin(grid, points, origin, request.radius, request.frame, grasped)
                               : listedParticles(grid, request.particles, grasped);
  if (why.empty() && request.snap)
    why = snapProblem(points, grasped, origin);
  if (why.empty())
  {
    NodeConfiguration next = config_;
    next.grid.fixed = effectiveFixed(config_.grid);  // the top row by default stays fixed with handles
    next.grid.handles.push_back(grasped);
    next.node.handles.push_back({request.frame, grasped});
    std::vector<int> keep(config_.node.handles.size());
    std::iota(keep.begin(), keep.end(), 0);
    keep.push_back(-1);
    why = changeHandles(&lock, next, keep, Grip{pose, request.snap != 0});
  }
  if (!why.empty())
  {
    response.message = "attach refused: " + why;
    return true;
  }
  grasp_limits_.resize(config_.node.handles.size(), 0.0);
  grasp_limits_.back() = request.max_force;
  response.success = true;
  response.handle = static_cast<int>(config_.node.handles.size() - 1);
  response.particles = grasped;
  response.message = "attached particles " + joinParticles(grasped) + " to frame '" + request.frame + "' as handle " +
                     std::to_string(response.handle) + (request.snap ? ", snapped onto its origin" : "") + " at step " +
                     std::to_string(steps(primary()));
  ROS_INFO("%s", response.message.c_str());
  return true;
}

bool SimulationNode::detach(Detach::Request& request, Detach::Response& response)
{
  boost::recursive_mutex::scoped_lock tuning(tuning_mutex_);
  ServiceLock lock(*this);
  response.success = false;
  int released = -1;
  std::string frames;
  for (size_t h = 0; h < config_.node.handles.size(); ++h)
  {
    frames += (frames.empty() ? "'" : ", '") + config_.node.handles[h].frame + "'";
    if (config_.node.handles[h].frame == request.frame)
      released = static_cast<int>(h);
  }
  std::string why = released < 0 ? "no handle follows frame '" + request.frame + "' (the handles' frames: " +
                                       (frames.empty() ? std::string("none") : frames) + ")"
                                 : graspChangeRefusal();
  if (why.empty())
    why = releaseHandle(&lock, static_cast<size_t>(released));
  if (!why.empty())
  {
    response.message = "detach refused: " + why;
    return true;
  }
  response.success = true;
  response.message = "detached frame '" + request.frame + "' (handle " + std::to_string(released) +
                     "): its particles are free at step " + std::to_string(steps(primary())) +
                     "; the handles after it are renumbered";
  ROS_INFO("%s", response.message.c_str());
  return true;
}

std::string SimulationNode::releaseHandle(ServiceLock* lock, size_t released)
{
  NodeConfiguration next = config_;
  next.grid.fixed = effectiveFixed(config_.grid);
  next.grid.handles.erase(next.grid.handles.begin() + static_cast<long>(released));
  next.node.handles.erase(next.node.handles.begin() + static_cast<long>(released));
  if (next.grid.handles.empty() && next.grid.fixed.empty())
    return "it is the last thing holding the cloth (no fixed particle, no other handle): a grid needs one";
  std::vector<int> keep;
  for (size_t h = 0; h < config_.node.handles.size(); ++h)
    if (h != released)
      keep.push_back(static_cast<int>(h));
  const std::string failure = changeHandles(lock, next, keep, std::nullopt);
  if (failure.empty() && released < grasp_limits_.size())
    grasp_limits_.erase(grasp_limits_.begin() + static_cast<long>(released));
  return failure;
}

std::string SimulationNode::changeHandles(ServiceLock* lock, NodeConfiguration next, const std::vector<int>& keep,
                                          const std::optional<Grip>& grip)
{
  // A grip taken while running is not where x_ref puts it: the handles are no longer one body.
  next.simulation.handles_one_body = false;
  next.simulation.handle_formulation = HandleFormulation::ConstraintModes;
  const std::vector<TrackKind> kinds = trackKinds();
  const long changes = state_changes_;
  std::vector<std::unique_ptr<Simulation>> built;
  if (lock)
    lock->unlock();  // the running model steps on while the new one is built
  std::string failure;
  try
  {
    built = buildTracksFor(next, kinds, "building the new held set");
  }
  catch (const std::exception& error)
  {
    failure = std::string("the model for the new held set could not be built: ") + error.what();
  }
  if (lock)
    lock->relock();
  if (!failure.empty())
    return failure;
  if (state_changes_ != changes)
    return "the simulation was reset or switched while the new model was built; call again";
  swapInHeldSet(next, built, keep, grip);
  return "";
}

void SimulationNode::swapInHeldSet(const NodeConfiguration& next, std::vector<std::unique_ptr<Simulation>>& built,
                                   const std::vector<int>& keep, const std::optional<Grip>& grip)
{
  // The grips: the kept ones as they were, the new one where its particles are now.
  const Eigen::Matrix3Xd points = primary().simulation->points();
  auto frames = std::make_unique<HandleFrames>(next.node.handles, built.front()->grid(),
                                               built.front()->linearizationPositions(), config_.node.offset);
  for (size_t h = 0; h < keep.size(); ++h)
    if (keep[h] >= 0)
      frames->adopt(h, *handle_frames_, static_cast<size_t>(keep[h]));
    else if (grip)
    {
      const std::vector<int>& particles = next.node.handles[h].particles;
      Eigen::Matrix3Xd held(3, static_cast<Eigen::Index>(particles.size()));
      for (size_t k = 0; k < particles.size(); ++k)
        held.col(static_cast<Eigen::Index>(k)) = points.col(particles[k]) + config_.node.offset;
      frames->grip(h, grip->pose, held, grip->snap);
    }
  for (size_t k = 0; k < tracks_.size(); ++k)
  {
    Track& track = tracks_[k];
    if (built[k]->method() != track.simulation->method())
      built[k]->setMethod(track.simulation->method());  // adaptive under full: full carries its state
    carryOver(*track.simulation, *built[k]);
    track.step_offset += track.simulation->stepCount();
    track.simulation = std::move(built[k]);
    track.restartAdaptive();
    track.divergence_message.clear();
    advertiseWrenches(track, track.handle_force_pubs, "handle_force/handle_", next.node.handles.size());
  }
  handle_frames_ = std::move(frames);
  config_.grid = next.grid;
  config_.node.handles = next.node.handles;
  config_.simulation.handles_one_body = next.simulation.handles_one_body;
  config_.simulation.handle_formulation = next.simulation.handle_formulation;
  // Live tuning builds from these: a later rebuild keeps the new held set.
  accepted_.grid = config_.grid;
  accepted_.node.handles = config_.node.handles;
  accepted_.simulation.handles_one_body = config_.simulation.handles_one_body;
  accepted_.simulation.handle_formulation = config_.simulation.handle_formulation;
  private_params_["handles"] = handleList(config_.node.handles);
  XmlRpc::XmlRpcValue fixed;
  fixed.setSize(static_cast<int>(config_.grid.fixed.size()));
  for (size_t i = 0; i < config_.grid.fixed.size(); ++i)
    fixed[static_cast<int>(i)] = config_.grid.fixed[i];
  private_params_["fixed"] = fixed;
  private_params_["handle_formulation"] = std::string("constraint_modes");
  ++live_builds_;  // the rollouts' workers are built anew
  ++state_changes_;
}

void SimulationNode::releaseSlippingGrasps()
{
  const Simulation& simulation = *primary().simulation;
  const bool limited = std::any_of(grasp_limits_.begin(), grasp_limits_.end(), [](double limit) { return limit > 0.0; });
  if (!limited || simulation.diverged())
    return;
  const std::vector<Simulation::Wrench> wrenches =
      simulation.handleWrenches(std::vector<Eigen::Vector3d>(simulation.grid().handles().size(), Eigen::Vector3d::Zero()));
  for (size_t h = 0; h < grasp_limits_.size() && h < wrenches.size(); ++h)
  {
    const double force = wrenches[h].force.norm();
    const double limit = grasp_limits_[h];
    if (limit > 0.0 && force > limit)
    {
      const std::string frame = config_.node.handles[h].frame;
      const std::string failure = releaseHandle(nullptr, h);
      if (failure.empty())
        ROS_WARN("the grasp of frame '%s' slipped: its force %.3g N is above its max_force %.3g N; its particles are free",
                 frame.c_str(), force, limit);
      else
        ROS_WARN_THROTTLE(5.0, "the grasp of frame '%s' is above its max_force but cannot let go: %s", frame.c_str(),
                          failure.c_str());
      return;  // one release a tick: the indices after it moved
    }
  }
}

}  // namespace modal_mass_spring
