#include "vision/render/scenes/target_scene.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <memory>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <string>
#include <vector>

#include "vision/camera/camera_file.h"
#include "vision/camera/pinhole_camera.h"

namespace kinevis::vision::render {
namespace {

using ::testing::ContainsRegex;
using ::testing::HasSubstr;

PinholeBrownCamera Pinhole640() {
  PinholeBrownParameters p;
  p.width = 640;
  p.height = 480;
  p.fx = p.fy = 600.0;
  p.cx = 322.3;
  p.cy = 236.8;
  return PinholeBrownCamera(p);
}

// A pose of T in C: the board's centre 'distance' along the ray of `pixel`, its normal tilted by
// `tilt` (rad) about x_T and y_T from facing the camera.
Eigen::Isometry3d BoardPose(const CameraModel& camera, const TargetSpec& spec,
                            const Eigen::Vector2d& pixel, double distance, double tilt,
                            double roll = 0.0) {
  Ray ray;
  EXPECT_EQ(camera.BackProject(pixel, &ray), ProjectionStatus::kOk);
  const Eigen::Vector3d z = ray.d_C;  // z_T away from the camera: the board faces it
  const Eigen::Vector3d x = Eigen::Vector3d::UnitY().cross(z).normalized();
  Eigen::Matrix3d R;
  R.col(0) = x;
  R.col(1) = z.cross(x);
  R.col(2) = z;
  R = R * (Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitZ()) *
           Eigen::AngleAxisd(tilt, Eigen::Vector3d::UnitX()) *
           Eigen::AngleAxisd(0.7 * tilt, Eigen::Vector3d::UnitY()))
              .toRotationMatrix();
  const double step = spec.pattern == TargetPattern::kChessboard ? spec.square : spec.pitch;
  const Eigen::Vector3d centre_T(0.5 * (spec.feature_cols() - 1) * step,
                                 0.5 * (spec.feature_rows() - 1) * step, 0.0);
  Eigen::Isometry3d X_CT = Eigen::Isometry3d::Identity();
  X_CT.linear() = R;
  X_CT.translation() = ray.p_C_O + distance * ray.d_C - R * centre_T;
  return X_CT;
}

struct Rendered {
  std::vector<uint8_t> pixels;
  GroundTruth truth;
  cv::Mat Mat() {
    return cv::Mat(static_cast<int>(truth.height), truth.width, CV_8UC1, pixels.data());
  }
};

Rendered Render(const CameraModel& camera, const Scene& scene, const RenderOptions& options = {}) {
  Rendered r;
  r.pixels.assign(static_cast<size_t>(camera.width()) * camera.height(), 0);
  Renderer renderer(camera, options);
  renderer.Render(scene, 0,
                  ImageView8{r.pixels.data(), camera.width(), camera.height(),
                             static_cast<size_t>(camera.width())},
                  &r.truth);
  return r;
}

TEST(TargetSpecTest, ValidateNamesEveryBadField) {
  EXPECT_EQ(TargetSpec{}.Validate(), "");
  TargetSpec chess;
  chess.cols = 2;
  chess.square = 0.0;
  chess.white_radiance = 2.0;
  const std::string m = chess.Validate();
  EXPECT_THAT(m, ContainsRegex("cols: [^;]*, got 2"));
  EXPECT_THAT(m, ContainsRegex("square: [^;]*, got 0"));
  EXPECT_THAT(m, ContainsRegex("white_radiance: [^;]*, got 2"));
  TargetSpec dots;
  dots.pattern = TargetPattern::kDotGrid;
  dots.dot_diameter = 0.04;
  dots.pitch = 0.03;
  dots.border = 0.01;
  const std::string d = dots.Validate();
  EXPECT_THAT(d, ContainsRegex("dot_diameter: [^;]*, got 0.04"));
  EXPECT_THAT(d, ContainsRegex("border: [^;]*, got 0.01"));
  EXPECT_THROW(TargetScene(chess, Eigen::Isometry3d::Identity()), std::invalid_argument);
}

TEST(TargetSpecTest, FeaturesAreRowMajorInOpenCvOrder) {
  TargetSpec chess;  // 9 × 7 squares → 8 × 6 inner corners
  const auto corners = chess.FeaturePoints();
  ASSERT_EQ(corners.size(), 48u);
  EXPECT_EQ(corners[1], Eigen::Vector3d(0.03, 0, 0));
  EXPECT_EQ(corners[8], Eigen::Vector3d(0, 0.03, 0));
  TargetSpec dots;
  dots.pattern = TargetPattern::kDotGrid;
  dots.cols = 4;
  dots.rows = 3;
  EXPECT_EQ(dots.FeaturePoints().size(), 12u);
  EXPECT_EQ(dots.FeaturePoints()[11], Eigen::Vector3d(0.09, 0.06, 0));
}

TEST(TargetSceneTest, TraceFollowsThePattern) {
  TargetSpec spec;
  Eigen::Isometry3d X_CT = Eigen::Isometry3d::Identity();
  X_CT.translation() = Eigen::Vector3d(0, 0, 1);
  const TargetScene scene(spec, X_CT);
  auto trace = [&](double x, double y) {
    Ray ray;
    ray.d_C = Eigen::Vector3d(x, y, 1.0).normalized();
    return scene.Trace(ray);
  };
  EXPECT_EQ(trace(-0.015, -0.015).object, kTargetBlackId);  // top-left square (c = r = 0)
  EXPECT_EQ(trace(0.015, -0.015).object, kTargetWhiteId);
  EXPECT_EQ(trace(0.015, 0.015).object, kTargetBlackId);
  EXPECT_EQ(trace(-0.04, 0.015).object, kTargetWhiteId);  // border
  EXPECT_EQ(trace(-0.07, 0.015).object, 0);               // beyond the board
  EXPECT_NEAR(trace(0.015, 0.015).depth, std::sqrt(1 + 2 * 0.015 * 0.015), 1e-12);
}

// The oracle: OpenCV's detector on the rendered image. Returns the max distance between detected
// and projected corners (-1 when not found).
double ChessboardDetectionError(const CameraModel& camera, const TargetScene& scene, Rendered* r,
                                double* mean_error) {
  cv::Mat image = r->Mat();
  const cv::Size pattern(scene.spec().feature_cols(), scene.spec().feature_rows());
  std::vector<cv::Point2f> corners;
  if (!cv::findChessboardCorners(image, pattern, corners,
                                 cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE)) {
    return -1.0;
  }
  cv::cornerSubPix(image, corners, cv::Size(5, 5), cv::Size(-1, -1),
                   cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 100, 1e-4));
  std::vector<Eigen::Vector2d> projected;
  std::vector<ProjectionStatus> status;
  const int visible = scene.ProjectFeatures(camera, &projected, &status);
  EXPECT_EQ(visible, static_cast<int>(projected.size()));
  EXPECT_EQ(corners.size(), projected.size());
  double max_error = 0.0, sum = 0.0;
  for (const cv::Point2f& c : corners) {  // OpenCV may order the corners either way round
    double nearest = 1e9;
    for (const Eigen::Vector2d& p : projected) {
      nearest = std::min(nearest, (p - Eigen::Vector2d(c.x, c.y)).norm());
    }
    max_error = std::max(max_error, nearest);
    sum += nearest;
  }
  *mean_error = sum / corners.size();
  return max_error;
}

// cornerSubPix is the limiting oracle here, not the renderer: on a perfectly sharp board whose
// edges are aligned with the pixel rows and columns its corners scatter by up to 0.25 px (mean
// 0.11 px, at any window size or supersampling), because the gradient then lives in one or two
// pixel columns. Hence a realistic lens (Gaussian PSF, σ = 0.7 px) and a board rolled by 0.3 rad;
// the renderer's own edge accuracy is pinned down in renderer_test and hexapod_scene_test.
constexpr double kRoll = 0.3;
RenderOptions CornerOptions() {
  RenderOptions o;
  o.blur_sigma_px = 0.7;
  return o;
}

TEST(TargetSceneTest, PinholeChessboardIsFoundByOpenCvWhereTheCameraProjectsIt) {
  const PinholeBrownCamera camera = Pinhole640();
  const TargetSpec spec;
  for (const double tilt : {0.0, 0.35}) {
    const TargetScene scene(spec,
                            BoardPose(camera, spec, Eigen::Vector2d(300, 250), 0.55, tilt, kRoll));
    Rendered r = Render(camera, scene, CornerOptions());
    double mean = 0.0;
    const double max_error = ChessboardDetectionError(camera, scene, &r, &mean);
    std::printf("pinhole chessboard, tilt %.2f rad: corner error mean %.4f px, max %.4f px\n", tilt,
                mean, max_error);
    EXPECT_GE(max_error, 0.0) << "not found";
    EXPECT_LT(max_error, 0.1);
  }
}

TEST(TargetSceneTest, FrontoParallelDotCentroidsMatchTheProjectedCentres) {
  const PinholeBrownCamera camera = Pinhole640();
  TargetSpec spec;
  spec.pattern = TargetPattern::kDotGrid;
  spec.cols = 7;
  spec.rows = 5;
  Eigen::Isometry3d X_CT = Eigen::Isometry3d::Identity();
  // Fronto-parallel at 0.52 m: a pitch of 34.6 px, so the dots sample every sub-pixel phase.
  X_CT.translation() = Eigen::Vector3d(-0.085, -0.062, 0.52);
  const TargetScene scene(spec, X_CT);
  Rendered r = Render(camera, scene);
  std::vector<Eigen::Vector2d> centres;
  std::vector<ProjectionStatus> status;
  ASSERT_EQ(scene.ProjectFeatures(camera, &centres, &status), 35);
  // The darkness-weighted centroid of each dot (weight (white − I)/(white − black), i.e. the
  // anti-aliased coverage) in a window of ± half a pitch, by cv::moments.
  const double white = std::round(255 * spec.white_radiance),
               black = std::round(255 * spec.black_radiance);
  cv::Mat weight;
  r.Mat().convertTo(weight, CV_64F, -1.0 / (white - black), white / (white - black));
  const int half = static_cast<int>(0.5 * 600.0 * spec.pitch / 0.52) - 1;
  double max_error = 0.0, sum = 0.0;
  for (const Eigen::Vector2d& c : centres) {
    const int u0 = static_cast<int>(std::lround(c.x())) - half,
              v0 = static_cast<int>(std::lround(c.y())) - half;
    const cv::Mat roi = weight(cv::Rect(u0, v0, 2 * half + 1, 2 * half + 1));
    const cv::Moments m = cv::moments(roi);
    const Eigen::Vector2d centroid(u0 + m.m10 / m.m00, v0 + m.m01 / m.m00);
    max_error = std::max(max_error, (centroid - c).norm());
    sum += (centroid - c).norm();
  }
  std::printf("fronto-parallel dots: centroid error mean %.4f px, max %.4f px\n", sum / 35,
              max_error);
  // Bound: the anti-aliasing errors of the ~60 rim pixels of an 18 px dot largely cancel in
  // the centroid; 8-bit rounding adds ≤ 0.5/204 per pixel. 0.02 px is well clear of both.
  EXPECT_LT(max_error, 0.02);
}

// Every built-in model: the board renders without failures, is visible, and each inner corner is
// where the model projects it (the traced pattern around the projected corner pixel shows both
// colours) — and for the perspective Tsai model OpenCV finds it there.
TEST(TargetSceneTest, RendersThroughEveryBuiltinModel) {
  struct Case {
    const char* name;
    double distance;         // m
    Eigen::Vector2d offset;  // from the image centre (px)
  };
  for (const Case& c :
       {Case{"tsai-seed004", 0.9, {60, -40}}, Case{"unified-default", 0.25, {30, 40}},
        Case{"scaramuzza-default", 0.22, {20, -30}}}) {
    SCOPED_TRACE(c.name);
    const std::unique_ptr<CameraModel> camera = BuiltinCameraModel(c.name);
    TargetSpec spec;
    const Eigen::Vector2d pixel =
        Eigen::Vector2d(0.5 * camera->width(), 0.5 * camera->height()) + c.offset;
    const TargetScene scene(spec, BoardPose(*camera, spec, pixel, c.distance, 0.2, kRoll));
    Rendered r = Render(*camera, scene, CornerOptions());
    std::vector<Eigen::Vector2d> corners;
    std::vector<ProjectionStatus> status;
    ASSERT_EQ(scene.ProjectFeatures(*camera, &corners, &status), 48);
    int black = 0, white = 0;
    for (const int id : r.truth.object) {
      black += id == kTargetBlackId;
      white += id == kTargetWhiteId;
    }
    EXPECT_GT(black, 1000);
    EXPECT_GT(white, 1000);
    // Around each projected corner, samples 0.4 px away see black and white.
    for (const Eigen::Vector2d& p : corners) {
      int seen_black = 0, seen_white = 0;
      for (int k = 0; k < 16; ++k) {
        const double angle = 2 * M_PI * (k + 0.5) / 16;
        Ray ray;
        ASSERT_EQ(
            camera->BackProject(p + 0.4 * Eigen::Vector2d(std::cos(angle), std::sin(angle)), &ray),
            ProjectionStatus::kOk);
        const int id = scene.Trace(ray).object;
        seen_black += id == kTargetBlackId;
        seen_white += id == kTargetWhiteId;
      }
      EXPECT_GE(seen_black, 4);
      EXPECT_GE(seen_white, 4);
    }
    if (std::string(c.name) == "tsai-seed004") {
      double mean = 0.0;
      const double max_error = ChessboardDetectionError(*camera, scene, &r, &mean);
      std::printf("tsai chessboard: corner error mean %.4f px, max %.4f px\n", mean, max_error);
      EXPECT_GE(max_error, 0.0) << "not found";
      EXPECT_LT(max_error, 0.1);
    }
  }
}

}  // namespace
}  // namespace kinevis::vision::render
