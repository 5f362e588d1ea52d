#include "vision/camera/unified_camera.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <opencv2/ccalib/omnidir.hpp>
#include <opencv2/core.hpp>
#include <random>
#include <stdexcept>
#include <vector>

#include "common/units.h"
#include "tests/utilities/allocation_counter.h"

namespace kinevis::vision {
namespace {

using ::testing::ContainsRegex;
using ::testing::IsEmpty;

UnifiedParameters Parameters(double xi, bool distorted) {
  UnifiedParameters p;
  p.width = 640;
  p.height = 480;
  p.xi = xi;
  p.gamma1 = 231.0;
  p.gamma2 = 226.5;
  p.skew = 0.7;
  p.u0 = 321.3;
  p.v0 = 238.9;
  if (distorted) p.distortion = {-0.05, 0.01, 1.2e-3, -0.8e-3};
  return p;
}

// Largest angle from +z of the directions the model images, with a margin (rad).
double MaxAngle(double xi, double margin) {
  const double limit = xi <= 1.0 ? std::acos(-xi) : std::acos(-1.0 / xi);
  return std::min(limit, common::kPi) - margin;
}

// Random point whose direction makes an angle <= max_angle with +z, at 0.2..10 m.
Eigen::Vector3d RandomPoint(double max_angle, std::mt19937* rng) {
  std::uniform_real_distribution<double> cos_angle(std::cos(max_angle), 1.0);
  std::uniform_real_distribution<double> azimuth(-common::kPi, common::kPi);
  std::uniform_real_distribution<double> range(0.2, 10.0);
  const double c = cos_angle(*rng);
  const double s = std::sqrt(1.0 - c * c);
  const double a = azimuth(*rng);
  return range(*rng) * Eigen::Vector3d(s * std::cos(a), s * std::sin(a), c);
}

// Points far outside the image (|pixel| ~ 1e5 px at grazing angles of a distorted model) lose
// absolute precision to rounding; the accuracy checks use points that image near the picture.
bool NearImage(const UnifiedCamera& camera, const Eigen::Vector3d& p_C) {
  Eigen::Vector2d pixel;
  if (camera.Project(p_C, &pixel) != ProjectionStatus::kOk) return false;
  return std::abs(pixel.x()) < 3.0 * camera.width() && std::abs(pixel.y()) < 3.0 * camera.height();
}

class UnifiedXiTest : public ::testing::TestWithParam<double> {};

// Oracle: cv::omnidir::projectPoints (rvec = tvec = 0 takes points in C) to 1e-9 px.
TEST_P(UnifiedXiTest, ProjectMatchesOpenCvOmnidir) {
  const double xi = GetParam();
  for (bool distorted : {false, true}) {
    const UnifiedParameters p = Parameters(xi, distorted);
    const UnifiedCamera camera(p);
    std::mt19937 rng(1234);
    std::vector<cv::Vec3d> object;
    // ξ = 0 is a pinhole: keep within 70° of the axis so the distortion stays monotonic.
    const double max_angle = xi == 0.0 ? 70.0 * common::kPi / 180.0 : MaxAngle(xi, 0.1);
    while (object.size() < 500) {
      const Eigen::Vector3d q = RandomPoint(max_angle, &rng);
      if (!NearImage(camera, q)) continue;
      object.emplace_back(q.x(), q.y(), q.z());
    }
    const cv::Matx33d K(p.gamma1, p.skew, p.u0, 0.0, p.gamma2, p.v0, 0.0, 0.0, 1.0);
    const cv::Vec4d D(p.distortion[0], p.distortion[1], p.distortion[2], p.distortion[3]);
    std::vector<cv::Vec2d> image;
    cv::omnidir::projectPoints(object, image, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), K, xi, D);
    double max_error = 0.0;
    for (size_t i = 0; i < object.size(); ++i) {
      Eigen::Vector2d pixel;
      ASSERT_EQ(camera.Project(Eigen::Vector3d(object[i][0], object[i][1], object[i][2]), &pixel),
                ProjectionStatus::kOk)
          << "point " << i;
      max_error = std::max(max_error, (pixel - Eigen::Vector2d(image[i][0], image[i][1])).norm());
    }
    EXPECT_LT(max_error, 1e-9) << "xi " << xi << " distorted " << distorted;
    std::printf("xi %.2f distorted %d: max |pixel - cv::omnidir| = %.2g px\n", xi, distorted,
                max_error);
  }
}

TEST_P(UnifiedXiTest, ProjectJacobianMatchesCentralDifferences) {
  const double xi = GetParam();
  const UnifiedCamera camera(Parameters(xi, true));
  std::mt19937 rng(77);
  const double max_angle = xi == 0.0 ? 70.0 * common::kPi / 180.0 : MaxAngle(xi, 0.1);
  for (int i = 0; i < 200; ++i) {
    const Eigen::Vector3d q = RandomPoint(max_angle, &rng);
    Eigen::Vector2d pixel;
    Matrix23d J;
    ASSERT_EQ(camera.Project(q, &pixel, &J), ProjectionStatus::kOk);
    const double h = 1e-6 * q.norm();
    Matrix23d J_fd;
    for (int k = 0; k < 3; ++k) {
      Eigen::Vector2d plus, minus;
      ASSERT_EQ(camera.Project(q + h * Eigen::Vector3d::Unit(k), &plus), ProjectionStatus::kOk);
      ASSERT_EQ(camera.Project(q - h * Eigen::Vector3d::Unit(k), &minus), ProjectionStatus::kOk);
      J_fd.col(k) = (plus - minus) / (2.0 * h);
    }
    EXPECT_LT((J - J_fd).norm(), 1e-6 * (1.0 + J.norm())) << "point " << q.transpose();
  }
}

TEST_P(UnifiedXiTest, BackProjectInvertsProjectWithJacobian) {
  const double xi = GetParam();
  const UnifiedCamera camera(Parameters(xi, true));
  std::mt19937 rng(99);
  const double max_angle = xi == 0.0 ? 70.0 * common::kPi / 180.0 : MaxAngle(xi, 0.1);
  double max_pixel_error = 0.0, max_direction_error = 0.0;
  for (int i = 0; i < 300; ++i) {
    const Eigen::Vector3d q = RandomPoint(max_angle, &rng);
    if (!NearImage(camera, q)) continue;
    Eigen::Vector2d pixel;
    ASSERT_EQ(camera.Project(q, &pixel), ProjectionStatus::kOk);
    Ray ray;
    RayJacobian J;
    ASSERT_EQ(camera.BackProject(pixel, &ray, &J), ProjectionStatus::kOk);
    EXPECT_EQ(ray.p_C_O, Eigen::Vector3d::Zero());
    EXPECT_NEAR(ray.d_C.norm(), 1.0, 1e-12);
    max_direction_error = std::max(max_direction_error, (ray.d_C - q.normalized()).norm());
    Eigen::Vector2d again;
    ASSERT_EQ(camera.Project(ray.d_C, &again), ProjectionStatus::kOk);
    max_pixel_error = std::max(max_pixel_error, (again - pixel).norm());

    const double h = 1e-4;
    Matrix32d J_fd;
    for (int k = 0; k < 2; ++k) {
      Ray plus, minus;
      ASSERT_EQ(camera.BackProject(pixel + h * Eigen::Vector2d::Unit(k), &plus),
                ProjectionStatus::kOk);
      ASSERT_EQ(camera.BackProject(pixel - h * Eigen::Vector2d::Unit(k), &minus),
                ProjectionStatus::kOk);
      J_fd.col(k) = (plus.d_C - minus.d_C) / (2.0 * h);
    }
    EXPECT_LT((J.d_direction_d_pixel - J_fd).norm(), 1e-7 * (1.0 + J_fd.norm()))
        << "pixel " << pixel.transpose();
    EXPECT_EQ(J.d_origin_d_pixel, Matrix32d::Zero());
  }
  EXPECT_LT(max_direction_error, 1e-12);
  EXPECT_LT(max_pixel_error, 1e-9);
}

// The lifted point agrees with OpenCV's omnidir::undistortPoints, which (OpenCV 4.6) returns the
// perspective-normalised direction X_s.xy / X_s.z, so only directions in front (X_s.z > 0) are
// used.
TEST_P(UnifiedXiTest, LiftAgreesWithOpenCvUndistortPoints) {
  const double xi = GetParam();
  const UnifiedParameters p = Parameters(xi, true);
  const UnifiedCamera camera(p);
  std::mt19937 rng(5);
  const double max_angle = 75.0 * common::kPi / 180.0;
  std::vector<cv::Vec2d> pixels;
  while (pixels.size() < 100) {
    Eigen::Vector2d pixel;
    ASSERT_EQ(camera.Project(RandomPoint(max_angle, &rng), &pixel), ProjectionStatus::kOk);
    // OpenCV's fixed-point undistortion only converges where the distortion is mild.
    if (!camera.InImage(pixel)) continue;
    pixels.emplace_back(pixel.x(), pixel.y());
  }
  const cv::Matx33d K(p.gamma1, p.skew, p.u0, 0.0, p.gamma2, p.v0, 0.0, 0.0, 1.0);
  const cv::Vec4d D(p.distortion[0], p.distortion[1], p.distortion[2], p.distortion[3]);
  std::vector<cv::Vec2d> normalised;
  cv::omnidir::undistortPoints(pixels, normalised, K, D, cv::Mat(1, 1, CV_64F, cv::Scalar(xi)),
                               cv::Matx33d::eye());
  for (size_t i = 0; i < pixels.size(); ++i) {
    Eigen::Vector3d X_s;
    ASSERT_EQ(camera.LiftToSphere(Eigen::Vector2d(pixels[i][0], pixels[i][1]), &X_s),
              ProjectionStatus::kOk);
    const Eigen::Vector2d x_perspective = X_s.head<2>() / X_s.z();
    // OpenCV stops after 20 fixed-point iterations: agreement to 1e-8, not machine precision.
    EXPECT_LT((x_perspective - Eigen::Vector2d(normalised[i][0], normalised[i][1])).norm(), 1e-8);
  }
}

// Points of a 3-D line project onto the conic of its interpretation plane (seed 002 eq. 1–2),
// and eq. (10) recovers the plane's normal from the conic.
TEST_P(UnifiedXiTest, ProjectedLinePointsLieOnLineConic) {
  const double xi = GetParam();
  const UnifiedCamera camera(Parameters(xi, false));
  std::mt19937 rng(2024);
  std::uniform_real_distribution<double> coordinate(-2.0, 2.0);
  int lines = 0;
  for (int attempt = 0; attempt < 200 && lines < 40; ++attempt) {
    // A point of the line in front of the camera, so that part of the line is imaged for ξ = 0.
    const Eigen::Vector3d p_C_L(coordinate(rng), coordinate(rng), 2.0 + coordinate(rng) / 2.0);
    const Eigen::Vector3d u =
        Eigen::Vector3d(coordinate(rng), coordinate(rng), coordinate(rng)).normalized();
    const Eigen::Vector3d n = p_C_L.cross(u).normalized();
    if (std::abs(n.z()) < 0.05) continue;  // keep eq. (10) well conditioned
    Eigen::Matrix3d Omega;
    ASSERT_EQ(camera.LineConic(n, &Omega), LineConicStatus::kOk);
    EXPECT_NEAR(Omega.norm(), 1.0, 1e-12);
    int on_line = 0;
    for (double t = -5.0; t <= 5.0; t += 0.25) {
      Eigen::Vector2d pixel;
      if (camera.Project(p_C_L + t * u, &pixel) != ProjectionStatus::kOk) continue;
      const Eigen::Vector3d m(pixel.x(), pixel.y(), 1.0);
      // Relative to scale: |mᵀ Ω m| / (|Ω| |m|²) with |Ω| = 1.
      EXPECT_LT(std::abs(m.dot(Omega * m)) / m.squaredNorm(), 1e-12) << "t " << t;
      ++on_line;
    }
    EXPECT_GT(on_line, 3);
    Eigen::Vector3d n_back;
    ASSERT_EQ(camera.InterpretationNormal(-3.0 * Omega, &n_back), LineConicStatus::kOk);
    EXPECT_LT((n_back - (n.z() > 0.0 ? n : Eigen::Vector3d(-n))).norm(), 1e-9);
    ++lines;
  }
  EXPECT_EQ(lines, 40);
}

INSTANTIATE_TEST_SUITE_P(Xi, UnifiedXiTest, ::testing::Values(0.0, 0.45, 0.8, 1.0, 1.6));

TEST(UnifiedCameraTest, LineConicNeedsADistortionFreeModelAndAUnitNormal) {
  const UnifiedCamera distorted(Parameters(0.8, true));
  Eigen::Matrix3d Omega;
  Eigen::Vector3d n;
  EXPECT_EQ(distorted.LineConic(Eigen::Vector3d(0.6, 0.0, 0.8), &Omega),
            LineConicStatus::kDistorted);
  EXPECT_EQ(distorted.InterpretationNormal(Eigen::Matrix3d::Identity(), &n),
            LineConicStatus::kDistorted);
  const UnifiedCamera camera(Parameters(0.8, false));
  EXPECT_EQ(camera.LineConic(Eigen::Vector3d(0.6, 0.0, 0.9), &Omega),
            LineConicStatus::kInvalidInput);
  // A plane containing the mirror axis: the image is a line through the principal point, and
  // eq. (10) cannot recover n from the (zero) third column.
  ASSERT_EQ(camera.LineConic(Eigen::Vector3d(0.6, 0.8, 0.0), &Omega), LineConicStatus::kOk);
  EXPECT_EQ(camera.InterpretationNormal(Omega, &n), LineConicStatus::kDegenerate);
  // Parabolic mirror and n_z = 0: the conic matrix vanishes altogether.
  const UnifiedCamera parabolic(Parameters(1.0, false));
  EXPECT_EQ(parabolic.LineConic(Eigen::Vector3d(0.6, 0.8, 0.0), &Omega),
            LineConicStatus::kDegenerate);
}

TEST(UnifiedCameraTest, DomainOfTheModel) {
  Eigen::Vector2d pixel;
  Ray ray;
  // ξ < 1: directions with X_s.z + ξ <= 0 are behind the optics.
  const UnifiedCamera hyperbolic(Parameters(0.5, false));
  EXPECT_EQ(hyperbolic.Project(Eigen::Vector3d(0.8, 0.0, -0.6), &pixel),
            ProjectionStatus::kBehindCamera);
  EXPECT_EQ(hyperbolic.Project(Eigen::Vector3d(0.8, 0.0, -0.4), &pixel), ProjectionStatus::kOk);
  EXPECT_EQ(hyperbolic.Project(Eigen::Vector3d::Zero(), &pixel), ProjectionStatus::kOutsideDomain);
  // Parabolic: everything but the -z direction.
  const UnifiedCamera parabolic(Parameters(1.0, false));
  EXPECT_EQ(parabolic.Project(Eigen::Vector3d(0.0, 0.0, -2.0), &pixel),
            ProjectionStatus::kBehindCamera);
  EXPECT_EQ(parabolic.Project(Eigen::Vector3d(0.05, 0.0, -2.0), &pixel), ProjectionStatus::kOk);
  // ξ > 1: only X_s.z > -1/ξ; pixels outside the image of the sphere (r² > 1/(ξ²-1)) have no ray.
  const double xi = 1.6;
  const UnifiedCamera fisheye(Parameters(xi, false));
  const double z_edge = -1.0 / xi;
  const double s_edge = std::sqrt(1.0 - z_edge * z_edge);
  EXPECT_EQ(fisheye.Project(Eigen::Vector3d(s_edge, 0.0, z_edge - 0.01), &pixel),
            ProjectionStatus::kOutsideDomain);
  EXPECT_EQ(fisheye.Project(Eigen::Vector3d(s_edge, 0.0, z_edge + 0.01), &pixel),
            ProjectionStatus::kOk);
  const double r_edge = 1.0 / std::sqrt(xi * xi - 1.0);  // normalised radius of the sphere's rim
  const UnifiedParameters p = fisheye.parameters();
  EXPECT_EQ(fisheye.BackProject(Eigen::Vector2d(p.u0, p.v0 + p.gamma2 * r_edge * 1.001), &ray),
            ProjectionStatus::kOutsideDomain);
  EXPECT_EQ(fisheye.BackProject(Eigen::Vector2d(p.u0, p.v0 + p.gamma2 * r_edge * 0.999), &ray),
            ProjectionStatus::kOk);
  EXPECT_NEAR(ray.d_C.z(), z_edge, 0.05);
}

TEST(UnifiedCameraTest, ValidateNamesEveryBadField) {
  EXPECT_THAT(UnifiedCamera(UnifiedParameters::Default()).Validate(), IsEmpty());
  UnifiedParameters p = UnifiedParameters::Default();
  p.width = 0;
  p.xi = -0.5;
  p.gamma1 = 0.0;
  p.distortion[1] = std::nan("");
  try {
    UnifiedCamera camera(p);
    FAIL() << "expected std::invalid_argument";
  } catch (const std::invalid_argument& e) {
    const std::string message = e.what();
    EXPECT_THAT(message, ContainsRegex("width = 0"));
    EXPECT_THAT(message, ContainsRegex("xi = -0.5"));
    EXPECT_THAT(message, ContainsRegex("gamma1 = 0"));
    EXPECT_THAT(message, ContainsRegex("k2 = nan"));
    EXPECT_THAT(message, ::testing::Not(ContainsRegex("gamma2")));
  }
}

TEST(UnifiedCameraTest, ProjectAndBackProjectDoNotAllocate) {
  const UnifiedCamera camera(Parameters(0.8, true));
  const UnifiedCamera undistorted(Parameters(0.8, false));
  Eigen::Vector2d pixel;
  Matrix23d J;
  Ray ray;
  RayJacobian J_ray;
  Eigen::Matrix3d Omega;
  Eigen::Vector3d n;
  int failures = 0;
  const long before = testing::ThreadAllocations();
  for (int i = 0; i < 100; ++i) {
    const Eigen::Vector3d q(0.3 + 0.01 * i, -0.2, 1.0);
    failures += camera.Project(q, &pixel, &J) != ProjectionStatus::kOk;
    failures += camera.BackProject(pixel, &ray, &J_ray) != ProjectionStatus::kOk;
    failures += undistorted.LineConic(q.cross(Eigen::Vector3d::UnitX()).normalized(), &Omega) !=
                LineConicStatus::kOk;
    failures += undistorted.InterpretationNormal(Omega, &n) != LineConicStatus::kOk;
  }
  const long allocations = testing::ThreadAllocations() - before;
  EXPECT_EQ(failures, 0);
  EXPECT_EQ(allocations, 0);
}

}  // namespace
}  // namespace kinevis::vision
