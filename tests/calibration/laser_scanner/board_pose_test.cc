#include "calibration/laser_scanner/board_pose.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <memory>
#include <vector>

#include "vision/camera/camera_file.h"
#include "vision/render/renderer.h"
#include "vision/render/scenes/laser_scene.h"

namespace kinevis::calibration {
namespace {

using vision::render::LaserScene;
using vision::render::LaserSceneParameters;

// The seed's dot board, lasers off, room-lit (ambient 0.6), at pose X_CS.
LaserSceneParameters Board(const Eigen::Isometry3d& X_CS) {
  LaserSceneParameters p;
  p.surface = vision::render::LaserSurfaceKind::kBoard;
  p.half_extent = Eigen::Vector2d(0.15, 0.15);
  p.dot_grid = true;
  p.fixed_on = false;
  p.rotating_on = false;
  p.ambient = 0.6;
  p.X_CS = X_CS;
  return p;
}

Eigen::Isometry3d Pose(double depth, double tilt_x, double tilt_y, double spin) {
  return Eigen::Translation3d(0.004, -0.006, depth) *
         Eigen::AngleAxisd(tilt_x, Eigen::Vector3d::UnitX()) *
         Eigen::AngleAxisd(tilt_y, Eigen::Vector3d::UnitY()) *
         Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()) *
         Eigen::AngleAxisd(spin, Eigen::Vector3d::UnitZ());
}

struct Image {
  std::vector<uint8_t> pixels;
  vision::ImageView8 view;
};

Image Render(const vision::CameraModel& camera, const LaserScene& scene, double noise,
             uint64_t frame) {
  vision::render::RenderOptions options;
  options.noise_sigma = noise;
  options.blur_sigma_px = 0.7;
  vision::render::Renderer renderer(camera, options);
  Image image;
  image.pixels.resize(static_cast<size_t>(camera.width()) * camera.height());
  image.view = {image.pixels.data(), camera.width(), camera.height(),
                static_cast<size_t>(camera.width())};
  renderer.Render(scene, frame, image.view);
  return image;
}

double RotationErrorDeg(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  return Eigen::AngleAxisd(a.linear().transpose() * b.linear()).angle() * 180.0 / M_PI;
}

TEST(BoardPose, RenderedBoardsGiveTheTruePoseAndPlane) {
  const auto camera = vision::BuiltinCameraModel("tsai-seed004");
  const std::vector<Eigen::Isometry3d> poses = {
      Pose(0.50, 0.0, 0.0, 0.02), Pose(0.55, 0.35, -0.1, -0.05), Pose(0.60, -0.2, 0.4, 0.1),
      Pose(0.62, 0.1, -0.5, 0.3)};
  int frame = 0;
  for (const Eigen::Isometry3d& truth : poses) {
    const LaserScene scene(Board(truth));
    const Image image = Render(*camera, scene, 2.0, frame++);
    const BoardPose pose = EstimateBoardPose(image.view, *camera, scene.parameters().dots);
    ASSERT_TRUE(pose.ok()) << pose.message;
    ASSERT_EQ(pose.dots.size(), 81u);
    const double dt = (pose.X_CS.translation() - truth.translation()).norm();
    const double dr = RotationErrorDeg(pose.X_CS, truth);
    // The plane (eq. 16) at the grid's centre: its distance from the true plane.
    const Eigen::Vector4d plane = pose.PlaneInC();
    const double plane_error = std::abs(plane.head<3>().dot(truth.translation()) + plane.w());
    std::printf("depth %.2f: %.3f mm, %.4f deg, plane %.3f mm, rms %.3f px, conf %.3f, %d it\n",
                truth.translation().z(), 1e3 * dt, dr, 1e3 * plane_error, pose.rms_px,
                pose.confidence, pose.iterations);
    EXPECT_LT(dt, 0.5e-3);
    EXPECT_LT(dr, 0.1);
    EXPECT_LT(plane_error, 0.1e-3);
    EXPECT_LT(pose.rms_px, 0.1);
    EXPECT_GT(pose.confidence, 0.8);
    // The reported σ covers the error (6σ: a rendered board's error is mostly systematic).
    const double sigma_t = std::sqrt(pose.covariance.bottomRightCorner<3, 3>().trace());
    EXPECT_GT(sigma_t, 0.0);
    EXPECT_LT(dt, 6.0 * sigma_t + 0.1e-3);
    // Dots ordered row by row, x_S (columns) running towards +u.
    EXPECT_EQ(pose.dots[1].col, 1);
    EXPECT_EQ(pose.dots[9].row, 1);
    EXPECT_GT(pose.dots[8].pixel.x(), pose.dots[0].pixel.x());
  }
}

// The centroid of a dot's image is not the image of its centre: fitting centre projections to the
// centroids absorbs the shift into a wrong pose (the residuals stay small); modelling the
// projected disc removes it (0.009 mm against 0.026 mm measured).
TEST(BoardPose, DiscCentroidModelRemovesThePerspectiveBias) {
  const auto camera = vision::BuiltinCameraModel("tsai-seed004");
  const Eigen::Isometry3d truth = Pose(0.5, 0.5, 0.3, 0.0);
  const LaserScene scene(Board(truth));
  const Image image = Render(*camera, scene, 0.0, 0);
  BoardPoseOptions with, without;
  without.disc_centroid_model = false;
  const BoardPose a = EstimateBoardPose(image.view, *camera, scene.parameters().dots, with);
  const BoardPose b = EstimateBoardPose(image.view, *camera, scene.parameters().dots, without);
  ASSERT_TRUE(a.ok()) << a.message;
  ASSERT_TRUE(b.ok()) << b.message;
  const double ea = (a.X_CS.translation() - truth.translation()).norm();
  const double eb = (b.X_CS.translation() - truth.translation()).norm();
  std::printf("disc model: rms %.4f px, %.3f mm; centre projection: rms %.4f px, %.3f mm\n",
              a.rms_px, 1e3 * ea, b.rms_px, 1e3 * eb);
  EXPECT_LT(ea, 0.6 * eb);
  EXPECT_LT(a.rms_px, 0.05);
}

TEST(BoardPose, ProjectedDiscCentroidOfAFrontalDiscIsItsCentresImage) {
  const auto camera = vision::BuiltinCameraModel("tsai-seed004");
  // Frontal, on the optical axis: the image is a circle about the centre's image.
  const Eigen::Isometry3d X_CS = Pose(0.4, 0.0, 0.0, 0.0) * Eigen::Translation3d(-0.004, -0.006, 0);
  Eigen::Vector2d centroid, centre;
  ASSERT_TRUE(ProjectedDiscCentroid(*camera, X_CS, Eigen::Vector2d::Zero(), 0.005, 48, &centroid));
  ASSERT_EQ(camera->Project(X_CS * Eigen::Vector3d::Zero(), &centre),
            vision::ProjectionStatus::kOk);
  EXPECT_LT((centroid - centre).norm(), 1e-6);
}

TEST(BoardPose, GridPartlyOutOfViewIsNotFound) {
  const auto camera = vision::BuiltinCameraModel("tsai-seed004");
  const LaserScene scene(Board(Pose(0.35, 0.0, 0.0, 0.0)));  // too close: the grid overfills
  const Image image = Render(*camera, scene, 1.0, 0);
  const BoardPose pose = EstimateBoardPose(image.view, *camera, scene.parameters().dots);
  EXPECT_EQ(pose.status, BoardPoseStatus::kGridNotFound);
  EXPECT_THAT(pose.message, ::testing::ContainsRegex("found [0-9]+ dot-like blobs, expected 81"));
  EXPECT_EQ(pose.confidence, 0.0);
  // A blank image: nothing at all.
  std::vector<uint8_t> blank(image.pixels.size(), 128);
  const vision::ImageView8 view{blank.data(), camera->width(), camera->height(),
                                static_cast<size_t>(camera->width())};
  const BoardPose none = EstimateBoardPose(view, *camera, scene.parameters().dots);
  EXPECT_EQ(none.status, BoardPoseStatus::kGridNotFound);
  EXPECT_EQ(none.candidates, 0);
}

TEST(BoardPose, BadOptionsAndImagesAreRefusedByName) {
  const auto camera = vision::BuiltinCameraModel("tsai-seed004");
  std::vector<uint8_t> pixels(100 * 100, 0);
  const vision::ImageView8 small{pixels.data(), 100, 100, 100};
  BoardPoseOptions options;
  options.threshold_window_px = 4;
  options.max_grid_residual = 0.7;
  vision::render::DotGrid grid;
  grid.dot_radius = 0.02;
  try {
    DetectDotGrid(small, *camera, grid, options);
    FAIL() << "accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), ::testing::ContainsRegex(
                              "threshold_window_px: must be 0 \\(auto\\) or odd >= 3, got 4"));
    EXPECT_THAT(e.what(), ::testing::ContainsRegex(
                              "max_grid_residual: must be in \\(0, 0.5\\) cells, got 0.7"));
    EXPECT_THAT(e.what(), ::testing::ContainsRegex(
                              "grid.dot_radius: must be in \\(0, pitch / 2\\) m, got 0.02"));
    EXPECT_THAT(e.what(), ::testing::ContainsRegex("image 100x100 .*1616x1216"));
  }
}

}  // namespace
}  // namespace kinevis::calibration
