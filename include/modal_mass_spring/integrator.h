// Time integrators for M q'' + C q' = F(q) with diagonal M; they see a method only through its
// ForceModel, mass and damping.
#pragma once

#include "modal_mass_spring/force_model.h"
#include "modal_mass_spring/spring_forces.h"

#include <Eigen/Core>
#include <Eigen/SparseCholesky>

#include <memory>

namespace modal_mass_spring
{

// Generalized state: displacement, velocity, acceleration.
struct State
{
  Eigen::VectorXd q, v, a;
};

// The linear part of a method's equation of motion: diagonal mass, sparse damping (diagonal in modal
// coordinates, alpha M + beta K in physical ones).
struct MassDamping
{
  Eigen::VectorXd mass;
  SparseMatrix damping;
};

class Integrator
{
public:
  virtual ~Integrator() = default;
  // Completes a state whose q and v are set with the acceleration they imply.
  virtual void initialize(ForceModel& model, State& state) const;
  // Advances `state` by one time step into `next`; false when the step cannot be taken (for
  // example an iteration that did not converge). Does not check for divergence.
  virtual bool step(ForceModel& model, const State& state, State& next) = 0;
  double timeStep() const { return dt_; }

protected:
  Integrator(MassDamping system, double dt) : system_(std::move(system)), dt_(dt) {}
  MassDamping system_;
  double dt_;
};

// The paper's scheme (eqs. 7-9): explicit positions, trapezoidal velocities, damping implicit, so
// each step solves (M + dt/2 C) v' = M v + dt/2 (M a + F(q')), factorised once.
class ExplicitNewmark : public Integrator
{
public:
  ExplicitNewmark(MassDamping system, double dt);
  bool step(ForceModel& model, const State& state, State& next) override;

private:
  bool diagonal_;                       // modal methods: M + dt/2 C is diagonal, solve by division
  Eigen::VectorXd inverse_diagonal_;
  Eigen::SimplicialLDLT<SparseMatrix> ldlt_;
  Eigen::VectorXd force_, rhs_;
};

}  // namespace modal_mass_spring
