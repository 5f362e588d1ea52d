// Guards issue 7's experiments 1 and 2 (experiments/scanner_accuracy, scanner_calibration) with
// margins of about twice to five times the measured figures.
#include "calibration/laser_scanner/scanner_accuracy.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "vision/camera/camera_file.h"

namespace kinevis::calibration {
namespace {

using vision::laser::ScannerGeometry;

TEST(ScannerExperiments, CalibrationRecoversTheSeedsTable2) {
  const auto camera = vision::BuiltinCameraModel("tsai-seed004");
  const ScannerGeometry truth = ScannerGeometry::Seed004();
  SimulatedCalibrationOptions options;
  options.outlier_fraction = 0.02;
  const SimulatedCalibration run = SimulateScannerCalibration(*camera, truth, options);
  const LaserScannerCalibration& c = run.calibration;
  ASSERT_TRUE(c.ok()) << c.errors.front();
  ASSERT_EQ(run.board_poses.size(), 5u);
  for (const BoardPose& pose : run.board_poses) EXPECT_TRUE(pose.ok()) << pose.message;
  const double e_by = c.geometry.rotating_b_y - truth.rotating_b_y;
  const double e_dy = c.geometry.rotating_d_y - truth.rotating_d_y;
  const double e_bx = c.geometry.fixed_b_x_prime - truth.fixed_b_x_prime;
  const double e_cx = c.geometry.fixed_cot_theta_x - truth.fixed_cot_theta_x;
  std::printf(
      "errors: b_y %.4f mm (σ %.4f), d_y %.4f mm (σ %.4f), b_x' %.4f mm (σ %.4f), "
      "cot_x %.2e (σ %.1e)\n",
      1e3 * e_by, 1e3 * c.b_y_sigma(), 1e3 * e_dy, 1e3 * c.d_y_sigma(), 1e3 * e_bx,
      1e3 * c.b_x_prime_sigma(), e_cx, c.cot_theta_x_sigma());
  // Measured: 0.008, 0.014, 0.001 mm, 2e-6.
  EXPECT_LT(std::abs(e_by), 0.05e-3);
  EXPECT_LT(std::abs(e_dy), 0.1e-3);
  EXPECT_LT(std::abs(e_bx), 0.02e-3);
  EXPECT_LT(std::abs(e_cx), 2e-5);
  // The σ are those of the stripe noise only (the board poses' ~0.01 mm errors are not in
  // them): errors stay within a few σ.
  EXPECT_LT(std::abs(e_by), 5.0 * c.b_y_sigma());
  EXPECT_LT(std::abs(e_dy), 5.0 * c.d_y_sigma());
  for (const RotatingPositionEstimate& p : c.positions) {
    const double cot = 1.0 / std::tan(options.theta0 + options.theta_per_step * p.step);
    EXPECT_LT(std::abs(p.cot_theta_y - cot), 5e-5) << "step " << p.step;
  }
  EXPECT_NEAR(c.stepper.theta_per_step, options.theta_per_step, 1e-3 * options.theta_per_step);
}

TEST(ScannerExperiments, AccuracyOverTheWorkingRangeMeetsTheTarget) {
  const auto camera = vision::BuiltinCameraModel("tsai-seed004");
  const ScannerGeometry truth = ScannerGeometry::Seed004();
  const SimulatedCalibration run = SimulateScannerCalibration(*camera, truth, {});
  ASSERT_TRUE(run.calibration.ok());
  ScannerAccuracyOptions options;  // 0.1 px stripe noise
  options.scans = 5;
  double ssr = 0.0;
  int n = 0;
  for (double depth = 0.25; depth <= 0.6501; depth += 0.1) {
    const ScannerAccuracy a = EvaluateScannerAccuracy(*camera, truth, run.calibration.geometry,
                                                      depth, AngleSource::kIntersection, options);
    ASSERT_GT(a.points, 1000);
    ssr += a.rms * a.rms * a.points;
    n += a.points;
    // Measured 0.05 mm at 250 mm to 0.25 mm at 650 mm (eq. 9's error grows as z²).
    EXPECT_LT(a.rms, 0.5e-3) << "depth " << depth;
    EXPECT_LT(std::abs(a.mean_depth_error), 0.15e-3) << "depth " << depth;
  }
  const double rms = std::sqrt(ssr / n);
  std::printf("RMS over 250-650 mm: %.3f mm\n", 1e3 * rms);
  EXPECT_LT(rms, 0.3e-3);  // issue 7's target; 0.16 mm measured
  // Without noise the calibrated geometry alone leaves well under 0.1 mm.
  options.noise_px = 0.0;
  options.scans = 1;
  const ScannerAccuracy exact = EvaluateScannerAccuracy(*camera, truth, run.calibration.geometry,
                                                        0.65, AngleSource::kIntersection, options);
  EXPECT_LT(exact.rms, 0.1e-3);
}

}  // namespace
}  // namespace kinevis::calibration
