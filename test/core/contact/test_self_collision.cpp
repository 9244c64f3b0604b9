// Self-collision: which pairs count, spheres against triangles (a layer through the other's cells),
// friction between the layers against the closed form on a slope, a folded sheet falling onto its
// lower half on a table under both integrators, a sheet dropped in a heap, the pairs kept over the
// steps against a search of every step, and the refusals.
#include "modal_mass_spring/self_collision.h"
#include "modal_mass_spring/simulation.h"

#include "test_support.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

using namespace modal_mass_spring;

namespace
{

// A towel rows x cols, `spacing` apart, lying along +y at z = 0 (rows along +y), its row 0 pinned.
GridParams towel(int rows, int cols, double spacing)
{
  GridParams g;
  g.rows = rows;
  g.cols = cols;
  g.dimension = 3;
  g.spacing = spacing;
  g.mass = 0.002;
  g.structural_stiffness = 50.0;
  g.shear_stiffness = 20.0;
  g.bending = true;
  g.bending_stiffness = 1.0;
  g.rotation_deg = 90.0;
  return g;
}

// Every particle of the towel folded: flat along +y at z = 0 for `flat` metres from row 0, then a
// half-turn of radius rho, then back along -y at z = 2 rho (each row at its arc length from row 0).
Eigen::VectorXd folded(const Grid& grid, double flat, double rho)
{
  const GridParams& g = grid.params();
  Eigen::VectorXd x(grid.numDofs());
  for (int r = 0; r < g.rows; ++r)
    for (int c = 0; c < g.cols; ++c)
    {
      const double t = r * g.spacing;
      Eigen::Vector3d at(c * g.spacing, t, 0.0);
      if (t > flat + M_PI * rho)
        at.tail<2>() << flat - (t - flat - M_PI * rho), 2.0 * rho;
      else if (t > flat)
      {
        const double phi = (t - flat) / rho;
        at.tail<2>() << flat + rho * std::sin(phi), rho * (1.0 - std::cos(phi));
      }
      x.segment<3>(3 * grid.particleIndex(r, c)) = at;
    }
  return x;
}

Collider table(double height, double friction = 0.5)
{
  Collider c;
  c.type = ColliderType::Plane;
  c.point = Eigen::Vector3d(0.0, 0.0, height);
  c.friction = friction;
  return c;
}

SimulationParams fullWith(IntegratorKind integrator, double dt, bool self, double thickness)
{
  SimulationParams s;
  s.method = Method::Full;
  s.integrator = integrator;
  s.time_step = dt;
  s.alpha = 1.0;
  s.self_collision = self;
  s.self_collision_thickness = thickness;
  s.self_friction = 0.5;
  return s;
}

// Puts the simulation's grid at `positions` (all particles), at rest.
void place(Simulation& sim, const Eigen::VectorXd& positions)
{
  const Grid& grid = sim.grid();
  sim.setPhysicalState(grid.gatherFree(positions - sim.linearizationPositions()),
                       Eigen::VectorXd::Zero(grid.numFreeDofs()));
}

// Steps `seconds`; the smallest distance between two particles more than two springs apart at any
// step (infinity when none came within `cutoff`).
double closestOverRun(Simulation& sim, double seconds, double cutoff)
{
  double closest = std::numeric_limits<double>::infinity();
  const long steps = std::lround(seconds / sim.params().time_step);
  for (long k = 0; k < steps; ++k)
  {
    const StepResult r = sim.step();
    EXPECT_FALSE(r.diverged) << r.message;
    if (r.diverged)
      break;
    closest = std::min(closest, closestSeparatedDistance(sim.grid(), sim.positions(), cutoff));
  }
  return closest;
}

// The mean height of the rows [first, last).
double meanHeight(const Simulation& sim, int first, int last)
{
  const Eigen::Matrix3Xd points = sim.points();
  const int cols = sim.grid().params().cols;
  return points.row(2).segment(first * cols, (last - first) * cols).mean();
}

// Explicit `full` at dt on a table 2 mm below, self-collision off: for the tests that correct each
// step's end with a SelfCollision of their own.
SimulationParams onTableUncorrected(double dt, double thickness)
{
  SimulationParams s = fullWith(IntegratorKind::Explicit, dt, false, thickness);
  s.colliders = {table(-0.002)};
  s.contact_thickness = 0.002;
  return s;
}

// One step of `sim`, its end corrected by `self` (after the table), the simulation going on from
// that correction.
void stepCorrectedBy(Simulation& sim, SelfCollision& self, double dt)
{
  const Grid& grid = sim.grid();
  const Eigen::VectorXd start = grid.gatherFree(sim.positions());
  ASSERT_FALSE(sim.step().diverged);
  Eigen::VectorXd x = grid.gatherFree(sim.positions()), v = sim.velocity();
  self.correct(start, x, v, dt, sim.contact());
  sim.setPhysicalState(x - grid.gatherFree(sim.linearizationPositions()), v);
}

}  // namespace

TEST(SelfCollision, PairsMoreThanTwoSpringsApartAreThoseOfChebyshevDistanceAboveTwo)
{
  const Grid grid(towel(8, 8, 0.02));
  EXPECT_FALSE(selfSeparated(grid, grid.particleIndex(3, 3), grid.particleIndex(5, 1)));
  EXPECT_FALSE(selfSeparated(grid, grid.particleIndex(3, 3), grid.particleIndex(3, 3)));
  EXPECT_TRUE(selfSeparated(grid, grid.particleIndex(3, 3), grid.particleIndex(6, 3)));
  EXPECT_TRUE(selfSeparated(grid, grid.particleIndex(0, 0), grid.particleIndex(2, 7)));
  // The hashed closest distance is the brute force's, on a random heap.
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> uniform(0.0, 0.1);
  Eigen::VectorXd x(grid.numDofs());
  for (Eigen::Index k = 0; k < x.size(); ++k)
    x[k] = uniform(rng);
  double brute = std::numeric_limits<double>::infinity();
  for (int p = 0; p < grid.numParticles(); ++p)
    for (int q = p + 1; q < grid.numParticles(); ++q)
      if (selfSeparated(grid, p, q))
        brute = std::min(brute, (x.segment<3>(3 * p) - x.segment<3>(3 * q)).norm());
  EXPECT_EQ(closestSeparatedDistance(grid, x, 0.03), brute);
}

namespace
{
// A 4 x 14 grid: a lower layer of the columns 0 to 4 at
// z = 0, an upper one of the columns 9 to 13 above it shifted half a cell in x and y (each upper
// particle over a lower cell's centre), the columns between flat beyond the lower layer, the upper
// layer lowered by `drop` a step for `steps` steps. Returns the lowest an upper particle over a cell gets above the
// middle of that cell's diagonal.
double lowerThroughCells(SelfPrimitive primitive, double thickness, double drop, int steps)
{
  GridParams g = towel(4, 14, 0.02);
  // Column 8 fixed: no cell joins the two layers (its triangles would cross the lower one).
  g.fixed = {8, g.cols + 8, 2 * g.cols + 8, 3 * g.cols + 8};
  const Grid grid(g);
  SelfCollision self(grid, thickness, 0.0, primitive);
  const double s = g.spacing;
  Eigen::VectorXd x(grid.numFreeDofs()), v = Eigen::VectorXd::Zero(grid.numFreeDofs());
  std::vector<int> upper;  // slots
  auto slot = [&](int r, int c) { return grid.freeIndex(3 * grid.particleIndex(r, c)) / 3; };
  for (int r = 0; r < g.rows; ++r)
    for (int c = 0; c < g.cols; ++c)
    {
      const int k = grid.freeIndex(3 * grid.particleIndex(r, c));
      if (k < 0)
        continue;
      if (c >= 9)
        upper.push_back(k / 3);
      x.segment<3>(k) = c >= 9  ? Eigen::Vector3d((c - 9 + 0.5) * s, (r + 0.5) * s, 2.0 * thickness)
                        : c < 5 ? Eigen::Vector3d(c * s, r * s, 0.0)
                                : Eigen::Vector3d(c * s, r * s, 0.0);
    }
  double lowest = std::numeric_limits<double>::infinity();
  for (int step = 0; step < steps; ++step)
  {
    const Eigen::VectorXd start = x;
    for (int u : upper)
    {
      x[3 * u + 2] -= drop;
      v[3 * u + 2] = -drop / 1e-3;
    }
    self.correct(start, x, v, 1e-3);
    // Upper particle (r, c), r < 3 and c < 13, is over the centre of the lower cell (r, c - 9).
    for (int r = 0; r < 3; ++r)
      for (int c = 9; c < 13; ++c)
      {
        const int l = c - 9;
        // The centre is on the diagonal both triangles of the cell share.
        const double diagonal = 0.5 * (x[3 * slot(r, l) + 2] + x[3 * slot(r + 1, l + 1) + 2]);
        lowest = std::min(lowest, x[3 * slot(r, c) + 2] - diagonal);
      }
  }
  return lowest;
}
}  // namespace

// Spheres of half the thickness leave a cell's centre open when the thickness is below the spacing
// over sqrt(2): a layer passes through the other. Particles against triangles hold it at the thickness.
TEST(SelfCollision, SpheresLetALayerThroughTheCellsAndTrianglesHoldIt)
{
  const double s = 0.02, thickness = 0.5 * s, drop = 0.2e-3;
  EXPECT_LT(lowerThroughCells(SelfPrimitive::Spheres, thickness, drop, 200), -thickness);
  const double held = lowerThroughCells(SelfPrimitive::Triangles, thickness, drop, 200);
  EXPECT_GT(held, thickness - 1e-3);
  EXPECT_LT(held, thickness + 1e-3);
}

namespace
{
// One particle of a flat 3 x 8 grid (row 0, column 7) lifted over the centroid of a triangle of the
// cell at (0, 0), the thickness above it, pulled by gravity tilted theta about y (only it: the
// triangle is carried along by its push): the layers' relative slide along the face after `seconds`
// (m). The correction acts on the pair's relative motion, so this is the collider's closed form.
double slideOverTriangle(double theta_deg, double mu, double seconds, double dt)
{
  GridParams g = towel(3, 8, 0.2);  // cells of 0.2 m: the triangle barely tilts as the particle slides
  // Free: the particle and the corners of the cell (0, 0), which its push carries along (a lower layer
  // of equal masses); the rest fixed, so that no other cell is pulled across them.
  for (int p = 0; p < g.rows * g.cols; ++p)
    if (p != 0 && p != 1 && p != g.cols && p != g.cols + 1 && p != 7)
      g.fixed.push_back(p);
  const Grid grid(g);
  const double thickness = 0.005, theta = theta_deg * M_PI / 180.0;
  SelfCollision self(grid, thickness, mu);
  const int p = grid.freeIndex(3 * grid.particleIndex(0, 7));
  const int a = grid.freeIndex(3 * grid.particleIndex(0, 0)), b = grid.freeIndex(3 * grid.particleIndex(0, 1)),
            d = grid.freeIndex(3 * grid.particleIndex(1, 1));
  // The rest of the grid stays flat where it starts (no springs act here): the lower layer.
  Eigen::VectorXd x = grid.gatherFree(grid.initialPositions()), v = Eigen::VectorXd::Zero(x.size());
  const Eigen::Vector3d centroid = (x.segment<3>(a) + x.segment<3>(b) + x.segment<3>(d)) / 3.0;
  x.segment<3>(p) = centroid + Eigen::Vector3d(0.0, 0.0, thickness);
  const Eigen::Vector3d gravity = 9.81 * Eigen::Vector3d(std::sin(theta), 0.0, -std::cos(theta));
  auto relative = [&] { return Eigen::Vector3d(x.segment<3>(p) - (x.segment<3>(a) + x.segment<3>(b) + x.segment<3>(d)) / 3.0); };
  const Eigen::Vector3d start = relative();
  for (long k = 0; k < std::lround(seconds / dt); ++k)
  {
    const Eigen::VectorXd x_start = x;
    v.segment<3>(p) += dt * gravity;
    x += dt * v;
    self.correct(x_start, x, v, dt);
    EXPECT_EQ(self.report().contacts, 1);
  }
  const Eigen::Vector3d moved = relative() - start;
  EXPECT_NEAR(moved.z(), 0.0, 1e-6);  // pushed off its centroid, the free triangle tilts a little
  return moved.norm();
}
}  // namespace

// The relative slide of two layers is the collider's closed form on a slope: none below the
// friction angle, 0.5 g (sin theta - mu cos theta) t^2 above it (over 50 ms, while the particle is
// still over the triangle).
TEST(SelfCollision, FrictionBetweenLayersHoldsBelowTheFrictionAngleAndSlidesAboveIt)
{
  const double mu = 0.5;  // friction angle 26.57 degrees
  const double seconds = 0.05, dt = 1e-4;
  EXPECT_LT(slideOverTriangle(0.0, mu, seconds, dt), 1e-9);
  EXPECT_LT(slideOverTriangle(25.0, mu, seconds, dt), 1e-9);
  for (double theta_deg : {28.0, 40.0})
  {
    const double theta = theta_deg * M_PI / 180.0;
    const double expected = 0.5 * 9.81 * (std::sin(theta) - mu * std::cos(theta)) * seconds * seconds;
    EXPECT_NEAR(slideOverTriangle(theta_deg, mu, seconds, dt), expected, 0.01 * expected) << theta_deg << " degrees";
  }
}

// A towel folded over itself with a loose crease on a table: its upper half falls onto the lower
// one and comes to rest there, no two particles more than two springs apart ever closer than the
// thickness less 1 mm; without self-collision the upper half falls through.
TEST(SelfCollision, FoldedTowelFallsOntoItsLowerHalfAndRestsThereUnderBothIntegrators)
{
  const GridParams g = towel(26, 10, 0.02);
  const double thickness = 0.01, flat = 10 * g.spacing, rho = 0.05;
  const int upper_first = static_cast<int>(std::ceil((flat + M_PI * rho) / g.spacing)) + 1;
  for (auto [integrator, dt] : {std::pair{IntegratorKind::Explicit, 5e-4}, std::pair{IntegratorKind::Implicit, 2e-3}})
  {
    SimulationParams s = fullWith(integrator, dt, true, thickness);
    s.colliders = {table(-0.002)};
    s.contact_thickness = 0.002;
    Simulation sim(g, s);
    place(sim, folded(sim.grid(), flat, rho));
    const double closest = closestOverRun(sim, 2.0, thickness);
    EXPECT_GT(closest, thickness - 1e-3) << toString(integrator);
    EXPECT_GT(sim.selfCollision()->report().contacts, 0) << toString(integrator);
    // At rest on the lower half, about a thickness above it.
    const double above = meanHeight(sim, upper_first, g.rows) - meanHeight(sim, 1, 10);
    EXPECT_GT(above, thickness - 1e-3) << toString(integrator);
    EXPECT_LT(above, 2.0 * thickness) << toString(integrator);
    EXPECT_LT(sim.velocity().cwiseAbs().maxCoeff(), 0.05) << toString(integrator);

    Simulation control(g, [&] {
      SimulationParams c = fullWith(integrator, dt, false, thickness);
      c.colliders = {table(-0.002)};
      c.contact_thickness = 0.002;
      return c;
    }());
    place(control, folded(control.grid(), flat, rho));
    EXPECT_LT(closestOverRun(control, 2.0, thickness), thickness - 1e-3) << toString(integrator) << ": would not meet";
  }
}

// A towel dropped onto a table from hanging, with a random push, lands in a heap: no two particles
// more than two springs apart ever closer than the thickness less 1 mm.
TEST(SelfCollision, TowelDroppedInAHeapKeepsItsLayersApart)
{
  GridParams g = towel(20, 20, 0.02);
  g.rotation_deg = 0.0;  // hanging in the x-z plane
  g.fixed = {g.rows * g.cols - 1};  // a bottom corner, above the table
  const double thickness = 0.01;
  SimulationParams s = fullWith(IntegratorKind::Explicit, 5e-4, true, thickness);
  s.colliders = {table(-0.45)};
  Simulation sim(g, s);
  // The hanging towel, all but the fixed corner, given a random velocity, then free to fall.
  std::mt19937_64 rng(7);
  std::normal_distribution<double> normal(0.0, 0.5);
  Eigen::VectorXd v(sim.grid().numFreeDofs());
  for (Eigen::Index k = 0; k < v.size(); ++k)
    v[k] = normal(rng);
  sim.setPhysicalState(Eigen::VectorXd::Zero(v.size()), v);
  const double closest = closestOverRun(sim, 1.5, thickness);
  EXPECT_GT(closest, thickness - 1e-3);
  EXPECT_GT(sim.selfCollision()->report().contacts, 0);
}

// The candidate pairs kept over the steps (listed anew only around the particles that moved, looked
// at only once their particles have travelled their margin, and keeping their closest points while
// touching) find what a search of the whole cloth finds at every step: the same closest gap and the
// same correction within the kept closest points' tolerance, along a towel crumpling through itself
// as it falls in a heap (self-collision off, so that its layers meet at every speed).
TEST(SelfCollision, PairsKeptOverTheStepsAreThoseASearchOfEveryStepFinds)
{
  GridParams g = towel(20, 20, 0.02);
  g.rotation_deg = 0.0;
  g.fixed = {g.rows * g.cols - 1};
  const double thickness = 0.01;
  SimulationParams s = fullWith(IntegratorKind::Explicit, 5e-4, false, thickness);
  s.colliders = {table(-0.45)};
  Simulation sim(g, s);
  std::mt19937_64 rng(7);
  std::normal_distribution<double> normal(0.0, 0.5);
  Eigen::VectorXd v0(sim.grid().numFreeDofs());
  for (Eigen::Index k = 0; k < v0.size(); ++k)
    v0[k] = normal(rng);
  sim.setPhysicalState(Eigen::VectorXd::Zero(v0.size()), v0);
  const Grid& grid = sim.grid();
  SelfCollision kept(grid, thickness, 0.5, SelfPrimitive::Triangles, 0.0);  // the narrow phase every step
  const double tolerance = 2.0 * SelfCollision::kReuse * thickness;
  Eigen::VectorXd start = grid.gatherFree(sim.positions());
  int partly = 0, touching = 0;
  for (int k = 0; k < 3000; ++k)
  {
    ASSERT_FALSE(sim.step().diverged);
    const Eigen::VectorXd end = grid.gatherFree(sim.positions());
    Eigen::VectorXd x = end, v = Eigen::VectorXd::Zero(end.size());
    kept.correct(start, x, v, 5e-4);
    SelfCollision fresh(grid, thickness, 0.5);
    Eigen::VectorXd x_fresh = end, v_fresh = Eigen::VectorXd::Zero(end.size());
    fresh.correct(start, x_fresh, v_fresh, 5e-4);
    // Within the kept closest points' tolerance (SelfCollision::kReuse).
    ASSERT_NEAR(kept.report().closest_before, fresh.report().closest_before, tolerance) << "step " << k;
    partly += kept.report().relisted > 0 && kept.report().relisted < grid.numFreeDofs() / 3;
    touching += fresh.report().contacts > 0;
    // The pairs found: at least those a search finds within the thickness less the tolerance, at
    // most those within the thickness plus it (every third step: three searches a step are slow).
    if (k % 3 == 0)
    {
      SelfCollision closer(grid, thickness - tolerance, 0.5), farther(grid, thickness + tolerance, 0.5);
      Eigen::VectorXd x_other = end, v_other = Eigen::VectorXd::Zero(end.size());
      closer.correct(start, x_other, v_other, 5e-4);
      x_other = end;
      farther.correct(start, x_other, v_other, 5e-4);
      ASSERT_LE(closer.report().contacts, kept.report().contacts) << "step " << k;
      ASSERT_GE(farther.report().contacts, kept.report().contacts) << "step " << k;
    }
    start = end;
  }
  EXPECT_GT(partly, 100);    // listed anew around some particles only
  EXPECT_GT(touching, 1000);  // the layers meet
}

// A folded towel coming to rest on a table, each step's end (after the table) corrected both by a
// SelfCollision kept over the steps, which keeps the touching pairs' closest points and normals
// while their particles travel less than the reuse fraction of the thickness, and by a fresh one that
// searches and finds every closest point anew: the kept gaps are within twice the reuse fraction of
// the closest points' (SelfCollision::kReuse), and so are the corrected positions; most pairs of the
// resting fold are kept ones.
TEST(SelfCollision, KeptClosestPointsCorrectAsTheClosestPointsOfEveryStepDo)
{
  const GridParams g = towel(26, 10, 0.02);
  const double thickness = 0.01, flat = 10 * g.spacing, rho = 0.05, dt = 5e-4;
  const SimulationParams s = onTableUncorrected(dt, thickness);
  Simulation sim(g, s);
  place(sim, folded(sim.grid(), flat, rho));
  const Grid& grid = sim.grid();
  const Eigen::VectorXd reference = grid.gatherFree(sim.linearizationPositions());
  SelfCollision kept(grid, thickness, 0.5, SelfPrimitive::Triangles, 0.0);  // the narrow phase every step
  const double tolerance = 2.0 * SelfCollision::kReuse * thickness;
  long reused = 0, contacts = 0;
  for (int k = 0; k < 2000; ++k)
  {
    const Eigen::VectorXd start = grid.gatherFree(sim.positions());
    ASSERT_FALSE(sim.step().diverged);
    const Eigen::VectorXd end = grid.gatherFree(sim.positions());
    Eigen::VectorXd x = end, v = sim.velocity();
    kept.correct(start, x, v, dt, sim.contact());
    SelfCollision fresh(grid, thickness, 0.5);
    Eigen::VectorXd x_fresh = end, v_fresh = sim.velocity();
    fresh.correct(start, x_fresh, v_fresh, dt, sim.contact());
    ASSERT_NEAR(kept.report().closest_before, fresh.report().closest_before, tolerance) << "step " << k;
    ASSERT_LT((x - x_fresh).reshaped(3, x.size() / 3).colwise().norm().maxCoeff(), tolerance) << "step " << k;
    reused += kept.report().reused;
    contacts += kept.report().contacts;
    sim.setPhysicalState(x - reference, v);  // the simulation goes on with the kept correction
  }
  // The upper half rests on the lower one, and most of its pairs kept their closest points.
  EXPECT_GT(contacts, 100000);
  EXPECT_GT(reused, contacts / 2);
}

// A folded towel coming to rest on a table, corrected at each step's end (after the table) by a
// SelfCollision whose narrow phase waits until a particle has moved the lapse (kLapse) and by one
// whose narrow phase runs every step: the first skips it on most steps, and yet keeps every two
// particles more than two springs apart at least the thickness less twice the lapse apart (the
// bound for the pairs it did not find), and the two come to rest alike.
TEST(SelfCollision, ANarrowPhaseThatWaitsForTheLapseKeepsTheLayersAsOneEveryStep)
{
  const GridParams g = towel(26, 10, 0.02);
  const double thickness = 0.01, flat = 10 * g.spacing, rho = 0.05, dt = 5e-4;
  const SimulationParams s = onTableUncorrected(dt, thickness);
  Simulation waits(g, s), every(g, s);
  place(waits, folded(waits.grid(), flat, rho));
  place(every, folded(every.grid(), flat, rho));
  const Grid& grid = waits.grid();
  SelfCollision lapsed(grid, thickness, 0.5), looking(grid, thickness, 0.5, SelfPrimitive::Triangles, 0.0);
  int skipped = 0;
  double closest = std::numeric_limits<double>::infinity();
  for (int k = 0; k < 2000; ++k)
  {
    stepCorrectedBy(waits, lapsed, dt);
    stepCorrectedBy(every, looking, dt);
    skipped += !lapsed.report().looked;
    closest = std::min(closest, closestSeparatedDistance(grid, waits.positions(), thickness));
  }
  EXPECT_GT(skipped, 1000);
  EXPECT_GT(closest, thickness - 2.0 * SelfCollision::kLapse * thickness);
  // At rest, the upper half as high as the other run's within the lapse, every particle within a
  // thickness of where the other puts it (the fall differs by millimetres on the way).
  const int upper_first = static_cast<int>(std::ceil((flat + M_PI * rho) / g.spacing)) + 1;
  EXPECT_NEAR(meanHeight(waits, upper_first, g.rows), meanHeight(every, upper_first, g.rows),
              SelfCollision::kLapse * thickness);
  EXPECT_LT((waits.points() - every.points()).colwise().norm().maxCoeff(), thickness);
}

// Positions that are not finite (a diverged step's, corrected before the simulation puts its last
// good state back), then finite ones again: the correction finds everything anew, with the table's
// surfaces, and corrects as a fresh one does; the step that was not finite leaves the others finite.
TEST(SelfCollision, AfterPositionsNotFiniteItCorrectsAsAFreshOne)
{
  const GridParams g = towel(26, 10, 0.02);
  const double thickness = 0.01, flat = 10 * g.spacing, rho = 0.05, dt = 5e-4;
  Simulation sim(g, onTableUncorrected(dt, thickness));
  place(sim, folded(sim.grid(), flat, rho));
  const Grid& grid = sim.grid();
  SelfCollision kept(grid, thickness, 0.5);
  for (int k = 0; k < 2000; ++k)  // to rest on the lower half
    stepCorrectedBy(sim, kept, dt);
  const Eigen::VectorXd start = grid.gatherFree(sim.positions());
  Eigen::VectorXd broken = start, v = sim.velocity();
  broken[3 * (grid.numFreeDofs() / 6)] = std::numeric_limits<double>::quiet_NaN();
  kept.correct(start, broken, v, dt, sim.contact());
  ASSERT_FALSE(sim.step().diverged);
  const Eigen::VectorXd end = grid.gatherFree(sim.positions());
  Eigen::VectorXd x = end, x_fresh = end, v_kept = sim.velocity(), v_fresh = sim.velocity();
  kept.correct(start, x, v_kept, dt, sim.contact());
  EXPECT_TRUE(kept.report().looked);
  SelfCollision fresh(grid, thickness, 0.5);
  fresh.correct(start, x_fresh, v_fresh, dt, sim.contact());
  EXPECT_GT(fresh.report().contacts, 100);
  EXPECT_EQ(kept.report().contacts, fresh.report().contacts);
  EXPECT_TRUE(x.allFinite() && v_kept.allFinite());
  EXPECT_LT((x - x_fresh).cwiseAbs().maxCoeff(), 2.0 * SelfCollision::kReuse * thickness);
}

TEST(SelfCollision, BadParametersAreRefusedByName)
{
  const GridParams g = towel(10, 10, 0.02);
  for (double thickness : {0.0, -0.01, 0.03, std::nan(""), std::numeric_limits<double>::infinity()})
  {
    const std::string message = refusal([&] { Simulation sim(g, fullWith(IntegratorKind::Explicit, 1e-3, true, thickness)); });
    EXPECT_TRUE(contains(message, "self_collision_thickness")) << message;
    EXPECT_TRUE(contains(message, "at most the grid's spacing")) << message;
  }
  SimulationParams s = fullWith(IntegratorKind::Explicit, 1e-3, true, 0.01);
  s.self_friction = -1.0;
  EXPECT_TRUE(contains(refusal([&] { Simulation sim(g, s); }), "self_friction"));
  GridParams flat2d;
  flat2d.dimension = 2;
  const std::string two_d = refusal([&] { Simulation sim(flat2d, fullWith(IntegratorKind::Explicit, 1e-3, true, 0.01)); });
  EXPECT_TRUE(contains(two_d, "self_collision")) << two_d;
  EXPECT_TRUE(contains(two_d, "dimension: 3")) << two_d;
  // Off, a 2D grid and the default thickness pass.
  EXPECT_EQ(refusal([&] { Simulation sim(flat2d, fullWith(IntegratorKind::Explicit, 1e-3, false, 1.0)); }), "");
  // The modal methods are refused, at the start and at a switch; live, nothing changes.
  SimulationParams modal = fullWith(IntegratorKind::Explicit, 1e-3, true, 0.01);
  modal.method = Method::Physical;
  EXPECT_TRUE(contains(refusal([&] { Simulation sim(g, modal); }), "must be full with self_collision"));
  Simulation sim(g, fullWith(IntegratorKind::Explicit, 1e-3, true, 0.01));
  EXPECT_TRUE(contains(refusal([&] { sim.setMethod(Method::Linear); }), "must be full with self_collision"));
  EXPECT_EQ(sim.method(), Method::Full);
  EXPECT_TRUE(contains(refusal([&] { sim.setSelfCollision(true, 0.05, 0.5); }), "self_collision_thickness"));
  EXPECT_EQ(sim.selfCollision()->thickness(), 0.01);
  sim.setSelfCollision(false, 0.01, 0.5);
  EXPECT_EQ(sim.selfCollision(), nullptr);
  sim.setMethod(Method::Linear);
  EXPECT_TRUE(contains(refusal([&] { sim.setSelfCollision(true, 0.01, 0.5); }), "needs method full"));
}
