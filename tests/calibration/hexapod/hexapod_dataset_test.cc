#include "calibration/hexapod/hexapod_dataset.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include "calibration/hexapod/dataset_calibration.h"
#include "calibration/hexapod/pose_planner.h"
#include "vision/camera/camera_file.h"
#include "vision/render/renderer.h"
#include "vision/render/scenes/hexapod_scene.h"

namespace kinevis::calibration {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

std::string TempDir() {
  const std::string name = ::testing::UnitTest::GetInstance()->current_test_info()->name();
  const fs::path dir =
      fs::temp_directory_path() / ("kinevis_dataset_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  return dir.string();
}

Eigen::Isometry3d Pose(double x, double y, double z, double yaw) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation() = Eigen::Vector3d(x, y, z);
  X.linear() = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  return X;
}

HexapodDataset NewDataset(const std::string& dir) {
  HexapodDataset d;
  d.directory = dir;
  d.camera_name = "omni";
  d.camera_model = "builtin:unified-default";
  d.X_BC_hint = Pose(0.01, -0.02, 0.03, 0.1);
  d.source = "test";
  CreateHexapodDataset(&d);
  return d;
}

TEST(HexapodDatasetTest, WhatIsWrittenReadsBackExactly) {
  const std::string dir = TempDir();
  HexapodDataset d = NewDataset(dir);
  std::vector<uint8_t> pixels(40 * 30);
  for (size_t i = 0; i < pixels.size(); ++i) pixels[i] = static_cast<uint8_t>(i * 7);
  for (int k = 0; k < 2; ++k) {
    HexapodDatasetPose pose;
    pose.index = k;
    pose.image = "images/pose_00" + std::to_string(k) + ".png";
    pose.s << 0.1 + k, 0.2, 0.3, 0.4, 0.5, 0.6 / 7.0;
    pose.X_BP_commanded = Pose(0.01 * k, 0.02, 0.4, 0.3 * k);
    AppendHexapodDatasetPose(d, pose, pixels.data(), 40, 30, 40);
  }
  const HexapodDataset r = ReadHexapodDataset(dir);
  EXPECT_EQ(r.camera_name, "omni");
  EXPECT_EQ(r.camera_model, "builtin:unified-default");
  EXPECT_EQ(r.source, "test");
  EXPECT_FALSE(r.created.empty());
  EXPECT_TRUE(r.X_BC_hint.isApprox(d.X_BC_hint, 1e-12));
  ASSERT_EQ(r.poses.size(), 2u);
  for (int k = 0; k < 2; ++k) {
    EXPECT_EQ(r.poses[k].index, k);
    EXPECT_EQ(r.poses[k].s[0], 0.1 + k);  // 17 significant digits: exact
    EXPECT_EQ(r.poses[k].s[5], 0.6 / 7.0);
    EXPECT_TRUE(r.poses[k].X_BP_commanded.isApprox(Pose(0.01 * k, 0.02, 0.4, 0.3 * k), 1e-15));
  }
  int w = 0, h = 0;
  EXPECT_EQ(ReadDatasetImage(r, r.poses[1], &w, &h), pixels);
  EXPECT_EQ(w, 40);
  EXPECT_EQ(h, 30);
  fs::remove_all(dir);
}

TEST(HexapodDatasetTest, AnExistingDatasetIsNotOverwritten) {
  const std::string dir = TempDir();
  NewDataset(dir);
  try {
    NewDataset(dir);
    FAIL() << "overwrote";
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr("exists; record into a new directory"));
  }
  fs::remove_all(dir);
}

TEST(HexapodDatasetTest, BadFilesAreRefusedNamingEveryProblem) {
  const std::string dir = TempDir();
  HexapodDataset d = NewDataset(dir);
  {
    std::ofstream csv(dir + "/poses.csv", std::ios::app);
    csv << "0,images/missing.png,0,0,0,0,0,0,0,0,0.4,1,0,0,0\n";  // line 2: no image
    csv << "1,images/missing.png,0,0,0\n";                        // line 3: short
    csv << "2,images/missing.png,0,0,0,0,0,0,0,0,0.4,2,0,0,0\n";  // line 4: not unit
  }
  {
    std::ofstream yaml(dir + "/dataset.yaml", std::ios::app);
    yaml << "unused: 1\n";
  }
  std::string text = fs::path(dir + "/dataset.yaml").string();
  {
    // version 2 is not read.
    std::ifstream in(text);
    std::string all((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    all.replace(all.find("version: 1"), 10, "version: 2");
    std::ofstream(text) << all;
  }
  try {
    ReadHexapodDataset(dir);
    FAIL() << "accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr("version: expected 1"));
    EXPECT_THAT(e.what(), HasSubstr("poses.csv line 2: image images/missing.png does not exist"));
    EXPECT_THAT(e.what(), HasSubstr("poses.csv line 3: expected 15 values, got 5"));
    EXPECT_THAT(e.what(), HasSubstr("poses.csv line 4: the quaternion is not unit"));
  }
  fs::remove_all(dir);
}

// The whole calibration from a dataset: images of a robot whose base points differ from the CAD
// by 1 mm, seen by the catadioptric camera between the legs through a camera pose hint 1 cm and
// 1° off; the second pass searches around the first pass's result.
TEST(DatasetCalibrationTest, RecoversTheTrueAttachmentPointsFromRenderedImages) {
  const std::string dir = TempDir();
  robots::HexapodModel truth = robots::HexapodModel::Default();
  std::mt19937 rng(3);
  std::normal_distribution<double> mm(0.0, 1e-3);
  for (auto& a : truth.p_B_A) a += Eigen::Vector3d(mm(rng), mm(rng), mm(rng));
  const Eigen::Isometry3d X_BC_true = Pose(0.0, 0.0, 0.03, 0.0);
  HexapodDataset d;
  d.directory = dir;
  d.camera_name = "omni";
  d.camera_model = "builtin:unified-default";
  d.X_BC_hint = X_BC_true;
  d.X_BC_hint.translation() += Eigen::Vector3d(0.01, -0.005, 0.004);
  d.X_BC_hint.linear() =
      Eigen::AngleAxisd(1.0 * M_PI / 180, Eigen::Vector3d(1, 1, 0).normalized()) *
      d.X_BC_hint.linear();
  CreateHexapodDataset(&d);
  const std::unique_ptr<vision::CameraModel> camera = vision::OpenCameraModel(d.camera_model);
  vision::render::RenderOptions ro;
  ro.noise_sigma = 1.0;
  vision::render::Renderer renderer(*camera, ro);
  PosePlannerOptions po;
  po.poses = 12;
  po.candidates = 300;
  const PosePlan plan = PlanCalibrationPoses(d.nominal, po);
  std::vector<uint8_t> pixels(static_cast<size_t>(camera->width()) * camera->height());
  robots::HexapodData ik;
  for (size_t k = 0; k < plan.X_BP.size(); ++k) {
    // The drives go where the nominal IK sends them; the true robot's FK gives the real pose.
    robots::InverseKinematics(d.nominal, plan.X_BP[k], &ik);
    robots::HexapodData fk;
    const robots::ForwardKinematicsSummary s =
        robots::ForwardKinematics(truth, ik.q, plan.X_BP[k], {}, &fk);
    ASSERT_TRUE(s.converged());
    const vision::render::HexapodScene scene(truth, s.X_BP, X_BC_true.inverse());
    renderer.Render(
        scene, k,
        {pixels.data(), camera->width(), camera->height(), static_cast<size_t>(camera->width())});
    HexapodDatasetPose pose;
    pose.index = static_cast<int>(k);
    pose.image = "images/pose_" + std::to_string(k) + ".png";
    pose.s = robots::JointPositionsFromLegLengths(d.nominal, ik.q);
    pose.X_BP_commanded = plan.X_BP[k];
    AppendHexapodDatasetPose(d, pose, pixels.data(), camera->width(), camera->height(),
                             camera->width());
  }
  const DatasetCalibrationResult r = CalibrateHexapodDataset(ReadHexapodDataset(dir), *camera);
  ASSERT_TRUE(r.result.ok()) << (r.result.errors.empty() ? "" : r.result.errors[0]);
  EXPECT_EQ(r.passes_run, 2);
  double worst = 0;
  for (int j = 0; j < 6; ++j) {
    worst = std::max(worst, (r.result.p_C_A[j] - X_BC_true.inverse() * truth.p_B_A[j]).norm());
  }
  std::printf("dataset calibration: worst |A_j - truth| %.3f mm, last pass moved %.3f mm\n",
              1e3 * worst, 1e3 * r.last_pass_change);
  EXPECT_LT(worst, 1.5e-3);
  for (const DatasetPoseReport& p : r.poses) EXPECT_GE(p.legs_seen, 4) << p.not_seen;
  // The rigid fit finds the true camera pose, not the hint.
  EXPECT_LT((r.result.X_CB.inverse().translation() - X_BC_true.translation()).norm(), 3e-3);

  // A camera of another size than the images is refused naming both.
  const std::unique_ptr<vision::CameraModel> other =
      vision::OpenCameraModel("builtin:tsai-seed004");
  try {
    CalibrateHexapodDataset(ReadHexapodDataset(dir), *other);
    FAIL() << "accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr("image is 640x480 but the camera model"));
  }
  fs::remove_all(dir);
}

}  // namespace
}  // namespace kinevis::calibration
