// The precomputation cache: what it loads equals what is computed; files that are corrupt,
// truncated, of another version or made for other parameters are rejected with a warning and
// rebuilt; an unwritable directory and a changed parameter only cost a recomputation.
#include "modal_mass_spring/cache.h"
#include "modal_mass_spring/simulation.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <cmath>
#include <filesystem>
#include <functional>
#include <fstream>
#include <string>
#include <sys/stat.h>
#include <unistd.h>
#include <vector>

using namespace modal_mass_spring;
namespace fs = std::filesystem;

namespace
{

// A 3D sheet at its hanging equilibrium with modal derivatives and `cubature`: every part the cache holds.
GridParams sheet()
{
  GridParams g;
  g.rows = g.cols = 7;
  g.dimension = 3;
  g.bending = true;
  return g;
}

SimulationParams sheetParams(Method method = Method::Cubature)
{
  SimulationParams s;
  s.method = method;
  s.num_modes = 5;
  s.linearization = Linearization::Equilibrium;
  s.initial_state = InitialState::Equilibrium;
  s.basis = BasisKind::ModalDerivatives;
  s.num_derivative_modes = 4;
  s.cubature_training_poses = 30;
  return s;
}

// A fresh directory per test, and the warnings the cache gives.
class CacheTest : public testing::Test
{
protected:
  void SetUp() override
  {
    dir_ = fs::temp_directory_path() /
           ("modal_cache_test_" + std::to_string(::getpid()) + "_" +
            testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  CacheOptions options(const std::string& directory = "")
  {
    CacheOptions o;
    o.directory = directory.empty() ? dir_.string() : directory;
    o.warn = [this](const std::string& message) { warnings_.push_back(message); };
    return o;
  }

  std::unique_ptr<Simulation> build(const GridParams& g, const SimulationParams& s, const CacheOptions& o)
  {
    return std::make_unique<Simulation>(g, s, StageFn{}, o);
  }

  fs::path dir_;
  std::vector<std::string> warnings_;
};

void expectSameBasis(const ModalBasis& a, const ModalBasis& b)
{
  EXPECT_EQ(a.phi, b.phi);
  EXPECT_EQ(a.eigenvalues, b.eigenvalues);
  EXPECT_EQ(a.frequencies, b.frequencies);
  EXPECT_EQ(a.num_zero_modes, b.num_zero_modes);
  EXPECT_EQ(a.reduced_stiffness, b.reduced_stiffness);
}

// Bitwise: the same parameters give the same doubles, computed or read back.
void expectSamePrecomputation(const Simulation& a, const Simulation& b)
{
  EXPECT_EQ(a.linearizationPositions(), b.linearizationPositions());
  EXPECT_EQ(a.startPositions(), b.startPositions());
  expectSameBasis(a.basis(), b.basis());
  expectSameBasis(a.physicalBasis(), b.physicalBasis());
  EXPECT_EQ(a.derivativeInfo().derivative_directions, b.derivativeInfo().derivative_directions);
  EXPECT_EQ(a.derivativeInfo().smallest_kept_singular_value, b.derivativeInfo().smallest_kept_singular_value);
  ASSERT_TRUE(a.cubature() && b.cubature());
  EXPECT_EQ(a.cubature()->springs, b.cubature()->springs);
  EXPECT_EQ(a.cubature()->weights, b.cubature()->weights);
  EXPECT_EQ(a.cubature()->training_error, b.cubature()->training_error);
}

void overwrite(const std::string& file, size_t offset, const std::vector<char>& bytes)
{
  std::fstream f(file, std::ios::in | std::ios::out | std::ios::binary);
  f.seekp(static_cast<std::streamoff>(offset));
  f.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

bool mentions(const std::vector<std::string>& warnings, const std::string& file, const std::string& why)
{
  for (const std::string& w : warnings)
    if (w.find(file) != std::string::npos && w.find(why) != std::string::npos)
      return true;
  return false;
}

}  // namespace

TEST_F(CacheTest, CachedBasisAndCubatureEqualRecomputedOnes)
{
  const auto computed = build(sheet(), sheetParams(), CacheOptions{});
  const auto first = build(sheet(), sheetParams(), options());
  EXPECT_FALSE(first->cacheReport().basis_loaded);
  EXPECT_TRUE(first->cacheReport().basis_stored);
  EXPECT_TRUE(first->cacheReport().cubature_stored);
  EXPECT_TRUE(fs::exists(first->cacheReport().basis_file));
  EXPECT_TRUE(fs::exists(first->cacheReport().cubature_file));

  const auto second = build(sheet(), sheetParams(), options());
  EXPECT_TRUE(second->cacheReport().basis_loaded);
  EXPECT_TRUE(second->cacheReport().cubature_loaded);
  EXPECT_FALSE(second->cacheReport().basis_stored);
  EXPECT_TRUE(warnings_.empty()) << warnings_.front();
  expectSamePrecomputation(*computed, *second);
  EXPECT_EQ(computed->linearization().equilibrium_iterations, second->linearization().equilibrium_iterations);

  // And so is what follows from them: a trajectory.
  ASSERT_FALSE(computed->step(50).diverged);
  ASSERT_FALSE(second->step(50).diverged);
  EXPECT_EQ(computed->positions(), second->positions());
}

TEST_F(CacheTest, AnEigenbasisIsStoredOnceAndLoadsAsBothBases)
{
  SimulationParams params;
  params.method = Method::Cubature;
  params.num_modes = 4;
  const auto computed = build(GridParams{}, params, CacheOptions{});
  build(GridParams{}, params, options());
  const auto loaded = build(GridParams{}, params, options());
  EXPECT_TRUE(loaded->cacheReport().basis_loaded);
  EXPECT_TRUE(loaded->cacheReport().cubature_loaded);
  EXPECT_EQ(loaded->physicalBasis().phi, loaded->basis().phi);
  expectSamePrecomputation(*computed, *loaded);
  EXPECT_TRUE(warnings_.empty());
}

TEST_F(CacheTest, LazilyTrainedCubatureIsCachedAtTheFirstSwitch)
{
  const auto physical = build(sheet(), sheetParams(Method::Physical), options());
  EXPECT_TRUE(physical->cacheReport().cubature_file.empty());
  physical->setMethod(Method::Cubature);
  EXPECT_TRUE(physical->cacheReport().cubature_stored);

  const auto cubature = build(sheet(), sheetParams(), options());
  EXPECT_TRUE(cubature->cacheReport().basis_loaded);
  EXPECT_TRUE(cubature->cacheReport().cubature_loaded);
  expectSamePrecomputation(*physical, *cubature);
}

TEST_F(CacheTest, CorruptTruncatedAndOtherVersionFilesAreRejectedAndRebuilt)
{
  const std::string file = build(sheet(), sheetParams(), options())->cacheReport().basis_file;
  const auto reference = build(sheet(), sheetParams(), CacheOptions{});
  const auto size = fs::file_size(file);

  struct Damage
  {
    std::string name;
    std::function<void()> apply;
    std::string why;  // what the warning must say
  };
  const std::vector<Damage> damages{
      {"corrupt", [&] { overwrite(file, size - 100, {'\x7f', '\x13'}); }, "checksum"},
      {"truncated", [&] { fs::resize_file(file, size / 2); }, "truncated"},
      {"another version",
       [&] {
         const std::uint32_t other = kCacheFormatVersion + 1;
         overwrite(file, 8, std::vector<char>(reinterpret_cast<const char*>(&other),
                                              reinterpret_cast<const char*>(&other) + sizeof(other)));
       },
       "format version"},
      {"not a cache file", [&] { overwrite(file, 0, {'G', 'I', 'F'}); }, "not a modal_mass_spring cache file"},
  };
  for (const Damage& damage : damages)
  {
    SCOPED_TRACE(damage.name);
    warnings_.clear();
    damage.apply();
    const auto rebuilt = build(sheet(), sheetParams(), options());
    EXPECT_FALSE(rebuilt->cacheReport().basis_loaded);
    EXPECT_TRUE(rebuilt->cacheReport().basis_stored);
    ASSERT_EQ(warnings_.size(), 1u);
    EXPECT_TRUE(mentions(warnings_, file, damage.why)) << warnings_.front();
    expectSamePrecomputation(*reference, *rebuilt);
    // The rebuilt file is whole again.
    warnings_.clear();
    EXPECT_TRUE(build(sheet(), sheetParams(), options())->cacheReport().basis_loaded);
    EXPECT_TRUE(warnings_.empty());
    ASSERT_EQ(fs::file_size(file), size);
  }
}

// An entry that is a directory or a FIFO is skipped with a warning naming it: never opened (a FIFO
// would block the reader, a directory read as a file asks for a huge buffer), the run goes on.
TEST_F(CacheTest, EntriesThatAreNotRegularFilesAreSkippedWithAWarning)
{
  const auto first = build(sheet(), sheetParams(), options());
  const std::string basis_file = first->cacheReport().basis_file;
  const std::string cubature_file = first->cacheReport().cubature_file;
  ASSERT_FALSE(cubature_file.empty());
  fs::remove(basis_file);
  fs::create_directory(basis_file);
  fs::remove(cubature_file);
  ASSERT_EQ(::mkfifo(cubature_file.c_str(), 0600), 0);
  warnings_.clear();
  const auto rebuilt = build(sheet(), sheetParams(), options());
  EXPECT_FALSE(rebuilt->cacheReport().basis_loaded);
  EXPECT_FALSE(rebuilt->cacheReport().cubature_loaded);
  EXPECT_TRUE(mentions(warnings_, basis_file, "not a regular file"));
  EXPECT_TRUE(mentions(warnings_, cubature_file, "not a regular file"));
  expectSamePrecomputation(*first, *rebuilt);
}

TEST_F(CacheTest, AChangedParameterMissesTheOldEntryAndAFileOfOtherParametersIsRejected)
{
  const auto soft = build(sheet(), sheetParams(), options());
  GridParams stiff_grid = sheet();
  stiff_grid.structural_stiffness *= 2.0;
  const auto stiff = build(stiff_grid, sheetParams(), options());
  EXPECT_FALSE(stiff->cacheReport().basis_loaded);
  EXPECT_FALSE(stiff->cacheReport().cubature_loaded);
  EXPECT_NE(soft->cacheReport().basis_file, stiff->cacheReport().basis_file);
  EXPECT_GT(stiff->basis().frequencies[0], soft->basis().frequencies[0]);
  EXPECT_TRUE(warnings_.empty());

  // A cubature parameter changes the cubature's entry, not the basis'.
  SimulationParams tighter = sheetParams();
  tighter.cubature_tolerance = 0.5 * tighter.cubature_tolerance;
  const auto retrained = build(sheet(), tighter, options());
  EXPECT_TRUE(retrained->cacheReport().basis_loaded);
  EXPECT_FALSE(retrained->cacheReport().cubature_loaded);

  // The soft sheet's file under the stiff sheet's name (a copied file, or a hash collision).
  fs::copy_file(soft->cacheReport().basis_file, stiff->cacheReport().basis_file,
                fs::copy_options::overwrite_existing);
  const auto again = build(stiff_grid, sheetParams(), options());
  EXPECT_FALSE(again->cacheReport().basis_loaded);
  EXPECT_TRUE(mentions(warnings_, stiff->cacheReport().basis_file, "other parameters"));
  EXPECT_EQ(again->basis().phi, stiff->basis().phi);
}

TEST_F(CacheTest, AnUnwritableDirectoryIsAWarningNotAFailure)
{
  // A directory below a regular file can be neither created nor written, even by root.
  fs::create_directories(dir_);
  std::ofstream(dir_ / "a_file") << "not a directory";
  const std::string unwritable = (dir_ / "a_file" / "cache").string();
  std::unique_ptr<Simulation> sim;
  ASSERT_NO_THROW(sim = build(sheet(), sheetParams(), options(unwritable)));
  EXPECT_FALSE(sim->cacheReport().basis_loaded);
  EXPECT_FALSE(sim->cacheReport().basis_stored);
  EXPECT_FALSE(sim->cacheReport().cubature_stored);
  EXPECT_EQ(warnings_.size(), 2u);  // the basis and the cubature
  EXPECT_TRUE(mentions(warnings_, unwritable, "cannot be created"));
  EXPECT_FALSE(sim->step(10).diverged);
  EXPECT_NE(describeCache(sim->cacheReport()).find("NOT stored"), std::string::npos);
}

TEST_F(CacheTest, AWellFormedFileWhoseContentDoesNotFitTheGridIsRejected)
{
  // Checksum and key right, content wrong: no equilibrium where one is needed, then a basis too short.
  const std::string key = basisKey(sheet(), sheetParams());
  const std::string file = cacheFile(dir_.string(), "basis", key);
  const auto reference = build(sheet(), sheetParams(), CacheOptions{});
  Precomputed bad;
  bad.basis = bad.physical_basis = reference->basis();
  ASSERT_TRUE(storePrecomputed(file, key, bad, options()));
  auto rebuilt = build(sheet(), sheetParams(), options());
  EXPECT_FALSE(rebuilt->cacheReport().basis_loaded);
  EXPECT_TRUE(mentions(warnings_, file, "its equilibrium has 0 values"));
  expectSamePrecomputation(*reference, *rebuilt);

  warnings_.clear();
  bad.equilibrium = reference->linearizationPositions();
  bad.basis.phi = bad.basis.phi.topRows(10).eval();
  ASSERT_TRUE(storePrecomputed(file, key, bad, options()));
  rebuilt = build(sheet(), sheetParams(), options());
  EXPECT_FALSE(rebuilt->cacheReport().basis_loaded);
  EXPECT_TRUE(mentions(warnings_, file, "wrong size")) << warnings_.front();
}

TEST(CacheKey, EveryParameterOfThePrecomputationChangesTheKey)
{
  const GridParams g = sheet();
  const SimulationParams s = sheetParams();
  const std::string key = basisKey(g, s);
  std::vector<std::pair<std::string, std::function<void(GridParams&, SimulationParams&)>>> changes{
      {"rows", [](GridParams& g, SimulationParams&) { ++g.rows; }},
      {"spacing", [](GridParams& g, SimulationParams&) { g.spacing = std::nextafter(g.spacing, 1.0); }},
      {"mass", [](GridParams& g, SimulationParams&) { g.mass *= 2; }},
      {"shear_stiffness", [](GridParams& g, SimulationParams&) { g.shear_stiffness *= 2; }},
      {"bending_stiffness", [](GridParams& g, SimulationParams&) { g.bending_stiffness *= 2; }},
      {"fixed", [](GridParams& g, SimulationParams&) { g.fixed = {0, 6}; }},
      {"handles", [](GridParams& g, SimulationParams&) { g.handles = {{7}}; }},
      {"handles grouped", [](GridParams& g, SimulationParams&) { g.handles = {{7}, {8}}; }},
      {"gravity", [](GridParams& g, SimulationParams&) { g.gravity.x() = 1.0; }},
      {"rotation_deg", [](GridParams& g, SimulationParams&) { g.rotation_deg = 10; }},
      {"linearization", [](GridParams&, SimulationParams& s) { s.linearization = Linearization::Rest; }},
      {"num_modes", [](GridParams&, SimulationParams& s) { ++s.num_modes; }},
      {"num_derivative_modes", [](GridParams&, SimulationParams& s) { ++s.num_derivative_modes; }},
      {"num_skinning_weights", [](GridParams&, SimulationParams& s) { ++s.num_skinning_weights; }},
  };
  for (const auto& [name, change] : changes)
  {
    GridParams g2 = g;
    SimulationParams s2 = s;
    change(g2, s2);
    EXPECT_NE(basisKey(g2, s2), key) << name;
  }
  // What does not change the precomputation does not change the key.
  SimulationParams s2 = s;
  s2.time_step = 0.01;
  s2.alpha = 1.0;
  s2.method = Method::Full;
  s2.integrator = IntegratorKind::Implicit;
  EXPECT_EQ(basisKey(g, s2), key);
  s2.cubature_seed = 7;
  EXPECT_EQ(basisKey(g, s2), key);
  EXPECT_NE(cubatureKey(g, s2), cubatureKey(g, s));
  // Every training parameter changes the cubature's key.
  const std::vector<std::pair<std::string, std::function<void(SimulationParams&)>>> training = {
      {"cubature_tolerance", [](SimulationParams& p) { p.cubature_tolerance = 0.05; }},
      {"cubature_max_springs", [](SimulationParams& p) { p.cubature_max_springs = 10; }},
      {"cubature_training_poses", [](SimulationParams& p) { p.cubature_training_poses = 50; }},
      {"cubature_max_training_poses", [](SimulationParams& p) { p.cubature_max_training_poses = 100; }},
      {"cubature_pose_size", [](SimulationParams& p) { p.cubature_pose_size = 0.2; }},
      {"cubature_seed", [](SimulationParams& p) { p.cubature_seed = 2; }}};
  for (const auto& [name, change] : training)
  {
    SimulationParams s3 = s;
    change(s3);
    EXPECT_NE(cubatureKey(g, s3), cubatureKey(g, s)) << name;
  }
}
