// Handle coupling, constraint modes and the rigid motion of a handle between two frame poses.
#include "modal_mass_spring/handles.h"

#include <Eigen/QR>
#include <Eigen/SparseCholesky>

#include <stdexcept>
#include <string>
#include <utility>

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
    // As K at the linearization point, which leaves compressed springs' geometric stiffness out.
    const Eigen::VectorXd d = x.segment(dim * s.j, dim) - x.segment(dim * s.i, dim);
    const Eigen::MatrixXd ke = springHessian(s.stiffness, s.rest_length, d, CompressedSprings::Drop);
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

namespace
{

// The two poses' rotations as unit quaternions on the same side (q and -q are the same rotation), so
// that the slerp between them and the turn they make take the shorter way.
std::pair<Eigen::Quaterniond, Eigen::Quaterniond> shorterWay(const FramePose& from, const FramePose& to)
{
  const Eigen::Quaterniond q0 = from.rotation.normalized();
  Eigen::Quaterniond q1 = to.rotation.normalized();
  if (q0.dot(q1) < 0.0)
    q1.coeffs() = -q1.coeffs();
  return {q0, q1};
}

}  // namespace

FrameVelocity interpolationVelocity(const FramePose& from, const FramePose& to, double duration)
{
  const auto [q0, q1] = shorterWay(from, to);
  // Slerp turns at a constant rate about a fixed axis: omega = angle / T along it (world frame).
  const Eigen::AngleAxisd turn(q1 * q0.conjugate());
  return {(to.translation - from.translation) / duration, turn.angle() * turn.axis() / duration};
}

RigidPointMotion interpolateRigidMotion(const Eigen::Matrix3Xd& offsets, const FramePose& from, const FramePose& to,
                                        double duration, double s)
{
  const auto [q0, q1] = shorterWay(from, to);
  const Eigen::Quaterniond rotation = q0.slerp(s, q1);
  const FrameVelocity frame = interpolationVelocity(from, to, duration);
  const Eigen::Vector3d& omega = frame.angular;
  const Eigen::Vector3d& velocity = frame.linear;
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

namespace modal_mass_spring
{

std::vector<int> gridAxes(int dimension) { return dimension == 3 ? std::vector<int>{0, 1, 2} : std::vector<int>{0, 2}; }

Eigen::Matrix3d crossMatrix(const Eigen::Vector3d& w)
{
  Eigen::Matrix3d m;
  m << 0.0, -w.z(), w.y(), w.z(), 0.0, -w.x(), -w.y(), w.x(), 0.0;
  return m;
}

bool FrameMotion::atRest() const
{
  return translation.isZero(0.0) && rotation == Eigen::Matrix3d::Identity() && velocity.isZero(0.0) &&
         acceleration.isZero(0.0) && angular_velocity.isZero(0.0) && angular_acceleration.isZero(0.0);
}

RigidPointMotion pointMotion(const FrameMotion& frame, const Eigen::Matrix3Xd& points)
{
  RigidPointMotion m;
  const Eigen::Matrix3Xd r = frame.rotation * points;
  m.position = r.colwise() + frame.translation;
  m.velocity.resize(3, points.cols());
  m.acceleration.resize(3, points.cols());
  const Eigen::Vector3d& w = frame.angular_velocity;
  for (Eigen::Index k = 0; k < points.cols(); ++k)
  {
    m.velocity.col(k) = frame.velocity + w.cross(r.col(k));
    m.acceleration.col(k) = frame.acceleration + frame.angular_acceleration.cross(r.col(k)) + w.cross(w.cross(r.col(k)));
  }
  return m;
}

FrameMotion interpolateFrameMotion(const FramePose& start, const FramePose& from, const FramePose& to,
                                   double duration, double s)
{
  // The frame's origin c and rotation Q along the path (interpolateRigidMotion of the origin): then
  // x = c + Q Q_start^-1 (y - c_start), so R = Q Q_start^-1 and p = c - R c_start.
  const Eigen::Matrix3Xd origin = Eigen::Vector3d::Zero();
  const RigidPointMotion c = interpolateRigidMotion(origin, from, to, duration, s);
  const auto [q0, q1] = shorterWay(from, to);
  FrameMotion m;
  m.rotation = (q0.slerp(s, q1) * start.rotation.normalized().conjugate()).toRotationMatrix();
  m.angular_velocity = interpolationVelocity(from, to, duration).angular;
  const Eigen::Vector3d r = m.rotation * start.translation;  // the start's origin, turned
  const Eigen::Vector3d& w = m.angular_velocity;
  m.translation = c.position.col(0) - r;
  m.velocity = c.velocity.col(0) - w.cross(r);
  m.acceleration = c.acceleration.col(0) - w.cross(w.cross(r));
  return m;
}

FrameForces frameForces(const FrameMotion& motion, int dimension, const Eigen::Vector3d& gravity, double alpha)
{
  const Eigen::Matrix3d& rt = motion.rotation.transpose();
  const Eigen::Vector3d w = rt * motion.angular_velocity;
  const Eigen::Matrix3d spin = crossMatrix(w);
  const Eigen::Vector3d uniform = rt * gravity - gravity - rt * (motion.acceleration + alpha * motion.velocity);
  const Eigen::Matrix3d position = crossMatrix(rt * motion.angular_acceleration) + spin * spin + alpha * spin;
  const std::vector<int> rows = gridAxes(dimension);
  FrameForces f;
  f.rotation = motion.rotation(rows, rows);
  f.uniform = uniform(rows);
  f.position = position(rows, rows);
  f.spin = spin(rows, rows);
  f.none = motion.atRest();
  return f;
}

AffineHandleFit::AffineHandleFit(const Grid& grid, const Eigen::VectorXd& x)
{
  const int dim = grid.dimension();
  const std::vector<int>& dofs = grid.handleDofs();
  if (dofs.empty())
    return;
  Eigen::VectorXd centre = Eigen::VectorXd::Zero(dim);
  for (int dof : dofs)
    centre[dof % dim] += x[dof];
  centre *= static_cast<double>(dim) / static_cast<double>(dofs.size());
  // Row (i, a): dof a of handle particle i moved by A (x_i - centre) + t, columns A(a, 0..dim-1), t(a).
  h = Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(dofs.size()), dim * (dim + 1));
  for (size_t k = 0; k < dofs.size(); ++k)
  {
    const int a = dofs[k] % dim, particle = dofs[k] / dim;
    const Eigen::Index row = static_cast<Eigen::Index>(k);
    for (int c = 0; c < dim; ++c)
      h(row, a * (dim + 1) + c) = x[dim * particle + c] - centre[c];
    h(row, a * (dim + 1) + dim) = 1.0;
  }
  Eigen::CompleteOrthogonalDecomposition<Eigen::MatrixXd> fit;
  fit.setThreshold(1e-9);  // handles in a plane or on a line fix the map only there
  fit.compute(h);
  h_plus = fit.pseudoInverse();
}

bool AffineHandleFit::split(const Eigen::VectorXd& dx, Eigen::VectorXd& a, Eigen::VectorXd& rest) const
{
  a.noalias() = h_plus * dx;
  rest = dx;
  rest.noalias() -= h * a;
  return rest.norm() > 1e-12 * dx.norm();
}

}  // namespace modal_mass_spring
