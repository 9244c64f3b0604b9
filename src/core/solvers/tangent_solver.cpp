// Sparse symmetric solves for Newton's method: three sparse Cholesky factorisations and conjugate
// gradients preconditioned by a diagonal or by the factor of an earlier tangent.
#include "solvers/tangent_solver.h"

#include "solvers/supernodal_cholesky.h"

#include <Eigen/CholmodSupport>
#include <Eigen/Cholesky>
#include <Eigen/SparseCholesky>

#include <dlfcn.h>

#include <algorithm>
#include <mutex>

namespace modal_mass_spring
{

bool SparsityPattern::changedTo(const SparseMatrix& m)
{
  const int* outer_index = m.outerIndexPtr();
  const int* inner_index = m.innerIndexPtr();
  const size_t num_outer = m.outerSize() + 1;
  const size_t num_inner = m.nonZeros();
  if (outer.size() == num_outer && inner.size() == num_inner &&
      std::equal(outer_index, outer_index + num_outer, outer.begin()) &&
      std::equal(inner_index, inner_index + num_inner, inner.begin()))
    return false;
  outer.assign(outer_index, outer_index + num_outer);
  inner.assign(inner_index, inner_index + num_inner);
  return true;
}

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

// CHOLMOD's supernodes run on the BLAS, and OpenBLAS starts a spinning worker thread per core, which
// starves the node's publishing timer during a rebuild (docs/benchmarks.md). One BLAS thread; looked up
// at run time, so that any other BLAS is left as it is.
void useOneBlasThread()
{
  static std::once_flag once;
  std::call_once(once, [] {
    using SetThreads = void (*)(int);
    if (auto set = reinterpret_cast<SetThreads>(dlsym(RTLD_DEFAULT, "openblas_set_num_threads")))
      set(1);
  });
}

class CholmodFactor : public TangentSolver::Factor
{
public:
  CholmodFactor()
  {
    useOneBlasThread();
    // A J that is not positive definite is an answer here (the caller adds inertia), not an error to
    // print.
    llt_.cholmod().print = 0;
    llt_.cholmod().error_handler = nullptr;
  }
  bool factorise(const SparseMatrix& j) override
  {
    if (pattern_.changedTo(j))
      llt_.analyzePattern(j);
    llt_.factorize(j);
    return llt_.info() == Eigen::Success;
  }
  void solveInPlace(Eigen::VectorXd& x) override { x = llt_.solve(x); }

private:
  Eigen::CholmodSupernodalLLT<SparseMatrix, Eigen::Lower> llt_;
  SparsityPattern pattern_;
};

class SupernodalFactor : public TangentSolver::Factor
{
public:
  bool factorise(const SparseMatrix& j) override
  {
    llt_ = std::make_unique<SupernodalCholesky>(j);
    return llt_->info() == Eigen::Success;
  }
  void solveInPlace(Eigen::VectorXd& x) override { llt_->solveInPlace(x); }

private:
  std::unique_ptr<SupernodalCholesky> llt_;
};

// Preconditioned by a factor of an earlier J, conjugate gradients converge in a few iterations while J
// changes little; past this many, factorising the new J costs less than iterating on.
constexpr int kMaxReusedFactorIterations = 8;
// A diagonal preconditioner leaves J's condition number to the square of the grid's size: cap the
// iterations there (then the factor).
constexpr int kMaxJacobiIterations = 2000;

}  // namespace

TangentSolver::TangentSolver(TangentSolverKind kind) : kind_(kind)
{
  switch (kind)
  {
    case TangentSolverKind::SimplicialLdlt:
      factor_ = std::make_unique<SimplicialFactor>();
      break;
    case TangentSolverKind::Supernodal:
      factor_ = std::make_unique<SupernodalFactor>();
      break;
    default:
      factor_ = std::make_unique<CholmodFactor>();
  }
}

TangentSolver::~TangentSolver() = default;
TangentSolver::TangentSolver(TangentSolver&&) noexcept = default;
TangentSolver& TangentSolver::operator=(TangentSolver&&) noexcept = default;

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
  else if (kind_ == TangentSolverKind::JacobiCg || kind_ == TangentSolverKind::BlockJacobiCg)
  {
    inverse_diagonal_ = j.diagonal().cwiseInverse();
    if (inverse_diagonal_.minCoeff() > 0.0 &&
        conjugateGradients(product, b, x, tolerance, kMaxJacobiIterations,
                           [&](Eigen::VectorXd& v) { v.array() *= inverse_diagonal_.array(); }) &&
        x.allFinite())
      return true;
  }
  else if (kind_ == TangentSolverKind::CholmodCg && factor_current_)
  {
    // CG from zero is a descent direction of the quadratic whatever the preconditioner.
    if (conjugateGradients(product, b, x, tolerance, kMaxReusedFactorIterations,
                           [&](Eigen::VectorXd& v) { factor_->solveInPlace(v); }) &&
        x.allFinite())
      return true;
  }
  ++factorisations_;
  factor_current_ = factor_->factorise(j);
  if (!factor_current_)
    return false;
  x = b;
  factor_->solveInPlace(x);
  return x.allFinite();
}

}  // namespace modal_mass_spring
