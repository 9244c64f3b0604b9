// Builds and validates the particle grid and its springs.
#include "modal_mass_spring/grid.h"

#include "modal_mass_spring/parameter_error.h"

#include <cmath>
#include <stdexcept>

namespace modal_mass_spring
{
namespace
{

void requirePositive(const std::string& name, double value)
{
  if (!std::isfinite(value) || value <= 0.0)
    rejectParameter(name, value, "must be a finite number > 0");
}

long long countHandleParticles(const GridParams& p)
{
  long long count = 0;
  for (const std::vector<int>& handle : p.handles)
    count += static_cast<long long>(handle.size());
  return count;
}

// Every handle names at least one particle, each in the grid, in one handle only and not fixed.
void validateHandles(const GridParams& p, int num_particles)
{
  std::vector<int> owner(num_particles, -1);
  for (int particle : effectiveFixed(p))
    owner[particle] = -2;
  for (size_t h = 0; h < p.handles.size(); ++h)
  {
    const std::string name = "handles[" + std::to_string(h) + "]";
    if (p.handles[h].empty())
      rejectParameter(name, "[]", "a handle must hold at least one particle");
    for (int particle : p.handles[h])
    {
      if (particle < 0 || particle >= num_particles)
        rejectParameter(name, particle,
                        "particle indices must be in [0, " + std::to_string(num_particles - 1) + "] (row * cols + col)");
      if (owner[particle] == -2)
        rejectParameter(name, particle, "a handle particle may not also be fixed");
      if (owner[particle] == static_cast<int>(h))
        rejectParameter(name, particle, "each particle index must be listed once");
      if (owner[particle] >= 0)
        rejectParameter(name, particle,
                        "a particle may be in one handle only (it is also in handles[" + std::to_string(owner[particle]) + "])");
      owner[particle] = static_cast<int>(h);
    }
  }
}

}  // namespace

void validateGridParams(const GridParams& p)
{
  if (p.rows < 1)
    rejectParameter("rows", p.rows, "must be an integer >= 1");
  if (p.cols < 1)
    rejectParameter("cols", p.cols, "must be an integer >= 1");
  // Counted in 64 bits: rows * cols overflows an int long before the machine runs out of memory.
  const long long n = static_cast<long long>(p.rows) * p.cols;
  const std::string size = std::to_string(p.rows) + " x " + std::to_string(p.cols);
  if (n < 2)
    rejectParameter("rows x cols", size, "the grid must have at least 2 particles");
  if (n > kMaxParticles)
    rejectParameter("rows x cols", size + " = " + std::to_string(n) + " particles",
                    "must be at most " + std::to_string(kMaxParticles) +
                        " particles (the sparse matrices index their entries with 32-bit integers)");
  if (p.dimension != 2 && p.dimension != 3)
    rejectParameter("dimension", p.dimension, "must be 2 (planar, x-z) or 3");
  requirePositive("spacing", p.spacing);
  requirePositive("mass", p.mass);
  requirePositive("structural_stiffness", p.structural_stiffness);
  requirePositive("shear_stiffness", p.shear_stiffness);
  if (p.bending)
    requirePositive("bending_stiffness", p.bending_stiffness);
  if (!p.gravity.allFinite())
    rejectParameter("gravity", p.gravity.transpose(), "must be 3 finite numbers");
  if (p.dimension == 2 && p.gravity.y() != 0.0)
    rejectParameter("gravity", p.gravity.transpose(), "the y component must be 0 for a 2D grid (it lies in the x-z plane)");
  if (!std::isfinite(p.rotation_deg))
    rejectParameter("rotation_deg", p.rotation_deg, "must be a finite angle in degrees");
  if (p.dimension == 2 && p.rotation_deg != 0.0)
    rejectParameter("rotation_deg", p.rotation_deg, "must be 0 for a 2D grid (a rotation about x leaves the x-z plane)");

  checkParticleIndices("fixed", p.fixed, static_cast<int>(n));
  validateHandles(p, static_cast<int>(n));
  const long long num_fixed = static_cast<long long>(effectiveFixed(p).size());
  const long long num_held = num_fixed + countHandleParticles(p);
  if (num_held >= n)
    rejectParameter(p.handles.empty() ? "fixed" : "fixed, handles",
                    std::to_string(num_held) + " of " + std::to_string(n) + " particles",
                    "at least one particle must be free");
}

std::vector<int> effectiveFixed(const GridParams& p)
{
  std::vector<int> fixed = p.fixed;
  if (fixed.empty() && p.handles.empty())
    for (int c = 0; c < p.cols; ++c)
      fixed.push_back(c);
  return fixed;
}

long long countFreeDofs(const GridParams& p)
{
  const long long num_held = static_cast<long long>(effectiveFixed(p).size()) + countHandleParticles(p);
  return p.dimension * (static_cast<long long>(p.rows) * p.cols - num_held);
}

long long countSprings(const GridParams& p)
{
  const long long rows = p.rows, cols = p.cols;
  long long count = rows * (cols - 1) + (rows - 1) * cols + 2 * (rows - 1) * (cols - 1);
  if (p.bending)
    count += rows * std::max(cols - 2, 0LL) + std::max(rows - 2, 0LL) * cols;
  return count;
}

Grid::Grid(const GridParams& params) : params_(params)
{
  validateGridParams(params_);
  const int n = numParticles();
  const int dim = dimension();
  const double s = params_.spacing;

  // Rows hang along -z, columns run along x; a 3D sheet is then turned about x.
  const double angle = params_.rotation_deg * M_PI / 180.0;
  x0_.resize(numDofs());
  for (int r = 0; r < params_.rows; ++r)
    for (int c = 0; c < params_.cols; ++c)
    {
      const int p = particleIndex(r, c);
      const double x = c * s;
      const double z = -r * s;
      if (dim == 2)
        x0_.segment<2>(2 * p) << x, z;
      else
        x0_.segment<3>(3 * p) << x, -z * std::sin(angle), z * std::cos(angle);
    }

  for (int r = 0; r < params_.rows; ++r)
    for (int c = 0; c < params_.cols; ++c)
    {
      if (c + 1 < params_.cols)
        addSpring(particleIndex(r, c), particleIndex(r, c + 1), params_.structural_stiffness), ++num_structural_;
      if (r + 1 < params_.rows)
        addSpring(particleIndex(r, c), particleIndex(r + 1, c), params_.structural_stiffness), ++num_structural_;
    }
  for (int r = 0; r + 1 < params_.rows; ++r)
    for (int c = 0; c + 1 < params_.cols; ++c)
    {
      addSpring(particleIndex(r, c), particleIndex(r + 1, c + 1), params_.shear_stiffness);
      addSpring(particleIndex(r, c + 1), particleIndex(r + 1, c), params_.shear_stiffness);
      num_shear_ += 2;
    }
  if (params_.bending)
    for (int r = 0; r < params_.rows; ++r)
      for (int c = 0; c < params_.cols; ++c)
      {
        if (c + 2 < params_.cols)
          addSpring(particleIndex(r, c), particleIndex(r, c + 2), params_.bending_stiffness), ++num_bending_;
        if (r + 2 < params_.rows)
          addSpring(particleIndex(r, c), particleIndex(r + 2, c), params_.bending_stiffness), ++num_bending_;
      }

  fixed_ = effectiveFixed(params_);
  fixed_mask_.assign(n, false);
  for (int p : fixed_)
    fixed_mask_[p] = true;
  handle_of_.assign(n, -1);
  for (size_t h = 0; h < params_.handles.size(); ++h)
    for (int p : params_.handles[h])
    {
      handle_of_[p] = static_cast<int>(h);
      for (int d = 0; d < dim; ++d)
        handle_dofs_.push_back(dim * p + d);
    }

  free_index_.assign(numDofs(), -1);
  for (int p = 0; p < n; ++p)
    if (!fixed_mask_[p] && handle_of_[p] < 0)
      for (int d = 0; d < dim; ++d)
      {
        free_index_[dim * p + d] = static_cast<int>(free_dofs_.size());
        free_dofs_.push_back(dim * p + d);
      }

  // In 2D the dofs are (x, z): take gravity's x and z components.
  gravity_force_.resize(numDofs());
  for (int p = 0; p < n; ++p)
  {
    if (dim == 2)
      gravity_force_.segment<2>(2 * p) << params_.gravity.x(), params_.gravity.z();
    else
      gravity_force_.segment<3>(3 * p) = params_.gravity;
  }
  gravity_force_ *= params_.mass;
}

void Grid::addSpring(int i, int j, double stiffness)
{
  const int dim = dimension();
  const double rest_length = (x0_.segment(dim * j, dim) - x0_.segment(dim * i, dim)).norm();
  springs_.push_back({i, j, stiffness, rest_length});
}

void Grid::addFree(const Eigen::VectorXd& free, Eigen::VectorXd& all) const
{
  for (size_t k = 0; k < free_dofs_.size(); ++k)
    all[free_dofs_[k]] += free[k];
}

Eigen::VectorXd Grid::gatherFree(const Eigen::VectorXd& all) const
{
  Eigen::VectorXd free(free_dofs_.size());
  for (size_t k = 0; k < free_dofs_.size(); ++k)
    free[k] = all[free_dofs_[k]];
  return free;
}

Eigen::Matrix3Xd Grid::toPoints(const Eigen::VectorXd& x) const
{
  const int n = numParticles();
  Eigen::Matrix3Xd points(3, n);
  for (int p = 0; p < n; ++p)
  {
    if (dimension() == 2)
      points.col(p) << x[2 * p], 0.0, x[2 * p + 1];
    else
      points.col(p) = x.segment<3>(3 * p);
  }
  return points;
}

void checkParticleIndices(const std::string& name, const std::vector<int>& indices, int num_particles)
{
  std::vector<bool> seen(num_particles > 0 ? num_particles : 0, false);
  for (int index : indices)
  {
    if (index < 0 || index >= num_particles)
      rejectParameter(name, index,
                      "particle indices must be in [0, " + std::to_string(num_particles - 1) + "] (row * cols + col)");
    if (seen[index])
      rejectParameter(name, index, "each particle index must be listed once");
    seen[index] = true;
  }
}

}  // namespace modal_mass_spring
