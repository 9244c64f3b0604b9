// Cubature training (greedy selection, NNLS refits) and the cubature force model.
#include "modal_mass_spring/cubature.h"

#include "modal_mass_spring/spring_forces.h"
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

// Up to 3 entries, never on the heap: per-spring vectors of the training.
using SmallVector = Eigen::Matrix<double, Eigen::Dynamic, 1, 0, 3, 1>;

// D_s = Phi_j - Phi_i: the spring's vector from i to j changes by D_s X (dim x r; fixed rows are 0).
// Read from Phi^T, where a dof's row of Phi is contiguous (Phi's rows are strided by n).
Eigen::MatrixXd springRows(const Grid& grid, const Eigen::MatrixXd& phi_t, const Spring& s)
{
  const int dim = grid.dimension();
  Eigen::MatrixXd rows = Eigen::MatrixXd::Zero(dim, phi_t.rows());
  for (int a = 0; a < dim; ++a)
  {
    const int fi = grid.freeIndex(dim * s.i + a), fj = grid.freeIndex(dim * s.j + a);
    if (fj >= 0)
      rows.row(a) += phi_t.col(fj).transpose();
    if (fi >= 0)
      rows.row(a) -= phi_t.col(fi).transpose();
  }
  return rows;
}

// The force on particle i of a spring whose vector from i to j is d.
SmallVector springForce(const Spring& s, const SmallVector& d)
{
  return modal_mass_spring::springForce(s.stiffness, s.rest_length, d);
}

Eigen::VectorXd restDiff(const Grid& grid, const Eigen::VectorXd& x, const Spring& s)
{
  const int dim = grid.dimension();
  return x.segment(dim * s.j, dim) - x.segment(dim * s.i, dim);
}

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
  const int dim = grid.dimension();
  std::mt19937_64 rng(static_cast<std::uint64_t>(params.seed));
  std::mt19937_64 validation_rng = poseStream(params.seed, 1), heldout_rng = poseStream(params.seed, 2);
  TrainingSet training(grid, basis, x_ref, draw(params.training_poses, rng));
  if (!training.target().allFinite())
  {
    char text[160];
    std::snprintf(text, sizeof text,
                  "the cubature's training poses give forces that are not finite (cubature_pose_size = %g m: too "
                  "large for this grid?)",
                  params.pose_size);
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
                  params.pose_size);
    throw std::runtime_error(text);
  }
  const int max_springs = effectiveMaxSprings(params, static_cast<int>(grid.springs().size()));
  const Eigen::Index max_poses = effectiveMaxTrainingPoses(params);
  const Eigen::MatrixXd phi_t = basis.phi.transpose();  // a dof's row of Phi contiguous, for D_s
  auto rowsOf = [&](int spring) { return springRows(grid, phi_t, grid.springs()[spring]); };

  std::vector<int> pool(grid.springs().size()), selected;
  for (size_t k = 0; k < pool.size(); ++k)
    pool[k] = static_cast<int>(k);
  // The selected springs' factors on the training poses, their capacity doubled as they grow.
  SpringFactors chosen;
  const Eigen::Index capacity = dim * std::min(max_springs, 64);
  chosen.diff_t.resize(basis.phi.cols(), capacity);
  chosen.forces.resize(capacity, training.size());
  NnlsNormal weights_fit;
  Eigen::MatrixXd residual = training.target();
  double error = 1.0, validation_error = 0.0;
  while (true)
  {
    const Eigen::MatrixXd& b = training.target();
    const double b_norm = b.norm();
    while (error > params.tolerance && static_cast<int>(selected.size()) < max_springs && !pool.empty())
    {
      // The candidate, among a random subset, whose column points most along the residual. (Adding
      // batches of the best candidates per refit was tried: it needed far more springs for the same error.)
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
        break;  // no spring reduces the residual
      const Eigen::Index k = static_cast<Eigen::Index>(selected.size());
      selected.push_back(pool[best]);
      pool[best] = pool.back();
      pool.pop_back();
      if (dim * (k + 1) > chosen.diff_t.cols())
      {
        const Eigen::Index grown = dim * std::min<Eigen::Index>(2 * chosen.diff_t.cols() / dim, max_springs);
        chosen.diff_t.conservativeResize(Eigen::NoChange, grown);
        chosen.forces.conservativeResize(grown, Eigen::NoChange);
      }
      chosen.diff_t.middleCols(dim * k, dim) = best_rows.transpose();
      chosen.forces.middleRows(dim * k, dim) = best_forces;
      // The refit: the new column's Gram entries (sum over poses of F_t^T D_t D_s^T F_s), then NNLS
      // from the previous weights.
      const Eigen::MatrixXd coupling = chosen.diff_t.leftCols(dim * (k + 1)).transpose() * best_rows.transpose();
      const Eigen::VectorXd gram_rows =
          (chosen.forces.topRows(dim * (k + 1)).array() * (coupling * best_forces).array()).rowwise().sum();
      weights_fit.addVariable(sumBlocks(gram_rows, dim), columnDot(best_rows, best_forces, b));
      weights_fit.solve();
      residual = b - chosen.fit(weights_fit.weights(), dim);
      error = residual.norm() / b_norm;
      if (on_iteration)
        on_iteration("cubature", static_cast<int>(selected.size()), error, params.tolerance);
    }
    // The fit is judged on fresh poses of the same law: below the tolerance there too, it generalises.
    // Otherwise those poses join the training set (twice as many poses, the same springs refitted) and
    // the selection goes on, as long as the training set may grow.
    const TrainingSet validation(grid, basis, x_ref, draw(static_cast<int>(training.size()), validation_rng));
    const Eigen::Index k = static_cast<Eigen::Index>(selected.size());
    SpringFactors on_validation{chosen.diff_t.leftCols(dim * k), Eigen::MatrixXd(dim * k, validation.size())};
    for (Eigen::Index s = 0; s < k; ++s)
      on_validation.forces.middleRows(dim * s, dim) =
          validation.forces(grid.springs()[selected[static_cast<size_t>(s)]], chosen.diff_t.middleCols(dim * s, dim).transpose());
    validation_error = relativeError(validation, on_validation, weights_fit.weights(), dim);
    if (validation_error <= params.tolerance || error > params.tolerance || 2 * training.size() > max_poses)
      break;
    const Eigen::Index before = training.size();
    training.append(validation.poses());
    chosen.forces.conservativeResize(Eigen::NoChange, training.size());
    chosen.forces.block(0, before, dim * k, validation.size()) = on_validation.forces;
    // The Gram matrix anew, a block of springs at a time: entry (s, t) sums (D_s D_t^T) .* (F_s F_t^T).
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

  Cubature cubature;
  cubature.training_poses = static_cast<int>(training.size());
  cubature.training_error = error;
  cubature.validation_error = validation_error;
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

  // Held-out poses, as many as the training's, that neither the selection nor the stop saw.
  const TrainingSet heldout(grid, basis, x_ref, draw(cubature.training_poses, heldout_rng));
  const Eigen::Index kept = static_cast<Eigen::Index>(cubature.springs.size());
  SpringFactors on_heldout{Eigen::MatrixXd(basis.phi.cols(), dim * kept), Eigen::MatrixXd(dim * kept, heldout.size())};
  for (Eigen::Index s = 0; s < kept; ++s)
  {
    const Eigen::MatrixXd rows = rowsOf(cubature.springs[static_cast<size_t>(s)]);
    on_heldout.diff_t.middleCols(dim * s, dim) = rows.transpose();
    on_heldout.forces.middleRows(dim * s, dim) = heldout.forces(grid.springs()[cubature.springs[static_cast<size_t>(s)]], rows);
  }
  cubature.heldout_error = relativeError(heldout, on_heldout, cubature.weights, dim);
  cubature.training_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return cubature;
}

CubatureForceModel::CubatureForceModel(const Grid& grid, const ModalBasis& basis, const Eigen::VectorXd& x_ref,
                                       const Cubature& cubature)
  : grid_(grid), basis_(basis), dim_(grid.dimension()), weights_(cubature.weights)
{
  const Eigen::Index count = static_cast<Eigen::Index>(cubature.springs.size());
  const Eigen::MatrixXd phi_t = basis.phi.transpose();
  diff_t_.resize(basis.phi.cols(), count * dim_);
  for (Eigen::Index t = 0; t < count; ++t)
  {
    springs_.push_back(grid.springs()[cubature.springs[t]]);
    diff_t_.middleCols(t * dim_, dim_) = springRows(grid, phi_t, springs_.back()).transpose();
  }
  // The exact force at the reference is part of F: it carries the round-off of every spring.
  roundoff_ = modalRoundoff(grid, basis, x_ref);
  setReference(x_ref);
}

void CubatureForceModel::setReference(const Eigen::VectorXd& x_ref)
{
  rest_diff_.resize(diff_t_.cols());
  for (size_t t = 0; t < springs_.size(); ++t)
    rest_diff_.segment(static_cast<Eigen::Index>(t) * dim_, dim_) = restDiff(grid_, x_ref, springs_[t]);
  d_modal_.resize(0);
  f_modal_.resize(0);
  // The exact force and energy at the reference, minus what the cubature gives there.
  Eigen::VectorXd f_all;
  double spring_energy = 0.0;
  springForces(grid_, x_ref, f_all, &spring_energy);
  f_all += grid_.gravityForce();
  const Eigen::VectorXd zero = Eigen::VectorXd::Zero(size());
  Eigen::VectorXd at_zero;
  const double cubature_energy = weightedSprings(zero, &at_zero);
  constant_ = basis_.phi.transpose() * grid_.gatherFree(f_all) - at_zero;
  energy_constant_ = spring_energy + gravityEnergy(grid_, x_ref) - cubature_energy;
  base_rest_diff_ = rest_diff_;
  base_energy_constant_ = energy_constant_;
  cache_.clear();
}

void CubatureForceModel::setHandleMap(const Eigen::MatrixXd& psi, const AffineHandleFit& fit)
{
  const std::vector<int>& handle_dofs = grid_.handleDofs();
  const Eigen::Index nb = static_cast<Eigen::Index>(handle_dofs.size());
  std::vector<Eigen::Index> handle_index(static_cast<size_t>(grid_.numDofs()), -1);
  for (Eigen::Index k = 0; k < nb; ++k)
    handle_index[static_cast<size_t>(handle_dofs[static_cast<size_t>(k)])] = k;
  // Dof `dof`'s row of [Psi; I] added `sign` times to `row`; fixed dofs do not move.
  auto add = [&](int dof, double sign, Eigen::Index row) {
    const int free = grid_.freeIndex(dof);
    if (free >= 0)
      handle_rows_.row(row) += sign * psi.row(free);
    else if (handle_index[static_cast<size_t>(dof)] >= 0)
      handle_rows_(row, handle_index[static_cast<size_t>(dof)]) += sign;
  };
  handle_rows_.setZero(diff_t_.cols(), nb);
  for (size_t t = 0; t < springs_.size(); ++t)
    for (int a = 0; a < dim_; ++a)
    {
      const Eigen::Index row = static_cast<Eigen::Index>(t) * dim_ + a;
      add(dim_ * springs_[t].j + a, 1.0, row);
      add(dim_ * springs_[t].i + a, -1.0, row);
    }
  fit_ = fit;
  handle_affine_rows_ = handle_rows_ * fit.h;
  const Eigen::VectorXd& g = grid_.gravityForce();
  handle_gravity_ = psi.transpose() * grid_.gatherFree(g);
  for (Eigen::Index k = 0; k < nb; ++k)
    handle_gravity_[k] += g[handle_dofs[static_cast<size_t>(k)]];
}

void CubatureForceModel::moveHandles(const Eigen::VectorXd& dx_b)
{
  rest_diff_ = base_rest_diff_;
  if (fit_.split(dx_b, affine_, non_affine_))
    rest_diff_.noalias() += handle_rows_ * dx_b;
  else
    rest_diff_.noalias() += handle_affine_rows_ * affine_;
  // The spring part of the correction at X = 0 stays the last setReference's; gravity's is exact.
  energy_constant_ = base_energy_constant_ - handle_gravity_.dot(dx_b);
  d_modal_.resize(0);
  f_modal_.resize(0);
  cache_.clear();
}

void CubatureForceModel::springVectors(const Eigen::VectorXd& modal)
{
  if (d_modal_.size() == modal.size() && d_modal_ == modal)
    return;
  d_.noalias() = diff_t_.transpose() * modal;
  d_ += rest_diff_;
  d_modal_ = modal;
}

// The per-spring work with the dimension fixed at compile time: Eigen's fixed-size vectors keep it on
// the stack and unrolled (dynamic ones of at most 3 entries cost twice as much here). One pass over
// D^T, spring by spring: its block D_s^T (r x dim, contiguous) gives the spring vector D_s X and,
// still in cache, takes back its force D_s^T f_s: D is kept once (as D^T) and read once per force.
// The multiply-adds, 2 |T| dim r, are the cost (docs/benchmarks.md, "The cubature's step").
template <int Dim>
double CubatureForceModel::weightedSpringForces(const Eigen::VectorXd& modal, Eigen::VectorXd* f)
{
  using Vector = Eigen::Matrix<double, Dim, 1>;
  // d_ holds the spring vectors already when a tangent or an energy at this X came first.
  const bool known = d_modal_.size() == modal.size() && d_modal_ == modal;
  d_.resize(diff_t_.cols());
  if (f)
    f->setZero(diff_t_.rows());
  double energy = 0.0;
  for (size_t t = 0; t < springs_.size(); ++t)
  {
    const Eigen::Index row = static_cast<Eigen::Index>(t) * Dim;
    const Spring& s = springs_[t];
    const auto block = diff_t_.middleCols<Dim>(row);  // D_s^T
    Vector d;
    if (known)
    {
      d = d_.segment<Dim>(row);
    }
    else
    {
      for (int c = 0; c < Dim; ++c)
        d[c] = block.col(c).dot(modal) + rest_diff_[row + c];
      d_.segment<Dim>(row) = d;
    }
    // The weighted spring is a spring of stiffness w_s k_s.
    double spring_energy = 0.0;
    const Vector force = springForce(weights_[static_cast<Eigen::Index>(t)] * s.stiffness, s.rest_length, d,
                                     &spring_energy);
    energy += spring_energy;
    if (f)
      f->noalias() -= block * force;  // dE_s/dX = D_s^T f_i, in one pass over f
  }
  d_modal_ = modal;
  return energy;
}

double CubatureForceModel::weightedSprings(const Eigen::VectorXd& modal, Eigen::VectorXd* f)
{
  return dim_ == 3 ? weightedSpringForces<3>(modal, f) : weightedSpringForces<2>(modal, f);
}

void CubatureForceModel::force(const Eigen::VectorXd& modal, Eigen::VectorXd& f)
{
  if (f_modal_.size() == modal.size() && f_modal_ == modal)
  {
    f = f_;
    return;
  }
  const double energy = weightedSprings(modal, &f);
  f += constant_;
  cache_.store(modal, energy + energy_constant_ - constant_.dot(modal));
  f_modal_ = modal;
  f_ = f;
}

double CubatureForceModel::energy(const Eigen::VectorXd& modal)
{
  double cached = 0.0;
  if (cache_.find(modal, cached))
    return cached;
  return weightedSprings(modal, nullptr) + energy_constant_ - constant_.dot(modal);
}

// The blocks w_s K_s D_s, with K_s = k_s (u u^T + (1 - L/l) (I - u u^T)) = a I + b u u^T: so
// a D_s + b u (u^T D_s), without forming K_s. Built transposed (r x dim per spring, contiguous): a
// spring's rows of the column-major D are r cache lines apart, which made this loop cost half the product.
template <int Dim>
void CubatureForceModel::weightedTangentBlocks()
{
  using Vector = Eigen::Matrix<double, Dim, 1>;
  weighted_t_.resize(diff_t_.rows(), diff_t_.cols());
  d_rows_.resize(diff_t_.rows());
  for (size_t t = 0; t < springs_.size(); ++t)
  {
    const Eigen::Index row = static_cast<Eigen::Index>(t) * Dim;
    const Spring& s = springs_[t];
    const Vector d = d_.segment<Dim>(row);
    const double l = d.norm();
    const Vector u = d / l;
    const double wk = weights_[static_cast<Eigen::Index>(t)] * s.stiffness;
    const double a = geometricStiffness(wk, s.rest_length, l);
    const double b = wk - a;
    const auto block = diff_t_.middleCols<Dim>(row);  // D_s^T
    d_rows_.noalias() = block * u;                    // D_s^T u
    for (int c = 0; c < Dim; ++c)  // column by column: an outer product in a sum would need a temporary
      weighted_t_.col(row + c) = a * block.col(c) + (b * u[c]) * d_rows_;
  }
}

void CubatureForceModel::tangentStiffness(const Eigen::VectorXd& modal, SparseMatrix& k)
{
  springVectors(modal);
  if (dim_ == 3)
    weightedTangentBlocks<3>();
  else
    weightedTangentBlocks<2>();
  // D^T (w K D) is symmetric: one triangle is computed, half the product's cost, and mirrored.
  const Eigen::Index r = diff_t_.rows();
  reduced_.resize(r, r);
  reduced_.triangularView<Eigen::Lower>() = diff_t_ * weighted_t_.transpose();
  for (Eigen::Index j = 1; j < r; ++j)
    for (Eigen::Index i = 0; i < j; ++i)
      reduced_(i, j) = reduced_(j, i);
  k = reduced_.sparseView();
}

bool CubatureForceModel::constantStiffness(SparseMatrix& l)
{
  Eigen::VectorXd stiffness(diff_t_.cols());
  for (size_t t = 0; t < springs_.size(); ++t)
    stiffness.segment(static_cast<Eigen::Index>(t) * dim_, dim_).setConstant(weights_[static_cast<Eigen::Index>(t)] *
                                                                             springs_[t].stiffness);
  const Eigen::MatrixXd laplacian = diff_t_ * stiffness.asDiagonal() * diff_t_.transpose();
  l = laplacian.sparseView();
  return true;
}

}  // namespace modal_mass_spring
