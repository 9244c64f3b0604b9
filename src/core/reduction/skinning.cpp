// Skinning weights from the spring graph's Laplacian, the linear-blend map B, and the interior
// subspace with the fixed particles and handles as equality constraints on its coordinates.
#include "modal_mass_spring/skinning.h"

#include "modal_mass_spring/cubature.h"
#include "modal_mass_spring/parameter_error.h"

#include <Eigen/Geometry>

#include <Eigen/Eigenvalues>
#include <Eigen/QR>
#include <Eigen/SVD>
#include <Eigen/SparseCholesky>

#include <chrono>
#include <sstream>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

namespace modal_mass_spring
{
namespace
{

// Singular values of B_c and eigenvalues of the subspace's Gram matrix below this, relative to the
// largest, are round-off: those directions are not in the span.
constexpr double kRankTolerance = 1e-9;

}  // namespace

namespace
{

// The spring graph's Laplacian over all particles, edge weight k_s / L_s^2 (L_s the spring's length at x).
SparseMatrix springLaplacian(const Grid& grid, const Eigen::VectorXd& x)
{
  const int dim = grid.dimension();
  std::vector<Eigen::Triplet<double>> entries;
  entries.reserve(4 * grid.springs().size());
  for (const Spring& s : grid.springs())
  {
    const double length = (x.segment(dim * s.j, dim) - x.segment(dim * s.i, dim)).norm();
    const double w = s.stiffness / (length * length);
    entries.emplace_back(s.i, s.i, w);
    entries.emplace_back(s.j, s.j, w);
    entries.emplace_back(s.i, s.j, -w);
    entries.emplace_back(s.j, s.i, -w);
  }
  SparseMatrix laplacian(grid.numParticles(), grid.numParticles());
  laplacian.setFromTriplets(entries.begin(), entries.end());
  return laplacian;
}

}  // namespace

std::vector<std::vector<int>> skinningHandleGroups(const Grid& grid)
{
  std::vector<std::vector<int>> groups = grid.handles();
  if (!grid.fixedParticles().empty())
    groups.push_back(grid.fixedParticles());
  return groups;
}

namespace
{

// Refuses a number of weights m that the groups (handles and the fixed particles) and the particles
// between them cannot give.
void checkWeightCount(int m, int particles, int num_groups, int num_interior)
{
  if (num_groups == 0)
  {
    if (m < 1 || m > particles)
      rejectParameter("num_skinning_weights", m,
                      "must be in [1, " + std::to_string(particles) + "], the number of particles");
  }
  else if (m < num_groups || m > num_groups + num_interior)
    rejectParameter("num_skinning_weights", m,
                    "must be in [" + std::to_string(num_groups) + ", " + std::to_string(num_groups + num_interior) +
                        "]: one weight per handle (and one for the fixed particles), plus at most one per particle "
                        "neither held nor fixed");
}

// The interior particles' rows of `weights` (particles x m, the first num_groups columns the
// groups'): the groups' harmonic weights, then the Dirichlet Laplacian's lowest eigenvectors.
void interiorWeights(const SparseMatrix& laplacian, const std::vector<int>& interior, const std::vector<int>& group_of,
                     int num_groups, int m, double particle_mass, Eigen::MatrixXd& weights)
{
  const int particles = static_cast<int>(group_of.size());
  const int num_interior = static_cast<int>(interior.size());
  std::vector<int> interior_index(static_cast<size_t>(particles), -1);
  for (int k = 0; k < num_interior; ++k)
    interior_index[static_cast<size_t>(interior[static_cast<size_t>(k)])] = k;
  std::vector<Eigen::Triplet<double>> l_ii_entries;
  Eigen::MatrixXd l_ib_groups = Eigen::MatrixXd::Zero(num_interior, num_groups);  // L_ib times the groups' indicators
  for (int col = 0; col < laplacian.outerSize(); ++col)
    for (SparseMatrix::InnerIterator it(laplacian, col); it; ++it)
    {
      const int row = interior_index[static_cast<size_t>(it.row())];
      if (row < 0)
        continue;
      if (interior_index[static_cast<size_t>(col)] >= 0)
        l_ii_entries.emplace_back(row, interior_index[static_cast<size_t>(col)], it.value());
      else
        l_ib_groups(row, group_of[static_cast<size_t>(col)]) += it.value();
    }
  SparseMatrix l_ii(num_interior, num_interior);
  l_ii.setFromTriplets(l_ii_entries.begin(), l_ii_entries.end());
  const Eigen::SimplicialLDLT<SparseMatrix> ldlt(l_ii);
  const Eigen::MatrixXd harmonic = ldlt.solve(-l_ib_groups);
  if (ldlt.info() != Eigen::Success || !harmonic.allFinite() || ldlt.vectorD().minCoeff() <= 0.0)
    rejectParameter("handles, fixed", "(as given)",
                    "must hold every connected part of the cloth: the skinning weights are harmonic between the "
                    "held particles, and a part connected to none has none");
  for (int k = 0; k < num_interior; ++k)
    weights.row(interior[static_cast<size_t>(k)]).head(num_groups) = harmonic.row(k);
  if (m > num_groups)
  {
    Eigen::MatrixXd dirichlet =
        computeModalBasis(l_ii, Eigen::VectorXd::Constant(num_interior, particle_mass), m - num_groups).phi;
    for (int j = 0; j < dirichlet.cols(); ++j)
      dirichlet.col(j) /= dirichlet.col(j).cwiseAbs().maxCoeff();
    for (int k = 0; k < num_interior; ++k)
      weights.row(interior[static_cast<size_t>(k)]).tail(m - num_groups) = dirichlet.row(k);
  }
}

}  // namespace

Eigen::MatrixXd skinningWeights(const Grid& grid, const Eigen::VectorXd& x, int m)
{
  const int particles = grid.numParticles();
  const std::vector<std::vector<int>> groups = skinningHandleGroups(grid);
  const int num_groups = static_cast<int>(groups.size());
  std::vector<int> group_of(static_cast<size_t>(particles), -1);
  for (int k = 0; k < num_groups; ++k)
    for (int particle : groups[static_cast<size_t>(k)])
      group_of[static_cast<size_t>(particle)] = k;
  std::vector<int> interior;
  for (int i = 0; i < particles; ++i)
    if (group_of[static_cast<size_t>(i)] < 0)
      interior.push_back(i);
  const int num_interior = static_cast<int>(interior.size());
  checkWeightCount(m, particles, num_groups, num_interior);
  const SparseMatrix laplacian = springLaplacian(grid, x);
  const double particle_mass = grid.particleMass();
  if (num_groups == 0)
  {
    // Nothing held: the lowest eigenvectors of the Laplacian against the masses (the first constant).
    Eigen::MatrixXd weights = computeModalBasis(laplacian, Eigen::VectorXd::Constant(particles, particle_mass), m).phi;
    // Each of order one, so that B's columns are of the size of the cloth's coordinates.
    for (int j = 0; j < m; ++j)
      weights.col(j) /= weights.col(j).cwiseAbs().maxCoeff();
    return weights;
  }
  // Held: one harmonic weight per group (1 on it, 0 on the other groups, L w = 0 at every other
  // particle), so the groups' weights sum to one and a group's affine transform moves its particles
  // alone; then the lowest eigenvectors of the Laplacian with every held particle as a Dirichlet
  // boundary (zero there), which leave the held particles' constraints to the groups' transforms and
  // spend their coordinates on the cloth between them.
  Eigen::MatrixXd weights = Eigen::MatrixXd::Zero(particles, m);
  for (int i = 0; i < particles; ++i)
    if (group_of[static_cast<size_t>(i)] >= 0)
      weights(i, group_of[static_cast<size_t>(i)]) = 1.0;
  if (num_interior == 0)
    return weights;
  interiorWeights(laplacian, interior, group_of, num_groups, m, particle_mass, weights);
  return weights;
}

Eigen::MatrixXd skinningMap(const Grid& grid, const Eigen::VectorXd& xbar, const Eigen::MatrixXd& weights)
{
  const int dim = grid.dimension();
  const int particles = grid.numParticles();
  const int per_weight = skinningCoordinatesPerWeight(dim);
  const Eigen::Map<const Eigen::MatrixXd> points(xbar.data(), dim, particles);
  const Eigen::VectorXd centroid = points.rowwise().mean();
  Eigen::MatrixXd b = Eigen::MatrixXd::Zero(grid.numDofs(), per_weight * weights.cols());
  for (Eigen::Index j = 0; j < weights.cols(); ++j)
    for (int i = 0; i < particles; ++i)
    {
      const double w = weights(i, j);
      const Eigen::VectorXd from_centroid = points.col(i) - centroid;
      for (int a = 0; a < dim; ++a)
      {
        const Eigen::Index column = j * per_weight + a * (dim + 1);
        for (int c = 0; c < dim; ++c)
          b(dim * i + a, column + c) = w * from_centroid[c];
        b(dim * i + a, column + dim) = w;
      }
    }
  return b;
}

std::string describeSkinning(const SkinningInfo& info)
{
  std::ostringstream out;
  out.precision(3);
  out << "skinning: " << info.weights << " weights, " << info.coordinates << " coordinates, ";
  if (info.constraint_rank == info.constraint_dofs)
    out << info.constraint_dofs << " constraint dofs (fixed and handles) met exactly";
  else
    out << info.constraint_dofs << " constraint dofs (fixed and handles) of rank " << info.constraint_rank
        << " (each held group's affine motions met exactly, the rest of " << info.constraint_dofs - info.constraint_rank
        << " by least squares)";
  out << ", with " << info.modes << " modes " << info.basis_size << " directions for the free particles, built in " << 1e3 * info.seconds << " ms";
  return out.str();
}

Eigen::MatrixXd skinningProjection(const Grid& grid, const Eigen::VectorXd& x_ref, const ModalBasis& basis,
                                   const Eigen::VectorXd& mass, int num_weights)
{
  const Eigen::MatrixXd b = skinningMap(grid, x_ref, skinningWeights(grid, x_ref, num_weights));
  return basis.phi.transpose() * mass.asDiagonal() * b(grid.freeDofs(), Eigen::all);
}

namespace
{

// A rotation by `angle` about a uniformly random axis (3D), or in the grid's plane (2D).
Eigen::MatrixXd randomRotation(int dim, double angle, std::mt19937_64& rng)
{
  if (dim == 2)
  {
    Eigen::Matrix2d r;
    r << std::cos(angle), -std::sin(angle), std::sin(angle), std::cos(angle);
    return r;
  }
  std::normal_distribution<double> normal;
  Eigen::Vector3d axis(normal(rng), normal(rng), normal(rng));
  if (axis.norm() == 0.0)
    axis = Eigen::Vector3d::UnitZ();
  return Eigen::AngleAxisd(angle, axis.normalized()).toRotationMatrix();
}

// The smallest ratio of a spring's length at x_ref + u (u on the free dofs) to its length at x_ref.
double shortestSpringRatio(const Grid& grid, const Eigen::VectorXd& x_ref, const Eigen::VectorXd& u)
{
  Eigen::VectorXd x = x_ref;
  grid.addFree(u, x);
  const int dim = grid.dimension();
  double shortest = std::numeric_limits<double>::infinity();
  for (const Spring& s : grid.springs())
  {
    const double before = (x_ref.segment(dim * s.j, dim) - x_ref.segment(dim * s.i, dim)).norm();
    const double after = (x.segment(dim * s.j, dim) - x.segment(dim * s.i, dim)).norm();
    shortest = std::min(shortest, after / before);
  }
  return shortest;
}

// Psi = E H^+ + Psi_0 (I - H H^+): H (handle dofs x affine coordinates) moves the handle particles
// by an affine map, E the free particles by the same map, H^+ is the least-squares fit of one to a
// handle motion dx_b. The part of dx_b that is such a map (every rigid motion of the handles taken
// together, a turn of any angle included) moves the whole cloth by it, the rest is carried by
// Psi_0. Either way Psi dx_b is in the span with the handles met, so the subspace and `physical` are
// unchanged, but a turned clamp now turns the reference x_ref + Psi dx_b with it: the reduced
// coordinates keep only the deformation, which the cubature, trained about x_ref, fits.
// The map is taken about the handle particles' centroid: what the handles leave undetermined (the
// columns of A along which they do not spread: all but the translation for one particle, the axis
// across a row) is then zero in the least-squares fit, so that a translation of the handles, say,
// translates the cloth rather than shearing it about a point away from them.
Eigen::MatrixXd affineHandleExtension(const Grid& grid, const Eigen::VectorXd& x_ref, const Eigen::MatrixXd& minimal)
{
  const int dim = grid.dimension();
  const std::vector<int>& handle_dofs = grid.handleDofs();
  Eigen::VectorXd centre = Eigen::VectorXd::Zero(dim);
  for (size_t k = 0; k < handle_dofs.size(); ++k)
    centre[handle_dofs[k] % dim] += x_ref[handle_dofs[k]];
  centre *= static_cast<double>(dim) / static_cast<double>(handle_dofs.size());
  // Row (i, a): dof a of particle i moved by A (x_i - centre) + t, columns A(a, 0..dim-1) and t(a).
  Eigen::MatrixXd affine = Eigen::MatrixXd::Zero(grid.numDofs(), dim * (dim + 1));
  for (int i = 0; i < grid.numParticles(); ++i)
    for (int a = 0; a < dim; ++a)
    {
      for (int c = 0; c < dim; ++c)
        affine(dim * i + a, a * (dim + 1) + c) = x_ref[dim * i + c] - centre[c];
      affine(dim * i + a, a * (dim + 1) + dim) = 1.0;
    }
  const Eigen::MatrixXd h = affine(handle_dofs, Eigen::all);
  Eigen::CompleteOrthogonalDecomposition<Eigen::MatrixXd> fit;
  fit.setThreshold(kRankTolerance);  // handles in a plane or on a line fix the map only there
  fit.compute(h);
  const Eigen::MatrixXd h_plus = fit.pseudoInverse();
  Eigen::MatrixXd psi = affine(grid.freeDofs(), Eigen::all) * h_plus;
  psi += minimal;
  psi.noalias() -= (minimal * h) * h_plus;
  return psi;
}

}  // namespace

Eigen::MatrixXd skinningTrainingPoses(const Grid& grid, const ModalBasis& basis, const Eigen::VectorXd& x_ref,
                                      const Eigen::MatrixXd& projection, int count, double size, std::mt19937_64& rng)
{
  const int dim = grid.dimension();
  const int per_weight = skinningCoordinatesPerWeight(dim);
  const Eigen::Index weights = projection.cols() / per_weight;
  const double pi = 3.14159265358979323846;
  std::uniform_real_distribution<double> uniform;
  Eigen::MatrixXd poses = trainingPoses(grid, basis, x_ref, count, size, rng);
  Eigen::VectorXd z(projection.cols());
  for (int p = 0; p < count; ++p)
  {
    std::vector<double> angles(static_cast<size_t>(weights));
    for (Eigen::Index j = 0; j < weights; ++j)
      angles[static_cast<size_t>(j)] = (dim == 2 && uniform(rng) < 0.5 ? -1.0 : 1.0) * uniform(rng) *
                                       (j == 0 ? pi : 0.5 * pi / std::sqrt(static_cast<double>(j)));
    std::vector<Eigen::MatrixXd> rotations;
    for (Eigen::Index j = 0; j < weights; ++j)
      rotations.push_back(randomRotation(dim, 1.0, rng));  // the axis; the angle is set below
    for (int halving = 0; halving < 20; ++halving)
    {
      z.setZero();
      for (Eigen::Index j = 0; j < weights; ++j)
      {
        const double angle = angles[static_cast<size_t>(j)] * (j == 0 ? 1.0 : std::pow(0.5, halving));
        Eigen::MatrixXd r;
        if (dim == 2)
          r = randomRotation(2, angle, rng);
        else
          r = Eigen::AngleAxisd(angle, Eigen::AngleAxisd(Eigen::Matrix3d(rotations[static_cast<size_t>(j)])).axis())
                  .toRotationMatrix();
        r -= Eigen::MatrixXd::Identity(dim, dim);
        for (int a = 0; a < dim; ++a)
          for (int c = 0; c < dim; ++c)
            z[j * per_weight + a * (dim + 1) + c] = r(a, c);
      }
      const Eigen::VectorXd turned = poses.col(p) + projection * z;
      // A pose that still folds keeps its stretch alone.
      if (shortestSpringRatio(grid, x_ref, basis.phi * turned) >= kShortestTrainingSpring)
      {
        poses.col(p) = turned;
        break;
      }
    }
  }
  return poses;
}

namespace
{

// The constraints' rows of B: the fixed particles' dofs (held at 0), then the handle dofs (at dx_b).
std::vector<int> heldDofs(const Grid& grid)
{
  const int dim = grid.dimension();
  std::vector<int> held;
  for (int particle : grid.fixedParticles())
    for (int a = 0; a < dim; ++a)
      held.push_back(dim * particle + a);
  held.insert(held.end(), grid.handleDofs().begin(), grid.handleDofs().end());
  return held;
}

// B_c = U S V^T: the null space N is V's columns past the rank, and the least-squares (minimum-norm)
// solution of B_c z = (0, dx_b) is G dx_b with G = V_k S_k^-1 U_k^T's handle columns (`particular`,
// p x nb, for nb > 0 handle dofs).
int splitConstraints(const Eigen::MatrixXd& b, const std::vector<int>& held, Eigen::Index nb, Eigen::MatrixXd& null_space,
                     Eigen::MatrixXd& particular)
{
  const Eigen::Index p = b.cols();
  null_space = Eigen::MatrixXd::Identity(p, p);
  int rank = 0;
  if (held.empty())
    return rank;
  const Eigen::MatrixXd b_c = b(held, Eigen::all);
  const Eigen::BDCSVD<Eigen::MatrixXd> svd(b_c, Eigen::ComputeFullV | Eigen::ComputeThinU);
  const Eigen::VectorXd& sigma = svd.singularValues();
  while (rank < sigma.size() && sigma[rank] > kRankTolerance * sigma[0])
    ++rank;
  null_space = svd.matrixV().rightCols(p - rank);
  if (nb > 0)
    particular = svd.matrixV().leftCols(rank) * sigma.head(rank).cwiseInverse().asDiagonal() *
                 svd.matrixU().bottomRows(nb).leftCols(rank).transpose();
  return rank;
}

// The span of `interior`'s columns made mass-orthonormal from its Gram matrix, directions that move
// no free dof dropped (refused when none is left, naming num_weights).
Eigen::MatrixXd massOrthonormal(Eigen::MatrixXd interior, const Eigen::VectorXd& mass, int num_weights)
{
  // Unit mass norm each, so that the rank tolerance compares directions, not their scales; a column
  // of round-off only (a null-space vector of coordinates that move nothing, such as an out-of-plane
  // column of A_j on a planar sheet, carries round-off of coordinates the constraints fix) is
  // dropped rather than blown up into a direction that would move the held particles.
  Eigen::VectorXd norms(interior.cols());
  for (Eigen::Index k = 0; k < interior.cols(); ++k)
    norms[k] = std::sqrt(interior.col(k).cwiseAbs2().dot(mass));
  const double largest_norm = norms.size() > 0 ? norms.maxCoeff() : 0.0;
  for (Eigen::Index k = 0; k < interior.cols(); ++k)
  {
    if (norms[k] > kRankTolerance * largest_norm)
      interior.col(k) /= norms[k];
    else
      interior.col(k).setZero();
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> gram(interior.transpose() * mass.asDiagonal() * interior);
  const Eigen::VectorXd& g = gram.eigenvalues();  // ascending
  Eigen::Index kept = 0;
  while (kept < g.size() && g[g.size() - 1 - kept] > kRankTolerance * g[g.size() - 1])
    ++kept;
  if (interior.cols() == 0 || kept == 0 || !(g[g.size() - 1] > 0.0))
    rejectParameter("num_skinning_weights", num_weights,
                    "leaves the free particles no motion: the fixed particles and handles take every direction of "
                    "the span; use more weights");
  return interior * (gram.eigenvectors().rightCols(kept) * g.tail(kept).cwiseSqrt().cwiseInverse().asDiagonal());
}

// The mass-orthonormal span rotated to diagonalise K (Rayleigh-Ritz): mass is I and Rayleigh damping
// diagonal, as for the eigenbasis.
void rayleighRitz(const Eigen::MatrixXd& orthonormal, const SparseMatrix& stiffness, const Eigen::VectorXd& mass,
                  ModalBasis& basis)
{
  const Eigen::MatrixXd k_reduced = orthonormal.transpose() * (stiffness * orthonormal);
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> ritz(0.5 * (k_reduced + k_reduced.transpose()));
  basis.phi = orthonormal * ritz.eigenvectors();
  basis.eigenvalues = ritz.eigenvalues();
  // Zero below 1e-8 of the largest diagonal stiffness per mass, as computeModalBasis counts them.
  const double scale = stiffness.diagonal().cwiseQuotient(mass).cwiseAbs().maxCoeff();
  for (Eigen::Index k = 0; k < basis.eigenvalues.size(); ++k)
    if (std::abs(basis.eigenvalues[k]) < 1e-8 * scale)
    {
      basis.eigenvalues[k] = 0.0;
      ++basis.num_zero_modes;
    }
  basis.eigenvalues = basis.eigenvalues.cwiseMax(0.0);
  basis.frequencies = basis.eigenvalues.cwiseSqrt();
  basis.sparse = false;
}

}  // namespace

SkinningBasis buildSkinningBasis(const Grid& grid, const Eigen::VectorXd& x_ref, const SparseMatrix& stiffness,
                                 const Eigen::VectorXd& mass, int num_weights, const Eigen::MatrixXd& modes)
{
  const auto start = std::chrono::steady_clock::now();
  const Eigen::MatrixXd b = skinningMap(grid, x_ref, skinningWeights(grid, x_ref, num_weights));
  const Eigen::Index p = b.cols();
  const std::vector<int> held = heldDofs(grid);
  const Eigen::Index c = static_cast<Eigen::Index>(held.size()), nb = grid.numHandleDofs();
  Eigen::MatrixXd null_space, particular;
  const int rank = splitConstraints(b, held, nb, null_space, particular);

  // The interior subspace B_i N and the modes, made mass-orthonormal, then rotated to diagonalise K.
  const Eigen::MatrixXd b_i = b(grid.freeDofs(), Eigen::all);
  Eigen::MatrixXd interior(b_i.rows(), null_space.cols() + modes.cols());
  interior << b_i * null_space, modes;
  const Eigen::MatrixXd orthonormal = massOrthonormal(std::move(interior), mass, num_weights);
  SkinningBasis out;
  ModalBasis& basis = out.basis;
  rayleighRitz(orthonormal, stiffness, mass, basis);
  if (nb > 0)
  {
    out.constraint_modes = b_i * particular;
    out.constraint_modes -= basis.phi * (basis.phi.transpose() * mass.asDiagonal() * out.constraint_modes);
    out.constraint_modes = affineHandleExtension(grid, x_ref, out.constraint_modes);
  }
  out.info.weights = num_weights;
  out.info.coordinates = static_cast<int>(p);
  out.info.constraint_dofs = static_cast<int>(c);
  out.info.constraint_rank = rank;
  out.info.basis_size = static_cast<int>(orthonormal.cols());
  out.info.modes = static_cast<int>(modes.cols());
  out.info.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  basis.build_seconds = out.info.seconds;
  return out;
}

}  // namespace modal_mass_spring
