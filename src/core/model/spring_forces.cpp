// The whole grid's spring forces, energy and tangents, summed from the spring law (spring_law.h),
// written once for 2D and 3D through a fixed-size template.
#include "modal_mass_spring/spring_forces.h"

#include <algorithm>
#include <limits>
#include <vector>

namespace modal_mass_spring
{
namespace
{

template <int Dim>
void springForcesDim(const Grid& grid, const Eigen::VectorXd& x, Eigen::VectorXd& f, double* energy)
{
  using Vec = Eigen::Matrix<double, Dim, 1>;
  f.setZero(x.size());
  double total_energy = 0.0;
  for (const Spring& s : grid.springs())
  {
    double e = 0.0;
    const Vec fi = springForce(s.stiffness, s.rest_length, Vec(x.segment<Dim>(Dim * s.j) - x.segment<Dim>(Dim * s.i)), &e);
    f.segment<Dim>(Dim * s.i) += fi;
    f.segment<Dim>(Dim * s.j) -= fi;
    total_energy += e;
  }
  if (energy)
    *energy = total_energy;
}

// A spring's Hessian block at x (spring_law.h), counting in `dropped` the geometric terms Drop leaves out.
template <int Dim>
Eigen::Matrix<double, Dim, Dim> springHessian(const Spring& s, const Eigen::VectorXd& x, CompressedSprings compressed,
                                              int& dropped)
{
  using Vec = Eigen::Matrix<double, Dim, 1>;
  const Vec d = x.segment<Dim>(Dim * s.j) - x.segment<Dim>(Dim * s.i);
  if (geometricStiffnessDropped(s.rest_length, d.norm(), compressed))
    ++dropped;
  return modal_mass_spring::springHessian(s.stiffness, s.rest_length, d, compressed);
}

template <int Dim>
SparseMatrix tangentStiffnessDim(const Grid& grid, const Eigen::VectorXd& x, CompressedSprings compressed,
                                 int* num_dropped)
{
  using Mat = Eigen::Matrix<double, Dim, Dim>;
  std::vector<Eigen::Triplet<double>> triplets;
  triplets.reserve(grid.springs().size() * 4 * Dim * Dim);
  int dropped = 0;

  // Adds sign * Ke to the block (a, b) of particles, skipping fixed dofs.
  auto addBlock = [&](int a, int b, const Mat& ke, double sign) {
    for (int r = 0; r < Dim; ++r)
    {
      const int row = grid.freeIndex(Dim * a + r);
      if (row < 0)
        continue;
      for (int c = 0; c < Dim; ++c)
      {
        const int col = grid.freeIndex(Dim * b + c);
        if (col >= 0)
          triplets.emplace_back(row, col, sign * ke(r, c));
      }
    }
  };

  for (const Spring& s : grid.springs())
  {
    const Mat ke = springHessian<Dim>(s, x, compressed, dropped);
    addBlock(s.i, s.i, ke, 1.0);
    addBlock(s.j, s.j, ke, 1.0);
    addBlock(s.i, s.j, ke, -1.0);
    addBlock(s.j, s.i, ke, -1.0);
  }
  if (num_dropped)
    *num_dropped = dropped;
  SparseMatrix k(grid.numFreeDofs(), grid.numFreeDofs());
  k.setFromTriplets(triplets.begin(), triplets.end());
  return k;
}

template <int Dim>
SparseMatrix tangentStiffnessDerivativeDim(const Grid& grid, const Eigen::VectorXd& x, const Eigen::VectorXd& direction)
{
  using Vec = Eigen::Matrix<double, Dim, 1>;
  using Mat = Eigen::Matrix<double, Dim, Dim>;
  std::vector<Eigen::Triplet<double>> triplets;
  triplets.reserve(grid.springs().size() * 4 * Dim * Dim);
  // The direction at a particle's dofs, zero where a dof is fixed.
  auto at = [&](int particle) {
    Vec v = Vec::Zero();
    for (int a = 0; a < Dim; ++a)
    {
      const int free = grid.freeIndex(Dim * particle + a);
      if (free >= 0)
        v[a] = direction[free];
    }
    return v;
  };
  for (const Spring& s : grid.springs())
  {
    const Vec d = x.segment<Dim>(Dim * s.j) - x.segment<Dim>(Dim * s.i);
    const Vec delta = at(s.j) - at(s.i);
    const Mat dke = springHessianDerivative(s.stiffness, s.rest_length, d, delta);
    for (int r = 0; r < Dim; ++r)
      for (int c = 0; c < Dim; ++c)
      {
        const int ri = grid.freeIndex(Dim * s.i + r), rj = grid.freeIndex(Dim * s.j + r);
        const int ci = grid.freeIndex(Dim * s.i + c), cj = grid.freeIndex(Dim * s.j + c);
        if (ri >= 0 && ci >= 0)
          triplets.emplace_back(ri, ci, dke(r, c));
        if (rj >= 0 && cj >= 0)
          triplets.emplace_back(rj, cj, dke(r, c));
        if (ri >= 0 && cj >= 0)
          triplets.emplace_back(ri, cj, -dke(r, c));
        if (rj >= 0 && ci >= 0)
          triplets.emplace_back(rj, ci, -dke(r, c));
      }
  }
  SparseMatrix dk(grid.numFreeDofs(), grid.numFreeDofs());
  dk.setFromTriplets(triplets.begin(), triplets.end());
  return dk;
}

template <int Dim>
void tangentTimesBasisDim(const Grid& grid, const Eigen::VectorXd& x, const Eigen::MatrixXd& phi_t,
                          Eigen::MatrixXd& out)
{
  using Vec = Eigen::Matrix<double, Dim, 1>;
  using Mat = Eigen::Matrix<double, Dim, Dim>;
  const Eigen::Index r = phi_t.rows();
  out.setZero(r, phi_t.cols());
  Eigen::Matrix<double, Eigen::Dynamic, Dim> d(r, Dim), kd(r, Dim);  // (Phi_j - Phi_i)^T, times Ke
  for (const Spring& s : grid.springs())
  {
    const Vec e = x.segment<Dim>(Dim * s.j) - x.segment<Dim>(Dim * s.i);
    const Mat ke = modal_mass_spring::springHessian(s.stiffness, s.rest_length, e);
    for (int a = 0; a < Dim; ++a)
    {
      const int fi = grid.freeIndex(Dim * s.i + a), fj = grid.freeIndex(Dim * s.j + a);
      d.col(a).setZero();
      if (fj >= 0)
        d.col(a) += phi_t.col(fj);
      if (fi >= 0)
        d.col(a) -= phi_t.col(fi);
    }
    // Rows i and j of K Phi get -Ke (Phi_j - Phi_i) and +Ke (Phi_j - Phi_i).
    kd.noalias() = d * ke;  // Ke is symmetric
    for (int a = 0; a < Dim; ++a)
    {
      const int fi = grid.freeIndex(Dim * s.i + a), fj = grid.freeIndex(Dim * s.j + a);
      if (fi >= 0)
        out.col(fi) -= kd.col(a);
      if (fj >= 0)
        out.col(fj) += kd.col(a);
    }
  }
}

}  // namespace

SparseMatrix tangentStiffnessDerivative(const Grid& grid, const Eigen::VectorXd& x, const Eigen::VectorXd& direction)
{
  if (grid.dimension() == 2)
    return tangentStiffnessDerivativeDim<2>(grid, x, direction);
  return tangentStiffnessDerivativeDim<3>(grid, x, direction);
}

TangentAssembler::TangentAssembler(const Grid& grid) : grid_(grid)
{
  pattern_ = modal_mass_spring::tangentStiffness(grid, grid.initialPositions());
  pattern_.makeCompressed();
  const int dim = grid.dimension();
  slots_.reserve(grid.springs().size() * 4 * dim * dim);
  // Where entry (row, col) of K lies in its values; -1 for a fixed dof's.
  auto slot = [&](int row, int col) {
    if (row < 0 || col < 0)
      return -1;
    const int* begin = pattern_.innerIndexPtr() + pattern_.outerIndexPtr()[col];
    const int* end = pattern_.innerIndexPtr() + pattern_.outerIndexPtr()[col + 1];
    return static_cast<int>(std::lower_bound(begin, end, row) - pattern_.innerIndexPtr());
  };
  for (const Spring& s : grid.springs())
    for (const auto& [a, b] : {std::pair{s.i, s.i}, std::pair{s.j, s.j}, std::pair{s.i, s.j}, std::pair{s.j, s.i}})
      for (int c = 0; c < dim; ++c)
        for (int r = 0; r < dim; ++r)
          slots_.push_back(slot(grid.freeIndex(dim * a + r), grid.freeIndex(dim * b + c)));
}

template <int Dim>
void TangentAssembler::assembleDim(const Eigen::VectorXd& x, SparseMatrix& k, CompressedSprings compressed,
                                   int& dropped) const
{
  using Mat = Eigen::Matrix<double, Dim, Dim>;
  double* values = k.valuePtr();
  std::fill(values, values + k.nonZeros(), 0.0);
  const int* slot = slots_.data();
  for (const Spring& s : grid_.springs())
  {
    const Mat ke = springHessian<Dim>(s, x, compressed, dropped);
    for (const double sign : {1.0, 1.0, -1.0, -1.0})  // blocks (i, i), (j, j), (i, j), (j, i)
      for (int c = 0; c < Dim; ++c)
        for (int r = 0; r < Dim; ++r, ++slot)
          if (*slot >= 0)
            values[*slot] += sign * ke(r, c);
  }
}

void TangentAssembler::assemble(const Eigen::VectorXd& x, SparseMatrix& k, CompressedSprings compressed,
                                int* num_dropped) const
{
  if (k.rows() != pattern_.rows() || k.nonZeros() != pattern_.nonZeros() || !k.isCompressed() ||
      !std::equal(pattern_.outerIndexPtr(), pattern_.outerIndexPtr() + pattern_.outerSize() + 1, k.outerIndexPtr()))
    k = pattern_;
  int dropped = 0;
  if (grid_.dimension() == 2)
    assembleDim<2>(x, k, compressed, dropped);
  else
    assembleDim<3>(x, k, compressed, dropped);
  if (num_dropped)
    *num_dropped = dropped;
}

SpringTangent::SpringTangent(const Grid& grid) : grid_(grid)
{
  const int dim = grid.dimension();
  // The springs with both ends free first: the product runs over them without a test.
  const std::vector<Spring>& springs = grid.springs();
  for (int pass = 0; pass < 2; ++pass)
    for (size_t s = 0; s < springs.size(); ++s)
    {
      const int i = grid.freeIndex(dim * springs[s].i), j = grid.freeIndex(dim * springs[s].j);
      if ((i >= 0 && j >= 0) != (pass == 0))
        continue;
      order_.push_back(static_cast<int>(s));
      ends_.push_back(i);
      ends_.push_back(j);
    }
  num_interior_ = 0;
  while (num_interior_ < static_cast<int>(order_.size()) && ends_[2 * num_interior_] >= 0 &&
         ends_[2 * num_interior_ + 1] >= 0)
    ++num_interior_;
  hessians_.resize(springs.size() * dim * dim);
}

void SpringTangent::update(const Eigen::VectorXd& x)
{
  const int dim = grid_.dimension();
  int dropped = 0;
  double* out = hessians_.data();
  for (const int spring : order_)
  {
    const Spring& s = grid_.springs()[spring];
    if (dim == 2)
      Eigen::Map<Eigen::Matrix2d>{out} = springHessian<2>(s, x, CompressedSprings::Keep, dropped);
    else
      Eigen::Map<Eigen::Matrix3d>{out} = springHessian<3>(s, x, CompressedSprings::Keep, dropped);
    out += dim * dim;
  }
}

template <int Dim>
void SpringTangent::multiplyAddDim(const Eigen::VectorXd& p, double scale, Eigen::VectorXd& y) const
{
  using Vec = Eigen::Matrix<double, Dim, 1>;
  using Mat = Eigen::Matrix<double, Dim, Dim>;
  const int num_springs = static_cast<int>(ends_.size() / 2);
  const double* k = hessians_.data();
  for (int s = 0; s < num_interior_; ++s, k += Dim * Dim)
  {
    const int i = ends_[2 * s], j = ends_[2 * s + 1];
    const Vec t = scale * (Eigen::Map<const Mat>(k) * (p.segment<Dim>(i) - p.segment<Dim>(j)));
    y.segment<Dim>(i) += t;
    y.segment<Dim>(j) -= t;
  }
  for (int s = num_interior_; s < num_springs; ++s)
  {
    const int i = ends_[2 * s], j = ends_[2 * s + 1];
    Vec d = Vec::Zero();
    if (i >= 0)
      d = p.segment<Dim>(i);
    if (j >= 0)
      d -= p.segment<Dim>(j);
    const Vec t = scale * (Eigen::Map<const Mat>(hessians_.data() + static_cast<size_t>(s) * Dim * Dim) * d);
    if (i >= 0)
      y.segment<Dim>(i) += t;
    if (j >= 0)
      y.segment<Dim>(j) -= t;
  }
}

void SpringTangent::multiplyAdd(const Eigen::VectorXd& p, double scale, Eigen::VectorXd& y) const
{
  if (grid_.dimension() == 2)
    multiplyAddDim<2>(p, scale, y);
  else
    multiplyAddDim<3>(p, scale, y);
}

void SpringTangent::addDiagonalBlocks(double scale, Eigen::VectorXd& blocks) const
{
  const int dim = grid_.dimension();
  const int num_springs = static_cast<int>(ends_.size() / 2);
  for (int s = 0; s < num_springs; ++s)
    for (int end = 0; end < 2; ++end)
    {
      const int first = ends_[2 * s + end];
      if (first < 0)
        continue;
      // The free dofs of a particle are consecutive: its block is the (first / dim)-th.
      double* block = blocks.data() + static_cast<Eigen::Index>(first / dim) * dim * dim;
      const double* k = hessians_.data() + static_cast<size_t>(s) * dim * dim;
      for (int e = 0; e < dim * dim; ++e)
        block[e] += scale * k[e];
    }
}

void tangentTimesBasis(const Grid& grid, const Eigen::VectorXd& x, const Eigen::MatrixXd& phi_t,
                       Eigen::MatrixXd& k_phi_t)
{
  if (grid.dimension() == 2)
    tangentTimesBasisDim<2>(grid, x, phi_t, k_phi_t);
  else
    tangentTimesBasisDim<3>(grid, x, phi_t, k_phi_t);
}

void springForces(const Grid& grid, const Eigen::VectorXd& x, Eigen::VectorXd& f, double* energy)
{
  if (grid.dimension() == 2)
    springForcesDim<2>(grid, x, f, energy);
  else
    springForcesDim<3>(grid, x, f, energy);
}

void springAndGravityForces(const Grid& grid, const Eigen::VectorXd& x, Eigen::VectorXd& f, double* spring_energy)
{
  springForces(grid, x, f, spring_energy);
  f += grid.gravityForce();
}

double springForceRoundoff(const Grid& grid, const Eigen::VectorXd& x)
{
  const GridParams& p = grid.params();
  double stiffest = std::max(p.structural_stiffness, p.shear_stiffness);
  if (p.bending)
    stiffest = std::max(stiffest, p.bending_stiffness);
  const double extent = std::max(x.cwiseAbs().maxCoeff(), p.spacing * std::max(p.rows, p.cols));
  return 12.0 * stiffest * extent * std::numeric_limits<double>::epsilon();
}

double springEnergy(const Grid& grid, const Eigen::VectorXd& x)
{
  const int dim = grid.dimension();
  double energy = 0.0;
  for (const Spring& s : grid.springs())
  {
    energy += modal_mass_spring::springEnergy(s.stiffness, s.rest_length,
                                              (x.segment(dim * s.j, dim) - x.segment(dim * s.i, dim)).norm());
  }
  return energy;
}

double gravityEnergy(const Grid& grid, const Eigen::VectorXd& x)
{
  return -grid.gravityForce().dot(x);
}

SparseMatrix tangentStiffness(const Grid& grid, const Eigen::VectorXd& x, CompressedSprings compressed,
                              int* num_dropped)
{
  if (grid.dimension() == 2)
    return tangentStiffnessDim<2>(grid, x, compressed, num_dropped);
  return tangentStiffnessDim<3>(grid, x, compressed, num_dropped);
}

SparseMatrix springLaplacian(const Grid& grid)
{
  const int dim = grid.dimension();
  std::vector<Eigen::Triplet<double>> triplets;
  triplets.reserve(grid.springs().size() * 4 * dim);
  for (const Spring& s : grid.springs())
    for (int c = 0; c < dim; ++c)
    {
      const int i = grid.freeIndex(dim * s.i + c), j = grid.freeIndex(dim * s.j + c);
      if (i >= 0)
        triplets.emplace_back(i, i, s.stiffness);
      if (j >= 0)
        triplets.emplace_back(j, j, s.stiffness);
      if (i >= 0 && j >= 0)
      {
        triplets.emplace_back(i, j, -s.stiffness);
        triplets.emplace_back(j, i, -s.stiffness);
      }
    }
  SparseMatrix l(grid.numFreeDofs(), grid.numFreeDofs());
  l.setFromTriplets(triplets.begin(), triplets.end());
  return l;
}

Eigen::VectorXd springLaplacianDiagonal(const Grid& grid)
{
  const int dim = grid.dimension();
  Eigen::VectorXd d = Eigen::VectorXd::Zero(grid.numFreeDofs());
  for (const Spring& s : grid.springs())
    for (int c = 0; c < dim; ++c)
      for (int end : {s.i, s.j})
        if (const int k = grid.freeIndex(dim * end + c); k >= 0)
          d[k] += s.stiffness;
  return d;
}

}  // namespace modal_mass_spring
