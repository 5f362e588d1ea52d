#pragma once

// Scanner accuracy against depth in simulation (issue 7, experiment 1; shared by
// experiments/scanner_accuracy and its guard test): a flat board at depth z (tilted a little),
// the exact stripes of the TRUE scanner (LaserScene) sampled as a column/row-wise extractor
// reports them (synthetic_stripes.h) with Gaussian noise across the stripe, triangulated by the
// scanner model with the geometry UNDER TEST (true or calibrated); the error of each point is its
// distance from the true surface point seen at the noise-free pixel.
//
// Two ways of knowing the rotating laser's angle at a scan:
//   kKnownAngle    cot θ_y is known (the stepper, calibrated): eq. 9 directly;
//   kIntersection  cot θ_y from the stripes' intersection (eq. 11): straight lines fitted to
//                  both noisy stripes within ±intersection_window_px of their crossing.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cmath>
#include <cstdint>
#include <vector>

#include "calibration/laser_scanner/board_pose.h"
#include "calibration/laser_scanner/laser_scanner_calibration.h"
#include "vision/camera/camera_model.h"
#include "vision/laser/scanner_model.h"

namespace kinevis::calibration {

enum class AngleSource { kKnownAngle, kIntersection };

struct ScannerAccuracyOptions {
  double noise_px = 0.1;  // σ across the stripe (px), >= 0
  int scans = 10;         // scans (noise draws) per depth, >= 1
  double intersection_window_px = 150.0;
  uint64_t seed = 1;
};

struct ScannerAccuracy {
  double depth = 0.0;  // board depth on the optical axis (m)
  int points = 0;
  double rms = 0.0;               // 3-D error RMS (m)
  double max = 0.0;               // (m)
  double mean_depth_error = 0.0;  // mean signed z error (m): the bias
  double cot_error_rms = 0.0;     // kIntersection: RMS error of cot θ_y
};

// One depth. `truth` renders, `used` triangulates. Throws std::invalid_argument for bad options.
ScannerAccuracy EvaluateScannerAccuracy(const vision::CameraModel& camera,
                                        const vision::laser::ScannerGeometry& truth,
                                        const vision::laser::ScannerGeometry& used, double depth,
                                        AngleSource source, const ScannerAccuracyOptions& options);

// A simulated calibration run (issue 7, experiment 2): the seed's dot board at `poses` (X_CS),
// rendered with the lasers off through `camera` (renderer noise 1.5 grey levels, blur 0.7 px) and
// its pose estimated from the image (board_pose.h); at each pose and stepper position the TRUE
// scanner's exact stripes with `noise_px` across them (no stripe extractor in the tree yet);
// then CalibrateLaserScanner. The stepper: θ_y = theta0 + theta_per_step · step.
struct SimulatedCalibrationOptions {
  std::vector<Eigen::Isometry3d> poses;  // empty: DefaultCalibrationPoses()
  std::vector<int> steps = {0, 40, 80, 120, 160, 200};
  double theta0 = 72.0 * M_PI / 180.0;                // (rad)
  double theta_per_step = 1.8 / 32.0 * M_PI / 180.0;  // (rad), 1.8° / 32 microsteps
  double noise_px = 0.1;
  double outlier_fraction = 0.0;  // stripe points moved 3–8 px
  uint64_t seed = 1;
};

struct SimulatedCalibration {
  LaserScannerCalibration calibration;
  std::vector<BoardPose> board_poses;
  double board_translation_error_max = 0.0;  // (m) against the true poses
  double board_rotation_error_max = 0.0;     // (rad)
};

// Five board poses 0.45–0.65 m away, tilted 15–20° about different axes.
std::vector<Eigen::Isometry3d> DefaultCalibrationPoses();

SimulatedCalibration SimulateScannerCalibration(const vision::CameraModel& camera,
                                                const vision::laser::ScannerGeometry& truth,
                                                const SimulatedCalibrationOptions& options);

}  // namespace kinevis::calibration
