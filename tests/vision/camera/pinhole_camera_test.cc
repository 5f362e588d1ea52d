#include "vision/camera/pinhole_camera.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "tests/utilities/allocation_counter.h"

namespace kinevis::vision {
namespace {

using ::testing::ContainsRegex;
using ::testing::IsEmpty;

struct NamedParameters {
  const char* name;
  PinholeBrownParameters parameters;
};

// Plain Brown (5 coefficients), a 1280×960 industrial camera.
PinholeBrownParameters Brown5() {
  PinholeBrownParameters p;
  p.width = 1280;
  p.height = 960;
  p.fx = 1000.0;
  p.fy = 1005.0;
  p.cx = 640.3;
  p.cy = 479.7;
  p.distortion = {-0.28, 0.09, 1e-3, -5e-4, -0.01, 0.0, 0.0, 0.0};
  return p;
}

// OpenCV's rational model (8 coefficients), 18 % barrel in the corners of a 1280×720 image.
PinholeBrownParameters Rational8() {
  PinholeBrownParameters p;
  p.width = 1280;
  p.height = 720;
  p.fx = 900.0;
  p.fy = 900.0;
  p.cx = 652.0;
  p.cy = 356.0;
  p.distortion = {2.5, -0.3, 2e-4, -1e-4, -0.05, 2.85, 0.05, -0.08};
  return p;
}

// Strong barrel of a wide lens: 1920×1080, 123° diagonal field of view, 26 % barrel in the
// corners; the polynomial folds at r = 2.28 (distorted radius 1.68), beyond the corners (1.38).
PinholeBrownParameters WideBarrel() {
  PinholeBrownParameters p;
  p.width = 1920;
  p.height = 1080;
  p.fx = 800.0;
  p.fy = 800.0;
  p.cx = 961.0;
  p.cy = 541.0;
  p.distortion = {-0.3, 0.1, 3e-4, -2e-4, -0.01, 0.0, 0.0, 0.0};
  return p;
}

std::vector<NamedParameters> AllParameterSets() {
  return {{"brown5", Brown5()}, {"rational8", Rational8()}, {"wide_barrel", WideBarrel()}};
}

// cv::projectPoints with rvec = tvec = 0: the pixel of p_C and, from the columns of the Jacobian
// for tvec, ∂pixel/∂p_C.
void OpenCvProject(const PinholeBrownParameters& p, const std::vector<cv::Point3d>& points,
                   std::vector<cv::Point2d>* pixels, cv::Mat* J_pixel_point) {
  const cv::Mat K = (cv::Mat_<double>(3, 3) << p.fx, 0.0, p.cx, 0.0, p.fy, p.cy, 0.0, 0.0, 1.0);
  const cv::Mat D(1, 8, CV_64F, const_cast<double*>(p.distortion.data()));
  const cv::Mat zero = cv::Mat::zeros(3, 1, CV_64F);
  cv::Mat jacobian;
  cv::projectPoints(points, zero, zero, K, D, *pixels, jacobian);
  *J_pixel_point = jacobian.colRange(3, 6).clone();
}

// Points in front of the camera: directions uniform over a disk of normalised radius
// `max_radius`, depths 0.2–5 m.
std::vector<Eigen::Vector3d> RandomPoints(int count, double max_radius, std::mt19937* rng) {
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::uniform_real_distribution<double> depth(0.2, 5.0);
  std::vector<Eigen::Vector3d> points;
  for (int i = 0; i < count; ++i) {
    const double r = max_radius * std::sqrt(unit(*rng));
    const double angle = 2.0 * M_PI * unit(*rng);
    const double z = depth(*rng);
    points.emplace_back(z * r * std::cos(angle), z * r * std::sin(angle), z);
  }
  return points;
}

// Pixels on a grid over the whole image, edges included.
std::vector<Eigen::Vector2d> ImageGrid(const CameraModel& camera, double step) {
  std::vector<Eigen::Vector2d> pixels;
  const double u_end = camera.width() - 0.5 - 1e-9;
  const double v_end = camera.height() - 0.5 - 1e-9;
  for (double v = -0.5;; v = std::min(v + step, v_end)) {
    for (double u = -0.5;; u = std::min(u + step, u_end)) {
      pixels.emplace_back(u, v);
      if (u == u_end) break;
    }
    if (v == v_end) break;
  }
  return pixels;
}

class PinholeBrownSetTest : public ::testing::TestWithParam<NamedParameters> {};

INSTANTIATE_TEST_SUITE_P(ParameterSets, PinholeBrownSetTest,
                         ::testing::ValuesIn(AllParameterSets()),
                         [](const auto& info) { return std::string(info.param.name); });

TEST_P(PinholeBrownSetTest, ProjectEqualsOpenCvProjectPoints) {
  const PinholeBrownCamera camera(GetParam().parameters);
  std::mt19937 rng(20240611);
  // Directions out to 98 % of the domain (far beyond the image for the milder sets), plus
  // directions of random pixels in the image.
  std::vector<Eigen::Vector3d> points =
      RandomPoints(1000, 0.98 * std::min(camera.max_undistorted_radius(), 3.0), &rng);
  std::uniform_real_distribution<double> u(-0.5, camera.width() - 0.5);
  std::uniform_real_distribution<double> v(-0.5, camera.height() - 0.5);
  std::uniform_real_distribution<double> depth(0.2, 5.0);
  for (int i = 0; i < 1000; ++i) {
    Ray ray;
    ASSERT_EQ(camera.BackProject({u(rng), v(rng)}, &ray), ProjectionStatus::kOk);
    points.push_back(ray.d_C * depth(rng));
  }
  std::vector<cv::Point3d> cv_points;
  std::vector<Eigen::Vector2d> pixels;
  std::vector<Matrix23d> jacobians;
  for (const Eigen::Vector3d& p_C : points) {
    Eigen::Vector2d pixel;
    Matrix23d J;
    // Inside the radial domain only a tangential fold could refuse a point; these sets have none.
    ASSERT_EQ(camera.Project(p_C, &pixel, &J), ProjectionStatus::kOk) << p_C.transpose();
    cv_points.emplace_back(p_C.x(), p_C.y(), p_C.z());
    pixels.push_back(pixel);
    jacobians.push_back(J);
  }
  std::vector<cv::Point2d> cv_pixels;
  cv::Mat cv_J;
  OpenCvProject(GetParam().parameters, cv_points, &cv_pixels, &cv_J);
  double max_error_px = 0.0;
  double max_jacobian_relative_error = 0.0;
  for (size_t i = 0; i < points.size(); ++i) {
    const double error =
        (pixels[i] - Eigen::Vector2d(cv_pixels[i].x, cv_pixels[i].y)).lpNorm<Eigen::Infinity>();
    max_error_px = std::max(max_error_px, error);
    EXPECT_LT(error, 1e-9) << "point " << points[i].transpose();
    Matrix23d J_cv;
    for (int r = 0; r < 2; ++r) {
      for (int c = 0; c < 3; ++c) J_cv(r, c) = cv_J.at<double>(2 * i + r, c);
    }
    const double relative =
        (jacobians[i] - J_cv).lpNorm<Eigen::Infinity>() / J_cv.lpNorm<Eigen::Infinity>();
    max_jacobian_relative_error = std::max(max_jacobian_relative_error, relative);
    EXPECT_LT(relative, 1e-10) << "point " << points[i].transpose();
  }
  std::printf(
      "[ %s ] max |pixel - cv::projectPoints| = %.3g px, max relative Jacobian "
      "difference = %.3g over %zu points\n",
      GetParam().name, max_error_px, max_jacobian_relative_error, points.size());
}

TEST_P(PinholeBrownSetTest, BackProjectThenProjectReturnsThePixelOverTheWholeImage) {
  const PinholeBrownCamera camera(GetParam().parameters);
  double max_error_px = 0.0;
  const std::vector<Eigen::Vector2d> grid = ImageGrid(camera, 7.0);
  for (const Eigen::Vector2d& pixel : grid) {
    Ray ray;
    ASSERT_EQ(camera.BackProject(pixel, &ray), ProjectionStatus::kOk) << pixel.transpose();
    EXPECT_NEAR(ray.d_C.norm(), 1.0, 1e-15);
    EXPECT_EQ(ray.p_C_O, Eigen::Vector3d::Zero());
    Eigen::Vector2d reprojected;
    ASSERT_EQ(camera.Project(ray.p_C_O + 2.0 * ray.d_C, &reprojected), ProjectionStatus::kOk);
    const double error = (reprojected - pixel).norm();
    max_error_px = std::max(max_error_px, error);
    EXPECT_LT(error, 1e-9) << "pixel " << pixel.transpose();
  }
  std::printf("[ %s ] round trip over %zu pixels: max error %.3g px\n", GetParam().name,
              grid.size(), max_error_px);
}

// cv::undistortPoints is OpenCV's fixed-point iteration x' <- (x'' - tangential(x')) / radial(x').
// Where it converges (its result reprojects onto the pixel) it must agree with our Newton solve;
// OpenCV's default of 5 iterations is reported for comparison (not asserted).
TEST_P(PinholeBrownSetTest, BackProjectAgreesWithOpenCvUndistortPointsWhereThatConverges) {
  const PinholeBrownParameters& p = GetParam().parameters;
  const PinholeBrownCamera camera(p);
  const std::vector<Eigen::Vector2d> grid = ImageGrid(camera, 23.0);
  std::vector<cv::Point2d> cv_pixels;
  for (const Eigen::Vector2d& pixel : grid) cv_pixels.emplace_back(pixel.x(), pixel.y());
  const cv::Mat K = (cv::Mat_<double>(3, 3) << p.fx, 0.0, p.cx, 0.0, p.fy, p.cy, 0.0, 0.0, 1.0);
  const cv::Mat D(1, 8, CV_64F, const_cast<double*>(p.distortion.data()));
  std::vector<cv::Point2d> fixed_point, default_5;
  cv::undistortPoints(cv_pixels, fixed_point, K, D, cv::noArray(), cv::noArray(),
                      cv::TermCriteria(cv::TermCriteria::COUNT, 1000, 0.0));
  cv::undistortPoints(cv_pixels, default_5, K, D);
  int converged = 0;
  double max_difference_px = 0.0;
  double max_default_error_px = 0.0;
  for (size_t i = 0; i < grid.size(); ++i) {
    Ray ray;
    ASSERT_EQ(camera.BackProject(grid[i], &ray), ProjectionStatus::kOk);
    const Eigen::Vector2d ours = ray.d_C.head<2>() / ray.d_C.z();
    const auto to_px = [&p](const Eigen::Vector2d& d) {
      return Eigen::Vector2d(p.fx * d.x(), p.fy * d.y()).norm();
    };
    max_default_error_px = std::max(max_default_error_px,
                                    to_px(ours - Eigen::Vector2d(default_5[i].x, default_5[i].y)));
    const Eigen::Vector2d theirs(fixed_point[i].x, fixed_point[i].y);
    Eigen::Vector2d reprojected;
    if (camera.Project(Eigen::Vector3d(theirs.x(), theirs.y(), 1.0), &reprojected) !=
            ProjectionStatus::kOk ||
        (reprojected - grid[i]).norm() > 1e-9) {
      continue;  // the fixed point did not converge here
    }
    ++converged;
    max_difference_px = std::max(max_difference_px, to_px(ours - theirs));
    EXPECT_LT(to_px(ours - theirs), 1e-9) << "pixel " << grid[i].transpose();
  }
  std::printf(
      "[ %s ] undistortPoints (1000 iterations) converged at %d of %zu pixels, max difference "
      "%.3g px; with OpenCV's default 5 iterations the error reaches %.3g px\n",
      GetParam().name, converged, grid.size(), max_difference_px, max_default_error_px);
  EXPECT_GT(converged, static_cast<int>(grid.size()) / 2);
}

TEST_P(PinholeBrownSetTest, ProjectJacobianMatchesCentralDifferences) {
  const PinholeBrownCamera camera(GetParam().parameters);
  std::mt19937 rng(7);
  const double radius = 0.95 * std::min(camera.max_undistorted_radius(), 3.0);
  for (const Eigen::Vector3d& p_C : RandomPoints(300, radius, &rng)) {
    Eigen::Vector2d pixel;
    Matrix23d J;
    ASSERT_EQ(camera.Project(p_C, &pixel, &J), ProjectionStatus::kOk);
    Matrix23d J_numeric;
    const double h = 1e-6 * p_C.z();
    for (int c = 0; c < 3; ++c) {
      Eigen::Vector2d plus, minus;
      ASSERT_EQ(camera.Project(p_C + h * Eigen::Vector3d::Unit(c), &plus), ProjectionStatus::kOk);
      ASSERT_EQ(camera.Project(p_C - h * Eigen::Vector3d::Unit(c), &minus), ProjectionStatus::kOk);
      J_numeric.col(c) = (plus - minus) / (2.0 * h);
    }
    EXPECT_LT((J - J_numeric).lpNorm<Eigen::Infinity>(), 1e-6 * J.lpNorm<Eigen::Infinity>())
        << "at " << p_C.transpose() << "\nanalytic\n"
        << J << "\nnumeric\n"
        << J_numeric;
  }
}

TEST_P(PinholeBrownSetTest, BackProjectJacobianMatchesCentralDifferences) {
  const PinholeBrownCamera camera(GetParam().parameters);
  const double h = 1e-3;  // pixels
  for (const Eigen::Vector2d& pixel : ImageGrid(camera, 97.0)) {
    Ray ray;
    RayJacobian J;
    ASSERT_EQ(camera.BackProject(pixel, &ray, &J), ProjectionStatus::kOk);
    EXPECT_EQ(J.d_origin_d_pixel, Matrix32d::Zero());
    Matrix32d J_numeric;
    for (int c = 0; c < 2; ++c) {
      Ray plus, minus;
      ASSERT_EQ(camera.BackProject(pixel + h * Eigen::Vector2d::Unit(c), &plus),
                ProjectionStatus::kOk);
      ASSERT_EQ(camera.BackProject(pixel - h * Eigen::Vector2d::Unit(c), &minus),
                ProjectionStatus::kOk);
      J_numeric.col(c) = (plus.d_C - minus.d_C) / (2.0 * h);
    }
    EXPECT_LT((J.d_direction_d_pixel - J_numeric).lpNorm<Eigen::Infinity>(),
              1e-7 * J.d_direction_d_pixel.lpNorm<Eigen::Infinity>())
        << "at " << pixel.transpose() << "\nanalytic\n"
        << J.d_direction_d_pixel << "\nnumeric\n"
        << J_numeric;
  }
}

TEST_P(PinholeBrownSetTest, ProjectAndBackProjectDoNotAllocate) {
  const PinholeBrownCamera camera(GetParam().parameters);
  const std::vector<Eigen::Vector2d> grid = ImageGrid(camera, 61.0);
  Ray ray;
  RayJacobian J_ray;
  Eigen::Vector2d pixel;
  Matrix23d J_pixel;
  int ok = 0;
  const long before = testing::ThreadAllocations();
  for (const Eigen::Vector2d& p : grid) {
    ok += camera.BackProject(p, &ray, &J_ray) == ProjectionStatus::kOk;
    ok += camera.Project(3.0 * ray.d_C, &pixel, &J_pixel) == ProjectionStatus::kOk;
  }
  // Failure paths too.
  ok += camera.Project({0.0, 0.0, -1.0}, &pixel, &J_pixel) == ProjectionStatus::kOk;
  ok += camera.BackProject({1e7, 1e7}, &ray, &J_ray) == ProjectionStatus::kOk;
  EXPECT_EQ(testing::ThreadAllocations() - before, 0);
  EXPECT_EQ(ok, 2 * static_cast<int>(grid.size()));
}

TEST(PinholeBrownCameraTest, WithoutDistortionIsThePlainPinhole) {
  PinholeBrownParameters p = Brown5();
  p.distortion.fill(0.0);
  const PinholeBrownCamera camera(p);
  EXPECT_EQ(camera.max_undistorted_radius(), std::numeric_limits<double>::infinity());
  Eigen::Vector2d pixel;
  Matrix23d J;
  ASSERT_EQ(camera.Project({0.3, -0.2, 2.0}, &pixel, &J), ProjectionStatus::kOk);
  EXPECT_NEAR(pixel.x(), 640.3 + 1000.0 * 0.15, 1e-12);
  EXPECT_NEAR(pixel.y(), 479.7 - 1005.0 * 0.1, 1e-12);
  Matrix23d expected;
  expected << 500.0, 0.0, -75.0, 0.0, 502.5, 50.25;
  EXPECT_LT((J - expected).lpNorm<Eigen::Infinity>(), 1e-12);
}

TEST(PinholeBrownCameraTest, PointsNotInFrontAreBehindCamera) {
  const PinholeBrownCamera camera(Brown5());
  Eigen::Vector2d pixel;
  EXPECT_EQ(camera.Project({0.1, 0.1, 0.0}, &pixel), ProjectionStatus::kBehindCamera);
  EXPECT_EQ(camera.Project({0.1, 0.1, -2.0}, &pixel), ProjectionStatus::kBehindCamera);
  EXPECT_EQ(camera.Project({0.0, 0.0, -1e-12}, &pixel), ProjectionStatus::kBehindCamera);
  EXPECT_EQ(camera.Project({0.0, 0.0, std::nan("")}, &pixel), ProjectionStatus::kBehindCamera);
  EXPECT_EQ(camera.Project({0.0, 0.0, 1e-9}, &pixel), ProjectionStatus::kOk);
}

// Barrel distortion k1 < 0 alone: r(1 + k1 r²) increases up to r = 1/sqrt(-3 k1) and reaches the
// distorted radius (2/3) r there; nothing beyond either is a lens.
TEST(PinholeBrownCameraTest, TheFoldOfTheDistortionBoundsTheDomain) {
  PinholeBrownParameters p = Brown5();
  p.distortion = {-0.35, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0};
  const PinholeBrownCamera camera(p);
  const double r_fold = 1.0 / std::sqrt(3.0 * 0.35);
  EXPECT_NEAR(camera.max_undistorted_radius(), r_fold, 1e-12);
  Eigen::Vector2d pixel;
  EXPECT_EQ(camera.Project({0.99 * r_fold, 0.0, 1.0}, &pixel), ProjectionStatus::kOk);
  EXPECT_EQ(camera.Project({0.0, 1.01 * r_fold, 1.0}, &pixel), ProjectionStatus::kOutsideDomain);
  EXPECT_EQ(camera.Project({3.0, 3.0, 1.0}, &pixel), ProjectionStatus::kOutsideDomain);

  const double rho_fold = 2.0 / 3.0 * r_fold;  // largest distorted radius
  Ray ray;
  // Just inside the fold: Newton still converges (the map is nearly flat there).
  const Eigen::Vector2d inside(p.cx + 0.999 * rho_fold * p.fx, p.cy);
  ASSERT_EQ(camera.BackProject(inside, &ray), ProjectionStatus::kOk);
  ASSERT_EQ(camera.Project(ray.d_C, &pixel), ProjectionStatus::kOk);
  EXPECT_LT((pixel - inside).norm(), 1e-9);
  // Beyond it no direction maps there.
  EXPECT_EQ(camera.BackProject({p.cx + 1.001 * rho_fold * p.fx, p.cy}, &ray),
            ProjectionStatus::kOutsideDomain);
  EXPECT_EQ(camera.BackProject({p.cx + 0.8 * rho_fold * p.fx, p.cy + 0.8 * rho_fold * p.fy}, &ray),
            ProjectionStatus::kOutsideDomain);
}

TEST(PinholeBrownCameraTest, WideBarrelFoldsBeyondTheImageCorners) {
  const PinholeBrownCamera camera(WideBarrel());
  EXPECT_NEAR(camera.max_undistorted_radius(), 2.281, 2e-3);
  Ray ray;
  // Distorted radius 1.8 > 1.683, the largest the polynomial reaches.
  EXPECT_EQ(camera.BackProject({961.0 + 1.8 * 800.0, 541.0}, &ray),
            ProjectionStatus::kOutsideDomain);
}

// Pincushion (k1 > 0) never folds radially, and the undistorted point lies inside the distorted
// one: Newton must still converge from the distorted starting point.
TEST(PinholeBrownCameraTest, PincushionRoundTrip) {
  PinholeBrownParameters p = Brown5();
  p.distortion = {0.4, 0.2, 0.0, 0.0, 0.05, 0.0, 0.0, 0.0};
  const PinholeBrownCamera camera(p);
  EXPECT_EQ(camera.max_undistorted_radius(), std::numeric_limits<double>::infinity());
  for (const Eigen::Vector2d& pixel : ImageGrid(camera, 53.0)) {
    Ray ray;
    ASSERT_EQ(camera.BackProject(pixel, &ray), ProjectionStatus::kOk);
    Eigen::Vector2d reprojected;
    ASSERT_EQ(camera.Project(ray.d_C, &reprojected), ProjectionStatus::kOk);
    EXPECT_LT((reprojected - pixel).norm(), 1e-9);
  }
}

TEST(PinholeBrownCameraTest, ValidateNamesEveryBadFieldWithItsValue) {
  PinholeBrownParameters p = Brown5();
  ASSERT_THAT(PinholeBrownCamera(p).Validate(), IsEmpty());
  p.width = 0;
  p.height = -3;
  p.fx = -1000.0;
  p.fy = std::numeric_limits<double>::infinity();
  p.cy = std::nan("");
  p.distortion[4] = std::numeric_limits<double>::infinity();
  p.distortion[7] = std::nan("");
  try {
    PinholeBrownCamera camera(p);
    FAIL() << "constructor accepted bad parameters";
  } catch (const std::invalid_argument& e) {
    const std::string message = e.what();
    EXPECT_THAT(message, ContainsRegex("^pinhole-brown camera: "));
    EXPECT_THAT(message, ContainsRegex("width = 0 must be > 0"));
    EXPECT_THAT(message, ContainsRegex("height = -3 must be > 0"));
    EXPECT_THAT(message, ContainsRegex("fx = -1000 must be finite and > 0"));
    EXPECT_THAT(message, ContainsRegex("fy = inf must be finite and > 0"));
    EXPECT_THAT(message, ContainsRegex("cy = nan is not finite"));
    EXPECT_THAT(message, ContainsRegex("distortion\\[4\\] \\(k3\\) = inf is not finite"));
    EXPECT_THAT(message, ContainsRegex("distortion\\[7\\] \\(k6\\) = nan is not finite"));
    EXPECT_THAT(message, ::testing::Not(ContainsRegex("cx =")));
    EXPECT_THAT(message, ::testing::Not(ContainsRegex("; $")));
  }
}

TEST(PinholeBrownCameraTest, NameAndImage) {
  const PinholeBrownCamera camera(Brown5());
  EXPECT_EQ(camera.Name(), "pinhole-brown");
  EXPECT_TRUE(camera.IsCentral());
  EXPECT_EQ(camera.width(), 1280);
  EXPECT_EQ(camera.height(), 960);
  EXPECT_EQ(camera.parameters().distortion[0], -0.28);
}

}  // namespace
}  // namespace kinevis::vision
