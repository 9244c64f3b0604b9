// A live comparison's methods: full ones started from a reduced one's state, distances between grids.
#include "lockstep.h"

#include <gtest/gtest.h>

#include <memory>

namespace
{

using namespace modal_mass_spring;

std::unique_ptr<Simulation> simulation(Method method)
{
  GridParams grid;
  grid.rows = grid.cols = 4;
  grid.spacing = 0.1;
  SimulationParams params;
  params.method = method;
  params.num_modes = 3;
  params.time_step = 1e-3;
  return std::make_unique<Simulation>(grid, params);
}

// After a few steps under gravity the reduced method has moved; the full ones take its state, the
// reduced one keeps its own.
TEST(Lockstep, FullMethodsStartFromTheFirstReducedOne)
{
  auto full = simulation(Method::Full), linear = simulation(Method::Linear), other = simulation(Method::Full);
  linear->step(50);
  const Eigen::VectorXd u = linear->displacement(), v = linear->velocity();
  ASSERT_GT(u.norm(), 0.0);
  EXPECT_EQ(synchroniseFull({full.get(), linear.get(), other.get()}, false), (std::vector<size_t>{0, 2}));
  EXPECT_LT((full->displacement() - u).norm(), 1e-12 * u.norm());
  EXPECT_LT((other->velocity() - v).norm(), 1e-12 * v.norm());
  EXPECT_LT((linear->displacement() - u).norm(), 1e-15);
}

// A single method with its shadow full: the first is the source even when it is full itself; every
// method full in a comparison has no source.
TEST(Lockstep, TheFirstIsTheSourceOfItsShadowAndAllFullHaveNone)
{
  auto first = simulation(Method::Full), shadow = simulation(Method::Full);
  first->step(50);
  EXPECT_EQ(synchroniseFull({first.get(), shadow.get()}, true), std::vector<size_t>{1});
  EXPECT_LT((shadow->displacement() - first->displacement()).norm(), 1e-12 * first->displacement().norm());
  shadow->step(10);
  EXPECT_TRUE(synchroniseFull({first.get(), shadow.get()}, false).empty());
  EXPECT_GT((shadow->displacement() - first->displacement()).norm(), 0.0) << "nothing set without a source";
}

TEST(Lockstep, DistancesPerParticleTheirRmsAndLargest)
{
  Eigen::Matrix3Xd reference = Eigen::Matrix3Xd::Zero(3, 2), points = reference;
  EXPECT_EQ(particleDistances(points, reference).max, 0.0);
  points.col(0) << 3.0, 4.0, 0.0;  // 5 m away; the other particle where it is
  const ParticleDistances d = particleDistances(points, reference);
  EXPECT_DOUBLE_EQ(d.max, 5.0);
  EXPECT_DOUBLE_EQ(d.rms, std::sqrt(25.0 / 2.0));
}

}  // namespace
