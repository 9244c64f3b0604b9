// The three force models of the paper.
#include "modal_mass_spring/force_model.h"

#include "modal_mass_spring/spring_forces.h"

#include <cmath>

namespace modal_mass_spring
{

double modalRoundoff(const Grid& grid, const ModalBasis& basis, const Eigen::VectorXd& x_ref)
{
  // Every dof's force carries about the same error; Phi^T adds them up, at worst in absolute value.
  return springForceRoundoff(grid, x_ref) * (basis.phi.cwiseAbs().transpose() * Eigen::VectorXd::Ones(basis.phi.rows())).norm();
}

FullForceModel::FullForceModel(const Grid& grid, const Eigen::VectorXd& x_ref)
  : grid_(grid), x_ref_(x_ref), x_(x_ref), f_all_(x_ref.size())
{
  roundoff_ = springForceRoundoff(grid, x_ref) * std::sqrt(static_cast<double>(grid.numFreeDofs()));
}

void FullForceModel::setPositions(const Eigen::VectorXd& u)
{
  x_ = x_ref_;
  grid_.addFree(u, x_);
}

void FullForceModel::force(const Eigen::VectorXd& u, Eigen::VectorXd& f)
{
  setPositions(u);
  double spring_energy = 0.0;
  springAndGravityForces(grid_, x_, f_all_, &spring_energy);
  cache_.store(u, spring_energy + gravityEnergy(grid_, x_));
  f.resize(u.size());
  const std::vector<int>& free = grid_.freeDofs();
  for (size_t k = 0; k < free.size(); ++k)
    f[k] = f_all_[free[k]];
}

void FullForceModel::tangentStiffness(const Eigen::VectorXd& u, SparseMatrix& k)
{
  setPositions(u);
  if (!assembler_)
    assembler_ = std::make_unique<TangentAssembler>(grid_);
  assembler_->assemble(x_, k);
}

const SpringTangent* FullForceModel::springTangent(const Eigen::VectorXd& u)
{
  setPositions(u);
  if (!spring_tangent_)
    spring_tangent_ = std::make_unique<SpringTangent>(grid_);
  spring_tangent_->update(x_);
  return spring_tangent_.get();
}

bool FullForceModel::constantStiffness(SparseMatrix& l)
{
  l = springLaplacian(grid_);
  return true;
}

double FullForceModel::energy(const Eigen::VectorXd& u)
{
  double cached = 0.0;
  if (cache_.find(u, cached))
    return cached;
  setPositions(u);
  return springEnergy(grid_, x_) + gravityEnergy(grid_, x_);
}

LinearModalForceModel::LinearModalForceModel(const Grid& grid, const ModalBasis& basis,
                                             const Eigen::VectorXd& x_ref)
  : grid_(grid), basis_(basis), lambda_(basis.eigenvalues)
{
  roundoff_ = modalRoundoff(grid, basis, x_ref);
  setReference(x_ref);
}

void LinearModalForceModel::setReference(const Eigen::VectorXd& x_ref)
{
  Eigen::VectorXd f;
  springAndGravityForces(grid_, x_ref, f);
  reference_ = basis_.phi.transpose() * grid_.gatherFree(f);
  reference_energy_ = springEnergy(grid_, x_ref) + gravityEnergy(grid_, x_ref);
}

void LinearModalForceModel::force(const Eigen::VectorXd& modal, Eigen::VectorXd& f)
{
  f = reference_ - lambda_.cwiseProduct(modal);
}

double LinearModalForceModel::energy(const Eigen::VectorXd& modal)
{
  return reference_energy_ - reference_.dot(modal) + 0.5 * modal.dot(lambda_.cwiseProduct(modal));
}

void LinearModalForceModel::tangentStiffness(const Eigen::VectorXd&, SparseMatrix& k)
{
  k.resize(lambda_.size(), lambda_.size());
  k.setIdentity();
  k = lambda_.asDiagonal() * k;
}

PhysicalModalForceModel::PhysicalModalForceModel(const Grid& grid, const ModalBasis& basis,
                                                 const Eigen::VectorXd& x_ref)
  : grid_(grid),
    basis_(basis),
    phi_t_(basis.phi.transpose()),
    x_ref_(x_ref),
    x_(x_ref),
    f_all_(x_ref.size()),
    f_free_(grid.numFreeDofs())
{
  roundoff_ = modalRoundoff(grid, basis, x_ref);
}

void PhysicalModalForceModel::setPositions(const Eigen::VectorXd& modal)
{
  u_.noalias() = basis_.phi * modal;
  x_ = x_ref_;
  grid_.addFree(u_, x_);
}

void PhysicalModalForceModel::force(const Eigen::VectorXd& modal, Eigen::VectorXd& f)
{
  setPositions(modal);
  double spring_energy = 0.0;
  springAndGravityForces(grid_, x_, f_all_, &spring_energy);
  cache_.store(modal, spring_energy + gravityEnergy(grid_, x_));
  const std::vector<int>& free = grid_.freeDofs();
  for (size_t k = 0; k < free.size(); ++k)
    f_free_[k] = f_all_[free[k]];
  f.noalias() = basis_.phi.transpose() * f_free_;
}

double PhysicalModalForceModel::energy(const Eigen::VectorXd& modal)
{
  double cached = 0.0;
  if (cache_.find(modal, cached))
    return cached;
  setPositions(modal);
  return springEnergy(grid_, x_) + gravityEnergy(grid_, x_);
}

void PhysicalModalForceModel::tangentStiffness(const Eigen::VectorXd& modal, SparseMatrix& k)
{
  setPositions(modal);
  tangentTimesBasis(grid_, x_, phi_t_, k_phi_t_);
  const Eigen::MatrixXd reduced = k_phi_t_ * basis_.phi;
  k = reduced.sparseView();
}

bool LinearModalForceModel::constantStiffness(SparseMatrix& l)
{
  tangentStiffness(Eigen::VectorXd(), l);
  return true;
}

bool PhysicalModalForceModel::constantStiffness(SparseMatrix& l)
{
  const Eigen::MatrixXd l_phi = springLaplacian(grid_) * basis_.phi;
  l = (basis_.phi.transpose() * l_phi).sparseView();
  return true;
}

}  // namespace modal_mass_spring
