#pragma once

// Intrinsic calibration of a pinhole + Brown camera (vision/camera/pinhole_camera.h, OpenCV's
// model) from images of a planar chessboard, on top of OpenCV: cv::findChessboardCorners +
// cv::cornerSubPix for detection, cv::calibrateCamera (Zhang's method followed by
// Levenberg–Marquardt on the reprojection error) for the estimate and its standard deviations.
//
// Frames: C the camera frame (camera_model.h). T the board ("target") frame: origin at the first
// inner corner OpenCV reports, x along the first row of inner corners, y along the columns,
// z = x × y; inner corner (i, j) at (i s, j s, 0) m. X_CT is the pose of T in C. A board with an
// even × odd or odd × even number of inner corners is reported in one of two orders (180° apart)
// depending on the view; the intrinsics do not depend on it, the poses do.
//
// Expected failures (a board not found, too few usable images) are data in the result, not
// exceptions; bad options throw std::invalid_argument.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "calibration/common/estimation.h"
#include "vision/camera/pinhole_camera.h"

namespace kinevis::calibration {

struct ChessboardCalibrationOptions {
  int board_cols = 9;       // inner corners along a row, >= 2
  int board_rows = 6;       // inner corners along a column, >= 2
  double square_m = 0.025;  // side of one square (m), finite and > 0
  int min_images = 3;       // fewer usable images than this: no calibration, >= 1
  // Distortion model: plumb_bob k1 k2 p1 p2 k3 by default with k3 fixed at zero (as ROS's
  // calibrator does; free it for wide-angle lenses); rational_model adds k4 k5 k6
  // (rational_polynomial) and frees k3 unless fix_k3 is set explicitly.
  bool fix_k3 = true;
  bool rational_model = false;
  bool zero_tangential = false;      // p1 = p2 = 0
  bool fix_principal_point = false;  // cx, cy stay at the image centre ((w-1)/2, (h-1)/2)
  bool fix_aspect_ratio = false;     // fx = fy
  // Corner refinement: cornerSubPix half-window (pixels); 0 = automatic, 40 % of the smallest
  // distance between neighbouring detected corners, clamped to [2, 11].
  int subpix_half_window_px = 0;

  // Empty when usable, otherwise one message naming every bad field and its value.
  std::string Validate() const;
};

// An 8-bit grey image, row-major: grey[v * width + u]. `name` identifies it in reports (the path
// for files).
struct CalibrationImage {
  std::string name;
  int width = 0;
  int height = 0;
  std::vector<std::uint8_t> grey;
};

// Loads a file as 8-bit grey (any format OpenCV reads). Throws std::runtime_error naming the path
// when it cannot be read.
CalibrationImage LoadCalibrationImage(const std::string& path);

enum class ImageStatus {
  kUsed,           // board found, used in the calibration
  kBoardNotFound,  // findChessboardCorners found no complete board
  kSizeMismatch,   // image size differs from the first readable image's
  kUnreadable,     // the file could not be read as an image
};
const char* ToString(ImageStatus status);  // "used", "board not found", ...

struct ImageReport {
  std::string name;
  ImageStatus status = ImageStatus::kBoardNotFound;
  std::string reason;  // why it was refused, empty when used
  int width = 0;
  int height = 0;
  // For used images (board order, row by row): refined corners and the corners re-projected
  // through the estimated intrinsics and pose (pixels).
  std::vector<Eigen::Vector2d> corners_px;
  std::vector<Eigen::Vector2d> reprojected_px;
  double rms_px = 0.0;  // RMS of |reprojected − detected| over this image's corners
  double max_px = 0.0;  // largest |reprojected − detected|
  Eigen::Isometry3d X_CT = Eigen::Isometry3d::Identity();  // board pose in C
  double tilt_rad = 0.0;  // angle between the board normal and the optical axis
};

// Standard deviations of the estimated intrinsics (from cv::calibrateCamera: the square roots of
// the diagonal of (JᵀJ)⁻¹ scaled by the residual variance); zero for fixed parameters.
struct IntrinsicsStdDev {
  double fx = 0, fy = 0, cx = 0, cy = 0;  // pixels
  std::array<double, 8> distortion{};     // k1 k2 p1 p2 k3 k4 k5 k6
};

struct ChessboardCalibrationResult {
  bool calibrated = false;  // false: too few usable images (see `message`)
  std::string message;      // why not calibrated; empty when calibrated
  vision::PinholeBrownParameters parameters;
  IntrinsicsStdDev stddev;
  double rms_px = 0.0;  // RMS reprojection error over all corners of all used images
  int used_images = 0;
  std::vector<ImageReport> images;  // one per input, in input order
  // Fraction of a 16 × 12 grid of image cells whose centre lies inside the convex hull of the
  // detected corners of at least one used image (0..1).
  double coverage = 0.0;
  double max_tilt_rad = 0.0;  // largest board tilt among used images
  // Degenerate or weak data: fewer than 3 usable images, all boards nearly fronto-parallel
  // (max tilt < 15°), coverage < 0.5, an intrinsic with a large standard deviation.
  std::vector<std::string> warnings;

  // The estimator contract's report: fx fy cx cy (px) and the distortion coefficients, σ and
  // covariance from one identifiability analysis of the reprojection Jacobian of every corner
  // (intrinsics and board poses together); held coefficients (fix_k3, zero_tangential, ...)
  // marked held. Residuals: corner reprojection (px).
  EstimationReport estimation;

  // Names of the refused images with their reasons, "a.png (board not found), b.png (...)".
  std::string RefusedSummary() const;
};

// Detects the board in every image and calibrates when at least options.min_images are usable.
// Throws std::invalid_argument with options.Validate()'s message when the options are bad.
ChessboardCalibrationResult CalibrateChessboard(const std::vector<CalibrationImage>& images,
                                                const ChessboardCalibrationOptions& options);

// The same for files, loaded one at a time (an unreadable file is refused as kUnreadable).
ChessboardCalibrationResult CalibrateChessboardFiles(const std::vector<std::string>& paths,
                                                     const ChessboardCalibrationOptions& options);

// Writes an overlay PNG of one used image: the image in grey, detected corners as green circles
// with the board's first corner marked and the rows joined, re-projected corners as red crosses,
// and the image's RMS / max error as text. Throws std::invalid_argument when `report` is not a
// used image of this size and std::runtime_error naming `png_path` when it cannot be written.
void WriteOverlayPng(const CalibrationImage& image, const ImageReport& report,
                     const std::string& png_path);

}  // namespace kinevis::calibration
