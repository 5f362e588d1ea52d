#include "calibration/weld_mount/scan_cloud.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <filesystem>

#include "vision/cloud/cloud_sidecar.h"

namespace kinevis::calibration {
namespace {

robots::Weld5Model Robot() {
  return robots::Weld5Model::Seed(robots::Weld5TorchTransform(0.025, 0.250, 0.0));
}

Eigen::Isometry3d Mount() {
  return Eigen::Translation3d(-0.05, -0.06, 0.10) *
         Eigen::AngleAxisd(0.01, Eigen::Vector3d(1, -2, 3).normalized());
}

TEST(ScansToCloud, MapsEveryPointThroughForwardKinematicsAndTheMount) {
  const robots::Weld5Model robot = Robot();
  std::vector<ScanLine> lines(3);
  for (int l = 0; l < 3; ++l) {
    lines[l].q << 0.1 * l, 0.05, 0.2, -0.1, 0.3 * l;
    for (int i = 0; i < 10; ++i) lines[l].p_C.emplace_back(0.001 * i, 0.002 * l, 0.4);
  }
  const ScanCloud c = ScansToCloud(robot, Mount(), lines);
  ASSERT_EQ(c.cloud.size(), 30u);
  EXPECT_EQ(c.line_offsets, (std::vector<std::size_t>{0, 10, 20, 30}));
  for (int l = 0; l < 3; ++l) {
    robots::Weld5Data data;
    Weld5ForwardKinematics(robot, lines[l].q, &data);
    // X_0T = X_05 · X_5T, so X_05 = X_0T · X_5T⁻¹ (independent of the scan-cloud code path).
    const Eigen::Isometry3d X_0C = data.X_0T * robot.X_5T.inverse() * Mount();
    EXPECT_LT((c.viewpoints_0[l].cast<double>() - X_0C.translation()).norm(), 1e-7);
    for (int i = 0; i < 10; ++i) {
      const Eigen::Vector3d expected = X_0C * lines[l].p_C[i];
      EXPECT_LT((c.cloud.points[10 * l + i].cast<double>() - expected).norm(), 1e-7);
    }
  }
}

TEST(ScansToCloud, NormalsOfAScannedPlaneFaceTheScanner) {
  // The scanner moves sideways over a plane 0.4 m ahead (constant joints except θ1, small steps):
  // stripes of points on the plane z_C = 0.4 of the first pose.
  const robots::Weld5Model robot = Robot();
  robots::Vector5d q0;
  q0 << 0.0, 0.0, 0.2, 0.0, 0.0;
  const Eigen::Isometry3d X_0C0 = robots::DhForwardKinematics(robot.joints, q0) * Mount();
  std::vector<ScanLine> lines;
  for (int l = 0; l < 30; ++l) {
    ScanLine line;
    line.q = q0;
    line.q(0) = 1e-3 * l;
    const Eigen::Isometry3d X_C0C =
        X_0C0.inverse() * robots::DhForwardKinematics(robot.joints, line.q) * Mount();
    // The stripe: the line y_C = 0 of this pose's camera, intersected with the first pose's
    // plane z_C0 = 0.4.
    for (int i = 0; i < 60; ++i) {
      const Eigen::Vector3d d = X_C0C.linear() * Eigen::Vector3d(-0.03 + 0.001 * i, 0.0, 1.0);
      const Eigen::Vector3d o = X_C0C.translation();
      const double t = (0.4 - o.z()) / d.z();
      line.p_C.push_back(X_C0C.inverse() * (o + t * d));
      line.confidence.push_back(0.9f);
    }
    lines.push_back(line);
  }
  ScanCloudOptions options;
  options.normals.radius = 4e-3;
  const ScanCloud c = ScansToCloud(robot, Mount(), lines, options);
  EXPECT_EQ(c.normals.missing, 0u);
  EXPECT_EQ(c.cloud.confidence.size(), c.cloud.size());
  const Eigen::Vector3d n_expected = -X_0C0.linear().col(2);  // towards the camera
  for (const Eigen::Vector3f& n : c.cloud.normals) {
    EXPECT_GT(n.cast<double>().dot(n_expected), std::cos(0.05 * M_PI / 180.0));
  }

  const std::string path =
      (std::filesystem::temp_directory_path() / "kinevis_scan_cloud_test.yaml").string();
  vision::cloud::CloudSidecar sidecar =
      MakeCloudSidecar(robot, "nominal seed", Mount(), "mount.yaml", lines.size());
  sidecar.ply = "kinevis_scan_cloud_test.ply";
  vision::cloud::WriteCloud(path, c.cloud, sidecar);
  vision::cloud::CloudSidecar read;
  const vision::cloud::PointCloud back = vision::cloud::ReadCloud(path, &read);
  EXPECT_EQ(back.size(), c.cloud.size());
  EXPECT_EQ(read.scan_lines, 30u);
  EXPECT_EQ(read.robot_dh.size(), 5u);
  EXPECT_TRUE(read.X_5C.isApprox(Mount(), 1e-12));
}

TEST(ScansToCloud, RefusesBadLinesNamingThem) {
  std::vector<ScanLine> lines(2);
  lines[0].p_C = {Eigen::Vector3d(0, 0, 0.4)};
  lines[1].p_C = {Eigen::Vector3d(0, 0, 0.4), Eigen::Vector3d(0, std::nan(""), 0.4)};
  try {
    ScansToCloud(Robot(), Mount(), lines);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), ::testing::HasSubstr("line 1: point 1 not finite"));
  }
  lines[1].p_C.pop_back();
  lines[0].confidence = {0.5f};
  EXPECT_THROW(ScansToCloud(Robot(), Mount(), lines), std::invalid_argument);  // 1 of 2 lines
  lines[1].confidence = {1.5f};
  EXPECT_THROW(ScansToCloud(Robot(), Mount(), lines), std::invalid_argument);
  Eigen::Isometry3d bad = Mount();
  bad.linear() *= 2.0;
  EXPECT_THROW(ScansToCloud(Robot(), bad, {}), std::invalid_argument);
}

}  // namespace
}  // namespace kinevis::calibration
