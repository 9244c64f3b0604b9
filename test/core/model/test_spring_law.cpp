// The spring law against finite differences of its own energy, in 2D and 3D, stretched and compressed.
#include "modal_mass_spring/spring_law.h"

#include <gtest/gtest.h>

#include <vector>

namespace modal_mass_spring
{
namespace
{

constexpr double kStiffness = 37.0;
constexpr double kRestLength = 0.3;

template <class Vector>
class SpringLaw : public ::testing::Test
{
};
using Dimensions = ::testing::Types<Eigen::Vector2d, Eigen::Vector3d>;
TYPED_TEST_SUITE(SpringLaw, Dimensions);

// Spring vectors from end i to end j: stretched, compressed and oblique.
template <class Vector>
std::vector<Vector> springVectors()
{
  std::vector<Vector> d;
  for (double scale : {1.4, 0.6, 1.0 + 1e-3})
  {
    Vector v = Vector::LinSpaced(Vector::RowsAtCompileTime, 0.2, 0.9);
    d.push_back(scale * kRestLength * v.normalized());
  }
  return d;
}

TYPED_TEST(SpringLaw, ForceIsMinusTheEnergyGradientAtEndI)
{
  const double h = 1e-6;
  for (const TypeParam& d : springVectors<TypeParam>())
  {
    double energy = 0.0;
    const TypeParam f = springForce(kStiffness, kRestLength, d, &energy);
    EXPECT_DOUBLE_EQ(energy, springEnergy(kStiffness, kRestLength, d.norm()));
    for (int a = 0; a < d.size(); ++a)
    {
      // Moving end i by +h along a shortens d by h along a.
      TypeParam dp = d, dm = d;
      dp[a] -= h;
      dm[a] += h;
      const double gradient = (springEnergy(kStiffness, kRestLength, dp.norm()) -
                               springEnergy(kStiffness, kRestLength, dm.norm())) / (2.0 * h);
      EXPECT_NEAR(f[a], -gradient, 1e-7 * kStiffness);
    }
  }
}

TYPED_TEST(SpringLaw, HessianIsTheForceJacobianAndDropLeavesOnlyTheAxialTerm)
{
  const double h = 1e-6;
  for (const TypeParam& d : springVectors<TypeParam>())
  {
    const auto ke = springHessian(kStiffness, kRestLength, d);
    EXPECT_TRUE(ke.isApprox(ke.transpose(), 1e-14));
    // Ke = -d^2E/(dx_i dx_j) = d f_i / d x_j, and d changes with x_j one to one.
    for (int b = 0; b < d.size(); ++b)
    {
      TypeParam dp = d, dm = d;
      dp[b] += h;
      dm[b] -= h;
      const TypeParam column = (springForce(kStiffness, kRestLength, dp) - springForce(kStiffness, kRestLength, dm)) / (2.0 * h);
      EXPECT_TRUE(ke.col(b).isApprox(column, 1e-6)) << ke.col(b).transpose() << " vs " << column.transpose();
    }
    const TypeParam u = d.normalized();
    const auto axial = (kStiffness * u * u.transpose()).eval();
    const auto dropped = springHessian(kStiffness, kRestLength, d, CompressedSprings::Drop);
    const bool compressed = d.norm() < kRestLength;
    EXPECT_EQ(geometricStiffnessDropped(kRestLength, d.norm(), CompressedSprings::Drop), compressed);
    if (compressed)
    {
      EXPECT_TRUE(dropped.isApprox(axial, 1e-14));
      EXPECT_FALSE(ke.isApprox(axial, 1e-3));  // Keep has the (negative) geometric term
      EXPECT_EQ(geometricStiffness(kStiffness, kRestLength, d.norm(), CompressedSprings::Drop), 0.0);
      EXPECT_LT(geometricStiffness(kStiffness, kRestLength, d.norm()), 0.0);
    }
    else
    {
      EXPECT_TRUE(dropped.isApprox(ke, 1e-14));
    }
  }
}

TYPED_TEST(SpringLaw, HessianDerivativeIsTheHessiansDirectionalDerivative)
{
  const double h = 1e-6;
  for (const TypeParam& d : springVectors<TypeParam>())
  {
    const TypeParam delta = TypeParam::LinSpaced(d.size(), -0.5, 0.7);
    const auto derivative = springHessianDerivative(kStiffness, kRestLength, d, delta);
    const auto difference = ((springHessian(kStiffness, kRestLength, TypeParam(d + h * delta)) -
                              springHessian(kStiffness, kRestLength, TypeParam(d - h * delta))) / (2.0 * h)).eval();
    EXPECT_TRUE(derivative.isApprox(difference, 1e-6)) << derivative << "\nvs\n" << difference;
  }
}

TEST(SpringLawDynamic, DynamicSizeVectorsGiveTheFixedSizeResults)
{
  const Eigen::Vector3d d(0.1, -0.25, 0.3);
  const Eigen::VectorXd dynamic = d;
  EXPECT_EQ((springForce(kStiffness, kRestLength, dynamic) - springForce(kStiffness, kRestLength, d)).norm(), 0.0);
  EXPECT_EQ((springHessian(kStiffness, kRestLength, dynamic, CompressedSprings::Drop) -
             springHessian(kStiffness, kRestLength, d, CompressedSprings::Drop)).norm(), 0.0);
}

}  // namespace
}  // namespace modal_mass_spring
