// Sparse symmetric solves for Newton's method: three sparse Cholesky factorisations and conjugate
// gradients preconditioned by a diagonal or by the factor of an earlier tangent.
#include "modal_mass_spring/tangent_solver.h"

#include "modal_mass_spring/supernodal_cholesky.h"

#include <Eigen/CholmodSupport>
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

// CHOLMOD's supernodes run on the BLAS, and OpenBLAS starts a spinning worker thread per core: on the
// node, whose rebuild runs beside the timer that publishes, those threads took both cores and the
// markers fell from 30 to 9 Hz during a rebuild. One BLAS thread (as every figure in the docs was
// measured with); looked up at run time, so that any other BLAS is left as it is.
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

template <typename Precondition>
bool TangentSolver::conjugateGradients(const SparseMatrix& j, const Eigen::VectorXd& b, Eigen::VectorXd& x,
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
    jp_.noalias() = j * p_;
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

bool TangentSolver::solve(const SparseMatrix& j, const Eigen::VectorXd& b, Eigen::VectorXd& x, double tolerance)
{
  if (kind_ == TangentSolverKind::JacobiCg)
  {
    inverse_diagonal_ = j.diagonal().cwiseInverse();
    if (inverse_diagonal_.minCoeff() > 0.0 &&
        conjugateGradients(j, b, x, tolerance, kMaxJacobiIterations,
                           [&](Eigen::VectorXd& v) { v.array() *= inverse_diagonal_.array(); }) &&
        x.allFinite())
      return true;
  }
  else if (kind_ == TangentSolverKind::CholmodCg && factor_current_)
  {
    // CG from zero is a descent direction of the quadratic whatever the preconditioner.
    if (conjugateGradients(j, b, x, tolerance, kMaxReusedFactorIterations,
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
