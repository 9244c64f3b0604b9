#include "reduction/coarse_grid.h"

#include "modal_mass_spring/handles.h"
#include "modal_mass_spring/parameter_error.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace modal_mass_spring
{

namespace
{

// Columns of the coarse grid whose rows come out whole.
std::vector<int> allowedCoarseCols(const GridParams& fine)
{
  std::vector<int> allowed;
  for (int c = 2; c <= fine.cols; ++c)
    if (static_cast<long long>(fine.rows - 1) * (c - 1) % (fine.cols - 1) == 0 &&
        static_cast<long long>(fine.rows - 1) * (c - 1) >= fine.cols - 1)
      allowed.push_back(c);
  return allowed;
}

// The point (v, u) (row and column, fractional) of a rows x cols grid as a blend of its four
// particles around it.
Stencil bilinear(double v, double u, int rows, int cols)
{
  // A point on the last row or column belongs to the cell before it.
  const int r0 = std::min(static_cast<int>(std::floor(v + 1e-9)), rows - 2);
  const int c0 = std::min(static_cast<int>(std::floor(u + 1e-9)), cols - 2);
  const double a = v - r0, b = u - c0;
  Stencil s;
  s.particle = {r0 * cols + c0, r0 * cols + c0 + 1, (r0 + 1) * cols + c0, (r0 + 1) * cols + c0 + 1};
  s.weight = {(1 - a) * (1 - b), (1 - a) * b, a * (1 - b), a * b};
  return s;
}

}  // namespace

int resolveCoarseCols(const GridParams& fine, int coarse_cols)
{
  if (fine.rows < 2 || fine.cols < 2)
    rejectParameter("method", "coarse", "needs a grid of at least 2 x 2 particles, got rows " +
                                            std::to_string(fine.rows) + ", cols " + std::to_string(fine.cols));
  const std::vector<int> allowed = allowedCoarseCols(fine);  // never empty: cols itself
  if (coarse_cols < 0)
    rejectParameter("coarse_cols", coarse_cols, "must be 0 (about a third of cols, at most " + std::to_string(kMaxDefaultCoarseCols) + ") or a number of columns >= 2");
  if (coarse_cols == 0)
  {
    // About a third of the columns, at most kMaxDefaultCoarseCols: a step about 3 times larger on 9
    // times fewer particles, and on a large grid a coarse step whose particles no longer grow with
    // the grid's (docs/benchmarks.md, "The coarse grid (`method: coarse`)").
    const double third = std::ceil((fine.cols - 1) / 3.0) + 1;
    const bool capped = third > kMaxDefaultCoarseCols && allowed.front() <= kMaxDefaultCoarseCols;
    const double target = capped ? kMaxDefaultCoarseCols : third;
    int best = capped ? allowed.front() : allowed.back();
    for (int c : allowed)
      if ((!capped || c <= kMaxDefaultCoarseCols) &&
          (std::abs(c - target) < std::abs(best - target) ||
           (std::abs(c - target) == std::abs(best - target) && c > best)))
        best = c;
    return best;
  }
  if (std::find(allowed.begin(), allowed.end(), coarse_cols) != allowed.end())
    return coarse_cols;
  std::ostringstream list;
  for (size_t i = 0; i < allowed.size() && i < 16; ++i)
    list << (i ? ", " : "") << allowed[i];
  if (allowed.size() > 16)
    list << ", ...";
  rejectParameter("coarse_cols", coarse_cols,
                  "must be 0 (about a third of cols, at most " + std::to_string(kMaxDefaultCoarseCols) +
                      ") or a number of columns in [2, cols " + std::to_string(fine.cols) +
                      "] for which (rows - 1) (coarse_cols - 1) / (cols - 1) is whole, so that the coarse grid "
                      "spans the same cloth: " +
                      list.str());
}

GridParams coarseGridParams(const GridParams& f, int coarse_cols)
{
  const int cols = resolveCoarseCols(f, coarse_cols);
  const int rows = static_cast<int>(static_cast<long long>(f.rows - 1) * (cols - 1) / (f.cols - 1)) + 1;
  const double ratio = static_cast<double>(f.cols - 1) / (cols - 1);  // fine spacings per coarse one
  GridParams g = f;
  g.rows = rows;
  g.cols = cols;
  g.spacing = f.spacing * ratio;
  g.mass = f.mass * f.rows * f.cols / (static_cast<double>(rows) * cols);
  g.fixed.clear();
  g.handles.assign(f.handles.size(), {});

  std::vector<int> holder(static_cast<size_t>(rows) * cols, -2);  // -2 free, -1 fixed, h: handle h
  auto hold = [&](int fine_particle, int by) {
    const int r = static_cast<int>(std::lround((fine_particle / f.cols) / ratio));
    const int c = static_cast<int>(std::lround((fine_particle % f.cols) / ratio));
    int& h = holder[static_cast<size_t>(r) * cols + c];
    if (h != -2 && h != by)
    {
      auto name = [](int who) { return who < 0 ? std::string("a fixed particle") : "handles[" + std::to_string(who) + "]"; };
      rejectParameter("coarse_cols", cols,
                      name(h) + " and " + name(by) + " fall on the same coarse particle (row " + std::to_string(r) +
                          ", column " + std::to_string(c) +
                          "): the coarse grid is too coarse to hold them apart; use more coarse columns");
    }
    h = by;
  };
  for (int p : effectiveFixed(f))
    hold(p, -1);
  for (size_t h = 0; h < f.handles.size(); ++h)
    for (int p : f.handles[h])
      hold(p, static_cast<int>(h));
  for (int p = 0; p < rows * cols; ++p)
    if (holder[p] == -1)
      g.fixed.push_back(p);
    else if (holder[p] >= 0)
      g.handles[holder[p]].push_back(p);
  if (countFreeDofs(g) == 0)
    rejectParameter("coarse_cols", cols,
                    "holds every particle of its " + std::to_string(rows) + " x " + std::to_string(cols) +
                        " grid by the fixed particles and handles: use more coarse columns");
  return g;
}

CoarseGrid::CoarseGrid(const Grid& fine, int coarse_cols) : grid(coarseGridParams(fine.params(), coarse_cols)), fine_(fine)
{
  const GridParams& f = fine.params();
  const GridParams& g = grid.params();
  const int dim = f.dimension;
  const int rows = g.rows, cols = g.cols;
  const double ratio = static_cast<double>(f.cols - 1) / (cols - 1);

  // Each coarse handle particle copies the motion of its handle's fine particle nearest it.
  int fine_offset = 0;
  for (size_t h = 0; h < f.handles.size(); ++h)
  {
    for (int p : g.handles[h])
    {
      const double v = (p / cols) * ratio, u = (p % cols) * ratio;
      size_t best = 0;
      double best_distance = std::numeric_limits<double>::infinity();
      for (size_t i = 0; i < f.handles[h].size(); ++i)
      {
        const int q = f.handles[h][i];
        const double d = std::hypot(q / f.cols - v, q % f.cols - u);
        if (d < best_distance)
          best_distance = d, best = i;
      }
      for (int d = 0; d < dim; ++d)
        handle_source.push_back(fine_offset + static_cast<int>(best) * dim + d);
    }
    fine_offset += static_cast<int>(f.handles[h].size()) * dim;
  }

  std::vector<Eigen::Triplet<double>> entries;
  interpolation_stencils.reserve(fine.numParticles());
  for (int p = 0; p < fine.numParticles(); ++p)
  {
    const Stencil s = bilinear((p / f.cols) / ratio, (p % f.cols) / ratio, rows, cols);
    interpolation_stencils.push_back(s);
    for (int d = 0; d < dim; ++d)
    {
      const int k = fine.freeIndex(p * dim + d);
      if (k < 0)
        continue;
      for (int i = 0; i < 4; ++i)
        if (s.weight[i] != 0.0)
          entries.emplace_back(k, s.particle[i] * dim + d, s.weight[i]);
    }
  }
  interpolation.resize(fine.numFreeDofs(), grid.numDofs());
  interpolation.setFromTriplets(entries.begin(), entries.end());

  entries.clear();
  for (int p = 0; p < rows * cols; ++p)
  {
    const Stencil s = bilinear((p / cols) * ratio, (p % cols) * ratio, f.rows, f.cols);
    for (int d = 0; d < dim; ++d)
      for (int i = 0; i < 4; ++i)
        if (s.weight[i] != 0.0)
          entries.emplace_back(p * dim + d, s.particle[i] * dim + d, s.weight[i]);
  }
  sampling.resize(grid.numDofs(), fine.numDofs());
  sampling.setFromTriplets(entries.begin(), entries.end());

  x_ref = grid.initialPositions();
  stiffness = tangentStiffness(grid, x_ref, CompressedSprings::Drop);
  mass = Eigen::VectorXd::Constant(grid.numFreeDofs(), grid.particleMass());
  if (grid.numHandleDofs() > 0)
    handle_coupling = handleCoupling(grid, x_ref);

  entries.clear();
  for (int k = 0; k < interpolation.outerSize(); ++k)
    for (SparseMatrix::InnerIterator it(interpolation, k); it; ++it)
      if (const int free = grid.freeIndex(static_cast<int>(it.col())); free >= 0)
        entries.emplace_back(static_cast<int>(it.row()), free, it.value());
  free_interpolation_.resize(fine.numFreeDofs(), grid.numFreeDofs());
  free_interpolation_.setFromTriplets(entries.begin(), entries.end());
  span_gram_.compute(SparseMatrix(free_interpolation_.transpose() * free_interpolation_));
  if (span_gram_.info() != Eigen::Success)
    throw std::runtime_error("coarse grid: its interpolation's Gram matrix could not be factorised");
}

bool CoarseGrid::fitRestLengths(const Eigen::VectorXd& x_fine, Held held)
{
  const int dim = grid.dimension();
  // The coarse positions: the free particles sampled, the held ones as `held` says.
  Eigen::VectorXd x = sampling * x_fine;
  if (held == Held::AtRest)
  {
    const Eigen::VectorXd sampled = x;
    x = grid.initialPositions();
    for (int dof : grid.freeDofs())
      x[dof] = sampled[dof];
  }
  Eigen::VectorXd f_fine, f_coarse;
  springAndGravityForces(fine_, x_fine, f_fine);
  springAndGravityForces(grid, x, f_coarse);
  const Eigen::VectorXd target = grid.gatherFree(interpolation.transpose() * fine_.gatherFree(f_fine));
  const Eigen::VectorXd residual = grid.gatherFree(f_coarse) - target;

  // A spring's force on i is k (l - l0) d/l: d/dl0 is -k d/l on i, +k d/l on j. A = d(f_free)/d(l0).
  const std::vector<Spring>& springs = grid.springs();
  std::vector<Eigen::Triplet<double>> entries;
  entries.reserve(springs.size() * 2 * dim);
  for (size_t s = 0; s < springs.size(); ++s)
  {
    const Spring& spring = springs[s];
    const Eigen::VectorXd d = x.segment(dim * spring.j, dim) - x.segment(dim * spring.i, dim);
    const double length = d.norm();
    if (length == 0.0)
      continue;
    for (int c = 0; c < dim; ++c)
    {
      const double a = spring.stiffness * d[c] / length;
      if (const int fi = grid.freeIndex(dim * spring.i + c); fi >= 0)
        entries.emplace_back(fi, static_cast<int>(s), -a);
      if (const int fj = grid.freeIndex(dim * spring.j + c); fj >= 0)
        entries.emplace_back(fj, static_cast<int>(s), a);
    }
  }
  SparseMatrix a(grid.numFreeDofs(), static_cast<Eigen::Index>(springs.size()));
  a.setFromTriplets(entries.begin(), entries.end());
  // The least change: l0 += A^T y with A A^T y = -residual. A direction no spring acts in (across a
  // flat sheet) has no force to balance either: a small shift keeps A A^T invertible there.
  SparseMatrix normal = a * a.transpose();
  const double shift = 1e-12 * normal.diagonal().maxCoeff();
  for (int k = 0; k < normal.rows(); ++k)
    normal.coeffRef(k, k) += shift;
  Eigen::SimplicialLDLT<SparseMatrix> solver(normal);
  if (solver.info() != Eigen::Success)
    throw std::runtime_error("coarse grid: its rest lengths could not be fitted");
  Eigen::VectorXd lengths(static_cast<Eigen::Index>(springs.size()));
  for (size_t s = 0; s < springs.size(); ++s)
    lengths[static_cast<Eigen::Index>(s)] = springs[s].rest_length;
  lengths += a.transpose() * solver.solve(-residual);
  if (!(lengths.allFinite() && (lengths.array() > 0.0).all()))
    return false;
  for (size_t s = 0; s < springs.size(); ++s)
    grid.setRestLength(static_cast<int>(s), lengths[static_cast<Eigen::Index>(s)]);
  return true;
}

Eigen::VectorXd CoarseGrid::missed(const Eigen::VectorXd& x) const
{
  return fine_.gatherFree(x) - interpolation * (sampling * x);
}

Eigen::VectorXd CoarseGrid::outsideSpan(const Eigen::VectorXd& f) const
{
  return f - free_interpolation_ * span_gram_.solve(free_interpolation_.transpose() * f);
}

}  // namespace modal_mass_spring
