// The skinning subspace: its span (rigid rotations of the whole cloth and of a grip), its mass and
// stiffness (Rayleigh-Ritz), grips that do not hold the cloth alone, handles held exactly, energy
// conservation, and a large turn checked against a converged `full`.
#include "modal_mass_spring/simulation.h"
#include "modal_mass_spring/skinning.h"
#include "modal_mass_spring/spring_forces.h"

#include <Eigen/Dense>
#include <Eigen/Geometry>
#include "test_support.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <cstdio>
#include <random>
#include <vector>

#include <unistd.h>

using namespace modal_mass_spring;

namespace
{

constexpr double kPi = 3.14159265358979323846;


SimulationParams heldParams(Method method, BasisKind basis, int weights)
{
  SimulationParams s;
  s.method = method;
  s.num_modes = 30;
  s.basis = basis;
  s.num_skinning_weights = basis == BasisKind::Skinning ? weights : 0;
  s.linearization = Linearization::Equilibrium;
  s.initial_state = InitialState::Equilibrium;
  s.integrator = IntegratorKind::Implicit;
  s.alpha = 0.5;
  s.time_step = 0.005;
  return s;
}

// The two top corners' 2 x 2 particles of an n x n grid.
std::vector<std::vector<int>> cornerGrips(int n)
{
  return {{0, 1, n, n + 1}, {n - 2, n - 1, 2 * n - 2, 2 * n - 1}};
}

std::vector<int> topRows(int n, int rows)
{
  std::vector<int> particles;
  for (int k = 0; k < rows * n; ++k)
    particles.push_back(k);
  return particles;
}

// u = (R - I)(x - c) over all dofs of 3D positions x.
Eigen::VectorXd rotationDisplacement(const Eigen::VectorXd& x, const Eigen::Matrix3d& r, const Eigen::Vector3d& c)
{
  Eigen::VectorXd u(x.size());
  for (Eigen::Index i = 0; i + 3 <= x.size(); i += 3)
    u.segment<3>(i) = (r - Eigen::Matrix3d::Identity()) * (x.segment<3>(i) - c);
  return u;
}

// RMS over the free particles of the distance between two position vectors.
double rmsFreeDistance(const Grid& grid, const Eigen::VectorXd& a, const Eigen::VectorXd& b)
{
  const Eigen::VectorXd d = grid.gatherFree(a - b);
  return std::sqrt(d.squaredNorm() / (d.size() / grid.dimension()));
}

// The handles turned by `angle` about the vertical through `centre` over `duration` (a smooth ramp,
// at rest at both ends), then held; one setHandleFrameMotion per step. Returns the positions after
// duration + hold.
void turnHandles(Simulation& sim, double angle, const Eigen::Vector3d& centre, double duration, double hold)
{
  const double dt = sim.params().time_step;
  const int steps = static_cast<int>(std::lround((duration + hold) / dt));
  for (int k = 1; k <= steps; ++k)
  {
    const double s = std::min(1.0, k * dt / duration);
    // theta = angle (3 s^2 - 2 s^3): zero angular velocity and a finite acceleration at both ends.
    const double theta = angle * (3 * s * s - 2 * s * s * s);
    const double omega = s < 1.0 ? angle * (6 * s - 6 * s * s) / duration : 0.0;
    const double alpha = s < 1.0 ? angle * (6 - 12 * s) / (duration * duration) : 0.0;
    FrameMotion m;
    m.rotation = Eigen::AngleAxisd(theta, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    m.angular_velocity = omega * Eigen::Vector3d::UnitZ();
    m.angular_acceleration = alpha * Eigen::Vector3d::UnitZ();
    // The origin's point turns about the centre: p = c - R c.
    const Eigen::Vector3d rc = m.rotation * centre;
    m.translation = centre - rc;
    m.velocity = -m.angular_velocity.cross(rc);
    m.acceleration = -m.angular_acceleration.cross(rc) - m.angular_velocity.cross(m.angular_velocity.cross(rc));
    sim.setHandleFrameMotion(m);
    const StepResult result = sim.step();
    ASSERT_FALSE(result.diverged) << result.message;
  }
}

}  // namespace

TEST(Skinning, SpanHoldsRigidRotationsOfTheClothAndOfAGrip)
{
  const GridParams g = heldCloth({}, 10);
  const Grid grid(g);
  const Eigen::VectorXd& x = grid.initialPositions();
  const Eigen::MatrixXd b = skinningMap(grid, x, skinningWeights(grid, x, 8));
  EXPECT_EQ(b.cols(), 8 * 12);
  const Eigen::Matrix3d r = Eigen::AngleAxisd(1.3, Eigen::Vector3d(0.3, -0.5, 0.8).normalized()).toRotationMatrix();
  // The whole cloth turned about an arbitrary point.
  const Eigen::VectorXd u = rotationDisplacement(x, r, Eigen::Vector3d(0.2, -0.1, 0.4));
  const Eigen::VectorXd z = b.colPivHouseholderQr().solve(u);
  EXPECT_LT((b * z - u).cwiseAbs().maxCoeff(), 1e-10 * u.cwiseAbs().maxCoeff());
  // A 2 x 2 corner grip turned about its own centre: its rows alone.
  const std::vector<int> grip{0, 1, 10, 11};
  std::vector<int> rows;
  for (int p : grip)
    for (int a = 0; a < 3; ++a)
      rows.push_back(3 * p + a);
  const Eigen::MatrixXd b_grip = b(rows, Eigen::all);
  const Eigen::Vector3d centre = 0.25 * (x.segment<3>(0) + x.segment<3>(3) + x.segment<3>(30) + x.segment<3>(33));
  const Eigen::VectorXd u_grip = rotationDisplacement(x, r, centre)(rows);
  const Eigen::VectorXd z_grip = b_grip.colPivHouseholderQr().solve(u_grip);
  EXPECT_LT((b_grip * z_grip - u_grip).cwiseAbs().maxCoeff(), 1e-10 * u_grip.cwiseAbs().maxCoeff());
}

TEST(Skinning, WeightsAreHarmonicBetweenTheHandlesAndVanishOnThemPastOnePerHandle)
{
  // Two 2 x 2 corner grips, nothing fixed: one weight per grip, 1 on it and 0 on the other, harmonic
  // (L w = 0) at every other particle, the two summing to one everywhere; every further weight zero
  // on every held particle and an eigenvector of the Laplacian with them as a Dirichlet boundary.
  const int n = 10;
  const Grid grid(heldCloth(cornerGrips(n), n));
  const Eigen::VectorXd& x = grid.initialPositions();
  const int m = 8;
  const Eigen::MatrixXd w = skinningWeights(grid, x, m);
  ASSERT_EQ(w.rows(), grid.numParticles());
  ASSERT_EQ(w.cols(), m);
  // The Laplacian, built here from the springs: edge weight k / L^2.
  Eigen::MatrixXd laplacian = Eigen::MatrixXd::Zero(grid.numParticles(), grid.numParticles());
  for (const Spring& s : grid.springs())
  {
    const double e = s.stiffness / (x.segment<3>(3 * s.j) - x.segment<3>(3 * s.i)).squaredNorm();
    laplacian(s.i, s.i) += e;
    laplacian(s.j, s.j) += e;
    laplacian(s.i, s.j) -= e;
    laplacian(s.j, s.i) -= e;
  }
  const Eigen::MatrixXd lw = laplacian * w;
  const double scale = laplacian.diagonal().maxCoeff();
  for (int i = 0; i < grid.numParticles(); ++i)
  {
    EXPECT_NEAR(w(i, 0) + w(i, 1), 1.0, 1e-10) << "particle " << i;
    const int handle = grid.isHandle(i) ? (i % n < n / 2 ? 0 : 1) : -1;
    for (int j = 0; j < 2; ++j)
    {
      if (handle >= 0)
      {
        EXPECT_EQ(w(i, j), handle == j ? 1.0 : 0.0) << "particle " << i << ", weight " << j;
      }
      else
      {
        EXPECT_NEAR(lw(i, j), 0.0, 1e-10 * scale) << "particle " << i << ", weight " << j;
        EXPECT_GT(w(i, j), 0.0);
        EXPECT_LT(w(i, j), 1.0);
      }
    }
    for (int j = 2; j < m && handle >= 0; ++j)
      EXPECT_EQ(w(i, j), 0.0) << "particle " << i << ", weight " << j;
  }
  // Dirichlet eigenvectors: L w = lambda m w at every particle not held, lambda > 0, ascending.
  double previous = 0.0;
  for (int j = 2; j < m; ++j)
  {
    double numerator = 0.0, denominator = 0.0;
    for (int i = 0; i < grid.numParticles(); ++i)
      if (!grid.isHandle(i))
      {
        numerator += w(i, j) * lw(i, j);
        denominator += grid.particleMass() * w(i, j) * w(i, j);
      }
    const double lambda = numerator / denominator;
    EXPECT_GT(lambda, previous * (1.0 - 1e-9));
    previous = lambda;
    for (int i = 0; i < grid.numParticles(); ++i)
    {
      if (!grid.isHandle(i))
      {
        EXPECT_NEAR(lw(i, j), lambda * grid.particleMass() * w(i, j), 1e-7 * scale) << "weight " << j;
      }
    }
  }
  // A clamp alone: its weight is one everywhere. Fixed particles are a group of their own.
  const Grid clamp(heldCloth({topRows(n, 2)}, n));
  const Eigen::MatrixXd w_clamp = skinningWeights(clamp, clamp.initialPositions(), 3);
  EXPECT_LT((w_clamp.col(0).array() - 1.0).abs().maxCoeff(), 1e-10);
  for (int i = 0; i < 2 * n; ++i)
    EXPECT_EQ(w_clamp.row(i).tail(2).cwiseAbs().maxCoeff(), 0.0);
  GridParams both = heldCloth({{n * n - 1}}, n);
  both.fixed = {0, 1};
  const Grid fixed_and_handle(both);
  const Eigen::MatrixXd w_both = skinningWeights(fixed_and_handle, fixed_and_handle.initialPositions(), 4);
  EXPECT_EQ(w_both(n * n - 1, 0), 1.0);
  EXPECT_EQ(w_both(0, 1), 1.0);
  EXPECT_LT((w_both.leftCols(2).rowwise().sum().array() - 1.0).abs().maxCoeff(), 1e-10);
  // Fewer weights than groups, or more than the groups and the particles not held, are refused.
  EXPECT_TRUE(contains(refusal([&] { skinningWeights(grid, x, 1); }),
                       "'num_skinning_weights' = 1: must be in [2, 94]"));
  EXPECT_TRUE(contains(refusal([&] { skinningWeights(grid, x, 95); }), "'num_skinning_weights' = 95"));
  EXPECT_NO_THROW(skinningWeights(grid, x, 94));
}

TEST(Skinning, BasisIsMassOrthonormalAndDiagonalisesTheStiffness)
{
  const GridParams g = heldCloth(cornerGrips(10), 10);
  Simulation sim(g, heldParams(Method::Physical, BasisKind::Skinning, 8));
  const ModalBasis& basis = sim.physicalBasis();
  const SparseMatrix k = tangentStiffness(sim.grid(), sim.linearizationPositions(), CompressedSprings::Drop);
  const Eigen::VectorXd mass = Eigen::VectorXd::Constant(sim.grid().numFreeDofs(), g.mass);
  const Eigen::Index r = basis.phi.cols();
  EXPECT_EQ(r, sim.skinningInfo().basis_size);
  // A planar sheet (it hangs in its plane): the column of each A_j that multiplies the out-of-plane
  // coordinate moves nothing, 9 of 12 coordinates per weight remain. Only a grip's own weight is
  // nonzero on it, and its four particles in a plane fix 9 of that weight's entries: 18 for the two.
  EXPECT_EQ(sim.skinningInfo().constraint_rank, 18);
  // With the 30 fixed-interface modes added, at most 30 more.
  EXPECT_GE(r, 9 * 8 - sim.skinningInfo().constraint_rank);
  EXPECT_LE(r, 9 * 8 - sim.skinningInfo().constraint_rank + 30);
  const Eigen::MatrixXd m_r = basis.phi.transpose() * mass.asDiagonal() * basis.phi;
  EXPECT_LT((m_r - Eigen::MatrixXd::Identity(r, r)).cwiseAbs().maxCoeff(), 1e-10);
  const Eigen::MatrixXd k_r = basis.phi.transpose() * (k * basis.phi);
  const double scale = basis.eigenvalues.maxCoeff();
  EXPECT_LT((k_r - Eigen::MatrixXd(basis.eigenvalues.asDiagonal())).cwiseAbs().maxCoeff(), 1e-9 * scale);
  EXPECT_TRUE((basis.eigenvalues.array() >= 0.0).all());
  // The handles' part: a rigid turn of both grips together (an affine motion of the handle
  // particles) turns the whole cloth with them, so that the reduced coordinates carry only the
  // deformation; a motion of the grips that is no affine map (here one grip alone moved) keeps the
  // least-squares interior M-orthogonal to the subspace.
  const Eigen::MatrixXd& psi = sim.skinningConstraintModes();
  const Grid& grid = sim.grid();
  EXPECT_EQ(psi.cols(), grid.numHandleDofs());
  const Eigen::Matrix3d rotation =
      Eigen::AngleAxisd(2.0, Eigen::Vector3d(0.2, 0.1, 1.0).normalized()).toRotationMatrix();
  const Eigen::VectorXd turn =
      rotationDisplacement(sim.linearizationPositions(), rotation, Eigen::Vector3d(0.2, 0.0, -0.1));
  const Eigen::VectorXd turn_b = turn(grid.handleDofs());
  EXPECT_LT((psi * turn_b - grid.gatherFree(turn)).cwiseAbs().maxCoeff(), 1e-10);
  // One grip turned alone, less its least-squares affine fit over both grips: no affine map.
  Eigen::VectorXd one_grip = Eigen::VectorXd::Zero(grid.numHandleDofs());
  one_grip.head(12) = turn_b.head(12);
  const Eigen::MatrixXd affine =
      skinningMap(grid, sim.linearizationPositions(), Eigen::MatrixXd::Ones(grid.numParticles(), 1))(grid.handleDofs(),
                                                                                                        Eigen::all);
  const Eigen::VectorXd non_affine = one_grip - affine * affine.colPivHouseholderQr().solve(one_grip);
  ASSERT_GT(non_affine.norm(), 0.05 * one_grip.norm());
  const Eigen::VectorXd interior = psi * non_affine;
  EXPECT_GT(interior.norm(), 1e-3 * non_affine.norm());
  EXPECT_LT((basis.phi.transpose() * mass.asDiagonal() * interior).cwiseAbs().maxCoeff(), 1e-9 * interior.norm());
}

TEST(Skinning, TwoCornerGripsWithNothingFixedHangAndFollowTheirHandles)
{
  // K_ii of this cloth held by two 2 x 2 corners is singular at rest (no out-of-plane stiffness):
  // constraint modes do not exist, but the skinning span carries the grips.
  const int n = 10;
  GridParams g = heldCloth(cornerGrips(n), n);
  SimulationParams s = heldParams(Method::Physical, BasisKind::Skinning, 12);
  s.linearization = Linearization::Rest;
  s.initial_state = InitialState::Initial;
  Simulation sim(g, s);
  EXPECT_EQ(sim.handleFormulation(), HandleFormulation::ConstraintModes);
  // A whole-cloth rigid turn is in the span with the grips: the projection leaves nothing out.
  const Eigen::Matrix3d r = Eigen::AngleAxisd(kPi / 2, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  const Eigen::VectorXd u = rotationDisplacement(sim.linearizationPositions(), r, Eigen::Vector3d(0.2, 0.0, 0.0));
  const Grid& grid = sim.grid();
  Eigen::VectorXd dx_b(grid.numHandleDofs());
  for (int k = 0; k < grid.numHandleDofs(); ++k)
    dx_b[k] = u[grid.handleDofs()[k]];
  const Eigen::VectorXd mass = Eigen::VectorXd::Constant(grid.numFreeDofs(), g.mass);
  const Eigen::VectorXd rest = grid.gatherFree(u) - sim.skinningConstraintModes() * dx_b;
  const Eigen::MatrixXd& phi = sim.physicalBasis().phi;
  EXPECT_LT((rest - phi * (phi.transpose() * mass.asDiagonal() * rest)).cwiseAbs().maxCoeff(), 1e-10);

  // Hangs: 3 s of damped motion under gravity from the flat start, finite, sagging, the grips in place.
  const StepResult hung = sim.step(600);
  ASSERT_FALSE(hung.diverged) << hung.message;
  const Eigen::VectorXd x = sim.positions();
  ASSERT_TRUE(x.allFinite());
  const double bottom = x(3 * grid.particleIndex(n - 1, n / 2) + 2);
  const double start = sim.startPositions()(3 * grid.particleIndex(n - 1, n / 2) + 2);
  EXPECT_LT(bottom, start - 0.01);  // sags
  EXPECT_GT(bottom, start - 0.3);   // but hangs: springs of 50 N/m hold 0.5 kg within centimetres

  // The grips turned a quarter turn about the vertical through the cloth's centre: every handle
  // particle where it was put, to round-off.
  turnHandles(sim, kPi / 2, Eigen::Vector3d(0.225, 0.0, 0.0), 1.0, 0.2);
  const Eigen::VectorXd held = sim.positions();
  const Eigen::VectorXd target = sim.handlePositions();
  for (int k = 0; k < grid.numHandleDofs(); ++k)
    EXPECT_EQ(held[grid.handleDofs()[k]], target[k]);
  const Eigen::Vector3d corner = held.segment<3>(0);
  const Eigen::Vector3d expected = r * (sim.linearizationPositions().segment<3>(0) - Eigen::Vector3d(0.225, 0, 0)) +
                                   Eigen::Vector3d(0.225, 0, 0);
  EXPECT_LT((corner - expected).norm(), 1e-12);
}

TEST(Skinning, GripsAlongOneRowTranslatedTogetherTranslateTheCloth)
{
  // Two grips on the top row: their particles lie on a line, which fixes only part of an affine map.
  // Taken about the grips' own centroid, the rest of the fit is zero, and moving both grips by one
  // vector moves every free particle by it (not a shear about a point below the row).
  const int n = 6;
  GridParams g = heldCloth({{0, 1, 2}, {3, 4, 5}}, n);
  SimulationParams s = heldParams(Method::Physical, BasisKind::Skinning, 4);
  s.num_modes = 4;
  s.linearization = Linearization::Rest;
  s.initial_state = InitialState::Initial;
  Simulation sim(g, s);
  const Grid& grid = sim.grid();
  const Eigen::Vector3d shift(0.1, -0.2, 0.3);
  const Eigen::VectorXd dx_b = shift.replicate(grid.numHandleDofs() / 3, 1);
  const Eigen::VectorXd moved = sim.skinningConstraintModes() * dx_b;
  const Eigen::VectorXd expected = shift.replicate(grid.numFreeDofs() / 3, 1);
  EXPECT_LT((moved - expected).cwiseAbs().maxCoeff(), 1e-10);
}

TEST(Skinning, PhysicalConservesEnergyWithoutDamping)
{
  // The paper's 3D sheet turned 45 degrees, its top row fixed, released under gravity.
  GridParams g = paper3D();
  SimulationParams s;
  s.method = Method::Physical;
  s.basis = BasisKind::Skinning;
  s.num_skinning_weights = 6;
  s.num_modes = 10;
  s.time_step = 1e-3;
  Simulation sim(g, s);
  const double e0 = sim.totalEnergy();
  double drift = 0.0, kinetic = 0.0;
  for (int k = 0; k < 20; ++k)
  {
    const StepResult result = sim.step(100);
    ASSERT_FALSE(result.diverged) << result.message;
    drift = std::max(drift, std::abs(sim.totalEnergy() - e0));
    kinetic = std::max(kinetic, sim.kineticEnergy());
  }
  // It swings (the kinetic energy reaches a good part of the energy exchanged with gravity), and the
  // total stays within a thousandth of that.
  std::printf("[ energy ] largest kinetic %.4g J, largest drift of the total %.3g J\n", kinetic, drift);
  EXPECT_GT(kinetic, 0.01);
  EXPECT_LT(drift, 1e-3 * kinetic);
}

TEST(Skinning, TurnedHeldClothStaysCloseToFull)
{
  // The top edge (two rows, one clamp) turned 90 degrees about the vertical through its middle in 1 s,
  // then held 0.5 s: converged `full` against `physical` on 24 skinning weights and on 30 linear modes.
  const int n = 20;
  const GridParams g = heldCloth({topRows(n, 2)}, n);
  const Eigen::Vector3d centre(0.475, 0.0, 0.0);
  SimulationParams full_params = heldParams(Method::Full, BasisKind::LinearModes, 0);
  full_params.time_step = 0.00125;  // a quarter of the reduced methods' step
  Simulation full(g, full_params);
  Simulation skinning(g, heldParams(Method::Physical, BasisKind::Skinning, 24));
  Simulation modes(g, heldParams(Method::Physical, BasisKind::LinearModes, 0));
  // Constraint modes, as the modal methods: the same handles' motion for all.
  for (Simulation* sim : {&full, &skinning, &modes})
    turnHandles(*sim, kPi / 2, centre, 1.0, 0.5);
  const double skinning_error = rmsFreeDistance(full.grid(), skinning.positions(), full.positions());
  const double modes_error = rmsFreeDistance(full.grid(), modes.positions(), full.positions());
  std::printf("[ turned held cloth ] RMS distance to full: physical on skinning (24 weights) %.4f m, on linear modes "
              "(30) %.4f m\n",
              skinning_error, modes_error);
  EXPECT_LT(skinning_error, 0.03);
  EXPECT_LT(skinning_error, 0.25 * modes_error);
}

TEST(Skinning, CubatureTrainsOnPosesThatTurnTheCloth)
{
  const int n = 10;
  const GridParams g = heldCloth(cornerGrips(n), n);
  SimulationParams s = heldParams(Method::Cubature, BasisKind::Skinning, 6);
  s.num_modes = 10;
  Simulation sim(g, s);
  const Grid& grid = sim.grid();
  const ModalBasis& basis = sim.physicalBasis();
  const Eigen::VectorXd mass = Eigen::VectorXd::Constant(grid.numFreeDofs(), g.mass);
  std::mt19937_64 rng(3);
  const Eigen::MatrixXd poses = skinningTrainingPoses(
      grid, basis, sim.linearizationPositions(), skinningProjection(grid, sim.linearizationPositions(), basis, mass, 6),
      50, s.cubature_pose_size, rng);
  // The poses turn the cloth: particles move by more than the cloth's half-width (0.225 m), far
  // beyond what the stretches of the pose size alone would give, and no spring folds.
  double largest = 0.0, shortest = 1.0;
  for (Eigen::Index p = 0; p < poses.cols(); ++p)
  {
    Eigen::VectorXd x = sim.linearizationPositions();
    grid.addFree(basis.phi * poses.col(p), x);
    for (Eigen::Index k = 0; k < x.size(); k += 3)
      largest = std::max(largest, (x.segment<3>(k) - sim.linearizationPositions().segment<3>(k)).norm());
    for (const Spring& spring : grid.springs())
      shortest = std::min(shortest, (x.segment<3>(3 * spring.j) - x.segment<3>(3 * spring.i)).norm() /
                                        (sim.linearizationPositions().segment<3>(3 * spring.j) -
                                         sim.linearizationPositions().segment<3>(3 * spring.i))
                                            .norm());
  }
  EXPECT_GT(largest, 0.3);
  EXPECT_GE(shortest, kShortestTrainingSpring);
  // The training fits them as it fits the modes' poses, and reports as usual.
  const Cubature& cubature = *sim.cubature();
  std::printf("[ skinning cubature ] %s\n", describeCubature(cubature, static_cast<int>(grid.springs().size())).c_str());
  EXPECT_LT(cubature.heldout_error, 2.0 * s.cubature_tolerance);
}

TEST(Skinning, CubatureFollowsPhysicalOnATurnedClamp)
{
  // A 10 x 10 cloth held by a clamp of its top two rows, turned 90 degrees about the vertical in 1 s
  // and held 0.5 s: the cubature, trained about the unturned cloth, stands in for `physical` on the
  // same span. The turned clamp turns the reference with it (the handles' part of the span), so the
  // cubature sees only the deformation (1.5 mm from `physical`, which moved the cloth 0.18 m RMS, as
  // the rigid quarter turn does; 5.8 mm with the global weights); with the least-squares interior
  // alone it had to fit the turn itself and ended 69 mm off.
  const int n = 10;
  const GridParams g = heldCloth({topRows(n, 2)}, n);
  SimulationParams s = heldParams(Method::Physical, BasisKind::Skinning, 8);
  s.num_modes = 10;
  Simulation physical(g, s);
  s.method = Method::Cubature;
  Simulation cubature(g, s);
  const Eigen::Vector3d centre(0.225, 0.0, 0.0);
  for (Simulation* sim : {&physical, &cubature})
    turnHandles(*sim, kPi / 2, centre, 1.0, 0.5);
  const double apart = rmsFreeDistance(physical.grid(), cubature.positions(), physical.positions());
  const double turned = rmsFreeDistance(physical.grid(), physical.positions(), physical.startPositions());
  std::printf("[ turned clamp ] cubature (%s) to physical on skinning: RMS %.4f m; physical moved %.4f m RMS\n",
              describeCubature(*cubature.cubature(), static_cast<int>(cubature.grid().springs().size())).c_str(),
              apart, turned);
  // The cloth turned with the clamp: at least half the RMS displacement of the rigid quarter turn.
  const Eigen::Matrix3d quarter = Eigen::AngleAxisd(kPi / 2, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  const Eigen::VectorXd start = physical.startPositions();
  const double rigid = rmsFreeDistance(
      physical.grid(), start + rotationDisplacement(start, quarter, centre), start);
  EXPECT_GT(turned, 0.5 * rigid);
  EXPECT_LT(apart, 0.1 * turned);
}

TEST(Skinning, BadSizesAreRefusedByName)
{
  const GridParams g = heldCloth(cornerGrips(4), 4);
  SimulationParams s = heldParams(Method::Physical, BasisKind::Skinning, 0);
  s.num_modes = 4;
  EXPECT_TRUE(contains(refusal([&] { validateParameters(g, s); }), "invalid parameter 'num_skinning_weights' = 0: must be an integer in [2, 10]"));
  // One weight per grip, then at most one per particle not held: 2 + 8.
  s.num_skinning_weights = 11;
  EXPECT_TRUE(contains(refusal([&] { validateParameters(g, s); }), "'num_skinning_weights' = 11: must be an integer in [2, 10]"));
  s.num_skinning_weights = -3;
  EXPECT_TRUE(contains(refusal([&] { validateParameters(g, s); }), "'num_skinning_weights' = -3"));
  s.num_skinning_weights = 17;
  EXPECT_TRUE(contains(refusal([&] { validateParameters(g, s); }), "'num_skinning_weights' = 17"));
  s.num_skinning_weights = 4;
  s.num_derivative_modes = 2;
  EXPECT_TRUE(contains(refusal([&] { validateParameters(g, s); }), "'num_derivative_modes' = 2: must be 0 with basis: skinning"));
  SimulationParams modes = heldParams(Method::Physical, BasisKind::LinearModes, 0);
  modes.num_modes = 4;
  modes.num_skinning_weights = 4;
  EXPECT_TRUE(contains(refusal([&] { validateParameters(g, modes); }), "'num_skinning_weights' = 4: must be 0 unless basis is skinning"));
  EXPECT_TRUE(contains(refusal([&] { parseBasis("skin"); }), "skinning"));
  // Memory: a big grid with many weights is refused before anything is built.
  GridParams big = heldCloth({{0}}, 1000);
  SimulationParams heavy = heldParams(Method::Physical, BasisKind::Skinning, 2000);
  heavy.memory_limit_gb = 1.0;
  EXPECT_TRUE(contains(refusal([&] { validateParameters(big, heavy); }), "memory_limit_gb"));
}

TEST(Skinning, CachedSubspaceEqualsTheRecomputedOne)
{
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("modal_skinning_cache_" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  CacheOptions cache;
  cache.directory = dir.string();
  const GridParams g = heldCloth(cornerGrips(6), 6);
  SimulationParams s = heldParams(Method::Physical, BasisKind::Skinning, 4);
  s.num_modes = 6;
  Simulation computed(g, s, {}, cache);
  Simulation loaded(g, s, {}, cache);
  EXPECT_TRUE(computed.cacheReport().basis_stored);
  EXPECT_TRUE(loaded.cacheReport().basis_loaded);
  EXPECT_EQ(loaded.physicalBasis().phi, computed.physicalBasis().phi);
  EXPECT_EQ(loaded.skinningConstraintModes(), computed.skinningConstraintModes());
  EXPECT_EQ(loaded.skinningInfo().basis_size, computed.skinningInfo().basis_size);
  // Another number of weights is another entry.
  s.num_skinning_weights = 5;
  Simulation other(g, s, {}, cache);
  EXPECT_FALSE(other.cacheReport().basis_loaded);
  EXPECT_NE(other.physicalBasis().phi.cols(), computed.physicalBasis().phi.cols());
  std::filesystem::remove_all(dir);
}
