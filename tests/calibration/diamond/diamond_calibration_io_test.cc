#include "calibration/diamond/diamond_calibration_io.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>
#include <regex>
#include <sstream>

#include "robots/io/robot_description.h"
#include "tests/utilities/version_one_file.h"
#include "vision/camera/pinhole_camera.h"
#include "vision/render/scenes/diamond_marker_scene.h"

namespace kinevis::calibration {
namespace {

using ::testing::HasSubstr;
namespace fs = std::filesystem;

std::string TempPath(const std::string& name) {
  return (fs::temp_directory_path() / ("kinevis_diamond_io_" + name)).string();
}

DiamondIdentificationSummary Identified() {
  vision::PinholeBrownParameters p;
  p.width = 1280;
  p.height = 640;
  p.fx = p.fy = 1000.0;
  p.cx = 639.5;
  p.cy = 319.5;
  const vision::PinholeBrownCamera camera(p);
  const Eigen::Isometry3d X_OC = vision::render::DiamondCameraPose(0.4462).inverse();
  robots::DiamondModel truth = robots::DiamondModel::SeedIdentified();
  truth.joint_offsets = {0.01, -0.007};
  const auto tasks = DiamondVisibleTaskGrid(robots::DiamondModel::APriori(), camera, X_OC, 8, 6);
  const auto samples =
      SimulateDiamondSamples(robots::DiamondModel::APriori(), truth, camera, X_OC, tasks);
  DiamondIdentificationOptions o;
  o.estimate_camera_distance = true;  // rank-deficient on purpose: inf σ and null vectors
  return IdentifyDiamond(samples, camera, robots::DiamondModel::APriori(), X_OC, o);
}

TEST(DiamondCalibrationIoTest, RoundTripsEverythingStored) {
  const DiamondIdentificationSummary s = Identified();
  ASSERT_FALSE(s.identifiability.unidentified.empty());
  DiamondCalibrationMetadata meta;
  meta.camera = "builtin:test";
  meta.source = "simulation";
  meta.created = "2024-05-01T12:00:00Z";
  const std::string path = TempPath("roundtrip.yaml");
  WriteDiamondCalibration(path, s, meta);
  const DiamondCalibrationFile f = ReadDiamondCalibration(path);
  EXPECT_EQ(f.metadata.camera, "builtin:test");
  EXPECT_EQ(f.metadata.created, "2024-05-01T12:00:00Z");
  EXPECT_EQ(f.metadata.source, "simulation");
  const DiamondIdentificationSummary& r = f.summary;
  EXPECT_EQ(r.status, s.status);
  EXPECT_EQ(r.residual, s.residual);
  EXPECT_EQ(r.scaling, s.scaling);
  EXPECT_DOUBLE_EQ(r.model.radius, s.model.radius);
  EXPECT_DOUBLE_EQ(r.model.alpha, s.model.alpha);
  EXPECT_DOUBLE_EQ(r.model.beta, s.model.beta);
  EXPECT_DOUBLE_EQ(r.model.joint_offsets[1], s.model.joint_offsets[1]);
  EXPECT_DOUBLE_EQ(r.model.gamma_max, s.model.gamma_max);
  EXPECT_LT((r.X_OC.matrix() - s.X_OC.matrix()).cwiseAbs().maxCoeff(), 1e-15);
  for (int j = 0; j < kDiamondParameterCount; ++j) {
    EXPECT_DOUBLE_EQ(r.parameters[j].value, s.parameters[j].value) << j;
    EXPECT_EQ(r.parameters[j].sigma, s.parameters[j].sigma) << j;  // inf included
    EXPECT_EQ(r.parameters[j].estimated, s.parameters[j].estimated);
    EXPECT_EQ(r.parameters[j].identified, s.parameters[j].identified);
  }
  EXPECT_TRUE(std::isinf(r.parameters[kDiamondRadius].sigma));
  EXPECT_EQ(r.covariance, s.covariance);
  EXPECT_EQ(r.pixel_residuals.count, s.pixel_residuals.count);
  EXPECT_DOUBLE_EQ(r.pixel_residuals.rms.y(), s.pixel_residuals.rms.y());
  EXPECT_DOUBLE_EQ(r.task_residuals.sup.x(), s.task_residuals.sup.x());
  EXPECT_EQ(r.identifiability.rank, s.identifiability.rank);
  EXPECT_EQ(r.identifiability.condition_number, s.identifiability.condition_number);
  EXPECT_EQ(r.identifiability.singular_values, s.identifiability.singular_values);
  EXPECT_EQ(r.identifiability.unidentified, s.identifiability.unidentified);
  EXPECT_EQ(r.identifiability.gauges, s.identifiability.gauges);
  EXPECT_EQ(r.warnings, s.warnings);
  EXPECT_EQ(r.samples_used, s.samples_used);
  EXPECT_EQ(r.estimation.status, EstimationStatus::kUnidentified);
  EXPECT_EQ(r.estimation.parameters.size(), s.estimation.parameters.size());
  EXPECT_EQ(r.estimation.Find("radius")->sigma, s.estimation.Find("radius")->sigma);
  EXPECT_EQ(r.estimation.covariance, s.estimation.covariance);
  EXPECT_EQ(r.estimation.identifiability.unidentified, s.estimation.identifiability.unidentified);
  // The file is a robot description too.
  const robots::DiamondDescription d = robots::LoadDiamondDescription(path);
  EXPECT_DOUBLE_EQ(d.model.radius, s.model.radius);
  EXPECT_DOUBLE_EQ(d.model.joint_offsets[0], s.model.joint_offsets[0]);
  EXPECT_EQ(d.name, "diamond-calibrated");
  fs::remove(path);
}

// Files written before the estimator contract (version 1, no estimation: block) still read, their
// report derived from what they hold.
TEST(DiamondCalibrationIoTest, ReadsVersionOneFilesWithoutTheEstimationBlock) {
  const DiamondIdentificationSummary s = Identified();
  const std::string path = TempPath("version1.yaml");
  WriteDiamondCalibration(path, s, {});
  kinevis::testing::RewriteAsVersionOne(path);
  const DiamondCalibrationFile f = ReadDiamondCalibration(path);
  EXPECT_EQ(f.summary.estimation.status, EstimationStatus::kUnidentified);
  EXPECT_EQ(f.summary.estimation.Validate(), "");
  EXPECT_DOUBLE_EQ(f.summary.estimation.Find("alpha")->value, s.model.alpha);
}

TEST(DiamondCalibrationIoTest, RefusesBadFilesNamingEveryKey) {
  const DiamondIdentificationSummary s = Identified();
  const std::string path = TempPath("bad.yaml");
  WriteDiamondCalibration(path, s, {});
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  std::string t = text.str();
  t = std::regex_replace(t, std::regex("\nalpha: [^\n]*"), "\nalpha: wide");
  t = std::regex_replace(t, std::regex("\nkind: [^\n]*"), "\nkind: something-else");
  t = std::regex_replace(t, std::regex("quaternion_wxyz: \\[[^\\]]*\\]"),
                         "quaternion_wxyz: [2, 0, 0, 0]");
  t = std::regex_replace(t, std::regex("status: converged"), "status: happy");
  std::ofstream(path) << t;
  try {
    ReadDiamondCalibration(path);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr(path));
    EXPECT_THAT(e.what(), HasSubstr("alpha: not a number (wide)"));
    EXPECT_THAT(e.what(), HasSubstr("kind: expected kinevis-diamond-calibration"));
    EXPECT_THAT(e.what(), HasSubstr("camera_pose.quaternion_wxyz: not a unit quaternion"));
    EXPECT_THAT(e.what(), HasSubstr("identification.status: unknown 'happy'"));
  }
  std::ofstream(path) << "robot: diamond\nkind: kinevis-diamond-calibration\nversion: 1\n";
  try {
    ReadDiamondCalibration(path);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr("radius: missing"));
    EXPECT_THAT(e.what(), HasSubstr("covariance: missing"));
  }
  fs::remove(path);
  EXPECT_THROW(ReadDiamondCalibration(TempPath("does-not-exist.yaml")), std::runtime_error);
  EXPECT_THROW(WriteDiamondCalibration("/nonexistent-dir/x.yaml", s, {}), std::runtime_error);
}

}  // namespace
}  // namespace kinevis::calibration
