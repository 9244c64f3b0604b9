// CHOLMOD through Eigen's CholmodSupernodalLLT, quiet and on one BLAS thread.
#include "solvers/sparse_cholesky.h"

#include <Eigen/CholmodSupport>

#include <dlfcn.h>

#include <algorithm>
#include <cmath>
#include <mutex>

namespace modal_mass_spring
{
namespace
{

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

// Eigen keeps CHOLMOD's factor to itself; its size says what a solve reads.
struct SupernodalLlt : Eigen::CholmodSupernodalLLT<SparseMatrix, Eigen::Lower>
{
  const cholmod_factor* factor() const { return m_cholmodFactor; }
};

}  // namespace

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

struct SparseCholesky::Factor
{
  Factor()
  {
    useOneBlasThread();
    // A matrix that is not positive definite is an answer here (Newton adds inertia, the equilibrium a
    // shift), not an error to print.
    llt.cholmod().print = 0;
    llt.cholmod().error_handler = nullptr;
  }
  SupernodalLlt llt;
  SparsityPattern pattern;
  bool valid = false;
};

SparseCholesky::SparseCholesky() : factor_(std::make_unique<Factor>()) {}
SparseCholesky::~SparseCholesky() = default;
SparseCholesky::SparseCholesky(SparseCholesky&&) noexcept = default;
SparseCholesky& SparseCholesky::operator=(SparseCholesky&&) noexcept = default;

bool SparseCholesky::factorise(const SparseMatrix& a, double shift)
{
  Factor& f = *factor_;
  // The BLAS's factorisation of a supernode need not refuse a NaN pivot.
  f.valid = false;
  if (!std::isfinite(shift) || !Eigen::Map<const Eigen::VectorXd>(a.valuePtr(), a.nonZeros()).allFinite())
    return false;
  if (f.pattern.changedTo(a))
    f.llt.analyzePattern(a);
  f.llt.setShift(shift);
  f.llt.factorize(a);
  f.valid = f.llt.info() == Eigen::Success;
  return f.valid;
}

void SparseCholesky::solveInPlace(Eigen::Ref<Eigen::VectorXd> x) const
{
  x = factor_->llt.solve(x);
}

long SparseCholesky::storedEntries() const
{
  const cholmod_factor* l = factor_->llt.factor();
  if (!factor_->valid || l == nullptr)
    return 0;
  return static_cast<long>(l->is_super ? l->xsize : l->nzmax);
}

}  // namespace modal_mass_spring
