// The linear solves of Newton's method on symmetric tangents: J x = b with J = M / (beta h^2) + ... + K
// (implicit steps) or K (the static equilibrium), sparse, positive definite where the method can use
// it.
#pragma once

#include "modal_mass_spring/spring_forces.h"

#include <Eigen/Core>

#include <functional>
#include <memory>
#include <vector>

namespace modal_mass_spring
{

// The sparsity pattern a factorisation was analysed for, so that it is analysed again only when the
// pattern changes.
struct SparsityPattern
{
  std::vector<int> outer, inner;
  // True, and `m`'s pattern recorded, when it differs from the one recorded.
  bool changedTo(const SparseMatrix& m);
};

// How J x = b is solved. Measured side by side on swinging cloths (docs/benchmarks.md); the default is
// the fastest of them that converges each step to the same tolerance.
enum class TangentSolverKind
{
  SimplicialLdlt,     // Eigen's simplicial LDL^T, refactorised for every J (one column at a time)
  Cholmod,            // CHOLMOD's supernodal Cholesky (BLAS), analysed once, refactorised for every J
  Supernodal,         // this package's supernodal Cholesky (SupernodalCholesky), built for every J
  JacobiCg,           // conjugate gradients preconditioned by J's diagonal
  CholmodCg,          // conjugate gradients preconditioned by the CHOLMOD factor of an earlier J
  BlockJacobiCg,      // conjugate gradients preconditioned by J's diagonal blocks (a particle's dofs)
};

// One J after another. A direct kind solves exactly; a conjugate gradient kind stops once the
// residual |b - J x| is below the tolerance given, and falls back on factorising J (and keeping that
// factor as the preconditioner of the next ones) where it does not get there in a few iterations or
// finds J not positive definite.
class TangentSolver
{
public:
  explicit TangentSolver(TangentSolverKind kind);
  ~TangentSolver();
  TangentSolver(TangentSolver&&) noexcept;
  TangentSolver& operator=(TangentSolver&&) noexcept;

  // x <- J^-1 b, |b - J x| <= tolerance (direct kinds: exact to round-off). False, x undefined, when J
  // is not positive definite (or not finite).
  bool solve(const SparseMatrix& j, const Eigen::VectorXd& b, Eigen::VectorXd& x, double tolerance);
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

private:
  // Conjugate gradients from x = 0, preconditioned by `precondition` (z <- P^-1 r); false when they
  // meet a direction of non-positive curvature or stop after max_iterations.
  // jp <- J p by `multiply`.
  template <typename Multiply, typename Precondition>
  bool conjugateGradients(Multiply multiply, const Eigen::VectorXd& b, Eigen::VectorXd& x, double tolerance,
                          int max_iterations, Precondition precondition);
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
  long factorisations_ = 0, cg_iterations_ = 0;
  int block_size_ = 1;
  Eigen::VectorXd r_, z_, p_, jp_, inverse_diagonal_, inverse_blocks_;
};

}  // namespace modal_mass_spring
