#include "control/weld/torch_ik.h"

#include <gtest/gtest.h>

namespace kinevis::control {
namespace {

robots::Weld5Model Robot() {
  return robots::Weld5Model::Seed(robots::Weld5TorchTransform(0.025, 0.250, 0.0));
}
robots::Vector5d Home() { return (robots::Vector5d() << 0, 0, 0.2, 0, 0).finished(); }

TEST(TorchIk, WirePointJacobianMatchesFiniteDifferences) {
  const robots::Weld5Model m = Robot();
  const robots::Vector5d q = (robots::Vector5d() << 0.3, -0.4, 0.25, 0.7, -0.9).finished();
  for (double d : {0.0, 0.015, 0.2}) {
    Eigen::Matrix<double, 3, 5> J;
    WirePoint(m, q, d, &J);
    for (int i = 0; i < 5; ++i) {
      robots::Vector5d dq = robots::Vector5d::Zero();
      dq(i) = 1e-6;
      const Eigen::Vector3d fd = (WirePoint(m, q + dq, d) - WirePoint(m, q - dq, d)) / 2e-6;
      EXPECT_LT((J.col(i) - fd).norm(), 1e-7) << "joint " << i << " d " << d;
    }
  }
}

void ExpectConsistent(const robots::Weld5Model& m, const TorchIkResult& r,
                      const Eigen::Vector3d& p_W, const Eigen::Vector3d& u_t, double d) {
  robots::Weld5Data fk;
  robots::Weld5ForwardKinematics(m, r.q, &fk);
  EXPECT_LT((fk.p_0T + d * fk.u_0T - p_W).norm(), 1e-7);
  EXPECT_LT((fk.p_0T - r.p_0T).norm(), 1e-12);
  EXPECT_NEAR(std::acos(std::clamp(fk.u_0T.dot(u_t), -1.0, 1.0)), r.tilt, 1e-6);
  for (int i = 0; i < 5; ++i) {
    EXPECT_GE(r.q(i), m.q_min(i));
    EXPECT_LE(r.q(i), m.q_max(i));
  }
}

TEST(TorchIk, HoldsTheNormalExactlyWhereTheArmCan) {
  const robots::Weld5Model m = Robot();
  const Eigen::Vector3d p(0.70, 0.105, 0.27), u(1, 0, 0);
  const TorchIkResult r = SolveTorchIk(m, p, u, 0.015, Home());
  ASSERT_TRUE(r.converged());
  EXPECT_LT(r.tilt, 1e-6);
  ExpectConsistent(m, r, p, u, 0.015);
}

TEST(TorchIk, TiltsOnlyAsMuchAsTheArmNeeds) {
  // 60 mm to the side of the arm's lateral offset: the axis must turn with θ1 (~ 0.06 / 0.7 rad).
  const robots::Weld5Model m = Robot();
  const Eigen::Vector3d p(0.70, 0.045, 0.27), u(1, 0, 0);
  const TorchIkResult r = SolveTorchIk(m, p, u, 0.015, Home());
  ASSERT_TRUE(r.converged());
  EXPECT_GT(r.tilt, 2.0 * M_PI / 180);
  EXPECT_LT(r.tilt, 3.5 * M_PI / 180);
  ExpectConsistent(m, r, p, u, 0.015);
  TorchIkOptions strict;
  strict.max_tilt = 1.0 * M_PI / 180;
  EXPECT_EQ(SolveTorchIk(m, p, u, 0.015, Home(), strict).status,
            robots::Weld5IkStatus::kNotReachable);
}

TEST(TorchIk, JointLimitIsNamed) {
  robots::Weld5Model m = Robot();
  m.q_min(0) = -0.01;  // θ1 cannot turn far enough to the right
  const TorchIkResult r =
      SolveTorchIk(m, Eigen::Vector3d(0.70, 0.02, 0.27), Eigen::Vector3d(1, 0, 0), 0.015, Home());
  EXPECT_EQ(r.status, robots::Weld5IkStatus::kJointLimit);
  EXPECT_EQ(r.limiting_joint, 0);
}

TEST(TorchIk, TargetBeyondTheStrokeNamesPz3) {
  // 2 m out: the prismatic joint would have to extend beyond its 0.5 m stroke.
  const TorchIkResult r = SolveTorchIk(Robot(), Eigen::Vector3d(2.0, 0.1, 0.27),
                                       Eigen::Vector3d(1, 0, 0), 0.015, Home());
  EXPECT_EQ(r.status, robots::Weld5IkStatus::kJointLimit);
  EXPECT_EQ(r.limiting_joint, 2);
}

}  // namespace
}  // namespace kinevis::control
