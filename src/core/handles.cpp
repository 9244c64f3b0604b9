// Handle coupling, constraint modes and the rigid motion of a handle between two frame poses.
#include "modal_mass_spring/handles.h"

#include <Eigen/SparseCholesky>

#include <stdexcept>
#include <string>

namespace modal_mass_spring
{

bool HandleMotion::atRest() const
{
  auto zero = [](const Eigen::VectorXd& v) { return v.size() == 0 || v.isZero(0.0); };
  return zero(displacement) && zero(velocity) && zero(acceleration);
}

SparseMatrix handleCoupling(const Grid& grid, const Eigen::VectorXd& x)
{
  const int dim = grid.dimension();
  // The column of each handle dof.
  std::vector<int> column(grid.numDofs(), -1);
  for (int k = 0; k < grid.numHandleDofs(); ++k)
    column[grid.handleDofs()[k]] = k;
  std::vector<Eigen::Triplet<double>> triplets;
  for (const Spring& s : grid.springs())
  {
    // Only springs between an interior and a handle particle couple them.
    int interior = s.i, handle = s.j;
    if (!grid.isHandle(handle))
      std::swap(interior, handle);
    if (!grid.isHandle(handle) || grid.freeIndex(dim * interior) < 0)
      continue;
    const Eigen::VectorXd d = x.segment(dim * s.j, dim) - x.segment(dim * s.i, dim);
    const double l = d.norm();
    const Eigen::VectorXd u = d / l;
    const Eigen::MatrixXd uu = u * u.transpose();
    Eigen::MatrixXd ke = s.stiffness * uu;
    if (l >= s.rest_length)
      ke += s.stiffness * (1.0 - s.rest_length / l) * (Eigen::MatrixXd::Identity(dim, dim) - uu);
    // The off-diagonal block of the spring's Hessian is -Ke.
    for (int r = 0; r < dim; ++r)
      for (int c = 0; c < dim; ++c)
        triplets.emplace_back(grid.freeIndex(dim * interior + r), column[dim * handle + c], -ke(r, c));
  }
  SparseMatrix k_ib(grid.numFreeDofs(), grid.numHandleDofs());
  k_ib.setFromTriplets(triplets.begin(), triplets.end());
  return k_ib;
}

Eigen::MatrixXd constraintModes(const SparseMatrix& k_ii, const SparseMatrix& k_ib)
{
  Eigen::SimplicialLDLT<SparseMatrix> ldlt(k_ii);
  const double scale = k_ii.diagonal().cwiseAbs().maxCoeff();
  if (ldlt.info() != Eigen::Success || ldlt.vectorD().minCoeff() <= 1e-12 * scale)
    throw std::runtime_error(
        "handles: the stiffness of the interior dofs with the handles held is singular, so the constraint modes "
        "Psi = -K_ii^-1 K_ib do not exist; the fixed particles and handles must hold the grid against rigid "
        "motion, and a 3D sheet needs linearization: equilibrium (at rest it has no out-of-plane stiffness)");
  const Eigen::MatrixXd rhs = -Eigen::MatrixXd(k_ib);
  Eigen::MatrixXd psi = ldlt.solve(rhs);
  if (!psi.allFinite())
    throw std::runtime_error("handles: the constraint modes are not finite");
  return psi;
}

RigidPointMotion interpolateRigidMotion(const Eigen::Matrix3Xd& offsets, const FramePose& from, const FramePose& to,
                                        double duration, double s)
{
  const Eigen::Quaterniond q0 = from.rotation.normalized();
  Eigen::Quaterniond q1 = to.rotation.normalized();
  if (q0.dot(q1) < 0.0)
    q1.coeffs() = -q1.coeffs();  // the same rotation; slerp then takes the shorter way
  const Eigen::Quaterniond rotation = q0.slerp(s, q1);
  // Slerp turns at a constant rate about a fixed axis: omega = angle / T along it (world frame).
  const Eigen::AngleAxisd turn(q1 * q0.conjugate());
  const Eigen::Vector3d omega = turn.angle() * turn.axis() / duration;
  const Eigen::Vector3d velocity = (to.translation - from.translation) / duration;
  const Eigen::Vector3d origin = from.translation + s * (to.translation - from.translation);

  RigidPointMotion motion;
  const Eigen::Matrix3Xd r = rotation.toRotationMatrix() * offsets;
  motion.position = r.colwise() + origin;
  motion.velocity.resize(3, offsets.cols());
  motion.acceleration.resize(3, offsets.cols());
  for (Eigen::Index k = 0; k < offsets.cols(); ++k)
  {
    motion.velocity.col(k) = velocity + omega.cross(r.col(k));
    motion.acceleration.col(k) = omega.cross(omega.cross(r.col(k)));
  }
  return motion;
}

}  // namespace modal_mass_spring
