// Time integrators for M q'' + C q' = F(q) with diagonal M; they see a method only through its
// ForceModel, mass and damping.
#pragma once

#include "modal_mass_spring/force_model.h"
#include "modal_mass_spring/spring_forces.h"

#include <Eigen/Core>
#include <Eigen/SparseCholesky>

#include <memory>
#include <vector>

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

// Newmark average acceleration (beta = 1/4, gamma = 1/2), implicit in the forces: each step solves
// R(q') = M a' + C v' - F(q') = 0 by Newton with the tangent 4/dt^2 M + 2/dt C + K(q') and a line
// search. Unconditionally stable and energy-conserving for linear systems. Where Newton does not
// converge in max_iterations, the step is retried as two half steps (recursively, down to 1/16);
// a step that still does not converge is refused, never taken.
class ImplicitNewmark : public Integrator
{
public:
  ImplicitNewmark(MassDamping system, double dt, int max_iterations = 50, double tolerance = 1e-9);
  bool step(ForceModel& model, const State& state, State& next) override;
  // Newton iterations of the last solve, and how many solves the last step took (1 unless split).
  int lastIterations() const { return last_iterations_; }
  int lastSubsteps() const { return substeps_; }

private:
  static constexpr int kMaxHalvings = 4;
  void setStepSize(double h);
  bool advance(ForceModel& model, const State& s, State& next, double h, int depth);
  // One Newton solve of a step of size h_.
  bool solve(ForceModel& model, const State& s, State& next);
  // a' and v' that the Newmark relations give for a trial q'.
  void kinematics(const State& s, State& next) const;
  void analyzeIfNewPattern(const SparseMatrix& jacobian);
  // Sets next.v, next.a from next.q, stores R(q') in residual_ and returns its norm.
  double residual(ForceModel& model, const State& s, State& next);
  // The residual below which round-off hides any further progress.
  double roundoff(const State& next) const;

  int max_iterations_;
  double tolerance_;
  int last_iterations_ = 0;
  int substeps_ = 0;
  double h_ = 0.0;             // the step size being solved
  SparseMatrix mass_matrix_;
  Eigen::SimplicialLDLT<SparseMatrix> ldlt_;
  SparseMatrix inertia_;  // 4/h^2 M + 2/h C
  SparseMatrix tangent_;
  std::vector<int> pattern_outer_, pattern_inner_;
  Eigen::VectorXd force_, residual_;
  double inertial_norm_ = 0.0;  // |M a' + C v'| at the last residual
};

}  // namespace modal_mass_spring
