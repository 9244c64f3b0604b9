// A spring seen from a modal basis (internal), shared by the cubature's training and its force model:
// how the basis moves its vector, and its force.
#pragma once

#include "modal_mass_spring/grid.h"
#include "modal_mass_spring/spring_law.h"

#include <Eigen/Core>

namespace modal_mass_spring
{

// Up to 3 entries, never on the heap: per-spring vectors of the training.
using SmallVector = Eigen::Matrix<double, Eigen::Dynamic, 1, 0, 3, 1>;

// D_s = Phi_j - Phi_i: the spring's vector from i to j changes by D_s X (dim x r; fixed rows are 0).
// Read from Phi^T, where a dof's row of Phi is contiguous (Phi's rows are strided by n).
inline Eigen::MatrixXd springRows(const Grid& grid, const Eigen::MatrixXd& phi_t, const Spring& s)
{
  const int dim = grid.dimension();
  Eigen::MatrixXd rows = Eigen::MatrixXd::Zero(dim, phi_t.rows());
  for (int a = 0; a < dim; ++a)
  {
    const int fi = grid.freeIndex(dim * s.i + a), fj = grid.freeIndex(dim * s.j + a);
    if (fj >= 0)
      rows.row(a) += phi_t.col(fj).transpose();
    if (fi >= 0)
      rows.row(a) -= phi_t.col(fi).transpose();
  }
  return rows;
}

// The force on particle i of a spring whose vector from i to j is d.
inline SmallVector springForce(const Spring& s, const SmallVector& d)
{
  return modal_mass_spring::springForce(s.stiffness, s.rest_length, d);
}

inline Eigen::VectorXd restDiff(const Grid& grid, const Eigen::VectorXd& x, const Spring& s)
{
  const int dim = grid.dimension();
  return x.segment(dim * s.j, dim) - x.segment(dim * s.i, dim);
}

}  // namespace modal_mass_spring
