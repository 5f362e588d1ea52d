#include "vision/camera/tsai_camera.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "common/units.h"
#include "tests/utilities/allocation_counter.h"
#include "vision/camera/pinhole_camera.h"

namespace kinevis::vision {
namespace {

using ::testing::ContainsRegex;
using ::testing::IsEmpty;

double AngleDeg(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::atan2(a.cross(b).norm(), a.dot(b)) * 180.0 / common::kPi;
}

struct NamedParameters {
  const char* name;
  TsaiParameters parameters;
};

TsaiParameters WithDistortion(TsaiParameters p, TsaiDistortionForm form, double kappa1) {
  p.distortion_form = form;
  p.kappa1_per_mm2 = kappa1;
  return p;
}

// Non-square, off-centre, s_x != 1: every term of the pixel mapping matters.
TsaiParameters Anisotropic() {
  TsaiParameters p;
  p.width = 1280;
  p.height = 1024;
  p.focal_length_mm = 6.2;
  p.cx = 655.3;
  p.cy = 497.8;
  p.pixel_pitch_x_mm = 0.0053;
  p.pixel_pitch_y_mm = 0.0048;
  p.scale_x = 1.0213;
  p.kappa1_per_mm2 = 2.5e-3;
  return p;
}

std::vector<NamedParameters> AllParameterSets() {
  using F = TsaiDistortionForm;
  const TsaiParameters seed = TsaiParameters::Seed004();
  return {
      {"seed004", seed},
      {"seed004_tsai_form", WithDistortion(seed, F::kTsai, seed.kappa1_per_mm2)},
      // 10 % barrel at the corners (κ1 r_d² = 0.11 at r_d = 4.75 mm).
      {"strong_barrel_tsai", WithDistortion(seed, F::kTsai, 5e-3)},
      {"strong_barrel_division", WithDistortion(seed, F::kDivision, 5e-3)},
      // Pincushion close to the fold: Tsai's fold at r_d = 5.27 mm, the corners at 4.75 mm.
      {"pincushion_tsai", WithDistortion(seed, F::kTsai, -1.2e-2)},
      {"pincushion_division", WithDistortion(seed, F::kDivision, -3e-2)},
      {"anisotropic_tsai", Anisotropic()},
      {"anisotropic_division", WithDistortion(Anisotropic(), F::kDivision, -4e-3)},
  };
}

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

// Points seen by random pixels of the image (and a margin around it), depths 0.25–0.65 m (the
// scanner's working range).
std::vector<Eigen::Vector3d> RandomVisiblePoints(const TsaiCamera& camera, int count,
                                                 std::mt19937* rng) {
  std::uniform_real_distribution<double> u(-0.1 * camera.width(), 1.1 * camera.width());
  std::uniform_real_distribution<double> v(-0.1 * camera.height(), 1.1 * camera.height());
  std::uniform_real_distribution<double> depth(0.25, 0.65);
  std::vector<Eigen::Vector3d> points;
  while (static_cast<int>(points.size()) < count) {
    Ray ray;
    if (camera.BackProject({u(*rng), v(*rng)}, &ray) != ProjectionStatus::kOk) continue;
    points.push_back(ray.d_C * (depth(*rng) / ray.d_C.z()));
  }
  return points;
}

class TsaiSetTest : public ::testing::TestWithParam<NamedParameters> {};

INSTANTIATE_TEST_SUITE_P(ParameterSets, TsaiSetTest, ::testing::ValuesIn(AllParameterSets()),
                         [](const auto& info) { return std::string(info.param.name); });

TEST_P(TsaiSetTest, BackProjectThenProjectReturnsThePixelOverTheWholeImage) {
  const TsaiCamera camera(GetParam().parameters);
  double max_error_px = 0.0;
  const std::vector<Eigen::Vector2d> grid = ImageGrid(camera, 5.0);
  for (const Eigen::Vector2d& pixel : grid) {
    Ray ray;
    ASSERT_EQ(camera.BackProject(pixel, &ray), ProjectionStatus::kOk) << pixel.transpose();
    EXPECT_NEAR(ray.d_C.norm(), 1.0, 1e-15);
    EXPECT_EQ(ray.p_C_O, Eigen::Vector3d::Zero());
    Eigen::Vector2d reprojected;
    ASSERT_EQ(camera.Project(0.4 * ray.d_C, &reprojected), ProjectionStatus::kOk);
    const double error = (reprojected - pixel).norm();
    max_error_px = std::max(max_error_px, error);
    EXPECT_LT(error, 1e-9) << "pixel " << pixel.transpose();
  }
  std::printf("[ %s ] round trip over %zu pixels: max error %.3g px\n", GetParam().name,
              grid.size(), max_error_px);
}

TEST_P(TsaiSetTest, ProjectThenBackProjectReturnsTheDirection) {
  const TsaiCamera camera(GetParam().parameters);
  std::mt19937 rng(404);
  for (const Eigen::Vector3d& p_C : RandomVisiblePoints(camera, 500, &rng)) {
    Eigen::Vector2d pixel;
    ASSERT_EQ(camera.Project(p_C, &pixel), ProjectionStatus::kOk);
    Ray ray;
    ASSERT_EQ(camera.BackProject(pixel, &ray), ProjectionStatus::kOk);
    EXPECT_LT((ray.d_C - p_C.normalized()).norm(), 1e-14) << p_C.transpose();
  }
}

TEST_P(TsaiSetTest, ProjectJacobianMatchesCentralDifferences) {
  const TsaiCamera camera(GetParam().parameters);
  std::mt19937 rng(11);
  for (const Eigen::Vector3d& p_C : RandomVisiblePoints(camera, 300, &rng)) {
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

TEST_P(TsaiSetTest, BackProjectJacobianMatchesCentralDifferences) {
  const TsaiCamera camera(GetParam().parameters);
  const double h = 1e-3;  // pixels
  for (const Eigen::Vector2d& pixel : ImageGrid(camera, 101.0)) {
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

TEST_P(TsaiSetTest, ProjectAndBackProjectDoNotAllocate) {
  const TsaiCamera camera(GetParam().parameters);
  const std::vector<Eigen::Vector2d> grid = ImageGrid(camera, 67.0);
  Ray ray;
  RayJacobian J_ray;
  Eigen::Vector2d pixel;
  Matrix23d J_pixel;
  int ok = 0;
  const long before = testing::ThreadAllocations();
  for (const Eigen::Vector2d& p : grid) {
    ok += camera.BackProject(p, &ray, &J_ray) == ProjectionStatus::kOk;
    ok += camera.Project(0.5 * ray.d_C, &pixel, &J_pixel) == ProjectionStatus::kOk;
  }
  ok += camera.Project({0.0, 0.0, -1.0}, &pixel, &J_pixel) == ProjectionStatus::kOk;
  EXPECT_EQ(testing::ThreadAllocations() - before, 0);
  EXPECT_EQ(ok, 2 * static_cast<int>(grid.size()));
}

// With κ1 = 0 Tsai's model is the pinhole fx = f s_x / d'_x, fy = f / d_y, (cx, cy) = (C_x, C_y).
TEST(TsaiCameraTest, WithoutDistortionEqualsThePinholeModel) {
  for (TsaiParameters tsai : {TsaiParameters::Seed004(), Anisotropic()}) {
    tsai.kappa1_per_mm2 = 0.0;
    PinholeBrownParameters pinhole;
    pinhole.width = tsai.width;
    pinhole.height = tsai.height;
    pinhole.fx = tsai.focal_length_mm * tsai.scale_x / tsai.pixel_pitch_x_mm;
    pinhole.fy = tsai.focal_length_mm / tsai.pixel_pitch_y_mm;
    pinhole.cx = tsai.cx;
    pinhole.cy = tsai.cy;
    EXPECT_DOUBLE_EQ(tsai.fx(), pinhole.fx);
    EXPECT_DOUBLE_EQ(tsai.fy(), pinhole.fy);
    const TsaiCamera a(tsai);
    const PinholeBrownCamera b(pinhole);
    std::mt19937 rng(5);
    for (const Eigen::Vector3d& p_C : RandomVisiblePoints(a, 200, &rng)) {
      Eigen::Vector2d pixel_a, pixel_b;
      Matrix23d J_a, J_b;
      ASSERT_EQ(a.Project(p_C, &pixel_a, &J_a), ProjectionStatus::kOk);
      ASSERT_EQ(b.Project(p_C, &pixel_b, &J_b), ProjectionStatus::kOk);
      EXPECT_LT((pixel_a - pixel_b).norm(), 1e-9);
      EXPECT_LT((J_a - J_b).lpNorm<Eigen::Infinity>(), 1e-12 * J_b.lpNorm<Eigen::Infinity>());
      Ray ray_a, ray_b;
      RayJacobian R_a, R_b;
      ASSERT_EQ(a.BackProject(pixel_a, &ray_a, &R_a), ProjectionStatus::kOk);
      ASSERT_EQ(b.BackProject(pixel_a, &ray_b, &R_b), ProjectionStatus::kOk);
      EXPECT_LT((ray_a.d_C - ray_b.d_C).norm(), 1e-15);
      EXPECT_LT((R_a.d_direction_d_pixel - R_b.d_direction_d_pixel).lpNorm<Eigen::Infinity>(),
                1e-12 * R_b.d_direction_d_pixel.lpNorm<Eigen::Infinity>());
    }
  }
}

TEST(TsaiCameraTest, Seed004Numbers) {
  const TsaiParameters p = TsaiParameters::Seed004();
  EXPECT_THAT(p.Validate(), IsEmpty());
  EXPECT_EQ(p.width, 1616);
  EXPECT_EQ(p.height, 1216);
  EXPECT_NEAR(p.pixel_pitch_x_mm, 4.4e-3, 1e-7);  // the LW230's 4.4 µm pixel
  EXPECT_NEAR(p.fx(), 2144.9, 0.05);              // 9.43773 mm × 227.27 px/mm
  EXPECT_NEAR(p.fy(), p.fx(), 1e-12);
  EXPECT_NEAR(p.kappa1_per_mm2, 4.8864e-4, 1e-8);
  EXPECT_EQ(p.distortion_form, TsaiDistortionForm::kDivision);
  const TsaiCamera camera(p);
  EXPECT_EQ(camera.Name(), "tsai");
  EXPECT_TRUE(camera.IsCentral());
}

// Seed 004, eq. (24)–(25): a pixel (x_im, y_im) on the plane A x + B y + C z + D = 0 lies at
// z = -D / (A A_x + B B_y + C), x = A_x z, y = B_y z, with A_x = (x_im - C_x) / (fx (1 - k r²)),
// r² = μ²(x_im - C_x)² + (y_im - C_y)², k per pixel². Our ray meets the plane at the same point.
TEST(TsaiCameraTest, Seed004ReproducesTheSeedsPlaneIntersection) {
  const TsaiParameters p = TsaiParameters::Seed004();
  const TsaiCamera camera(p);
  const double k = 9.4604e-9;
  const double fx = p.fx();
  const double fy = p.fy();
  const double mu = fy / fx;
  const double A = 0.03, B = -0.12, C = 1.0, D = -0.383;  // a tilted board about 383 mm away
  double max_difference_m = 0.0;
  for (const Eigen::Vector2d& pixel : ImageGrid(camera, 40.0)) {
    const double du = pixel.x() - p.cx;
    const double dv = pixel.y() - p.cy;
    const double r2 = mu * mu * du * du + dv * dv;
    const double A_x = du / (fx * (1.0 - k * r2));
    const double B_y = dv / (fy * (1.0 - k * r2));
    const double z = -D / (A * A_x + B * B_y + C);
    const Eigen::Vector3d p_seed(A_x * z, B_y * z, z);
    Ray ray;
    ASSERT_EQ(camera.BackProject(pixel, &ray), ProjectionStatus::kOk);
    const double t = -D / (Eigen::Vector3d(A, B, C).dot(ray.d_C));
    const double difference = (ray.p_C_O + t * ray.d_C - p_seed).norm();
    max_difference_m = std::max(max_difference_m, difference);
    EXPECT_LT(difference, 1e-12) << pixel.transpose();
  }
  std::printf("seed eq. (24)-(25) vs BackProject: max difference %.3g m\n", max_difference_m);
}

// The image of the seed's camera: ~41° × 32° (a 7.1 × 5.4 mm sensor behind 9.44 mm), and the
// seed's 9 × 9 dot board (26.5 mm pitch) at the calibration distance of ~383 mm nearly fills the
// image height, as a calibration board should.
TEST(TsaiCameraTest, Seed004FieldOfViewIsThatOfTheLens) {
  const TsaiCamera camera(TsaiParameters::Seed004());
  const auto ray_at = [&camera](double u, double v) {
    Ray ray;
    EXPECT_EQ(camera.BackProject({u, v}, &ray), ProjectionStatus::kOk);
    return ray.d_C;
  };
  const double h_fov = AngleDeg(ray_at(-0.5, 585.0), ray_at(1615.5, 585.0));
  const double v_fov = AngleDeg(ray_at(738.0, -0.5), ray_at(738.0, 1215.5));
  const double d_fov = AngleDeg(ray_at(-0.5, -0.5), ray_at(1615.5, 1215.5));
  std::printf("seed 004 field of view: %.2f° × %.2f°, diagonal %.2f°\n", h_fov, v_fov, d_fov);
  // Distortion-free values: 2 atan(3.5552 / 9.43773) = 41.3°, 2 atan(2.6752 / 9.43773) = 31.6°;
  // the 1.1 % barrel widens them slightly.
  EXPECT_GT(h_fov, 41.3);
  EXPECT_LT(h_fov, 42.0);
  EXPECT_GT(v_fov, 31.6);
  EXPECT_LT(v_fov, 32.2);

  const Eigen::Vector3d d_centre = ray_at(807.5, 607.5);  // the middle of the image
  const Eigen::Vector3d p_C_board = d_centre * (0.383 / d_centre.z());
  double v_min = 1e9, v_max = -1e9;
  for (int i = -4; i <= 4; ++i) {
    for (int j = -4; j <= 4; ++j) {
      Eigen::Vector2d pixel;
      ASSERT_EQ(camera.Project(p_C_board + Eigen::Vector3d(0.0265 * i, 0.0265 * j, 0.0), &pixel),
                ProjectionStatus::kOk);
      EXPECT_TRUE(camera.InImage(pixel))
          << "dot (" << i << ", " << j << ") at " << pixel.transpose();
      v_min = std::min(v_min, pixel.y());
      v_max = std::max(v_max, pixel.y());
    }
  }
  EXPECT_GT((v_max - v_min) / camera.height(), 0.9);
}

// Seed 004 writes the distortion as 1/(1 - k r²), Tsai as 1 + κ1 r²: with the seed's κ1 the two
// differ by κ1² r_d⁵ ≈ 0.13 px in the corners, and by nothing at the centre.
TEST(TsaiCameraTest, DivisionAndTsaiFormsDifferOnlyToSecondOrder) {
  const TsaiParameters seed = TsaiParameters::Seed004();
  const TsaiCamera division(seed);
  const TsaiCamera tsai(WithDistortion(seed, TsaiDistortionForm::kTsai, seed.kappa1_per_mm2));
  double max_difference_px = 0.0;
  for (const Eigen::Vector2d& pixel : ImageGrid(division, 20.0)) {
    Ray ray;
    ASSERT_EQ(division.BackProject(pixel, &ray), ProjectionStatus::kOk);
    Eigen::Vector2d other;
    ASSERT_EQ(tsai.Project(ray.d_C, &other), ProjectionStatus::kOk);
    max_difference_px = std::max(max_difference_px, (other - pixel).norm());
  }
  std::printf("division vs Tsai form at the seed's kappa1: max %.3f px\n", max_difference_px);
  EXPECT_GT(max_difference_px, 0.08);
  EXPECT_LT(max_difference_px, 0.2);
  Eigen::Vector2d a, b;
  ASSERT_EQ(division.Project({0.0, 0.0, 1.0}, &a), ProjectionStatus::kOk);
  ASSERT_EQ(tsai.Project({0.0, 0.0, 1.0}, &b), ProjectionStatus::kOk);
  EXPECT_EQ(a, b);
}

// The cubic's physical root: near the axis r_d = r_u (no cancellation), and for κ1 < 0 the root
// below the fold, up to the fold; beyond it kOutsideDomain.
TEST(TsaiCameraTest, CubicRootSelectionAndTheFold) {
  const TsaiParameters seed = TsaiParameters::Seed004();
  for (double kappa1 : {5e-3, -3e-3}) {
    // Centre at pixel 0 so that the tiny offsets are not rounded away by adding C_x, C_y.
    TsaiParameters centred = WithDistortion(seed, TsaiDistortionForm::kTsai, kappa1);
    centred.cx = 0.0;
    centred.cy = 0.0;
    const TsaiCamera camera(centred);
    Eigen::Vector2d pixel;
    ASSERT_EQ(camera.Project({1e-9, -2e-9, 1.0}, &pixel), ProjectionStatus::kOk);
    EXPECT_NEAR(pixel.x() / (seed.fx() * 1e-9), 1.0, 1e-14);
    EXPECT_NEAR(pixel.y() / (seed.fy() * -2e-9), 1.0, 1e-14);
  }
  const double kappa1 = -3e-3;
  const TsaiCamera camera(WithDistortion(seed, TsaiDistortionForm::kTsai, kappa1));
  const double r_fold_mm = 1.0 / std::sqrt(-3.0 * kappa1);  // 10.5 mm
  EXPECT_NEAR(camera.max_distorted_radius_mm(), r_fold_mm, 1e-12);
  const double r_u_max_mm = 2.0 / 3.0 * r_fold_mm;  // the largest undistorted radius reached
  const double f = seed.focal_length_mm;
  Eigen::Vector2d pixel;
  ASSERT_EQ(camera.Project({0.999 * r_u_max_mm / f, 0.0, 1.0}, &pixel), ProjectionStatus::kOk);
  const double r_d_mm = (pixel.x() - seed.cx) * seed.pixel_pitch_x_mm;
  EXPECT_LT(r_d_mm, r_fold_mm);  // the branch below the fold, not the one beyond it
  EXPECT_NEAR(r_d_mm * (1.0 + kappa1 * r_d_mm * r_d_mm), 0.999 * r_u_max_mm, 1e-12);
  EXPECT_EQ(camera.Project({1.001 * r_u_max_mm / f, 0.0, 1.0}, &pixel),
            ProjectionStatus::kOutsideDomain);
  Ray ray;
  EXPECT_EQ(
      camera.BackProject({seed.cx + 1.001 * r_fold_mm / seed.pixel_pitch_x_mm, seed.cy}, &ray),
      ProjectionStatus::kOutsideDomain);
  ASSERT_EQ(
      camera.BackProject({seed.cx + 0.999 * r_fold_mm / seed.pixel_pitch_x_mm, seed.cy}, &ray),
      ProjectionStatus::kOk);

  // Division form, barrel: every direction up to 90° lands inside the pole radius.
  const TsaiCamera division(WithDistortion(seed, TsaiDistortionForm::kDivision, 5e-3));
  ASSERT_EQ(division.Project({10.0, 0.0, 1.0}, &pixel), ProjectionStatus::kOk);
  EXPECT_LT((pixel.x() - seed.cx) * seed.pixel_pitch_x_mm, division.max_distorted_radius_mm());
}

TEST(TsaiCameraTest, PointsNotInFrontAreBehindCamera) {
  const TsaiCamera camera(TsaiParameters::Seed004());
  Eigen::Vector2d pixel;
  EXPECT_EQ(camera.Project({0.1, 0.1, 0.0}, &pixel), ProjectionStatus::kBehindCamera);
  EXPECT_EQ(camera.Project({0.0, 0.0, -0.4}, &pixel), ProjectionStatus::kBehindCamera);
  EXPECT_EQ(camera.Project({0.0, 0.0, std::nan("")}, &pixel), ProjectionStatus::kBehindCamera);
}

TEST(TsaiCameraTest, ValidateNamesEveryBadFieldWithItsValue) {
  TsaiParameters p = TsaiParameters::Seed004();
  p.width = 0;
  p.focal_length_mm = -9.4;
  p.cx = std::nan("");
  p.pixel_pitch_y_mm = 0.0;
  p.scale_x = std::numeric_limits<double>::infinity();
  p.kappa1_per_mm2 = std::nan("");
  p.distortion_form = static_cast<TsaiDistortionForm>(7);
  try {
    TsaiCamera camera(p);
    FAIL() << "constructor accepted bad parameters";
  } catch (const std::invalid_argument& e) {
    const std::string message = e.what();
    EXPECT_THAT(message, ContainsRegex("^tsai camera: "));
    EXPECT_THAT(message, ContainsRegex("width = 0 must be > 0"));
    EXPECT_THAT(message, ContainsRegex("focal_length_mm = -9.4 must be finite and > 0"));
    EXPECT_THAT(message, ContainsRegex("cx = nan is not finite"));
    EXPECT_THAT(message, ContainsRegex("pixel_pitch_y_mm = 0 must be finite and > 0"));
    EXPECT_THAT(message, ContainsRegex("scale_x = inf must be finite and > 0"));
    EXPECT_THAT(message, ContainsRegex("kappa1_per_mm2 = nan is not finite"));
    EXPECT_THAT(message, ContainsRegex("distortion_form = 7 is neither tsai nor division"));
    EXPECT_THAT(message, ::testing::Not(ContainsRegex("height|pixel_pitch_x_mm|cy =")));
    EXPECT_THAT(message, ::testing::Not(ContainsRegex("; $")));
  }
}

// A pincushion strong enough to fold inside the image is not a lens model for that image.
TEST(TsaiCameraTest, ValidateRejectsADistortionThatFoldsInsideTheImage) {
  const TsaiParameters seed = TsaiParameters::Seed004();
  // Tsai form: fold at r_d² = 1/(3·0.02) = 16.7 mm² < 22.6 mm² (the far corner).
  const TsaiParameters tsai = WithDistortion(seed, TsaiDistortionForm::kTsai, -0.02);
  EXPECT_THAT(tsai.Validate(),
              ContainsRegex("^kappa1_per_mm2 = -0.02 \\(tsai form\\) folds the distortion at "
                            "r_d = 4.08[0-9]* mm, inside the image \\(its far corner is at "
                            "r_d = 4.75[0-9]* mm\\)$"));
  EXPECT_THROW(TsaiCamera{tsai}, std::invalid_argument);
  // Division form with κ1 > 0: the pole at r_d = 1/sqrt(κ1).
  EXPECT_THAT(WithDistortion(seed, TsaiDistortionForm::kDivision, 0.05).Validate(),
              ContainsRegex("division form\\) folds the distortion at r_d = 4.47"));
  EXPECT_THAT(WithDistortion(seed, TsaiDistortionForm::kDivision, 0.04).Validate(), IsEmpty());
}

TEST(TsaiCameraTest, DistortionFormNames) {
  EXPECT_EQ(ToString(TsaiDistortionForm::kTsai), "tsai");
  EXPECT_EQ(ToString(TsaiDistortionForm::kDivision), "division");
  EXPECT_NEAR(Kappa1PerMm2FromPerPixel2(1e-8, 0.005), 4e-4, 1e-18);
}

}  // namespace
}  // namespace kinevis::vision
