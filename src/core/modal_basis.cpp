// Sparse shift-invert Lanczos (Spectra) over a sparse LDLT factorisation.
#include "modal_mass_spring/modal_basis.h"

#include <Eigen/Eigenvalues>
#include <Eigen/SparseCholesky>
#include <Spectra/SymEigsShiftSolver.h>

#include <algorithm>
#include <chrono>
#include <numeric>
#include <stdexcept>
#include <string>

namespace modal_mass_spring
{
namespace
{

// y = (A - sigma I)^-1 x for Spectra. Spectra's own SparseSymShiftSolve uses SparseLU; A - sigma I is
// symmetric positive definite here (sigma < 0, A semi-definite), so a simplicial LDLT is enough and
// several times faster.
class ShiftInvertLDLT
{
public:
  using Scalar = double;

  explicit ShiftInvertLDLT(const SparseMatrix& a) : a_(a) {}
  Eigen::Index rows() const { return a_.rows(); }
  Eigen::Index cols() const { return a_.cols(); }

  void set_shift(double sigma)
  {
    SparseMatrix identity(a_.rows(), a_.cols());
    identity.setIdentity();
    ldlt_.compute(a_ - sigma * identity);
    if (ldlt_.info() != Eigen::Success)
      throw std::runtime_error("modal basis: factorising K - sigma M failed (sigma = " + std::to_string(sigma) + ")");
  }

  void perform_op(const double* x_in, double* y_out) const
  {
    Eigen::Map<const Eigen::VectorXd> x(x_in, a_.rows());
    Eigen::Map<Eigen::VectorXd> y(y_out, a_.rows());
    y.noalias() = ldlt_.solve(x);
  }

private:
  const SparseMatrix& a_;
  Eigen::SimplicialLDLT<SparseMatrix> ldlt_;
};

}  // namespace

ModalBasis computeModalBasis(const SparseMatrix& stiffness, const Eigen::VectorXd& mass, int r)
{
  const auto start = std::chrono::steady_clock::now();
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
  const int ncv = std::min(n, std::max(2 * r + 1, r + 20));
  if (ncv <= r)
  {
    // r = n: Lanczos needs more vectors than the space has; the whole spectrum is wanted anyway.
    basis.sparse = false;
    const Eigen::MatrixXd dense_a = Eigen::MatrixXd(a);
    Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> dense(dense_a);
    values = dense.eigenvalues().head(r);
    vectors = dense.eigenvectors().leftCols(r);
  }
  else
  {
    // A negative shift keeps A - sigma I positive definite even when A has zero eigenvalues.
    basis.shift = -1e-4 * scale;
    ShiftInvertLDLT op(a);
    Spectra::SymEigsShiftSolver<ShiftInvertLDLT> solver(op, r, ncv, basis.shift);
    solver.init();
    solver.compute(Spectra::SortRule::LargestMagn, 1000, 1e-12);
    if (solver.info() != Spectra::CompInfo::Successful)
      throw std::runtime_error("modal basis: the eigensolver did not converge for " + std::to_string(r) +
                               " modes of " + std::to_string(n) + " free degrees of freedom");
    values = solver.eigenvalues();
    vectors = solver.eigenvectors();
  }

  std::vector<int> order(r);
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(), [&](int i, int j) { return values[i] < values[j]; });
  basis.eigenvalues.resize(r);
  basis.frequencies.resize(r);
  basis.phi.resize(n, r);
  const double zero_tolerance = 1e-8 * scale;
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
  basis.build_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return basis;
}

}  // namespace modal_mass_spring
