// The package's methods beside Bullet's deformable world on the same swinging cloth, in one run: the
// cost of simulating it with `full` (implicit and explicit), `physical` and `cubature` against a cloth
// solver users know, per step and per simulated second.
//
// The cloth is core_benchmark's BM_ImplicitFullSolver's (config/cloth_large.yaml's at n x n): 0.99 m
// wide, 2 kg in all, structural/shear/bending springs of 200/80/20 N/m, top row fixed, released 60
// degrees out of the vertical, 5 ms steps. The package steps it through its Simulation API (method
// full, implicit integrator, mass damping alpha = 0.5 /s, HHT alpha -0.1, Newton converged to its
// default tolerance every step). Bullet steps a btSoftBody with the same particles and the same links
// (one per spring of the package's grid, the bending ones flagged as bending) in a
// btDeformableMultiBodyDynamicsWorld with a btDeformableMassSpringForce and a btDeformableGravityForce,
// in its implicit mode (backward Euler: Newton iterations of a conjugate gradient solve each, the fixed
// nodes projected out; its default semi-implicit mode takes the springs explicitly: --semi-implicit).
// Where the two models differ (docs/benchmarks.md, "Against Bullet's deformable world"):
// - Bullet's mass-spring force has one stiffness for every link but the bending ones: its shear links
//   get the structural 200 N/m, not 80.
// - Bullet has no mass-proportional damping, and its implicit mode drops the soft body's drag: the
//   package's alpha M is added as a force of this benchmark's (MassDampingForce). Bullet's spring
//   damping (--bullet-damping, along the links) is 0, as the package's beta.
// - Bullet's Newton takes one iteration a step (its default, printed as read from its solver: it
//   linearises backward Euler once, a step is not converged); the package's Newton converges to 1e-9
//   of the forces.
// Beside the implicit `full` row, the package steps the same cloth with explicit `full` at the largest
// step it takes (--explicit-step; by default 1 ms up to 50 x 50, 0.5 ms up to 100 x 100, 0.25 ms up to
// 200 x 200), and with `physical` and `cubature` on --modes modes at the hanging equilibrium
// (config/cloth_large.yaml's set-up), implicit at 5 ms and explicit at --modal-explicit-step. Building
// each Simulation (equilibrium, basis, cubature training) is timed once and printed as its start-up,
// never in the step times; the modal rows share a precomputation cache (a fresh folder unless
// --cache-dir), so the first computes the basis, the first `cubature` trains, the others load them.
// The per-step times are medians over the steps, and every row also gives its time per simulated
// second (the median step over the step size), which compares rows at different steps. All solvers run
// in alternating blocks covering the same simulated time (--block 5 ms steps; an explicit row takes as
// many of its steps) so that all see the same load. A sample of every trajectory (the centre of mass's
// angle from the vertical and its distance from the top row) shows how each swings.
//
// Usage: bullet_peer [--sizes 50,100] [--steps 200] [--block 10] [--explicit-step MS]
//                    [--modal-explicit-step 1] [--modes 30] [--cache-dir DIR | --no-cache]
//                    [--bullet-damping 0] [--bullet-newton-iterations N]
//                    [--bullet-newton-tolerance T] [--bullet-krylov-tolerance T] [--semi-implicit]
// (--modes 0: no modal rows; --modal-explicit-step 0: no explicit modal rows.)
// Built against Bullet's double-precision build (bullet_peer) and, where installed, its single-precision
// one (bullet_peer_float, what pkg-config's `bullet` links): its Krylov tolerance is btScalar's epsilon.
#include "modal_mass_spring/cpu_time.h"
#include "modal_mass_spring/simulation.h"
#include "swinging_cloth.h"

#include <BulletCollision/BroadphaseCollision/btDbvtBroadphase.h>
#include <BulletCollision/CollisionDispatch/btCollisionDispatcher.h>
#include <BulletSoftBody/btDeformableBodySolver.h>
#include <BulletSoftBody/btDeformableGravityForce.h>
#include <BulletSoftBody/btDeformableMassSpringForce.h>
#include <BulletSoftBody/btDeformableMultiBodyConstraintSolver.h>
#include <BulletSoftBody/btDeformableMultiBodyDynamicsWorld.h>
#include <BulletSoftBody/btSoftBody.h>
#include <BulletSoftBody/btSoftBodyRigidBodyCollisionConfiguration.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

using namespace modal_mass_spring;

namespace
{

constexpr double kTimeStep = 0.005;  // s
constexpr double kAlpha = 0.5;       // 1/s, the package's mass damping

struct Options
{
  std::vector<int> sizes{50, 100};
  int steps = 200;
  int block = 10;
  double bullet_damping = 0.0;        // N s/m along each link
  int bullet_newton_iterations = -1;  // -1: Bullet's default
  double bullet_newton_tolerance = -1.0;
  double bullet_krylov_tolerance = -1.0;  // -1: Bullet's default
  bool semi_implicit = false;
  double explicit_step = -1.0;       // s, full explicit; -1: defaultExplicitStep(n)
  double modal_explicit_step = 1e-3; // s, physical and cubature explicit; 0: no such rows
  int modes = 30;                    // physical and cubature's; 0: no modal rows
  std::string cache_dir;             // empty: a fresh folder, removed at the end
  bool no_cache = false;
};

[[noreturn]] void refuse(const std::string& what)
{
  std::cerr << "bullet_peer: " << what << "\n"
            << "usage: bullet_peer [--sizes 50,100] [--steps 200] [--block 10] [--explicit-step MS]\n"
            << "                   [--modal-explicit-step 1] [--modes 30] [--cache-dir DIR | --no-cache]\n"
            << "                   [--bullet-damping 0] [--bullet-newton-iterations N]\n"
            << "                   [--bullet-newton-tolerance T] [--bullet-krylov-tolerance T] [--semi-implicit]\n";
  std::exit(2);
}

double number(const std::string& flag, const std::string& text)
{
  std::size_t used = 0;
  double value = 0.0;
  try
  {
    value = std::stod(text, &used);
  }
  catch (const std::exception&)
  {
    used = 0;
  }
  if (used != text.size() || !std::isfinite(value))
    refuse(flag + " '" + text + "': must be a finite number");
  return value;
}

int whole(const std::string& flag, const std::string& text, int least, int most)
{
  const double value = number(flag, text);
  if (value != std::floor(value) || value < least || value > most)
    refuse(flag + " '" + text + "': must be a whole number in [" + std::to_string(least) + ", " +
           std::to_string(most) + "]");
  return static_cast<int>(value);
}

Options parse(int argc, char** argv)
{
  Options o;
  for (int i = 1; i < argc; ++i)
  {
    const std::string flag = argv[i];
    if (flag == "--semi-implicit" || flag == "--no-cache")
    {
      (flag == "--semi-implicit" ? o.semi_implicit : o.no_cache) = true;
      continue;
    }
    if (i + 1 >= argc)
      refuse(flag == "--sizes" || flag == "--steps" || flag == "--block" || flag == "--bullet-damping" ||
                     flag == "--bullet-newton-iterations" || flag == "--bullet-newton-tolerance" ||
                     flag == "--bullet-krylov-tolerance" || flag == "--explicit-step" ||
                     flag == "--modal-explicit-step" || flag == "--modes" || flag == "--cache-dir"
                 ? flag + ": needs a value"
                 : "unknown argument '" + flag + "'");
    const std::string value = argv[++i];
    if (flag == "--sizes")
    {
      o.sizes.clear();
      std::stringstream list(value);
      std::string item;
      while (std::getline(list, item, ','))
        o.sizes.push_back(whole("--sizes", item, 3, 400));
      if (o.sizes.empty())
        refuse("--sizes '" + value + "': give one or more grid sizes n (3 to 400), separated by commas");
    }
    else if (flag == "--steps")
      o.steps = whole(flag, value, 1, 100000);
    else if (flag == "--block")
      o.block = whole(flag, value, 1, 100000);
    else if (flag == "--explicit-step" || flag == "--modal-explicit-step")
    {
      // ms; a whole number of them make the others' 5 ms step, so that all cover the same time.
      const double ms = number(flag, value);
      const double ratio = 1e3 * kTimeStep / ms;
      if (flag == "--modal-explicit-step" && ms == 0.0)
        o.modal_explicit_step = 0.0;
      else if (ms <= 0.0 || ratio > 10000.0 || std::abs(ratio - std::round(ratio)) > 1e-9 * ratio)
        refuse(flag + " '" + value + "': must be a step in ms that divides 5 ms (5, 2.5, 1, 0.5, 0.25, ...)" +
               (flag == "--modal-explicit-step" ? ", or 0 for no such rows" : ""));
      else
        (flag == "--explicit-step" ? o.explicit_step : o.modal_explicit_step) = kTimeStep / std::round(ratio);
    }
    else if (flag == "--modes")
      o.modes = whole(flag, value, 0, 500);
    else if (flag == "--cache-dir")
    {
      if (value.empty())
        refuse("--cache-dir '': must be a folder (or --no-cache)");
      o.cache_dir = value;
    }
    else if (flag == "--bullet-damping")
    {
      o.bullet_damping = number(flag, value);
      if (o.bullet_damping < 0.0)
        refuse("--bullet-damping '" + value + "': must be >= 0 (N s/m along each link)");
    }
    else if (flag == "--bullet-newton-iterations")
      o.bullet_newton_iterations = whole(flag, value, 1, 1000);
    else if (flag == "--bullet-newton-tolerance")
    {
      o.bullet_newton_tolerance = number(flag, value);
      if (o.bullet_newton_tolerance <= 0.0)
        refuse("--bullet-newton-tolerance '" + value + "': must be > 0 (N s, the norm of Bullet's residual)");
    }
    else if (flag == "--bullet-krylov-tolerance")
    {
      o.bullet_krylov_tolerance = number(flag, value);
      if (o.bullet_krylov_tolerance <= 0.0 || o.bullet_krylov_tolerance >= 1.0)
        refuse("--bullet-krylov-tolerance '" + value + "': must be in (0, 1) (Bullet's relative Krylov tolerance)");
    }
    else
      refuse("unknown argument '" + flag + "'");
  }
  if (o.no_cache && !o.cache_dir.empty())
    refuse("--cache-dir '" + o.cache_dir + "': must not be given with --no-cache");
  return o;
}

// Bullet's mass-spring force, counting what its solver asks of it: the force evaluations (one per
// Newton iteration and one more a step) and the products with the elastic tangent (one per Krylov
// iteration and one more per solve).
class CountingMassSpring : public btDeformableMassSpringForce
{
public:
  CountingMassSpring(btScalar k, btScalar d, btScalar bending_k)
    : btDeformableMassSpringForce(k, d, true, bending_k)
  {
  }
  void addScaledForces(btScalar scale, TVStack& force) override
  {
    ++force_evaluations;
    btDeformableMassSpringForce::addScaledForces(scale, force);
  }
  void addScaledElasticForceDifferential(btScalar scale, const TVStack& dx, TVStack& df) override
  {
    ++tangent_products;
    btDeformableMassSpringForce::addScaledElasticForceDifferential(scale, dx, df);
  }
  long force_evaluations = 0;
  long tangent_products = 0;
};

// The package's mass damping -alpha M v as a Bullet force, taken implicitly like Bullet's other
// damping (its differential -alpha M joins the system's matrix): Bullet has no mass-proportional
// damping of its own, and the soft body's drag is dropped in its implicit mode.
class MassDampingForce : public btDeformableLagrangianForce
{
public:
  explicit MassDampingForce(btScalar alpha) : alpha_(alpha) {}
  void addScaledForces(btScalar scale, TVStack& force) override { addScaledDampingForce(scale, force); }
  void addScaledExplicitForce(btScalar, TVStack&) override {}
  void addScaledElasticForceDifferential(btScalar, const TVStack&, TVStack&) override {}
  void addScaledDampingForce(btScalar scale, TVStack& force) override
  {
    forEachFreeNode([&](const btSoftBody::Node& node) { force[node.index] -= scale * alpha_ / node.m_im * node.m_v; });
  }
  void addScaledDampingForceDifferential(btScalar scale, const TVStack& dv, TVStack& df) override
  {
    forEachFreeNode([&](const btSoftBody::Node& node) { df[node.index] -= scale * alpha_ / node.m_im * dv[node.index]; });
  }
  void buildDampingForceDifferentialDiagonal(btScalar scale, TVStack& diagA) override
  {
    forEachFreeNode([&](const btSoftBody::Node& node) {
      diagA[node.index] -= btVector3(1, 1, 1) * (scale * alpha_ / node.m_im);
    });
  }
  // A type of its own: the world merges a force into one of the same type already added (a second
  // mass-spring type would count the springs twice). 7 is none of Bullet's (1 to 6) and within the
  // enumeration's range.
  btDeformableLagrangianForceType getForceType() override { return static_cast<btDeformableLagrangianForceType>(7); }

private:
  template <typename F>
  void forEachFreeNode(F f)
  {
    for (int b = 0; b < m_softBodies.size(); ++b)
      for (int n = 0; n < m_softBodies[b]->m_nodes.size(); ++n)
        if (m_softBodies[b]->m_nodes[n].m_im > 0)
          f(m_softBodies[b]->m_nodes[n]);
  }
  btScalar alpha_;
};

// Bullet's deformable solver, with its Newton and Krylov settings readable (they are protected).
class ReadableSolver : public btDeformableBodySolver
{
public:
  int newtonIterations() const { return m_maxNewtonIterations; }
  double newtonTolerance() const { return m_newtonTolerance; }
  void setNewton(int iterations, double tolerance)
  {
    if (iterations > 0)
      m_maxNewtonIterations = iterations;
    if (tolerance > 0.0)
      m_newtonTolerance = tolerance;
  }
  // Both Krylov solvers' tolerances (the world picks one at every step).
  void setKrylovTolerance(double tolerance)
  {
    if (tolerance > 0.0)
      m_cg.m_tolerance = m_cr.m_tolerance = tolerance;
  }
  // Without projection (the default) Bullet solves with conjugate residuals, else with CG.
  const char* krylovName() const { return m_useProjection ? "conjugate gradients" : "conjugate residuals"; }
  int krylovIterations() const { return m_useProjection ? m_cg.m_maxIterations : m_cr.m_maxIterations; }
  double krylovTolerance() const { return m_useProjection ? m_cg.m_tolerance : m_cr.m_tolerance; }
  const char* preconditionerName() const
  {
    if (m_objective->m_preconditioner == m_objective->m_KKTPreconditioner)
      return "KKT (mass and damping diagonal)";
    if (m_objective->m_preconditioner == m_objective->m_massPreconditioner)
      return "mass";
    return "other";
  }
};

struct BulletCloth
{
  BulletCloth(const Grid& grid, const Options& o)
    : dispatcher(&configuration), solver(new ReadableSolver)
  {
    constraint_solver.setDeformableSolver(solver);
    world = std::make_unique<btDeformableMultiBodyDynamicsWorld>(&dispatcher, &broadphase, &constraint_solver,
                                                                 &configuration, solver);
    const btVector3 gravity(grid.params().gravity.x(), grid.params().gravity.y(), grid.params().gravity.z());
    world->setGravity(gravity);
    world->getWorldInfo().m_gravity = gravity;
    // Implicit: Bullet's Newton on backward Euler. In Bullet 3.24 it moves a cloth only with projection
    // on (conjugate gradients, the fixed nodes projected out, the mass preconditioner): without it,
    // its conjugate-residual path leaves the cloth at rest. Semi-implicit: the world's defaults.
    world->setImplicit(!o.semi_implicit);
    world->setUseProjection(!o.semi_implicit);
    solver->setNewton(o.bullet_newton_iterations, o.bullet_newton_tolerance);
    solver->setKrylovTolerance(o.bullet_krylov_tolerance);

    // The package's particles, the fixed ones massless (Bullet holds a node of mass 0 in place).
    const Eigen::VectorXd& x0 = grid.initialPositions();
    const int count = grid.numParticles();
    std::vector<btVector3> positions(count);
    std::vector<btScalar> masses(count);
    for (int p = 0; p < count; ++p)
    {
      positions[p] = btVector3(x0[3 * p], x0[3 * p + 1], x0[3 * p + 2]);
      masses[p] = grid.isFixed(p) ? 0.0 : grid.particleMass();
    }
    body = new btSoftBody(&world->getWorldInfo(), count, positions.data(), masses.data());
    // One link per spring, rest length the initial distance, as the package's.
    const int bending_from = grid.numStructuralSprings() + grid.numShearSprings();
    for (int s = 0; s < static_cast<int>(grid.springs().size()); ++s)
    {
      body->appendLink(grid.springs()[s].i, grid.springs()[s].j);
      if (s >= bending_from)
        body->m_links[body->m_links.size() - 1].m_bbending = 1;
    }
    // Semi-implicit, the soft body's drag v <- (1 - drag) v once a step stands in for alpha M.
    if (o.semi_implicit)
      body->m_cfg.drag = kAlpha * kTimeStep;
    world->addSoftBody(body);
    springs = new CountingMassSpring(grid.params().structural_stiffness, o.bullet_damping,
                                     grid.params().bending_stiffness);
    world->addForce(body, springs);
    gravity_force = new btDeformableGravityForce(gravity);
    world->addForce(body, gravity_force);
    if (!o.semi_implicit)
    {
      mass_damping = new MassDampingForce(kAlpha);
      world->addForce(body, mass_damping);
    }
  }
  ~BulletCloth()
  {
    world->removeSoftBody(body);
    delete body;
    world.reset();
    delete springs;
    delete gravity_force;
    delete mass_damping;
    delete solver;
  }
  BulletCloth(const BulletCloth&) = delete;
  BulletCloth& operator=(const BulletCloth&) = delete;

  // stepSimulation(dt, 0): one step of exactly dt, no fixed-step interpolation.
  void step() { world->stepSimulation(kTimeStep, 0); }
  Eigen::Matrix3Xd points() const
  {
    Eigen::Matrix3Xd x(3, body->m_nodes.size());
    for (int p = 0; p < body->m_nodes.size(); ++p)
      for (int d = 0; d < 3; ++d)
        x(d, p) = body->m_nodes[p].m_x[d];
    return x;
  }

  btSoftBodyRigidBodyCollisionConfiguration configuration;
  btCollisionDispatcher dispatcher;
  btDbvtBroadphase broadphase;
  btDeformableMultiBodyConstraintSolver constraint_solver;
  ReadableSolver* solver;
  std::unique_ptr<btDeformableMultiBodyDynamicsWorld> world;
  btSoftBody* body = nullptr;
  CountingMassSpring* springs = nullptr;
  btDeformableGravityForce* gravity_force = nullptr;
  MassDampingForce* mass_damping = nullptr;
};

double wallSeconds()
{
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

double median(std::vector<double> v)
{
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

std::string loadAverage()
{
  std::ifstream in("/proc/loadavg");
  std::string one, five, fifteen;
  in >> one >> five >> fifteen;
  return one + " " + five + " " + fifteen;
}

// The centre of mass's angle from the downward vertical about the top row (deg; the cloth starts at
// 60) and its distance from the top row (m; 0.495 for an inextensible sheet), or NaN for a
// non-finite state.
struct Swing
{
  double angle_deg, distance;
};
Swing swing(const Eigen::Matrix3Xd& x, double top_y, double top_z)
{
  if (!x.allFinite())
    return {std::nan(""), std::nan("")};
  const Eigen::Vector3d c = x.rowwise().mean();
  const double dy = c.y() - top_y, dz = c.z() - top_z;
  return {std::atan2(dy, -dz) * 180.0 / M_PI, std::hypot(dy, dz)};
}

struct Timing
{
  std::vector<double> cpu, wall;
};

// One of the package's rows: a method and integrator at its step, stepped through the Simulation API.
struct PackageRow
{
  std::string label;
  SimulationParams params;
  int steps_per_peer_step = 1;  // its steps per 5 ms step of the others: the same simulated time
  std::unique_ptr<Simulation> sim;
  double startup_cpu = 0.0, startup_wall = 0.0;  // s: building the Simulation (precomputation included)
  Timing time;
  long newton = 0, substeps = 0;
  bool failed = false;
  std::vector<Swing> samples;
};

SimulationParams packageParams(Method method, IntegratorKind integrator, double dt, const Options& o)
{
  SimulationParams s;
  s.method = method;
  s.integrator = integrator;
  s.time_step = dt;
  s.alpha = kAlpha;
  s.hht_alpha = -0.1;
  if (method != Method::Full)
  {
    // config/cloth_large.yaml's modal set-up: the modes at the hanging equilibrium, cubature trained
    // at its defaults (1% of the force on fresh poses).
    s.num_modes = o.modes;
    s.linearization = Linearization::Equilibrium;
  }
  return s;
}

// The full explicit step of the n x n cloth when --explicit-step is not given: the largest of 1,
// 0.5, 0.25, 0.125 ms that stays stable on it (the highest frequency grows with n, the particle mass
// falling as 1/n^2 with the same springs): on 50 x 50 and 100 x 100 the next divisor of 5 ms up
// (2.5 ms, 1 ms) diverges within a dozen steps (docs/benchmarks.md).
double defaultExplicitStep(int size)
{
  if (size <= 50)
    return 1e-3;
  if (size <= 100)
    return 5e-4;
  if (size <= 200)
    return 2.5e-4;
  return 1.25e-4;
}

std::string stepLabel(double dt)
{
  char text[32];
  std::snprintf(text, sizeof text, "%g ms", 1e3 * dt);
  return text;
}

void run(int size, const Options& o)
{
  const GridParams g = swingingCloth(size);
  const double explicit_step = o.explicit_step > 0.0 ? o.explicit_step : defaultExplicitStep(size);
  const int explicit_ratio = static_cast<int>(std::lround(kTimeStep / explicit_step));
  if (std::abs(explicit_ratio * explicit_step - kTimeStep) > 1e-12)
    refuse("--explicit-step: " + stepLabel(explicit_step) + " must divide the 5 ms step");

  std::vector<PackageRow> rows;
  auto add = [&](const std::string& name, Method method, IntegratorKind integrator, double dt) {
    PackageRow row;
    row.label = name + " " + toString(integrator) + " " + stepLabel(dt);
    row.params = packageParams(method, integrator, dt, o);
    row.steps_per_peer_step = static_cast<int>(std::lround(kTimeStep / dt));
    rows.push_back(std::move(row));
  };
  add("full", Method::Full, IntegratorKind::Implicit, kTimeStep);
  add("full", Method::Full, IntegratorKind::Explicit, explicit_step);
  if (o.modes > 0)
  {
    // Built in this order, the cache computes the equilibrium and basis once (physical implicit),
    // trains the cubature once (cubature implicit), and the later rows load both.
    add("physical", Method::Physical, IntegratorKind::Implicit, kTimeStep);
    add("cubature", Method::Cubature, IntegratorKind::Implicit, kTimeStep);
    if (o.modal_explicit_step > 0.0)
    {
      add("physical", Method::Physical, IntegratorKind::Explicit, o.modal_explicit_step);
      add("cubature", Method::Cubature, IntegratorKind::Explicit, o.modal_explicit_step);
    }
  }
  CacheOptions cache;
  cache.directory = o.cache_dir;
  cache.warn = [](const std::string& warning) { std::fprintf(stderr, "bullet_peer: cache: %s\n", warning.c_str()); };
  for (PackageRow& row : rows)
  {
    const double c0 = processCpuSeconds(), w0 = wallSeconds();
    row.sim = std::make_unique<Simulation>(g, row.params, StageFn{}, cache);
    row.startup_cpu = processCpuSeconds() - c0;
    row.startup_wall = wallSeconds() - w0;
  }
  const Grid& grid = rows.front().sim->grid();
  BulletCloth bullet(grid, o);
  const double top_y = grid.initialPositions()[1], top_z = grid.initialPositions()[2];

  std::printf("\n== %d x %d: %d particles, %d springs (%d structural, %d shear, %d bending), %d free dofs; "
              "%d steps of %g s (%g s simulated) each, in blocks of %d alternating over all solvers\n",
              size, size, grid.numParticles(), static_cast<int>(grid.springs().size()), grid.numStructuralSprings(),
              grid.numShearSprings(), grid.numBendingSprings(), grid.numFreeDofs(), o.steps, kTimeStep,
              o.steps * kTimeStep, o.block);
  std::printf("package: alpha %g /s; implicit: Newmark HHT alpha %g, Newton to 1e-9 of the forces (at most %d "
              "iterations); explicit: the paper's Newmark, one force evaluation a step; physical and cubature: "
              "%d modes at the hanging equilibrium, started from the released cloth projected onto them\n",
              kAlpha, -0.1, rows.front().params.newton_max_iterations, o.modes);
  std::printf("start-up (building the Simulation: for the modal rows the equilibrium, basis and cubature, or "
              "loading them from the cache under %s), not in the step times:\n",
              o.cache_dir.empty() ? "(none)" : o.cache_dir.c_str());
  for (const PackageRow& row : rows)
  {
    std::string what = row.params.method == Method::Full ? "" : "; " + describeCache(row.sim->cacheReport());
    if (const Cubature* c = row.sim->cubature())
      what += "; " + describeCubature(*c, static_cast<int>(grid.springs().size()), row.params.cubature_tolerance);
    std::printf("  %-28s %.2f s CPU, %.2f s wall%s\n", row.label.c_str(), row.startup_cpu, row.startup_wall,
                what.c_str());
  }

  Timing bullet_time;
  const int sample_every = std::max(1, static_cast<int>(std::lround(0.1 / kTimeStep)));
  for (PackageRow& row : rows)
    row.samples.push_back(swing(row.sim->points(), top_y, top_z));
  std::vector<Swing> bullet_samples{swing(bullet.points(), top_y, top_z)};
  for (int done = 0; done < o.steps;)
  {
    const int count = std::min(o.block, o.steps - done);
    for (PackageRow& row : rows)
    {
      const int ratio = row.steps_per_peer_step;
      for (int k = 0; k < count * ratio && !row.failed; ++k)
      {
        const double c0 = processCpuSeconds(), w0 = wallSeconds();
        const StepResult result = row.sim->step(1);
        row.time.cpu.push_back(processCpuSeconds() - c0);
        row.time.wall.push_back(wallSeconds() - w0);
        row.newton += row.sim->lastNewtonIterations();
        row.substeps += row.sim->lastImplicitSubsteps();
        if (result.diverged || result.steps_taken != 1)
        {
          std::printf("package %s: step %ld (t = %.4f s) refused: %s\n", row.label.c_str(),
                      row.sim->stepCount() + 1, row.sim->time(), result.message.c_str());
          row.failed = true;
        }
        if ((done * ratio + k + 1) % (sample_every * ratio) == 0)
          row.samples.push_back(swing(row.sim->points(), top_y, top_z));
      }
    }
    for (int k = 0; k < count; ++k)
    {
      const double c0 = processCpuSeconds(), w0 = wallSeconds();
      bullet.step();
      bullet_time.cpu.push_back(processCpuSeconds() - c0);
      bullet_time.wall.push_back(wallSeconds() - w0);
      if ((done + k + 1) % sample_every == 0)
        bullet_samples.push_back(swing(bullet.points(), top_y, top_z));
    }
    done += count;
  }

  // Read after the run: the world sets the solver's mode and preconditioner at every step.
  std::printf("Bullet:  %d-bit btScalar, btDeformableMultiBodyDynamicsWorld %s, Newton at most %d iterations, stops at |residual| < %g "
              "N s; %s, at most %d iterations, tolerance %g; preconditioner %s; links %g N/m (bending %g), "
              "damping %g N s/m along the links; mass damping %s\n",
              static_cast<int>(8 * sizeof(btScalar)), o.semi_implicit ? "semi-implicit (springs explicit, damping implicit: one Krylov solve)" : "implicit",
              bullet.solver->newtonIterations(), bullet.solver->newtonTolerance(), bullet.solver->krylovName(),
              bullet.solver->krylovIterations(), bullet.solver->krylovTolerance(), bullet.solver->preconditionerName(),
              g.structural_stiffness, g.bending_stiffness, o.bullet_damping,
              o.semi_implicit ? "by the soft body's drag alpha dt" : "alpha M, implicit (a force of this benchmark's)");

  // The time per simulated second: the median step's time times the steps a second takes, what
  // compares solvers at different steps.
  std::printf("\n| solver | step | CPU ms/step (median) | CPU ms per simulated s | wall ms/step (median) | "
              "wall ms per simulated s | steps timed | Newton iterations/step | Krylov products/step |\n"
              "|---|---|---|---|---|---|---|---|---|\n");
  for (const PackageRow& row : rows)
  {
    const double dt = row.params.time_step;
    const double timed = static_cast<double>(row.time.cpu.size());
    char newton[64] = "-";
    if (row.params.integrator == IntegratorKind::Implicit && timed > 0)
      std::snprintf(newton, sizeof newton, "%.2f (substeps %.2f)", row.newton / timed, row.substeps / timed);
    const double cpu = timed > 0 ? median(row.time.cpu) : std::nan("");
    const double wall = timed > 0 ? median(row.time.wall) : std::nan("");
    std::printf("| package %s%s | %s | %.3f | %.1f | %.3f | %.1f | %d | %s | - |\n", row.label.c_str(),
                row.failed ? " (diverged)" : "", stepLabel(dt).c_str(), 1e3 * cpu, 1e3 * cpu / dt, 1e3 * wall,
                1e3 * wall / dt, static_cast<int>(timed), newton);
  }
  // Each Newton iteration evaluates the forces once more; the iterations a step are Bullet's setting
  // unless its tolerance stops them earlier (never with one).
  const double bullet_steps = static_cast<double>(bullet_time.cpu.size());
  std::printf("| Bullet deformable | %s | %.3f | %.1f | %.3f | %.1f | %d | at most %d (force evaluations %.2f) | %.1f |\n",
              stepLabel(kTimeStep).c_str(), 1e3 * median(bullet_time.cpu), 1e3 * median(bullet_time.cpu) / kTimeStep,
              1e3 * median(bullet_time.wall), 1e3 * median(bullet_time.wall) / kTimeStep,
              static_cast<int>(bullet_steps), bullet.solver->newtonIterations(),
              bullet.springs->force_evaluations / bullet_steps, bullet.springs->tangent_products / bullet_steps);
  std::printf("CPU per simulated second, Bullet / each package row:");
  for (const PackageRow& row : rows)
    std::printf(" %s %.3f;", row.label.c_str(),
                (median(bullet_time.cpu) / kTimeStep) / (median(row.time.cpu) / row.params.time_step));
  std::printf("\n");

  std::printf("\nswing: the centre of mass's angle from the vertical (deg) / distance from the top row (m)\n| t (s) |");
  for (const PackageRow& row : rows)
    std::printf(" %s |", row.label.c_str());
  std::printf(" Bullet |\n|---|");
  for (std::size_t r = 0; r <= rows.size(); ++r)
    std::printf("---|");
  std::printf("\n");
  std::size_t samples = bullet_samples.size();
  for (const PackageRow& row : rows)
    samples = std::max(samples, row.samples.size());
  const Swing none{std::nan(""), std::nan("")};
  for (std::size_t k = 0; k < samples; ++k)
  {
    std::printf("| %.2f |", k * sample_every * kTimeStep);
    for (const PackageRow& row : rows)
    {
      const Swing p = k < row.samples.size() ? row.samples[k] : none;
      std::printf(" %.1f / %.4f |", p.angle_deg, p.distance);
    }
    const Swing b = k < bullet_samples.size() ? bullet_samples[k] : none;
    std::printf(" %.1f / %.4f |\n", b.angle_deg, b.distance);
  }
  if (!bullet.points().allFinite())
    std::printf("Bullet: the state is not finite (exploded)\n");
}

}  // namespace

int main(int argc, char** argv)
{
  Options o = parse(argc, argv);
  // Without --cache-dir a fresh folder: the modal rows after the first load its basis and cubature
  // instead of computing them again, and nothing outlives the run.
  std::string temporary_cache;
  if (o.cache_dir.empty() && !o.no_cache && o.modes > 0)
  {
    char pattern[] = "/tmp/bullet_peer_cache_XXXXXX";
    if (!mkdtemp(pattern))
    {
      std::cerr << "bullet_peer: cannot create a cache folder under /tmp (give --cache-dir or --no-cache)\n";
      return 1;
    }
    temporary_cache = o.cache_dir = pattern;
  }
  std::setvbuf(stdout, nullptr, _IOLBF, 0);  // each table as it is measured, also into a file
  std::printf("bullet_peer: load average %s at the start\n", loadAverage().c_str());
  try
  {
    for (int size : o.sizes)
      run(size, o);
  }
  catch (const std::exception& e)
  {
    std::cerr << "bullet_peer: " << e.what() << "\n";
    if (!temporary_cache.empty())
      std::filesystem::remove_all(temporary_cache);
    return 1;
  }
  if (!temporary_cache.empty())
    std::filesystem::remove_all(temporary_cache);
  std::printf("\nload average %s at the end\n", loadAverage().c_str());
  return 0;
}
