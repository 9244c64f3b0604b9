// The cubature's training: poses drawn, springs selected greedily, their weights refitted by NNLS
// (cubature.h).
#include "modal_mass_spring/cubature.h"

#include "modal_mass_spring/spring_forces.h"
#include "reduction/cubature_springs.h"
#include "solvers/nnls.h"

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cmath>
#include <random>
#include <stdexcept>
#include <utility>

namespace modal_mass_spring
{
namespace
{

// Phi^T f_spring(x_ref + Phi X) on the free dofs.
Eigen::VectorXd reducedSpringForce(const Grid& grid, const Eigen::MatrixXd& phi, const Eigen::VectorXd& x_ref,
                                   const Eigen::VectorXd& modal)
{
  Eigen::VectorXd x = x_ref;
  grid.addFree(phi * modal, x);
  Eigen::VectorXd f;
  springForces(grid, x, f);
  return phi.transpose() * grid.gatherFree(f);
}

// Whether x_ref + u (u on the free dofs) shortens a spring below kShortestTrainingSpring of its
// length at x_ref (`reference`, per spring); x is scratch.
bool folds(const Grid& grid, const Eigen::VectorXd& x_ref, const Eigen::VectorXd& reference, const Eigen::VectorXd& u,
           Eigen::VectorXd& x)
{
  x = x_ref;
  grid.addFree(u, x);
  const int dim = grid.dimension();
  const std::vector<Spring>& springs = grid.springs();
  for (size_t k = 0; k < springs.size(); ++k)
  {
    double squared = 0.0;
    for (int a = 0; a < dim; ++a)
    {
      const double d = x[dim * springs[k].j + a] - x[dim * springs[k].i + a];
      squared += d * d;
    }
    const double shortest = kShortestTrainingSpring * reference[static_cast<Eigen::Index>(k)];
    if (squared < shortest * shortest)
      return true;
  }
  return false;
}

}  // namespace

// A pose that folds a spring is drawn again: modes extrapolated that far are no deformation the grid
// takes, and such poses, whose force nearly cancels, made a single one dominate the relative error
// of a whole set.
Eigen::MatrixXd trainingPoses(const Grid& grid, const ModalBasis& basis, const Eigen::VectorXd& x_ref, int count,
                              double size, std::mt19937_64& rng)
{
  const Eigen::Index r = basis.phi.cols();
  const int dim = grid.dimension();
  double omega_1 = 0.0;
  for (Eigen::Index i = 0; i < r && omega_1 == 0.0; ++i)
    omega_1 = basis.frequencies[i];
  Eigen::VectorXd reference(static_cast<Eigen::Index>(grid.springs().size()));
  for (size_t k = 0; k < grid.springs().size(); ++k)
    reference[static_cast<Eigen::Index>(k)] = restDiff(grid, x_ref, grid.springs()[k]).norm();
  std::normal_distribution<double> normal;
  std::uniform_real_distribution<double> uniform;
  Eigen::MatrixXd poses(r, count);
  Eigen::VectorXd u, x;
  for (int p = 0; p < count; ++p)
  {
    bool folded = true;
    for (int attempt = 0; attempt < kPoseAttempts && folded; ++attempt)
    {
      for (Eigen::Index i = 0; i < r; ++i)
      {
        const double omega = basis.frequencies[i];
        poses(i, p) = normal(rng) * (omega > 0.0 && omega_1 > 0.0 ? omega_1 / omega : 1.0);
      }
      u.noalias() = basis.phi * poses.col(p);
      double largest = 0.0;
      for (Eigen::Index k = 0; k + dim <= u.size(); k += dim)
        largest = std::max(largest, u.segment(k, dim).norm());
      const double magnitude = size * (1.0 - uniform(rng));  // (0, size]
      const double scale = largest > 0.0 ? magnitude / largest : 0.0;
      poses.col(p) *= scale;
      u *= scale;
      folded = folds(grid, x_ref, reference, u, x);
    }
    // Where nearly every direction folds (a pose size far beyond the grid), the last one is shrunk.
    for (int halving = 0; halving < 60 && folded; ++halving)
    {
      poses.col(p) *= 0.5;
      u *= 0.5;
      folded = folds(grid, x_ref, reference, u, x);
    }
  }
  return poses;
}

namespace
{

// The training problem, with every pose scaled by 1 / |its target| so that |A w - b| / |b| is the
// RMS over poses of the relative error. Pose p's target (r entries) is column p of target(); spring
// s's column of A is never stored: its block for pose p is -D_s^T F_s(:, p), with D_s = springRows
// (dim x r) and F_s (dim x poses) the spring's scaled force change (forces()). The training keeps
// D_s^T and F_s of the selected springs only, dim (r + poses) numbers each instead of r poses.
class TrainingSet
{
public:
  TrainingSet(const Grid& grid, const ModalBasis& basis, const Eigen::VectorXd& x_ref, const Eigen::MatrixXd& poses)
    : grid_(grid), phi_(basis.phi), x_ref_(x_ref),
      base_(reducedSpringForce(grid, phi_, x_ref, Eigen::VectorXd::Zero(phi_.cols())))
  {
    append(poses);
  }

  // Adds poses after the current ones.
  void append(const Eigen::MatrixXd& poses)
  {
    const Eigen::Index r = phi_.cols(), first = size(), count = poses.cols();
    poses_.conservativeResize(r, first + count);
    poses_.rightCols(count) = poses;
    scale_.conservativeResize(first + count);
    b_.conservativeResize(r, first + count);
    for (Eigen::Index p = first; p < first + count; ++p)
    {
      const Eigen::VectorXd target = reducedSpringForce(grid_, phi_, x_ref_, poses_.col(p)) - base_;
      const double norm = target.norm();
      scale_[p] = norm > 0.0 ? 1.0 / norm : 0.0;  // a pose that moves no spring carries no information
      b_.col(p) = scale_[p] * target;
    }
  }

  Eigen::Index size() const { return poses_.cols(); }
  const Eigen::MatrixXd& poses() const { return poses_; }
  const Eigen::MatrixXd& target() const { return b_; }

  // F_s: the scaled f_s(X_p) - f_s(0), the spring's force on its particle i, for every pose p (a
  // column each); `rows` is its D_s.
  Eigen::MatrixXd forces(const Spring& s, const Eigen::MatrixXd& rows) const
  {
    const SmallVector d0 = restDiff(grid_, x_ref_, s);
    const SmallVector f0 = springForce(s, d0);
    const Eigen::MatrixXd d = (rows * poses_).colwise() + Eigen::VectorXd(d0);
    Eigen::MatrixXd f(d.rows(), d.cols());
    for (Eigen::Index p = 0; p < d.cols(); ++p)
      f.col(p) = scale_[p] * (springForce(s, d.col(p)) - f0);
    return f;
  }

private:
  const Grid& grid_;
  const Eigen::MatrixXd& phi_;
  const Eigen::VectorXd& x_ref_;
  const Eigen::VectorXd base_;
  Eigen::MatrixXd poses_, b_;
  Eigen::VectorXd scale_;
};

// Each purpose draws from its own stream of the seed: growing the training set never changes the
// held-out poses.
std::mt19937_64 poseStream(int seed, int purpose)
{
  std::seed_seq sequence{static_cast<std::uint32_t>(seed), static_cast<std::uint32_t>(purpose)};
  return std::mt19937_64(sequence);
}

// The springs' columns of A, kept as their factors: D_s^T side by side (r x dim k) and F_s stacked
// (dim k x poses), for the first k springs.
struct SpringFactors
{
  Eigen::MatrixXd diff_t, forces;

  // A w for the first w.size() springs, as r x poses: -sum_s D_s^T (w_s F_s), one matrix product.
  Eigen::MatrixXd fit(const Eigen::VectorXd& w, int dim) const
  {
    const Eigen::Index k = w.size();
    Eigen::MatrixXd weighted = forces.topRows(dim * k);
    for (Eigen::Index s = 0; s < k; ++s)
      weighted.middleRows(dim * s, dim) *= w[s];
    return -diff_t.leftCols(dim * k) * weighted;
  }
};

// The relative error of weights w on `factors`' springs, their forces on `set`'s poses.
double relativeError(const TrainingSet& set, const SpringFactors& factors, const Eigen::VectorXd& w, int dim)
{
  const double norm = set.target().norm();
  return norm > 0.0 ? (factors.fit(w, dim) - set.target()).norm() / norm : 0.0;
}

// The column of spring (rows, f) dotted with a matrix of the target's shape: -sum(F_s .* (D_s Y)).
double columnDot(const Eigen::MatrixXd& rows, const Eigen::MatrixXd& f, const Eigen::MatrixXd& y)
{
  return -(f.array() * (rows * y).array()).sum();
}

// Sums each run of `dim` consecutive rows of a column vector: dim k entries to k.
Eigen::VectorXd sumBlocks(const Eigen::VectorXd& v, int dim)
{
  return Eigen::Map<const Eigen::MatrixXd>(v.data(), dim, v.size() / dim).colwise().sum().transpose();
}

// A training set whose forces are not finite, or all zero, cannot be fitted: refused with the pose
// size that made it so.
void requireTrainingForces(const TrainingSet& training, double pose_size)
{
  if (!training.target().allFinite())
  {
    char text[160];
    std::snprintf(text, sizeof text,
                  "the cubature's training poses give forces that are not finite (cubature_pose_size = %g m: too "
                  "large for this grid?)",
                  pose_size);
    throw std::runtime_error(text);
  }
  if (!(training.target().norm() > 0.0))
  {
    // Poses so small that every spring's force change underflows: nothing to fit, and a cubature of
    // no springs would pass for exact.
    char text[200];
    std::snprintf(text, sizeof text,
                  "the cubature's training poses give no force at all (cubature_pose_size = %g m: too small for "
                  "this grid's springs to stretch); a cubature of no springs would model no force",
                  pose_size);
    throw std::runtime_error(text);
  }
}

// The greedy selection: the springs not selected yet (pool) and those selected, their factors on the
// training poses (their capacity doubled as they grow), the NNLS fit of their weights, its residual
// and its relative error.
struct Selection
{
  const Grid& grid;
  const Eigen::MatrixXd phi_t;  // a dof's row of Phi contiguous, for D_s
  const int dim;
  const int max_springs;
  std::vector<int> pool, selected;
  SpringFactors chosen;
  NnlsNormal weights_fit;
  Eigen::MatrixXd residual;
  double error = 1.0;

  Selection(const Grid& g, const ModalBasis& basis, const TrainingSet& training, int max)
    : grid(g), phi_t(basis.phi.transpose()), dim(g.dimension()), max_springs(max), pool(g.springs().size()),
      residual(training.target())
  {
    for (size_t k = 0; k < pool.size(); ++k)
      pool[k] = static_cast<int>(k);
    const Eigen::Index capacity = dim * std::min(max_springs, 64);
    chosen.diff_t.resize(basis.phi.cols(), capacity);
    chosen.forces.resize(capacity, training.size());
  }

  Eigen::MatrixXd rowsOf(int spring) const { return springRows(grid, phi_t, grid.springs()[spring]); }

  // Selects the candidate, among a random subset of the pool, whose column points most along the
  // residual, and refits; false when none reduces the residual. (Adding batches of the best
  // candidates per refit was tried: it needed far more springs for the same error.)
  bool selectSpring(const TrainingSet& training, std::mt19937_64& rng)
  {
    const size_t candidates = std::min<size_t>(kCubatureCandidates, pool.size());
    size_t best = candidates;
    double best_score = 0.0;
    Eigen::MatrixXd best_rows, best_forces;
    for (size_t c = 0; c < candidates; ++c)
    {
      std::swap(pool[c], pool[c + std::uniform_int_distribution<size_t>(0, pool.size() - 1 - c)(rng)]);
      Eigen::MatrixXd rows = rowsOf(pool[c]);
      Eigen::MatrixXd forces = training.forces(grid.springs()[pool[c]], rows);
      // |column|^2 = sum over poses of F_s^T (D_s D_s^T) F_s.
      const double norm = std::sqrt(std::max(0.0, (forces.array() * ((rows * rows.transpose()) * forces).array()).sum()));
      const double score = norm > 0.0 ? columnDot(rows, forces, residual) / norm : 0.0;
      if (score > best_score)
      {
        best = c;
        best_score = score;
        best_rows = std::move(rows);
        best_forces = std::move(forces);
      }
    }
    if (best == candidates)
      return false;
    selected.push_back(pool[best]);
    pool[best] = pool.back();
    pool.pop_back();
    addColumn(training, best_rows, best_forces);
    return true;
  }

  // The selected spring's factors (rows, forces) appended, and the weights refitted: the new
  // column's Gram entries (sum over poses of F_t^T D_t D_s^T F_s), then NNLS from the previous weights.
  void addColumn(const TrainingSet& training, const Eigen::MatrixXd& rows, const Eigen::MatrixXd& forces)
  {
    const Eigen::MatrixXd& b = training.target();
    const Eigen::Index k = static_cast<Eigen::Index>(selected.size()) - 1;
    if (dim * (k + 1) > chosen.diff_t.cols())
    {
      const Eigen::Index grown = dim * std::min<Eigen::Index>(2 * chosen.diff_t.cols() / dim, max_springs);
      chosen.diff_t.conservativeResize(Eigen::NoChange, grown);
      chosen.forces.conservativeResize(grown, Eigen::NoChange);
    }
    chosen.diff_t.middleCols(dim * k, dim) = rows.transpose();
    chosen.forces.middleRows(dim * k, dim) = forces;
    const Eigen::MatrixXd coupling = chosen.diff_t.leftCols(dim * (k + 1)).transpose() * rows.transpose();
    const Eigen::VectorXd gram_rows =
        (chosen.forces.topRows(dim * (k + 1)).array() * (coupling * forces).array()).rowwise().sum();
    weights_fit.addVariable(sumBlocks(gram_rows, dim), columnDot(rows, forces, b));
    weights_fit.solve();
    residual = b - chosen.fit(weights_fit.weights(), dim);
    error = residual.norm() / b.norm();
  }

  // The selected springs' factors on another set of poses.
  SpringFactors factorsOn(const TrainingSet& set) const
  {
    const Eigen::Index k = static_cast<Eigen::Index>(selected.size());
    SpringFactors on_set{chosen.diff_t.leftCols(dim * k), Eigen::MatrixXd(dim * k, set.size())};
    for (Eigen::Index s = 0; s < k; ++s)
      on_set.forces.middleRows(dim * s, dim) =
          set.forces(grid.springs()[selected[static_cast<size_t>(s)]], chosen.diff_t.middleCols(dim * s, dim).transpose());
    return on_set;
  }

  // The validation poses (their factors on_validation) join the training set, and the selected
  // springs are refitted on it: the Gram matrix anew, a block of springs at a time (entry (s, t)
  // sums (D_s D_t^T) .* (F_s F_t^T)).
  void grow(TrainingSet& training, const TrainingSet& validation, const SpringFactors& on_validation)
  {
    const Eigen::Index k = static_cast<Eigen::Index>(selected.size());
    const Eigen::Index before = training.size();
    training.append(validation.poses());
    chosen.forces.conservativeResize(Eigen::NoChange, training.size());
    chosen.forces.block(0, before, dim * k, validation.size()) = on_validation.forces;
    const auto diff_t = chosen.diff_t.leftCols(dim * k);
    const auto forces = chosen.forces.topRows(dim * k);
    Eigen::MatrixXd gram(k, k);
    for (Eigen::Index t0 = 0; t0 < k; t0 += 64)
    {
      const Eigen::Index width = dim * std::min<Eigen::Index>(64, k - t0);
      const Eigen::MatrixXd products = (diff_t.transpose() * diff_t.middleCols(dim * t0, width)).array() *
                                       (forces * forces.middleRows(dim * t0, width).transpose()).array();
      for (Eigen::Index t = 0; t < width / dim; ++t)
        gram.col(t0 + t) = sumBlocks(products.middleCols(dim * t, dim).rowwise().sum(), dim);
    }
    const Eigen::VectorXd atb =
        -sumBlocks((forces.array() * (diff_t.transpose() * training.target()).array()).rowwise().sum(), dim);
    weights_fit = NnlsNormal();
    for (Eigen::Index j = 0; j < k; ++j)
      weights_fit.addVariable(gram.col(j).head(j + 1), atb[j]);
    weights_fit.solve();
    residual = training.target() - chosen.fit(weights_fit.weights(), dim);
    error = residual.norm() / training.target().norm();
  }

  // The cubature: the selected springs with a positive weight (refused when there is none).
  Cubature cubature(const CubatureParams& params) const
  {
    Cubature cubature;
    std::vector<double> weights;
    const Eigen::VectorXd& w = weights_fit.weights();
    for (size_t k = 0; k < selected.size(); ++k)
      if (w[static_cast<Eigen::Index>(k)] > 0.0)
      {
        cubature.springs.push_back(selected[k]);
        weights.push_back(w[static_cast<Eigen::Index>(k)]);
      }
    cubature.weights = Eigen::Map<const Eigen::VectorXd>(weights.data(), static_cast<Eigen::Index>(weights.size()));
    if (cubature.springs.empty())
      throw std::runtime_error("the cubature's training selected no spring (cubature_pose_size = " +
                               std::to_string(params.pose_size) + " m, cubature_seed = " + std::to_string(params.seed) +
                               "): a cubature of no springs would model no force");
    return cubature;
  }

  // The relative error of the cubature's springs and weights on held-out poses.
  double heldoutError(const Cubature& cubature, const TrainingSet& heldout) const
  {
    const Eigen::Index kept = static_cast<Eigen::Index>(cubature.springs.size());
    SpringFactors on_heldout{Eigen::MatrixXd(phi_t.rows(), dim * kept), Eigen::MatrixXd(dim * kept, heldout.size())};
    for (Eigen::Index s = 0; s < kept; ++s)
    {
      const Eigen::MatrixXd rows = rowsOf(cubature.springs[static_cast<size_t>(s)]);
      on_heldout.diff_t.middleCols(dim * s, dim) = rows.transpose();
      on_heldout.forces.middleRows(dim * s, dim) = heldout.forces(grid.springs()[cubature.springs[static_cast<size_t>(s)]], rows);
    }
    return relativeError(heldout, on_heldout, cubature.weights, dim);
  }
};

}  // namespace

std::string describeCubature(const Cubature& c, int num_springs, double tolerance)
{
  char text[512];
  int length = std::snprintf(text, sizeof text,
                             "cubature: %zu of %d springs, training error %.3g%% on %d poses, validation %.3g%%, "
                             "held-out %.3g%%, trained in %.3g s",
                             c.springs.size(), num_springs, 100.0 * c.training_error, c.training_poses,
                             100.0 * c.validation_error, 100.0 * c.heldout_error, c.training_seconds);
  // The training stops at its caps too; say so rather than let the figures pass for the tolerance.
  if (tolerance > 0.0 && std::max(c.training_error, c.validation_error) > tolerance && length > 0)
    std::snprintf(text + length, sizeof text - static_cast<std::size_t>(length),
                  "; above cubature_tolerance %.3g%%: the training stopped at its caps (cubature_max_springs, "
                  "cubature_max_training_poses) or found no spring that helps",
                  100.0 * tolerance);
  return text;
}

Eigen::Index effectiveMaxTrainingPoses(const CubatureParams& params)
{
  return params.max_training_poses > 0 ? params.max_training_poses
                                       : static_cast<Eigen::Index>(kDefaultPoseGrowth) * params.training_poses;
}

int effectiveMaxSprings(const CubatureParams& params, int num_springs)
{
  return params.max_springs > 0 ? std::min(params.max_springs, num_springs)
                                : std::min(kDefaultMaxSprings, num_springs);
}

Cubature trainCubature(const Grid& grid, const ModalBasis& basis, const Eigen::VectorXd& x_ref,
                       const CubatureParams& params, const PoseSampler& sampler, const IterationFn& on_iteration)
{
  auto draw = [&](int count, std::mt19937_64& stream) {
    return sampler ? sampler(count, stream) : trainingPoses(grid, basis, x_ref, count, params.pose_size, stream);
  };
  const auto start = std::chrono::steady_clock::now();
  std::mt19937_64 rng(static_cast<std::uint64_t>(params.seed));
  std::mt19937_64 validation_rng = poseStream(params.seed, 1), heldout_rng = poseStream(params.seed, 2);
  TrainingSet training(grid, basis, x_ref, draw(params.training_poses, rng));
  requireTrainingForces(training, params.pose_size);
  const Eigen::Index max_poses = effectiveMaxTrainingPoses(params);
  Selection selection(grid, basis, training, effectiveMaxSprings(params, static_cast<int>(grid.springs().size())));
  double validation_error = 0.0;
  while (true)
  {
    while (selection.error > params.tolerance && static_cast<int>(selection.selected.size()) < selection.max_springs &&
           !selection.pool.empty() && selection.selectSpring(training, rng))
      if (on_iteration)
        on_iteration("cubature", static_cast<int>(selection.selected.size()), selection.error, params.tolerance);
    // The fit is judged on fresh poses of the same law: below the tolerance there too, it generalises.
    // Otherwise those poses join the training set (twice as many poses, the same springs refitted) and
    // the selection goes on, as long as the training set may grow.
    const TrainingSet validation(grid, basis, x_ref, draw(static_cast<int>(training.size()), validation_rng));
    const SpringFactors on_validation = selection.factorsOn(validation);
    validation_error = relativeError(validation, on_validation, selection.weights_fit.weights(), grid.dimension());
    if (validation_error <= params.tolerance || selection.error > params.tolerance || 2 * training.size() > max_poses)
      break;
    selection.grow(training, validation, on_validation);
  }

  Cubature cubature = selection.cubature(params);
  cubature.training_poses = static_cast<int>(training.size());
  cubature.training_error = selection.error;
  cubature.validation_error = validation_error;
  // Held-out poses, as many as the training's, that neither the selection nor the stop saw.
  const TrainingSet heldout(grid, basis, x_ref, draw(cubature.training_poses, heldout_rng));
  cubature.heldout_error = selection.heldoutError(cubature, heldout);
  cubature.training_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return cubature;
}

}  // namespace modal_mass_spring
