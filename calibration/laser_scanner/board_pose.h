#pragma once

// The pose of the seed's calibration board (seed 004 §5.1, Fig. 14: 9 × 9 dark dots 26.5 mm
// apart on a flat board) from one image, and the board plane in the scanner camera frame C
// (eq. 12–16) that the laser calibration intersects the stripe pixels' rays with.
//
// Frames: C the scanner camera frame (vision/camera/camera_model.h); S the board frame of
// vision/render/scenes/laser_scene.h: the board is z_S = 0, z_S out of the board towards the
// camera, dot (row, col) at render::DotGrid::DotCentre_S(row, col). X_CS is the pose of S in C.
//
// Steps (EstimateBoardPose):
//  1. dots: adaptive threshold (dark against the local mean), connected components, kept when
//     ellipse-like (area ≈ 4π√det Σ of the pixel covariance Σ); exactly rows × cols must remain
//     (the whole grid in view), otherwise kGridNotFound says how many were found;
//  2. sub-pixel centre of each dot: the centroid of its darkness (local board level minus grey
//     level) over the blob's grown bounding box — the centroid of the dot's image area, which
//     anti-aliased edges make sub-pixel;
//  3. order: the dots' undistorted coordinates, the four corners of their convex hull, the
//     homography from the grid to the image tried for each corner labelling; a labelling is
//     accepted when every dot falls within max_grid_residual cells of a distinct grid node. A
//     square grid fits in four ways (quarter turns about z_S): the one with x_S (columns) closest
//     to the image's +u and a right-handed S with z_S towards the camera is taken; the board
//     PLANE, which is all the laser calibration needs, is the same for all four;
//  4. pose: planar PnP (OpenCV IPPE) on the undistorted coordinates, then Gauss–Newton on the
//     pixel residuals through the camera model. The measured centroid of a dot is the centroid of
//     the projected disc, which is not the projection of the disc's centre (perspective and
//     distortion shift it, ≈ 0.1–0.2 px for 5 mm dots at 400 mm tilted 30°): the refinement
//     predicts the centroid of the projected disc boundary (48 points, polygon centroid) unless
//     options.disc_centroid_model is false.
//
// Expected failures (no grid, a pose that does not converge) are data in BoardPose (status,
// message), never exceptions; bad options or a bad grid throw std::invalid_argument.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <string>
#include <string_view>
#include <vector>

#include "vision/camera/camera_model.h"
#include "vision/render/renderer.h"
#include "vision/render/scenes/laser_scene.h"

namespace kinevis::calibration {

using Matrix6d = Eigen::Matrix<double, 6, 6>;

struct BoardPoseOptions {
  // Adaptive threshold: a pixel is dark when it is more than threshold_offset grey levels below
  // the mean of its threshold_window_px × threshold_window_px neighbourhood (odd, >= 3; 0: auto,
  // width / 8 rounded to odd, at least 51 — larger than the biggest dot expected). offset > 0.
  int threshold_window_px = 0;
  double threshold_offset = 12.0;
  // Blobs kept as dots: area in [min_dot_area_px, max_dot_area_fraction × image area], ellipse
  // fill ratio area / (4π√det Σ) within [1 − max_fill_deviation, 1 + max_fill_deviation], minor /
  // major axis >= min_axis_ratio (0.15: tilted up to ≈ 80°).
  double min_dot_area_px = 20.0;        // > 0
  double max_dot_area_fraction = 0.02;  // (0, 1]
  double max_fill_deviation = 0.2;      // (0, 1)
  double min_axis_ratio = 0.15;         // (0, 1]
  // Grid ordering: largest distance (grid cells) of a dot from its node under the fitted
  // homography, (0, 0.5).
  double max_grid_residual = 0.3;
  // Refinement.
  bool disc_centroid_model = true;
  int max_iterations = 30;        // >= 1
  double step_tolerance = 1e-10;  // stop when |Δ| (rad, m) <= this, >= 0
  // The pose is rejected (kPoseFailed) when the residual RMS exceeds this (px), > 0.
  double max_rms_px = 1.0;

  // Empty when usable, otherwise every bad field and its value.
  std::string Validate() const;
};

enum class BoardPoseStatus {
  kOk,
  kGridNotFound,  // not exactly rows × cols dots, or no consistent ordering
  kPoseFailed,    // PnP or the refinement failed (a dot not projectable, no convergence, RMS)
};
std::string_view ToString(BoardPoseStatus status);  // "ok", "grid not found", "pose failed"

struct DotObservation {
  int row = 0;
  int col = 0;
  Eigen::Vector2d pixel = Eigen::Vector2d::Zero();  // measured centroid (px)
  double area_px = 0.0;                             // thresholded blob area (px²)
};

struct BoardPose {
  BoardPoseStatus status = BoardPoseStatus::kGridNotFound;
  std::string message;               // why, when not kOk
  int candidates = 0;                // dot-like blobs found
  std::vector<DotObservation> dots;  // ordered row by row when the grid was found
  double grid_residual = 0.0;        // largest distance of a dot from its node (cells)
  // Confidence in [0, 1]: (1 − grid_residual / 0.5) · exp(−rms_px² / (2 · 0.3²)); 0 when not kOk.
  // ≈ 1 for a clean grid with sub-pixel residuals; below 0.5 something is off (blur, a dot
  // half-hidden, a wrong camera model).
  double confidence = 0.0;

  Eigen::Isometry3d X_CS = Eigen::Isometry3d::Identity();
  // Covariance of the pose (6 × 6): a small rotation δω (rad, in C: R ← exp(δω) R) and the
  // translation (m), σ² (JᵀJ)⁻¹ with σ² = SSR / (2N − 6) from the final pixel residuals.
  Matrix6d covariance = Matrix6d::Zero();
  double rms_px = 0.0;
  double max_px = 0.0;
  int iterations = 0;
  bool converged = false;

  bool ok() const { return status == BoardPoseStatus::kOk; }
  // Eq. 13–16: the board plane (A, B, C, D) in C with A x + B y + C z + D = 0, (A, B, C) = the
  // third column of R (unit), D = −(A, B, C) · T.
  Eigen::Vector4d PlaneInC() const;
};

// Steps 1–3 only: the ordered dots (status kOk with dots filled, pose untouched) or kGridNotFound.
// The image must be camera-sized. Throws std::invalid_argument for bad options, a bad grid or an
// image of the wrong size.
BoardPose DetectDotGrid(const vision::ImageView8& image, const vision::CameraModel& camera,
                        const vision::render::DotGrid& grid, const BoardPoseOptions& options = {});

// Step 4 from ordered dots (e.g. DetectDotGrid's, or observations from elsewhere): fills the
// pose of `detection` (a copy) and returns it. kPoseFailed with a message when it fails.
BoardPose SolveBoardPose(const BoardPose& detection, const vision::CameraModel& camera,
                         const vision::render::DotGrid& grid, const BoardPoseOptions& options = {});

// Steps 1–4.
BoardPose EstimateBoardPose(const vision::ImageView8& image, const vision::CameraModel& camera,
                            const vision::render::DotGrid& grid,
                            const BoardPoseOptions& options = {});

// The centroid (px) of the image of the disc of radius `radius` (m) centred at p_S_centre on
// z_S = 0, seen from pose X_CS: the polygon centroid of `samples` projected boundary points.
// False when a boundary point does not project.
bool ProjectedDiscCentroid(const vision::CameraModel& camera, const Eigen::Isometry3d& X_CS,
                           const Eigen::Vector2d& p_S_centre, double radius, int samples,
                           Eigen::Vector2d* centroid);

}  // namespace kinevis::calibration
