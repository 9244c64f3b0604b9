// Self-collision of a 3D grid: the free particles are kept at least a thickness apart from every part
// of the cloth more than two springs away, as a correction of each step's end state (after the
// colliders', in the same way: positions, then velocities, with Coulomb friction between the layers).
//
// Two particles are "more than two springs away" when the structural and shear springs (a grid cell's
// sides and diagonals) need more than two to join them: max(|row difference|, |column difference|) > 2.
// Closer pairs are held apart by the springs themselves.
//
// Primitives (docs/design.md, "Self-collision" measures both): spheres of half the thickness at the
// particles, and each particle against the triangles of the cells (two per cell) whose corners are
// all more than two springs from it. Spheres alone let a layer through a cell of the other whenever
// the thickness is below the spacing over sqrt(2) (a particle over a cell's centre is that far from
// its corners); the triangles close the cells, and the spheres still keep particles apart at the
// grid's edges, where every triangle at a particle may touch a neighbour of the other.
//
// Broad phase: a list of candidate pairs within the thickness plus twice a skin, kept over the steps;
// the pairs of a particle that has moved more than half the skin since its pairs were last listed
// are listed anew (all of them when many have), so that no pair outside the list can have come
// within the thickness (docs/design.md, "Self-collision", gives the bound); a listing of some
// particles visits only the groups that name them (named_by_). A listing searches a
// uniform grid of cells as wide as the reach (the listing distance plus the longest edge of any
// triangle, so that a triangle within it has its first corner in a neighbouring cell), sorted by a
// counting sort. Narrow phase, once a particle has moved a fraction of the thickness since it last
// ran (kLapse; the steps between sweep the touches it found): the candidates within the thickness at the step's end,
// one per closest point (a triangle whose closest point is a corner or an edge it shares is left to
// the pair that holds that point), skipping those whose particles have travelled less than their
// gap's margin over the thickness since they were last looked at, and keeping the closest point and
// normal of those within reach of the thickness while their particles travel less than a hundredth
// of it (kReuse). Correction: Gauss-Seidel sweeps of equal-and-opposite pushes along each pair's
// normal at the step's end, split by the inverse masses (every free particle weighs the same), the
// contact point of a triangle spread to its corners by barycentric weights; the sweeps stop after
// one that moved nothing by more than a thousandth of the thickness (after the first, only the
// pairs a larger push moved are swept). Fixed and held particles, and the triangles at them, take
// no part.
#pragma once

#include "modal_mass_spring/contact.h"
#include "modal_mass_spring/grid.h"

#include <Eigen/Core>

#include <array>
#include <vector>

namespace modal_mass_spring
{

enum class SelfPrimitive
{
  Spheres,    // particle against particle only
  Triangles,  // particle against triangle, and particle against particle
};

// Throws std::invalid_argument (rejectParameter) naming the parameter: self_collision on a 2D grid,
// a self_collision_thickness not finite, <= 0 or larger than the spacing, a self_friction not finite
// or negative. The thickness and friction are checked only when self_collision is on (the default
// thickness may exceed a fine grid's spacing).
void validateSelfCollision(const GridParams& grid, bool enabled, double thickness, double friction);

// What a modal method with self-collision is told: why only `full` is allowed.
constexpr const char* kSelfCollisionMethods =
    "must be full with self_collision: true (a modal basis cannot hold two layers a thickness apart: the "
    "contact's shape is local and far from the modes; turn self_collision off to use linear, physical or "
    "cubature)";

// True when particles p and q are more than two springs apart (see above).
bool selfSeparated(const Grid& grid, int p, int q);

// The smallest distance between two particles more than two springs apart (positions of all
// particles, 3 per particle), counting only pairs closer than `cutoff` (infinity when none is).
double closestSeparatedDistance(const Grid& grid, const Eigen::VectorXd& positions, double cutoff);

// What the last correction did.
struct SelfCollisionReport
{
  int contacts = 0;  // pairs (particle-particle and particle-triangle) closer than the thickness, one per closest point
  // The smallest gap among them before the correction and after it (as the last sweep left it), along
  // each pair's normal at the step's end (m; the thickness when none).
  double closest_before = 0.0;
  double closest_after = 0.0;
  int relisted = 0;  // particles whose candidate pairs were listed anew this step (all at a full listing)
  int reused = 0;    // pairs whose closest point and normal were kept from an earlier step (see kReuse)
  int position_sweeps = 0, velocity_sweeps = 0;  // the Gauss-Seidel sweeps of the correction
  // Whether the narrow phase ran (see kLapse). When it did not, the touches it last found were swept
  // again: `contacts` and `closest_before` are theirs within the thickness as the first sweep found them.
  bool looked = true;
};

struct Cells;  // the broad phase's cells (internal)

class SelfCollision
{
public:
  // grid: 3D; thickness > 0 and <= the spacing; friction >= 0 (validated by the caller).
  // lapse: see kLapse (0: the narrow phase runs every step).
  SelfCollision(const Grid& grid, double thickness, double friction, SelfPrimitive primitive = SelfPrimitive::Triangles,
                double lapse = kLapse);

  double thickness() const { return thickness_; }
  double friction() const { return friction_; }
  void setThickness(double thickness)
  {
    thickness_ = thickness;
    built_at_.resize(0);  // the candidates were listed for the old thickness (and the summaries' allowances found)
  }
  void setFriction(double friction) { friction_ = friction; }

  // Corrects the free dofs' absolute end positions x and velocities v, given their start positions
  // x_start (all free-dof vectors, as Contact::correctParticles) and the step dt. A particle within
  // the colliders' thickness of an active collider of `contact` (corrected before) is held where it
  // is, as if it were fixed, by a pair pushing along the surface's normal: the layer above a layer
  // on a table is pushed off it, not the table's layer into the table (which the colliders would
  // push back the next step, leaving a velocity into the table every step). Pushed along the
  // surface (two particles side by side on it), it moves as any other.
  void correct(const Eigen::VectorXd& x_start, Eigen::VectorXd& x, Eigen::VectorXd& v, double dt,
               const Contact* contact = nullptr);
  const SelfCollisionReport& report() const { return report_; }

  // At most this many Gauss-Seidel sweeps of the position and of the velocity correction.
  static constexpr int kSweeps = 4;
  // The skin of the candidate list, as a fraction of the thickness.
  static constexpr double kSkin = 0.25;
  // A particle's candidates within the thickness plus this fraction of it keep their closest point
  // and normal while the sum of their particles' travel since stays below it: their gaps are then
  // measured with the kept weights and normal, within twice this fraction of the thickness of the
  // closest point's (docs/design.md, "Self-collision").
  static constexpr double kReuse = 0.01;
  // The narrow phase (and the listing) runs only once a particle has moved this fraction of the
  // thickness since it last ran; the steps between sweep the touches it found, with their kept
  // closest points and normals, whose particles may then have moved this fraction beyond the reuse
  // fraction. A pair it did not find was no closer than the thickness then (within the kept closest
  // points' tolerance), and its gap has closed by at most twice this fraction since
  // (docs/design.md, "Self-collision", "The lapse").
  static constexpr double kLapse = 0.05;

private:
  // One pair: particle p (a free-particle slot) against corners c[0..2] (slots, -1 for none: a
  // particle-particle pair has only c[0]). A triangle is half `half` (0: c[0], its right and its
  // lower-right neighbour; 1: c[0], its lower-right and its lower neighbour) of the cell c[0] anchors.
  // Its gap less the thickness when last looked at and the sum of its particles' travel then (a
  // pair is not looked at again while they have travelled less than that margin since). A pair
  // within the thickness plus the reuse fraction then is `kept`: a pair of its own (1, with its
  // closest point's weights and normal in `kept_geometry`) or one whose point another pair holds (2,
  // likewise; 3 for a triangle whose point is at a particle the particle pair holds, not looked at);
  // its closest point is found again once its particles have travelled the reuse fraction since.
  struct Geometry
  {
    double w[3] = {1.0, 0.0, 0.0};
    Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
    double gap = 0.0;
  };
  struct Pair
  {
    Pair(int p, int c0, int c1, int c2, int half) : p(p), c{c0, c1, c2}, half(half) {}
    int p;
    int c[3];
    int half;
    double margin = -1.0;
    double travel = 0.0;
    int kept = 0;
    Geometry kept_geometry;
  };
  // The closest point to p on the pair's other side, its barycentric weights, the unit normal from
  // there to p (oriented by the start positions inside a triangle) and the gap along it.
  Geometry geometry(const Pair& pair, const double* x, const double* x_start) const;
  // A kept pair of its own (kept 1) as the sweeps read it: its particles, its closest point's weights
  // and normal, and its particles' shares of a push (weigh). The touches are kept from step to step:
  // a group's are found anew only when it is looked at, and they are weighed again when the surfaces
  // change. Those closer than the thickness when the narrow phase ran are swept (swept_) until it
  // runs again; the sweeps push those closer than the thickness then. In single precision, 48 bytes,
  // so that a resting fold's touches stay in the cache over the sweeps: the weights' rounding moves
  // a contact point by about 1e-7 of the cell's size, wherever the cloth is (see relative).
  struct Touch
  {
    int p;
    int c[3];
    float w[3];
    float normal[3];
    float scale;          // 1 over the sum of its sharing particles' weights squared (weigh; 0: none shares)
    unsigned char shares;  // bit k: particle k (p, c[0], c[1], c[2]) takes its weight's share of a push
    Eigen::Vector3d normalVector() const { return Eigen::Vector3d(normal[0], normal[1], normal[2]); }
  };
  // Adds the touch of a kept pair of its own, weighed.
  void addTouch(const Pair& pair, const double* x);
  // Which of the touch's particles take a share of a push along its normal (its weight, 1 for p,
  // times its inverse mass relative to a free particle's: none on a collider when the push is along
  // the surface's normal, more than 60 degrees from the surface; none for a weight of at most
  // kLeastShare, which would scale the push up without bound when no other shares), and its scale.
  static constexpr double kLeastShare = 1e-6;
  void weigh(Touch& touch, const double* x);
  // Lists the candidate pairs closer than the thickness plus twice the skin at positions x: every
  // pair when `moved` is empty, else those of the particles in it and of the triangles at them.
  void listCandidates(const Eigen::VectorXd& x, const std::vector<int>& moved);
  // Its steps (self_collision_candidates.cpp), at positions xs with the listing distance `listed`
  // and the broad phase's cells `reach` wide. Empties every group (all), or moves the pairs with a
  // moved particle to the end of their group, [gone_from_, gone_end_), in the groups that name one
  // (dropped_from_, found by named_by_).
  void dropMovedPairs(bool all, const std::vector<int>& moved);
  // Marks the particles within `reach` of the box around the moved ones (is_near_moved_): a listing of
  // some particles files only those into its cells, as it finds no pair farther from a moved particle.
  void markNearMoved(const std::vector<int>& moved, const double* xs, double reach);
  // A pair listed into its group, the group named by its other particles (named_by_).
  void addPair(const Pair& pair);
  // After a full listing: every particle's named_by_ found anew.
  void nameAll();
  // The square of the longest edge of a cell's triangles.
  double longestCellEdge(const double* xs) const;
  // The centre and the squared radius of a sphere around the cell anchored at slot s that holds
  // every point within `listed` of its triangles (found once a listing, cell_sphere_).
  const Eigen::Vector4d& cellSphere(int s, const double* xs, double listed);
  // Particle p against the cell anchored at q (both its triangles, or only those with a moved corner
  // when `moved_only`), when a triangle is within `listed`; every corner of the cell is more than two
  // springs from p (the caller checks it).
  void listTriangles(int p, int q, bool moved_only, const double* xs, double listed);
  // The moved particles against everything (a particle pair in both particles' lists).
  void listAroundMoved(const Cells& cells, const double* xs, double reach, double listed);
  // The triangles with a moved corner against the particles that have not moved.
  void listMovedTriangles(const std::vector<int>& moved, const Cells& cells, const double* xs, double reach,
                          double listed);
  // A pair listed again takes what was found of it before (its margin, its kept closest point: they
  // hold for the pair whatever the listing), so that a listing does not send it to the narrow phase;
  // then the gone pairs are erased.
  void takeBackFound();
  int slotAt(int row, int col) const { return slot_of_[row * grid_.params().cols + col]; }
  // The touches at the step's end x: those of the groups not settled found anew (looking_).
  void findTouches(const Eigen::VectorXd& x_start, const Eigen::VectorXd& x);
  // The touches closer than the thickness at x (swept_), and the report's contacts, closest gap and
  // reused pairs.
  void measureTouches(const Eigen::VectorXd& x);
  // Whether slot p's candidates are as they were last looked at within the tolerances (none listed or
  // dropped since, the kept ones travelled less than the reuse fraction, the others less than their
  // margin): by the group's bound while it holds, else pair by pair (setting the bound anew).
  bool groupSettled(int p);
  // What a settled group's steps read of its pairs, so that they stream that and not every pair (a
  // pair is 152 bytes, and a resting fold has 73,000): per pair, its other particles, its travel when
  // last looked at and its allowance then (the reuse fraction when kept, else its margin). So
  // whatever changes a copied field of a pair, or the order of a group, clears its `found`: a
  // look at the group (after which it is found at once, its pairs in the cache) and a listing that
  // changes its pairs.
  struct Allowance
  {
    int c[3];
    double travel;
    double allowance;
  };
  // A group's summary; not `found`: to be found again before it is read.
  struct GroupSummary
  {
    bool found = false;
    std::vector<Allowance> allowances;
  };
  // Group p's summary, found first when it is not.
  GroupSummary& summaryOf(int p);
  // The sum of the pair's particles' travel (travel_): p against corners c.
  double travelOf(int p, const int c[3]) const
  {
    const double travel = travel_[p] + travel_[c[0]];
    return c[1] >= 0 ? travel + travel_[c[1]] + travel_[c[2]] : travel;
  }
  double travelOf(const Pair& pair) const { return travelOf(pair.p, pair.c); }
  // Looks at slot p's candidates (those not still apart) and keeps those within reach of the thickness.
  void lookAtGroup(int p, const double* x, const double* x_start);
  // Whether a pair whose particles have travelled less than its margin since it was last looked at is
  // still apart (a point's distance to a triangle changes by at most its own and the farthest
  // corner's displacements); a kept pair is looked at whenever its group is. Else marks it looked at.
  bool apart(Pair& pair) const;
  // lookAtGroup's steps: its particle pairs (returns how many particles it puts in `covered`, those
  // whose triangles have their closest point to p at them), its triangle pairs (not those at a
  // covered particle), and the pairs within reach kept.
  int lookAtParticlePairs(int p, const double* x, const double* x_start, int covered[8]);
  void lookAtTrianglePairs(int p, const double* x, const double* x_start, const int covered[8], int covering);
  void keepWithinReach(int p, const double* x);
  // Whether the triangle pair `k` of `group` (one particle's candidates, with this step's geometry)
  // leaves its closest point (on the edge opposite its corner `opposite`) to the triangle sharing
  // that edge, when that one holds the same point.
  bool edgeHeldByNeighbour(const std::vector<Pair>& group, const std::vector<Geometry>& geometry, int k,
                           int opposite) const;
  // correct's steps. Whether the narrow phase is due at x (kLapse).
  bool lookDue(const Eigen::VectorXd& x) const;
  // Finds the particles moved half the skin since their pairs were listed (moved_);
  // true when every pair is to be listed anew.
  bool findMoved(const Eigen::VectorXd& x);
  // Adds the path from the positions at the last narrow phase to x to each particle's travel (a
  // displacement at least: the pairs' bounds hold over the steps between); false when not finite.
  bool addTravel(const Eigen::VectorXd& x);
  // The colliders' surfaces under the touches' particles: all forgotten once a collider has moved
  // (or none is given); a particle's found anew (surfaceOf) when it has travelled the reuse fraction
  // since it was last.
  // Returns whether they changed.
  bool checkSurfaces(const Contact* contact);
  // The outward normal of the collider surface slot s lies on at x (zero when on none).
  const Eigen::Vector3d& surfaceOf(int s, const double* x);
  // The Gauss-Seidel sweeps over the touches: positions pushed apart, then approaching velocities
  // removed (the first velocity sweep within the first position sweep; the rest after the position
  // sweeps, the first of them starting from the largest approach it removed, `fastest`).
  void sweep(const Eigen::VectorXd& x_start, Eigen::VectorXd& x, Eigen::VectorXd& v, double dt);
  void sweepVelocities(Eigen::VectorXd& v, double dt, double fastest);
  // Removes the approach of the touch's relative velocity, with Coulomb friction on the tangential;
  // returns the approach removed (0 when separating).
  static double pushVelocity(double* vs, const Touch& t, double friction);
  // The pair's relative position (or velocity) among `values`: p less the corners c by their kept weights w.
  template <typename Weight>
  static Eigen::Vector3d relative(const double* values, int p, const int c[3], const Weight w[3]);
  static Eigen::Vector3d relative(const double* values, const Pair& pair)
  {
    return relative(values, pair.p, pair.c, pair.kept_geometry.w);
  }
  static Eigen::Vector3d relative(const double* values, const Touch& touch)
  {
    return relative(values, touch.p, touch.c, touch.w);
  }
  // Moves p by delta / (1 + sum w^2) and the corners against it by their weights (each times its
  // inverse mass): the pair's relative displacement changes by delta and, between free particles, its
  // momentum not at all.
  static void apply(double* values, const Touch& touch, const Eigen::Vector3d& delta);
  // The sweeps end after one that moved nothing by more than this (m, and m over the step for
  // velocities): what it leaves is smaller still, and the next step pushes out what is left. After
  // the first sweep, a pair is swept again only when a push of more than this moved one of its
  // particles in the last sweep or this one (stirred, stir): the rule that ends the sweeps, pair by pair.
  double settledDistance() const { return 1e-3 * thickness_; }
  static bool stirred(const int* stirred, const Touch& touch, int sweep);
  static void stir(int* stirred, const Touch& touch, int sweep);

  const Grid& grid_;
  double thickness_;
  double friction_;
  SelfPrimitive primitive_;
  double lapse_;
  std::vector<int> particle_of_;  // slot -> grid particle
  std::vector<int> slot_of_;      // grid particle -> slot, -1 when fixed or held
  std::vector<int> row_, col_;    // per slot
  std::vector<char> anchor_;      // per slot: its particle is the first corner of a cell with every corner free
  std::vector<std::array<int, 6>> fan_;  // per slot: the slots its triangles' edges join it to (-1: none, not free)
  // The broad phase's cells, kept between steps (no allocation a step once grown).
  std::vector<int> cell_of_, cell_start_, sorted_;
  // Per slot p: its candidate pairs (p against a triangle, or against a particle of a later slot).
  std::vector<std::vector<Pair>> candidates_;
  std::vector<char> group_changed_;  // per slot: pairs listed or dropped since its candidates were looked at
  // Per slot: the groups with a pair naming it as the other particle or a corner (and maybe some that
  // did: a listing only adds to it), so that a listing of a few particles visits only their groups.
  std::vector<std::vector<int>> named_by_;
  std::vector<int> dropped_from_;        // this listing's groups that named a moved particle
  std::vector<int> gone_from_, gone_end_;  // per slot in dropped_from_
  bool naming_ = false;                  // whether the listing keeps named_by_ as it goes (not a full one)
  // A settled group's bound: no pair's particles can have travelled their allowance (the reuse
  // fraction, or the margin) while the blocks of the grid that hold them have travelled less than
  // `slack` since `at`. A block is kBlock x kBlock particles; its travel is the sum over the narrow phases
  // of the farthest any of its particles went since the last (block_travel_), so a group at rest is one
  // comparison, not one per pair. Slack < 0: none (the pairs are compared one by one).
  struct GroupBound
  {
    int blocks[4] = {-2, -1, -1, -1};
    double at = 0.0;
    double slack = -1.0;
  };
  static constexpr int kBlock = 8;
  double blockTravel(const GroupBound& bound) const;
  // The blocks of the group's particles (blocks[0]: -2 not found yet, -3 more than four).
  void findBlocks(int p);
  std::vector<GroupBound> group_bound_;
  std::vector<GroupSummary> group_summary_;
  std::vector<int> block_;              // per slot
  std::vector<double> block_travel_, block_step_;  // per block
  Eigen::VectorXd built_at_;  // per slot, where its pairs were last listed (empty: none yet)
  double longest_listed_ = 0.0;  // at least the longest edge of a cell's triangles at built_at_
  std::vector<Geometry> group_geometry_;  // this step's, per candidate of one slot
  std::vector<int> moved_;                // slots moved more than half the skin
  Eigen::VectorXd last_x_;                // the free positions at the last narrow phase, before its correction
  std::vector<double> travel_;            // per slot: the length of its path over those positions since the start
  std::vector<char> is_moved_, is_anchor_listed_, is_near_moved_;
  std::vector<Touch> touches_, swept_;
  bool weights_stale_ = false;  // the colliders moved since touches_ were weighed (swept_ are weighed at once)
  std::vector<char> looking_;  // per slot: its group was looked at in this narrow phase
  std::vector<char> touched_;  // per touch swept: 0 apart, 1 pushed, 2 pushed and its velocity too in the first sweep
  // Per slot: the last sweep that pushed it by more than the settled distance (positions, velocities).
  std::vector<int> stirred_, velocity_stirred_;
  SelfCollisionReport report_;
  // Per slot: the outward normal of the collider surface it lies on (zero when on none), and its
  // travel when that was found (NaN: not yet); the colliders then (whether given, poses, active).
  std::vector<Eigen::Vector3d> surface_normal_;
  std::vector<double> surface_travel_;
  bool surface_contact_ = false;
  const Contact* contact_ = nullptr;  // this correction's
  std::vector<Eigen::Isometry3d> surface_poses_;
  std::vector<char> surface_active_;
  // Per anchor slot: the centre and the squared radius of a sphere around its cell (this step's).
  std::vector<Eigen::Vector4d> cell_sphere_;
};

}  // namespace modal_mass_spring
