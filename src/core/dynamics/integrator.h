// Time integrators for M q'' + C q' = F(q) with diagonal M; they see a method only through its
// ForceModel, mass and damping.
#pragma once

#include "modal_mass_spring/force_model.h"
#include "modal_mass_spring/options.h"
#include "modal_mass_spring/spring_forces.h"
#include "modal_mass_spring/state.h"
#include "solvers/tangent_solver.h"

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <Eigen/SparseCholesky>
#include <Eigen/SparseLU>

#include <functional>
#include <memory>
#include <vector>

namespace modal_mass_spring
{

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
  // Newton iterations of the last solve, and how many solves the last step took (1 unless Newton
  // failed and the step was split); 0 for a scheme without iterations.
  virtual int lastIterations() const { return 0; }
  virtual int lastSubsteps() const { return 0; }
  // Adds a skew velocity coupling G to the damping from now on (the Coriolis forces -G q' of a
  // turning frame, in the method's coordinates; the acceleration of the end of the next step sees
  // it); null: none. G stays the caller's (the method's), which keeps it alive and may change its
  // values before the next step, calling this again.
  void setGyroscopic(const SparseMatrix* g);

protected:
  Integrator(MassDamping system, double dt) : system_(std::move(system)), dt_(dt) {}
  virtual void gyroscopicChanged() {}
  // (C + G) v
  Eigen::VectorXd dampingForce(const Eigen::VectorXd& v) const;
  MassDamping system_;
  const SparseMatrix* gyroscopic_ = nullptr;  // G; null: none
  double dt_;
};

// The paper's scheme (eqs. 7-9): explicit positions, trapezoidal velocities, damping implicit, so
// each step solves (M + dt/2 C) v' = M v + dt/2 (M a + F(q')), factorised once. A gyroscopic G
// joins C by a fixed-point iteration on that factorisation, v' <- (M + dt/2 C)^-1 (rhs - dt/2 G v'),
// which contracts by about dt |omega| per iteration: the scheme stays second order and
// damping-implicit.
class ExplicitNewmark : public Integrator
{
public:
  ExplicitNewmark(MassDamping system, double dt);
  bool step(ForceModel& model, const State& state, State& next) override;

private:
  static constexpr int kMaxIterations = 100;
  // (M + dt/2 C)^-1 rhs
  Eigen::VectorXd solve(const Eigen::VectorXd& rhs) const;
  bool diagonal_;                       // C diagonal (modal methods, or alpha alone): solve by division
  Eigen::VectorXd inverse_diagonal_;
  Eigen::SimplicialLDLT<SparseMatrix> ldlt_;
  Eigen::VectorXd force_, rhs_, gyroscopic_force_, velocity_;
};

// Where Newton starts an implicit step.
enum class NewtonStart
{
  ConstantVelocity,      // q' = q + h v
  ConstantAcceleration,  // q' = q + h v + h^2 / 2 a: the start's acceleration kept over the step
};

// Implicit Newmark with the Hilber-Hughes-Taylor alpha: each step solves
//   R(q') = M a' + (1 + alpha) (C v' - F(q')) - alpha (C v - F(q)) = 0,
// beta = (1 - alpha)^2 / 4, gamma = 1/2 - alpha, by Newton with the tangent
// M / (beta dt^2) + (1 + alpha) (gamma / (beta dt) C + K(q')) and a line search. alpha = 0 is
// Newmark average acceleration: unconditionally stable and energy-conserving for linear systems,
// but not for stiff nonlinear springs at large steps, where energy can grow without bound; alpha in
// [-1/3, 0) damps the highest frequencies (second order still), which keeps those steps bounded.
// Where Newton does not converge in max_iterations, the step is retried as two half steps
// (recursively, down to 1/16); a step that still does not converge is refused, never taken.
// A gyroscopic G or a force whose tangent is not symmetric (a turning frame's) makes R no gradient:
// Newton then solves with a sparse LU and its line search asks for a smaller |R|.
// Two solvers iterate with a matrix factorised less often than Newton's (setSolver). With the
// constant matrix each iteration solves with the model's constant stiffness L >= K in place of the
// tangent, factorised once per step size: no tangent is built (projective dynamics' global step,
// Liu et al. 2013). With the lagged tangent it solves with K at a recent state, factorised again
// every refresh_steps solves, at a new step size, and within a solve that is slow to converge (a
// chord method); where that K + inertia is not positive definite, with L until the next refresh.
// Either matrix is positive definite, so the plain step descends G; where an iterate goes uphill
// it is backtracked (Armijo). Anderson mixing of the last iterates (Walker and Ni 2011) is kept where
// it descends too (Peng et al. 2018).
class ImplicitNewmark : public Integrator
{
public:
  ImplicitNewmark(MassDamping system, double dt, int max_iterations = 50, double hht_alpha = 0.0,
                  double tolerance = 1e-9, TangentSolverKind linear_solver = TangentSolverKind::BlockJacobiCg);
  // The symmetric tangents' solver, for its counters.
  const TangentSolver& linearSolver() const { return *linear_solver_; }
  // Another solver of the symmetric tangents in place of the one of the kind given at construction
  // (a benchmark's own kinds).
  void setLinearSolver(std::unique_ptr<TangentSolver> solver) { linear_solver_ = std::move(solver); }
  bool step(ForceModel& model, const State& state, State& next) override;
  int lastIterations() const override { return last_iterations_; }
  int lastSubsteps() const override { return substeps_; }
  void setNewtonStart(NewtonStart start) { start_ = start; }
  // The largest relative linear residual |R + J delta| / |R| of an inexact Newton direction.
  void setMaxForcing(double forcing) { max_forcing_ = forcing; }
  // The constant matrix or the lagged tangent are used where R is a gradient (no gyroscopic or
  // non-symmetric force) and the model is not linear; Newton's tangent otherwise.
  void setSolver(ImplicitSolver solver, int refresh_steps = 20);

private:
  // Anderson mixing's depth, chosen by measurement (docs/benchmarks.md); the constant matrix
  // converges linearly, so it may take this many times Newton's iterations. A lagged tangent is
  // factorised again at the current iterate after kRefreshIterations iterations of one solve.
  static constexpr int kAndersonDepth = 10;
  static constexpr int kConstantMatrixIterations = 10;
  static constexpr int kRefreshIterations = 20;
  static constexpr int kMaxHalvings = 4;
  void setStepSize(double h);
  bool advance(ForceModel& model, const State& s, State& next, double h, int depth);
  // The step's predicted q (Newmark's y, predicted_), the HHT terms of the step's start (old_terms_)
  // and the first iterate next.q.
  void predict(ForceModel& model, const State& s, State& next);
  // One Newton solve of a step of size h_.
  bool solve(ForceModel& model, const State& s, State& next);
  // Backtracks next.q + fraction delta until G (`incremental`; without symmetry, the residual)
  // decreases enough; false, with next.q and the residual as they were, when no fraction does.
  bool lineSearch(ForceModel& model, const State& s, State& next, const Eigen::VectorXd& delta, double residual_norm,
                  bool symmetric, const std::function<double(const Eigen::VectorXd&)>& incremental);
  // The same step by iterations with the constant matrix or the lagged tangent; `incremental` is G.
  bool solveWithFactor(ForceModel& model, const State& s, State& next,
                       const std::function<double(const Eigen::VectorXd&)>& incremental);
  // Makes the iteration matrix of this solve ready, factorised anew where it is stale or `refresh`
  // (the lagged tangent at q); false where the model has neither a positive definite tangent nor L.
  bool prepareFactor(ForceModel& model, const Eigen::VectorXd& q, bool refresh);
  // Factorises inertia + (1 + alpha) stiffness for the step size h_.
  bool factorize(const ForceModel& model, const SparseMatrix& stiffness);
  // The iteration matrix's inverse times rhs.
  Eigen::VectorXd applyFactor(const Eigen::VectorXd& rhs) const;
  // The Newton direction -J^-1 R at next.q (empty when J cannot be factorised); with a symmetric J it
  // may leave a residual |R + J delta| up to `slack`.
  Eigen::VectorXd direction(ForceModel& model, const State& next, bool symmetric, double slack);
  void gyroscopicChanged() override;
  // jacobian_ <- inertia_factor inertia_ + tangent_factor tangent_
  void assembleJacobian(double inertia_factor, double tangent_factor);
  // blocks <- the inertia's diagonal blocks of block_size dofs (block_size^2 values each, column-major).
  void inertiaBlocks(int block_size, Eigen::VectorXd& blocks) const;
  // a' and v' that the Newmark relations give for a trial q'.
  void kinematics(const State& s, State& next) const;
  // Sets next.v, next.a from next.q, stores R(q') in residual_ and returns its norm.
  double residual(ForceModel& model, const State& s, State& next);
  // The residual below which round-off hides any further progress.
  double roundoff(const ForceModel& model, const State& next) const;

  const double alpha_, beta_, gamma_;  // HHT alpha and the Newmark parameters it implies
  int max_iterations_;
  double tolerance_;
  NewtonStart start_ = NewtonStart::ConstantVelocity;
  double max_forcing_ = 1e-3;
  int last_iterations_ = 0;
  int substeps_ = 0;
  double h_ = 0.0;             // the step size being solved
  SparseMatrix mass_matrix_;
  std::unique_ptr<TangentSolver> linear_solver_;
  Eigen::SparseLU<SparseMatrix> lu_;
  SparsityPattern lu_pattern_;  // what lu_ was analysed for
  SparseMatrix damping_;  // C + G
  SparseMatrix inertia_;  // M / (beta h^2) + (1 + alpha) gamma / (beta h) (C + G)
  SparseMatrix tangent_, jacobian_;
  // The inertia's values at their places in the tangent's pattern, when it holds them (the full model),
  // so that J is assembled without a sparse sum; for the tangent pattern recorded.
  SparsityPattern tangent_pattern_;
  Eigen::VectorXd inertia_on_tangent_;
  Eigen::VectorXd inertia_diagonal_;  // the inertia's diagonal when it has nothing else (else empty)
  Eigen::VectorXd jacobian_blocks_;   // J's diagonal blocks for a product without J
  bool inertia_mapped_ = false, inertia_fits_ = false;
  Eigen::VectorXd force_, residual_;
  Eigen::VectorXd old_terms_;  // alpha (C v - F(q)): the HHT part of R from the start of the step
  Eigen::VectorXd predicted_;  // y = q + h v + h^2 (1/2 - beta) a: q' = y + beta h^2 a
  double inertial_norm_ = 0.0;  // |M a' + C v'| at the last residual
  // The iteration matrix of the constant matrix or the lagged tangent: the inertia plus L (from the
  // model at the first use) or a lagged K, factorised dense (modal coordinates) or sparse, for the
  // step size factor_h_ (0: none), solves_since_factor_ solves ago.
  ImplicitSolver solver_ = ImplicitSolver::Newton;
  int refresh_steps_ = 20;
  int solves_since_factor_ = 0;
  SparseMatrix constant_stiffness_;
  double factor_h_ = 0.0;
  bool factor_dense_ = false;
  Eigen::LLT<Eigen::MatrixXd> dense_factor_;
  Eigen::SimplicialLLT<SparseMatrix> sparse_factor_;
};

}  // namespace modal_mass_spring
