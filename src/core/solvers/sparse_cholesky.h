// CHOLMOD's supernodal Cholesky factorisation of the modal basis and of Newton's tangents (internal).
#pragma once

#include "modal_mass_spring/spring_forces.h"

#include <Eigen/Core>

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

// P (A + shift I) P^T = L L^T for a symmetric positive definite A + shift I (its lower triangle is
// read), by CHOLMOD's supernodal factorisation over the system's BLAS on one thread; the ordering and
// symbolic analysis are done again only when A's sparsity pattern changes. Why CHOLMOD rather than a
// factorisation of the package's own: docs/design.md, "The modal basis".
class SparseCholesky
{
public:
  SparseCholesky();
  ~SparseCholesky();
  SparseCholesky(SparseCholesky&&) noexcept;
  SparseCholesky& operator=(SparseCholesky&&) noexcept;

  // False, and no factor, where A + shift I is not positive definite (or not finite): an answer, not
  // an error printed.
  bool factorise(const SparseMatrix& a, double shift = 0.0);
  // x <- (A + shift I)^-1 x with the last factor.
  void solveInPlace(Eigen::Ref<Eigen::VectorXd> x) const;
  // Values of L kept (the supernodes' dense blocks, their zero upper triangles included).
  long storedEntries() const;

private:
  struct Factor;
  std::unique_ptr<Factor> factor_;
};

}  // namespace modal_mass_spring
