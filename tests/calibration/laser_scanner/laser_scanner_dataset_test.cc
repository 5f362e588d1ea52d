#include "calibration/laser_scanner/laser_scanner_dataset.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>
#include <string>
#include <vector>

#include "calibration/laser_scanner/laser_scanner_calibration_io.h"
#include "calibration/laser_scanner/synthetic_stripes.h"
#include "tests/utilities/version_one_file.h"
#include "vision/camera/camera_file.h"
#include "vision/render/renderer.h"

namespace kinevis::calibration {
namespace {

namespace fs = std::filesystem;
using vision::render::LaserId;
using vision::render::LaserScene;
using vision::render::LaserSceneParameters;

fs::path TempDir(const std::string& name) {
  const fs::path dir =
      fs::temp_directory_path() / ("kinevis_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  return dir;
}

Eigen::Isometry3d Pose(double depth, double tilt_x, double tilt_y) {
  return Eigen::Translation3d(0.003, -0.004, depth) *
         Eigen::AngleAxisd(tilt_x, Eigen::Vector3d::UnitX()) *
         Eigen::AngleAxisd(tilt_y, Eigen::Vector3d::UnitY()) *
         Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX());
}

// A dataset recorded from the simulated scanner: per board pose a lasers-off image (the dots)
// and lasers-on images at three stepper positions, with the stripes' ground truth (+0.1 px
// noise) in the stripe files (no stripe extractor in the tree yet).
LaserScannerDataset Record(const fs::path& dir, const vision::CameraModel& camera) {
  LaserScannerDataset d;
  d.directory = dir.string();
  d.camera_model = "builtin:tsai-seed004";
  d.camera_name = "weld-scanner";
  d.source = "laser_scanner_dataset_test";
  CreateLaserScannerDataset(&d);
  vision::render::RenderOptions render;
  render.noise_sigma = 1.5;
  render.blur_sigma_px = 0.7;
  vision::render::Renderer renderer(camera, render);
  std::vector<uint8_t> pixels(static_cast<size_t>(camera.width()) * camera.height());
  const vision::ImageView8 view{pixels.data(), camera.width(), camera.height(),
                                static_cast<size_t>(camera.width())};
  std::mt19937 rng(5);
  std::normal_distribution<double> noise(0.0, 0.1);
  const std::vector<Eigen::Isometry3d> poses = {Pose(0.5, 0.3, 0.25), Pose(0.6, -0.25, -0.3)};
  int frame = 0;
  for (size_t i = 0; i < poses.size(); ++i) {
    LaserSceneParameters p;
    p.surface = vision::render::LaserSurfaceKind::kBoard;
    p.half_extent = Eigen::Vector2d(0.15, 0.15);
    p.dot_grid = true;
    p.dots = d.board;
    p.ambient = 0.5;
    p.X_CS = poses[i];
    p.fixed_on = p.rotating_on = false;
    renderer.Render(LaserScene(p), frame++, view);
    LaserScannerDatasetImage off;
    off.image = "images/pose" + std::to_string(i) + "_off.png";
    off.board_pose = static_cast<int>(i);
    AppendLaserScannerDatasetImage(&d, off, pixels.data(), camera.width(), camera.height(),
                                   camera.width());
    for (int step : {0, 100, 200}) {
      p.fixed_on = p.rotating_on = true;
      p.rotating_cot_theta_y = 1.0 / std::tan((72.0 + 0.05625 * step) * M_PI / 180.0);
      const LaserScene scene(p);
      renderer.Render(scene, frame++, view);
      std::vector<Eigen::Vector2d> fixed = ExactStripePixels(scene, camera, LaserId::kFixed);
      std::vector<Eigen::Vector2d> rotating = ExactStripePixels(scene, camera, LaserId::kRotating);
      for (auto& px : fixed) px.x() += noise(rng);
      for (auto& px : rotating) px.y() += noise(rng);
      LaserScannerDatasetImage on;
      on.image = "images/pose" + std::to_string(i) + "_step" + std::to_string(step) + ".png";
      on.board_pose = static_cast<int>(i);
      on.lasers_on = true;
      on.rotating_step = step;
      AppendLaserScannerDatasetImage(&d, on, pixels.data(), camera.width(), camera.height(),
                                     camera.width(), &fixed, &rotating);
    }
  }
  return d;
}

TEST(LaserScannerDataset, RecordedDatasetCalibratesAndTheResultFileRoundTrips) {
  const auto camera = vision::BuiltinCameraModel("tsai-seed004");
  const fs::path dir = TempDir("scanner_dataset");
  Record(dir, *camera);
  const LaserScannerDataset d = ReadLaserScannerDataset(dir.string());
  ASSERT_EQ(d.images.size(), 8u);
  EXPECT_EQ(d.camera_model, "builtin:tsai-seed004");
  EXPECT_NEAR(d.board.pitch, 0.0265, 1e-12);
  EXPECT_EQ(d.images[1].stripes, "stripes/pose0_step0.csv");
  const LaserScannerDatasetCalibration c = CalibrateLaserScannerDataset(d, *camera);
  ASSERT_TRUE(c.calibration.ok()) << c.calibration.errors[0];
  ASSERT_EQ(c.board_poses.size(), 2u);
  const vision::laser::ScannerGeometry truth;
  const auto& g = c.calibration.geometry;
  std::printf("from the dataset: b_y %.4f (%.4f) d_y %.4f (%.4f) b_x' %.4f (%.4f) mm\n",
              1e3 * g.rotating_b_y, 1e3 * c.calibration.b_y_sigma(), 1e3 * g.rotating_d_y,
              1e3 * c.calibration.d_y_sigma(), 1e3 * g.fixed_b_x_prime,
              1e3 * c.calibration.b_x_prime_sigma());
  // Board poses from rendered images carry ~0.01 mm errors: sub-0.2 mm parameters.
  EXPECT_NEAR(g.rotating_b_y, truth.rotating_b_y, 0.2e-3);
  EXPECT_NEAR(g.rotating_d_y, truth.rotating_d_y, 0.5e-3);
  EXPECT_NEAR(g.fixed_b_x_prime, truth.fixed_b_x_prime, 0.2e-3);
  EXPECT_NEAR(g.fixed_cot_theta_x, truth.fixed_cot_theta_x, 1e-3);

  const std::string yaml = (dir / "scanner.yaml").string();
  WriteLaserScannerCalibration(yaml, c.calibration,
                               {d.camera_model, d.camera_name, "", d.directory});
  const LaserScannerCalibrationFile back = ReadLaserScannerCalibration(yaml);
  EXPECT_EQ(back.metadata.camera, "builtin:tsai-seed004");
  EXPECT_EQ(back.metadata.source, d.directory);
  EXPECT_FALSE(back.metadata.created.empty());
  EXPECT_TRUE(back.result.rotating_calibrated);
  EXPECT_NEAR(back.result.geometry.rotating_b_y, g.rotating_b_y, 1e-12);
  EXPECT_NEAR(back.result.geometry.rotating_d_y, g.rotating_d_y, 1e-12);
  EXPECT_NEAR(back.result.geometry.fixed_b_x_prime, g.fixed_b_x_prime, 1e-12);
  EXPECT_NEAR(back.result.geometry.fixed_cot_theta_x, g.fixed_cot_theta_x, 1e-12);
  EXPECT_NEAR(back.result.b_y_sigma(), c.calibration.b_y_sigma(), 1e-12);
  EXPECT_NEAR(back.result.rotating_covariance(0, 1), c.calibration.rotating_covariance(0, 1),
              1e-15);
  ASSERT_EQ(back.result.positions.size(), 3u);
  EXPECT_EQ(back.result.positions[2].step, 200);
  EXPECT_NEAR(back.result.positions[2].cot_theta_y, c.calibration.positions[2].cot_theta_y, 1e-11);
  EXPECT_NEAR(back.result.stepper.theta_per_step, c.calibration.stepper.theta_per_step, 1e-13);
  EXPECT_EQ(back.result.warnings, c.calibration.warnings);
  // The estimator contract's block reads back too.
  EXPECT_EQ(back.result.estimation.status, c.calibration.estimation.status);
  EXPECT_EQ(back.result.estimation.parameters.size(), c.calibration.estimation.parameters.size());
  EXPECT_NEAR(back.result.estimation.Find("d_y")->sigma,
              c.calibration.estimation.Find("d_y")->sigma, 1e-6 * c.calibration.d_y_sigma());

  // A version 1 file (before the contract) reads, its report rebuilt from the planes.
  kinevis::testing::RewriteAsVersionOne(yaml);
  const LaserScannerCalibrationFile old = ReadLaserScannerCalibration(yaml);
  EXPECT_EQ(old.result.estimation.Validate(), "");
  EXPECT_EQ(old.result.estimation.status, EstimationStatus::kConverged);
  EXPECT_NEAR(old.result.estimation.Find("b_y")->sigma, c.calibration.b_y_sigma(),
              1e-6 * c.calibration.b_y_sigma());
  fs::remove_all(dir);
}

TEST(LaserScannerDataset, BadFilesAreRefusedNamingTheKeyOrLine) {
  const fs::path dir = TempDir("scanner_bad");
  fs::create_directories(dir);
  const std::string yaml = (dir / "scanner.yaml").string();
  {
    std::ofstream f(yaml);
    f << "kind: kinevis-laser-scanner-calibration\nversion: 1\ncamera: builtin:tsai-seed004\n"
         "rotating_laser: {calibrated: true, b_y_mm: .nan}\n";
  }
  try {
    ReadLaserScannerCalibration(yaml);
    FAIL() << "accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), ::testing::ContainsRegex("scanner.yaml: "));
    EXPECT_THAT(e.what(), ::testing::ContainsRegex("rotating_laser.b_y_mm: must be finite"));
    EXPECT_THAT(e.what(), ::testing::ContainsRegex("rotating_laser.d_y_mm: missing"));
    EXPECT_THAT(e.what(), ::testing::ContainsRegex("fixed_laser: missing"));
  }
  EXPECT_THROW(ReadLaserScannerCalibration((dir / "none.yaml").string()), std::runtime_error);
  // A dataset with a bad row.
  LaserScannerDataset d;
  d.directory = (dir / "set").string();
  d.camera_model = "builtin:tsai-seed004";
  CreateLaserScannerDataset(&d);
  EXPECT_THROW(CreateLaserScannerDataset(&d), std::invalid_argument);
  {
    std::ofstream csv(dir / "set" / "images.csv", std::ios::app);
    csv << "images/a.png,-1,maybe,x,\n";
  }
  try {
    ReadLaserScannerDataset(d.directory);
    FAIL() << "accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), ::testing::ContainsRegex("images.csv line 2: board_pose '-1'"));
    EXPECT_THAT(e.what(), ::testing::ContainsRegex("lasers 'maybe'"));
    EXPECT_THAT(e.what(), ::testing::ContainsRegex("rotating_step 'x'"));
    EXPECT_THAT(e.what(), ::testing::ContainsRegex("image images/a.png does not exist"));
  }
  fs::remove_all(dir);
}

}  // namespace
}  // namespace kinevis::calibration
