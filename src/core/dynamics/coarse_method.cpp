// `coarse`: `full` on the same cloth's coarse grid, read out on the fine grid by interpolation.
#include "dynamics/method_model.h"

#include <algorithm>
#include <stdexcept>

namespace modal_mass_spring
{
namespace
{

// The coarse grid's own parts, in the form `full` takes them.
LinearizedGrid coarseLinearized(const LinearizedGrid& fine)
{
  if (!fine.coarse)
    throw std::logic_error("the coarse method needs its coarse grid");
  const CoarseGrid& c = *fine.coarse;
  return LinearizedGrid{c.grid,    fine.basis, c.x_ref, c.stiffness, c.mass, nullptr,
                        c.grid.numHandleDofs() > 0 ? &c.handle_coupling : nullptr};
}

// A vector over the handle dofs of one grid from another's: entry k is source[k]'s (empty stays empty).
Eigen::VectorXd gather(const Eigen::VectorXd& values, const std::vector<int>& source)
{
  if (values.size() == 0)
    return Eigen::VectorXd();
  Eigen::VectorXd out(static_cast<Eigen::Index>(source.size()));
  for (size_t k = 0; k < source.size(); ++k)
    out[static_cast<Eigen::Index>(k)] = values[source[k]];
  return out;
}

// `all` (every dof of `grid`) plus values on the free dofs and on the handle dofs (empty: none).
Eigen::VectorXd plusFreeAndHandles(const Grid& grid, Eigen::VectorXd all, const Eigen::VectorXd& free,
                                   const Eigen::VectorXd& handles)
{
  grid.addFree(free, all);
  const std::vector<int>& dofs = grid.handleDofs();
  if (handles.size() > 0)
    for (size_t k = 0; k < dofs.size(); ++k)
      all[dofs[k]] += handles[static_cast<Eigen::Index>(k)];
  return all;
}

}  // namespace

CoarseMethod::CoarseMethod(const LinearizedGrid& fine, const IntegratorSettings& settings)
  : FullMethod(Method::Coarse, coarseLinearized(fine), settings), fine_(fine), coarse_(*fine.coarse)
{
  fine_reference_ = fine_.grid.gatherFree(fine_.x_ref);
  handle_index_.assign(coarse_.grid.numDofs(), -1);
  const std::vector<int>& dofs = coarse_.grid.handleDofs();
  for (size_t k = 0; k < dofs.size(); ++k)
    handle_index_[dofs[k]] = static_cast<int>(k);
}

Eigen::VectorXd CoarseMethod::coarsePositions(const Eigen::VectorXd& q) const
{
  return plusFreeAndHandles(coarse_.grid, coarse_.x_ref, q, coarse_motion_.displacement);
}

Eigen::VectorXd CoarseMethod::coarseVelocities(const Eigen::VectorXd& v) const
{
  return plusFreeAndHandles(coarse_.grid, Eigen::VectorXd::Zero(coarse_.grid.numDofs()), v, coarse_motion_.velocity);
}

Eigen::VectorXd CoarseMethod::sampleVelocity(const Eigen::VectorXd& fine_free, const Eigen::VectorXd& fine_handles) const
{
  return coarse_.grid.gatherFree(
      coarse_.sampling * plusFreeAndHandles(fine_.grid, Eigen::VectorXd::Zero(fine_.grid.numDofs()), fine_free, fine_handles));
}

Eigen::VectorXd CoarseMethod::sampleDisplacement(const Eigen::VectorXd& u, const Eigen::VectorXd& handles) const
{
  // The coarse rest equals the sampled fine rest unless the grid is linearized elsewhere (its equilibrium).
  return coarse_.grid.gatherFree(coarse_.sampling * plusFreeAndHandles(fine_.grid, fine_.x_ref, u, handles) -
                                 coarse_.x_ref);
}

HandleMotion CoarseMethod::coarseMotion(const HandleMotion& fine) const
{
  return HandleMotion{gather(fine.displacement, coarse_.handle_source), gather(fine.velocity, coarse_.handle_source),
                      gather(fine.acceleration, coarse_.handle_source)};
}

double CoarseMethod::assign(const Eigen::VectorXd& u, const Eigen::VectorXd& v, Remainder remainder)
{
  const Eigen::VectorXd q = sampleDisplacement(u, fine_motion_.displacement);
  offset_.resize(0);
  FullMethod::assign(q, sampleVelocity(v, fine_motion_.velocity), remainder);
  offset_ = u - displacement(state());
  return 0.0;
}

Eigen::VectorXd CoarseMethod::displacement(const State& s) const
{
  Eigen::VectorXd u = coarse_.interpolation * coarsePositions(s.q) - fine_reference_;
  if (offset_.size() > 0)
    u += offset_;
  return u;
}

Eigen::VectorXd CoarseMethod::velocity(const State& s) const { return coarse_.interpolation * coarseVelocities(s.v); }

double CoarseMethod::interpolateAt(const Eigen::VectorXd& free, const Eigen::VectorXd& handles,
                                   const Eigen::VectorXd& rest, int k) const
{
  const int dim = fine_.grid.dimension();
  const int dof = fine_.grid.freeDofs()[k];
  const Stencil& stencil = coarse_.interpolation_stencils[dof / dim];
  double x = 0.0;
  for (int i = 0; i < 4; ++i)
  {
    const int c = stencil.particle[i] * dim + dof % dim;
    double value = rest.size() > 0 ? rest[c] : 0.0;
    if (const int f = coarse_.grid.freeIndex(c); f >= 0)
      value += free[f];
    else if (handles.size() > 0 && handle_index_[c] >= 0)
      value += handles[handle_index_[c]];
    x += stencil.weight[i] * value;
  }
  return x;
}

double CoarseMethod::displacementAt(const State& s, int k) const
{
  return interpolateAt(s.q, coarse_motion_.displacement, coarse_.x_ref, k) - fine_reference_[k] +
         (offset_.size() > 0 ? offset_[k] : 0.0);
}

double CoarseMethod::velocityAt(const State& s, int k) const
{
  return interpolateAt(s.v, coarse_motion_.velocity, Eigen::VectorXd(), k);
}

void CoarseMethod::statesAt(const State& s, const std::vector<int>& k, Eigen::VectorXd& u, Eigen::VectorXd& v) const
{
  // The coarse grid's every dof once, then each fine dof from its stencil's four.
  const Eigen::VectorXd x_c = coarsePositions(s.q), v_c = coarseVelocities(s.v);
  const int dim = fine_.grid.dimension();
  u.resize(static_cast<Eigen::Index>(k.size()));
  v.resize(u.size());
  for (size_t i = 0; i < k.size(); ++i)
  {
    const int dof = fine_.grid.freeDofs()[k[i]];
    const Stencil& stencil = coarse_.interpolation_stencils[dof / dim];
    double x = 0.0, speed = 0.0;
    for (int j = 0; j < 4; ++j)
    {
      const int c = stencil.particle[j] * dim + dof % dim;
      x += stencil.weight[j] * x_c[c];
      speed += stencil.weight[j] * v_c[c];
    }
    u[static_cast<Eigen::Index>(i)] = x - fine_reference_[k[i]] + (offset_.size() > 0 ? offset_[k[i]] : 0.0);
    v[static_cast<Eigen::Index>(i)] = speed;
  }
}

void CoarseMethod::setAnchor(const Eigen::VectorXd& u_anchor, const Eigen::VectorXd& handles_anchor)
{
  FullMethod::setAnchor(sampleDisplacement(u_anchor, handles_anchor), gather(handles_anchor, coarse_.handle_source));
}

void CoarseMethod::setHandleMotion(const HandleMotion& motion)
{
  fine_motion_ = motion;
  coarse_motion_ = coarseMotion(motion);
  FullMethod::setHandleMotion(coarse_motion_);
}

void CoarseMethod::restore(const State& state, const Eigen::VectorXd& offset)
{
  MethodModel::restore(state, offset);
  offset_ = offset;
}

Eigen::VectorXd CoarseMethod::generalizedForce(const Eigen::VectorXd& f_free) const
{
  return coarse_.grid.gatherFree(coarse_.interpolation.transpose() * f_free);
}

void CoarseMethod::correctContacts(Contact& contact)
{
  if (!contact_)
    contact_ = std::make_unique<Contact>(coarse_.grid, contact.colliders(), contact.thickness());
  contact_->follow(contact);
  FullMethod::correctContacts(*contact_);
  ContactReport report = contact_->report();
  report.touched_by.clear();
  contact.setReport(std::move(report));
}

std::vector<int> CoarseMethod::touchedBy(const Contact&) const
{
  const int dim = fine_.grid.dimension();
  const std::vector<int>& free_dofs = fine_.grid.freeDofs();
  std::vector<int> touched(free_dofs.size() / dim, -1);
  if (!contact_)
    return touched;
  const std::vector<int>& coarse = contact_->report().touched_by;
  for (size_t j = 0; j < touched.size(); ++j)
  {
    const Stencil& stencil = coarse_.interpolation_stencils[free_dofs[j * dim] / dim];
    const int heaviest = static_cast<int>(std::max_element(stencil.weight.begin(), stencil.weight.end()) - stencil.weight.begin());
    const int free = coarse_.grid.freeIndex(stencil.particle[heaviest] * dim);
    if (free >= 0 && static_cast<size_t>(free / dim) < coarse.size())
      touched[j] = coarse[free / dim];
  }
  return touched;
}

}  // namespace modal_mass_spring
