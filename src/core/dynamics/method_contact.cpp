// How each method hands its step's end state to the contact correction (contact.h): `full` its
// particles' dofs, the modal methods their coordinates through the basis; and to the self-collision
// (self_collision.h), `full` alone.
#include "dynamics/method_model.h"

#include <stdexcept>

namespace modal_mass_spring
{

const Eigen::VectorXd& MethodModel::freeReference()
{
  if (free_reference_.size() == 0)
    free_reference_ = lin_.grid.gatherFree(lin_.x_ref);
  return free_reference_;
}

void FullMethod::correctContacts(Contact& contact)
{
  State& next = mutableNext();
  const Eigen::VectorXd& reference = freeReference();
  contact_x_.noalias() = reference + next.q;
  contact_start_.noalias() = reference + state().q;
  contact.correctParticles(contact_start_, contact_x_, next.v, lin_.mass, settings_.time_step);
  next.q.noalias() = contact_x_ - reference;
}

void MethodModel::correctSelfCollision(SelfCollision& /*self*/, const Contact* /*contact*/)
{
  throw std::logic_error("self-collision is corrected for method 'full' only; method '" + toString(method()) +
                         "' was asked to");
}

void FullMethod::correctSelfCollision(SelfCollision& self, const Contact* contact)
{
  State& next = mutableNext();
  const Eigen::VectorXd& reference = freeReference();
  contact_x_.noalias() = reference + next.q;
  contact_start_.noalias() = reference + state().q;
  self.correct(contact_start_, contact_x_, next.v, settings_.time_step, contact);
  next.q.noalias() = contact_x_ - reference;
}

void ModalMethod::correctContacts(Contact& contact)
{
  State& next = mutableNext();
  if (!sample_.dofs.empty())
  {
    sampleState(state().q, sample_.x_start, nullptr, nullptr);
    sampleState(next.q, sample_.x, &next.v, &sample_.v);
    contact.correctModal(sample_.x_start, sample_.x, sample_.v, sample_.mass, sample_.phi, next.q, next.v,
                         settings_.time_step);
    return;
  }
  const Eigen::VectorXd& reference = freeReference();
  contact.correctModal(reference + displacement(state()), reference + displacement(next), velocity(next),
                       lin_.mass, lin_.basis.phi, next.q, next.v, settings_.time_step);
}

void ModalMethod::setContactSample(const std::vector<int>& particles)
{
  const int dim = lin_.grid.dimension();
  sample_ = ContactSample{};
  for (int p : particles)
    for (int a = 0; a < dim; ++a)
      sample_.dofs.push_back(dim * p + a);
  const auto rows = static_cast<Eigen::Index>(sample_.dofs.size());
  sample_.phi = lin_.basis.phi(sample_.dofs, Eigen::all);
  sample_.mass = lin_.mass(sample_.dofs);
  sample_.x_start.resize(rows);
  sample_.x.resize(rows);
  sample_.v.resize(rows);
}

void ModalMethod::sampleState(const Eigen::VectorXd& q, Eigen::VectorXd& x, const Eigen::VectorXd* qv,
                              Eigen::VectorXd* v)
{
  const Eigen::VectorXd& reference = freeReference();
  x.noalias() = sample_.phi * q;
  if (v)
    v->noalias() = sample_.phi * *qv;
  // The handles' part, Psi dx_b and Psi v_b on the sample's rows: through Psi H where the handles
  // move as one affine body (a few columns), Psi's own rows otherwise.
  Eigen::VectorXd dx, dv, rest;
  const Eigen::MatrixXd* psi = lin_.constraint_modes ? lin_.constraint_modes : nullptr;
  if (psi)
  {
    dx = handle_motion_.displacement;
    dv = handle_motion_.velocity;
    Eigen::VectorXd affine_dx, affine_dv;
    if (psi_affine_.size() > 0 && !handle_fit_.split(dx, affine_dx, rest) && !handle_fit_.split(dv, affine_dv, rest))
    {
      psi = &psi_affine_;
      dx = affine_dx;
      dv = affine_dv;
    }
  }
  for (Eigen::Index i = 0; i < x.size(); ++i)
  {
    const int k = sample_.dofs[i];
    x[i] += reference[k] + offset_[k];
    if (psi)
    {
      x[i] += psi->row(k).dot(dx);
      if (v)
        (*v)[i] += psi->row(k).dot(dv);
    }
  }
}

}  // namespace modal_mass_spring
