// The spring law (paper eq. 13), the one place a spring is evaluated: every force, energy and
// tangent of the package (full, the modal force models, the cubature, the handles' coupling and
// forces) calls these.
//
// A spring of stiffness k and rest length L whose vector from its end i to its end j is d, with
// l = |d| and u = d / l:
//   energy             E   = k (l - L)^2 / 2
//   force on end i     f_i = k (l - L) d / l        (on end j: -f_i)
//   Hessian block      Ke  = k u u^T + g (I - u u^T),  g = k (1 - L / l)
// Ke is d^2E/dx_i^2 = d^2E/dx_j^2 = -d^2E/(dx_i dx_j). Its second term, the geometric stiffness, is
// negative for a compressed spring (l < L); CompressedSprings::Drop leaves it out there, so that K
// stays positive semi-definite. l = 0 is outside the law (u undefined): callers keep springs apart.
#pragma once

#include <Eigen/Core>

namespace modal_mass_spring
{

// Whether a compressed spring's geometric stiffness enters its Hessian.
enum class CompressedSprings
{
  Keep,  // the exact Hessian
  Drop,  // keep only k u u^T: K stays positive semi-definite (used at a hanging equilibrium)
};

// E = k (l - L)^2 / 2.
inline double springEnergy(double k, double rest_length, double length)
{
  const double stretch = length - rest_length;
  return 0.5 * k * stretch * stretch;
}

// f_i = k (l - L) d / l, the force on end i (towards j when stretched); with `energy`, E as well.
template <class Vector>
typename Vector::PlainObject springForce(double k, double rest_length, const Eigen::MatrixBase<Vector>& d,
                                         double* energy = nullptr)
{
  const double l = d.norm();
  const double stretch = l - rest_length;
  if (energy)
    *energy = 0.5 * k * stretch * stretch;
  return k * stretch / l * d;
}

// g = k (1 - L / l), the geometric stiffness across the spring; 0 for a compressed spring under Drop.
inline double geometricStiffness(double k, double rest_length, double length,
                                 CompressedSprings compressed = CompressedSprings::Keep)
{
  if (length < rest_length && compressed == CompressedSprings::Drop)
    return 0.0;
  return k * (1.0 - rest_length / length);
}

// True where Drop leaves a spring's geometric stiffness out.
inline bool geometricStiffnessDropped(double rest_length, double length, CompressedSprings compressed)
{
  return length < rest_length && compressed == CompressedSprings::Drop;
}

// Ke = k u u^T + g (I - u u^T), as a fixed- or dynamic-size matrix like d.
template <class Vector>
Eigen::Matrix<double, Vector::RowsAtCompileTime, Vector::RowsAtCompileTime>
springHessian(double k, double rest_length, const Eigen::MatrixBase<Vector>& d,
              CompressedSprings compressed = CompressedSprings::Keep)
{
  using Matrix = Eigen::Matrix<double, Vector::RowsAtCompileTime, Vector::RowsAtCompileTime>;
  const double l = d.norm();
  const typename Vector::PlainObject u = d / l;
  const Matrix uu = u * u.transpose();
  Matrix ke = k * uu;
  if (!geometricStiffnessDropped(rest_length, l, compressed))
    ke += geometricStiffness(k, rest_length, l) * (Matrix::Identity(d.size(), d.size()) - uu);
  return ke;
}

// dKe/dx_j along delta (the exact Ke's, with delta the change of d): the spring energy's third
// derivative contracted with delta,
//   k L / l^2 ((u.delta) I + delta u^T + u delta^T - 3 (u.delta) u u^T).
template <class Vector>
Eigen::Matrix<double, Vector::RowsAtCompileTime, Vector::RowsAtCompileTime>
springHessianDerivative(double k, double rest_length, const Eigen::MatrixBase<Vector>& d,
                        const Eigen::MatrixBase<Vector>& delta)
{
  using Matrix = Eigen::Matrix<double, Vector::RowsAtCompileTime, Vector::RowsAtCompileTime>;
  const double l = d.norm();
  const typename Vector::PlainObject u = d / l;
  const double ud = u.dot(delta);
  return k * rest_length / (l * l) *
         (ud * Matrix::Identity(d.size(), d.size()) + delta * u.transpose() + u * delta.transpose() -
          3.0 * ud * u * u.transpose());
}

}  // namespace modal_mass_spring
