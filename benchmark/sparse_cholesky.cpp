// The package's former supernodal Cholesky (supernodal_cholesky.h, kept here for this comparison)
// against the core's, CHOLMOD's supernodal one (SparseCholesky, over the system's BLAS on one thread),
// on the two matrices the package factorises: the modal basis's shift-invert M^-1/2 K M^-1/2 - sigma I and the static equilibrium's Newton tangent
// K + 1e-8 max K_ii I, both of the swinging cloth (benchmark/swinging_cloth.h) at n x n particles, on its
// 3D sheet or on the 2D grid of the same size. docs/benchmarks.md, "Sparse Cholesky", has the figures.
//
//   sparse_cholesky [Google Benchmark flags]
//   sparse_cholesky once WHAT MATRIX SIZE DIMENSION SOLVER   one call of `measured` for callgrind:
//     WHAT factorise | refactorise | solve; MATRIX basis | tangent; SOLVER own | cholmod, e.g.
//     valgrind --tool=callgrind --toggle-collect='*measured*' sparse_cholesky once factorise basis 100 3 own
//
// factorise: ordering, analysis and numeric factorisation, what the basis does once; refactorise: the
// numeric factorisation of a new matrix on the pattern analysed before, what each of the equilibrium's
// Newton iterations does (the own Cholesky has no separate analysis: it builds everything again); solve:
// one solve with the factor (x <- A^-1 b), what each Lanczos step and each refinement does.
#include "modal_mass_spring/grid.h"
#include "modal_mass_spring/spring_forces.h"
#include "solvers/sparse_cholesky.h"
#include "supernodal_cholesky.h"
#include "swinging_cloth.h"

#include <benchmark/benchmark.h>

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <iostream>
#include <memory>
#include <stdexcept>
#include <string>

using namespace modal_mass_spring;

namespace
{

enum class Matrix
{
  Basis,
  Tangent
};
enum class Solver
{
  Own,
  Cholmod
};
enum class What
{
  Factorise,
  Refactorise,
  Solve
};

// A - shift I, symmetric positive definite, of the cloth at size x size particles.
struct Problem
{
  SparseMatrix a;
  double shift = 0.0;
};

Problem problem(Matrix matrix, int size, int dimension)
{
  GridParams g = swingingCloth(size);
  g.dimension = dimension;
  if (dimension == 2)
    g.rotation_deg = 0.0;
  const Grid grid(g);
  // The start's K without compressed springs' geometric part: the same pattern as any other state's.
  const SparseMatrix k = tangentStiffness(grid, grid.initialPositions(), CompressedSprings::Drop);
  Problem p;
  if (matrix == Matrix::Basis)
  {
    // As computeModalBasis: A = M^-1/2 K M^-1/2 (M diagonal), sigma = -1e-4 max A_ii.
    const Eigen::VectorXd inv_sqrt_mass = Eigen::VectorXd::Constant(k.rows(), 1.0 / std::sqrt(grid.particleMass()));
    p.a = inv_sqrt_mass.asDiagonal() * k * inv_sqrt_mass.asDiagonal();
    p.shift = -1e-4 * p.a.diagonal().cwiseAbs().maxCoeff();
  }
  else
  {
    // As the equilibrium's Newton direction: K + 1e-8 max K_ii I.
    p.a = k;
    p.shift = -1e-8 * k.diagonal().cwiseAbs().maxCoeff();
  }
  return p;
}

class Factor
{
public:
  virtual ~Factor() = default;
  virtual void factorise(const Problem& p) = 0;
  virtual void refactorise(const Problem& p) = 0;
  virtual void solve(Eigen::VectorXd& x) = 0;
  virtual long entries() const = 0;  // of L, as kept
};

class OwnFactor : public Factor
{
public:
  void factorise(const Problem& p) override
  {
    llt_ = std::make_unique<SupernodalCholesky>(p.a, p.shift);
    if (llt_->info() != Eigen::Success)
      throw std::runtime_error("own supernodal Cholesky failed");
  }
  void refactorise(const Problem& p) override { factorise(p); }
  void solve(Eigen::VectorXd& x) override { llt_->solveInPlace(x); }
  long entries() const override { return llt_->storedEntries(); }

private:
  std::unique_ptr<SupernodalCholesky> llt_;
};

// The core's: CHOLMOD's supernodal factorisation, analysed again only for a new pattern.
class CholmodFactor : public Factor
{
public:
  void factorise(const Problem& p) override
  {
    llt_ = std::make_unique<SparseCholesky>();
    refactorise(p);
  }
  void refactorise(const Problem& p) override
  {
    if (!llt_->factorise(p.a, -p.shift))
      throw std::runtime_error("CHOLMOD failed");
  }
  void solve(Eigen::VectorXd& x) override { llt_->solveInPlace(x); }
  long entries() const override { return llt_->storedEntries(); }

private:
  std::unique_ptr<SparseCholesky> llt_;
};

std::unique_ptr<Factor> makeFactor(Solver solver)
{
  if (solver == Solver::Own)
    return std::make_unique<OwnFactor>();
  return std::make_unique<CholmodFactor>();
}

Eigen::VectorXd rightHandSide(Eigen::Index n)
{
  std::srand(1);
  return Eigen::VectorXd::Random(n);
}

// What is timed (or counted): one factorisation, refactorisation or solve.
__attribute__((noinline)) void measured(What what, Factor& factor, const Problem& p, Eigen::VectorXd& x)
{
  if (what == What::Factorise)
    factor.factorise(p);
  else if (what == What::Refactorise)
    factor.refactorise(p);
  else
    factor.solve(x);
}

// |b - A x| / |b| of a solve: a wrong factor is an error, not a figure.
double relativeResidual(Factor& factor, const Problem& p)
{
  const Eigen::VectorXd b = rightHandSide(p.a.rows());
  Eigen::VectorXd x = b;
  factor.solve(x);
  const SparseMatrix full = p.a.selfadjointView<Eigen::Lower>();
  return (b - full * x + p.shift * x).norm() / b.norm();
}

// range(0): matrix (0 basis, 1 tangent); range(1): n; range(2): dimension; range(3): solver (0 own,
// 1 CHOLMOD); range(4): what (0 factorise, 1 refactorise, 2 solve).
void BM_SparseCholesky(benchmark::State& state)
{
  const Problem p = problem(static_cast<Matrix>(state.range(0)), static_cast<int>(state.range(1)),
                            static_cast<int>(state.range(2)));
  auto factor = makeFactor(static_cast<Solver>(state.range(3)));
  const auto what = static_cast<What>(state.range(4));
  factor->factorise(p);
  Eigen::VectorXd x = rightHandSide(p.a.rows());
  for (auto _ : state)
  {
    if (what == What::Solve)
    {
      state.PauseTiming();
      x = rightHandSide(p.a.rows());
      state.ResumeTiming();
    }
    measured(what, *factor, p, x);
  }
  // The flat sheet's tangent holds out of its plane by its 1e-8 regularisation alone: a residual of
  // about 1e-8 there is its condition number's, not a wrong factor's.
  const double residual = relativeResidual(*factor, p);
  if (!(residual < 1e-6))
    state.SkipWithError("the solve's residual is not small");
  state.counters["dofs"] = static_cast<double>(p.a.rows());
  state.counters["entries_of_L"] = static_cast<double>(factor->entries());
  state.counters["residual"] = residual;
}
BENCHMARK(BM_SparseCholesky)
    ->ArgsProduct({{0, 1}, {50, 100, 200}, {2, 3}, {0, 1}, {0, 1, 2}})
    ->Unit(benchmark::kMillisecond);

int once(int argc, char** argv)
{
  if (argc != 7)
  {
    std::cerr << "usage: sparse_cholesky once factorise|refactorise|solve basis|tangent SIZE DIMENSION own|cholmod\n";
    return 2;
  }
  const std::string what_name = argv[2], matrix_name = argv[3], solver_name = argv[6];
  const What what = what_name == "factorise" ? What::Factorise : what_name == "refactorise" ? What::Refactorise : What::Solve;
  const Problem p = problem(matrix_name == "basis" ? Matrix::Basis : Matrix::Tangent, std::atoi(argv[4]), std::atoi(argv[5]));
  auto factor = makeFactor(solver_name == "own" ? Solver::Own : Solver::Cholmod);
  if (what != What::Factorise)
    factor->factorise(p);
  Eigen::VectorXd x = rightHandSide(p.a.rows());
  measured(what, *factor, p, x);
  std::cout << what_name << " " << matrix_name << " " << argv[4] << " " << argv[5] << "D " << solver_name << ": "
            << p.a.rows() << " dofs, " << factor->entries() << " entries of L, residual "
            << relativeResidual(*factor, p) << "\n";
  return 0;
}

}  // namespace

int main(int argc, char** argv)
{
  if (argc > 1 && std::strcmp(argv[1], "once") == 0)
    return once(argc, argv);
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv))
    return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
