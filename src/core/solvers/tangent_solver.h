// The linear solves of Newton's method on symmetric tangents: J x = b with J = M / (beta h^2) + ... + K
// (implicit steps) or K (the static equilibrium), sparse, positive definite where the method can use
// it.
#pragma once

#include "modal_mass_spring/spring_forces.h"
#include "solvers/sparse_cholesky.h"

#include <Eigen/Core>

#include <functional>
#include <memory>
#include <vector>

namespace modal_mass_spring
{

// How J x = b is solved: the kinds the core uses (other kinds, measured side by side on swinging
// cloths, are the benchmark's own: docs/benchmarks.md).
enum class TangentSolverKind
{
  SimplicialLdlt,  // Eigen's simplicial LDL^T, refactorised for every J (one column at a time)
  Cholmod,         // CHOLMOD's supernodal Cholesky (SparseCholesky), analysed once, refactorised for every J
  BlockJacobiCg,   // conjugate gradients preconditioned by J's diagonal blocks (a particle's dofs)
};

// One J after another. A direct kind solves exactly; a conjugate gradient kind stops once the
// residual |b - J x| is below the tolerance given, and falls back on factorising J (CHOLMOD) where it
// does not get there within its iterations or finds J not positive definite. A benchmark derives its
// own kinds (solve() and the protected conjugate gradients).
class TangentSolver
{
public:
  explicit TangentSolver(TangentSolverKind kind);
  virtual ~TangentSolver();
  TangentSolver(TangentSolver&&) noexcept;
  TangentSolver& operator=(TangentSolver&&) noexcept;

  // x <- J^-1 b, |b - J x| <= tolerance (direct kinds: exact to round-off). False, x undefined, when J
  // is not positive definite (or not finite).
  virtual bool solve(const SparseMatrix& j, const Eigen::VectorXd& b, Eigen::VectorXd& x, double tolerance);
  // The same by conjugate gradients preconditioned by J's diagonal blocks (block size as set) with J
  // given only as its product jp <- J p and those blocks (block_size^2 values a block, column-major),
  // never assembled. False where a block or J is not positive definite or CG does not converge in
  // its iterations: the caller then assembles J for solve(), which can factorise it.
  bool solveMatrixFree(const std::function<void(const Eigen::VectorXd&, Eigen::VectorXd&)>& multiply,
                       const Eigen::VectorXd& diagonal_blocks, const Eigen::VectorXd& b, Eigen::VectorXd& x,
                       double tolerance);
  // x <- J^-1 b with the factor of the J that solve() last factorised (iterative refinement: no new
  // factorisation); false when there is none or it failed.
  bool solveWithFactor(const Eigen::VectorXd& b, Eigen::VectorXd& x);
  // The next J is far from the earlier ones (another step size): factorise it rather than iterate.
  void forgetFactor() { factor_current_ = false; }
  TangentSolverKind kind() const { return kind_; }
  // The dofs come in groups of this many consecutive ones (a particle's coordinates): the blocks that
  // BlockJacobiCg inverts. 1 (scalar Jacobi) unless set, or where it does not divide J's size.
  void setBlockSize(int block_size) { block_size_ = block_size; }
  // Counters since construction: factorisations, conjugate gradient iterations.
  long factorisations() const { return factorisations_; }
  long cgIterations() const { return cg_iterations_; }

  class Factor;  // a sparse Cholesky factorisation (one per direct kind)

protected:
  // Conjugate gradients from x = 0, preconditioned by `precondition` (z <- P^-1 r); false when they
  // meet a direction of non-positive curvature or stop after max_iterations.
  // jp <- J p by `multiply`.
  template <typename Multiply, typename Precondition>
  bool conjugateGradients(Multiply multiply, const Eigen::VectorXd& b, Eigen::VectorXd& x, double tolerance,
                          int max_iterations, Precondition precondition);
  // Conjugate gradients preconditioned by J's diagonal; false where they do not reach `tolerance`
  // within kMaxJacobiIterations (then the factor).
  bool diagonalJacobi(const SparseMatrix& j, const Eigen::VectorXd& b, Eigen::VectorXd& x, double tolerance);
  // Whether solve() holds the factor of a J still usable (solveWithFactor).
  bool hasFactor() const { return factor_current_; }
  // A diagonal preconditioner leaves J's condition number to the square of the grid's size: cap the
  // iterations there.
  static constexpr int kMaxJacobiIterations = 2000;
  long factorisations_ = 0, cg_iterations_ = 0;

private:
  int blockSize(Eigen::Index size) const;

  // inverse_blocks_ <- J's diagonal blocks, block_size^2 values a block (column-major).
  template <int Size>
  void diagonalBlocks(const SparseMatrix& j);
  // inverse_blocks_ <- the inverses of the blocks it holds; false where one of them is not positive
  // definite.
  template <int Size>
  bool invertBlocks();
  // CG preconditioned by inverse_blocks_ once it holds J's blocks.
  template <typename Multiply>
  bool blockJacobi(Multiply multiply, int block_size, const Eigen::VectorXd& b, Eigen::VectorXd& x, double tolerance);
  template <int Size>
  void applyInverseBlocks(Eigen::VectorXd& v) const;

  TangentSolverKind kind_;
  std::unique_ptr<Factor> factor_;
  bool factor_current_ = false;  // the factor is of a J still usable as a preconditioner
  int block_size_ = 1;
  Eigen::VectorXd r_, z_, p_, jp_, inverse_diagonal_, inverse_blocks_;
};

template <typename Multiply, typename Precondition>
bool TangentSolver::conjugateGradients(Multiply multiply, const Eigen::VectorXd& b, Eigen::VectorXd& x,
                                       double tolerance, int max_iterations, Precondition precondition)
{
  x.setZero(b.size());
  r_ = b;
  z_ = r_;
  precondition(z_);
  p_ = z_;
  double rz = r_.dot(z_);
  for (int iteration = 0; iteration < max_iterations; ++iteration)
  {
    if (r_.norm() <= tolerance)
      return true;
    ++cg_iterations_;
    multiply(p_, jp_);
    const double curvature = p_.dot(jp_);
    if (!(curvature > 0.0))
      return false;
    const double step = rz / curvature;
    x += step * p_;
    r_ -= step * jp_;
    z_ = r_;
    precondition(z_);
    const double rz_next = r_.dot(z_);
    p_ = z_ + (rz_next / rz) * p_;
    rz = rz_next;
  }
  return r_.norm() <= tolerance;
}

}  // namespace modal_mass_spring
