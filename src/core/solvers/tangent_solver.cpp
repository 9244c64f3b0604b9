// Sparse symmetric solves for Newton's method: two sparse Cholesky factorisations and conjugate
// gradients preconditioned by J's diagonal blocks.
#include "solvers/tangent_solver.h"

#include <Eigen/Cholesky>
#include <Eigen/SparseCholesky>

#include <algorithm>

namespace modal_mass_spring
{

class TangentSolver::Factor
{
public:
  virtual ~Factor() = default;
  // False when J is not positive definite.
  virtual bool factorise(const SparseMatrix& j) = 0;
  virtual void solveInPlace(Eigen::VectorXd& x) = 0;
};

namespace
{

class SimplicialFactor : public TangentSolver::Factor
{
public:
  bool factorise(const SparseMatrix& j) override
  {
    // The symbolic analysis (fill-reducing ordering) is the costly part; the full model's pattern
    // never changes.
    if (pattern_.changedTo(j))
      ldlt_.analyzePattern(j);
    ldlt_.factorize(j);
    return ldlt_.info() == Eigen::Success && ldlt_.vectorD().minCoeff() > 0.0;
  }
  void solveInPlace(Eigen::VectorXd& x) override { x = ldlt_.solve(x); }

private:
  Eigen::SimplicialLDLT<SparseMatrix> ldlt_;
  SparsityPattern pattern_;
};

class CholmodFactor : public TangentSolver::Factor
{
public:
  bool factorise(const SparseMatrix& j) override { return llt_.factorise(j); }
  void solveInPlace(Eigen::VectorXd& x) override { llt_.solveInPlace(x); }

private:
  SparseCholesky llt_;
};

}  // namespace

TangentSolver::TangentSolver(TangentSolverKind kind) : kind_(kind)
{
  switch (kind)
  {
    case TangentSolverKind::SimplicialLdlt:
      factor_ = std::make_unique<SimplicialFactor>();
      break;
    default:
      factor_ = std::make_unique<CholmodFactor>();
  }
}

TangentSolver::~TangentSolver() = default;
TangentSolver::TangentSolver(TangentSolver&&) noexcept = default;
TangentSolver& TangentSolver::operator=(TangentSolver&&) noexcept = default;

int TangentSolver::blockSize(Eigen::Index size) const
{
  return block_size_ >= 2 && block_size_ <= 3 && size % block_size_ == 0 ? block_size_ : 1;
}

template <int Size>
void TangentSolver::diagonalBlocks(const SparseMatrix& j)
{
  inverse_blocks_.setZero(j.rows() * Size);
  // J is symmetric: its columns are its rows, so each column's entries within the column's own block
  // fill that block.
  for (int col = 0; col < j.outerSize(); ++col)
  {
    const int block = col / Size;
    double* values = inverse_blocks_.data() + static_cast<Eigen::Index>(block) * Size * Size;
    for (SparseMatrix::InnerIterator it(j, col); it; ++it)
      if (it.row() / Size == block)
        values[(col % Size) * Size + it.row() % Size] = it.value();
  }
}

template <int Size>
bool TangentSolver::invertBlocks()
{
  using Block = Eigen::Matrix<double, Size, Size>;
  const Eigen::Index num_blocks = inverse_blocks_.size() / (Size * Size);
  for (Eigen::Index block = 0; block < num_blocks; ++block)
  {
    Eigen::Map<Block> values(inverse_blocks_.data() + block * Size * Size);
    const Eigen::LLT<Block> llt(values);
    if (llt.info() != Eigen::Success)
      return false;
    values = llt.solve(Block::Identity());
  }
  return inverse_blocks_.allFinite();
}

template <int Size>
void TangentSolver::applyInverseBlocks(Eigen::VectorXd& v) const
{
  using Block = Eigen::Matrix<double, Size, Size>;
  using Segment = Eigen::Matrix<double, Size, 1>;
  const Eigen::Index num_blocks = v.size() / Size;
  for (Eigen::Index block = 0; block < num_blocks; ++block)
  {
    Eigen::Map<Segment> segment(v.data() + block * Size);
    const Segment r = segment;
    segment.noalias() = Eigen::Map<const Block>(inverse_blocks_.data() + block * Size * Size) * r;
  }
}

template <typename Multiply>
bool TangentSolver::blockJacobi(Multiply multiply, int block_size, const Eigen::VectorXd& b, Eigen::VectorXd& x,
                                double tolerance)
{
  if (block_size == 2)
    return invertBlocks<2>() &&
           conjugateGradients(multiply, b, x, tolerance, kMaxJacobiIterations,
                              [&](Eigen::VectorXd& v) { applyInverseBlocks<2>(v); }) &&
           x.allFinite();
  if (block_size == 3)
    return invertBlocks<3>() &&
           conjugateGradients(multiply, b, x, tolerance, kMaxJacobiIterations,
                              [&](Eigen::VectorXd& v) { applyInverseBlocks<3>(v); }) &&
           x.allFinite();
  inverse_diagonal_ = inverse_blocks_.cwiseInverse();
  return inverse_diagonal_.minCoeff() > 0.0 &&
         conjugateGradients(multiply, b, x, tolerance, kMaxJacobiIterations,
                            [&](Eigen::VectorXd& v) { v.array() *= inverse_diagonal_.array(); }) &&
         x.allFinite();
}

bool TangentSolver::solveMatrixFree(const std::function<void(const Eigen::VectorXd&, Eigen::VectorXd&)>& multiply,
                                    const Eigen::VectorXd& diagonal_blocks, const Eigen::VectorXd& b,
                                    Eigen::VectorXd& x, double tolerance)
{
  const int block_size = blockSize(b.size());
  if (diagonal_blocks.size() != b.size() * block_size)
    return false;
  inverse_blocks_ = diagonal_blocks;
  return blockJacobi(multiply, block_size, b, x, tolerance);
}

bool TangentSolver::solveWithFactor(const Eigen::VectorXd& b, Eigen::VectorXd& x)
{
  if (!factor_current_)
    return false;
  x = b;
  factor_->solveInPlace(x);
  return x.allFinite();
}

bool TangentSolver::diagonalJacobi(const SparseMatrix& j, const Eigen::VectorXd& b, Eigen::VectorXd& x,
                                   double tolerance)
{
  auto product = [&](const Eigen::VectorXd& p, Eigen::VectorXd& jp) { jp.noalias() = j * p; };
  inverse_diagonal_ = j.diagonal().cwiseInverse();
  return inverse_diagonal_.minCoeff() > 0.0 &&
         conjugateGradients(product, b, x, tolerance, kMaxJacobiIterations,
                            [&](Eigen::VectorXd& v) { v.array() *= inverse_diagonal_.array(); }) &&
         x.allFinite();
}

bool TangentSolver::solve(const SparseMatrix& j, const Eigen::VectorXd& b, Eigen::VectorXd& x, double tolerance)
{
  auto product = [&](const Eigen::VectorXd& p, Eigen::VectorXd& jp) { jp.noalias() = j * p; };
  const int block_size = blockSize(j.rows());
  if (kind_ == TangentSolverKind::BlockJacobiCg && block_size > 1)
  {
    if (block_size == 2)
      diagonalBlocks<2>(j);
    else
      diagonalBlocks<3>(j);
    if (blockJacobi(product, block_size, b, x, tolerance))
      return true;
  }
  else if (kind_ == TangentSolverKind::BlockJacobiCg && diagonalJacobi(j, b, x, tolerance))  // blocks of one dof
    return true;
  ++factorisations_;
  factor_current_ = factor_->factorise(j);
  if (!factor_current_)
    return false;
  x = b;
  factor_->solveInPlace(x);
  return x.allFinite();
}

}  // namespace modal_mass_spring
