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
  if (!contact)  // else correctContacts left them at this step's end and start
  {
    contact_x_.noalias() = reference + next.q;
    contact_start_.noalias() = reference + state().q;
  }
  self.correct(contact_start_, contact_x_, next.v, settings_.time_step, contact);
  next.q.noalias() = contact_x_ - reference;
}

void ModalMethod::correctContacts(Contact& contact)
{
  State& next = mutableNext();
  const Eigen::VectorXd& reference = freeReference();
  contact.correctModal(reference + displacement(state()), reference + displacement(next), velocity(next),
                       lin_.mass, lin_.basis.phi, next.q, next.v, settings_.time_step);
}

}  // namespace modal_mass_spring
