#include "calibration/hexapod/hexapod_calibration_io.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <random>
#include <string>
#include <vector>

#include "calibration/hexapod/pose_planner.h"
#include "calibration/hexapod/reprojection_image.h"
#include "tests/utilities/version_one_file.h"
#include "vision/camera/pinhole_camera.h"
#include "vision/render/scenes/hexapod_scene.h"

namespace kinevis::calibration {
namespace {

using ::testing::AllOf;
using ::testing::HasSubstr;

std::string TempPath(const std::string& name) {
  return (std::filesystem::temp_directory_path() /
          ("kinevis_hcal_" + std::to_string(::getpid()) + "_" + name))
      .string();
}

Eigen::Isometry3d CameraPose() {
  return vision::render::CameraLookingAt(Eigen::Vector3d(0.2, -1.25, 0.45),
                                         Eigen::Vector3d(0.0, 0.0, 0.25), Eigen::Vector3d::UnitZ())
      .inverse();
}

// A result with every field populated: noisy normals with outliers (down-weighted entries), and a
// leg dropped so that a status, NaNs and an error are in the file too.
HexapodCalibrationResult SomeResult() {
  robots::HexapodModel truth = robots::HexapodModel::Default();
  truth.p_B_A[1] += Eigen::Vector3d(0.003, -0.002, 0.001);
  PosePlannerOptions po;
  po.poses = 30;
  po.candidates = 300;
  HexapodCalibrationData data =
      PredictCalibrationData(truth, CameraPose(), PlanCalibrationPoses(truth, po).X_BP);
  std::mt19937 rng(4);
  std::normal_distribution<double> g(0.0, 3e-4);
  for (auto& c : data.configurations) {
    for (auto& l : c) {
      if (!l) continue;
      l->n1_C = (l->n1_C + Eigen::Vector3d(g(rng), g(rng), g(rng))).normalized();
      l->n2_C = (l->n2_C + Eigen::Vector3d(g(rng), g(rng), g(rng))).normalized();
    }
  }
  data.configurations[3][2]->n1_C = data.configurations[3][0]->n1_C;  // an outlier
  for (size_t k = 1; k < data.configurations.size(); ++k) data.configurations[k][5].reset();
  return CalibrateHexapod(data, robots::HexapodModel::Default());
}

TEST(HexapodCalibrationIoTest, RoundTripKeepsEveryValue) {
  const HexapodCalibrationResult r = SomeResult();
  ASSERT_FALSE(r.down_weighted.empty());
  ASSERT_FALSE(r.errors.empty());
  HexapodCalibrationMetadata m{"hexapod-perspective", "2024-05-01T12:00:00Z",
                               "robots/hexapod/hexapod.yaml", "synthetic"};
  const std::string path = TempPath("roundtrip.yaml");
  WriteHexapodCalibration(path, r, m);
  const HexapodCalibrationFile f = ReadHexapodCalibration(path);
  EXPECT_EQ(f.metadata.camera, m.camera);
  EXPECT_EQ(f.metadata.created, m.created);
  EXPECT_EQ(f.metadata.robot, m.robot);
  EXPECT_EQ(f.metadata.source, m.source);
  const HexapodCalibrationResult& q = f.result;
  EXPECT_EQ(q.leg_radius, r.leg_radius);
  EXPECT_EQ(q.configurations, r.configurations);
  EXPECT_EQ(q.loss, r.loss);
  for (int j = 0; j < robots::kHexapodLegs; ++j) {
    const LegCalibration &a = r.legs[j], &b = q.legs[j];
    EXPECT_EQ(a.status, b.status) << j;
    if (a.status == LegStatus::kEstimated) {
      EXPECT_EQ(a.p_C_A, b.p_C_A) << j;  // 17 significant digits: exact
      EXPECT_EQ(a.covariance, b.covariance) << j;
      EXPECT_EQ(a.sigma, b.sigma) << j;
      EXPECT_EQ(a.rigid_fit_residual, b.rigid_fit_residual) << j;
    } else {
      EXPECT_TRUE(std::isnan(b.p_C_A.x()));
      EXPECT_TRUE(std::isnan(b.rigid_fit_residual));
    }
    EXPECT_EQ(a.condition_number, b.condition_number) << j;
    EXPECT_EQ(a.configurations, b.configurations);
    EXPECT_EQ(a.equations, b.equations);
    EXPECT_EQ(a.down_weighted, b.down_weighted);
    EXPECT_EQ(a.residual_rms, b.residual_rms);
    EXPECT_EQ(a.residual_max, b.residual_max);
    EXPECT_EQ(a.robust_scale, b.robust_scale);
  }
  EXPECT_EQ(q.rigid_fit, r.rigid_fit);
  EXPECT_TRUE(q.X_CB.isApprox(r.X_CB, 1e-15));
  EXPECT_EQ(q.rigid_fit_rms, r.rigid_fit_rms);
  EXPECT_EQ(q.scale, r.scale);
  EXPECT_EQ(q.scale_estimator, r.scale_estimator);
  EXPECT_EQ(q.scale_max_ratio, r.scale_max_ratio);
  EXPECT_EQ(q.scale_median_ratio, r.scale_median_ratio);
  EXPECT_EQ(q.scale_corrected, r.scale_corrected);
  ASSERT_EQ(q.down_weighted.size(), r.down_weighted.size());
  for (size_t i = 0; i < r.down_weighted.size(); ++i) {
    EXPECT_EQ(q.down_weighted[i].configuration, r.down_weighted[i].configuration);
    EXPECT_EQ(q.down_weighted[i].leg, r.down_weighted[i].leg);
    EXPECT_EQ(q.down_weighted[i].limb, r.down_weighted[i].limb);
    EXPECT_EQ(q.down_weighted[i].residual, r.down_weighted[i].residual);
    EXPECT_EQ(q.down_weighted[i].weight, r.down_weighted[i].weight);
  }
  EXPECT_EQ(q.errors, r.errors);
  EXPECT_EQ(q.warnings, r.warnings);
  // The estimator contract's block.
  EXPECT_EQ(q.estimation.status, r.estimation.status);
  ASSERT_EQ(q.estimation.parameters.size(), 18u);
  EXPECT_EQ(q.estimation.Find("leg2.p_C_A.z")->sigma, r.estimation.Find("leg2.p_C_A.z")->sigma);
  EXPECT_EQ(q.estimation.covariance, r.estimation.covariance);

  // A version 1 file (before the contract) reads, its report rebuilt from the legs.
  kinevis::testing::RewriteAsVersionOne(path);
  const HexapodCalibrationFile old = ReadHexapodCalibration(path);
  EXPECT_EQ(old.result.estimation.Validate(), "");
  EXPECT_EQ(old.result.estimation.status, r.estimation.status);
  EXPECT_NEAR(old.result.estimation.Find("leg2.p_C_A.z")->sigma,
              r.estimation.Find("leg2.p_C_A.z")->sigma,
              1e-6 * r.estimation.Find("leg2.p_C_A.z")->sigma);
  std::remove(path.c_str());
}

TEST(HexapodCalibrationIoTest, EmptyDateIsFilledWithNow) {
  const std::string path = TempPath("date.yaml");
  WriteHexapodCalibration(path, SomeResult(), {});
  EXPECT_THAT(ReadHexapodCalibration(path).metadata.created,
              ::testing::MatchesRegex("20[0-9][0-9]-[01][0-9]-[0-3][0-9]T.*Z"));
  std::remove(path.c_str());
}

TEST(HexapodCalibrationIoTest, BadFileNamesTheFileAndEveryBadKey) {
  const std::string good = TempPath("good.yaml");
  WriteHexapodCalibration(good, SomeResult(), {"cam", "2024-05-01T12:00:00Z", "", ""});
  std::ifstream in(good);
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  auto replace = [&](const std::string& from, const std::string& to) {
    const size_t at = text.find(from);
    ASSERT_NE(at, std::string::npos) << from;
    text.replace(at, from.size(), to);
  };
  replace("leg_radius: 0.02", "leg_radius: -1");
  replace("loss: tukey", "loss: cauchy");
  replace("status: estimated", "status: maybe");
  replace("quaternion_wxyz: [", "quaternion_wxyz: [2, ");
  replace("\ncamera: cam", "\ncamara: cam");
  const std::string bad = TempPath("bad.yaml");
  std::ofstream(bad) << text;
  try {
    ReadHexapodCalibration(bad);
    ADD_FAILURE() << "bad file accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), AllOf(HasSubstr(bad), HasSubstr("leg_radius: must be > 0"),
                                HasSubstr("loss: unknown (cauchy"),
                                HasSubstr("legs[0].status: unknown (maybe)"),
                                HasSubstr("rigid_fit.X_CB.quaternion_wxyz: must be a list of 4"),
                                HasSubstr("camera: missing")));
  }
  EXPECT_THROW(ReadHexapodCalibration(TempPath("does_not_exist.yaml")), std::runtime_error);
  std::ofstream(bad) << "[1, 2";
  EXPECT_THROW(ReadHexapodCalibration(bad), std::invalid_argument);
  std::remove(good.c_str());
  std::remove(bad.c_str());
}

TEST(HexapodCalibrationIoTest, ReprojectionImageMarksEstimatedAndCadPoints) {
  vision::PinholeBrownParameters p;
  p.width = 640;
  p.height = 480;
  p.fx = p.fy = 600.0;
  p.cx = 319.5;
  p.cy = 239.5;
  const vision::PinholeBrownCamera camera(p);
  std::vector<uint8_t> pixels(640 * 480, 40);
  const vision::ImageView8 view{pixels.data(), 640, 480, 640};
  HexapodCalibrationResult r = SomeResult();
  const std::string path = TempPath("reprojection.png");
  WriteReprojectionImage(path, view, camera, r, robots::HexapodModel::Default());
  const cv::Mat png = cv::imread(path, cv::IMREAD_COLOR);
  ASSERT_EQ(png.cols, 640);
  ASSERT_EQ(png.rows, 480);
  int checked = 0;
  for (int j = 0; j < robots::kHexapodLegs; ++j) {
    Eigen::Vector2d uv;
    if (r.legs[j].status != LegStatus::kEstimated) continue;
    ASSERT_EQ(camera.Project(r.p_C_A[j], &uv), vision::ProjectionStatus::kOk);
    // The circle's ring (radius 8) is yellow somewhere around the point.
    bool yellow = false;
    for (int a = 0; a < 32 && !yellow; ++a) {
      const int u = static_cast<int>(std::lround(uv.x() + 8 * std::cos(a * 0.19635)));
      const int v = static_cast<int>(std::lround(uv.y() + 8 * std::sin(a * 0.19635)));
      if (u < 0 || v < 0 || u >= 640 || v >= 480) continue;
      const cv::Vec3b c = png.at<cv::Vec3b>(v, u);
      yellow = c[2] > 200 && c[1] > 200 && c[0] < 100;
    }
    EXPECT_TRUE(yellow) << "leg " << j;
    ++checked;
  }
  EXPECT_GE(checked, 5);
  // Wrong size is refused; an unwritable path names itself.
  const vision::ImageView8 small{pixels.data(), 320, 240, 640};
  EXPECT_THROW(WriteReprojectionImage(path, small, camera, r, robots::HexapodModel::Default()),
               std::invalid_argument);
  try {
    WriteReprojectionImage("/nonexistent/dir/x.png", view, camera, r,
                           robots::HexapodModel::Default());
    ADD_FAILURE();
  } catch (const std::runtime_error& e) {
    EXPECT_THAT(e.what(), HasSubstr("/nonexistent/dir/x.png"));
  }
  std::remove(path.c_str());
}

}  // namespace
}  // namespace kinevis::calibration
