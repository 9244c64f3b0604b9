// The supernodal Cholesky the modal basis factorised its shift-invert with until CHOLMOD over OpenBLAS
// replaced it, kept for benchmark/sparse_cholesky.cpp's comparison (docs/benchmarks.md, "Sparse Cholesky").
#pragma once

#include <Eigen/Core>
#include <Eigen/SparseCore>

#include <cstddef>
#include <vector>

namespace modal_mass_spring
{

// Sparse Cholesky factorisation P (A - sigma I) P^T = L L^T of a symmetric positive definite A - sigma I
// (P an AMD ordering), by supernodes: runs of columns of L with the same rows below them, each kept
// as one dense block, factorised and updated with dense matrix products. The solves, memory-bound,
// read each supernode's row list once and its entries in order.
class SupernodalCholesky
{
public:
  // a: symmetric; its lower triangle is read. Check info(): Eigen::NumericalIssue when A - sigma I is
  // not positive definite (or not finite).
  explicit SupernodalCholesky(const Eigen::SparseMatrix<double>& a, double sigma = 0.0);

  Eigen::ComputationInfo info() const { return info_; }
  Eigen::Index rows() const { return n_; }
  // Entries of L kept, the supernodes' zero upper triangles included.
  Eigen::Index storedEntries() const { return static_cast<Eigen::Index>(values_.size()); }
  Eigen::Index supernodes() const { return static_cast<Eigen::Index>(supernodes_.size()); }

  // x <- (A - sigma I)^-1 x
  void solveInPlace(Eigen::Ref<Eigen::VectorXd> x) const;

private:
  struct Supernode
  {
    int first;   // its columns are first .. first + width - 1
    int width;
    int height;  // rows of its block: its own columns, then the rows below them
    int rows;    // offset in rows_ of its row list
    std::ptrdiff_t values;  // offset in values_ of its height x width block, row-major
  };
  using RowMajorMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

  void analyse(const Eigen::SparseMatrix<double>& ap);
  void factorise(const Eigen::SparseMatrix<double>& ap, double sigma);

  int n_ = 0;
  Eigen::ComputationInfo info_ = Eigen::NumericalIssue;
  Eigen::PermutationMatrix<Eigen::Dynamic, Eigen::Dynamic, int> p_, p_inverse_;
  std::vector<Supernode> supernodes_;
  std::vector<int> supernode_of_;  // of each column
  std::vector<int> rows_;
  std::vector<double> values_;
  Eigen::VectorXd inverse_diagonal_;  // 1 / L_jj: the solves multiply
  int tallest_ = 0;  // rows of the tallest supernode
  mutable Eigen::VectorXd work_, gathered_;
};

}  // namespace modal_mass_spring
