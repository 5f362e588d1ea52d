// The scanner-mount measurement plan (calibration/weld_mount/mount_plan.h): every planned touch
// lies on the feature it names, the approach axes come from outside the block, the aim puts the
// point on the optical axis, and bad plan sizes are refused by name.

#include "calibration/weld_mount/mount_plan.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <set>
#include <stdexcept>
#include <string>

#include "sim/weld_cell_world.h"

namespace kinevis::calibration {
namespace {

TEST(MountPlan, EveryTouchLiesOnTheFeatureItNames) {
  const std::vector<PlannedTouch> plan = MountTouchPlan();
  ASSERT_EQ(plan.size(), 14u);
  int equations = 0;
  std::set<std::string> sides;
  for (const PlannedTouch& t : plan) {
    const BlockFeature f = BlockFeature::Parse(t.feature);
    equations += f.Equations();
    for (int k = 0; k < 3; ++k) {
      if (f.sign(k) != 0) {
        // On the plane the feature fixes: p_B[k] = s_k h_k.
        EXPECT_EQ(t.fraction(k), f.sign(k)) << t.feature << " axis " << k;
      } else if (f.sign.z() < 0 && k < 2) {
        // A board point lies outside the block's footprint.
        EXPECT_TRUE(std::abs(t.fraction.x()) > 1.0 || std::abs(t.fraction.y()) > 1.0) << t.feature;
      } else {
        // Strictly inside the face (not on one of its edges).
        EXPECT_LT(std::abs(t.fraction(k)), 1.0) << t.feature << " axis " << k;
      }
    }
    sides.insert(t.feature);
  }
  EXPECT_EQ(equations, 17);
  // Each of the block's five visible faces and the board is touched.
  for (const char* face : {"top", "board", "+x", "-x", "+y", "-y"})
    EXPECT_EQ(sides.count(face), 1u);
  EXPECT_EQ(MountTouchPlan(false).size(), 6u);
}

TEST(MountPlan, ApproachAxesComeFromOutsideTheFaceMostHeadOnFirst) {
  const Eigen::Matrix3d R_0B(Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ()));
  for (const char* feature : {"top", "board", "+x", "-y", "+x+z"}) {
    const Eigen::Vector3d n_0 = TouchApproachNormal(BlockFeature::Parse(feature), R_0B);
    EXPECT_NEAR(n_0.norm(), 1.0, 1e-12);
    const std::vector<Eigen::Vector3d> axes = TouchApproachAxes(n_0);
    ASSERT_FALSE(axes.empty()) << feature;
    for (size_t k = 0; k < axes.size(); ++k) {
      EXPECT_NEAR(axes[k].norm(), 1.0, 1e-12);
      EXPECT_LE(axes[k].dot(n_0), 0.3 + 1e-12) << feature;
      if (k > 0) {
        EXPECT_LE(axes[k - 1].dot(n_0), axes[k].dot(n_0)) << feature;
      }
    }
  }
  // A board touch is approached from above the board, not from below it.
  const Eigen::Vector3d n_board = TouchApproachNormal(BlockFeature::Parse("board"), R_0B);
  EXPECT_NEAR(n_board.z(), 1.0, 1e-12);
}

TEST(MountPlan, AimPutsThePointOnTheOpticalAxisTurningOnlyTheFirstTwoJoints) {
  const sim::WeldCellWorldConfig config;
  const Eigen::Isometry3d X_5C = sim::NominalScannerMount();
  const auto X_0C = [&](const robots::Vector5d& q) -> Eigen::Isometry3d {
    return robots::DhForwardKinematics(config.nominal.joints, q) * X_5C;
  };
  robots::Vector5d home;
  for (int i = 0; i < 5; ++i) home(i) = config.initial_joints[static_cast<size_t>(i)];
  for (const Eigen::Vector2d& wrist : MountViewPlan(kMaxMountViews)) {
    robots::Vector5d q = home;
    q(3) += wrist.x();
    q(4) = wrist.y();
    // A point ~0.4 m in front of the camera but 3 cm off its axis.
    const Eigen::Vector3d p_0 = X_0C(q) * Eigen::Vector3d(0.03, -0.02, 0.4);
    const robots::Vector5d aimed = AimOpticalAxisAt(X_0C, p_0, q);
    const Eigen::Vector3d p_C = X_0C(aimed).inverse() * p_0;
    EXPECT_GT(p_C.z(), 0.3);
    EXPECT_LT(std::hypot(p_C.x(), p_C.y()) / p_C.z(), 1e-8) << wrist.transpose();
    EXPECT_EQ(aimed.tail<3>(), q.tail<3>());
  }
}

TEST(MountPlan, ViewCountsOutsideThePlanAreRefusedByName) {
  EXPECT_EQ(MountViewPlan(7).size(), 7u);
  EXPECT_EQ(MountLaserAngles().size(), 3u);
  for (int bad : {0, -1, kMaxMountViews + 1}) {
    try {
      MountViewPlan(bad);
      ADD_FAILURE() << bad;
    } catch (const std::invalid_argument& e) {
      EXPECT_THAT(e.what(),
                  ::testing::HasSubstr("views: must be in [1, 12], got " + std::to_string(bad)));
    }
  }
}

}  // namespace
}  // namespace kinevis::calibration
