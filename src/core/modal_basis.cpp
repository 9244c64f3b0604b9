// Shift-invert Lanczos with partial reorthogonalisation (Spectra as a fallback) over a sparse LDLT
// factorisation solved by supernodes.
#include "modal_mass_spring/modal_basis.h"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/QR>
#include <Eigen/SparseCholesky>
#include <Spectra/SymEigsShiftSolver.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <random>
#include <cstddef>
#include <memory>
#include <numeric>
#include <stdexcept>
#include <string>
#include <vector>

namespace modal_mass_spring
{
namespace
{

// A Ritz value theta has converged when the estimate of its residual is below kTolerance |theta|
// (Spectra's and ARPACK's criterion).
constexpr double kTolerance = 1e-12;

// Eigen's sparse LDLT factor of A - sigma I (its ordering and numbers unchanged) regrouped into
// supernodes for the solves: runs of columns whose rows below the diagonal are the same, each kept as
// a dense block with one list of row indices. Eigen's own solve reads a row index with every entry of
// L; here the index list is read once per supernode and the entries are contiguous, which matters
// because the solves, memory-bound, are most of the basis's time (about 1.8x faster per solve on a
// 100 x 100 2D grid, where the columns come in pairs or wider).
class SupernodalSolve
{
public:
  explicit SupernodalSolve(const Eigen::SimplicialLDLT<SparseMatrix>& ldlt)
    : n_(static_cast<int>(ldlt.rows())), d_(ldlt.vectorD()), p_(ldlt.permutationP()), p_inverse_(ldlt.permutationPinv())
  {
    const SparseMatrix& l = ldlt.matrixL().nestedExpression();  // strictly lower, unit diagonal implied
    const int* start = l.outerIndexPtr();
    const int* row = l.innerIndexPtr();
    const double* value = l.valuePtr();
    // Column j joins the supernode of column j - 1 when column j - 1 holds exactly row j and the rows of
    // column j below it.
    auto continues = [&](int j) {
      const int previous = start[j] - start[j - 1];
      const int count = start[j + 1] - start[j];
      return previous == count + 1 && row[start[j - 1]] == j &&
             std::equal(row + start[j], row + start[j + 1], row + start[j - 1] + 1);
    };
    rows_.reserve(l.nonZeros());
    values_.reserve(l.nonZeros() + l.nonZeros() / 4);  // and the triangles' upper halves, zero
    for (int first = 0; first < n_;)
    {
      int last = first;
      while (last + 1 < n_ && continues(last + 1))
        ++last;
      Supernode s;
      s.first = first;
      s.width = last - first + 1;
      s.rows = static_cast<int>(rows_.size());
      s.height = start[last + 1] - start[last];
      s.values = static_cast<std::ptrdiff_t>(values_.size());
      rows_.insert(rows_.end(), row + start[last], row + start[last + 1]);
      // Row-major: the strictly lower width x width triangle, then the height x width block below.
      values_.resize(values_.size() + static_cast<std::size_t>(s.width) * (s.width + s.height), 0.0);
      double* triangle = values_.data() + s.values;
      double* below = triangle + s.width * s.width;
      for (int c = 0; c < s.width; ++c)
      {
        const int column = first + c;
        const int inside = last - column;  // entries of this column within the supernode's triangle
        for (int k = 0; k < inside; ++k)
          triangle[(c + 1 + k) * s.width + c] = value[start[column] + k];
        for (int k = 0; k < s.height; ++k)
          below[k * s.width + c] = value[start[column] + inside + k];
      }
      supernodes_.push_back(s);
      first = last + 1;
    }
  }

  // x <- (L D L^T)^-1 x with the factor's permutation.
  void solveInPlace(Eigen::Ref<Eigen::VectorXd> x) const
  {
    work_ = p_ * x;
    double* y = work_.data();
    for (const Supernode& s : supernodes_)  // L z = y
    {
      double* ys = y + s.first;
      const double* triangle = values_.data() + s.values;
      const double* below = triangle + s.width * s.width;
      const int* rows = rows_.data() + s.rows;
      for (int i = 1; i < s.width; ++i)
      {
        double sum = ys[i];
        for (int c = 0; c < i; ++c)
          sum -= triangle[i * s.width + c] * ys[c];
        ys[i] = sum;
      }
      if (s.width == 1)
        for (int k = 0; k < s.height; ++k)
          y[rows[k]] -= below[k] * ys[0];
      else if (s.width == 2)
        for (int k = 0; k < s.height; ++k)
          y[rows[k]] -= below[2 * k] * ys[0] + below[2 * k + 1] * ys[1];
      else
        for (int k = 0; k < s.height; ++k)
        {
          const double* entries = below + static_cast<std::ptrdiff_t>(k) * s.width;
          double sum = 0.0;
          for (int c = 0; c < s.width; ++c)
            sum += entries[c] * ys[c];
          y[rows[k]] -= sum;
        }
    }
    work_.array() /= d_.array();
    for (auto s = supernodes_.rbegin(); s != supernodes_.rend(); ++s)  // L^T z = y
    {
      double* ys = y + s->first;
      const double* triangle = values_.data() + s->values;
      const double* below = triangle + s->width * s->width;
      const int* rows = rows_.data() + s->rows;
      if (s->width == 1)
      {
        double sum = ys[0];
        for (int k = 0; k < s->height; ++k)
          sum -= below[k] * y[rows[k]];
        ys[0] = sum;
      }
      else if (s->width == 2)
      {
        double sum0 = ys[0], sum1 = ys[1];
        for (int k = 0; k < s->height; ++k)
        {
          const double yk = y[rows[k]];
          sum0 -= below[2 * k] * yk;
          sum1 -= below[2 * k + 1] * yk;
        }
        ys[0] = sum0;
        ys[1] = sum1;
      }
      else
        for (int k = 0; k < s->height; ++k)
        {
          const double* entries = below + static_cast<std::ptrdiff_t>(k) * s->width;
          const double yk = y[rows[k]];
          for (int c = 0; c < s->width; ++c)
            ys[c] -= entries[c] * yk;
        }
      for (int i = s->width - 1; i >= 1; --i)
        for (int c = 0; c < i; ++c)
          ys[c] -= triangle[i * s->width + c] * ys[i];
    }
    x = p_inverse_ * work_;
  }

private:
  struct Supernode
  {
    int first;   // its columns are first .. first + width - 1
    int width;
    int rows;    // offset in rows_ of the rows below it
    int height;  // how many rows below it
    std::ptrdiff_t values;  // offset in values_
  };
  int n_;
  Eigen::VectorXd d_;
  Eigen::PermutationMatrix<Eigen::Dynamic, Eigen::Dynamic, int> p_, p_inverse_;
  std::vector<Supernode> supernodes_;
  std::vector<int> rows_;
  std::vector<double> values_;
  mutable Eigen::VectorXd work_;
};

// y = P (A - sigma I)^-1 P x, P = I - Q Q^T the projector onto the complement of the
// modes found so far (none at first). Spectra's own SparseSymShiftSolve uses SparseLU; A - sigma I is
// symmetric positive definite here (sigma < 0, A semi-definite), so a simplicial LDLT is enough and
// several times faster. It is factorised once and reused by every deflated pass.
class ShiftInvertLDLT
{
public:
  using Scalar = double;

  ShiftInvertLDLT(const SparseMatrix& a, double sigma) : n_(a.rows())
  {
    SparseMatrix identity(a.rows(), a.cols());
    identity.setIdentity();
    Eigen::SimplicialLDLT<SparseMatrix> ldlt(a - sigma * identity);
    if (ldlt.info() != Eigen::Success)
      throw std::runtime_error("modal basis: factorising K - sigma M failed (sigma = " + std::to_string(sigma) + ")");
    solve_ = std::make_shared<const SupernodalSolve>(ldlt);
  }
  Eigen::Index rows() const { return n_; }
  Eigen::Index cols() const { return n_; }
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
    if (q_.cols() == 0)
    {
      y = x;
      solve_->solveInPlace(y);
      return;
    }
    y = x - q_ * (q_.transpose() * x);
    solve_->solveInPlace(y);
    y -= q_ * (q_.transpose() * y);
  }

private:
  Eigen::Index n_;
  std::shared_ptr<const SupernodalSolve> solve_;  // shared: Spectra may copy the operator
  Eigen::MatrixXd q_;
};

// Lanczos without restarts and with partial reorthogonalisation (Simon 1984): the Ritz vectors of the
// nev largest eigenvalues of the operator B, or false when max_steps were not enough. Reorthogonalising
// against every earlier Lanczos vector at every step (Spectra's way) costs nearly as much as the solves
// on a 100 x 100 grid; here Simon's recurrence estimates the loss of orthogonality and the vectors are
// reorthogonalised only when it passes sqrt(eps) (every third step there), which keeps them
// semi-orthogonal: enough for Ritz values to working precision. The Ritz vectors are orthonormalised
// afterwards.
bool partialLanczos(const ShiftInvertLDLT& op, int nev, int max_steps, Eigen::MatrixXd& vectors)
{
  const int n = static_cast<int>(op.rows());
  const int m = std::min(n, max_steps);
  const double eps = std::numeric_limits<double>::epsilon();
  const double limit = std::sqrt(eps);
  Eigen::MatrixXd v(n, m + 1);
  Eigen::VectorXd alpha = Eigen::VectorXd::Zero(m), beta = Eigen::VectorXd::Zero(m);
  // omega[k] estimates v_j . v_k for the newest vector j, omega_previous for j - 1.
  Eigen::VectorXd omega = Eigen::VectorXd::Zero(m + 1), omega_previous = Eigen::VectorXd::Zero(m + 1);
  std::mt19937_64 random(1);  // fixed: the same basis for the same matrices
  std::normal_distribution<double> normal;

  // A random unit vector in the operator's complement, orthogonal to v.leftCols(cols), into
  // v.col(cols); false when nothing is left (the Krylov spaces so far fill the complement).
  auto fresh = [&](int cols) {
    Eigen::VectorXd x(n);
    for (int i = 0; i < n; ++i)
      x[i] = normal(random);
    op.project(x);
    const double before = x.norm();
    for (int pass = 0; pass < 2 && cols > 0; ++pass)
      x -= v.leftCols(cols) * (v.leftCols(cols).transpose() * x);
    if (x.norm() <= 1e-8 * before)
      return false;
    v.col(cols) = x / x.norm();
    return true;
  };
  auto reorthogonalise = [&](Eigen::VectorXd& w, int cols) {
    w -= v.leftCols(cols) * (v.leftCols(cols).transpose() * w);
  };

  if (!fresh(0))
    return false;
  omega[0] = 1.0;
  bool reorthogonalise_next = false;

  double norm_estimate = 0.0;  // of B, from the tridiagonal matrix so far
  Eigen::VectorXd w(n);
  for (int j = 0; j < m; ++j)
  {
    op.perform_op(v.col(j).data(), w.data());
    if (j > 0)
      w -= beta[j - 1] * v.col(j - 1);
    alpha[j] = v.col(j).dot(w);
    w -= alpha[j] * v.col(j);
    const double local = v.col(j).dot(w);  // once more against v_j: the recurrence assumes it exact
    w -= local * v.col(j);
    alpha[j] += local;
    beta[j] = w.norm();
    norm_estimate = std::max(norm_estimate, std::abs(alpha[j]) + beta[j] + (j > 0 ? beta[j - 1] : 0.0));

    // Simon's recurrence for omega_{j+1, k}, with a rounding term of the size of eps ||B||.
    Eigen::VectorXd omega_next = Eigen::VectorXd::Zero(m + 1);
    if (beta[j] > 0.0)
      for (int k = 0; k < j; ++k)
      {
        double next = beta[k] * omega[k + 1] + (alpha[k] - alpha[j]) * omega[k] +
                      (k > 0 ? beta[k - 1] * omega[k - 1] : 0.0) - beta[j - 1] * omega_previous[k];
        next += std::copysign(eps * norm_estimate, next);
        omega_next[k] = next / beta[j];
      }
    omega_next[j] = eps * norm_estimate / std::max(beta[j], eps * norm_estimate);
    omega_next[j + 1] = 1.0;
    const bool lost = omega_next.head(j).cwiseAbs().maxCoeff() > limit;
    if ((lost || reorthogonalise_next) && j + 1 < n)
    {
      // Both this vector and the next, as Simon prescribes: the next inherits the error otherwise.
      reorthogonalise(w, j + 1);
      omega_next.head(j + 1).setConstant(eps);
      beta[j] = w.norm();
      reorthogonalise_next = lost;
    }
    omega_previous = omega;
    omega = omega_next;

    // A breakdown (an invariant subspace) goes on from a new direction, uncoupled (beta_j = 0): one
    // more copy of a repeated eigenvalue each time. When none is left, the Ritz pairs are exact.
    const bool breakdown = beta[j] <= 1e-12 * norm_estimate;
    const bool exhausted = j + 1 == n || (breakdown && !fresh(j + 1));
    const bool last = j + 1 == m || exhausted;
    // When the steps may fill the whole space, only the end is looked at: stopping early could miss
    // copies of a repeated eigenvalue that later breakdowns would find.
    if (j + 1 >= nev && (last || (m < n && (j + 1 - nev) % 2 == 0)))
    {
      Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> ritz;
      if (breakdown)
        beta[j] = 0.0;
      ritz.computeFromTridiagonal(alpha.head(j + 1), beta.head(j), Eigen::ComputeEigenvectors);
      // Ascending: the wanted (largest) ones are the last columns; residual beta_j |last entry|.
      bool converged = true;
      for (int i = j + 1 - nev; i <= j && converged && !exhausted; ++i)
        converged = beta[j] * std::abs(ritz.eigenvectors()(j, i)) <=
                    kTolerance * std::max(std::abs(ritz.eigenvalues()[i]), 1e-11);
      if (converged)
      {
        vectors = v.leftCols(j + 1) * ritz.eigenvectors().rightCols(nev);
        return true;
      }
    }
    if (last)
      return false;
    if (breakdown)
    {
      beta[j] = 0.0;  // v.col(j + 1) is the fresh direction
      omega.head(j + 1).setConstant(eps);
      continue;
    }
    v.col(j + 1) = w / beta[j];
  }
  return false;
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

// Rayleigh-Ritz for vectors already orthonormal to about sqrt(eps) (Ritz vectors of semi-orthogonal
// Lanczos vectors): made orthonormal by a Cholesky QR, half the cost of a Householder QR, and
// rotated to the eigenvectors of A within their span, which undoes the mixing the orthonormalisation
// brings. Householder when the Cholesky QR cannot.
void orthonormalRayleighRitz(const SparseMatrix& a, Eigen::VectorXd& values, Eigen::MatrixXd& vectors)
{
  Eigen::MatrixXd gram = Eigen::MatrixXd::Zero(vectors.cols(), vectors.cols());
  gram.selfadjointView<Eigen::Lower>().rankUpdate(vectors.transpose());
  const Eigen::LLT<Eigen::MatrixXd> llt(gram);
  if (llt.info() != Eigen::Success)
  {
    rayleighRitz(a, static_cast<int>(vectors.cols()), values, vectors);
    return;
  }
  llt.matrixU().solveInPlace<Eigen::OnTheRight>(vectors);
  const Eigen::MatrixXd projected = vectors.transpose() * (a * vectors);
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> small(0.5 * (projected + projected.transpose()));
  values = small.eigenvalues();
  vectors = vectors * small.eigenvectors();
}

// The nev eigenpairs of A nearest sigma in the complement the operator is deflated to: Lanczos with
// partial reorthogonalisation; Spectra's restarted Lanczos (full reorthogonalisation, a bounded
// space) when that has not converged within maxLanczosVectors(nev) - 1 steps.
void lanczos(const SparseMatrix& a, ShiftInvertLDLT& op, int nev, double sigma, Eigen::VectorXd& values,
             Eigen::MatrixXd& vectors)
{
  if (partialLanczos(op, nev, maxLanczosVectors(nev) - 1, vectors))
  {
    orthonormalRayleighRitz(a, values, vectors);
    return;
  }
  const int n = static_cast<int>(op.rows());
  const int ncv = std::min(n, std::max(2 * nev + 1, nev + 20));
  Spectra::SymEigsShiftSolver<ShiftInvertLDLT> solver(op, nev, ncv, sigma);
  solver.init();
  solver.compute(Spectra::SortRule::LargestMagn, 1000, kTolerance);
  if (solver.info() != Spectra::CompInfo::Successful)
    throw std::runtime_error("modal basis: the eigensolver did not converge for " + std::to_string(nev) +
                             " modes of " + std::to_string(n) + " free degrees of freedom");
  values = solver.eigenvalues();
  vectors = solver.eigenvectors();
}

}  // namespace

ModalBasis computeModalBasis(const SparseMatrix& stiffness, const Eigen::VectorXd& mass, int r,
                             const StageFn& on_stage)
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
    ShiftInvertLDLT op(a, basis.shift);
    basis.factorization_seconds = seconds();
    stage("eigensolver");
    lanczos(a, op, r, basis.shift, values, vectors);
    // A Krylov space holds one vector per eigenvalue, so a null space larger than a few vectors (a
    // flat 3D sheet at rest has one zero mode per free particle) is found only in part, and modes
    // above zero slip in. Look again in the complement of what was found until nothing lower turns
    // up, then keep the r lowest of everything by Rayleigh-Ritz.
    const int zeros = static_cast<int>((values.array().abs() < zero_tolerance).count());
    for (int pass = 0; zeros > 0 && zeros < r && pass < 20 && vectors.cols() + r + 1 < n; ++pass)
    {
      const double highest = values.maxCoeff();
      op.deflate(Eigen::HouseholderQR<Eigen::MatrixXd>(vectors).householderQ() *
                 Eigen::MatrixXd::Identity(n, vectors.cols()));
      Eigen::VectorXd more_values;
      Eigen::MatrixXd more_vectors;
      lanczos(a, op, r, basis.shift, more_values, more_vectors);
      ++basis.deflation_passes;
      if (more_values.minCoeff() >= highest - zero_tolerance)
        break;
      Eigen::MatrixXd all(n, vectors.cols() + more_vectors.cols());
      all << vectors, more_vectors;
      vectors = all;
      rayleighRitz(a, r, values, vectors);
    }
  }

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
  basis.build_seconds = seconds();
  return basis;
}

}  // namespace modal_mass_spring
