#include "vision/camera/scaramuzza_camera.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <stdexcept>

#include "common/units.h"
#include "tests/utilities/allocation_counter.h"

namespace kinevis::vision {
namespace {

using ::testing::ContainsRegex;
using ::testing::IsEmpty;

// The default calibration, and a variant with a1 != 0 and a stronger affine part and a rim
// radius (catadioptric-like) to exercise every term.
ScaramuzzaParameters Variant(int which) {
  ScaramuzzaParameters p = ScaramuzzaParameters::Default();
  if (which == 1) {
    p.poly[1] = 0.05;
    p.c = 1.01;
    p.d = -0.004;
    p.e = 0.006;
    p.max_radius_px = 235.0;
  }
  return p;
}

// Random pixel whose ideal radius is below `fraction` of the valid radius.
Eigen::Vector2d RandomPixel(const ScaramuzzaCamera& camera, double fraction, std::mt19937* rng) {
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  for (;;) {
    const Eigen::Vector2d pixel(camera.parameters().u0 + 500.0 * unit(*rng),
                                camera.parameters().v0 + 500.0 * unit(*rng));
    Ray ray;
    if (camera.BackProject(pixel, &ray) != ProjectionStatus::kOk) continue;
    // Keep away from the rim by angle: re-test a slightly enlarged radius.
    const Eigen::Vector2d centre(camera.parameters().u0, camera.parameters().v0);
    if (camera.BackProject(centre + (pixel - centre) / fraction, &ray) == ProjectionStatus::kOk) {
      return pixel;
    }
  }
}

class ScaramuzzaVariantTest : public ::testing::TestWithParam<int> {};

// The inverse polynomial fitted at construction stays within 0.01 px over a sweep of 100001 radii
// (12x denser than the construction's own sweep), both as a function and through Project().
TEST_P(ScaramuzzaVariantTest, FittedInverseWithinTolerance) {
  const ScaramuzzaCamera camera(Variant(GetParam()), ScaramuzzaProjection::kInversePolynomial);
  const InverseFit& fit = camera.inverse_fit();
  ASSERT_TRUE(fit.fitted);
  EXPECT_GT(fit.degree, 2);
  EXPECT_LE(fit.max_error_px, 0.01);
  const ScaramuzzaParameters& p = camera.parameters();
  double max_radius_error = 0.0;
  for (int i = 0; i <= 100000; ++i) {
    const double rho = fit.max_radius_px * i / 100000.0;
    const double f =
        p.poly[0] + rho * (p.poly[1] + rho * (p.poly[2] + rho * (p.poly[3] + rho * p.poly[4])));
    const double phi = std::atan2(rho, -f);
    max_radius_error = std::max(max_radius_error, std::abs(camera.FittedRadius(phi) - rho));
  }
  EXPECT_LE(max_radius_error, 0.01 / 1.02);  // σ_max(A) <= 1.02 for these variants
  // Through the camera: pixel -> ray (exact) -> pixel (fitted inverse), along 8 azimuths.
  double max_pixel_error = 0.0;
  const Eigen::Vector2d centre(p.u0, p.v0);
  for (int k = 0; k < 8; ++k) {
    const Eigen::Vector2d direction(std::cos(k * common::kPi / 4.0 + 0.1),
                                    std::sin(k * common::kPi / 4.0 + 0.1));
    for (int i = 0; i <= 20000; ++i) {
      const Eigen::Vector2d pixel = centre + direction * (0.99 * fit.max_radius_px * i / 20000.0);
      Ray ray;
      if (camera.BackProject(pixel, &ray) != ProjectionStatus::kOk) continue;
      Eigen::Vector2d again;
      ASSERT_EQ(camera.Project(ray.d_C, &again), ProjectionStatus::kOk);
      max_pixel_error = std::max(max_pixel_error, (again - pixel).norm());
    }
  }
  EXPECT_LE(max_pixel_error, 0.01);
  EXPECT_GT(max_pixel_error, 1e-6);  // the polynomial alone is not exact: the next test refines
  std::printf(
      "variant %d: degree %d, fit max error %.3g px (construction), %.3g px along the "
      "radius, %.3g px through Project; rho_max %.1f px, phi_max %.1f deg\n",
      GetParam(), fit.degree, fit.max_error_px, max_radius_error, max_pixel_error,
      fit.max_radius_px, fit.max_angle * 180.0 / common::kPi);
}

TEST_P(ScaramuzzaVariantTest, RefinedProjectionRoundTripsToMicroPixels) {
  const ScaramuzzaCamera camera(Variant(GetParam()));
  std::mt19937 rng(31);
  double max_pixel_error = 0.0, max_direction_error = 0.0;
  for (int i = 0; i < 2000; ++i) {
    const Eigen::Vector2d pixel = RandomPixel(camera, 0.999, &rng);
    Ray ray;
    ASSERT_EQ(camera.BackProject(pixel, &ray), ProjectionStatus::kOk);
    EXPECT_EQ(ray.p_C_O, Eigen::Vector3d::Zero());
    EXPECT_NEAR(ray.d_C.norm(), 1.0, 1e-12);
    Eigen::Vector2d again;
    ASSERT_EQ(camera.Project(3.7 * ray.d_C, &again), ProjectionStatus::kOk);
    max_pixel_error = std::max(max_pixel_error, (again - pixel).norm());
    Ray ray_again;
    ASSERT_EQ(camera.BackProject(again, &ray_again), ProjectionStatus::kOk);
    max_direction_error = std::max(max_direction_error, (ray_again.d_C - ray.d_C).norm());
  }
  EXPECT_LT(max_pixel_error, 1e-6);
  EXPECT_LT(max_direction_error, 1e-9);
  std::printf("variant %d: refined round trip max %.3g px\n", GetParam(), max_pixel_error);
}

// Project's Jacobian (both methods) and BackProject's against central differences, including
// points on and next to the axis.
TEST_P(ScaramuzzaVariantTest, JacobiansMatchCentralDifferences) {
  for (ScaramuzzaProjection method :
       {ScaramuzzaProjection::kRefined, ScaramuzzaProjection::kInversePolynomial}) {
    const ScaramuzzaCamera camera(Variant(GetParam()), method);
    std::mt19937 rng(8);
    for (int i = 0; i < 300; ++i) {
      const Eigen::Vector2d pixel =
          i == 0 ? Eigen::Vector2d(camera.parameters().u0, camera.parameters().v0)
                 : RandomPixel(camera, 0.98, &rng);
      Ray ray;
      RayJacobian J_ray;
      ASSERT_EQ(camera.BackProject(pixel, &ray, &J_ray), ProjectionStatus::kOk);
      // Back-projection (skip the centre pixel when a1 != 0: not differentiable there).
      if (!(i == 0 && camera.parameters().poly[1] != 0.0)) {
        const double h = 1e-3;
        Matrix32d J_fd;
        for (int k = 0; k < 2; ++k) {
          Ray plus, minus;
          ASSERT_EQ(camera.BackProject(pixel + h * Eigen::Vector2d::Unit(k), &plus),
                    ProjectionStatus::kOk);
          ASSERT_EQ(camera.BackProject(pixel - h * Eigen::Vector2d::Unit(k), &minus),
                    ProjectionStatus::kOk);
          J_fd.col(k) = (plus.d_C - minus.d_C) / (2.0 * h);
        }
        EXPECT_LT((J_ray.d_direction_d_pixel - J_fd).norm(), 1e-7 * (1.0 + J_fd.norm()))
            << "pixel " << pixel.transpose();
      }
      // Projection, at a point 2.5 m along the ray (and exactly on the axis for i == 0).
      const Eigen::Vector3d q = 2.5 * ray.d_C;
      Eigen::Vector2d projected;
      Matrix23d J;
      ASSERT_EQ(camera.Project(q, &projected, &J), ProjectionStatus::kOk);
      const double h = 1e-6 * q.norm();
      Matrix23d J_fd;
      for (int k = 0; k < 3; ++k) {
        Eigen::Vector2d plus, minus;
        ASSERT_EQ(camera.Project(q + h * Eigen::Vector3d::Unit(k), &plus), ProjectionStatus::kOk);
        ASSERT_EQ(camera.Project(q - h * Eigen::Vector3d::Unit(k), &minus), ProjectionStatus::kOk);
        J_fd.col(k) = (plus - minus) / (2.0 * h);
      }
      EXPECT_LT((J - J_fd).norm(), 1e-6 * (1.0 + J.norm()))
          << "point " << q.transpose() << " method " << static_cast<int>(method);
    }
  }
}

INSTANTIATE_TEST_SUITE_P(Variants, ScaramuzzaVariantTest, ::testing::Values(0, 1));

// The direction agrees with OCamCalib's cam2world, re-derived here from its published formulas
// in its own (row, column) convention, under p_C = (y_ocam, x_ocam, -z_ocam).
TEST(ScaramuzzaCameraTest, MatchesOcamCalibCam2WorldConvention) {
  const ScaramuzzaParameters p = Variant(1);
  const ScaramuzzaCamera camera(p);
  std::mt19937 rng(3);
  for (int i = 0; i < 200; ++i) {
    const Eigen::Vector2d pixel = RandomPixel(camera, 1.0, &rng);
    const double row = pixel.y(), col = pixel.x();
    const double xc = p.v0, yc = p.u0;  // calib_results.txt order: row, column
    const double inv_det = 1.0 / (p.c - p.d * p.e);
    const double xp = inv_det * ((row - xc) - p.d * (col - yc));
    const double yp = inv_det * (-p.e * (row - xc) + p.c * (col - yc));
    const double rho = std::hypot(xp, yp);
    const double zp = p.poly[0] + p.poly[1] * rho + p.poly[2] * rho * rho +
                      p.poly[3] * std::pow(rho, 3) + p.poly[4] * std::pow(rho, 4);
    const Eigen::Vector3d ocam = Eigen::Vector3d(xp, yp, zp).normalized();
    Ray ray;
    ASSERT_EQ(camera.BackProject(pixel, &ray), ProjectionStatus::kOk);
    EXPECT_LT((ray.d_C - Eigen::Vector3d(ocam.y(), ocam.x(), -ocam.z())).norm(), 1e-12);
  }
  // Sanity of the kinevis frame: the centre looks along +z, right is +x, down is +y.
  Ray ray;
  ASSERT_EQ(camera.BackProject(Eigen::Vector2d(p.u0, p.v0), &ray), ProjectionStatus::kOk);
  EXPECT_LT((ray.d_C - Eigen::Vector3d::UnitZ()).norm(), 1e-12);
  ASSERT_EQ(camera.BackProject(Eigen::Vector2d(p.u0 + 50.0, p.v0), &ray), ProjectionStatus::kOk);
  EXPECT_GT(ray.d_C.x(), 0.2);
  EXPECT_NEAR(ray.d_C.y(), 0.0, 0.01);
  ASSERT_EQ(camera.BackProject(Eigen::Vector2d(p.u0, p.v0 + 50.0), &ray), ProjectionStatus::kOk);
  EXPECT_GT(ray.d_C.y(), 0.2);
  EXPECT_NEAR(ray.d_C.x(), 0.0, 0.01);
}

// A tolerance no polynomial of degree <= 30 meets: reported, and projection falls back to
// exact root-finding on f.
TEST(ScaramuzzaCameraTest, FallsBackToRootFindingWhenTheFitCannotMeetTheBound) {
  ScaramuzzaParameters p = ScaramuzzaParameters::Default();
  p.inverse_fit_tolerance_px = 1e-15;
  const ScaramuzzaCamera camera(p, ScaramuzzaProjection::kInversePolynomial);
  EXPECT_FALSE(camera.inverse_fit().fitted);
  EXPECT_EQ(camera.inverse_fit().degree, -1);
  EXPECT_GT(camera.inverse_fit().max_error_px, 1e-15);
  std::mt19937 rng(4);
  for (int i = 0; i < 200; ++i) {
    const Eigen::Vector2d pixel = RandomPixel(camera, 0.999, &rng);
    Ray ray;
    ASSERT_EQ(camera.BackProject(pixel, &ray), ProjectionStatus::kOk);
    Eigen::Vector2d again;
    ASSERT_EQ(camera.Project(ray.d_C, &again), ProjectionStatus::kOk);
    EXPECT_LT((again - pixel).norm(), 1e-6);
  }
}

TEST(ScaramuzzaCameraTest, DomainIsTheValidRadius) {
  const ScaramuzzaParameters p = Variant(1);  // rim at 235 px
  const ScaramuzzaCamera camera(p);
  const double phi_max = camera.inverse_fit().max_angle;
  Ray ray;
  Eigen::Vector2d pixel;
  EXPECT_EQ(camera.BackProject(Eigen::Vector2d(p.u0 + 240.0, p.v0), &ray),
            ProjectionStatus::kOutsideDomain);
  EXPECT_EQ(camera.BackProject(Eigen::Vector2d(p.u0 + 230.0, p.v0), &ray), ProjectionStatus::kOk);
  const double beyond = phi_max + 0.01, within = phi_max - 0.01;
  EXPECT_EQ(camera.Project(Eigen::Vector3d(std::sin(beyond), 0.0, std::cos(beyond)), &pixel),
            ProjectionStatus::kOutsideDomain);
  EXPECT_EQ(camera.Project(Eigen::Vector3d(std::sin(within), 0.0, std::cos(within)), &pixel),
            ProjectionStatus::kOk);
  EXPECT_EQ(camera.Project(Eigen::Vector3d::Zero(), &pixel), ProjectionStatus::kOutsideDomain);
  EXPECT_EQ(camera.Project(Eigen::Vector3d(0.0, 0.0, -1.0), &pixel),
            ProjectionStatus::kOutsideDomain);
}

TEST(ScaramuzzaCameraTest, ValidateNamesEveryBadField) {
  EXPECT_THAT(ScaramuzzaCamera(ScaramuzzaParameters::Default()).Validate(), IsEmpty());
  ScaramuzzaParameters p = ScaramuzzaParameters::Default();
  p.width = -1;
  p.poly[0] = 5.0;
  p.c = 0.5;
  p.d = 1.0;
  p.e = 1.0;
  p.inverse_fit_tolerance_px = 0.0;
  try {
    ScaramuzzaCamera camera(p);
    FAIL() << "expected std::invalid_argument";
  } catch (const std::invalid_argument& e) {
    const std::string message = e.what();
    EXPECT_THAT(message, ContainsRegex("width = -1"));
    EXPECT_THAT(message, ContainsRegex("a0\\) = 5"));
    EXPECT_THAT(message, ContainsRegex("c - d\\*e = -0.5"));
    EXPECT_THAT(message, ContainsRegex("inverse_fit_tolerance_px = 0"));
  }
  // A polynomial whose viewing angle turns back inside the valid radius.
  ScaramuzzaParameters folding = ScaramuzzaParameters::Default();
  folding.poly[4] = -1.0e-8;
  EXPECT_THROW(
      {
        try {
          ScaramuzzaCamera camera(folding);
        } catch (const std::invalid_argument& e) {
          EXPECT_THAT(e.what(), ContainsRegex("not increasing at rho = [0-9.]+ px"));
          throw;
        }
      },
      std::invalid_argument);
}

TEST(ScaramuzzaCameraTest, ProjectAndBackProjectDoNotAllocate) {
  const ScaramuzzaCamera refined(Variant(1));
  const ScaramuzzaCamera polynomial(Variant(1), ScaramuzzaProjection::kInversePolynomial);
  Eigen::Vector2d pixel;
  Matrix23d J;
  Ray ray;
  RayJacobian J_ray;
  int failures = 0;
  const long before = testing::ThreadAllocations();
  for (int i = 0; i < 100; ++i) {
    const Eigen::Vector3d q(0.01 * i - 0.5, 0.3, 1.0);
    failures += refined.Project(q, &pixel, &J) != ProjectionStatus::kOk;
    failures += polynomial.Project(q, &pixel, &J) != ProjectionStatus::kOk;
    failures += refined.BackProject(pixel, &ray, &J_ray) != ProjectionStatus::kOk;
  }
  const long allocations = testing::ThreadAllocations() - before;
  EXPECT_EQ(failures, 0);
  EXPECT_EQ(allocations, 0);
}

}  // namespace
}  // namespace kinevis::vision
