// The cubature force model: the projected force summed over the trained springs with their weights
// (cubature.h; the training is in cubature_training.cpp).
#include "modal_mass_spring/cubature.h"

#include "modal_mass_spring/spring_forces.h"
#include "reduction/cubature_springs.h"

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cmath>
#include <random>
#include <stdexcept>
#include <utility>

namespace modal_mass_spring
{
namespace
{

}  // namespace

CubatureForceModel::CubatureForceModel(const Grid& grid, const ModalBasis& basis, const Eigen::VectorXd& x_ref,
                                       const Cubature& cubature)
  : grid_(grid), basis_(basis), dim_(grid.dimension()), weights_(cubature.weights)
{
  const Eigen::Index count = static_cast<Eigen::Index>(cubature.springs.size());
  const Eigen::MatrixXd phi_t = basis.phi.transpose();
  diff_t_.resize(basis.phi.cols(), count * dim_);
  for (Eigen::Index t = 0; t < count; ++t)
  {
    springs_.push_back(grid.springs()[cubature.springs[t]]);
    diff_t_.middleCols(t * dim_, dim_) = springRows(grid, phi_t, springs_.back()).transpose();
  }
  // The exact force at the reference is part of F: it carries the round-off of every spring.
  roundoff_ = modalRoundoff(grid, basis, x_ref);
  setReference(x_ref);
}

void CubatureForceModel::setReference(const Eigen::VectorXd& x_ref)
{
  rest_diff_.resize(diff_t_.cols());
  for (size_t t = 0; t < springs_.size(); ++t)
    rest_diff_.segment(static_cast<Eigen::Index>(t) * dim_, dim_) = restDiff(grid_, x_ref, springs_[t]);
  d_modal_.resize(0);
  f_modal_.resize(0);
  // The exact force and energy at the reference, minus what the cubature gives there.
  Eigen::VectorXd f_all;
  double spring_energy = 0.0;
  springAndGravityForces(grid_, x_ref, f_all, &spring_energy);
  const Eigen::VectorXd zero = Eigen::VectorXd::Zero(size());
  Eigen::VectorXd at_zero;
  const double cubature_energy = weightedSprings(zero, &at_zero);
  constant_ = basis_.phi.transpose() * grid_.gatherFree(f_all) - at_zero;
  energy_constant_ = spring_energy + gravityEnergy(grid_, x_ref) - cubature_energy;
  base_rest_diff_ = rest_diff_;
  base_energy_constant_ = energy_constant_;
  cache_.clear();
}

void CubatureForceModel::setHandleMap(const Eigen::MatrixXd& psi, const AffineHandleFit& fit)
{
  const std::vector<int>& handle_dofs = grid_.handleDofs();
  const Eigen::Index nb = static_cast<Eigen::Index>(handle_dofs.size());
  std::vector<Eigen::Index> handle_index(static_cast<size_t>(grid_.numDofs()), -1);
  for (Eigen::Index k = 0; k < nb; ++k)
    handle_index[static_cast<size_t>(handle_dofs[static_cast<size_t>(k)])] = k;
  // Dof `dof`'s row of [Psi; I] added `sign` times to `row`; fixed dofs do not move.
  auto add = [&](int dof, double sign, Eigen::Index row) {
    const int free = grid_.freeIndex(dof);
    if (free >= 0)
      handle_rows_.row(row) += sign * psi.row(free);
    else if (handle_index[static_cast<size_t>(dof)] >= 0)
      handle_rows_(row, handle_index[static_cast<size_t>(dof)]) += sign;
  };
  handle_rows_.setZero(diff_t_.cols(), nb);
  for (size_t t = 0; t < springs_.size(); ++t)
    for (int a = 0; a < dim_; ++a)
    {
      const Eigen::Index row = static_cast<Eigen::Index>(t) * dim_ + a;
      add(dim_ * springs_[t].j + a, 1.0, row);
      add(dim_ * springs_[t].i + a, -1.0, row);
    }
  fit_ = fit;
  handle_affine_rows_ = handle_rows_ * fit.h;
  const Eigen::VectorXd& g = grid_.gravityForce();
  handle_gravity_ = psi.transpose() * grid_.gatherFree(g);
  for (Eigen::Index k = 0; k < nb; ++k)
    handle_gravity_[k] += g[handle_dofs[static_cast<size_t>(k)]];
}

void CubatureForceModel::moveHandles(const Eigen::VectorXd& dx_b)
{
  rest_diff_ = base_rest_diff_;
  if (fit_.split(dx_b, affine_, non_affine_))
    rest_diff_.noalias() += handle_rows_ * dx_b;
  else
    rest_diff_.noalias() += handle_affine_rows_ * affine_;
  // The spring part of the correction at X = 0 stays the last setReference's; gravity's is exact.
  energy_constant_ = base_energy_constant_ - handle_gravity_.dot(dx_b);
  d_modal_.resize(0);
  f_modal_.resize(0);
  cache_.clear();
}

void CubatureForceModel::springVectors(const Eigen::VectorXd& modal)
{
  if (d_modal_.size() == modal.size() && d_modal_ == modal)
    return;
  d_.noalias() = diff_t_.transpose() * modal;
  d_ += rest_diff_;
  d_modal_ = modal;
}

// The per-spring work with the dimension fixed at compile time: Eigen's fixed-size vectors keep it on
// the stack and unrolled (dynamic ones of at most 3 entries cost twice as much here). One pass over
// D^T, spring by spring: its block D_s^T (r x dim, contiguous) gives the spring vector D_s X and,
// still in cache, takes back its force D_s^T f_s: D is kept once (as D^T) and read once per force.
// The multiply-adds, 2 |T| dim r, are the cost (docs/benchmarks.md, "The cubature's step").
template <int Dim>
double CubatureForceModel::weightedSpringForces(const Eigen::VectorXd& modal, Eigen::VectorXd* f)
{
  using Vector = Eigen::Matrix<double, Dim, 1>;
  // d_ holds the spring vectors already when a tangent or an energy at this X came first.
  const bool known = d_modal_.size() == modal.size() && d_modal_ == modal;
  d_.resize(diff_t_.cols());
  if (f)
    f->setZero(diff_t_.rows());
  double energy = 0.0;
  for (size_t t = 0; t < springs_.size(); ++t)
  {
    const Eigen::Index row = static_cast<Eigen::Index>(t) * Dim;
    const Spring& s = springs_[t];
    const auto block = diff_t_.middleCols<Dim>(row);  // D_s^T
    Vector d;
    if (known)
    {
      d = d_.segment<Dim>(row);
    }
    else
    {
      for (int c = 0; c < Dim; ++c)
        d[c] = block.col(c).dot(modal) + rest_diff_[row + c];
      d_.segment<Dim>(row) = d;
    }
    // The weighted spring is a spring of stiffness w_s k_s.
    double spring_energy = 0.0;
    const Vector force = springForce(weights_[static_cast<Eigen::Index>(t)] * s.stiffness, s.rest_length, d,
                                     &spring_energy);
    energy += spring_energy;
    if (f)
      f->noalias() -= block * force;  // dE_s/dX = D_s^T f_i, in one pass over f
  }
  d_modal_ = modal;
  return energy;
}

double CubatureForceModel::weightedSprings(const Eigen::VectorXd& modal, Eigen::VectorXd* f)
{
  return dim_ == 3 ? weightedSpringForces<3>(modal, f) : weightedSpringForces<2>(modal, f);
}

void CubatureForceModel::force(const Eigen::VectorXd& modal, Eigen::VectorXd& f)
{
  if (f_modal_.size() == modal.size() && f_modal_ == modal)
  {
    f = f_;
    return;
  }
  const double energy = weightedSprings(modal, &f);
  f += constant_;
  cache_.store(modal, energy + energy_constant_ - constant_.dot(modal));
  f_modal_ = modal;
  f_ = f;
}

double CubatureForceModel::energy(const Eigen::VectorXd& modal)
{
  double cached = 0.0;
  if (cache_.find(modal, cached))
    return cached;
  return weightedSprings(modal, nullptr) + energy_constant_ - constant_.dot(modal);
}

// The blocks w_s K_s D_s, with K_s = k_s (u u^T + (1 - L/l) (I - u u^T)) = a I + b u u^T: so
// a D_s + b u (u^T D_s), without forming K_s. Built transposed (r x dim per spring, contiguous): a
// spring's rows of the column-major D are r cache lines apart, which made this loop cost half the product.
template <int Dim>
void CubatureForceModel::weightedTangentBlocks()
{
  using Vector = Eigen::Matrix<double, Dim, 1>;
  weighted_t_.resize(diff_t_.rows(), diff_t_.cols());
  d_rows_.resize(diff_t_.rows());
  for (size_t t = 0; t < springs_.size(); ++t)
  {
    const Eigen::Index row = static_cast<Eigen::Index>(t) * Dim;
    const Spring& s = springs_[t];
    const Vector d = d_.segment<Dim>(row);
    const double l = d.norm();
    const Vector u = d / l;
    const double wk = weights_[static_cast<Eigen::Index>(t)] * s.stiffness;
    const double a = geometricStiffness(wk, s.rest_length, l);
    const double b = wk - a;
    const auto block = diff_t_.middleCols<Dim>(row);  // D_s^T
    d_rows_.noalias() = block * u;                    // D_s^T u
    for (int c = 0; c < Dim; ++c)  // column by column: an outer product in a sum would need a temporary
      weighted_t_.col(row + c) = a * block.col(c) + (b * u[c]) * d_rows_;
  }
}

void CubatureForceModel::tangentStiffness(const Eigen::VectorXd& modal, SparseMatrix& k)
{
  springVectors(modal);
  if (dim_ == 3)
    weightedTangentBlocks<3>();
  else
    weightedTangentBlocks<2>();
  // D^T (w K D) is symmetric: one triangle is computed, half the product's cost, and mirrored.
  const Eigen::Index r = diff_t_.rows();
  reduced_.resize(r, r);
  reduced_.triangularView<Eigen::Lower>() = diff_t_ * weighted_t_.transpose();
  for (Eigen::Index j = 1; j < r; ++j)
    for (Eigen::Index i = 0; i < j; ++i)
      reduced_(i, j) = reduced_(j, i);
  k = reduced_.sparseView();
}

bool CubatureForceModel::constantStiffness(SparseMatrix& l)
{
  Eigen::VectorXd stiffness(diff_t_.cols());
  for (size_t t = 0; t < springs_.size(); ++t)
    stiffness.segment(static_cast<Eigen::Index>(t) * dim_, dim_).setConstant(weights_[static_cast<Eigen::Index>(t)] *
                                                                             springs_[t].stiffness);
  const Eigen::MatrixXd laplacian = diff_t_ * stiffness.asDiagonal() * diff_t_.transpose();
  l = laplacian.sparseView();
  return true;
}

}  // namespace modal_mass_spring
