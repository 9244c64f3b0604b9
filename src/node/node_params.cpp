// Every node parameter, its default and its range, in one place.
#include "node_params.h"

#include "contact_messages.h"

#include "drag_and_poke.h"

#include "modal_mass_spring/cache.h"
#include "modal_mass_spring/validation.h"

#include <algorithm>
#include <cmath>
#include <set>
#include <sstream>

namespace modal_mass_spring
{
namespace
{

// More steps per tick than this would stall the timer for seconds; it is a configuration mistake.
constexpr double kMaxStepsPerTick = 100000.0;
// Lengths and scales beyond this (m, or a strain) are typing mistakes, and would overflow the markers.
constexpr double kMaxLength = 1e6;
// A surface of more cells than this would exceed rviz's message sizes by far (480 bytes a cell).
constexpr int kMaxSurfaceCells = 1000000;

// Remembers which keys were asked for, so the keys nobody reads can be named.
class RecordingSource : public NodeParameterSource
{
public:
  explicit RecordingSource(const NodeParameterSource& source) : source_(source) {}
  std::optional<int> getInt(const std::string& key) const override { return note(key), source_.getInt(key); }
  std::optional<double> getDouble(const std::string& key) const override { return note(key), source_.getDouble(key); }
  std::optional<bool> getBool(const std::string& key) const override { return note(key), source_.getBool(key); }
  std::optional<std::string> getString(const std::string& key) const override
  {
    return note(key), source_.getString(key);
  }
  std::optional<std::vector<int>> getIntList(const std::string& key) const override
  {
    return note(key), source_.getIntList(key);
  }
  std::optional<std::vector<double>> getDoubleList(const std::string& key) const override
  {
    return note(key), source_.getDoubleList(key);
  }
  std::optional<std::vector<std::string>> getStringList(const std::string& key) const override
  {
    return note(key), source_.getStringList(key);
  }
  std::optional<std::vector<HandleParam>> getHandleList(const std::string& key) const override
  {
    return note(key), source_.getHandleList(key);
  }
  std::optional<std::vector<Collider>> getColliderList(const std::string& key) const override
  {
    return note(key), source_.getColliderList(key);
  }
  const std::set<std::string>& queried() const { return queried_; }

private:
  void note(const std::string& key) const { queried_.insert(key); }
  const NodeParameterSource& source_;
  mutable std::set<std::string> queried_;
};

// A number in (0, max].
double positive(const ParameterSource& s, const std::string& name, double fallback, double max, const std::string& unit)
{
  const double value = s.getDouble(name).value_or(fallback);
  if (!std::isfinite(value) || value <= 0.0 || value > max)
  {
    std::ostringstream allowed;
    allowed << "must be a number > 0 and <= " << max << unit;
    rejectParameter(name, value, allowed.str());
  }
  return value;
}

// A number in [0, max].
double nonNegative(const ParameterSource& s, const std::string& name, double fallback, double max,
                   const std::string& unit)
{
  const double value = s.getDouble(name).value_or(fallback);
  if (!std::isfinite(value) || value < 0.0 || value > max)
  {
    std::ostringstream allowed;
    allowed << "must be a number >= 0 and <= " << max << unit;
    rejectParameter(name, value, allowed.str());
  }
  return value;
}

// An integer in [min, max].
int intInRange(const ParameterSource& s, const std::string& name, int fallback, long long min, long long max)
{
  const int value = s.getInt(name).value_or(fallback);
  if (value < min || value > max)
    rejectParameter(name, value, "must be an integer in [" + std::to_string(min) + ", " + std::to_string(max) + "]");
  return value;
}

std::string frameId(const ParameterSource& s, const std::string& name, const std::string& fallback)
{
  const std::string value = s.getString(name).value_or(fallback);
  if (value.empty() || value.front() == '/' || value.find_first_of(" \t\n\r") != std::string::npos)
    rejectParameter(name, "'" + value + "'", "must be a non-empty frame id without a leading '/' or spaces");
  return value;
}

// real_time_factor and publish_rate, and the steps per tick they give at the time step.
void loadPacing(const NodeParameterSource& s, const SimulationParams& sim, NodeParams& p)
{
  p.real_time_factor = positive(s, "real_time_factor", p.real_time_factor, 1000.0, "");
  p.publish_rate = positive(s, "publish_rate", p.publish_rate, 1000.0, " Hz");
  const double steps_per_tick = p.real_time_factor / (p.publish_rate * sim.time_step);
  if (steps_per_tick > kMaxStepsPerTick)
  {
    // All three decide it: name them all, with their values.
    std::ostringstream value, allowed;
    value << "real_time_factor " << p.real_time_factor << ", publish_rate " << p.publish_rate << " Hz, time_step "
          << sim.time_step << " s";
    allowed << "give real_time_factor / (publish_rate * time_step) = " << steps_per_tick
            << " steps per tick; must be at most " << kMaxStepsPerTick
            << " (lower real_time_factor, raise publish_rate or time_step)";
    rejectParameter("real_time_factor, publish_rate, time_step", value.str(), allowed.str());
  }
}

// The fixed and grid frames, the particles given TF frames, and where the grid is drawn.
void loadFrames(const NodeParameterSource& s, const GridParams& grid, NodeParams& p)
{
  p.fixed_frame = frameId(s, "fixed_frame", p.fixed_frame);
  p.grid_frame = frameId(s, "grid_frame", p.grid_frame);
  if (p.grid_frame == p.fixed_frame)
    rejectParameter("grid_frame", "'" + p.grid_frame + "'", "must differ from fixed_frame");

  // validateParameters bounds the grid far below 2^31 particles.
  const int n = grid.rows * grid.cols;
  // The two bottom corners: the particles that move most under gravity.
  std::vector<int> corners{(grid.rows - 1) * grid.cols, n - 1};
  corners.erase(std::unique(corners.begin(), corners.end()), corners.end());
  p.tf_particles = s.getIntList("tf_particles").value_or(corners);
  checkParticleIndices("tf_particles", p.tf_particles, n);

  if (const auto offset = s.getDoubleList("offset"))
  {
    const auto bad = std::find_if(offset->begin(), offset->end(),
                                  [](double v) { return !std::isfinite(v) || std::abs(v) > kMaxLength; });
    if (offset->size() != 3)
      rejectParameter("offset", std::to_string(offset->size()) + " values",
                      "must be a list of 3 numbers [x, y, z] in m, each in [-1e+06, 1e+06]");
    if (bad != offset->end())
      rejectParameter("offset", *bad, "must be a list of 3 numbers [x, y, z] in m, each in [-1e+06, 1e+06]");
    p.offset = Eigen::Vector3d((*offset)[0], (*offset)[1], (*offset)[2]);
  }
}

// How the markers look: colours, sizes, which namespaces are drawn.
void loadDrawing(const NodeParameterSource& s, const GridParams& grid, NodeParams& p)
{
  p.color_by_strain = s.getBool("color_by_strain").value_or(p.color_by_strain);
  p.strain_scale = positive(s, "strain_scale", p.strain_scale, kMaxLength, "");
  p.particle_diameter = positive(s, "particle_diameter", 0.3 * grid.spacing, kMaxLength, " m");
  p.spring_width = positive(s, "spring_width", 0.06 * grid.spacing, kMaxLength, " m");
  p.detail_max_particles = intInRange(s, "detail_max_particles", p.detail_max_particles, 0, kMaxParticles);
  const bool detailed = grid.rows * grid.cols <= p.detail_max_particles;
  p.show_surface = s.getBool("show_surface").value_or(p.show_surface);
  p.show_particles = s.getBool("show_particles").value_or(detailed);
  p.show_springs = s.getBool("show_springs").value_or(detailed);
  p.surface_max_cells = intInRange(s, "surface_max_cells", p.surface_max_cells, 1, kMaxSurfaceCells);
  p.show_labels = s.getBool("show_labels").value_or(p.show_labels);
  p.show_shadow = s.getBool("show_shadow").value_or(p.show_shadow);
  // Markers are most of a recording's bytes: a lower rate keeps a bag small, the points stay per tick.
  p.markers_rate = nonNegative(s, "markers_rate", p.markers_rate, p.publish_rate,
                               " Hz (publish_rate: markers go out with a tick; 0: every tick)");
}

// The methods compared in lockstep and their spacing, or the shadow full beside a single one.
void loadMethods(const NodeParameterSource& s, const GridParams& grid, NodeParams& p)
{
  if (const auto names = s.getStringList("methods"))
  {
    const std::string allowed = methodList();
    if (names->empty() || names->size() > methodNames().size())
      rejectParameter("methods", std::to_string(names->size()) + " names",
                      "must list 1 to " + std::to_string(methodNames().size()) + " of " + allowed);
    for (const auto& name : *names)
    {
      if (std::find(methodNames().begin(), methodNames().end(), name) == methodNames().end())
        rejectParameter("methods", "'" + name + "'", "each must be one of " + allowed);
      if (std::count(names->begin(), names->end(), name) > 1)
        rejectParameter("methods", "'" + name + "'", "each method must be listed once");
      p.methods.push_back(parseMethod(name));
    }
  }
  p.method_spacing = positive(s, "method_spacing", (grid.cols + 2) * grid.spacing, kMaxLength, " m");
  p.shadow_full = s.getBool("shadow_full").value_or(p.shadow_full);
  if (p.shadow_full && !p.methods.empty())
    rejectParameter("shadow_full", "true",
                    "must be false when methods is set (list full among the methods to compare with it)");
}

}  // namespace

std::string particleFrame(const std::string& grid_frame, int particle)
{
  return grid_frame + "/particle_" + std::to_string(particle);
}

Eigen::Vector3d methodOffset(const NodeParams& params, size_t index)
{
  const double centre = 0.5 * (static_cast<double>(params.methods.size()) - 1.0);
  return params.offset + Eigen::Vector3d((static_cast<double>(index) - centre) * params.method_spacing, 0.0, 0.0);
}

NodeParams loadNodeParams(const NodeParameterSource& s, const GridParams& grid, const SimulationParams& sim)
{
  NodeParams p;
  loadPacing(s, sim, p);
  loadFrames(s, grid, p);
  loadDrawing(s, grid, p);
  loadMethods(s, grid, p);
  p.status_log_period = nonNegative(s, "status_log_period", p.status_log_period, 86400.0, " s (0: no status lines)");
  p.diagnostic_period = positive(s, "diagnostic_period", p.diagnostic_period, 3600.0, " s");
  // The spring acts from the state at the start of each step: a stiffer one than this the step cannot hold.
  p.drag_stiffness = nonNegative(s, "drag_stiffness", defaultDragStiffness(grid, sim.time_step),
                                 maxDragStiffness(grid, sim.time_step),
                                 " N/m (mass / time_step^2: the spring is applied once per step, a stiffer one is "
                                 "unstable; 0: no dragging)");
  p.poke_impulse = nonNegative(s, "poke_impulse", defaultPokeImpulse(grid), maxPokeImpulse(grid),
                               " N s (the grid's momentum at 10 m/s; 0: no poking)");
  p.rollout_threads = intInRange(s, "rollout_threads", p.rollout_threads, 1, 64);
  p.rollout_max_horizon = positive(s, "rollout_max_horizon", p.rollout_max_horizon, 3600.0, " s");
  p.rollout_max_candidates = intInRange(s, "rollout_max_candidates", p.rollout_max_candidates, 1, 100000);
  // Any path: one that cannot be written is a warning at start-up, not an error.
  p.cache_dir = s.getString("cache_dir").value_or(defaultCacheDirectory());
  return p;
}

namespace
{

// The frames are checked here, the particle groups by the core.
std::vector<HandleParam> loadHandles(const NodeParameterSource& s)
{
  const std::vector<HandleParam> handles = s.getHandleList("handles").value_or(std::vector<HandleParam>{});
  for (size_t h = 0; h < handles.size(); ++h)
  {
    const std::string name = "handles[" + std::to_string(h) + "].frame";
    const std::string& frame = handles[h].frame;
    if (frame.empty() || frame.front() == '/' || frame.find_first_of(" \t\n\r") != std::string::npos)
      rejectParameter(name, "'" + frame + "'", "must be a non-empty frame id without a leading '/' or spaces");
  }
  return handles;
}

}  // namespace

std::vector<std::string> handleFrames(const std::vector<HandleParam>& handles)
{
  std::vector<std::string> frames;
  for (const auto& handle : handles)
    if (std::find(frames.begin(), frames.end(), handle.frame) == frames.end())
      frames.push_back(handle.frame);
  return frames;
}

NodeConfiguration loadNodeConfiguration(const NodeParameterSource& source, const std::vector<std::string>& present_keys)
{
  const RecordingSource recording(source);
  NodeConfiguration c;
  c.grid = loadGridParams(recording);
  c.simulation = loadSimulationParams(recording);
  c.simulation.colliders = recording.getColliderList("colliders").value_or(std::vector<Collider>{});
  nameColliders(c.simulation.colliders);  // ~set_colliders knows them by id
  // A collider's `frame` (checked by colliderFromFields) is followed by the node (collider_frames.h).
  // The handles' particle groups are the core's to check (range, one handle each, not fixed).
  const std::vector<HandleParam> handles = loadHandles(recording);
  for (const auto& handle : handles)
    c.grid.handles.push_back(handle.particles);
  // Handles on one TF frame move as one rigid body: the core may then simulate in that frame.
  const std::vector<std::string> frames = handleFrames(handles);
  c.simulation.handles_one_body = frames.size() == 1;
  if (c.simulation.handle_formulation == HandleFormulation::MovingFrame && frames.size() > 1)
  {
    std::string names;
    for (const auto& frame : frames)
      names += (names.empty() ? "'" : ", '") + frame + "'";
    rejectParameter("handle_formulation", "moving_frame",
                    "needs every handle on one TF frame (one rigid body), but the handles name " +
                        std::to_string(frames.size()) + " frames: " + names +
                        "; use auto or constraint_modes for handles that move apart");
  }
  // The node's own checks (tf_particles, steps per tick) rely on a valid grid and time step.
  validateParameters(c.grid, c.simulation);
  // The explicit scheme's position update takes the damping force at the step's start: beyond
  // alpha dt = 2 it overshoots, and the first push (a poke, a handle, the motion carried over by a live
  // change) diverges. The core allows it (modal_compare's stability scan crosses it on purpose).
  const double alpha_dt = c.simulation.alpha * c.simulation.time_step;
  if (c.simulation.integrator == IntegratorKind::Explicit && alpha_dt > 2.0)
  {
    std::ostringstream allowed;
    allowed << "with the explicit integrator alpha * time_step must be at most 2 (alpha <= " << 2.0 / c.simulation.time_step
            << " 1/s at time_step = " << c.simulation.time_step
            << " s): beyond it the damping overshoots and a moving cloth diverges; use integrator: implicit for heavier damping";
    rejectParameter("alpha", c.simulation.alpha, allowed.str());
  }
  c.node = loadNodeParams(recording, c.grid, c.simulation);
  c.node.handles = handles;
  for (size_t h = 0; h < handles.size(); ++h)
    if (handles[h].frame == c.node.fixed_frame || handles[h].frame == c.node.grid_frame)
      rejectParameter("handles[" + std::to_string(h) + "].frame", "'" + handles[h].frame + "'",
                      "a handle's frame must differ from fixed_frame and grid_frame (use `fixed` for particles "
                      "that never move)");
  for (const auto& key : present_keys)
    if (!recording.queried().count(key))
      c.unknown_keys.push_back(key);
  return c;
}

}  // namespace modal_mass_spring
