// The force models against central differences of their energy and force, and their constant
// stiffness against their tangent.
#include "modal_mass_spring/force_model.h"
#include "modal_mass_spring/simulation.h"

#include "test_support.h"

#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>

#include <cstdlib>
#include <vector>

using namespace modal_mass_spring;

// Central differences of energy and force for the modal force models, at a large deformation.
TEST(ForceModels, ModalForceIsMinusEnergyGradientAndTangentIsMinusForceJacobian)
{
  GridParams g = paper3D();
  g.bending = true;
  SimulationParams s;
  s.num_modes = 12;
  s.linearization = Linearization::Equilibrium;
  Simulation sim(g, s);
  const Eigen::VectorXd& x_ref = sim.linearizationPositions();
  LinearModalForceModel linear(sim.grid(), sim.basis(), x_ref);
  PhysicalModalForceModel physical(sim.grid(), sim.basis(), x_ref);
  std::srand(3);
  // Modal amplitudes that move particles by several centimetres on a 0.9 m sheet.
  const Eigen::VectorXd q = 0.02 * Eigen::VectorXd::Random(s.num_modes);
  for (ForceModel* model : std::vector<ForceModel*>{&linear, &physical})
  {
    Eigen::VectorXd f, f_plus, f_minus;
    model->force(q, f);
    SparseMatrix k;
    model->tangentStiffness(q, k);
    const Eigen::MatrixXd tangent(k);
    const double h = 1e-6;
    for (int i = 0; i < s.num_modes; ++i)
    {
      Eigen::VectorXd plus = q, minus = q;
      plus[i] += h;
      minus[i] -= h;
      const double gradient = (model->energy(plus) - model->energy(minus)) / (2.0 * h);
      EXPECT_NEAR(-gradient, f[i], 1e-6 * (f.norm() + 1.0)) << "coordinate " << i;
      model->force(plus, f_plus);
      model->force(minus, f_minus);
      const Eigen::VectorXd column = -(f_plus - f_minus) / (2.0 * h);
      EXPECT_LT((column - tangent.col(i)).norm(), 1e-5 * (tangent.norm() + 1.0)) << "coordinate " << i;
    }
    // The energy a force evaluation leaves behind is the energy at that q, not the last one asked for.
    model->force(q, f);
    const double cached = model->energy(q);
    model->force(0.5 * q, f);
    EXPECT_EQ(model->energy(q), cached);
  }
}

// Each model's constant stiffness L is at least its tangent at a large deformation with compressed
// and stretched springs (L - K positive semidefinite), so a step solved with L descends.
TEST(ForceModels, ConstantStiffnessBoundsTheTangent)
{
  GridParams g = paper3D();
  g.bending = true;
  SimulationParams s;
  s.num_modes = 12;
  s.method = Method::Cubature;
  s.linearization = Linearization::Equilibrium;
  Simulation sim(g, s);
  ASSERT_NE(sim.cubature(), nullptr);
  const Eigen::VectorXd& x_ref = sim.linearizationPositions();
  FullForceModel full(sim.grid(), x_ref);
  PhysicalModalForceModel physical(sim.grid(), sim.basis(), x_ref);
  CubatureForceModel cubature(sim.grid(), sim.basis(), x_ref, *sim.cubature());
  std::srand(5);
  const Eigen::VectorXd modal = 0.05 * Eigen::VectorXd::Random(s.num_modes);
  const Eigen::VectorXd free = 0.05 * Eigen::VectorXd::Random(sim.grid().numFreeDofs());
  for (auto [model, q] : {std::pair<ForceModel*, Eigen::VectorXd>{&full, free}, {&physical, modal}, {&cubature, modal}})
  {
    SparseMatrix k, l;
    model->tangentStiffness(q, k);
    ASSERT_TRUE(model->constantStiffness(l));
    const Eigen::MatrixXd tangent(k), constant(l);
    if (model == &full)
    {
      // Indefinite here (compressed springs): the bound still holds.
      EXPECT_LT(Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(tangent).eigenvalues().minCoeff(), 0.0);
    }
    const Eigen::VectorXd gap = Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(constant - tangent).eigenvalues();
    EXPECT_GT(gap.minCoeff(), -1e-9 * constant.norm()) << "size " << model->size();
    EXPECT_LT((constant - constant.transpose()).norm(), 1e-12 * constant.norm());
  }
}
