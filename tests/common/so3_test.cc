#include "common/so3.h"

#include <random>

#include "common/units.h"
#include "gtest/gtest.h"

namespace kinevis::common {
namespace {

Eigen::Vector3d RandomVector(std::mt19937& rng, double scale) {
  std::uniform_real_distribution<double> u(-scale, scale);
  return Eigen::Vector3d(u(rng), u(rng), u(rng));
}

TEST(So3Test, SkewIsTheCrossProductAndAntisymmetric) {
  std::mt19937 rng(3);
  for (int i = 0; i < 100; ++i) {
    const Eigen::Vector3d a = RandomVector(rng, 5), b = RandomVector(rng, 5);
    EXPECT_LT((Skew(a) * b - a.cross(b)).norm(), 1e-12);
    EXPECT_LT((Skew(a) + Skew(a).transpose()).norm(), 1e-15);
  }
}

TEST(So3Test, ExpIsRodriguesAndLogInvertsIt) {
  std::mt19937 rng(5);
  for (int i = 0; i < 200; ++i) {
    Eigen::Vector3d w = RandomVector(rng, 1.0);
    w *= (0.999 * kPi) * std::uniform_real_distribution<double>(0, 1)(rng) / w.norm();
    // Rodrigues written out: I + sin|w| K + (1 - cos|w|) K^2, K = [w/|w|]x.
    const double t = w.norm();
    const Eigen::Matrix3d K = Skew(w / t);
    const Eigen::Matrix3d R =
        Eigen::Matrix3d::Identity() + std::sin(t) * K + (1 - std::cos(t)) * K * K;
    EXPECT_LT((Exp(w) - R).norm(), 1e-12);
    EXPECT_LT((Log(Exp(w)) - w).norm(), 1e-9);
  }
}

TEST(So3Test, ExpOfSmallAndZeroVectors) {
  EXPECT_EQ(Exp(Eigen::Vector3d::Zero()), Eigen::Matrix3d::Identity());
  const Eigen::Vector3d w(1e-14, -2e-14, 3e-14);
  EXPECT_LT((Exp(w) - (Eigen::Matrix3d::Identity() + Skew(w))).norm(), 1e-27);
  EXPECT_LT(Log(Eigen::Matrix3d::Identity()).norm(), 1e-15);
}

TEST(So3Test, LogAtHalfTurnHasLengthPi) {
  const Eigen::Matrix3d R = Eigen::AngleAxisd(kPi, Eigen::Vector3d::UnitY()).toRotationMatrix();
  const Eigen::Vector3d w = Log(R);
  EXPECT_NEAR(w.norm(), kPi, 1e-12);
  EXPECT_LT((Exp(w) - R).norm(), 1e-12);
}

TEST(UnitsTest, DegreesAndRadians) {
  EXPECT_DOUBLE_EQ(180 * kDeg, kPi);
  EXPECT_DOUBLE_EQ(ToDegrees(kPi / 2), 90.0);
  EXPECT_DOUBLE_EQ(ToRadians(ToDegrees(0.3)), 0.3);
  EXPECT_DOUBLE_EQ(kDegPerRad * kDeg, 1.0);
  EXPECT_EQ(0.25 * kMmPerM, 250.0);
}

}  // namespace
}  // namespace kinevis::common
