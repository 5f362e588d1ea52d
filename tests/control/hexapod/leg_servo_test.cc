#include "control/hexapod/leg_servo.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <Eigen/SVD>
#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include "common/so3.h"
#include "common/units.h"

namespace kinevis::control {
namespace {

using robots::HexapodData;
using robots::HexapodModel;
using ::testing::HasSubstr;

// A camera in front of the robot: X_BC = {[0, -1.2, 0.9], rpy (-113, 0, 0)°}.
Eigen::Isometry3d CameraPose_CB() {
  Eigen::Isometry3d X_BC = Eigen::Isometry3d::Identity();
  X_BC.linear() =
      Eigen::AngleAxisd(-113.0 * common::kPi / 180.0, Eigen::Vector3d::UnitX()).matrix();
  X_BC.translation() = Eigen::Vector3d(0.0, -1.2, 0.9);
  return X_BC.inverse();
}

// Moves the platform by the twist τ (in C, referred to C's origin) applied for time eps:
// every platform point p (in C) goes to exp(eps [ω]×) p + eps v, whose derivative at eps = 0 is
// v + ω × p, the definition of the twist.
Eigen::Isometry3d MovePlatform(const Eigen::Isometry3d& X_BP, const Eigen::Isometry3d& X_CB,
                               const Vector6d& tau_C, double eps) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  const Eigen::Vector3d w = eps * tau_C.tail<3>();
  if (w.norm() > 0) T.linear() = Eigen::AngleAxisd(w.norm(), w.normalized()).matrix();
  T.translation() = eps * tau_C.head<3>();
  return X_CB.inverse() * T * X_CB * X_BP;
}

struct Measured {
  LegDirections u_C;
  Vector6d q;
};

Measured Measure(const HexapodModel& model, const Eigen::Isometry3d& X_BP,
                 const Eigen::Isometry3d& X_CB) {
  HexapodData data;
  robots::InverseKinematics(model, X_BP, &data);
  Measured m;
  for (int j = 0; j < kHexapodLegs; ++j) m.u_C[j] = X_CB.linear() * data.u_B[j];
  m.q = data.q;
  return m;
}

Eigen::Isometry3d Pose(double x, double y, double z, double rx, double ry, double rz) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation() = Eigen::Vector3d(x, y, z);
  X.linear() = (Eigen::AngleAxisd(rz, Eigen::Vector3d::UnitZ()) *
                Eigen::AngleAxisd(ry, Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(rx, Eigen::Vector3d::UnitX()))
                   .matrix();
  return X;
}

std::vector<Eigen::Isometry3d> RandomPoses(const HexapodModel& model, int count,
                                           std::mt19937* rng) {
  std::uniform_real_distribution<double> lateral(-0.05, 0.05), height(0.37, 0.45),
      angle(-0.15, 0.15);
  std::vector<Eigen::Isometry3d> poses;
  HexapodData data;
  while (static_cast<int>(poses.size()) < count) {
    const Eigen::Isometry3d X =
        Pose(lateral(*rng), lateral(*rng), height(*rng), angle(*rng), angle(*rng), angle(*rng));
    if (robots::InverseKinematics(model, X, &data).ok()) poses.push_back(X);
  }
  return poses;
}

Eigen::MatrixXd PseudoInverse(const Eigen::MatrixXd& m) {
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(m, Eigen::ComputeThinU | Eigen::ComputeThinV);
  Eigen::VectorXd inv = svd.singularValues();
  for (int i = 0; i < inv.size(); ++i) inv[i] = inv[i] > 1e-6 * inv[0] ? 1.0 / inv[i] : 0.0;
  return svd.matrixV() * inv.asDiagonal() * svd.matrixU().transpose();
}

LegMask AllVisible() { return {true, true, true, true, true, true}; }

TEST(LegServoTest,
     InteractionMatrixAndInverseDifferentialMatchCentralDifferencesOfAMovingPlatform) {
  const HexapodModel model = HexapodModel::Default();
  const Eigen::Isometry3d X_CB = CameraPose_CB();
  const LegPoints p_C_A = AttachmentPointsInCamera(model, X_CB);
  std::mt19937 rng(6);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  const double h = 1e-6;
  for (const Eigen::Isometry3d& X_BP : RandomPoses(model, 20, &rng)) {
    const Measured m = Measure(model, X_BP, X_CB);
    for (int axis = 0; axis < 6; ++axis) {
      Vector6d tau = Vector6d::Zero();
      tau[axis] = 1.0;
      const Measured plus = Measure(model, MovePlatform(X_BP, X_CB, tau, h), X_CB);
      const Measured minus = Measure(model, MovePlatform(X_BP, X_CB, tau, -h), X_CB);
      for (int j = 0; j < kHexapodLegs; ++j) {
        const Eigen::Vector3d du_fd = (plus.u_C[j] - minus.u_C[j]) / (2 * h);
        const Eigen::Vector3d du =
            LegDirectionInteractionMatrixAtCameraOrigin(p_C_A[j], m.u_C[j], m.q[j]) * tau;
        EXPECT_LT((du - du_fd).norm(), 1e-6 * (1.0 + du_fd.norm()))
            << "leg " << j << " axis " << axis;
        const double dq_fd = (plus.q[j] - minus.q[j]) / (2 * h);
        const double dq = InverseDifferentialRowAtCameraOrigin(p_C_A[j], m.u_C[j]) * tau;
        EXPECT_NEAR(dq, dq_fd, 1e-6 * (1.0 + std::abs(dq_fd))) << "leg " << j;
      }
    }
  }
}

TEST(LegServoTest, InteractionMatrixEqualsTheRobotsOneAfterMovingTheReferencePoint) {
  const HexapodModel model = HexapodModel::Default();
  const Eigen::Isometry3d X_CB = CameraPose_CB();
  const LegPoints p_C_A = AttachmentPointsInCamera(model, X_CB);
  std::mt19937 rng(7);
  for (const Eigen::Isometry3d& X_BP : RandomPoses(model, 10, &rng)) {
    HexapodData data;
    robots::InverseKinematics(model, X_BP, &data);
    const Measured m = Measure(model, X_BP, X_CB);
    // [v_P; ω] = [[I, −[p_C_P]×]; [0, I]] [v_O; ω]: the velocity of the platform origin from
    // the velocity of the point at C's origin.
    const Eigen::Vector3d p_C_P = X_CB * X_BP.translation();
    robots::Matrix6d shift = robots::Matrix6d::Identity();
    shift.topRightCorner<3, 3>() = -common::Skew(p_C_P);
    for (int j = 0; j < kHexapodLegs; ++j) {
      const Matrix36d L_P = robots::LegDirectionInteractionMatrixInCamera(data, j, X_CB);
      const Matrix36d L_O = LegDirectionInteractionMatrixAtCameraOrigin(p_C_A[j], m.u_C[j], m.q[j]);
      EXPECT_LT((L_P * shift - L_O).norm(), 1e-10) << "leg " << j;
    }
  }
}

TEST(LegServoTest, VpServoGivesMinusLambdaTimesThePseudoInverseOfLTimesTheError) {
  const HexapodModel model = HexapodModel::Default();
  const Eigen::Isometry3d X_CB = CameraPose_CB();
  const LegPoints p_C_A = AttachmentPointsInCamera(model, X_CB);
  LegServoOptions options;
  options.gain = 0.7;
  LegServo servo(p_C_A, options);
  LegDirections u_star;
  ASSERT_TRUE(
      DesiredLegDirections(model, Pose(0.01, 0.02, 0.42, 0.05, -0.03, 0.1), X_CB, &u_star).ok());
  servo.SetDesired(u_star);
  const Measured m = Measure(model, Pose(-0.02, 0.0, 0.39, 0.0, 0.06, -0.05), X_CB);
  const LegServoResult r = servo.Compute(m.u_C, AllVisible(), m.q);
  ASSERT_TRUE(r.ok()) << ToString(r.status);
  EXPECT_EQ(r.rank, 6);
  EXPECT_EQ(r.visible_legs, 6);

  Eigen::Matrix<double, 18, 6> L;
  Eigen::Matrix<double, 18, 1> e;
  ASSERT_EQ(StackLegServoTask(p_C_A, m.u_C, u_star, AllVisible(), m.q, &L, &e), 18);
  const Vector6d tau = -0.7 * PseudoInverse(L) * e;
  EXPECT_LT((r.twist_C - tau).norm(), 1e-10 * tau.norm());
  EXPECT_NEAR(r.error_norm, e.norm(), 1e-15);
  const Vector6d q_dot = InverseDifferentialAtCameraOrigin(p_C_A, m.u_C) * tau;
  EXPECT_LT((r.q_dot - q_dot).norm(), 1e-10 * q_dot.norm());
  EXPECT_GT(tau.norm(), 1e-3);  // not a trivially zero comparison
}

// The remaining displacement is L⁺e moved to the platform centre: for a small pose offset it is
// (to first order in the offset) the motion from the current to the desired pose, [δp of the
// platform centre; δθ], in C. Checked at two offset sizes: the error must shrink quadratically.
TEST(LegServoTest, RemainingDisplacementIsThePoseOffsetAtThePlatformCentre) {
  const HexapodModel model = HexapodModel::Default();
  const Eigen::Isometry3d X_CB = CameraPose_CB();
  LegServo servo(AttachmentPointsInCamera(model, X_CB));
  const Eigen::Isometry3d X_BP = Pose(0.01, -0.005, 0.41, 0.02, -0.03, 0.04);
  const Vector6d direction = (Vector6d() << 0.3, -0.5, 0.4, 0.6, -0.2, 0.5).finished();
  double previous_error = 0;
  for (const double size : {2e-3, 1e-3}) {
    // The desired pose: X_BP moved by δp = size·d_p (of the platform centre) and δθ = size·d_θ,
    // both in C, about the platform centre.
    const Eigen::Vector3d dp = size * direction.head<3>();
    const Eigen::Vector3d dtheta = size * direction.tail<3>();
    const Eigen::Isometry3d X_CP = X_CB * X_BP;
    Eigen::Isometry3d X_CP_star = X_CP;
    X_CP_star.linear() = Eigen::AngleAxisd(dtheta.norm(), dtheta.normalized()) * X_CP.linear();
    X_CP_star.translation() = X_CP.translation() + dp;
    // HexapodModel::Default()'s platform points are centred on P's origin: the centre is P.
    LegDirections u_star;
    ASSERT_TRUE(DesiredLegDirections(model, X_CB.inverse() * X_CP_star, X_CB, &u_star).ok());
    servo.SetDesired(u_star);
    const Measured m = Measure(model, X_BP, X_CB);
    const LegServoResult r = servo.Compute(m.u_C, AllVisible(), m.q);
    ASSERT_TRUE(r.ok());
    // e = u − u*: L⁺e points from the desired pose back to the current one.
    Vector6d expected;
    expected << -dp, -dtheta;
    const double error = (r.remaining_displacement - expected).norm();
    EXPECT_LT(error, 0.05 * expected.norm()) << size;
    if (previous_error > 0) {
      EXPECT_LT(error, 0.4 * previous_error);  // second order
    }
    previous_error = error;
  }
}

TEST(LegServoTest, AdaptiveGainIsViSPsLawOfTheInfinityNormOfLPlusE) {
  const HexapodModel model = HexapodModel::Default();
  const Eigen::Isometry3d X_CB = CameraPose_CB();
  const LegPoints p_C_A = AttachmentPointsInCamera(model, X_CB);
  LegServoOptions options;
  options.adaptive_gain = true;
  options.gain_at_zero = 4.0;
  options.gain_at_infinity = 0.5;
  options.slope_at_zero = 20.0;
  LegServo servo(p_C_A, options);
  LegDirections u_star;
  DesiredLegDirections(model, Pose(0, 0, 0.41, 0, 0, 0), X_CB, &u_star);
  servo.SetDesired(u_star);
  const Measured m = Measure(model, Pose(0.01, 0, 0.40, 0.02, 0, 0), X_CB);
  const LegServoResult r = servo.Compute(m.u_C, AllVisible(), m.q);
  ASSERT_TRUE(r.ok());
  Eigen::Matrix<double, 18, 6> L;
  Eigen::Matrix<double, 18, 1> e;
  StackLegServoTask(p_C_A, m.u_C, u_star, AllVisible(), m.q, &L, &e);
  const Vector6d e1 = PseudoInverse(L) * e;
  const double x = e1.cwiseAbs().maxCoeff();
  const double lambda = (4.0 - 0.5) * std::exp(-20.0 * x / (4.0 - 0.5)) + 0.5;
  EXPECT_LT((r.twist_C + lambda * e1).norm(), 1e-10 * e1.norm());
  EXPECT_GT(lambda, 0.6);  // the gain is really between its limits here
  EXPECT_LT(lambda, 3.9);
}

// The law closed on ideal kinematics: the leg rates it commands are integrated exactly and the
// true forward kinematics give the next pose; features every dt. With exact A_j the error
// decreases like exp(−λ t) (e is in the range of L near the goal, so L L⁺ e = e).
TEST(LegServoTest, ErrorDecreasesExponentiallyInAnIdealKinematicLoop) {
  const HexapodModel model = HexapodModel::Default();
  const Eigen::Isometry3d X_CB = CameraPose_CB();
  LegServoOptions options;
  options.gain = 2.0;
  LegServo servo(AttachmentPointsInCamera(model, X_CB), options);
  const Eigen::Isometry3d X_BP_goal = Pose(0.02, -0.01, 0.42, 0.04, 0.02, -0.06);
  LegDirections u_star;
  ASSERT_TRUE(DesiredLegDirections(model, X_BP_goal, X_CB, &u_star).ok());
  servo.SetDesired(u_star);

  Eigen::Isometry3d X_BP = robots::HexapodModel::NominalPose();
  const double dt = 0.002;
  std::vector<double> norms;
  HexapodData data;
  for (int k = 0; k <= 2000; ++k) {  // 4 s
    const Measured m = Measure(model, X_BP, X_CB);
    const LegServoResult r = servo.Compute(m.u_C, AllVisible(), m.q);
    ASSERT_TRUE(r.ok()) << "step " << k << ": " << ToString(r.status);
    norms.push_back(r.error_norm);
    const robots::ForwardKinematicsSummary fk = robots::ForwardKinematics(
        model, m.q + dt * r.q_dot, X_BP, robots::ForwardKinematicsOptions{}, &data);
    ASSERT_TRUE(fk.converged());
    X_BP = fk.X_BP;
  }
  for (size_t k = 1; k < norms.size(); ++k) ASSERT_LE(norms[k], norms[k - 1]) << "step " << k;
  // Rate measured over the second half (near the goal, where the model is linear):
  const double rate = std::log(norms[1000] / norms[2000]) / 2.0;
  EXPECT_NEAR(rate, 2.0, 0.05);
  // Bounded by the exponential from the start (with the first-half transient allowed for).
  for (size_t k = 0; k < norms.size(); ++k) {
    EXPECT_LE(norms[k], 1.05 * norms[0] * std::exp(-1.9 * dt * k)) << "step " << k;
  }
  // The pose follows the error: the start is 3 cm / 0.075 rad away, exp(−8) of that remains.
  EXPECT_LT((X_BP.translation() - X_BP_goal.translation()).norm(), 5e-5);
  EXPECT_LT(Eigen::AngleAxisd(X_BP.linear().transpose() * X_BP_goal.linear()).angle(), 1e-4);
  std::printf("ideal loop: |e| %.3e -> %.3e in 4 s, rate over the last 2 s %.4f 1/s (gain 2)\n",
              norms.front(), norms.back(), rate);
}

TEST(LegServoTest, HiddenLegsLeaveTheirRowsOutAndStillConverge) {
  const HexapodModel model = HexapodModel::Default();
  const Eigen::Isometry3d X_CB = CameraPose_CB();
  const LegPoints p_C_A = AttachmentPointsInCamera(model, X_CB);
  LegServoOptions options;
  options.gain = 2.0;
  options.min_visible_legs = 4;
  LegServo servo(p_C_A, options);
  const Eigen::Isometry3d X_BP_goal = Pose(-0.015, 0.01, 0.41, -0.03, 0.02, 0.05);
  LegDirections u_star;
  DesiredLegDirections(model, X_BP_goal, X_CB, &u_star);
  servo.SetDesired(u_star);

  Eigen::Isometry3d X_BP = robots::HexapodModel::NominalPose();
  // Legs never seen cannot give a D_inv row.
  LegMask visible = {true, false, true, true, false, true};
  Measured m = Measure(model, X_BP, X_CB);
  EXPECT_EQ(servo.Compute(m.u_C, visible, m.q).status, LegServoStatus::kNoDirection);
  servo.Compute(m.u_C, AllVisible(), m.q);  // seen once

  // Four legs: 12 rows, equal to the Eigen law on those rows.
  LegServoResult r = servo.Compute(m.u_C, visible, m.q);
  ASSERT_TRUE(r.ok()) << ToString(r.status);
  EXPECT_EQ(r.visible_legs, 4);
  EXPECT_TRUE(r.stale_direction[1]);
  EXPECT_TRUE(r.stale_direction[4]);
  EXPECT_FALSE(r.stale_direction[0]);
  EXPECT_EQ(r.error[1], Eigen::Vector3d::Zero());
  Eigen::Matrix<double, 18, 6> L;
  Eigen::Matrix<double, 18, 1> e;
  ASSERT_EQ(StackLegServoTask(p_C_A, m.u_C, u_star, visible, m.q, &L, &e), 12);
  const Vector6d tau = -2.0 * PseudoInverse(L.topRows(12)) * e.head(12);
  EXPECT_LT((r.twist_C - tau).norm(), 1e-10 * tau.norm());

  // Closed loop on four legs; the hidden legs' D_inv rows use the stale directions, so each
  // step refreshes them from the truth, as a camera seeing them again would not: measure them
  // here but do not show them to the law.
  HexapodData data;
  for (int k = 0; k < 2000; ++k) {
    m = Measure(model, X_BP, X_CB);
    servo.Compute(m.u_C, AllVisible(), m.q);  // refresh the stale rows
    r = servo.Compute(m.u_C, visible, m.q);
    ASSERT_TRUE(r.ok());
    X_BP = robots::ForwardKinematics(model, m.q + 0.002 * r.q_dot, X_BP,
                                     robots::ForwardKinematicsOptions{}, &data)
               .X_BP;
  }
  EXPECT_LT((X_BP.translation() - X_BP_goal.translation()).norm(), 1e-5);

  // Three legs visible with min_visible_legs = 4: refused, no motion.
  visible = {true, false, true, false, false, true};
  r = servo.Compute(m.u_C, visible, m.q);
  EXPECT_EQ(r.status, LegServoStatus::kTooFewLegs);
  EXPECT_EQ(r.q_dot, Vector6d::Zero());
}

TEST(LegServoTest, BadOptionsAndInputsAreRefusedNamingEveryField) {
  LegServoOptions options;
  options.gain = -1;
  options.adaptive_gain = true;
  options.gain_at_zero = 0.5;
  options.gain_at_infinity = 1.0;
  options.min_visible_legs = 2;
  const std::string message = options.Validate();
  EXPECT_THAT(message, HasSubstr("gain: must be finite and > 0, got -1"));
  EXPECT_THAT(message, HasSubstr("gain_at_zero: must exceed gain_at_infinity, got 0.5"));
  EXPECT_THAT(message, HasSubstr("min_visible_legs: must be in 3..6, got 2"));
  EXPECT_EQ(LegServoOptions{}.Validate(), "");
  LegPoints p{};
  EXPECT_THROW(LegServo(p, options), std::invalid_argument);
  p[3] = Eigen::Vector3d(std::nan(""), 0, 0);
  try {
    LegServo servo(p);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr("p_C_A[3]: must be finite"));
  }
  LegServo servo(AttachmentPointsInCamera(HexapodModel::Default(), CameraPose_CB()));
  LegDirections u{};
  EXPECT_THROW(servo.SetDesired(u), std::invalid_argument);
  // No desired features yet, or bad measurements: refused, zero rates.
  for (auto& v : u) v = Eigen::Vector3d::UnitZ();
  Vector6d q = Vector6d::Constant(0.45);
  EXPECT_EQ(servo.Compute(u, AllVisible(), q).status, LegServoStatus::kInvalidInput);
  servo.SetDesired(u);
  q[2] = 0;
  EXPECT_EQ(servo.Compute(u, AllVisible(), q).status, LegServoStatus::kInvalidInput);
}

}  // namespace
}  // namespace kinevis::control
