// Force models: the generalized force F(q) of each method in its own coordinates q.
#pragma once

#include "modal_mass_spring/grid.h"
#include "modal_mass_spring/modal_basis.h"
#include "modal_mass_spring/spring_forces.h"

#include <Eigen/Core>

#include <memory>

namespace modal_mass_spring
{

// q are displacements from a reference configuration x_ref: free-dof displacements u for the full
// model (x = x_ref + u), modal coordinates X for the reduced ones (u = Phi X).
class ForceModel
{
public:
  virtual ~ForceModel() = default;
  virtual int size() const = 0;
  // Spring plus gravity force in these coordinates. Not const: models keep scratch buffers.
  virtual void force(const Eigen::VectorXd& q, Eigen::VectorXd& f) = 0;
  // Potential energy E(q) with F = -dE/dq, for line searches and the energy check of a step; free
  // at the q of the last force() (the models compute both in one pass over the springs).
  virtual double energy(const Eigen::VectorXd& q) = 0;
  // Tangent stiffness -dF/dq at q, for implicit integrators: sparse for the full model, dense
  // (r x r, stored sparse) for the physical one, diagonal for the linear one.
  virtual void tangentStiffness(const Eigen::VectorXd& q, SparseMatrix& k) = 0;
  // True when F is affine in q, so one Newton iteration solves an implicit step exactly.
  virtual bool isLinear() const { return false; }
  // False when the tangent stiffness is not symmetric (the force is then not conservative).
  virtual bool isSymmetric() const { return true; }
  // The round-off of one evaluation of F (its norm, N in these coordinates): an iteration cannot
  // bring a residual below it. Where forces balance (an equilibrium) it is the only scale there is.
  double roundoff() const { return roundoff_; }
  // The coordinates come in groups of this many consecutive ones that couple strongly (a particle's):
  // the blocks of a block-diagonal preconditioner.
  virtual int blockSize() const { return 1; }
  // K(q) as the springs' blocks, for products J p without assembling K (the full model); nullptr for a
  // model without springs of its own coordinates.
  virtual const SpringTangent* springTangent(const Eigen::VectorXd&) { return nullptr; }
  // A constant stiffness L >= K(q) for every q (the springs' Laplacian in these coordinates): an
  // implicit step solved with L in place of K descends at every iteration, with a matrix factorised
  // once (projective dynamics' global step). False for a model without one.
  virtual bool constantStiffness(SparseMatrix&) { return false; }

protected:
  double roundoff_ = 0.0;
};

// The spring energy of the last force evaluation, kept for energy() at the same q.
class EnergyCache
{
public:
  void store(const Eigen::VectorXd& q, double energy)
  {
    q_ = q;
    energy_ = energy;
  }
  bool find(const Eigen::VectorXd& q, double& energy) const
  {
    if (q_.size() != q.size() || q_ != q)
      return false;
    energy = energy_;
    return true;
  }
  void clear() { q_.resize(0); }

private:
  Eigen::VectorXd q_;
  double energy_ = 0.0;
};

// `full`: eq. 13 forces on every free dof, no reduction.
class FullForceModel : public ForceModel
{
public:
  FullForceModel(const Grid& grid, const Eigen::VectorXd& x_ref);
  // Moves the positions of the dofs that are not free (the handles'); u still measures from x_ref.
  void setReference(const Eigen::VectorXd& x_ref)
  {
    x_ref_ = x_ref;
    cache_.clear();
  }
  int size() const override { return grid_.numFreeDofs(); }
  void force(const Eigen::VectorXd& u, Eigen::VectorXd& f) override;
  void tangentStiffness(const Eigen::VectorXd& u, SparseMatrix& k) override;
  double energy(const Eigen::VectorXd& u) override;
  int blockSize() const override { return grid_.dimension(); }
  const SpringTangent* springTangent(const Eigen::VectorXd& u) override;
  bool constantStiffness(SparseMatrix& l) override;

private:
  void setPositions(const Eigen::VectorXd& u);  // x_ = x_ref + u

  const Grid& grid_;
  Eigen::VectorXd x_ref_, x_, f_all_;
  EnergyCache cache_;
  std::unique_ptr<TangentAssembler> assembler_;  // built at the first tangent (explicit steps need none)
  std::unique_ptr<SpringTangent> spring_tangent_;  // built at the first use
};

// A force model in modal coordinates: X = 0 stands for a reference configuration that a method
// switch can move (the part of a displacement the modes cannot hold), the basis staying.
class ModalForceModel : public ForceModel
{
public:
  virtual void setReference(const Eigen::VectorXd& x_ref) = 0;
};

// The round-off of Phi^T f, the modal models' force, at positions near x_ref (see ForceModel::roundoff).
double modalRoundoff(const Grid& grid, const ModalBasis& basis, const Eigen::VectorXd& x_ref);

// `linear` (O'Brien): F = Phi^T (f(x_ref) + f_g) - Lambda X, the force linearised at x_ref.
class LinearModalForceModel : public ModalForceModel
{
public:
  LinearModalForceModel(const Grid& grid, const ModalBasis& basis, const Eigen::VectorXd& x_ref);
  void setReference(const Eigen::VectorXd& x_ref) override;
  int size() const override { return static_cast<int>(lambda_.size()); }
  void force(const Eigen::VectorXd& modal, Eigen::VectorXd& f) override;
  void tangentStiffness(const Eigen::VectorXd& modal, SparseMatrix& k) override;
  double energy(const Eigen::VectorXd& modal) override;
  bool isLinear() const override { return true; }
  bool constantStiffness(SparseMatrix& l) override;

private:
  const Grid& grid_;
  const ModalBasis& basis_;
  Eigen::VectorXd lambda_;      // lambda^2 per mode
  Eigen::VectorXd reference_;   // Phi^T (f(x_ref) + f_g), constant
  double reference_energy_;     // E(x_ref)
};

// `physical` (Kobayashi et al.): x = x_ref + Phi X, F = Phi^T (f(x) + f_g).
class PhysicalModalForceModel : public ModalForceModel
{
public:
  PhysicalModalForceModel(const Grid& grid, const ModalBasis& basis, const Eigen::VectorXd& x_ref);
  void setReference(const Eigen::VectorXd& x_ref) override
  {
    x_ref_ = x_ref;
    cache_.clear();
  }
  int size() const override { return static_cast<int>(basis_.phi.cols()); }
  void force(const Eigen::VectorXd& modal, Eigen::VectorXd& f) override;
  // Phi^T K(x) Phi at x = x_ref + Phi X, K(x) Phi summed spring by spring.
  void tangentStiffness(const Eigen::VectorXd& modal, SparseMatrix& k) override;
  double energy(const Eigen::VectorXd& modal) override;
  // Phi^T L Phi
  bool constantStiffness(SparseMatrix& l) override;

private:
  void setPositions(const Eigen::VectorXd& modal);  // x_ = x_ref + Phi X

  const Grid& grid_;
  const ModalBasis& basis_;
  Eigen::MatrixXd phi_t_, k_phi_t_;  // Phi^T, contiguous per dof, and (K Phi)^T
  Eigen::VectorXd x_ref_, u_, x_, f_all_, f_free_;
  EnergyCache cache_;
};

}  // namespace modal_mass_spring
