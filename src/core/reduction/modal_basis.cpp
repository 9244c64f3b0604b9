// Shift-invert Lanczos with partial reorthogonalisation (Spectra as a fallback) over CHOLMOD's
// supernodal Cholesky factorisation.
#include "modal_mass_spring/modal_basis.h"
#include "solvers/huge_pages.h"
#include "solvers/sparse_cholesky.h"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/QR>
#include <Spectra/SymEigsShiftSolver.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <cstddef>
#include <memory>
#include <numeric>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace modal_mass_spring
{
namespace
{

// A Ritz value theta has converged when the estimate of its residual is below kTolerance |theta|
// (Spectra's and ARPACK's criterion).
constexpr double kTolerance = 1e-12;

// A convergence check after j Lanczos steps (a tridiagonal eigensolve, O(j^3)) is spaced from the
// last by kCheckCost j^3 / entries of the factor steps, so that the checks cost a bounded fraction of
// the steps and stopping comes at most that late (the costs behind it: docs/benchmarks.md, "Modal basis").
constexpr double kCheckCost = 1.0;

// y = P (A - sigma I)^-1 P x, P = I - Q Q^T the projector onto the complement of the
// modes found so far (none at first). Spectra's own SparseSymShiftSolve uses SparseLU; A - sigma I is
// symmetric positive definite here (sigma < 0, A semi-definite), so a Cholesky factorisation is
// enough and several times faster. It is factorised once and reused by every deflated pass.
class ShiftInvert
{
public:
  using Scalar = double;

  ShiftInvert(const SparseMatrix& a, double sigma) : n_(a.rows()), cholesky_(std::make_shared<SparseCholesky>())
  {
    if (!cholesky_->factorise(a, -sigma))
      throw std::runtime_error("modal basis: factorising K - sigma M failed (sigma = " + std::to_string(sigma) + ")");
  }
  Eigen::Index rows() const { return n_; }
  Eigen::Index cols() const { return n_; }
  // What a solve costs, in entries read.
  double solveCost() const { return static_cast<double>(cholesky_->storedEntries() + n_); }
  void set_shift(double) {}  // factorised at construction, for the one shift used
  void deflate(const Eigen::MatrixXd& q) { q_ = q; }
  void project(Eigen::Ref<Eigen::VectorXd> x) const
  {
    if (q_.cols() > 0)
      x -= q_ * (q_.transpose() * x);
  }

  void perform_op(const double* x_in, double* y_out) const
  {
    Eigen::Map<const Eigen::VectorXd> x(x_in, n_);
    Eigen::Map<Eigen::VectorXd> y(y_out, n_);
    y = x;
    project(y);
    cholesky_->solveInPlace(y);
    project(y);
  }

private:
  Eigen::Index n_;
  std::shared_ptr<SparseCholesky> cholesky_;  // shared: Spectra may copy the operator
  Eigen::MatrixXd q_;
};

// Lanczos without restarts and with partial reorthogonalisation (Simon 1984): the Ritz vectors of the
// nev largest eigenvalues of the operator B, or false when max_steps were not enough. Reorthogonalising
// against every earlier Lanczos vector at every step (Spectra's way) costs nearly as much as the solves
// on a 100 x 100 grid; here Simon's recurrence estimates the loss of orthogonality and the vectors are
// reorthogonalised only when it passes sqrt(eps) (every third step there), which keeps them
// semi-orthogonal: enough for Ritz values to working precision. The Ritz vectors are orthonormalised
// afterwards.
class PartialLanczos
{
public:
  PartialLanczos(const ShiftInvert& op, int max_steps)
    : op_(op), n_(static_cast<int>(op.rows())), m_(std::min(n_, max_steps)), v_(n_, m_ + 1),
      alpha_(Eigen::VectorXd::Zero(m_)), beta_(Eigen::VectorXd::Zero(m_)), omega_(Eigen::VectorXd::Zero(m_ + 1)),
      omega_previous_(Eigen::VectorXd::Zero(m_ + 1))
  {
    adviseHugePages(v_.data(), sizeof(double) * static_cast<std::size_t>(v_.size()));
  }

  bool run(int nev, Eigen::MatrixXd& vectors, const IterationFn& on_iteration)
  {
    if (!fresh(0))
      return false;
    omega_[0] = 1.0;
    int next_check = nev;
    Eigen::VectorXd w(n_);
    for (int j = 0; j < m_; ++j)
    {
      lanczosStep(j, w);
      keepSemiOrthogonal(j, w);

      // A breakdown (an invariant subspace) goes on from a new direction, uncoupled (beta_j = 0): one
      // more copy of a repeated eigenvalue each time. When none is left, the Ritz pairs are exact.
      const bool breakdown = beta_[j] <= 1e-12 * norm_estimate_;
      const bool exhausted = j + 1 == n_ || (breakdown && !fresh(j + 1));
      const bool last = j + 1 == m_ || exhausted;
      // When the steps may fill the whole space, only the end is looked at: stopping early could miss
      // copies of a repeated eigenvalue that later breakdowns would find.
      if (j + 1 >= nev && (last || (m_ < n_ && !breakdown && j + 1 >= next_check)))
      {
        // Every second step on a 100 x 100 grid; on a 20 x 20 one checking that often would cost more
        // than the steps.
        const double check_per_step = kCheckCost * std::pow(j + 1.0, 3) / op_.solveCost();
        next_check = j + 1 + std::max(2, static_cast<int>(std::ceil(check_per_step)));
        if (breakdown)
          beta_[j] = 0.0;
        if (converged(j, nev, exhausted, vectors, on_iteration))
          return true;
      }
      if (last)
        return false;
      if (breakdown)
      {
        beta_[j] = 0.0;  // v.col(j + 1) is the fresh direction
        omega_.head(j + 1).setConstant(kEps);
        continue;
      }
      v_.col(j + 1) = w / beta_[j];
    }
    return false;
  }

private:
  static constexpr double kEps = std::numeric_limits<double>::epsilon();

  // A random unit vector in the operator's complement, orthogonal to v.leftCols(cols), into
  // v.col(cols); false when nothing is left (the Krylov spaces so far fill the complement).
  bool fresh(int cols)
  {
    Eigen::VectorXd x(n_);
    for (int i = 0; i < n_; ++i)
      x[i] = normal_(random_);
    op_.project(x);
    const double before = x.norm();
    for (int pass = 0; pass < 2 && cols > 0; ++pass)
      x -= v_.leftCols(cols) * (v_.leftCols(cols).transpose() * x);
    if (x.norm() <= 1e-8 * before)
      return false;
    v_.col(cols) = x / x.norm();
    return true;
  }

  // w <- B v_j made orthogonal to v_j and v_{j-1}: alpha_j, beta_j and the estimate of |B|.
  void lanczosStep(int j, Eigen::VectorXd& w)
  {
    op_.perform_op(v_.col(j).data(), w.data());
    if (j > 0)
      w -= beta_[j - 1] * v_.col(j - 1);
    alpha_[j] = v_.col(j).dot(w);
    w -= alpha_[j] * v_.col(j);
    const double local = v_.col(j).dot(w);  // once more against v_j: the recurrence assumes it exact
    w -= local * v_.col(j);
    alpha_[j] += local;
    beta_[j] = w.norm();
    norm_estimate_ = std::max(norm_estimate_, std::abs(alpha_[j]) + beta_[j] + (j > 0 ? beta_[j - 1] : 0.0));
  }

  // Simon's recurrence for omega_{j+1, k}, with a rounding term of the size of eps ||B||; where the
  // estimated loss passes sqrt(eps), w is reorthogonalised (and the next vector too).
  void keepSemiOrthogonal(int j, Eigen::VectorXd& w)
  {
    Eigen::VectorXd omega_next = Eigen::VectorXd::Zero(m_ + 1);
    if (beta_[j] > 0.0)
      for (int k = 0; k < j; ++k)
      {
        double next = beta_[k] * omega_[k + 1] + (alpha_[k] - alpha_[j]) * omega_[k] +
                      (k > 0 ? beta_[k - 1] * omega_[k - 1] : 0.0) - beta_[j - 1] * omega_previous_[k];
        next += std::copysign(kEps * norm_estimate_, next);
        omega_next[k] = next / beta_[j];
      }
    omega_next[j] = kEps * norm_estimate_ / std::max(beta_[j], kEps * norm_estimate_);
    omega_next[j + 1] = 1.0;
    const bool lost = j > 0 && omega_next.head(j).cwiseAbs().maxCoeff() > std::sqrt(kEps);
    if ((lost || reorthogonalise_next_) && j + 1 < n_)
    {
      // Both this vector and the next, as Simon prescribes: the next inherits the error otherwise,
      // against the same runs (and the newest vector).
      if (lost)
        findRuns(omega_next, j + 1);
      else
        runs_.emplace_back(j, j + 1);
      reorthogonalise(w, omega_next);
      beta_[j] = w.norm();
      reorthogonalise_next_ = lost;
    }
    omega_previous_ = omega_;
    omega_ = omega_next;
  }

  // The runs of earlier vectors whose estimated overlap passed eps^(3/4) (Larsen's refinement of
  // Simon's scheme: the rest are orthogonal enough already), widened by one on each side.
  void findRuns(const Eigen::VectorXd& overlap, int cols)
  {
    const double eta = std::pow(kEps, 0.75);
    runs_.clear();
    for (int k = 0; k < cols;)
    {
      if (std::abs(overlap[k]) <= eta)
      {
        ++k;
        continue;
      }
      int last = k;
      while (last < cols && std::abs(overlap[last]) > eta)
        ++last;
      runs_.emplace_back(std::max(0, k - 1), std::min(cols, last + 1));
      k = last;
    }
  }

  void reorthogonalise(Eigen::VectorXd& w, Eigen::VectorXd& overlap)
  {
    for (const auto& run : runs_)
    {
      const auto block = v_.middleCols(run.first, run.second - run.first);
      w -= block * (block.transpose() * w);
      overlap.segment(run.first, run.second - run.first).setConstant(kEps);
    }
  }

  // Whether the nev largest Ritz values of the tridiagonal matrix after step j have converged (a
  // residual estimate beta_j |last entry| below kTolerance of the value); if so, their Ritz vectors.
  bool converged(int j, int nev, bool exhausted, Eigen::MatrixXd& vectors, const IterationFn& on_iteration)
  {
    Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> ritz;
    ritz.computeFromTridiagonal(alpha_.head(j + 1), beta_.head(j), Eigen::ComputeEigenvectors);
    // Ascending: the wanted (largest) ones are the last columns.
    double worst = 0.0;  // the largest residual estimate relative to its Ritz value
    for (int i = j + 1 - nev; i <= j && !exhausted; ++i)
      worst = std::max(worst, beta_[j] * std::abs(ritz.eigenvectors()(j, i)) /
                                  std::max(std::abs(ritz.eigenvalues()[i]), 1e-11));
    if (on_iteration)
      on_iteration("eigensolver", j + 1, worst, kTolerance);
    if (worst > kTolerance)
      return false;
    vectors = v_.leftCols(j + 1) * ritz.eigenvectors().rightCols(nev);
    return true;
  }

  const ShiftInvert& op_;
  const int n_, m_;
  Eigen::MatrixXd v_;  // the Lanczos vectors
  Eigen::VectorXd alpha_, beta_;
  // omega_[k] estimates v_j . v_k for the newest vector j, omega_previous_ for j - 1.
  Eigen::VectorXd omega_, omega_previous_;
  double norm_estimate_ = 0.0;  // of B, from the tridiagonal matrix so far
  std::vector<std::pair<int, int>> runs_;  // [first, last)
  bool reorthogonalise_next_ = false;
  std::mt19937_64 random_{1};  // fixed: the same basis for the same matrices
  std::normal_distribution<double> normal_;
};

bool partialLanczos(const ShiftInvert& op, int nev, int max_steps, Eigen::MatrixXd& vectors,
                    const IterationFn& on_iteration)
{
  return PartialLanczos(op, max_steps).run(nev, vectors, on_iteration);
}

// Rayleigh-Ritz: the r lowest eigenpairs of A within the span of `vectors`.
void rayleighRitz(const SparseMatrix& a, int r, Eigen::VectorXd& values, Eigen::MatrixXd& vectors)
{
  const Eigen::HouseholderQR<Eigen::MatrixXd> qr(vectors);
  const Eigen::MatrixXd q = qr.householderQ() * Eigen::MatrixXd::Identity(vectors.rows(), vectors.cols());
  const Eigen::MatrixXd projected = q.transpose() * (a * q);
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> small(0.5 * (projected + projected.transpose()));
  values = small.eigenvalues().head(r);
  vectors = q * small.eigenvectors().leftCols(r);
}

// Rayleigh-Ritz for vectors Y already orthonormal to about sqrt(eps) (Ritz vectors of semi-orthogonal
// Lanczos vectors): made orthonormal by a Cholesky QR, Y R^-1 with R^T R = Y^T Y, half the cost of a
// Householder QR, and rotated to the eigenvectors of A within their span, which undoes the mixing
// the orthonormalisation brings. Both happen in the small space: the eigenvectors E of
// R^-T (Y^T A Y) R^-1 give Y (R^-1 E), one product with the tall Y. Householder when the Cholesky QR
// cannot.
void orthonormalRayleighRitz(const SparseMatrix& a, Eigen::VectorXd& values, Eigen::MatrixXd& vectors)
{
  const Eigen::Index r = vectors.cols();
  Eigen::MatrixXd gram = Eigen::MatrixXd::Zero(r, r);
  gram.selfadjointView<Eigen::Lower>().rankUpdate(vectors.transpose());
  const Eigen::LLT<Eigen::MatrixXd> llt(gram);
  if (llt.info() != Eigen::Success)
  {
    rayleighRitz(a, static_cast<int>(r), values, vectors);
    return;
  }
  // A times a row-major copy: each entry of A then scales one contiguous row, twice as fast.
  const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> rows = vectors;
  const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> a_rows = a * rows;
  Eigen::MatrixXd projected = vectors.transpose() * a_rows;
  llt.matrixL().solveInPlace(projected);                           // R^-T (Y^T A Y)
  llt.matrixU().solveInPlace<Eigen::OnTheRight>(projected);        // ... R^-1
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> small(0.5 * (projected + projected.transpose()));
  values = small.eigenvalues();
  Eigen::MatrixXd rotation = small.eigenvectors();
  llt.matrixU().solveInPlace(rotation);                             // R^-1 E
  vectors = vectors * rotation;
}

// The nev eigenpairs of A nearest sigma in the complement the operator is deflated to: Lanczos with
// partial reorthogonalisation; Spectra's restarted Lanczos (full reorthogonalisation, a bounded
// space) when that has not converged within maxLanczosVectors(nev) - 1 steps.
void lanczos(const SparseMatrix& a, ShiftInvert& op, int nev, double sigma, Eigen::VectorXd& values,
             Eigen::MatrixXd& vectors, const IterationFn& on_iteration)
{
  if (partialLanczos(op, nev, maxLanczosVectors(nev) - 1, vectors, on_iteration))
  {
    orthonormalRayleighRitz(a, values, vectors);
    return;
  }
  const int n = static_cast<int>(op.rows());
  const int ncv = std::min(n, std::max(2 * nev + 1, nev + 20));
  Spectra::SymEigsShiftSolver<ShiftInvert> solver(op, nev, ncv, sigma);
  solver.init();
  solver.compute(Spectra::SortRule::LargestMagn, 1000, kTolerance);
  if (solver.info() != Spectra::CompInfo::Successful)
    throw std::runtime_error("modal basis: the eigensolver did not converge for " + std::to_string(nev) +
                             " modes of " + std::to_string(n) + " free degrees of freedom");
  values = solver.eigenvalues();
  vectors = solver.eigenvectors();
}

// A Krylov space holds one vector per eigenvalue, so a null space larger than a few vectors (a flat
// 3D sheet at rest has one zero mode per free particle) is found only in part, and modes above zero
// slip in. Looks again in the complement of what was found until nothing lower turns up, then keeps
// the r lowest of everything by Rayleigh-Ritz; returns how many passes it took.
int deflateNullSpace(const SparseMatrix& a, ShiftInvert& op, int r, double shift, double zero_tolerance,
                     Eigen::VectorXd& values, Eigen::MatrixXd& vectors, const IterationFn& on_iteration)
{
  const int n = static_cast<int>(a.rows());
  int passes = 0;
  const int zeros = static_cast<int>((values.array().abs() < zero_tolerance).count());
  for (int pass = 0; zeros > 0 && zeros < r && pass < 20 && vectors.cols() + r + 1 < n; ++pass)
  {
    const double highest = values.maxCoeff();
    op.deflate(Eigen::HouseholderQR<Eigen::MatrixXd>(vectors).householderQ() *
               Eigen::MatrixXd::Identity(n, vectors.cols()));
    Eigen::VectorXd more_values;
    Eigen::MatrixXd more_vectors;
    lanczos(a, op, r, shift, more_values, more_vectors, on_iteration);
    ++passes;
    if (more_values.minCoeff() >= highest - zero_tolerance)
      break;
    Eigen::MatrixXd all(n, vectors.cols() + more_vectors.cols());
    all << vectors, more_vectors;
    vectors = all;
    rayleighRitz(a, r, values, vectors);
  }
  return passes;
}

// The basis's r modes from the eigenpairs of A (u = M^-1/2 y), in ascending order, those below
// zero_tolerance counted as zero.
void fillBasis(const Eigen::VectorXd& values, const Eigen::MatrixXd& vectors, const Eigen::VectorXd& inv_sqrt_mass, int r,
               double zero_tolerance, ModalBasis& basis)
{
  const Eigen::Index n = vectors.rows();
  std::vector<int> order(r);
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(), [&](int i, int j) { return values[i] < values[j]; });
  basis.eigenvalues.resize(r);
  basis.frequencies.resize(r);
  basis.phi.resize(n, r);
  for (int k = 0; k < r; ++k)
  {
    double lambda2 = values[order[k]];
    if (std::abs(lambda2) < zero_tolerance)
    {
      lambda2 = 0.0;
      ++basis.num_zero_modes;
    }
    basis.eigenvalues[k] = lambda2;
    basis.frequencies[k] = std::sqrt(std::max(lambda2, 0.0));
    basis.phi.col(k) = inv_sqrt_mass.asDiagonal() * vectors.col(order[k]);
    // An eigenvector's sign is the eigensolver's accident; fixed here (its largest entry positive), so
    // the same matrices give the same basis whichever solver path ran.
    Eigen::Index largest = 0;
    basis.phi.col(k).cwiseAbs().maxCoeff(&largest);
    if (basis.phi(largest, k) < 0.0)
      basis.phi.col(k) *= -1.0;
  }
}

}  // namespace

ModalBasis computeModalBasis(const SparseMatrix& stiffness, const Eigen::VectorXd& mass, int r,
                             const StageFn& on_stage, const IterationFn& on_iteration)
{
  auto stage = [&](const std::string& name) {
    if (on_stage)
      on_stage(name);
  };
  const auto start = std::chrono::steady_clock::now();
  auto seconds = [&] { return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(); };
  const int n = static_cast<int>(stiffness.rows());
  if (r < 1 || r > n)
    throw std::invalid_argument("invalid parameter 'num_modes' = " + std::to_string(r) +
                                ": must be in [1, " + std::to_string(n) + "] (the number of free degrees of freedom)");

  // With diagonal M, K u = lambda^2 M u is the standard problem A y = lambda^2 y for
  // A = M^-1/2 K M^-1/2 and u = M^-1/2 y, which is then mass-normalised by construction.
  const Eigen::VectorXd inv_sqrt_mass = mass.cwiseSqrt().cwiseInverse();
  const SparseMatrix a = inv_sqrt_mass.asDiagonal() * stiffness * inv_sqrt_mass.asDiagonal();
  const double scale = a.diagonal().cwiseAbs().maxCoeff();

  ModalBasis basis;
  Eigen::VectorXd values;
  Eigen::MatrixXd vectors;
  const double zero_tolerance = 1e-8 * scale;
  if (r + 1 >= n)
  {
    // r = n or n - 1: Lanczos needs more vectors than the space has; the whole spectrum is wanted
    // anyway.
    basis.sparse = false;
    stage("eigensolver");
    const Eigen::MatrixXd dense_a = Eigen::MatrixXd(a);
    Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> dense(dense_a);
    values = dense.eigenvalues().head(r);
    vectors = dense.eigenvectors().leftCols(r);
  }
  else
  {
    // A negative shift keeps A - sigma I positive definite even when A has zero eigenvalues.
    basis.shift = -1e-4 * scale;
    stage("factorisation");
    ShiftInvert op(a, basis.shift);
    basis.factorization_seconds = seconds();
    stage("eigensolver");
    lanczos(a, op, r, basis.shift, values, vectors, on_iteration);
    basis.deflation_passes += deflateNullSpace(a, op, r, basis.shift, zero_tolerance, values, vectors, on_iteration);
  }

  fillBasis(values, vectors, inv_sqrt_mass, r, zero_tolerance, basis);
  basis.build_seconds = seconds();
  return basis;
}

}  // namespace modal_mass_spring
