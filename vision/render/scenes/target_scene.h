#pragma once

// Planar calibration targets (issue 5): a chessboard or a grid of dark dots on a white board with a
// white border, at a pose X_CT, seen through any CameraModel; with the ground-truth feature points
// (chessboard inner corners, dot centres) in the target frame and their projections.
//
// Frame T (the target): the board lies in the plane z_T = 0; the origin is the first feature (the
// top-left inner corner of a chessboard, the centre of the top-left dot); x_T runs along a row of
// features, y_T down the columns — OpenCV's object-point layout (i·pitch, j·pitch, 0). With
// X_CT = a translation along z_C the board faces a perspective camera with x_T to the right and
// y_T down in the image. The board is two-sided.
//
// Chessboard: cols × rows squares of side `square`; the square in column c = 0..cols−1 and row
// r = 0..rows−1 spans x_T ∈ [(c−1)·square, c·square], y_T likewise, and is black when c + r is
// even (the top-left square is black). Inner corners: (cols−1) × (rows−1).
// Dot grid: cols × rows dots of `dot_diameter`, centres (i·pitch, j·pitch, 0).
// Both have a white `border` (m) beyond the outermost squares (chessboard) or beyond the outermost
// dot centres (dot grid; border > dot_diameter/2).
//
// Object ids: 0 background (beyond the board), kTargetWhiteId the white board, kTargetBlackId a
// black square or dot.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <string>
#include <vector>

#include "vision/render/renderer.h"

namespace kinevis::vision::render {

inline constexpr int kTargetWhiteId = 1;
inline constexpr int kTargetBlackId = 2;

enum class TargetPattern { kChessboard, kDotGrid };

struct TargetSpec {
  TargetPattern pattern = TargetPattern::kChessboard;
  int cols = 9;  // squares (chessboard) or dots (dot grid) along x_T, >= 2 (chessboard >= 3)
  int rows = 7;  // along y_T, >= 2 (chessboard >= 3)
  double square = 0.03;         // chessboard square side (m), > 0
  double dot_diameter = 0.015;  // dot grid (m), 0 < dot_diameter < pitch
  double pitch = 0.03;          // dot grid centre spacing (m)
  double border = 0.03;         // white margin (m), > 0 (dot grid: > dot_diameter / 2)
  // Radiances in [0, 1].
  double white_radiance = 0.9;
  double black_radiance = 0.1;
  double background_radiance = 0.4;

  // Empty when usable, otherwise every bad field and its value.
  std::string Validate() const;

  // Ground-truth features in T (m), row-major (x_T fastest): chessboard inner corners
  // ((cols−1)·(rows−1) of them), dot centres (cols·rows). Allocates.
  std::vector<Eigen::Vector3d> FeaturePoints() const;
  // Number of features along x_T and y_T (OpenCV's pattern size).
  int feature_cols() const { return pattern == TargetPattern::kChessboard ? cols - 1 : cols; }
  int feature_rows() const { return pattern == TargetPattern::kChessboard ? rows - 1 : rows; }
};

class TargetScene final : public Scene {
 public:
  // X_CT: pose of T in C. Throws std::invalid_argument naming every bad field of `spec`.
  TargetScene(const TargetSpec& spec, const Eigen::Isometry3d& X_CT);

  Hit Trace(const Ray& ray_C) const override;

  const TargetSpec& spec() const { return spec_; }
  const Eigen::Isometry3d& X_CT() const { return X_CT_; }

  // Projects the features through `camera`: (*pixels)[k] and (*status)[k] for feature k of
  // spec().FeaturePoints(). Returns the number of features with status kOk that lie in the image.
  // Allocates (resizes the outputs).
  int ProjectFeatures(const CameraModel& camera, std::vector<Eigen::Vector2d>* pixels,
                      std::vector<ProjectionStatus>* status) const;

 private:
  TargetSpec spec_;
  Eigen::Isometry3d X_CT_;
  Eigen::Matrix3d R_TC_;
  Eigen::Vector3d p_CT_;
  Eigen::Vector3d normal_C_;
  double x_min_, x_max_, y_min_, y_max_;  // board extent in T (m)
};

}  // namespace kinevis::vision::render
