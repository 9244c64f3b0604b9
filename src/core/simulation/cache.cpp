// The precomputation cache. The format is hand-written rather than a serialisation library's: the
// payload is a few Eigen matrices written as their sizes and raw doubles, which a library (Boost
// serialization, cereal, HDF5) would add a dependency for without checking more than the header below
// does. A file:
//   "MMSCACHE" | u32 format version | u64 key length | key | u64 payload length | u64 payload checksum | payload
// Native byte order and doubles: the key names the byte order, so a file from another machine misses.
#include "modal_mass_spring/cache.h"

#include "modal_mass_spring/simulation.h"

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <algorithm>
#include <random>
#include <sstream>
#include <system_error>
#include <type_traits>
#include <unistd.h>
#include <vector>

namespace modal_mass_spring
{
namespace
{

constexpr char kMagic[8] = {'M', 'M', 'S', 'C', 'A', 'C', 'H', 'E'};

// FNV-1a, 64 bits, over 8-byte words (a byte at a time is slow on a basis of many MB), the tail
// byte by byte: the file name's hash and the payload's checksum. Not cryptographic: it catches
// truncation, bit flips and stray writes, not an attacker (the cache directory is the user's own).
std::uint64_t fnv1a(const char* data, size_t size)
{
  std::uint64_t hash = 14695981039346656037ull;
  size_t k = 0;
  for (; k + 8 <= size; k += 8)
  {
    std::uint64_t word;
    std::memcpy(&word, data + k, 8);
    hash = (hash ^ word) * 1099511628211ull;
  }
  for (; k < size; ++k)
    hash = (hash ^ static_cast<unsigned char>(data[k])) * 1099511628211ull;
  return hash;
}

void warn(const CacheOptions& options, const std::string& message)
{
  if (options.warn)
    options.warn(message);
  else
    std::cerr << "warning: " << message << std::endl;
}

// Appends plain values and matrices to a byte buffer.
class Writer
{
public:
  template <typename T>
  void put(const T& value)
  {
    static_assert(std::is_trivially_copyable_v<T>);
    const char* p = reinterpret_cast<const char*>(&value);
    bytes.insert(bytes.end(), p, p + sizeof(T));
  }
  void put(const Eigen::MatrixXd& m)
  {
    put<std::int64_t>(m.rows());
    put<std::int64_t>(m.cols());
    if (m.size() == 0)
      return;
    const char* p = reinterpret_cast<const char*>(m.data());
    bytes.insert(bytes.end(), p, p + sizeof(double) * m.size());
  }
  void put(const Eigen::VectorXd& v) { put(Eigen::MatrixXd(v)); }
  std::vector<char> bytes;
};

// Reads them back; any read past the end or an impossible size makes ok() false.
class Reader
{
public:
  Reader(const char* data, size_t size) : data_(data), size_(size) {}
  template <typename T>
  T get()
  {
    static_assert(std::is_trivially_copyable_v<T>);
    T value{};
    if (!take(sizeof(T)))
      return value;
    std::memcpy(&value, data_ + pos_ - sizeof(T), sizeof(T));
    return value;
  }
  Eigen::MatrixXd matrix()
  {
    const auto rows = get<std::int64_t>();
    const auto cols = get<std::int64_t>();
    if (!ok_ || rows < 0 || cols < 0 || (cols > 0 && static_cast<std::uint64_t>(rows) > (size_ - pos_) / 8 / cols))
    {
      ok_ = false;
      return {};
    }
    Eigen::MatrixXd m(rows, cols);
    if (take(sizeof(double) * m.size()) && m.size() > 0)  // an empty matrix has no data pointer
      std::memcpy(m.data(), data_ + pos_ - sizeof(double) * m.size(), sizeof(double) * m.size());
    return m;
  }
  Eigen::VectorXd vector()
  {
    const Eigen::MatrixXd m = matrix();
    if (m.cols() != 1 && m.size() != 0)
      ok_ = false;
    return m.size() == 0 ? Eigen::VectorXd() : Eigen::VectorXd(m.col(0));
  }
  bool ok() const { return ok_; }
  bool atEnd() const { return pos_ == size_; }

private:
  bool take(size_t n)
  {
    if (!ok_ || n > size_ - pos_)
      return ok_ = false;
    pos_ += n;
    return true;
  }
  const char* data_;
  size_t size_;
  size_t pos_ = 0;
  bool ok_ = true;
};

void putBasis(Writer& w, const ModalBasis& b)
{
  w.put(b.phi);
  w.put(b.eigenvalues);
  w.put(b.frequencies);
  w.put<std::int32_t>(b.num_zero_modes);
  w.put<std::int32_t>(b.sparse ? 1 : 0);
  w.put(b.shift);
  w.put<std::int32_t>(b.deflation_passes);
  w.put(b.build_seconds);
  w.put(b.factorization_seconds);
  w.put(b.reduced_stiffness);
}

ModalBasis getBasis(Reader& r)
{
  ModalBasis b;
  b.phi = r.matrix();
  b.eigenvalues = r.vector();
  b.frequencies = r.vector();
  b.num_zero_modes = r.get<std::int32_t>();
  b.sparse = r.get<std::int32_t>() != 0;
  b.shift = r.get<double>();
  b.deflation_passes = r.get<std::int32_t>();
  b.build_seconds = r.get<double>();
  b.factorization_seconds = r.get<double>();
  b.reduced_stiffness = r.matrix();
  return b;
}

// Why a loaded basis does not fit the grid it is for, or empty.
std::string basisMismatch(const ModalBasis& b, int free_dofs)
{
  const auto r = b.phi.cols();
  if (b.phi.rows() != free_dofs || r < 1 || b.eigenvalues.size() != r || b.frequencies.size() != r)
    return "its basis has the wrong size for " + std::to_string(free_dofs) + " free degrees of freedom";
  if (b.reduced_stiffness.size() != 0 && (b.reduced_stiffness.rows() != r || b.reduced_stiffness.cols() != r))
    return "its reduced stiffness has the wrong size";
  if (!b.phi.allFinite() || !b.eigenvalues.allFinite() || !b.frequencies.allFinite())
    return "its basis is not finite";
  return "";
}

// The payload of `file` for `key`, or nothing (with a warning unless the file does not exist).
std::optional<std::vector<char>> readPayload(const std::string& file, const std::string& key,
                                             const CacheOptions& options)
{
  std::error_code error;
  const auto status = std::filesystem::status(file, error);
  if (!std::filesystem::exists(status))
    return std::nullopt;
  // A directory reads as a huge size, a FIFO blocks its reader: neither is ever opened.
  if (!std::filesystem::is_regular_file(status))
  {
    warn(options, "cache file '" + file + "' ignored and rebuilt: it is not a regular file (a directory, FIFO or "
                  "device)");
    return std::nullopt;
  }
  std::ifstream in(file, std::ios::binary | std::ios::ate);
  std::vector<char> bytes(in ? static_cast<size_t>(std::max<std::streamoff>(0, in.tellg())) : 0);
  in.seekg(0);
  in.read(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  auto reject = [&](const std::string& why) -> std::optional<std::vector<char>> {
    warn(options, "cache file '" + file + "' ignored and rebuilt: " + why);
    return std::nullopt;
  };
  if (!in)
    return reject("it cannot be read");
  Reader r(bytes.data(), bytes.size());
  char magic[sizeof(kMagic)];
  for (char& c : magic)
    c = r.get<char>();
  if (!r.ok() || std::memcmp(magic, kMagic, sizeof(kMagic)) != 0)
    return reject("it is not a modal_mass_spring cache file (or is truncated before its header)");
  const auto version = r.get<std::uint32_t>();
  if (!r.ok())
    return reject("it is truncated in its header");
  if (version != kCacheFormatVersion)
    return reject("format version " + std::to_string(version) + ", this build reads version " +
                  std::to_string(kCacheFormatVersion));
  const auto key_length = r.get<std::uint64_t>();
  if (!r.ok() || key_length > bytes.size())
    return reject("it is truncated in its header");
  std::string stored_key(key_length, '\0');
  for (char& c : stored_key)
    c = r.get<char>();
  const auto payload_length = r.get<std::uint64_t>();
  const auto checksum = r.get<std::uint64_t>();
  if (!r.ok())
    return reject("it is truncated in its header");
  if (stored_key != key)
    return reject("it was made for other parameters (a hash collision or a copied file)");
  const size_t header = sizeof(kMagic) + sizeof(std::uint32_t) + 3 * sizeof(std::uint64_t) + key_length;
  if (bytes.size() - header != payload_length)
    return reject("it holds " + std::to_string(bytes.size() - header) + " bytes of data where its header says " +
                  std::to_string(payload_length) + " (truncated or appended to)");
  if (fnv1a(bytes.data() + header, payload_length) != checksum)
    return reject("its checksum does not match its content (corrupt)");
  return std::vector<char>(bytes.begin() + static_cast<long>(header), bytes.end());
}

bool writeFile(const std::string& file, const std::string& key, const std::vector<char>& payload,
               const CacheOptions& options)
{
  namespace fs = std::filesystem;
  std::error_code error;
  const fs::path path(file);
  fs::create_directories(path.parent_path(), error);
  if (error)
  {
    warn(options, "cache directory '" + path.parent_path().string() + "' cannot be created (" + error.message() +
                      "): the precomputation is not cached");
    return false;
  }
  Writer header;
  for (char c : kMagic)
    header.put(c);
  header.put(kCacheFormatVersion);
  header.put<std::uint64_t>(key.size());
  header.bytes.insert(header.bytes.end(), key.begin(), key.end());
  header.put<std::uint64_t>(payload.size());
  header.put(fnv1a(payload.data(), payload.size()));
  // A name no other process or thread writes: the pid and a random number.
  std::random_device random;
  const fs::path temporary =
      path.string() + ".tmp." + std::to_string(::getpid()) + "." + std::to_string(random());
  {
    std::ofstream out(temporary, std::ios::binary | std::ios::trunc);
    out.write(header.bytes.data(), static_cast<std::streamsize>(header.bytes.size()));
    out.write(payload.data(), static_cast<std::streamsize>(payload.size()));
    out.close();
    if (!out)
    {
      fs::remove(temporary, error);
      warn(options, "cache file '" + file + "' cannot be written (directory not writable or full): the "
                    "precomputation is not cached");
      return false;
    }
  }
  fs::rename(temporary, path, error);
  if (error)
  {
    fs::remove(temporary, error);
    warn(options, "cache file '" + file + "' cannot be written (" + error.message() + "): the precomputation is not cached");
    return false;
  }
  return true;
}

void keyLine(std::ostringstream& key, const std::string& name, double value)
{
  char text[64];
  std::snprintf(text, sizeof(text), "%a", value);  // exact: hexadecimal mantissa
  key << name << '=' << text << '\n';
}

}  // namespace

std::string defaultCacheDirectory()
{
  if (const char* ros_home = std::getenv("ROS_HOME"); ros_home && *ros_home)
    return std::string(ros_home) + "/modal_mass_spring";
  if (const char* home = std::getenv("HOME"); home && *home)
    return std::string(home) + "/.ros/modal_mass_spring";
  return "";
}

std::string basisKey(const GridParams& g, const SimulationParams& p)
{
  std::ostringstream key;
  const std::uint32_t order = 0x01020304;
  key << "byte_order=" << static_cast<int>(*reinterpret_cast<const unsigned char*>(&order)) << '\n';
  key << "rows=" << g.rows << "\ncols=" << g.cols << "\ndimension=" << g.dimension << '\n';
  keyLine(key, "spacing", g.spacing);
  keyLine(key, "mass", g.mass);
  keyLine(key, "structural_stiffness", g.structural_stiffness);
  keyLine(key, "shear_stiffness", g.shear_stiffness);
  key << "bending=" << g.bending << '\n';
  keyLine(key, "bending_stiffness", g.bending_stiffness);
  key << "fixed=";
  for (int index : g.fixed)
    key << index << ',';
  key << '\n';
  // Handle particles are held while the basis is computed (the fixed-interface modes).
  key << "handles=";
  for (const std::vector<int>& handle : g.handles)
  {
    for (int index : handle)
      key << index << ',';
    key << ';';
  }
  key << '\n';
  for (int k = 0; k < 3; ++k)
    keyLine(key, "gravity" + std::to_string(k), g.gravity[k]);
  keyLine(key, "rotation_deg", g.rotation_deg);
  key << "linearization=" << toString(p.linearization) << "\ninitial_state=" << toString(p.initial_state)
      << "\nnum_modes=" << p.num_modes << "\nbasis=" << toString(p.basis)
      << "\nnum_derivative_modes=" << p.num_derivative_modes << "\nnum_skinning_weights=" << p.num_skinning_weights
      << '\n';
  // The handles' part of the skinning span moves the whole cloth by their affine motion (entries
  // stored before it was, with the least-squares interior alone, must not be read for it).
  // Its weights are harmonic between the held particles and vanish on them past one per group
  // (entries stored with the global Laplacian's eigenvectors must not be read for them).
  if (p.basis == BasisKind::Skinning)
    key << "skinning_handle_extension=affine\nskinning_weights=held_groups\n";
  return key.str();
}

std::string cubatureKey(const GridParams& g, const SimulationParams& p)
{
  std::ostringstream key;
  key << basisKey(g, p);
  keyLine(key, "cubature_tolerance", p.cubature_tolerance);
  key << "cubature_max_springs=" << p.cubature_max_springs << "\ncubature_training_poses=" << p.cubature_training_poses
      << "\ncubature_max_training_poses=" << p.cubature_max_training_poses << '\n';
  keyLine(key, "cubature_pose_size", p.cubature_pose_size);
  key << "cubature_seed=" << p.cubature_seed << '\n';
  return key.str();
}

std::string cacheFile(const std::string& directory, const std::string& kind, const std::string& key)
{
  char hash[17];
  std::snprintf(hash, sizeof(hash), "%016llx", static_cast<unsigned long long>(fnv1a(key.data(), key.size())));
  return (std::filesystem::path(directory) / (kind + "-" + hash + ".bin")).string();
}

std::string describeCache(const CacheReport& report)
{
  std::ostringstream text;
  text.precision(3);
  if (report.basis_file.empty())
    text << "basis computed (cache off)";
  else if (report.basis_loaded)
    text << "basis loaded from the cache " << report.basis_file << " in " << report.basis_load_seconds * 1e3 << " ms";
  else
    text << "basis computed and " << (report.basis_stored ? "stored in " : "NOT stored in ") << report.basis_file;
  if (report.cubature_loaded)
    text << "; cubature loaded from " << report.cubature_file;
  else if (!report.cubature_file.empty())
    text << "; cubature trained and " << (report.cubature_stored ? "stored in " : "NOT stored in ")
         << report.cubature_file;
  return text.str();
}

std::optional<Precomputed> loadPrecomputed(const std::string& file, const std::string& key, int free_dofs,
                                           int equilibrium_dofs, const CacheOptions& options)
{
  const auto payload = readPayload(file, key, options);
  if (!payload)
    return std::nullopt;
  Reader r(payload->data(), payload->size());
  Precomputed p;
  p.equilibrium = r.vector();
  p.equilibrium_iterations = r.get<std::int32_t>();
  p.equilibrium_residual = r.get<double>();
  p.equilibrium_seconds = r.get<double>();
  p.basis = getBasis(r);
  p.physical_basis = r.get<std::int32_t>() != 0 ? p.basis : getBasis(r);
  DerivativeBasisInfo& d = p.derivative_info;
  d.linear_modes = r.get<std::int32_t>();
  d.derivative_directions = r.get<std::int32_t>();
  d.derivatives_computed = r.get<std::int32_t>();
  d.seconds = r.get<double>();
  d.smallest_kept_singular_value = r.get<double>();
  d.largest_dropped_singular_value = r.get<double>();
  p.skinning_constraint_modes = r.matrix();
  SkinningInfo& k = p.skinning_info;
  k.weights = r.get<std::int32_t>();
  k.coordinates = r.get<std::int32_t>();
  k.constraint_dofs = r.get<std::int32_t>();
  k.constraint_rank = r.get<std::int32_t>();
  k.basis_size = r.get<std::int32_t>();
  k.modes = r.get<std::int32_t>();
  k.seconds = r.get<double>();
  std::string why = !r.ok() || !r.atEnd() ? "its content does not have the layout of this format version" : "";
  if (why.empty())
    why = basisMismatch(p.basis, free_dofs);
  if (why.empty())
    why = basisMismatch(p.physical_basis, free_dofs);
  if (why.empty() && p.skinning_constraint_modes.size() > 0 &&
      (p.skinning_constraint_modes.rows() != free_dofs || !p.skinning_constraint_modes.allFinite()))
    why = "its skinning constraint modes do not fit " + std::to_string(free_dofs) + " free degrees of freedom";
  if (why.empty() && p.equilibrium.size() != equilibrium_dofs)
    why = "its equilibrium has " + std::to_string(p.equilibrium.size()) + " values where " +
          std::to_string(equilibrium_dofs) + " are needed";
  if (why.empty() && !p.equilibrium.allFinite())
    why = "its equilibrium is not finite";
  if (!why.empty())
  {
    warn(options, "cache file '" + file + "' ignored and rebuilt: " + why);
    return std::nullopt;
  }
  return p;
}

bool storePrecomputed(const std::string& file, const std::string& key, const Precomputed& p,
                      const CacheOptions& options)
{
  Writer w;
  w.put(p.equilibrium);
  w.put<std::int32_t>(p.equilibrium_iterations);
  w.put(p.equilibrium_residual);
  w.put(p.equilibrium_seconds);
  putBasis(w, p.basis);
  // Without derivative directions the physical basis is the eigenbasis: written once.
  const bool same = p.physical_basis.phi.cols() == p.basis.phi.cols() && p.physical_basis.phi == p.basis.phi &&
                    p.physical_basis.reduced_stiffness.size() == p.basis.reduced_stiffness.size();
  w.put<std::int32_t>(same ? 1 : 0);
  if (!same)
    putBasis(w, p.physical_basis);
  const DerivativeBasisInfo& d = p.derivative_info;
  w.put<std::int32_t>(d.linear_modes);
  w.put<std::int32_t>(d.derivative_directions);
  w.put<std::int32_t>(d.derivatives_computed);
  w.put(d.seconds);
  w.put(d.smallest_kept_singular_value);
  w.put(d.largest_dropped_singular_value);
  w.put(p.skinning_constraint_modes);
  const SkinningInfo& k = p.skinning_info;
  for (int value : {k.weights, k.coordinates, k.constraint_dofs, k.constraint_rank, k.basis_size, k.modes})
    w.put<std::int32_t>(value);
  w.put(k.seconds);
  return writeFile(file, key, w.bytes, options);
}

std::optional<Cubature> loadCubature(const std::string& file, const std::string& key, int num_springs,
                                     const CacheOptions& options)
{
  const auto payload = readPayload(file, key, options);
  if (!payload)
    return std::nullopt;
  Reader r(payload->data(), payload->size());
  Cubature c;
  const Eigen::VectorXd springs = r.vector();
  c.weights = r.vector();
  c.training_error = r.get<double>();
  c.validation_error = r.get<double>();
  c.heldout_error = r.get<double>();
  c.training_seconds = r.get<double>();
  c.training_poses = r.get<std::int32_t>();
  std::string why = !r.ok() || !r.atEnd() ? "its content does not have the layout of this format version" : "";
  if (why.empty() && (springs.size() == 0 || springs.size() != c.weights.size()))
    why = "its springs and weights differ in number";
  for (int k = 0; why.empty() && k < springs.size(); ++k)
  {
    if (!(springs[k] >= 0 && springs[k] < num_springs) || springs[k] != static_cast<int>(springs[k]))
      why = "a spring index is outside the grid's " + std::to_string(num_springs) + " springs";
    else if (!(c.weights[k] >= 0.0) || !std::isfinite(c.weights[k]))
      why = "a weight is negative or not finite";
    c.springs.push_back(static_cast<int>(springs[k]));
  }
  if (!why.empty())
  {
    warn(options, "cache file '" + file + "' ignored and rebuilt: " + why);
    return std::nullopt;
  }
  return c;
}

bool storeCubature(const std::string& file, const std::string& key, const Cubature& c, const CacheOptions& options)
{
  Writer w;
  // Spring indices as doubles: exact below 2^53, and one matrix routine for everything.
  Eigen::VectorXd springs(static_cast<long>(c.springs.size()));
  for (size_t k = 0; k < c.springs.size(); ++k)
    springs[static_cast<long>(k)] = c.springs[k];
  w.put(springs);
  w.put(c.weights);
  w.put(c.training_error);
  w.put(c.validation_error);
  w.put(c.heldout_error);
  w.put(c.training_seconds);
  w.put<std::int32_t>(c.training_poses);
  return writeFile(file, key, w.bytes, options);
}

}  // namespace modal_mass_spring
