#include "calibration/laser_scanner/laser_scanner_calibration.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <memory>
#include <random>
#include <vector>

#include "calibration/laser_scanner/laser_scanner_calibration_internal.h"
#include "calibration/laser_scanner/synthetic_stripes.h"
#include "common/units.h"
#include "vision/camera/camera_file.h"
#include "vision/render/scenes/laser_scene.h"

namespace kinevis::calibration {
namespace {

using vision::laser::ScannerGeometry;
using vision::render::LaserId;
using vision::render::LaserScene;
using vision::render::LaserSceneParameters;

// The scanner's stepper (truth): θ_y = θ0 + Δ · step, 1.8° / 32 microsteps.
struct Stepper {
  double theta0 = 72.0 * common::kDeg;
  double per_step = 1.8 / 32.0 * common::kDeg;
  double Cot(int step) const { return 1.0 / std::tan(theta0 + per_step * step); }
};

Eigen::Isometry3d Pose(double depth, double tilt_x, double tilt_y) {
  return Eigen::Translation3d(0.003, -0.004, depth) *
         Eigen::AngleAxisd(tilt_x, Eigen::Vector3d::UnitX()) *
         Eigen::AngleAxisd(tilt_y, Eigen::Vector3d::UnitY()) *
         Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX());
}

std::vector<Eigen::Isometry3d> DefaultPoses() {
  return {Pose(0.45, 0.25, 0.2), Pose(0.52, -0.3, -0.25), Pose(0.58, 0.2, -0.3),
          Pose(0.64, -0.15, 0.3)};
}

struct DataOptions {
  double noise_px = 0.0;          // across the stripe
  double outlier_fraction = 0.0;  // of the points, moved by 3–8 px
  uint32_t seed = 1;
};

// One image per (pose, step): the exact stripes (projected StripeCurve) with noise across them.
std::vector<LaserCalibrationImage> MakeImages(const vision::CameraModel& camera,
                                              const ScannerGeometry& truth, const Stepper& stepper,
                                              const std::vector<Eigen::Isometry3d>& poses,
                                              const std::vector<int>& steps,
                                              const DataOptions& options, int* outliers = nullptr) {
  std::mt19937 rng(options.seed);
  std::normal_distribution<double> noise(0.0, options.noise_px);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  std::vector<LaserCalibrationImage> images;
  if (outliers != nullptr) *outliers = 0;
  for (size_t i = 0; i < poses.size(); ++i) {
    for (int step : steps) {
      LaserSceneParameters p;
      p.surface = vision::render::LaserSurfaceKind::kBoard;
      p.half_extent = Eigen::Vector2d(0.15, 0.15);
      p.X_CS = poses[i];
      p.scanner = vision::laser::ToSceneGeometry(truth);
      p.rotating_cot_theta_y = stepper.Cot(step);
      const LaserScene scene(p);
      LaserCalibrationImage image;
      image.name = "pose" + std::to_string(i) + "_step" + std::to_string(step);
      image.X_CS = poses[i];
      image.rotating_step = step;
      for (LaserId id : {LaserId::kRotating, LaserId::kFixed}) {
        std::vector<Eigen::Vector2d> pixels = ExactStripePixels(scene, camera, id);
        const int across = id == LaserId::kRotating ? 1 : 0;
        for (Eigen::Vector2d& px : pixels) {
          if (options.noise_px > 0.0) px(across) += noise(rng);
          if (uniform(rng) < options.outlier_fraction) {
            px(across) += (uniform(rng) < 0.5 ? -1.0 : 1.0) * (3.0 + 5.0 * uniform(rng));
            if (outliers != nullptr) ++*outliers;
          }
        }
        (id == LaserId::kRotating ? image.rotating_pixels : image.fixed_pixels) = pixels;
      }
      images.push_back(image);
    }
  }
  return images;
}

const std::vector<int> kSteps = {0, 40, 80, 120, 160, 200};

TEST(LaserScannerCalibration, ExactStripesGiveTheSeedsParameters) {
  const auto camera = vision::BuiltinCameraModel("tsai-seed004");
  const ScannerGeometry truth = ScannerGeometry::Seed004();
  const Stepper stepper;
  const auto images = MakeImages(*camera, truth, stepper, DefaultPoses(), kSteps, {});
  const LaserScannerCalibration c = CalibrateLaserScanner(images, *camera);
  ASSERT_TRUE(c.ok()) << (c.errors.empty() ? "" : c.errors[0]);
  EXPECT_TRUE(c.rotating_calibrated);
  EXPECT_TRUE(c.fixed_calibrated);
  EXPECT_TRUE(c.converged);
  EXPECT_GE(c.iterations, 1);
  EXPECT_NEAR(c.geometry.rotating_b_y, truth.rotating_b_y, 1e-8);
  EXPECT_NEAR(c.geometry.rotating_d_y, truth.rotating_d_y, 1e-8);
  EXPECT_NEAR(c.geometry.fixed_b_x_prime, truth.fixed_b_x_prime, 1e-8);
  EXPECT_NEAR(c.geometry.fixed_cot_theta_x, truth.fixed_cot_theta_x, 1e-8);
  ASSERT_EQ(c.positions.size(), kSteps.size());
  for (const RotatingPositionEstimate& p : c.positions) {
    EXPECT_TRUE(p.estimated) << p.problem;
    EXPECT_EQ(p.images, 4);
    EXPECT_NEAR(p.cot_theta_y, stepper.Cot(p.step), 1e-9);
    EXPECT_NEAR(p.cot_theta_y_linear, stepper.Cot(p.step), 1e-9);
    EXPECT_NEAR(p.b_y_prime, truth.RotatingBPrime(stepper.Cot(p.step)), 1e-9);
    EXPECT_GT(p.points, 1000);
  }
  ASSERT_TRUE(c.stepper.fitted);
  EXPECT_NEAR(c.stepper.theta_at_step0, stepper.theta0, 1e-9);
  EXPECT_NEAR(c.stepper.theta_per_step, stepper.per_step, 1e-11);
  EXPECT_LT(c.rotating_residual_max, 1e-9);
  EXPECT_LT(c.fixed_residual_max, 1e-9);
  EXPECT_LT(c.separation_condition, 100.0);
  EXPECT_EQ(c.unusable_pixels, 0);
}

// 0.1 px stripe noise and 3 % gross outliers: the outliers are found, the parameters are within
// their reported uncertainty, and over 20 draws the uncertainty is honest (mean squared
// Mahalanobis error of (b_y, d_y) ≈ 2).
TEST(LaserScannerCalibration, NoisyStripesWithOutliersAreWithinTheirUncertainty) {
  const auto camera = vision::BuiltinCameraModel("tsai-seed004");
  const ScannerGeometry truth = ScannerGeometry::Seed004();
  const Stepper stepper;
  double mahalanobis = 0.0, mahalanobis_fixed = 0.0;
  constexpr int kDraws = 20;
  for (int draw = 0; draw < kDraws; ++draw) {
    DataOptions data;
    data.noise_px = 0.1;
    data.outlier_fraction = 0.03;
    data.seed = 100 + draw;
    int outliers = 0;
    const auto images =
        MakeImages(*camera, truth, stepper, DefaultPoses(), kSteps, data, &outliers);
    const LaserScannerCalibration c = CalibrateLaserScanner(images, *camera);
    ASSERT_TRUE(c.ok());
    const Eigen::Vector2d e(c.geometry.rotating_b_y - truth.rotating_b_y,
                            c.geometry.rotating_d_y - truth.rotating_d_y);
    const Eigen::Vector2d f(c.geometry.fixed_b_x_prime - truth.fixed_b_x_prime,
                            c.geometry.fixed_cot_theta_x - truth.fixed_cot_theta_x);
    mahalanobis += e.dot(c.rotating_covariance.inverse() * e) / kDraws;
    mahalanobis_fixed += f.dot(c.fixed_covariance.inverse() * f) / kDraws;
    EXPECT_LT(std::abs(e(0)), 0.1e-3);
    EXPECT_LT(std::abs(e(1)), 0.3e-3);
    EXPECT_LT(std::abs(f(0)), 0.1e-3);
    EXPECT_LT(std::abs(f(1)), 2e-4);
    // Every injected outlier (≥ 3 px ≈ 30 σ) is dropped; a few true points at the noise's tail
    // may be dropped too (4 robust σ).
    EXPECT_GE(c.rotating_outliers + c.fixed_outliers, outliers);
    EXPECT_LT(c.rotating_outliers + c.fixed_outliers, outliers * 1.2 + 50);
    EXPECT_LT(c.rotating_residual_rms, 0.05e-3);
    if (draw == 0) {
      std::printf(
          "b_y %.4f ± %.4f mm, d_y %.4f ± %.4f mm, b_x' %.4f ± %.4f mm, cot_x %.5f ± "
          "%.5f; %d outliers injected, %d dropped\n",
          1e3 * c.geometry.rotating_b_y, 1e3 * c.b_y_sigma(), 1e3 * c.geometry.rotating_d_y,
          1e3 * c.d_y_sigma(), 1e3 * c.geometry.fixed_b_x_prime, 1e3 * c.b_x_prime_sigma(),
          c.geometry.fixed_cot_theta_x, c.cot_theta_x_sigma(), outliers,
          c.rotating_outliers + c.fixed_outliers);
    }
  }
  std::printf("mean squared Mahalanobis error: rotating %.2f, fixed %.2f (2 expected)\n",
              mahalanobis, mahalanobis_fixed);
  EXPECT_GT(mahalanobis, 0.7);
  EXPECT_LT(mahalanobis, 4.0);
  EXPECT_GT(mahalanobis_fixed, 0.7);
  EXPECT_LT(mahalanobis_fixed, 4.0);
}

// `converged` is the refinement's own verdict: one Gauss–Newton step from the linear values of
// noisy stripes is not below a zero step tolerance, and without refinement nothing iterated.
TEST(LaserScannerCalibration, ConvergedSaysWhetherTheRefinementMetItsTolerance) {
  const auto camera = vision::BuiltinCameraModel("tsai-seed004");
  const ScannerGeometry truth = ScannerGeometry::Seed004();
  DataOptions data;
  data.noise_px = 0.1;
  data.seed = 7;
  const auto images = MakeImages(*camera, truth, Stepper(), DefaultPoses(), kSteps, data);

  const LaserScannerCalibration full = CalibrateLaserScanner(images, *camera);
  ASSERT_TRUE(full.ok());
  EXPECT_TRUE(full.converged);
  EXPECT_LT(full.iterations, LaserScannerCalibrationOptions().max_iterations);
  // The contract's σ come from one identifiability analysis of both solves' Jacobians; they
  // agree with each plane's own (JᵀJ)⁻¹.
  const EstimationReport& e = full.estimation;
  EXPECT_EQ(e.Validate(), "");
  EXPECT_EQ(e.status, EstimationStatus::kConverged);
  EXPECT_EQ(e.parameters.size(), 4 + full.positions.size());
  EXPECT_NEAR(e.Find("b_y")->sigma, full.b_y_sigma(), 1e-6 * full.b_y_sigma());
  EXPECT_NEAR(e.Find("d_y")->sigma, full.d_y_sigma(), 1e-6 * full.d_y_sigma());
  EXPECT_NEAR(e.Find("b_x_prime")->sigma, full.b_x_prime_sigma(), 1e-6 * full.b_x_prime_sigma());
  EXPECT_NEAR(e.Find("cot_theta_x")->sigma, full.cot_theta_x_sigma(),
              1e-6 * full.cot_theta_x_sigma());
  EXPECT_NEAR(e.Find("cot_theta_y.0")->sigma, full.positions[0].cot_theta_y_sigma,
              1e-6 * full.positions[0].cot_theta_y_sigma);
  EXPECT_DOUBLE_EQ(e.Find("b_y")->value, full.geometry.rotating_b_y);
  EXPECT_EQ(e.Find("cot_theta_x")->unit, "1");
  EXPECT_EQ(e.identifiability.rank, static_cast<int>(e.parameters.size()));
  ASSERT_EQ(e.residuals.size(), 2u);
  EXPECT_DOUBLE_EQ(e.residuals[0].rms, full.rotating_residual_rms);

  LaserScannerCalibrationOptions one_step;
  one_step.max_iterations = 1;
  one_step.step_tolerance = 0.0;
  const LaserScannerCalibration cut = CalibrateLaserScanner(images, *camera, one_step);
  EXPECT_TRUE(cut.ok());
  EXPECT_FALSE(cut.converged);
  EXPECT_EQ(cut.iterations, 1);
  EXPECT_EQ(cut.estimation.status, EstimationStatus::kNotConverged);
  EXPECT_THAT(cut.warnings, ::testing::Contains(::testing::HasSubstr(
                                "joint refinement did not converge in 1 iteration")));

  LaserScannerCalibrationOptions linear;
  linear.refine = false;
  const LaserScannerCalibration raw = CalibrateLaserScanner(images, *camera, linear);
  EXPECT_TRUE(raw.ok());
  EXPECT_FALSE(raw.converged);
  EXPECT_EQ(raw.iterations, 0);
  EXPECT_EQ(raw.estimation.status, EstimationStatus::kConverged);
  EXPECT_EQ(raw.estimation.message, "linear solution (no refinement)");
}

TEST(LaserScannerCalibration, OnePositionCannotSeparateBFromD) {
  const auto camera = vision::BuiltinCameraModel("tsai-seed004");
  const auto images =
      MakeImages(*camera, ScannerGeometry::Seed004(), Stepper{}, DefaultPoses(), {80}, {});
  const LaserScannerCalibration c = CalibrateLaserScanner(images, *camera);
  EXPECT_FALSE(c.ok());
  EXPECT_FALSE(c.rotating_calibrated);
  EXPECT_TRUE(c.fixed_calibrated);
  ASSERT_EQ(c.errors.size(), 1u);
  EXPECT_THAT(c.errors[0], ::testing::ContainsRegex("rotating laser: 1 estimated stepper position"
                                                    ".*need >= 2"));
  EXPECT_TRUE(std::isnan(c.geometry.rotating_b_y));
  // The position itself is still measured (eq. 28).
  ASSERT_EQ(c.positions.size(), 1u);
  EXPECT_TRUE(c.positions[0].estimated);
  EXPECT_NEAR(c.positions[0].cot_theta_y, Stepper{}.Cot(80), 1e-9);
  EXPECT_FALSE(c.stepper.fitted);
  // In the contract: the fixed laser identified, the rotating one not.
  EXPECT_EQ(c.estimation.status, EstimationStatus::kUnidentified);
  EXPECT_EQ(c.estimation.Validate(), "");
  EXPECT_FALSE(c.estimation.Find("b_y")->identified);
  EXPECT_TRUE(std::isinf(c.estimation.Find("d_y")->sigma));
  EXPECT_TRUE(c.estimation.Find("b_x_prime")->identified);
  EXPECT_THAT(c.estimation.message, ::testing::HasSubstr("rotating laser: 1 estimated"));
}

TEST(LaserScannerCalibration, PositionsAtAlmostOneAngleAreWarnedAboutOrRefused) {
  const auto camera = vision::BuiltinCameraModel("tsai-seed004");
  const ScannerGeometry truth = ScannerGeometry::Seed004();
  // Two adjacent microsteps: 0.056° apart.
  const LaserScannerCalibration close = CalibrateLaserScanner(
      MakeImages(*camera, truth, Stepper{}, DefaultPoses(), {0, 1}, {}), *camera);
  EXPECT_TRUE(close.ok());
  EXPECT_GT(close.separation_condition, 100.0);
  EXPECT_THAT(close.warnings,
              ::testing::Contains(::testing::ContainsRegex("separate b_y from d_y poorly")));
  // A stepper that does not move: two positions, one angle.
  Stepper stuck;
  stuck.per_step = 0.0;
  const LaserScannerCalibration same = CalibrateLaserScanner(
      MakeImages(*camera, truth, stuck, DefaultPoses(), {0, 50}, {}), *camera);
  EXPECT_FALSE(same.ok());
  EXPECT_FALSE(same.rotating_calibrated);
  EXPECT_THAT(same.errors,
              ::testing::Contains(::testing::ContainsRegex("cannot separate b_y from d_y")));
}

TEST(LaserScannerCalibration, OneFrontalBoardPoseIsRefusedAsNoDepth) {
  const auto camera = vision::BuiltinCameraModel("tsai-seed004");
  const auto images = MakeImages(*camera, ScannerGeometry::Seed004(), Stepper{},
                                 {Pose(0.5, 0.0, 0.0)}, {0, 100, 200}, {});
  const LaserScannerCalibration c = CalibrateLaserScanner(images, *camera);
  EXPECT_FALSE(c.ok());
  for (const RotatingPositionEstimate& p : c.positions) {
    EXPECT_FALSE(p.estimated);
    EXPECT_THAT(p.problem, ::testing::ContainsRegex("do not span depth"));
  }
  EXPECT_THAT(c.errors,
              ::testing::Contains(::testing::ContainsRegex("rotating laser: 0 estimated")));
  EXPECT_THAT(c.errors,
              ::testing::Contains(::testing::ContainsRegex("fixed laser: .*do not span depth")));
}

TEST(LaserScannerCalibration, MalformedInputIsRefusedByName) {
  const auto camera = vision::BuiltinCameraModel("tsai-seed004");
  EXPECT_THROW(
      {
        try {
          CalibrateLaserScanner({}, *camera);
        } catch (const std::invalid_argument& e) {
          EXPECT_THAT(e.what(), ::testing::ContainsRegex("no images"));
          throw;
        }
      },
      std::invalid_argument);
  std::vector<LaserCalibrationImage> images(2);
  images[1].name = "b.png";
  images[1].rotating_pixels.assign(5, Eigen::Vector2d(100, 100));
  images[1].rotating_pixels[3].x() = std::nan("");
  images[0].X_CS.linear() *= 2.0;
  LaserScannerCalibrationOptions options;
  options.min_points_per_position = 1;
  try {
    CalibrateLaserScanner(images, *camera, options);
    FAIL() << "accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), ::testing::ContainsRegex("min_points_per_position: must be >= 2, got 1"));
    EXPECT_THAT(e.what(), ::testing::ContainsRegex("images\\[0\\].X_CS is not a finite rigid"));
    EXPECT_THAT(e.what(),
                ::testing::ContainsRegex("images\\[1\\] \\(b.png\\).rotating_pixels\\[3\\] is not "
                                         "finite"));
  }
}

TEST(LaserScannerCalibration, RefinementJacobianMatchesCentralDifferences) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-0.1, 0.1);
  std::vector<Eigen::Vector3d> points;
  std::vector<int> position;
  for (int i = 0; i < 30; ++i) {
    points.emplace_back(u(rng), u(rng), 0.5 + u(rng));
    position.push_back(i % 3);
  }
  Eigen::VectorXd x(5);
  x << 0.1, -0.016, 0.2, 0.25, 0.31;
  auto f = [&](const Eigen::VectorXd& q) {
    Eigen::VectorXd r;
    Eigen::MatrixXd J;
    internal::RotatingResiduals(points, position, q(0), q(1), q.tail(3), &r, &J);
    return r;
  };
  Eigen::VectorXd r;
  Eigen::MatrixXd J;
  internal::RotatingResiduals(points, position, x(0), x(1), x.tail(3), &r, &J);
  Eigen::MatrixXd numeric(r.size(), 5);
  for (int k = 0; k < 5; ++k) {
    Eigen::VectorXd xp = x, xm = x;
    xp(k) += 1e-6;
    xm(k) -= 1e-6;
    numeric.col(k) = (f(xp) - f(xm)) / 2e-6;
  }
  EXPECT_LT((J - numeric).norm(), 1e-8 * numeric.norm());
}

}  // namespace
}  // namespace kinevis::calibration
