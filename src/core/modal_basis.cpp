// Sparse shift-invert Lanczos (Spectra) over a sparse LDLT factorisation solved by supernodes.
#include "modal_mass_spring/modal_basis.h"

#include <Eigen/Eigenvalues>
#include <Eigen/QR>
#include <Eigen/SparseCholesky>
#include <Spectra/SymEigsShiftSolver.h>

#include <algorithm>
#include <chrono>
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

// y = P (A - sigma I)^-1 P x for Spectra, P = I - Q Q^T the projector onto the complement of the
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
  std::shared_ptr<const SupernodalSolve> solve_;  // shared: Spectra copies the operator
  Eigen::MatrixXd q_;
};

// The nev eigenpairs of A nearest sigma in the complement the operator is deflated to.
void lanczos(ShiftInvertLDLT& op, int nev, double sigma, Eigen::VectorXd& values, Eigen::MatrixXd& vectors)
{
  const int n = static_cast<int>(op.rows());
  const int ncv = std::min(n, std::max(2 * nev + 1, nev + 20));
  Spectra::SymEigsShiftSolver<ShiftInvertLDLT> solver(op, nev, ncv, sigma);
  solver.init();
  solver.compute(Spectra::SortRule::LargestMagn, 1000, 1e-12);
  if (solver.info() != Spectra::CompInfo::Successful)
    throw std::runtime_error("modal basis: the eigensolver did not converge for " + std::to_string(nev) +
                             " modes of " + std::to_string(n) + " free degrees of freedom");
  values = solver.eigenvalues();
  vectors = solver.eigenvectors();
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
    lanczos(op, r, basis.shift, values, vectors);
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
      lanczos(op, r, basis.shift, more_values, more_vectors);
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
  }
  basis.build_seconds = seconds();
  return basis;
}

}  // namespace modal_mass_spring
