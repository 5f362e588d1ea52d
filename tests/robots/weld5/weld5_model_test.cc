#include "robots/weld5/weld5_model.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdlib>
#include <new>
#include <random>
#include <string>

#include "common/units.h"
#include "tests/utilities/allocation_counter.h"

namespace kinevis::robots {
namespace {

// Torch: tip 25 mm off axis and 250 mm out along z_5 (assumed configuration values).
constexpr double kPx5 = 0.025;
constexpr double kPz5 = 0.250;

Vector5d RandomInLimits(const Weld5Model& m, std::mt19937* rng, double margin) {
  Vector5d q;
  for (int i = 0; i < kWeld5Joints; ++i) {
    const double span = m.q_max(i) - m.q_min(i);
    std::uniform_real_distribution<double> d(m.q_min(i) + margin * span,
                                             m.q_max(i) - margin * span);
    q(i) = d(*rng);
  }
  return q;
}

TEST(DhChain, LinkTransformIsRzTzTxRx) {
  const DhJoint j{0.3, 0.7, 0.2, 0.1, false};
  const double q = 0.4;
  const Eigen::Isometry3d expected =
      Eigen::AngleAxisd(0.5, Eigen::Vector3d::UnitZ()) * Eigen::Translation3d(0.0, 0.0, 0.2) *
      Eigen::Translation3d(0.3, 0.0, 0.0) * Eigen::AngleAxisd(0.7, Eigen::Vector3d::UnitX());
  EXPECT_TRUE(DhLinkTransform(j, q).matrix().isApprox(expected.matrix(), 1e-14));
  const DhJoint p{0.3, 0.7, 0.2, 0.1, true};
  const Eigen::Isometry3d expected_p =
      Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitZ()) * Eigen::Translation3d(0.0, 0.0, 0.6) *
      Eigen::Translation3d(0.3, 0.0, 0.0) * Eigen::AngleAxisd(0.7, Eigen::Vector3d::UnitX());
  EXPECT_TRUE(DhLinkTransform(p, q).matrix().isApprox(expected_p.matrix(), 1e-14));
}

// Finite differences of FK: linear part from the tip position, angular part from R(q+h) R(q-h)ᵀ.
TEST(DhChain, GeometricJacobianMatchesFiniteDifferences) {
  const Weld5Model m = Weld5Model::Seed(Weld5TorchTransform(kPx5, kPz5, 0.3));
  std::mt19937 rng(4);
  for (int trial = 0; trial < 50; ++trial) {
    const Vector5d q = RandomInLimits(m, &rng, 0.0);
    const Matrix65d J = DhGeometricJacobian(m.joints, q, m.X_5T);
    const double h = 1e-6;
    for (int i = 0; i < kWeld5Joints; ++i) {
      Vector5d qp = q, qm = q;
      qp(i) += h;
      qm(i) -= h;
      const Eigen::Isometry3d Xp = DhForwardKinematics(m.joints, qp) * m.X_5T;
      const Eigen::Isometry3d Xm = DhForwardKinematics(m.joints, qm) * m.X_5T;
      const Eigen::Vector3d v = (Xp.translation() - Xm.translation()) / (2 * h);
      const Eigen::AngleAxisd aa(Eigen::Matrix3d(Xp.linear() * Xm.linear().transpose()));
      const Eigen::Vector3d w = aa.angle() * aa.axis() / (2 * h);
      EXPECT_LT((J.block<3, 1>(0, i) - v).norm(), 1e-7) << "joint " << i;
      EXPECT_LT((J.block<3, 1>(3, i) - w).norm(), 1e-7) << "joint " << i;
    }
    Weld5Data data;
    Weld5ForwardKinematics(m, q, &data);
    EXPECT_TRUE(data.J.isApprox(J, 1e-12));
  }
}

TEST(DhChain, PerLinkFramesComposeToEndFrame) {
  const Weld5Model m = Weld5Model::Seed(Eigen::Isometry3d::Identity());
  Vector5d q;
  q << 0.3, -0.4, 0.35, 0.9, -1.2;
  std::array<Eigen::Isometry3d, kWeld5Joints> X_0L;
  const Eigen::Isometry3d X_05 = DhForwardKinematics(m.joints, q, &X_0L);
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  for (int i = 0; i < kWeld5Joints; ++i) {
    X = X * DhLinkTransform(m.joints[i], q(i));
    EXPECT_TRUE(X_0L[i].matrix().isApprox(X.matrix(), 1e-14));
  }
  EXPECT_TRUE(X_05.matrix().isApprox(X_0L[4].matrix(), 1e-14));
}

struct SeedFk {
  Eigen::Matrix3d R;  // columns n, o, a
  Eigen::Vector3d p;
};

// Seed 004 eq. (35)–(46) by hand, in the ideal geometry they assume (α1 = −90°, α2 = 90°,
// px1 = 0, no offsets). Rotation as printed. Position: the pz1, pz2, pz3, pz5, px5 terms as
// printed (eq. 38 with its px5 bracket closed after the −sinθ1 sinθ5 term, as eq. 42 and 46
// have it); the px2 terms are replaced by px2·x_2 = px2·(c1 c2, s1 c2, −s2) — see README.md.
SeedFk SeedEquations(const Vector5d& q, double pz1, double pz2, double px2, double pz5,
                     double px5) {
  const double t1 = q(0), t2 = q(1), pz3 = q(2), t4 = q(3), t5 = q(4);
  const double c1 = std::cos(t1), s1 = std::sin(t1), c2 = std::cos(t2), s2 = std::sin(t2);
  const double c24 = std::cos(t2 + t4), s24 = std::sin(t2 + t4);
  const double c5 = std::cos(t5), s5 = std::sin(t5);
  SeedFk f;
  const double nx = -s1 * s5 + c5 * c1 * c24;  // (35)
  const double ox = -s1 * c5 - s5 * c1 * c24;  // (36)
  const double ax = c1 * s24;                  // (37)
  const double ny = c1 * s5 + c5 * s1 * c24;   // (39)
  const double oy = c1 * c5 - s5 * s1 * c24;   // (40)
  const double ay = s1 * s24;                  // (41)
  const double nz = -s24 * c5;                 // (43)
  const double oz = s24 * s5;                  // (44)
  const double az = c24;                       // (45)
  f.R << nx, ox, ax, ny, oy, ay, nz, oz, az;
  f.p.x() = pz3 * c1 * s2 + px2 * c1 * c2 - pz2 * s1 + pz5 * c1 * s24 +
            px5 * (c1 * c24 * c5 - s1 * s5);  // (38), px2 term corrected
  f.p.y() = pz3 * s1 * s2 + px2 * s1 * c2 + pz2 * c1 + pz5 * s1 * s24 +
            px5 * (c1 * s5 + c5 * s1 * c24);                         // (42), px2 term corrected
  f.p.z() = pz1 + pz5 * c24 + pz3 * c2 - px2 * s2 - px5 * s24 * c5;  // (46), px2 sign corrected
  return f;
}

TEST(Weld5Model, ForwardKinematicsMatchesSeedEquations35To46) {
  const Weld5Model m = Weld5Model::Ideal(Weld5TorchTransform(kPx5, kPz5, 0.0));
  std::mt19937 rng(35);
  Weld5Data data;
  for (int trial = 0; trial < 100; ++trial) {
    const Vector5d q = RandomInLimits(m, &rng, 0.0);
    Weld5ForwardKinematics(m, q, &data);
    const SeedFk f = SeedEquations(q, 0.275, 0.104718, 0.033389, kPz5, kPx5);
    EXPECT_LT((data.X_0T.linear() - f.R).cwiseAbs().maxCoeff(), 1e-12);
    EXPECT_LT((data.p_0T - f.p).norm(), 1e-12);
    EXPECT_LT((data.u_0T - f.R.col(2)).norm(), 1e-12);
  }
}

// The printed px2 terms of eq. (38), (42), (46) are not those of any D–H chain with the
// rotations of eq. (35)–(45) (−px2·s1·c1 in (42) is not even of the form px2·(unit vector)).
// Pin down that the model does NOT compute the printed form (it differs by > 10 mm here), so the
// correction is a deliberate choice.
TEST(Weld5Model, PrintedPx2TermsOfSeedDisagreeWithChain) {
  const Weld5Model m = Weld5Model::Ideal(Weld5TorchTransform(kPx5, kPz5, 0.0));
  Vector5d q;
  q << 0.6, 0.5, 0.3, 0.2, 0.1;
  Weld5Data data;
  Weld5ForwardKinematics(m, q, &data);
  const double px2 = 0.033389;
  const double c1 = std::cos(q(0)), s1 = std::sin(q(0)), s2 = std::sin(q(1));
  const SeedFk f = SeedEquations(q, 0.275, 0.104718, 0.0, kPz5, kPx5);
  // As printed: px2·s1·s2 in (38), −px2·s1·c1 in (42), +px2·s2 in (46).
  const Eigen::Vector3d printed = f.p + px2 * Eigen::Vector3d(s1 * s2, -s1 * c1, s2);
  EXPECT_GT((printed - data.p_0T).norm(), 0.01);
}

TEST(Weld5Model, SeedParametersInSi) {
  const Weld5Model m = Weld5Model::Seed(Eigen::Isometry3d::Identity());
  EXPECT_NEAR(m.joints[0].alpha, -89.827 * common::kDeg, 1e-15);
  EXPECT_NEAR(m.joints[1].alpha, 90.0 * common::kDeg, 1e-15);
  EXPECT_DOUBLE_EQ(m.joints[0].d, 0.275);
  EXPECT_DOUBLE_EQ(m.joints[1].d, 0.104718);
  EXPECT_DOUBLE_EQ(m.joints[0].a, -0.059e-3);
  EXPECT_DOUBLE_EQ(m.joints[1].a, 0.033389);
  EXPECT_NEAR(m.joints[0].theta_offset, 0.1097 * common::kDeg, 1e-15);
  EXPECT_NEAR(m.joints[1].theta_offset, 89.602 * common::kDeg, 1e-15);
  EXPECT_TRUE(m.joints[2].prismatic);
  for (int i = 0; i < kWeld5Joints; ++i) {
    EXPECT_LT(m.q_min(i), m.q_max(i));
    if (i != 2) {
      EXPECT_FALSE(m.joints[i].prismatic);
    }
  }
}

TEST(Weld5Model, ValidateNamesEveryBadFieldAndItsValue) {
  const Weld5Model seed = Weld5Model::Seed(Weld5TorchTransform(kPx5, kPz5, 0.3));
  EXPECT_EQ(seed.Validate(), "");
  EXPECT_EQ(Weld5Model::Ideal(Eigen::Isometry3d::Identity()).Validate(), "");

  Weld5Model bad = seed;
  bad.joints[1].alpha = std::nan("");
  bad.q_min(2) = 0.4;
  bad.q_max(2) = 0.1;
  bad.qd_max(4) = 0.0;
  const std::string message = bad.Validate();
  EXPECT_NE(message.find("theta2.alpha: must be finite, got nan"), std::string::npos) << message;
  EXPECT_NE(message.find("pz3.limits: need q_min < q_max, got [0.4, 0.1]"), std::string::npos)
      << message;
  EXPECT_NE(message.find("theta5.qd_max: must be > 0, got 0"), std::string::npos) << message;
  EXPECT_EQ(message.find("theta1"), std::string::npos) << message;

  Weld5Model sheared = seed;
  sheared.X_5T.matrix()(0, 1) = 0.2;
  EXPECT_NE(sheared.Validate().find("X_5T.linear: must be a rotation"), std::string::npos);
  Weld5Model mirrored = seed;
  mirrored.X_5T.matrix().col(0) *= -1.0;
  EXPECT_NE(mirrored.Validate().find("det = -1"), std::string::npos) << mirrored.Validate();
  Weld5Model infinite = seed;
  infinite.X_5T.translation().x() = INFINITY;
  EXPECT_NE(infinite.Validate().find("X_5T: must be finite"), std::string::npos);
}

TEST(Weld5Model, TorchTransformTiltsAxisAboutY5) {
  const Weld5Model m = Weld5Model::Seed(Weld5TorchTransform(kPx5, kPz5, 0.25));
  Vector5d q;
  q << 0.1, 0.2, 0.3, 0.4, 0.5;
  Weld5Data data;
  Weld5ForwardKinematics(m, q, &data);
  const Eigen::Isometry3d& X_05 = data.X_0L[4];
  EXPECT_LT((data.p_0T - X_05 * Eigen::Vector3d(kPx5, 0, kPz5)).norm(), 1e-14);
  EXPECT_NEAR(data.u_0T.dot(X_05.linear().col(2)), std::cos(0.25), 1e-14);
  EXPECT_NEAR(data.u_0T.dot(X_05.linear().col(1)), 0.0, 1e-14);
}

TEST(Weld5Model, ForwardKinematicsJacobianAndIkDoNotAllocate) {
  const Weld5Model m = Weld5Model::Seed(Weld5TorchTransform(kPx5, kPz5, 0.2));
  Vector5d q;
  q << 0.1, 0.2, 0.3, 0.4, 0.5;
  Weld5Data data;
  const long before = kinevis::testing::ThreadAllocations();
  Weld5ForwardKinematics(m, q, &data);
  const Matrix65d J = DhGeometricJacobian(m.joints, q, m.X_5T);
  const Eigen::Isometry3d X = DhForwardKinematics(m.joints, q);
  Vector5d guess = q;
  guess(0) += 0.1;
  const Weld5IkResult r = Weld5InverseKinematics(m, data.p_0T, data.u_0T, guess);
  const long after = kinevis::testing::ThreadAllocations();
  EXPECT_EQ(after - before, 0);
  EXPECT_TRUE(r.converged());
  // The counter does see heap allocations.
  int* probe = new int(1);
  EXPECT_EQ(kinevis::testing::ThreadAllocations() - after, 1);
  delete probe;
  EXPECT_TRUE(J.isApprox(data.J));  // keep the results alive
  EXPECT_TRUE(X.isApprox(data.X_0L[4]));
}

TEST(Weld5Ik, RoundTripsOnRandomReachableConfigurations) {
  const Weld5Model m = Weld5Model::Seed(Weld5TorchTransform(kPx5, kPz5, 0.2));
  std::mt19937 rng(2024);
  std::normal_distribution<double> noise(0.0, 0.05);
  Weld5Data data, check;
  int converged = 0;
  constexpr int kTrials = 100;
  for (int trial = 0; trial < kTrials; ++trial) {
    const Vector5d q_true = RandomInLimits(m, &rng, 0.05);
    Weld5ForwardKinematics(m, q_true, &data);
    Vector5d guess = q_true;
    for (int i = 0; i < kWeld5Joints; ++i) guess(i) += noise(rng);
    const Weld5IkResult r = Weld5InverseKinematics(m, data.p_0T, data.u_0T, guess);
    ASSERT_TRUE(r.converged()) << "trial " << trial << ": " << ToString(r.status) << " pos "
                               << r.position_error << " axis " << r.axis_error << " q_true "
                               << q_true.transpose() << " guess " << guess.transpose();
    ++converged;
    Weld5ForwardKinematics(m, r.q, &check);
    EXPECT_LT((check.p_0T - data.p_0T).norm(), 1e-8);
    EXPECT_LT(std::acos(std::clamp(check.u_0T.dot(data.u_0T), -1.0, 1.0)), 1e-6);
    EXPECT_TRUE(((r.q - m.q_min).array() >= 0).all());
    EXPECT_TRUE(((m.q_max - r.q).array() >= 0).all());
  }
  EXPECT_EQ(converged, kTrials);
}

TEST(Weld5Ik, FarTargetIsNotReachable) {
  const Weld5Model m = Weld5Model::Seed(Weld5TorchTransform(kPx5, kPz5, 0.0));
  Vector5d guess;
  guess << 0.0, 0.0, 0.3, 0.0, 0.0;
  const Weld5IkResult r =
      Weld5InverseKinematics(m, Eigen::Vector3d(5.0, 0.0, 0.3), Eigen::Vector3d(0, 0, -1), guess);
  EXPECT_EQ(r.status, Weld5IkStatus::kNotReachable);
  EXPECT_GT(r.position_error, 1.0);
  EXPECT_EQ(r.limiting_joint, -1);
}

TEST(Weld5Ik, TargetNeedingLongerStrokeReportsPz3) {
  const Weld5Model m = Weld5Model::Seed(Weld5TorchTransform(kPx5, kPz5, 0.0));
  Vector5d q_true;
  q_true << 0.2, 0.3, m.q_max(2) + 0.05, 0.4, 0.1;
  Weld5Data data;
  Weld5ForwardKinematics(m, q_true, &data);
  Vector5d guess = q_true;
  guess(2) = m.q_max(2) - 0.05;
  guess(0) += 0.05;
  const Weld5IkResult r = Weld5InverseKinematics(m, data.p_0T, data.u_0T, guess);
  EXPECT_EQ(r.status, Weld5IkStatus::kJointLimit);
  EXPECT_EQ(r.limiting_joint, 2);
  EXPECT_STREQ(r.limiting_joint_name, "pz3");
  EXPECT_LE(r.q(2), m.q_max(2));
}

}  // namespace
}  // namespace kinevis::robots

namespace kinevis::robots {
namespace {

// From a fixed mid-range guess (no knowledge of the answer), with the extra starts, nearly all
// random reachable targets converge; every reported solution must reproduce the target.
TEST(Weld5Ik, ConvergesFromMidRangeGuessOnMostTargets) {
  const Weld5Model m = Weld5Model::Seed(Weld5TorchTransform(kPx5, kPz5, 0.2));
  std::mt19937 rng(77);
  const Vector5d guess = 0.5 * (m.q_min + m.q_max);
  Weld5Data data, check;
  int converged = 0;
  constexpr int kTrials = 100;
  for (int trial = 0; trial < kTrials; ++trial) {
    const Vector5d q_true = RandomInLimits(m, &rng, 0.05);
    Weld5ForwardKinematics(m, q_true, &data);
    const Weld5IkResult r = Weld5InverseKinematics(m, data.p_0T, data.u_0T, guess);
    if (!r.converged()) continue;
    ++converged;
    Weld5ForwardKinematics(m, r.q, &check);
    EXPECT_LT((check.p_0T - data.p_0T).norm(), 1e-8);
  }
  // 99 / 100 with the defaults (seed 77); the margin absorbs platform rounding.
  EXPECT_GE(converged, 95);
}

}  // namespace
}  // namespace kinevis::robots
