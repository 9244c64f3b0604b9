// External forces: a constant load in physical coordinates on every method, checked against the
// static response it must produce and the energy it must conserve.
#include "modal_mass_spring/simulation.h"
#include "modal_mass_spring/spring_forces.h"

#include <gtest/gtest.h>

#include <limits>
#include <string>

using namespace modal_mass_spring;

namespace
{

SimulationParams params(Method method, double alpha)
{
  SimulationParams s;
  s.method = method;
  s.alpha = alpha;
  s.time_step = 1e-3;
  return s;
}

// A force along +x on the paper grid's bottom-right corner, as a vector over every dof.
Eigen::VectorXd cornerForce(const Simulation& sim, double newtons)
{
  const GridParams& g = sim.grid().params();
  Eigen::VectorXd f = Eigen::VectorXd::Zero(sim.positions().size());
  f[sim.grid().dimension() * (g.rows * g.cols - 1)] = newtons;
  return f;
}

std::string refusal(Simulation& sim, const Eigen::VectorXd& f)
{
  try
  {
    sim.setExternalForce(f);
  }
  catch (const std::invalid_argument& e)
  {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(ExternalForce, FullSettlesWhereSpringsGravityAndTheLoadBalance)
{
  // Heavily damped, the grid comes to rest; there the spring forces, computed independently from
  // the positions, must balance gravity and the applied force on every free dof.
  Simulation sim(GridParams{}, params(Method::Full, 20.0));
  const Eigen::VectorXd load = cornerForce(sim, 0.05);
  sim.setExternalForce(load);
  ASSERT_FALSE(sim.step(20000).diverged);
  Eigen::VectorXd f;
  springForces(sim.grid(), sim.positions(), f);
  const Eigen::VectorXd unbalanced = sim.grid().gatherFree(f + sim.grid().gravityForce() + load);
  EXPECT_LT(unbalanced.cwiseAbs().maxCoeff(), 1e-6);
  // The loaded corner moved along the force.
  const int corner_x = sim.grid().dimension() * (sim.grid().numParticles() - 1);
  EXPECT_GT(sim.positions()[corner_x] - sim.startPositions()[corner_x], 0.005);
}

TEST(ExternalForce, LinearStaticResponseIsPhiLambdaInversePhiTransposeF)
{
  // F = -Lambda X + Phi^T f_ext: at rest the load adds Phi Lambda^-1 Phi^T f_ext to the displacement
  // of the unloaded run, whatever gravity does.
  Simulation loaded(GridParams{}, params(Method::Linear, 20.0));
  Simulation unloaded(GridParams{}, params(Method::Linear, 20.0));
  const Eigen::VectorXd load = cornerForce(loaded, 0.05);
  loaded.setExternalForce(load);
  loaded.step(20000);
  unloaded.step(20000);
  const Eigen::MatrixXd& phi = loaded.basis().phi;
  const Eigen::VectorXd expected =
      phi * (phi.transpose() * loaded.grid().gatherFree(load)).cwiseQuotient(loaded.basis().eigenvalues);
  const Eigen::VectorXd response = loaded.displacement() - unloaded.displacement();
  EXPECT_LT((response - expected).cwiseAbs().maxCoeff(), 1e-6 * expected.cwiseAbs().maxCoeff() + 1e-9);
  EXPECT_GT(expected.cwiseAbs().maxCoeff(), 1e-3);
}

TEST(ExternalForce, EveryMethodMovesTheLoadedParticleAlongTheForce)
{
  for (Method method : {Method::Full, Method::Linear, Method::Physical})
  {
    Simulation loaded(GridParams{}, params(method, 0.2));
    Simulation unloaded(GridParams{}, params(method, 0.2));
    loaded.setExternalForce(cornerForce(loaded, 0.05));
    loaded.step(300);
    unloaded.step(300);
    const int corner_x = loaded.grid().dimension() * (loaded.grid().numParticles() - 1);
    EXPECT_GT(loaded.positions()[corner_x] - unloaded.positions()[corner_x], 1e-3) << toString(method);
  }
}

TEST(ExternalForce, AConstantLoadIsConservativeAndClearingItIsNoDivergence)
{
  // Undamped, the energy with the load's potential is what the dynamics conserve: the divergence
  // check must not see the load's work as a rise, before or after the load changes.
  for (Method method : {Method::Full, Method::Physical})
  {
    Simulation sim(GridParams{}, params(method, 0.0));
    sim.setExternalForce(cornerForce(sim, 0.1));
    const StepResult loaded = sim.step(3000);
    EXPECT_FALSE(loaded.diverged) << toString(method) << ": " << loaded.message;
    EXPECT_NEAR(sim.methodEnergy(), sim.startEnergy(), 1e-3 * sim.energyScale()) << toString(method);
    sim.setExternalForce(Eigen::VectorXd::Zero(sim.positions().size()));
    const StepResult cleared = sim.step(3000);
    EXPECT_FALSE(cleared.diverged) << toString(method) << ": " << cleared.message;
    EXPECT_NEAR(sim.methodEnergy(), sim.startEnergy(), 1e-3 * sim.energyScale()) << toString(method);
  }
}

TEST(ExternalForce, StaysThroughMethodSwitchesAndResets)
{
  Simulation sim(GridParams{}, params(Method::Physical, 20.0));
  const Eigen::VectorXd load = cornerForce(sim, 0.05);
  sim.setExternalForce(load);
  sim.setMethod(Method::Full);
  sim.reset();
  EXPECT_EQ(sim.externalForce(), load);
  sim.step(20000);
  Eigen::VectorXd f;
  springForces(sim.grid(), sim.positions(), f);
  EXPECT_LT(sim.grid().gatherFree(f + sim.grid().gravityForce() + load).cwiseAbs().maxCoeff(), 1e-6);
}

TEST(ExternalForce, BadVectorsAreRefusedAndChangeNothing)
{
  Simulation sim(GridParams{}, params(Method::Physical, 0.2));
  const Eigen::VectorXd load = cornerForce(sim, 0.05);
  sim.setExternalForce(load);
  EXPECT_NE(refusal(sim, Eigen::VectorXd::Zero(3)).find("'external force' = 3 values: must have 50 values, 2 per particle"),
            std::string::npos)
      << refusal(sim, Eigen::VectorXd::Zero(3));
  Eigen::VectorXd bad = load;
  bad[7] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_NE(refusal(sim, bad).find("non-finite value on particle 3"), std::string::npos) << refusal(sim, bad);
  EXPECT_EQ(sim.externalForce(), load);
}
