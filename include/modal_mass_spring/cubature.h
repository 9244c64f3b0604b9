// Optimized cubature (An, Kim & James 2008): a few springs with non-negative weights whose projected
// forces stand in for the reduced spring force Phi^T f(x_ref + Phi X), so a step costs O(|T| r).
#pragma once

#include "modal_mass_spring/force_model.h"
#include "modal_mass_spring/grid.h"
#include "modal_mass_spring/handles.h"
#include "modal_mass_spring/modal_basis.h"

#include <Eigen/Core>

#include <functional>
#include <random>
#include <string>
#include <vector>

namespace modal_mass_spring
{

struct CubatureParams
{
  double tolerance = 0.01;      // relative RMS force error to reach on the training and validation poses, in (0, 1)
  int max_springs = 0;          // the most springs T may hold; 0: min(number of springs, kDefaultMaxSprings)
  int training_poses = 100;     // to start from
  int max_training_poses = 0;   // the training set may double up to this; 0: kDefaultPoseGrowth training_poses
  double pose_size = 0.4;       // m: the largest particle displacement of the largest training pose
  int seed = 1;                 // of the poses and the candidate sets: training is reproducible
};

// The cap of max_springs = 0: keeps the training's dense Gram matrix and the step's cost bounded.
constexpr int kDefaultMaxSprings = 1000;
// The training set's default largest size, as a multiple of training_poses.
constexpr int kDefaultPoseGrowth = 8;
// A training pose shortens no spring below this fraction of its length at the reference (the paper
// setups' simulations reach 0.74 in 2D and 0.62 in 3D): beyond, the grid has folded.
constexpr double kShortestTrainingSpring = 0.5;
// Draws of a training pose before one that folds no spring is shrunk instead.
constexpr int kPoseAttempts = 100;
// Springs tried in each greedy selection (all when fewer remain).
constexpr int kCubatureCandidates = 256;

// The springs T and their weights, and how well they fit.
struct Cubature
{
  std::vector<int> springs;  // indices into Grid::springs()
  Eigen::VectorXd weights;   // w_s > 0, one per spring of T
  // Relative force error, sqrt of the mean over poses of (|F_T - F| / |F|)^2, of the spring force's
  // change from the reference: on the training poses; on the last validation set (as many fresh
  // poses, which decided the stop); and on as many held-out poses, which nothing in the training saw.
  double training_error = 0.0;
  double validation_error = 0.0;
  double heldout_error = 0.0;
  double training_seconds = 0.0;
  int training_poses = 0;  // after the training set's growth
};

// "cubature: 174 of 342 springs, training error 1.97% on 400 poses, validation 2.1%, held-out 2.3%,
// trained in 0.29 s", and with a tolerance, whether the fit missed it ("; above cubature_tolerance 2%
// on fresh poses: ...").
std::string describeCubature(const Cubature& cubature, int num_springs, double tolerance = 0.0);

// The max_springs that applies on a grid with `num_springs` springs.
int effectiveMaxSprings(const CubatureParams& params, int num_springs);
// The most training poses after growth.
Eigen::Index effectiveMaxTrainingPoses(const CubatureParams& params);

// `count` poses (columns) of the training's law: N(0, 1) amplitudes times omega_1 / omega_i (An et
// al.: low modes move most), scaled so that the largest particle displacement is uniform in
// (0, size], drawn again while x_ref + Phi X shortens a spring below kShortestTrainingSpring of its
// length at x_ref (after kPoseAttempts draws, the last is halved until it does not).
Eigen::MatrixXd trainingPoses(const Grid& grid, const ModalBasis& basis, const Eigen::VectorXd& x_ref, int count,
                              double size, std::mt19937_64& rng);

// Greedy selection with NNLS refits on random poses X around x_ref (each mode's amplitude scaled by
// omega_1 / omega_i, the largest particle displacement uniform in (0, pose_size], no spring shorter
// than kShortestTrainingSpring of its length at x_ref). The target of a pose is
// Phi^T (f(x_ref + Phi X) - f(x_ref)). The training matrix is never stored: a spring's column is
// -D_s^T F_s pose by pose (D_s its rows of Phi, F_s its force change over the poses, dim x poses), and
// only the selected springs' D_s and F_s are kept, so memory grows as |T| dim (r + poses), not
// |T| r poses. Once the training error is below params.tolerance, the fit is measured on as many
// fresh poses: above the tolerance there, they join the training set and the selection goes on, while
// the set may double within max_training_poses. Stops there, at max_springs, or when no candidate helps.
// `sampler` draws the poses instead of trainingPoses (a subspace whose poses follow another law, as
// the skinning span's rotations); empty: trainingPoses. `on_iteration` is told each spring selected
// ("cubature", springs selected, training error, tolerance); it may throw to stop the training.
using PoseSampler = std::function<Eigen::MatrixXd(int count, std::mt19937_64& rng)>;
Cubature trainCubature(const Grid& grid, const ModalBasis& basis, const Eigen::VectorXd& x_ref,
                       const CubatureParams& params, const PoseSampler& sampler = {},
                       const IterationFn& on_iteration = {});

// `cubature`: F(X) = Phi^T f_g + F_exact(ref) + sum over T of w_s (g_s(X) - g_s(0)), g_s the force of
// spring s projected onto its particles' rows of Phi. Exact at the reference (an equilibrium stays
// one), and the gradient of a weighted spring energy: conservative, with a symmetric tangent.
class CubatureForceModel : public ModalForceModel
{
public:
  CubatureForceModel(const Grid& grid, const ModalBasis& basis, const Eigen::VectorXd& x_ref,
                     const Cubature& cubature);
  // O(springs) once: the exact force and energy at the new reference.
  void setReference(const Eigen::VectorXd& x_ref) override;
  int size() const override { return static_cast<int>(basis_.phi.cols()); }
  void force(const Eigen::VectorXd& modal, Eigen::VectorXd& f) override;
  // sum over T of w_s D_s^T K_s D_s, D_s = Phi_j - Phi_i the spring's rows.
  void tangentStiffness(const Eigen::VectorXd& modal, SparseMatrix& k) override;
  double energy(const Eigen::VectorXd& modal) override;
  // sum over T of w_s k_s D_s^T D_s: the Laplacian of the weighted springs, at least the tangent above.
  bool constantStiffness(SparseMatrix& l) override;

  // With handles: moves the reference with them in O(|T| x handle dofs), or O(|T|) for a motion that
  // is one affine map of all handles (a turned clamp), where setReference is O(all springs) and its
  // caller O(free dofs x handle dofs). `psi` (free dofs x handle dofs): the free dofs' part of a
  // handle displacement dx_b, the handle dofs moving by dx_b itself; `fit`: the handles' affine maps.
  // The exact force at X = 0 is then that of the last setReference's reference; how the handles' move
  // since changes it is the cubature's own estimate, from its springs (the springs' rows of psi).
  void setHandleMap(const Eigen::MatrixXd& psi, const AffineHandleFit& fit);
  // The handles' displacement from where they were at the last setReference (setHandleMap first).
  void moveHandles(const Eigen::VectorXd& dx_b);

private:
  // Weighted sum over T of spring forces (returned in f) and energies at X.
  double weightedSprings(const Eigen::VectorXd& modal, Eigen::VectorXd* f);
  template <int Dim>
  double weightedSpringForces(const Eigen::VectorXd& modal, Eigen::VectorXd* f);
  template <int Dim>
  void weightedTangentBlocks();
  // d_ = D X + the rest vectors, unless it already holds them for this X (a tangent after the force
  // of a Newton iteration, at the same X).
  void springVectors(const Eigen::VectorXd& modal);

  const Grid& grid_;
  const ModalBasis& basis_;
  int dim_;
  std::vector<Spring> springs_;
  Eigen::VectorXd weights_;
  // D^T, r x (|T| dim), D's rows Phi_j - Phi_i (zero for fixed dofs) stored as columns: a spring's
  // D_s^T is contiguous, for the force's pass and the tangent's blocks (D itself is not kept).
  Eigen::MatrixXd diff_t_;
  Eigen::VectorXd rest_diff_;   // x_ref_j - x_ref_i per spring of T
  Eigen::VectorXd constant_;    // Phi^T f_g plus the correction that makes F exact at X = 0
  double energy_constant_ = 0.0;
  // Handles: the springs' rows of [Psi; I] (x_j - x_i per unit dx_b), (|T| dim) x handle dofs, those
  // times the fit's H, and f_g^T [Psi; I] (the gravity energy's change per dx_b); rest_diff_ and
  // energy_constant_ at the last setReference.
  Eigen::MatrixXd handle_rows_, handle_affine_rows_;
  Eigen::VectorXd handle_gravity_;
  AffineHandleFit fit_;
  Eigen::VectorXd base_rest_diff_, affine_, non_affine_;
  double base_energy_constant_ = 0.0;
  // Scratch, kept so that a step allocates nothing: spring vectors (and the X they are at), the
  // blocks (w_s K_s D_s)^T, D_s^T u and the reduced tangent.
  Eigen::VectorXd d_, d_modal_, d_rows_;
  Eigen::MatrixXd weighted_t_, reduced_;
  // The last force and its X: an implicit step asks again for the force at the state it starts from.
  Eigen::VectorXd f_modal_, f_;
  EnergyCache cache_;
};

}  // namespace modal_mass_spring
