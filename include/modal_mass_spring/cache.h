// The precomputation cache: the equilibrium, the bases and the cubature written to files keyed by
// every parameter they depend on, so that a start with the same parameters loads them instead of
// solving again.
#pragma once

#include "modal_mass_spring/cubature.h"
#include "modal_mass_spring/grid.h"
#include "modal_mass_spring/modal_basis.h"
#include "modal_mass_spring/modal_derivatives.h"
#include "modal_mass_spring/skinning.h"

#include <Eigen/Core>

#include <cstdint>
#include <functional>
#include <optional>
#include <string>

namespace modal_mass_spring
{

struct SimulationParams;

// Bumped whenever the file layout or anything that changes the computed result (the eigensolver, the
// derivative basis, the training, the equilibrium solve) changes: a file of another version is rebuilt.
constexpr std::uint32_t kCacheFormatVersion = 6;

// Where a Simulation keeps its cache. Not a SimulationParams: it changes no result, only whether the
// start-up recomputes it, and its default is the caller's ($ROS_HOME for the node).
struct CacheOptions
{
  std::string directory;  // empty: no cache
  // Told each file rejected or not written, and why; null: printed on stderr.
  std::function<void(const std::string&)> warn;
};

// "$ROS_HOME/modal_mass_spring", else "$HOME/.ros/modal_mass_spring", else "" (no cache).
std::string defaultCacheDirectory();

// What the cache did for a Simulation: the files it read or wrote.
struct CacheReport
{
  std::string basis_file;        // empty with no cache
  bool basis_loaded = false;     // the equilibrium and the bases came from basis_file
  bool basis_stored = false;     // they were computed and written to it
  double basis_load_seconds = 0.0;
  std::string cubature_file;     // once a cubature is needed
  bool cubature_loaded = false;
  bool cubature_stored = false;
};

// "basis loaded from the cache /x/basis-0123.bin in 3.1 ms", "basis computed and stored in ...",
// "basis computed (no cache)"; and the cubature's when there is one.
std::string describeCache(const CacheReport& report);

// Everything a Simulation computes before its first step from the parameters alone, but its
// stiffness (cheap to assemble again from the linearization point).
struct Precomputed
{
  Eigen::VectorXd equilibrium;  // all dofs; empty when it was not solved
  int equilibrium_iterations = 0;
  double equilibrium_residual = 0.0;
  double equilibrium_seconds = 0.0;
  ModalBasis basis;           // the eigenbasis
  ModalBasis physical_basis;  // the same, or with the derivative directions, or the skinning subspace
  DerivativeBasisInfo derivative_info;
  Eigen::MatrixXd skinning_constraint_modes;  // with basis: skinning and handles, else empty
  SkinningInfo skinning_info;
};

// The text of every parameter the equilibrium and the bases depend on (doubles exact), and the same
// with the cubature's training parameters: a file is used only for the very same text.
std::string basisKey(const GridParams& grid, const SimulationParams& params);
std::string cubatureKey(const GridParams& grid, const SimulationParams& params);

// The file of a key in `directory`: "<kind>-<64-bit hash of the key in hex>.bin".
std::string cacheFile(const std::string& directory, const std::string& kind, const std::string& key);

// Reads the file of `key`. A missing file gives nothing silently; one that is truncated, corrupt
// (checksum), of another format version or made for other parameters, or whose sizes do not fit
// `free_dofs` and `equilibrium_dofs` (all dofs when the equilibrium is needed, else 0), gives nothing
// and a warning naming the file and why.
std::optional<Precomputed> loadPrecomputed(const std::string& file, const std::string& key, int free_dofs,
                                           int equilibrium_dofs, const CacheOptions& options);
std::optional<Cubature> loadCubature(const std::string& file, const std::string& key, int num_springs,
                                     const CacheOptions& options);

// Writes atomically (a temporary file in the same directory, then a rename): readers see the old
// file or the whole new one. Returns false, with a warning, when the directory or file cannot be
// written.
bool storePrecomputed(const std::string& file, const std::string& key, const Precomputed& data,
                      const CacheOptions& options);
bool storeCubature(const std::string& file, const std::string& key, const Cubature& cubature,
                   const CacheOptions& options);

}  // namespace modal_mass_spring
