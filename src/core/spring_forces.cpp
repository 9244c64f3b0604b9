// Per-spring force and Hessian, written once for 2D and 3D through a fixed-size template.
#include "modal_mass_spring/spring_forces.h"

#include <vector>

namespace modal_mass_spring
{
namespace
{

template <int Dim>
void springForcesDim(const Grid& grid, const Eigen::VectorXd& x, Eigen::VectorXd& f)
{
  using Vec = Eigen::Matrix<double, Dim, 1>;
  f.setZero(x.size());
  for (const Spring& s : grid.springs())
  {
    const Vec d = x.segment<Dim>(Dim * s.j) - x.segment<Dim>(Dim * s.i);
    const double l = d.norm();
    const Vec fi = s.stiffness * (l - s.rest_length) / l * d;
    f.segment<Dim>(Dim * s.i) += fi;
    f.segment<Dim>(Dim * s.j) -= fi;
  }
}

template <int Dim>
SparseMatrix tangentStiffnessDim(const Grid& grid, const Eigen::VectorXd& x, CompressedSprings compressed,
                                 int* num_dropped)
{
  using Vec = Eigen::Matrix<double, Dim, 1>;
  using Mat = Eigen::Matrix<double, Dim, Dim>;
  std::vector<Eigen::Triplet<double>> triplets;
  triplets.reserve(grid.springs().size() * 4 * Dim * Dim);
  int dropped = 0;

  // Adds sign * Ke to the block (a, b) of particles, skipping fixed dofs.
  auto addBlock = [&](int a, int b, const Mat& ke, double sign) {
    for (int r = 0; r < Dim; ++r)
    {
      const int row = grid.freeIndex(Dim * a + r);
      if (row < 0)
        continue;
      for (int c = 0; c < Dim; ++c)
      {
        const int col = grid.freeIndex(Dim * b + c);
        if (col >= 0)
          triplets.emplace_back(row, col, sign * ke(r, c));
      }
    }
  };

  for (const Spring& s : grid.springs())
  {
    const Vec d = x.segment<Dim>(Dim * s.j) - x.segment<Dim>(Dim * s.i);
    const double l = d.norm();
    const Vec u = d / l;
    const Mat uu = u * u.transpose();
    Mat ke = s.stiffness * uu;
    if (l >= s.rest_length || compressed == CompressedSprings::Keep)
      ke += s.stiffness * (1.0 - s.rest_length / l) * (Mat::Identity() - uu);
    else
      ++dropped;
    addBlock(s.i, s.i, ke, 1.0);
    addBlock(s.j, s.j, ke, 1.0);
    addBlock(s.i, s.j, ke, -1.0);
    addBlock(s.j, s.i, ke, -1.0);
  }
  if (num_dropped)
    *num_dropped = dropped;
  SparseMatrix k(grid.numFreeDofs(), grid.numFreeDofs());
  k.setFromTriplets(triplets.begin(), triplets.end());
  return k;
}

}  // namespace

void springForces(const Grid& grid, const Eigen::VectorXd& x, Eigen::VectorXd& f)
{
  if (grid.dimension() == 2)
    springForcesDim<2>(grid, x, f);
  else
    springForcesDim<3>(grid, x, f);
}

double springEnergy(const Grid& grid, const Eigen::VectorXd& x)
{
  const int dim = grid.dimension();
  double energy = 0.0;
  for (const Spring& s : grid.springs())
  {
    const double l = (x.segment(dim * s.j, dim) - x.segment(dim * s.i, dim)).norm();
    energy += 0.5 * s.stiffness * (l - s.rest_length) * (l - s.rest_length);
  }
  return energy;
}

double gravityEnergy(const Grid& grid, const Eigen::VectorXd& x)
{
  return -grid.gravityForce().dot(x);
}

SparseMatrix tangentStiffness(const Grid& grid, const Eigen::VectorXd& x, CompressedSprings compressed,
                              int* num_dropped)
{
  if (grid.dimension() == 2)
    return tangentStiffnessDim<2>(grid, x, compressed, num_dropped);
  return tangentStiffnessDim<3>(grid, x, compressed, num_dropped);
}

}  // namespace modal_mass_spring
