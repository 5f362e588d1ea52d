#include "robots/hexapod/hexapod_model.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <cstdlib>
#include <new>
#include <random>
#include <vector>

#include "common/so3.h"
#include "common/units.h"
#include "tests/utilities/allocation_counter.h"

namespace kinevis::robots {
namespace {

using ::testing::ContainsRegex;
using ::testing::IsEmpty;

// Applies the increment used throughout: p_BP += δp, R_BP = exp([δθ]×) R_BP (twist in B at the
// platform origin, integrated over unit time).
Eigen::Isometry3d Perturb(const Eigen::Isometry3d& X_BP, const Vector6d& delta) {
  Eigen::Isometry3d X = X_BP;
  X.translation() += delta.head<3>();
  const double angle = delta.tail<3>().norm();
  if (angle > 0.0) {
    X.linear() =
        Eigen::AngleAxisd(angle, delta.tail<3>() / angle).toRotationMatrix() * X_BP.linear();
  }
  return X;
}

double RotationAngleBetween(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
  return Eigen::AngleAxisd(a.transpose() * b).angle();
}

// Random poses around the nominal one, kept only when every leg is within stroke and the
// platform is well away from singularities (cond(D_inv) < 1e3), so accuracy margins hold.
std::vector<Eigen::Isometry3d> RandomReachablePoses(const HexapodModel& model, int count,
                                                    std::mt19937* rng) {
  std::uniform_real_distribution<double> lateral(-0.06, 0.06);
  std::uniform_real_distribution<double> height(0.36, 0.46);
  std::uniform_real_distribution<double> angle(-0.2, 0.2);
  std::vector<Eigen::Isometry3d> poses;
  HexapodData data;
  for (int attempt = 0; attempt < 100 * count && static_cast<int>(poses.size()) < count;
       ++attempt) {
    Vector6d delta;
    delta << lateral(*rng), lateral(*rng), height(*rng), angle(*rng), angle(*rng), angle(*rng);
    const Eigen::Isometry3d X_BP = Perturb(Eigen::Isometry3d::Identity(), delta);
    if (!InverseKinematics(model, X_BP, &data).ok()) continue;
    if (ConditionNumber(InverseDifferential(data)) > 1e3) continue;
    poses.push_back(X_BP);
  }
  return poses;
}

TEST(HexapodModelTest, DefaultModelIsValidAndMatchesTheDocumentedGeometry) {
  const HexapodModel model = HexapodModel::Default();
  EXPECT_THAT(model.Validate(), IsEmpty());
  for (int j = 0; j < kHexapodLegs; ++j) {
    EXPECT_NEAR(model.p_B_A[j].head<2>().norm(), 0.30, 1e-12) << "leg " << j;
    EXPECT_NEAR(model.p_P_B[j].head<2>().norm(), 0.15, 1e-12) << "leg " << j;
  }
  // Base points come in pairs whose centres are 120° apart.
  for (int k = 0; k < 3; ++k) {
    const Eigen::Vector3d centre = model.p_B_A[2 * k] + model.p_B_A[2 * k + 1];
    const double angle_deg = std::atan2(centre.y(), centre.x()) * 180.0 / common::kPi;
    EXPECT_NEAR(std::remainder(angle_deg - 120.0 * k, 360.0), 0.0, 1e-9);
  }
  HexapodData data;
  const Reachability reach = InverseKinematics(model, HexapodModel::NominalPose(), &data);
  EXPECT_TRUE(reach.ok()) << reach.Describe(model, data.q);
  EXPECT_NEAR(HexapodModel::NominalPose().translation().z(), 0.40, 1e-15);
  // The symmetric layout gives equal leg lengths at the nominal pose.
  for (int j = 1; j < kHexapodLegs; ++j) EXPECT_NEAR(data.q[j], data.q[0], 1e-12);
}

TEST(HexapodModelTest, ValidateNamesEveryBadFieldWithItsValue) {
  HexapodModel model = HexapodModel::Default();
  model.leg_radius = -0.01;
  model.leg_length_min = 0.5;
  model.leg_length_max = 0.4;
  model.p_B_A[3].x() = std::nan("");
  model.p_P_B[4] = model.p_P_B[1];
  model.q0[5] = std::numeric_limits<double>::infinity();
  const std::string message = model.Validate();
  EXPECT_THAT(message, ContainsRegex("leg_radius = -0\\.01"));
  EXPECT_THAT(message, ContainsRegex("leg_length_max = 0\\.4 must be .*> leg_length_min = 0\\.5"));
  EXPECT_THAT(message, ContainsRegex("p_B_A\\[3\\] = \\(nan, 0\\.2298[0-9]*, 0\\) is not finite"));
  EXPECT_THAT(message, ContainsRegex("p_P_B\\[1\\] and p_P_B\\[4\\] coincide at \\(0\\.0964"));
  EXPECT_THAT(message, ContainsRegex("q0\\[5\\] = inf"));
  EXPECT_THAT(message, ::testing::Not(ContainsRegex("leg_length_min = 0\\.5 must")));
}

TEST(HexapodModelTest, ValidateRejectsNonPositiveMinimumLength) {
  HexapodModel model = HexapodModel::Default();
  model.leg_length_min = 0.0;
  EXPECT_THAT(model.Validate(), ContainsRegex("^leg_length_min = 0 must be finite and > 0$"));
}

TEST(HexapodModelTest, InverseKinematicsSatisfiesSeedEquation5) {
  const HexapodModel model = HexapodModel::Default();
  std::mt19937 rng(42);
  HexapodData data;
  for (const Eigen::Isometry3d& X_BP : RandomReachablePoses(model, 20, &rng)) {
    ASSERT_TRUE(InverseKinematics(model, X_BP, &data).ok());
    for (int j = 0; j < kHexapodLegs; ++j) {
      // q_j u_j = R p_P_Bj + t − p_B_Aj, |u_j| = 1, u_j from A_j towards B_j.
      const Eigen::Vector3d expected = X_BP * model.p_P_B[j] - model.p_B_A[j];
      EXPECT_LT((data.q[j] * data.u_B[j] - expected).norm(), 1e-14);
      EXPECT_NEAR(data.u_B[j].norm(), 1.0, 1e-14);
      EXPECT_GT(data.u_B[j].dot(data.p_B_B[j] - model.p_B_A[j]), 0.0);
    }
  }
}

TEST(HexapodModelTest, UnreachablePoseReportsTheOffendingLegIndex) {
  HexapodModel model = HexapodModel::Default();
  // Move only A_4 outward by 0.2 m: only leg 4 gets longer than the 0.55 m stroke.
  model.p_B_A[4] += 0.2 * model.p_B_A[4].normalized();
  ASSERT_THAT(model.Validate(), IsEmpty());
  HexapodData data;
  const Reachability reach = InverseKinematics(model, HexapodModel::NominalPose(), &data);
  EXPECT_FALSE(reach.ok());
  EXPECT_EQ(reach.FirstBadLeg(), 4);
  for (int j = 0; j < kHexapodLegs; ++j) {
    EXPECT_EQ(reach.legs[j], j == 4 ? LegReach::kTooLong : LegReach::kOk) << "leg " << j;
  }
  EXPECT_THAT(reach.Describe(model, data.q),
              ContainsRegex("^leg 4 too long \\(q = 0\\.5[6-9][0-9]* m, stroke \\[0\\.35, "
                            "0\\.55\\] m\\)$"));
}

TEST(HexapodModelTest, PlatformTooLowMakesEveryLegTooShort) {
  const HexapodModel model = HexapodModel::Default();
  Eigen::Isometry3d X_BP = HexapodModel::NominalPose();
  X_BP.translation().z() = 0.25;
  HexapodData data;
  const Reachability reach = InverseKinematics(model, X_BP, &data);
  EXPECT_EQ(reach.FirstBadLeg(), 0);
  for (int j = 0; j < kHexapodLegs; ++j) EXPECT_EQ(reach.legs[j], LegReach::kTooShort);
  EXPECT_THAT(reach.Describe(model, data.q), ContainsRegex("leg 5 too short"));
}

TEST(HexapodModelTest, ZeroLengthLegIsDegenerateWithZeroDirection) {
  const HexapodModel model = HexapodModel::Default();
  Eigen::Isometry3d X_BP = Eigen::Isometry3d::Identity();
  X_BP.translation() = model.p_B_A[2] - model.p_P_B[2];  // puts B_2 on A_2
  HexapodData data;
  const Reachability reach = InverseKinematics(model, X_BP, &data);
  EXPECT_EQ(reach.legs[2], LegReach::kDegenerate);
  EXPECT_EQ(data.u_B[2], Eigen::Vector3d::Zero());
  EXPECT_THAT(reach.Describe(model, data.q), ContainsRegex("leg 2 degenerate"));
}

TEST(HexapodModelTest, JointOffsetsConvertBetweenReadingsAndLengths) {
  HexapodModel model = HexapodModel::Default();
  for (int j = 0; j < kHexapodLegs; ++j) model.q0[j] = 0.3 + 0.01 * j;
  Vector6d s;
  s << 0.01, 0.02, 0.03, 0.04, 0.05, 0.06;
  const Vector6d q = LegLengthsFromJointPositions(model, s);
  for (int j = 0; j < kHexapodLegs; ++j) EXPECT_NEAR(q[j], 0.3 + 0.01 * j + s[j], 1e-15);
  EXPECT_LT((JointPositionsFromLegLengths(model, q) - s).norm(), 1e-15);
}

TEST(HexapodModelTest, ForwardKinematicsInvertsInverseKinematicsFromPerturbedGuess) {
  const HexapodModel model = HexapodModel::Default();
  std::mt19937 rng(7);
  const std::vector<Eigen::Isometry3d> poses = RandomReachablePoses(model, 100, &rng);
  ASSERT_EQ(poses.size(), 100u);
  std::uniform_real_distribution<double> offset(-0.01, 0.01);
  std::uniform_real_distribution<double> tilt(-0.03, 0.03);
  HexapodData data;
  for (const Eigen::Isometry3d& X_BP : poses) {
    InverseKinematics(model, X_BP, &data);
    const Vector6d q = data.q;
    Vector6d delta;
    delta << offset(rng), offset(rng), offset(rng), tilt(rng), tilt(rng), tilt(rng);
    const Eigen::Isometry3d guess = Perturb(X_BP, delta);
    const ForwardKinematicsSummary summary =
        ForwardKinematics(model, q, guess, ForwardKinematicsOptions{}, &data);
    ASSERT_TRUE(summary.converged()) << ToString(summary.status);
    EXPECT_GT(summary.iterations, 0);
    EXPECT_LE(summary.iterations, 10);
    EXPECT_LE(summary.residual, 1e-12);
    EXPECT_LT(summary.condition_number, 1e3);
    EXPECT_LT((summary.X_BP.translation() - X_BP.translation()).norm(), 1e-9);
    EXPECT_LT(RotationAngleBetween(summary.X_BP.linear(), X_BP.linear()), 1e-9);
    // *data describes the solution.
    EXPECT_LT((data.q - q).cwiseAbs().maxCoeff(), 1e-12);
    EXPECT_TRUE(data.reach.ok());
  }
}

// The symmetric 6-6 platform rotated by 90° about its vertical axis is in Fichter's singularity:
// D_inv loses rank. Newton must stop and say so rather than return a pose.
TEST(HexapodModelTest, ForwardKinematicsReportsSingularConfiguration) {
  const HexapodModel model = HexapodModel::Default();
  Eigen::Isometry3d singular = HexapodModel::NominalPose();
  singular.linear() =
      Eigen::AngleAxisd(common::kPi / 2, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  HexapodData data;
  InverseKinematics(model, singular, &data);
  EXPECT_GT(ConditionNumber(InverseDifferential(data)), 1e12);

  Eigen::Isometry3d target = singular;
  target.translation().z() += 0.002;
  InverseKinematics(model, target, &data);
  const Vector6d q = data.q;
  const ForwardKinematicsSummary summary =
      ForwardKinematics(model, q, singular, ForwardKinematicsOptions{}, &data);
  EXPECT_EQ(summary.status, ForwardKinematicsStatus::kSingular);
  EXPECT_FALSE(summary.converged());
  EXPECT_GT(summary.condition_number, 1e8);
  EXPECT_GT(summary.residual, 1e-4);
  EXPECT_EQ(summary.iterations, 0);
}

TEST(HexapodModelTest, ForwardKinematicsHonoursTheConditionNumberLimit) {
  const HexapodModel model = HexapodModel::Default();
  HexapodData data;
  Eigen::Isometry3d guess = HexapodModel::NominalPose();
  guess.linear() = Eigen::AngleAxisd(0.01, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  InverseKinematics(model, HexapodModel::NominalPose(), &data);
  const Vector6d q = data.q;
  ForwardKinematicsOptions options;
  options.max_condition_number = 5.0;  // below cond(D_inv) ≈ 13.8 at the nominal pose
  EXPECT_EQ(ForwardKinematics(model, q, guess, options, &data).status,
            ForwardKinematicsStatus::kSingular);
  options.max_condition_number = 1e8;
  EXPECT_EQ(ForwardKinematics(model, q, guess, options, &data).status,
            ForwardKinematicsStatus::kConverged);
}

// |A_0 A_1| = 0.104 m and |B_0 B_1| = 0.230 m, so q_1 <= q_0 + 0.334 m for every pose: lengths
// 0.1 m and 1.0 m have no solution and the residual cannot fall below 0.266 m.
TEST(HexapodModelTest, ForwardKinematicsReportsInconsistentLengthsAsNotConverged) {
  const HexapodModel model = HexapodModel::Default();
  Vector6d q = Vector6d::Constant(0.45);
  q[0] = 0.1;
  q[1] = 1.0;
  ForwardKinematicsOptions options;
  options.max_iterations = 30;
  HexapodData data;
  const ForwardKinematicsSummary summary =
      ForwardKinematics(model, q, HexapodModel::NominalPose(), options, &data);
  EXPECT_FALSE(summary.converged());
  EXPECT_TRUE(summary.status == ForwardKinematicsStatus::kMaxIterations ||
              summary.status == ForwardKinematicsStatus::kSingular)
      << ToString(summary.status);
  EXPECT_GT(summary.residual, 0.26);
  EXPECT_LE(summary.iterations, 30);
}

TEST(HexapodModelTest, ForwardKinematicsRejectsInvalidInput) {
  const HexapodModel model = HexapodModel::Default();
  HexapodData data;
  const Vector6d good = Vector6d::Constant(0.45);
  Vector6d nan_q = good;
  nan_q[3] = std::nan("");
  Vector6d negative_q = good;
  negative_q[2] = -0.1;
  const Eigen::Isometry3d guess = HexapodModel::NominalPose();
  EXPECT_EQ(ForwardKinematics(model, nan_q, guess, {}, &data).status,
            ForwardKinematicsStatus::kInvalidInput);
  EXPECT_EQ(ForwardKinematics(model, negative_q, guess, {}, &data).status,
            ForwardKinematicsStatus::kInvalidInput);
  EXPECT_FALSE(data.valid);
  ForwardKinematicsOptions bad;
  bad.max_iterations = 0;
  bad.residual_tolerance = -1.0;
  EXPECT_EQ(ForwardKinematics(model, good, guess, bad, &data).status,
            ForwardKinematicsStatus::kInvalidInput);
  EXPECT_THAT(bad.Validate(), ContainsRegex("max_iterations = 0 .*residual_tolerance = -1"));
  EXPECT_THAT(ForwardKinematicsOptions{}.Validate(), IsEmpty());
}

TEST(HexapodModelTest, InverseDifferentialMatchesCentralDifferencesOfInverseKinematics) {
  const HexapodModel model = HexapodModel::Default();
  std::mt19937 rng(2024);
  constexpr double kStep = 1e-6;
  HexapodData data;
  HexapodData plus;
  HexapodData minus;
  for (const Eigen::Isometry3d& X_BP : RandomReachablePoses(model, 30, &rng)) {
    InverseKinematics(model, X_BP, &data);
    const Matrix6d D_inv = InverseDifferential(data);
    Matrix6d numeric;
    for (int k = 0; k < 6; ++k) {
      const Vector6d step = kStep * Vector6d::Unit(k);
      InverseKinematics(model, Perturb(X_BP, step), &plus);
      InverseKinematics(model, Perturb(X_BP, -step), &minus);
      numeric.col(k) = (plus.q - minus.q) / (2 * kStep);
    }
    EXPECT_LE((numeric - D_inv).norm(), 1e-6 * D_inv.norm()) << "D_inv\n"
                                                             << D_inv << "\nnumeric\n"
                                                             << numeric;
  }
}

// Seed 002 eq. (7) writes row j as [u_jᵀ, (A_j × u_j)ᵀ] for a twist referred to the frame
// origin; moving the reference point from the B origin to the platform origin,
// v_P = v_O − [p_BP]× ω, must give the same rates.
TEST(HexapodModelTest, InverseDifferentialAgreesWithSeedFormReferredToBaseOrigin) {
  const HexapodModel model = HexapodModel::Default();
  std::mt19937 rng(5);
  HexapodData data;
  for (const Eigen::Isometry3d& X_BP : RandomReachablePoses(model, 10, &rng)) {
    InverseKinematics(model, X_BP, &data);
    Matrix6d seed_form;
    for (int j = 0; j < kHexapodLegs; ++j) {
      seed_form.block<1, 3>(j, 0) = data.u_B[j].transpose();
      seed_form.block<1, 3>(j, 3) = model.p_B_A[j].cross(data.u_B[j]).transpose();
    }
    Matrix6d shift = Matrix6d::Identity();
    shift.block<3, 3>(0, 3) = -common::Skew(X_BP.translation());
    EXPECT_LT((InverseDifferential(data) * shift - seed_form).norm(), 1e-12);
  }
}

TEST(HexapodModelTest, LegDirectionInteractionMatrixMatchesCentralDifferences) {
  const HexapodModel model = HexapodModel::Default();
  std::mt19937 rng(99);
  constexpr double kStep = 1e-6;
  HexapodData data;
  HexapodData plus;
  HexapodData minus;
  for (const Eigen::Isometry3d& X_BP : RandomReachablePoses(model, 30, &rng)) {
    InverseKinematics(model, X_BP, &data);
    for (int j = 0; j < kHexapodLegs; ++j) {
      const Matrix36d L = LegDirectionInteractionMatrix(data, j);
      Matrix36d numeric;
      for (int k = 0; k < 6; ++k) {
        const Vector6d step = kStep * Vector6d::Unit(k);
        InverseKinematics(model, Perturb(X_BP, step), &plus);
        InverseKinematics(model, Perturb(X_BP, -step), &minus);
        numeric.col(k) = (plus.u_B[j] - minus.u_B[j]) / (2 * kStep);
      }
      EXPECT_LE((numeric - L).norm(), 1e-6 * L.norm()) << "leg " << j;
      // u̇ stays orthogonal to u (unit norm preserved).
      EXPECT_LT((data.u_B[j].transpose() * L).norm(), 1e-12);
    }
  }
}

TEST(HexapodModelTest, LegDirectionInteractionMatrixInCameraMatchesCentralDifferences) {
  const HexapodModel model = HexapodModel::Default();
  std::mt19937 rng(1234);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  constexpr double kStep = 1e-6;
  HexapodData data;
  HexapodData plus;
  HexapodData minus;
  for (const Eigen::Isometry3d& X_BP : RandomReachablePoses(model, 20, &rng)) {
    Eigen::Isometry3d X_CB = Eigen::Isometry3d::Identity();
    const Eigen::Vector3d axis = Eigen::Vector3d(unit(rng), unit(rng), unit(rng)).normalized();
    X_CB.linear() = Eigen::AngleAxisd(common::kPi * unit(rng), axis).toRotationMatrix();
    X_CB.translation() = Eigen::Vector3d(unit(rng), unit(rng), unit(rng));
    const Eigen::Matrix3d R_CB = X_CB.linear();
    Matrix6d twist_B_from_C = Matrix6d::Zero();
    twist_B_from_C.block<3, 3>(0, 0) = R_CB.transpose();
    twist_B_from_C.block<3, 3>(3, 3) = R_CB.transpose();
    InverseKinematics(model, X_BP, &data);
    for (int j = 0; j < kHexapodLegs; ++j) {
      const Matrix36d L_C = LegDirectionInteractionMatrixInCamera(data, j, X_CB);
      Matrix36d numeric;
      for (int k = 0; k < 6; ++k) {
        const Vector6d step_B = twist_B_from_C * (kStep * Vector6d::Unit(k));
        InverseKinematics(model, Perturb(X_BP, step_B), &plus);
        InverseKinematics(model, Perturb(X_BP, -step_B), &minus);
        numeric.col(k) = R_CB * (plus.u_B[j] - minus.u_B[j]) / (2 * kStep);
      }
      EXPECT_LE((numeric - L_C).norm(), 1e-6 * L_C.norm()) << "leg " << j;
      // The camera form differs from the base form unless R_CB is the identity.
      EXPECT_GT((L_C - LegDirectionInteractionMatrix(data, j)).norm(), 1e-3);
    }
  }
}

// Seed 002 eq. (9), re-derived for a twist referred to the camera (here B) origin:
// L = (I − u uᵀ)/q [I, −[A_j + q_j u_j]×]. It must equal our form after the reference shift.
TEST(HexapodModelTest, LegDirectionInteractionMatrixAgreesWithSeedFormReferredToBaseOrigin) {
  const HexapodModel model = HexapodModel::Default();
  std::mt19937 rng(11);
  HexapodData data;
  for (const Eigen::Isometry3d& X_BP : RandomReachablePoses(model, 10, &rng)) {
    InverseKinematics(model, X_BP, &data);
    Matrix6d shift = Matrix6d::Identity();
    shift.block<3, 3>(0, 3) = -common::Skew(X_BP.translation());
    for (int j = 0; j < kHexapodLegs; ++j) {
      const Eigen::Vector3d& u = data.u_B[j];
      const Eigen::Matrix3d projector =
          (Eigen::Matrix3d::Identity() - u * u.transpose()) / data.q[j];
      Matrix36d seed_form;
      seed_form.leftCols<3>() = projector;
      seed_form.rightCols<3>() = -projector * common::Skew(model.p_B_A[j] + data.q[j] * u);
      EXPECT_LT((LegDirectionInteractionMatrix(data, j) * shift - seed_form).norm(), 1e-12);
    }
  }
}

TEST(HexapodModelTest, KinematicsDoNotAllocateOnTheHeap) {
  const HexapodModel model = HexapodModel::Default();
  HexapodData data;
  Eigen::Isometry3d X_CB = Eigen::Isometry3d::Identity();
  X_CB.linear() = Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitX()).toRotationMatrix();
  Eigen::Isometry3d guess = HexapodModel::NominalPose();
  guess.translation().x() += 0.005;
  InverseKinematics(model, HexapodModel::NominalPose(), &data);
  const Vector6d q = data.q;
  const ForwardKinematicsOptions options;

  const long before = kinevis::testing::ThreadAllocations();
  const bool reachable = InverseKinematics(model, HexapodModel::NominalPose(), &data).ok();
  const double condition = ConditionNumber(InverseDifferential(data));
  const Matrix36d L = LegDirectionInteractionMatrix(data, 1);
  const Matrix36d L_C = LegDirectionInteractionMatrixInCamera(data, 1, X_CB);
  const ForwardKinematicsSummary summary = ForwardKinematics(model, q, guess, options, &data);
  const long allocations = kinevis::testing::ThreadAllocations() - before;

  EXPECT_EQ(allocations, 0);
  // ...and the counter does see allocations made by the library.
  ForwardKinematicsOptions bad;
  bad.max_iterations = -1;
  const long before_validate = kinevis::testing::ThreadAllocations();
  const std::string message = bad.Validate();
  EXPECT_GT(kinevis::testing::ThreadAllocations() - before_validate, 0);
  EXPECT_THAT(message, ContainsRegex("max_iterations = -1"));
  // The calls above did real work (and were not optimised away).
  EXPECT_TRUE(reachable);
  EXPECT_NEAR(condition, 13.8, 0.1);
  EXPECT_GT(L.norm(), 0.0);
  EXPECT_GT(L_C.norm(), 0.0);
  EXPECT_TRUE(summary.converged());
}

TEST(HexapodModelDeathTest, JacobiansRequireInverseKinematicsFirst) {
  const HexapodData fresh;
  EXPECT_DEATH(InverseDifferential(fresh), "data.valid");
  HexapodData data;
  InverseKinematics(HexapodModel::Default(), HexapodModel::NominalPose(), &data);
  EXPECT_DEATH(LegDirectionInteractionMatrix(data, 6), "leg >= 0 && leg < kHexapodLegs");
}

}  // namespace
}  // namespace kinevis::robots
