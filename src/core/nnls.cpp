// Lawson-Hanson non-negative least squares on the normal equations.
#include "modal_mass_spring/nnls.h"

#include <Eigen/Cholesky>
#include <Eigen/QR>

#include <algorithm>
#include <vector>

namespace modal_mass_spring
{
namespace
{

// The unconstrained least-squares solution on the passive variables (zero elsewhere): G_PP z_P = c_P.
Eigen::VectorXd solvePassive(const Eigen::MatrixXd& gram, const Eigen::VectorXd& atb, const std::vector<bool>& passive)
{
  std::vector<Eigen::Index> index;
  for (size_t k = 0; k < passive.size(); ++k)
    if (passive[k])
      index.push_back(static_cast<Eigen::Index>(k));
  Eigen::VectorXd z = Eigen::VectorXd::Zero(atb.size());
  if (index.empty())
    return z;
  const Eigen::MatrixXd g = gram(index, index);
  const Eigen::VectorXd c = atb(index);
  Eigen::VectorXd zp;
  Eigen::LLT<Eigen::MatrixXd> llt(g);
  if (llt.info() == Eigen::Success)
    zp = llt.solve(c);
  else  // singular to round-off: the minimum-norm solution
    zp = g.completeOrthogonalDecomposition().solve(c);
  for (size_t k = 0; k < index.size(); ++k)
    z[index[k]] = zp[static_cast<Eigen::Index>(k)];
  return z;
}

}  // namespace

NnlsResult solveNnlsNormal(const Eigen::MatrixXd& gram, const Eigen::VectorXd& atb, Eigen::VectorXd& w,
                           double tolerance, int max_iterations)
{
  const Eigen::Index n = atb.size();
  if (w.size() != n)
    w.setZero(n);
  w = w.cwiseMax(0.0);
  if (max_iterations < 0)
    max_iterations = static_cast<int>(3 * n + 10);
  const double threshold = tolerance * std::max(atb.cwiseAbs().maxCoeff(), 1e-300);
  std::vector<bool> passive(n), rejected(n, false);
  bool any_passive = false;
  for (Eigen::Index k = 0; k < n; ++k)
    any_passive |= (passive[k] = w[k] > 0.0);

  NnlsResult result;
  Eigen::Index entered = -1;
  bool check_warm_start = any_passive;  // a warm start's passive set is solved first
  while (true)
  {
    if (!check_warm_start)
    {
      const Eigen::VectorXd gradient = atb - gram * w;  // -d/dw of 1/2 |A w - b|^2
      entered = -1;
      for (Eigen::Index k = 0; k < n; ++k)
        if (!passive[k] && !rejected[k] && gradient[k] > threshold && (entered < 0 || gradient[k] > gradient[entered]))
          entered = k;
      if (entered < 0)
      {
        result.converged = true;
        break;
      }
      if (result.iterations >= max_iterations)
        break;
      passive[entered] = true;
      ++result.iterations;
    }
    check_warm_start = false;
    // Move towards the passive set's least-squares solution until every passive weight is positive.
    while (true)
    {
      const Eigen::VectorXd z = solvePassive(gram, atb, passive);
      double step = 1.0;
      for (Eigen::Index k = 0; k < n; ++k)
        if (passive[k] && z[k] <= 0.0)
          step = std::min(step, w[k] > 0.0 ? w[k] / (w[k] - z[k]) : 0.0);
      if (step >= 1.0)
      {
        w = z;
        break;
      }
      w += step * (z - w);
      for (Eigen::Index k = 0; k < n; ++k)
        if (passive[k] && w[k] <= 0.0)
        {
          passive[k] = false;
          w[k] = 0.0;
        }
    }
    // A variable whose gradient is positive but whose least-squares weight is not (round-off in a
    // nearly dependent column) would enter and leave forever: skip it until another one enters.
    if (entered >= 0 && !passive[entered])
      rejected[entered] = true;
    else
      std::fill(rejected.begin(), rejected.end(), false);
  }
  return result;
}

Eigen::VectorXd nnls(const Eigen::MatrixXd& a, const Eigen::VectorXd& b, NnlsResult* result)
{
  Eigen::VectorXd w;
  const NnlsResult r = solveNnlsNormal(a.transpose() * a, a.transpose() * b, w);
  if (result)
    *result = r;
  return w;
}

}  // namespace modal_mass_spring
