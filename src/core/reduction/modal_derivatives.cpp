// Modal derivatives by one sparse factorisation of K, and their mass-PCA into the basis.
#include "modal_mass_spring/modal_derivatives.h"

#include "modal_mass_spring/parameter_error.h"

#include <Eigen/Eigenvalues>
#include <Eigen/SparseCholesky>

#include <chrono>
#include <cmath>
#include <stdexcept>
#include <string>

namespace modal_mass_spring
{

ModalDerivatives computeModalDerivatives(const Grid& grid, const Eigen::VectorXd& x_ref, const SparseMatrix& stiffness,
                                         const ModalBasis& modes)
{
  if (modes.num_zero_modes > 0)
    rejectParameter("basis", "modal_derivatives",
                    "needs a stiffness without zero modes, and the linear modes include " +
                        std::to_string(modes.num_zero_modes) +
                        " (K is singular: no static response); use linearization: equilibrium, or basis: linear_modes");
  const int r = static_cast<int>(modes.phi.cols());
  const int n = static_cast<int>(modes.phi.rows());
  ModalDerivatives out;
  out.rhs.resize(n, r * (r + 1) / 2);
  for (int j = 0; j < r; ++j)
  {
    // dK/dx[Phi_j] is symmetric in the pair: one assembly serves every i <= j.
    const SparseMatrix dk = tangentStiffnessDerivative(grid, x_ref, modes.phi.col(j));
    for (int i = 0; i <= j; ++i)
    {
      out.rhs.col(static_cast<Eigen::Index>(out.pairs.size())) = dk * modes.phi.col(i);
      out.pairs.emplace_back(i, j);
    }
  }
  Eigen::SimplicialLDLT<SparseMatrix> ldlt(stiffness);
  if (ldlt.info() != Eigen::Success)
    throw std::runtime_error("modal derivatives: factorising K at the linearization point failed");
  out.psi = -ldlt.solve(out.rhs);
  if (!out.psi.allFinite())
    throw std::runtime_error("modal derivatives: K at the linearization point is singular (a non-finite solve)");
  return out;
}

namespace
{

// The derivatives weighted by lambda_1^2 / (lambda_i lambda_j), with their part in the span of the
// modes removed (M-orthogonally, twice for round-off), in the coordinates M^1/2 u where the mass
// norm is the Euclidean one.
Eigen::MatrixXd weightedDerivatives(const ModalDerivatives& derivatives, const ModalBasis& modes,
                                    const Eigen::VectorXd& mass, const Eigen::VectorXd& sqrt_mass)
{
  const Eigen::MatrixXd& phi = modes.phi;
  const Eigen::Index n = phi.rows(), pairs = derivatives.psi.cols();
  const double lambda1 = modes.eigenvalues[0];
  Eigen::MatrixXd w(n, pairs);
  for (Eigen::Index k = 0; k < pairs; ++k)
  {
    const auto [i, j] = derivatives.pairs[k];
    w.col(k) = (lambda1 * lambda1 / (modes.eigenvalues[i] * modes.eigenvalues[j])) * derivatives.psi.col(k);
  }
  for (int pass = 0; pass < 2; ++pass)
    w -= phi * (phi.transpose() * mass.asDiagonal() * w);
  w = sqrt_mass.asDiagonal() * w;
  return w;
}

// The kept directions u (in M^1/2 coordinates) orthonormalised in the Euclidean (mass) norm, again
// against the modes phi, and taken back to u = M^-1/2 (that).
Eigen::MatrixXd orthonormalDirections(Eigen::MatrixXd u, const Eigen::MatrixXd& phi, const Eigen::VectorXd& sqrt_mass)
{
  const Eigen::MatrixXd phi_scaled = sqrt_mass.asDiagonal() * phi;
  for (Eigen::Index k = 0; k < u.cols(); ++k)
  {
    for (int pass = 0; pass < 2; ++pass)
    {
      u.col(k) -= phi_scaled * (phi_scaled.transpose() * u.col(k));
      u.col(k) -= u.leftCols(k) * (u.leftCols(k).transpose() * u.col(k));
    }
    u.col(k).normalize();
  }
  return sqrt_mass.cwiseInverse().asDiagonal() * u;
}

}  // namespace

ModalBasis buildDerivativeBasis(const Grid& grid, const Eigen::VectorXd& x_ref, const SparseMatrix& stiffness,
                                const Eigen::VectorXd& mass, const ModalBasis& modes, int num_derivative_modes,
                                DerivativeBasisInfo* info)
{
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  const ModalDerivatives derivatives = computeModalDerivatives(grid, x_ref, stiffness, modes);
  const Eigen::MatrixXd& phi = modes.phi;
  const Eigen::Index r = phi.cols(), n = phi.rows(), d = num_derivative_modes;
  const Eigen::Index pairs = derivatives.psi.cols();
  if (d < 1 || d > pairs || r + d > n)
    rejectParameter("num_derivative_modes", d,
                    "must be in [1, " + std::to_string(std::min<Eigen::Index>(pairs, n - r)) +
                        "]: at most the r (r + 1) / 2 pairs of the r = num_modes linear modes, and at most the free "
                        "degrees of freedom minus num_modes");

  const Eigen::VectorXd sqrt_mass = mass.cwiseSqrt();
  const Eigen::MatrixXd w = weightedDerivatives(derivatives, modes, mass, sqrt_mass);

  // Mass-PCA: the leading left singular vectors of W from the eigenvectors of the small Gram matrix
  // W^T W (pairs x pairs), U = W V S^-1.
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> gram(w.transpose() * w);
  const Eigen::VectorXd sigma2 = gram.eigenvalues().reverse().cwiseMax(0.0);  // descending
  const Eigen::MatrixXd v = gram.eigenvectors().rowwise().reverse();
  const double largest = std::sqrt(sigma2[0]);
  const double smallest_kept = std::sqrt(sigma2[d - 1]) / largest;
  // Below this the direction is round-off of the projection, not a derivative: say so, never keep noise.
  if (!(largest > 0.0) || !(smallest_kept > 1e-6))
  {
    int independent = 0;
    while (independent < pairs && largest > 0.0 && std::sqrt(sigma2[independent]) / largest > 1e-6)
      ++independent;
    rejectParameter("num_derivative_modes", d,
                    "the derivatives of the " + std::to_string(r) + " linear modes span only " +
                        std::to_string(independent) + " directions outside them on this grid; ask for at most that many");
  }
  const Eigen::MatrixXd directions = orthonormalDirections(w * v.leftCols(d), phi, sqrt_mass);

  // Rotate the derivative directions so that their block of Phi^T K Phi is diagonal: its Ritz values
  // are then the directions' lambda^2 (their frequencies set the explicit step).
  const Eigen::MatrixXd k_directions = stiffness * directions;
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> ritz(directions.transpose() * k_directions);
  ModalBasis basis = modes;
  basis.phi.resize(n, r + d);
  basis.phi << phi, directions * ritz.eigenvectors();
  basis.reduced_stiffness = basis.phi.transpose() * (stiffness * basis.phi);
  basis.reduced_stiffness = 0.5 * (basis.reduced_stiffness + basis.reduced_stiffness.transpose()).eval();
  basis.eigenvalues.resize(r + d);
  basis.eigenvalues << modes.eigenvalues, ritz.eigenvalues();
  basis.frequencies = basis.eigenvalues.cwiseMax(0.0).cwiseSqrt();
  if (info)
  {
    info->linear_modes = static_cast<int>(r);
    info->derivative_directions = static_cast<int>(d);
    info->derivatives_computed = static_cast<int>(pairs);
    info->smallest_kept_singular_value = smallest_kept;
    info->largest_dropped_singular_value = d < pairs ? std::sqrt(sigma2[d]) / largest : 0.0;
    info->seconds = std::chrono::duration<double>(Clock::now() - start).count();
  }
  return basis;
}

}  // namespace modal_mass_spring
