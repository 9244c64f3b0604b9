// The node's parameters: its own on top of the core's, read and validated before anything is built.
#pragma once

#include "modal_mass_spring/grid.h"
#include "modal_mass_spring/parameters.h"
#include "modal_mass_spring/simulation.h"

#include <Eigen/Core>

#include <string>
#include <vector>

namespace modal_mass_spring
{

// A handle as the parameter `handles` gives it: a TF frame and the particles it holds rigidly.
struct HandleParam
{
  std::string frame;
  std::vector<int> particles;  // row * cols + col
};

// The node's sources also read lists of names (methods) and of handles.
class NodeParameterSource : public ParameterSource
{
public:
  virtual std::optional<std::vector<std::string>> getStringList(const std::string& key) const = 0;
  // A list of maps {frame: <string>, particles: [indices]}; throws std::invalid_argument naming the
  // element (`handles[1].particles`) when the value has another shape.
  virtual std::optional<std::vector<HandleParam>> getHandleList(const std::string& key) const = 0;
  // A list of collider maps (contact.h, colliderFromFields); throws std::invalid_argument naming the
  // element and key. A source without colliders need not override it.
  virtual std::optional<std::vector<Collider>> getColliderList(const std::string& /*key*/) const { return std::nullopt; }
};

// Parameters of the node itself, on top of the core's GridParams and SimulationParams.
struct NodeParams
{
  double real_time_factor = 1.0;  // simulated seconds per wall second
  double publish_rate = 30.0;     // Hz: timer ticks, markers, TF and status
  double markers_rate = 0.0;      // Hz of ~markers, at most publish_rate; 0: every tick
  std::string fixed_frame = "world";
  std::string grid_frame = "grid";       // static child of fixed_frame, translated by offset
  std::vector<int> tf_particles;         // broadcast as <grid_frame>/particle_<index>
  Eigen::Vector3d offset = Eigen::Vector3d::Zero();  // m, where the grid is drawn in fixed_frame
  bool color_by_strain = true;
  double strain_scale = 0.1;      // |strain| drawn in full colour
  double particle_diameter = 0.0; // m
  double spring_width = 0.0;      // m
  // Marker namespaces sent. Above detail_max_particles particles, particles and springs are off
  // unless set: the surface alone shows a large sheet at a fraction of the bytes.
  int detail_max_particles = 2500;
  bool show_surface = true;
  bool show_particles = true;
  bool show_springs = true;
  int surface_max_cells = 1600;   // above this, the surface skips rows and columns evenly
  bool show_labels = true;        // a TEXT_VIEW_FACING label per grid: method, distance to full, cost
  bool show_shadow = true;        // the shadow full's faint surface (with shadow_full)

  // The live comparison: these methods stepped in lockstep from the same state, each drawn
  // method_spacing apart along x; empty: one method (`method`). A single method may run a shadow
  // full beside it (shadow_full) for its distance to the unreduced reference.
  std::vector<Method> methods;
  double method_spacing = 0.0;    // m; default: the grid's width plus three spacings
  bool shadow_full = false;
  double status_log_period = 5.0; // s of wall time between status lines in the log; 0: never
  double diagnostic_period = 1.0; // s between /diagnostics messages (diagnostic_updater reads it too)
  // Where the equilibrium, bases and cubature are cached between starts (see cache.h); empty: off.
  // Default: $ROS_HOME/modal_mass_spring, else ~/.ros/modal_mass_spring.
  std::string cache_dir;
  // Particles held rigidly by TF frames (their groups also go to GridParams::handles).
  std::vector<HandleParam> handles;
  // By hand in rviz: the interactive marker's spring (N/m) on the particle it grabs, and the impulse
  // (N s) of a /clicked_point poke; 0 turns either off. Defaults from the grid (drag_and_poke.h).
  double drag_stiffness = 0.0;
  double poke_impulse = 0.0;
  // ~rollout: its worker threads (each with a simulation of its own), the longest horizon (s) and the
  // most candidates a goal may ask for.
  int rollout_threads = 2;
  double rollout_max_horizon = 10.0;
  int rollout_max_candidates = 256;
};

// Reads and validates the node's own parameters, each named once here with its range; defaults that
// depend on the grid (tf_particles, the marker sizes) come from `grid`. `grid` and `sim` must be valid
// (validateParameters). Throws std::invalid_argument naming the parameter, its value and what is
// allowed.
NodeParams loadNodeParams(const NodeParameterSource& source, const GridParams& grid, const SimulationParams& sim);

// Everything the node is configured with.
struct NodeConfiguration
{
  GridParams grid;
  SimulationParams simulation;
  NodeParams node;
  std::vector<std::string> unknown_keys;  // present but read by nobody: typos, or another node's keys
};

// Reads and validates every parameter of the node, builds nothing, so a bad parameter fails at once
// whatever the grid's size: the core's (loadGridParams, loadSimulationParams, validateParameters),
// then the node's (loadNodeParams). SimulationParams::handles_one_body is set when every handle names
// one TF frame; handle_formulation moving_frame with handles on several frames is refused. `present_keys` are the keys set for the node; the ones no getter
// asked for end in unknown_keys. Throws std::invalid_argument naming the first bad parameter.
NodeConfiguration loadNodeConfiguration(const NodeParameterSource& source, const std::vector<std::string>& present_keys);

// The distinct TF frames of the handles, in the order they first appear.
std::vector<std::string> handleFrames(const std::vector<HandleParam>& handles);

// Where the grid of `methods[index]` is drawn in a lockstep comparison: centred on `offset` along x.
Eigen::Vector3d methodOffset(const NodeParams& params, size_t index);

// The child frame of a broadcast particle.
std::string particleFrame(const std::string& grid_frame, int particle);

}  // namespace modal_mass_spring
