#pragma once

// Calibration of the laser-triangulation scanner's geometry (seed 004 §3, eq. 12–32) from images
// of a flat board with the laser stripes on: the rotating laser's base distance b_y and
// misalignment d_y (eq. 8), its angle cot θ_y at every stepper position, and the fixed laser's
// b_x' and cot θ_x. The camera is calibrated beforehand (vision::CameraModel, e.g. Tsai).
//
// Frames and units: C the scanner camera frame (vision/laser/scanner_model.h), S the board frame
// (board_pose.h: the board is z_S = 0). Metres; calibration/laser_scanner/README.md derives the
// equations and says where we depart from the seed.
//
// Per image: the board pose X_CS (board_pose.h), the rotating laser's stepper position, and the
// stripe pixels of each laser. Every stripe pixel's ray is met with the board plane (eq. 13–16,
// 23–25) giving p = (x, y, z) in C; then
//   rotating laser, per stepper position k (eq. 28):  cot θ_k z − b'_k = −y   over its points,
//   across positions (eq. 32):                        b_y + d_y cot θ_k = b'_k,
//   fixed laser, over all images (eq. 29):            cot θ_x z − b_x' = −x,
// each solved by linear least squares (SVD), then the rotating laser's (b_y, d_y, cot θ_1..N)
// refined jointly over all its stripe points (Gauss–Newton on y + cot θ_k z − b_y − d_y cot θ_k,
// a bilinear problem started from the linear solution), which gives their joint covariance.
//
// Identifiability, reported not hidden:
//   - a position's points must span depth (several board poses, or a tilted board): the
//     condition number of its column-equilibrated [z, −1] system is warned about above
//     warn_depth_condition and the position is refused above max_depth_condition (a single
//     frontal board pose gives one depth: cot θ and b' are then inseparable);
//   - b_y and d_y are separated only by positions with different cot θ_y (eq. 31–32): the
//     condition number of [1, cot θ_k] is warned about above warn_separation_condition, and
//     with fewer than 2 positions or above max_separation_condition the rotating laser is not
//     calibrated (error), while each position's cot θ_k and b'_k are still reported;
//   - the fixed laser needs the same depth spread over all images.
// Stripe points far from their plane (beyond outlier_threshold robust σ, MAD) are dropped and
// counted. Expected problems are data (errors, warnings); malformed input throws.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "calibration/common/estimation.h"
#include "vision/camera/camera_model.h"
#include "vision/laser/scanner_model.h"

namespace kinevis::calibration {

// One board image with the stripes on.
struct LaserCalibrationImage {
  std::string name;  // for messages (e.g. the image file); may be empty
  // Pose of the board frame S in C (the board is z_S = 0), e.g. BoardPose::X_CS.
  Eigen::Isometry3d X_CS = Eigen::Isometry3d::Identity();
  // The rotating laser's stepper position (motor steps) when the image was taken: images with
  // the same step share one cot θ_y. The real scanner reports it (its stepper driver's count).
  int rotating_step = 0;
  // Stripe pixels (px, camera_model.h convention); either may be empty (that laser off).
  std::vector<Eigen::Vector2d> rotating_pixels;
  std::vector<Eigen::Vector2d> fixed_pixels;
};

struct LaserScannerCalibrationOptions {
  int min_points_per_position = 20;  // rotating stripe points a position needs, >= 2
  int min_fixed_points = 20;         // fixed stripe points needed, >= 2
  // Column-equilibrated condition numbers (see the header comment), 1 <= warn <= max.
  double warn_depth_condition = 200.0;       // ≈ 4 mm depth spread at 0.4 m
  double max_depth_condition = 1e4;          // ≈ 0.08 mm
  double warn_separation_condition = 100.0;  // ≈ cot θ_y spread 0.005 about 0.25 (0.3°)
  double max_separation_condition = 1e4;
  // Robust σ multiples beyond which a stripe point is an outlier (0 = keep all), >= 0 (or 0).
  double outlier_threshold = 4.0;
  // Floor of the robust σ (m), > 0: exact synthetic data would give 0.
  double min_robust_sigma = 1e-6;
  bool refine = true;             // the joint Gauss–Newton refinement of the rotating laser
  int max_iterations = 20;        // >= 1
  double step_tolerance = 1e-13;  // stop when |Δ| <= this, >= 0

  // Empty when usable, otherwise every bad field and its value.
  std::string Validate() const;
};

// One stepper position of the rotating laser.
struct RotatingPositionEstimate {
  int step = 0;
  int images = 0;
  int points = 0;    // stripe points used (inliers)
  int outliers = 0;  // dropped
  bool estimated = false;
  std::string problem;  // why not estimated
  double depth_condition = std::numeric_limits<double>::infinity();
  // Eq. 28 for this position alone (linear least squares) and its standard deviations.
  double cot_theta_y_linear = std::numeric_limits<double>::quiet_NaN();
  double cot_theta_y_linear_sigma = std::numeric_limits<double>::quiet_NaN();
  double b_y_prime_linear = std::numeric_limits<double>::quiet_NaN();  // (m)
  double b_y_prime_linear_sigma = std::numeric_limits<double>::quiet_NaN();
  // After the joint refinement (the linear values when it did not run): cot θ_y, its σ, and
  // b_y' = b_y + d_y cot θ_y (eq. 8, m).
  double cot_theta_y = std::numeric_limits<double>::quiet_NaN();
  double cot_theta_y_sigma = std::numeric_limits<double>::quiet_NaN();
  double b_y_prime = std::numeric_limits<double>::quiet_NaN();
  double residual_rms = std::numeric_limits<double>::quiet_NaN();  // distance from the plane (m)
};

// θ_y (rad, in (0, π): θ = atan2(1, cot θ)) against the stepper position, least squares over the
// estimated positions: θ_y = theta_at_step0 + theta_per_step · step. Fitted with >= 2 distinct
// steps; lets a scan use the stepper count when the stripes' intersection is not seen.
struct StepperFit {
  bool fitted = false;
  double theta_at_step0 = std::numeric_limits<double>::quiet_NaN();  // (rad)
  double theta_per_step = std::numeric_limits<double>::quiet_NaN();  // (rad per step)
  double residual_rms = std::numeric_limits<double>::quiet_NaN();    // (rad)
  int positions = 0;
};

struct LaserScannerCalibration {
  vision::laser::ScannerGeometry geometry;  // NaN for what was not calibrated
  bool rotating_calibrated = false;         // b_y, d_y
  bool fixed_calibrated = false;            // b_x', cot θ_x
  // Covariances: (b_y, d_y) in m², and (b_x' (m), cot θ_x) — σ² (JᵀJ)⁻¹ from the residuals.
  Eigen::Matrix2d rotating_covariance = Eigen::Matrix2d::Zero();
  Eigen::Matrix2d fixed_covariance = Eigen::Matrix2d::Zero();
  double b_y_sigma() const { return std::sqrt(rotating_covariance(0, 0)); }
  double d_y_sigma() const { return std::sqrt(rotating_covariance(1, 1)); }
  double b_x_prime_sigma() const { return std::sqrt(fixed_covariance(0, 0)); }
  double cot_theta_x_sigma() const { return std::sqrt(fixed_covariance(1, 1)); }

  std::vector<RotatingPositionEstimate> positions;                        // ascending step
  double separation_condition = std::numeric_limits<double>::infinity();  // eq. 32
  double fixed_depth_condition = std::numeric_limits<double>::infinity();
  StepperFit stepper;

  // Residuals: distance of the stripe points (met with the board) from their laser plane (m).
  int rotating_points = 0, rotating_outliers = 0;
  int fixed_points = 0, fixed_outliers = 0;
  int unusable_pixels = 0;  // not back-projected, or their ray misses the board
  double rotating_residual_rms = std::numeric_limits<double>::quiet_NaN();
  double rotating_residual_max = std::numeric_limits<double>::quiet_NaN();
  double fixed_residual_rms = std::numeric_limits<double>::quiet_NaN();
  double fixed_residual_max = std::numeric_limits<double>::quiet_NaN();
  int images = 0;
  int iterations = 0;  // joint refinement
  // The joint refinement's last step was <= options.step_tolerance within max_iterations (a
  // warning says so when it was not). False when options.refine is off: nothing iterated.
  bool converged = false;

  std::vector<std::string> errors;    // what could not be calibrated and why
  std::vector<std::string> warnings;  // weakly identified parameters, outliers, unusable pixels
  // The estimator contract's report: b_y, d_y, cot θ_y per stepper position, b_x', cot θ_x with
  // σ from one identifiability analysis of both solves; unidentified when one laser failed.
  // Position parameters are named "cot_theta_y.K", K the index into `positions`.
  EstimationReport estimation;
  bool ok() const { return errors.empty(); }
};

// Throws std::invalid_argument naming every problem: bad options, no images, a pose that is not
// finite or not a rotation, a non-finite pixel (image index/name and point index). The camera
// must be central with its viewpoint at C's origin (as ScannerModel). Allocates.
LaserScannerCalibration CalibrateLaserScanner(const std::vector<LaserCalibrationImage>& images,
                                              const vision::CameraModel& camera,
                                              const LaserScannerCalibrationOptions& options = {});

// The point where `pixel`'s ray meets the board plane of X_CS (eq. 23–25 with eq. 16), in C.
// False when the pixel cannot be back-projected or the ray misses the board (parallel, behind).
bool IntersectBoard(const vision::CameraModel& camera, const Eigen::Isometry3d& X_CS,
                    const Eigen::Vector2d& pixel, Eigen::Vector3d* p_C);

}  // namespace kinevis::calibration
