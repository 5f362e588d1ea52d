#include "calibration/hexapod/pose_planner.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "common/units.h"
#include "vision/camera/pinhole_camera.h"
#include "vision/render/scenes/hexapod_scene.h"

namespace kinevis::calibration {
namespace {

using ::testing::HasSubstr;
using ::testing::IsEmpty;

const PosePlan& DefaultPlan() {
  static const PosePlan plan = [] {
    PosePlannerOptions o;
    o.X_CB =
        vision::render::CameraLookingAt(Eigen::Vector3d(0.2, -1.25, 0.45),
                                        Eigen::Vector3d(0.0, 0.0, 0.25), Eigen::Vector3d::UnitZ())
            .inverse();
    return PlanCalibrationPoses(robots::HexapodModel::Default(), o);
  }();
  return plan;
}

// Random admissible poses (uniform in a box around the nominal pose, rejection sampled): what an
// operator jogging the robot "somewhere different each time" would record.
std::vector<Eigen::Isometry3d> RandomPoses(int count, uint32_t seed) {
  const robots::HexapodModel model = robots::HexapodModel::Default();
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> t(-0.12, 0.12), r(-0.5, 0.5);
  std::vector<Eigen::Isometry3d> poses;
  const PosePlannerOptions o;
  while (static_cast<int>(poses.size()) < count) {
    Eigen::Isometry3d X = robots::HexapodModel::NominalPose();
    X.translation() += Eigen::Vector3d(t(rng), t(rng), t(rng));
    const Eigen::Vector3d w(r(rng), r(rng), r(rng));
    X.linear() = Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix();
    if (PoseIsAdmissible(model, X, o)) poses.push_back(X);
  }
  return poses;
}

TEST(PosePlannerTest, PlansTheRequestedReachableCollisionFreePoses) {
  const robots::HexapodModel model = robots::HexapodModel::Default();
  const PosePlan& plan = DefaultPlan();
  const PosePlannerOptions o;
  ASSERT_EQ(plan.X_BP.size(), 60u);
  ASSERT_EQ(plan.q.size(), 60u);
  EXPECT_THAT(plan.warnings, IsEmpty());
  EXPECT_EQ(plan.candidates_tried, o.candidates);
  EXPECT_GT(plan.candidates_admissible, 1000);
  robots::HexapodData data;
  int on_a_limit = 0;
  for (size_t k = 0; k < plan.X_BP.size(); ++k) {
    ASSERT_TRUE(robots::InverseKinematics(model, plan.X_BP[k], &data).ok()) << k;
    EXPECT_TRUE(data.q.isApprox(plan.q[k], 1e-12));
    for (int j = 0; j < robots::kHexapodLegs; ++j) {
      EXPECT_GE(data.q(j), model.leg_length_min + o.stroke_margin - 1e-12);
      EXPECT_LE(data.q(j), model.leg_length_max - o.stroke_margin + 1e-12);
      for (int i = j + 1; i < robots::kHexapodLegs; ++i) {
        EXPECT_GT(
            SegmentSegmentDistance(model.p_B_A[j], data.p_B_B[j], model.p_B_A[i], data.p_B_B[i]),
            2 * model.leg_radius + o.collision_margin)
            << "pose " << k << " legs " << j << ", " << i;
      }
    }
    EXPECT_LE(robots::ConditionNumber(robots::InverseDifferential(data)), o.max_jacobian_condition);
    // "On the workspace limits": a leg at a stroke end, or legs nearly touching, or a singularity.
    const double to_stroke = std::min((data.q.array() - model.leg_length_min).minCoeff(),
                                      (model.leg_length_max - data.q.array()).minCoeff());
    if (to_stroke < o.stroke_margin + 1e-3) ++on_a_limit;
  }
  EXPECT_GE(on_a_limit, 50);
}

TEST(PosePlannerTest, IsDeterministicForASeedAndChangesWithIt) {
  PosePlannerOptions o;
  o.poses = 10;
  o.candidates = 200;
  const robots::HexapodModel model = robots::HexapodModel::Default();
  const PosePlan a = PlanCalibrationPoses(model, o), b = PlanCalibrationPoses(model, o);
  ASSERT_EQ(a.X_BP.size(), b.X_BP.size());
  for (size_t k = 0; k < a.X_BP.size(); ++k) EXPECT_EQ(a.X_BP[k].matrix(), b.X_BP[k].matrix());
  o.seed = 2;
  const PosePlan c = PlanCalibrationPoses(model, o);
  EXPECT_NE(a.X_BP[0].matrix(), c.X_BP[0].matrix());
}

TEST(PosePlannerTest, SpreadsEveryLegsDirectionMoreThanRandomPoses) {
  const PosePlan& plan = DefaultPlan();
  const Eigen::Isometry3d camera =
      vision::render::CameraLookingAt(Eigen::Vector3d(0.2, -1.25, 0.45),
                                      Eigen::Vector3d(0.0, 0.0, 0.25), Eigen::Vector3d::UnitZ())
          .inverse();
  const robots::HexapodModel model = robots::HexapodModel::Default();
  for (uint32_t seed : {1u, 2u, 3u}) {
    const auto random = EvaluatePoseSpread(model, RandomPoses(60, seed), camera);
    for (int j = 0; j < robots::kHexapodLegs; ++j) {
      EXPECT_GT(plan.legs[j].max_angle, random[j].max_angle) << "leg " << j;
      EXPECT_GT(plan.legs[j].direction_spread, 1.5 * random[j].direction_spread) << "leg " << j;
      EXPECT_LT(plan.legs[j].condition_number, random[j].condition_number) << "leg " << j;
    }
  }
  for (int j = 0; j < robots::kHexapodLegs; ++j) {
    std::printf("leg %d: max angle %.1f deg, direction spread %.4f, cond(eq. 14) %.1f\n", j,
                plan.legs[j].max_angle * 180 / common::kPi, plan.legs[j].direction_spread,
                plan.legs[j].condition_number);
    EXPECT_GT(plan.legs[j].max_angle, 20.0 * common::kPi / 180.0);
  }
}

TEST(PosePlannerTest, TheCallersPredicateIsRespected) {
  PosePlannerOptions o;
  o.poses = 15;
  o.candidates = 300;
  o.admissible = [](const Eigen::Isometry3d& X_BP) { return X_BP.translation().x() <= 0.01; };
  const PosePlan plan = PlanCalibrationPoses(robots::HexapodModel::Default(), o);
  ASSERT_EQ(plan.X_BP.size(), 15u);
  for (const auto& X : plan.X_BP) EXPECT_LE(X.translation().x(), 0.01);
  // A predicate that refuses everything but the nominal pose leaves nothing to plan.
  o.admissible = [](const Eigen::Isometry3d& X_BP) {
    return X_BP.isApprox(robots::HexapodModel::NominalPose());
  };
  const PosePlan none = PlanCalibrationPoses(robots::HexapodModel::Default(), o);
  EXPECT_TRUE(none.X_BP.empty());
  ASSERT_FALSE(none.warnings.empty());
  EXPECT_THAT(none.warnings[0], HasSubstr("no admissible candidate"));
}

TEST(PosePlannerTest, BadOptionsModelAndNominalPoseAreRefused) {
  PosePlannerOptions o;
  o.poses = 1;
  o.candidates = 0;
  o.translation_scale = -1;
  o.collision_margin = NAN;
  const std::string message = o.Validate();
  for (const char* s :
       {"poses: must be >= 2, got 1", "candidates: must be >= poses, got 0",
        "translation_scale: must be finite and > 0, got -1", "collision_margin: "}) {
    EXPECT_THAT(message, HasSubstr(s));
  }
  EXPECT_THROW(PlanCalibrationPoses(robots::HexapodModel::Default(), o), std::invalid_argument);
  PosePlannerOptions far;
  far.X_BP_nominal.translation().z() = 2.0;  // legs far too long
  try {
    PlanCalibrationPoses(robots::HexapodModel::Default(), far);
    ADD_FAILURE();
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr("X_BP_nominal is not admissible"));
  }
  robots::HexapodModel bad = robots::HexapodModel::Default();
  bad.leg_radius = 0;
  EXPECT_THROW(PlanCalibrationPoses(bad, PosePlannerOptions{}), std::invalid_argument);
}

TEST(PosePlannerTest, SegmentDistanceMatchesDenseSampling) {
  std::mt19937 rng(9);
  std::normal_distribution<double> g(0.0, 1.0);
  for (int trial = 0; trial < 200; ++trial) {
    Eigen::Vector3d p0(g(rng), g(rng), g(rng)), p1(g(rng), g(rng), g(rng));
    Eigen::Vector3d q0(g(rng), g(rng), g(rng)), q1(g(rng), g(rng), g(rng));
    if (trial % 4 == 0) q1 = q0 + (p1 - p0) * 0.7;  // parallel
    if (trial % 7 == 0) p1 = p0;                    // a point
    double brute = 1e9;
    constexpr int kN = 400;
    for (int i = 0; i <= kN; ++i) {
      const Eigen::Vector3d p = p0 + (p1 - p0) * (double(i) / kN);
      // Distance from a point to a segment, exactly.
      const Eigen::Vector3d d = q1 - q0;
      const double t =
          d.squaredNorm() > 0 ? std::clamp((p - q0).dot(d) / d.squaredNorm(), 0.0, 1.0) : 0.0;
      brute = std::min(brute, (p - (q0 + t * d)).norm());
    }
    const double exact = SegmentSegmentDistance(p0, p1, q0, q1);
    EXPECT_LE(exact, brute + 1e-12) << trial;
    EXPECT_GE(exact, brute - 3.0 * (p1 - p0).norm() / kN) << trial;
  }
}

// AllLegsInView against the camera's own projection, worked by hand: a pinhole 1.5 m in front of
// the robot looking at it sees every leg; turned round (looking away) it sees none; a margin
// larger than half the image admits nothing; a camera far to the side with a narrow view loses
// the legs at the image's edge.
TEST(PosePlanner, AllLegsInViewIsWhatTheCameraProjectsInsideTheMargin) {
  const robots::HexapodModel model = robots::HexapodModel::Default();
  const Eigen::Isometry3d X_BP = model.NominalPose();
  vision::PinholeBrownParameters p;
  p.width = 1024;
  p.height = 780;
  p.fx = p.fy = 700.0;
  p.cx = 511.5;
  p.cy = 389.5;
  const vision::PinholeBrownCamera camera(p);
  const Eigen::Vector3d target(0.0, 0.0, 0.2);
  const Eigen::Isometry3d X_CB = vision::render::CameraLookingAt(Eigen::Vector3d(0.0, -1.5, 0.6),
                                                                 target, Eigen::Vector3d::UnitZ())
                                     .inverse();
  EXPECT_TRUE(AllLegsInView(model, camera, X_CB, X_BP));
  const Eigen::Isometry3d X_CB_away =
      vision::render::CameraLookingAt(Eigen::Vector3d(0.0, -1.5, 0.6),
                                      Eigen::Vector3d(0.0, -3.0, 0.6), Eigen::Vector3d::UnitZ())
          .inverse();
  EXPECT_FALSE(AllLegsInView(model, camera, X_CB_away, X_BP));
  EXPECT_FALSE(AllLegsInView(model, camera, X_CB, X_BP, 400.0));
  // Aimed 0.5 m beside the robot from 0.8 m: the nearest legs fall outside the 1024 px width.
  const Eigen::Isometry3d X_CB_aside =
      vision::render::CameraLookingAt(Eigen::Vector3d(0.5, -0.8, 0.3),
                                      Eigen::Vector3d(0.5, 0.0, 0.3), Eigen::Vector3d::UnitZ())
          .inverse();
  EXPECT_FALSE(AllLegsInView(model, camera, X_CB_aside, X_BP));
}

}  // namespace
}  // namespace kinevis::calibration
