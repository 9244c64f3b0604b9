// One object per method: its coordinates q, its force model and integrator, and the map between q
// and free-dof displacements u (from the linearization point): u = q for `full`, u = offset + Phi X
// for the modal methods.
#pragma once

#include "modal_mass_spring/contact.h"
#include "modal_mass_spring/cubature.h"
#include "modal_mass_spring/force_model.h"
#include "modal_mass_spring/grid.h"
#include "modal_mass_spring/handles.h"
#include "modal_mass_spring/modal_basis.h"
#include "modal_mass_spring/options.h"
#include "modal_mass_spring/self_collision.h"
#include "dynamics/integrator.h"
#include "reduction/coarse_grid.h"

#include <Eigen/Core>

#include <memory>

namespace modal_mass_spring
{

// The parts of a linearized grid that every method refers to. The Simulation owns them and never
// moves, so the references stay valid for the methods' lifetime.
struct LinearizedGrid
{
  const Grid& grid;
  const ModalBasis& basis;
  const Eigen::VectorXd& x_ref;   // linearization point: q = 0 stands for it
  const SparseMatrix& stiffness;  // K(x_ref) on the free dofs
  const Eigen::VectorXd& mass;    // the diagonal of M on the free dofs
  const Cubature* cubature = nullptr;  // the trained springs and weights, for `cubature`
  // With handles: K_ib at x_ref, and the constraint modes Psi (needed by the modal methods only).
  const SparseMatrix* handle_coupling = nullptr;
  const Eigen::MatrixXd* constraint_modes = nullptr;
  // Psi is the static response -K_ii^-1 K_ib (Craig-Bampton); false for another particular solution
  // of the handles (the skinning span's), whose stiffness coupling K_ii Psi + K_ib is not zero.
  bool static_constraint_modes = true;
  // `coarse`'s grid (built when the method is first used; null before).
  const CoarseGrid* coarse = nullptr;
};

// A method's force model plus a constant external load G in the same coordinates: F(q) + G, with
// the load's potential -G . q in the energy, so that a constant load keeps the dynamics conservative
// and the divergence check meaningful.
class LoadedForceModel : public ForceModel
{
public:
  explicit LoadedForceModel(ForceModel& inner) : inner_(inner) { roundoff_ = inner.roundoff(); }
  void setLoad(const Eigen::VectorXd& load) { load_ = load; }
  int size() const override { return inner_.size(); }
  void force(const Eigen::VectorXd& q, Eigen::VectorXd& f) override
  {
    inner_.force(q, f);
    if (load_.size() > 0)
      f += load_;
    if (linear_)
      f.noalias() -= *linear_ * q;
  }
  double energy(const Eigen::VectorXd& q) override
  {
    return inner_.energy(q) - (load_.size() > 0 ? load_.dot(q) : 0.0);
  }
  void tangentStiffness(const Eigen::VectorXd& q, SparseMatrix& k) override
  {
    inner_.tangentStiffness(q, k);
    if (linear_)
      k += *linear_;
  }
  bool isLinear() const override { return inner_.isLinear(); }
  bool isSymmetric() const override { return !linear_ && inner_.isSymmetric(); }
  int blockSize() const override { return inner_.blockSize(); }
  // The load is constant: K is the inner model's, so are its springs' blocks; L has none.
  const SpringTangent* springTangent(const Eigen::VectorXd& q) override
  {
    return linear_ ? nullptr : inner_.springTangent(q);
  }
  bool constantStiffness(SparseMatrix& l) override { return !linear_ && inner_.constantStiffness(l); }
  // A force -L q linear in q (a turning frame's Euler and centrifugal forces), L kept by the caller;
  // null: none. It has no potential in energy(): the energy check is off while a frame moves.
  void setLinearTerm(const SparseMatrix* l) { linear_ = l; }

private:
  ForceModel& inner_;
  Eigen::VectorXd load_;              // empty: no load
  const SparseMatrix* linear_ = nullptr;  // L; null: none
};

// What a method's integrator is built from besides its force model.
struct IntegratorSettings
{
  IntegratorKind kind = IntegratorKind::Explicit;
  double time_step = 1e-3;
  int newton_max_iterations = 50;
  double hht_alpha = 0.0;          // the implicit integrator's HHT alpha
  double alpha = 0.0, beta = 0.0;  // Rayleigh damping alpha M + beta K(x_ref)
  ImplicitSolver solver = ImplicitSolver::Newton;
  int tangent_refresh_steps = 20;  // lagged_tangent only
};

// What a method does with the part of a displacement its coordinates cannot hold.
enum class Remainder
{
  Keep,  // frozen as an offset of the reference, so that no particle moves (a method switch)
  Drop,  // discarded: the state is the projection (a start or reset)
};

class MethodModel
{
public:
  virtual ~MethodModel() = default;
  Method method() const { return method_; }

  // (Re)builds the integrator, keeping q and v; the acceleration follows from them.
  void configure(const IntegratorSettings& settings);
  const Integrator& integrator() const { return *integrator_; }

  // Sets q and v from a free-dof displacement and velocity, with zero offset unless `remainder` is
  // Keep. Returns the largest particle distance (m) between the requested and the represented
  // positions (0 with Keep).
  virtual double assign(const Eigen::VectorXd& u, const Eigen::VectorXd& v, Remainder remainder) = 0;
  virtual Eigen::VectorXd displacement(const State& s) const = 0;
  virtual Eigen::VectorXd velocity(const State& s) const = 0;
  // Free dof k's entry of displacement(s) and velocity(s), in O(size of q) rather than O(n size of q):
  // for following one particle every step (a drag).
  virtual double displacementAt(const State& s, int k) const = 0;
  virtual double velocityAt(const State& s, int k) const = 0;
  // The same of many free dofs, u[i] and v[i] of k[i]: where the entries share work (`coarse`'s
  // coarse positions), read faster than one at a time.
  virtual void statesAt(const State& s, const std::vector<int>& k, Eigen::VectorXd& u, Eigen::VectorXd& v) const;
  virtual double kineticEnergy(const State& s) const = 0;
  // Sets the displacement that distances are measured from (the start of the run), with the handle
  // dofs' displacement then (empty: at rest), and measures a state's mass-weighted squared distance
  // |u(q) - anchor|_M^2 from it, in O(size of q).
  virtual void setAnchor(const Eigen::VectorXd& u_anchor, const Eigen::VectorXd& handles_anchor) = 0;
  virtual double anchorDistanceSquared(const Eigen::VectorXd& q) const = 0;
  // Kinetic plus potential energy in this method's own measure, the one its dynamics conserve
  // without damping: the physical energy for `full` and `physical`, the quadratic model's for
  // `linear`, the weighted springs' for `cubature`; with an external force, plus its potential.
  double energy(const State& s) { return kineticEnergy(s) + loaded_.energy(s.q); }
  // Sets the external force on the free dofs (N, physical coordinates; empty or zero: none), which
  // then acts like the springs and gravity; the state keeps q and v, its acceleration follows.
  void setExternalForce(const Eigen::VectorXd& f_free);
  // Prescribes the handle dofs' motion for the forces evaluated from now on (the end of the next
  // step); the state, its acceleration included, is left as it is.
  virtual void setHandleMotion(const HandleMotion& motion) = 0;
  // Simulates in a moving frame B (handle_formulation moving_frame): its forces for the end of the
  // next step, as setHandleMotion; q then measures positions in B, and the external force (world)
  // is turned into B. The state is left as it is.
  void setFrameForces(const FrameForces& frame);

  // Takes one step from state() into next(); false when the integrator refuses it. commit() makes
  // next() the state.
  bool step() { return integrator_->step(loaded_, state_, next_); }
  void commit() { std::swap(state_, next_); }
  const State& state() const { return state_; }
  const State& next() const { return next_; }
  // The frozen offset (free dofs; empty for `full`), and a saved state put back as it was: q, v, a and
  // the offset, with no projection and no acceleration recomputed (a step's contact correction
  // leaves a as the forces gave it, which the next step starts from).
  virtual Eigen::VectorXd offset() const { return Eigen::VectorXd(); }
  virtual void restore(const State& state, const Eigen::VectorXd& offset);
  // Corrects next() for contact with the colliders (Contact), before commit(): per particle for
  // `full`, through the basis for the modal methods. The acceleration is left as the forces gave it.
  virtual void correctContacts(Contact& contact) = 0;
  // Per free particle of the grid: the collider it touched in the last step's correction, -1 none.
  virtual std::vector<int> touchedBy(const Contact& contact) const { return contact.report().touched_by; }
  // Corrects next() for self-collision, before commit(): `full` only (the Simulation refuses it for
  // the modal methods; they throw std::logic_error). `contact`: the colliders whose correctContacts
  // ran on this same next() just before (null: none).
  virtual void correctSelfCollision(SelfCollision& self, const Contact* contact);

protected:
  MethodModel(Method method, const LinearizedGrid& linearized, std::unique_ptr<ForceModel> force);
  // Mass and damping in this method's coordinates.
  virtual MassDamping massDamping(double alpha, double beta) const = 0;
  // A free-dof force in this method's coordinates.
  virtual Eigen::VectorXd generalizedForce(const Eigen::VectorXd& f_free) const = 0;
  // Sets the state to (q, v), with the acceleration the forces give.
  void setState(const Eigen::VectorXd& q, const Eigen::VectorXd& v);
  ForceModel& forceModel() { return *force_; }
  // The generalized load the handles' motion adds (their velocity through damping, their
  // acceleration through inertia); empty: none.
  void setHandleLoad(const Eigen::VectorXd& load);
  // B's forces in this method's coordinates: the load at q = 0, the linear force's matrix L (the
  // force -L q) and the gyroscopic G (the force -G q'); L and G are the last call's, to be updated
  // in place where their pattern allows.
  virtual void frameTerms(const FrameForces& frame, Eigen::VectorXd& load, SparseMatrix& linear,
                          SparseMatrix& gyroscopic) = 0;
  // Computes the frame's terms again (after the reference they depend on moved).
  void applyFrame();
  State& mutableNext() { return next_; }
  // x_ref on the free dofs (computed when first asked for).
  const Eigen::VectorXd& freeReference();

  const LinearizedGrid lin_;
  IntegratorSettings settings_;

private:
  Method method_;
  std::unique_ptr<ForceModel> force_;
  void updateLoad();

  // The external force on the free dofs (world), turned into B when a frame turns.
  Eigen::VectorXd bodyExternalForce() const;

  Eigen::VectorXd free_reference_;
  LoadedForceModel loaded_;  // force_ plus the external force and handle load: what the integrator sees
  Eigen::VectorXd external_free_;  // world, free dofs; empty: none
  Eigen::VectorXd external_load_, handle_load_, frame_load_;  // generalized; empty: none
  FrameForces frame_;
  SparseMatrix frame_linear_, frame_gyroscopic_;  // L and G
  std::unique_ptr<Integrator> integrator_;
  State state_, next_;
};

// `full`: q = u.
class FullMethod : public MethodModel
{
public:
  FullMethod(const LinearizedGrid& linearized, const IntegratorSettings& settings);
  // `full` on another grid standing for this one (`coarse`).
  FullMethod(Method method, const LinearizedGrid& linearized, const IntegratorSettings& settings);
  double assign(const Eigen::VectorXd& u, const Eigen::VectorXd& v, Remainder remainder) override;
  Eigen::VectorXd displacement(const State& s) const override { return s.q; }
  Eigen::VectorXd velocity(const State& s) const override { return s.v; }
  double displacementAt(const State& s, int k) const override { return s.q[k]; }
  double velocityAt(const State& s, int k) const override { return s.v[k]; }
  double kineticEnergy(const State& s) const override;
  // Measured relative to the handles: the handle particles' mean displacement since the anchor is
  // taken off every free particle's (the free dofs hold the whole motion, which handles carried
  // 100 m are not diverged by; the modal methods' q holds none of the handles' static influence).
  void setAnchor(const Eigen::VectorXd& u_anchor, const Eigen::VectorXd& handles_anchor) override;
  double anchorDistanceSquared(const Eigen::VectorXd& q) const override;
  // The handle particles sit at their prescribed positions; their velocity damps the interior
  // through the coupling of Rayleigh damping, -beta K_ib v_b.
  void setHandleMotion(const HandleMotion& motion) override;
  void correctContacts(Contact& contact) override;
  void correctSelfCollision(SelfCollision& self, const Contact* contact) override;

private:
  MassDamping massDamping(double alpha, double beta) const override;
  Eigen::VectorXd generalizedForce(const Eigen::VectorXd& f_free) const override { return f_free; }
  // Per particle: m (uniform - position y_ref), m position and 2 m spin, 3 x 3 blocks.
  void frameTerms(const FrameForces& frame, Eigen::VectorXd& load, SparseMatrix& linear,
                  SparseMatrix& gyroscopic) override;
  // The handle particles' mean displacement (dimension values; empty without handles or at rest).
  Eigen::VectorXd handleTranslation(const Eigen::VectorXd& handle_displacement) const;
  Eigen::VectorXd anchor_;
  Eigen::VectorXd anchor_translation_;  // the handles' at the anchor
  Eigen::VectorXd handle_displacement_;  // the prescribed handle dofs' displacement (empty: at rest)
  Eigen::VectorXd y_ref_;  // x_ref on the free dofs, once a frame moves
  // The contact pass's absolute end and start positions, kept between steps (no allocation a step).
  Eigen::VectorXd contact_x_, contact_start_;
};

// `linear`, `physical` and `cubature`: q = X, u = offset + Phi X with a mass-orthonormal Phi. With
// handles (Craig-Bampton), Phi are the fixed-interface modes and u = Psi dx_b + offset + Phi X:
// `linear` keeps its force linearized at x_ref (whose static response to the handles is Psi dx_b
// exactly), the others evaluate the forces at x_ref + Psi dx_b + offset + Phi X with the handles at
// x_b; every method adds the inertial load -Phi^T M Psi (a_b + alpha v_b) of the moving interface.
class ModalMethod : public MethodModel
{
public:
  ModalMethod(Method method, const LinearizedGrid& linearized, const IntegratorSettings& settings);
  double assign(const Eigen::VectorXd& u, const Eigen::VectorXd& v, Remainder remainder) override;
  Eigen::VectorXd displacement(const State& s) const override;
  Eigen::VectorXd velocity(const State& s) const override;
  double displacementAt(const State& s, int k) const override;
  double velocityAt(const State& s, int k) const override;
  // Phi is mass-orthonormal: 1/2 V^T V is the kinetic energy of u' = Phi V.
  double kineticEnergy(const State& s) const override { return 0.5 * s.v.squaredNorm(); }
  void setAnchor(const Eigen::VectorXd& u_anchor, const Eigen::VectorXd& handles_anchor) override;
  double anchorDistanceSquared(const Eigen::VectorXd& q) const override;
  void setHandleMotion(const HandleMotion& motion) override;
  Eigen::VectorXd offset() const override { return offset_; }
  void restore(const State& state, const Eigen::VectorXd& offset) override;
  // The touching particles' impulses through Phi (Contact::correctModal): O(n r) to find them.
  void correctContacts(Contact& contact) override;

private:
  MassDamping massDamping(double alpha, double beta) const override;
  // Phi^T f from the rows of the dofs the force touches.
  Eigen::VectorXd generalizedForce(const Eigen::VectorXd& f_free) const override;
  // The frame's per-particle terms projected, from the products of Phi's components below: O(r^2)
  // per step whatever the grid's size.
  void frameTerms(const FrameForces& frame, Eigen::VectorXd& load, SparseMatrix& linear,
                  SparseMatrix& gyroscopic) override;
  // Built at the first moving frame: with Phi_j the rows of Phi for component j (x, y, z),
  // S_jk = Phi_j^T M Phi_k (r x r), U_j = Phi_j^T M 1 and W_jk = Phi_j^T M y_k, y = x_ref + offset.
  struct FrameProjection
  {
    std::vector<Eigen::MatrixXd> s;  // index j * dim + k
    std::vector<Eigen::VectorXd> u, w;
    bool w_stale = true;  // the offset moved since W was computed
  };
  void projectFrame();
  std::unique_ptr<FrameProjection> frame_projection_;
  void setOffset(const Eigen::VectorXd& offset);
  // Moves the force model's reference to x_ref + offset, plus the handles' displacement (handle
  // dofs) and its static response Psi dx_b (interior) unless the method is `linear`.
  void updateReference();

  ModalForceModel* modal_force_;  // owned by the base
  Eigen::VectorXd offset_;        // free-dof displacement the modes cannot hold, frozen
  HandleMotion handle_motion_;
  // Psi dx_b and Psi v_b, the interior's part carried by the handles: O(interior x handle dofs),
  // so computed when asked for (every step for the nonlinear forces, only on output for `linear`).
  const Eigen::VectorXd& psiDx() const;
  const Eigen::VectorXd& psiV() const;
  mutable Eigen::VectorXd psi_dx_, psi_v_;  // empty without handles
  mutable bool psi_dx_stale_ = false, psi_v_stale_ = false;
  // Psi applied to a handle motion through its affine part (AffineHandleFit): Psi H (interior x
  // dim (dim + 1)) makes Psi dx_b O(interior) when the handles move as one rigid or affine body.
  void applyPsi(const Eigen::VectorXd& dx, Eigen::VectorXd& out) const;
  AffineHandleFit handle_fit_;
  Eigen::MatrixXd psi_affine_;
  // `cubature` moves its reference with the handles itself, through its springs' rows of Psi only
  // (CubatureForceModel::moveHandles): the step then touches no full-size vector. Null otherwise.
  CubatureForceModel* cubature_force_ = nullptr;
  Eigen::VectorXd reference_handles_;  // dx_b at the force model's last setReference
  Eigen::MatrixXd interface_mass_;  // Phi^T M Psi (r x handle dofs)
  Eigen::MatrixXd interface_mass_affine_;  // Phi^T M Psi H (r x the handles' affine maps), with psi_affine_
  // Phi^T (K_ii Psi + K_ib): the stiffness-proportional damping of the handles' velocity; empty when
  // Psi is static (zero).
  Eigen::MatrixXd interface_stiffness_;
  Eigen::VectorXd anchor_;
  // |offset + Phi X - anchor|_M^2 = c + 2 b.X + X.X with b = Phi^T M (offset - anchor).
  Eigen::VectorXd anchor_b_;
  double anchor_c_ = 0.0;
};

// `coarse`: `full` on the coarse grid (reduction/coarse_grid.h), its q the coarse free dofs'
// displacement from the coarse rest; the fine grid's free dofs follow by interpolation,
// u = offset + P x_c - x_ref, reconstructed only when read. The fine handle motion moves the coarse
// handle particles; contact is the coarse particles' against the simulation's colliders.
class CoarseMethod : public FullMethod
{
public:
  // `fine`: the simulation's grid, with fine.coarse set.
  CoarseMethod(const LinearizedGrid& fine, const IntegratorSettings& settings);
  // Samples the fine displacement and velocity at the coarse particles and freezes what the
  // interpolation of the sample misses as the offset, whatever `remainder` says: a start is then as
  // exact as a switch. Dropped, the detail below the coarse spacing of a hanging cloth was 2 mm of
  // error from the first step, and most of the error indicator at rest (docs/results.md).
  double assign(const Eigen::VectorXd& u, const Eigen::VectorXd& v, Remainder remainder) override;
  Eigen::VectorXd displacement(const State& s) const override;
  Eigen::VectorXd velocity(const State& s) const override;
  double displacementAt(const State& s, int k) const override;
  double velocityAt(const State& s, int k) const override;
  void statesAt(const State& s, const std::vector<int>& k, Eigen::VectorXd& u, Eigen::VectorXd& v) const override;
  void setAnchor(const Eigen::VectorXd& u_anchor, const Eigen::VectorXd& handles_anchor) override;
  void setHandleMotion(const HandleMotion& motion) override;
  Eigen::VectorXd offset() const override { return offset_; }
  void restore(const State& state, const Eigen::VectorXd& offset) override;
  // The coarse particles against colliders posed as the simulation's; `contact` takes their report
  // (its particles the coarse ones) but for touched_by, which touchedBy() gives when asked: a fine
  // particle touches what the heaviest of its stencil touched.
  void correctContacts(Contact& contact) override;
  std::vector<int> touchedBy(const Contact& contact) const override;
  // The coarse grid's every dof: its rest plus q on the free dofs and the handles' displacement.
  Eigen::VectorXd coarsePositions(const Eigen::VectorXd& q) const;
  // The coarse handle particles' motion (copied from the grid's handle particles).
  const HandleMotion& coarseHandleMotion() const { return coarse_motion_; }

private:
  // P^T f: a fine free-dof force on the coarse free dofs.
  Eigen::VectorXd generalizedForce(const Eigen::VectorXd& f_free) const override;
  Eigen::VectorXd coarseVelocities(const Eigen::VectorXd& v) const;
  // A fine free-dof displacement (velocity) with the fine handle dofs' (empty: zero) sampled at the
  // coarse free dofs: their displacement from the coarse rest (their velocity).
  Eigen::VectorXd sampleDisplacement(const Eigen::VectorXd& u, const Eigen::VectorXd& handles) const;
  Eigen::VectorXd sampleVelocity(const Eigen::VectorXd& v, const Eigen::VectorXd& handles) const;
  HandleMotion coarseMotion(const HandleMotion& fine) const;
  // Fine free dof k interpolated from the coarse free dofs' values, the handle dofs' and a rest
  // (every coarse dof; empty: zero).
  double interpolateAt(const Eigen::VectorXd& free, const Eigen::VectorXd& handles, const Eigen::VectorXd& rest,
                       int k) const;

  const LinearizedGrid fine_;
  const CoarseGrid& coarse_;
  Eigen::VectorXd fine_reference_;  // x_ref on the fine free dofs
  Eigen::VectorXd offset_;          // fine free dofs; empty: none
  HandleMotion fine_motion_, coarse_motion_;
  std::vector<int> handle_index_;     // per coarse dof: its index in the coarse handle dofs, -1 none
  std::unique_ptr<Contact> contact_;  // built at the first contact
};

std::unique_ptr<MethodModel> makeMethod(Method method, const LinearizedGrid& linearized,
                                        const IntegratorSettings& settings);

}  // namespace modal_mass_spring
