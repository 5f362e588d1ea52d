#pragma once

// Pinhole camera with Brown–Conrady distortion, identical to OpenCV's model (cv::projectPoints with
// up to 8 coefficients k1 k2 p1 p2 k3 k4 k5 k6; k4..k6 form OpenCV's rational model and are zero for
// plain Brown). Frames and pixel convention: see camera_model.h.
//
//   x' = X/Z, y' = Y/Z, r² = x'² + y'²
//   radial = (1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶)
//   x'' = x' radial + 2 p1 x'y' + p2 (r² + 2x'²)
//   y'' = y' radial + p1 (r² + 2y'²) + 2 p2 x'y'
//   u = fx x'' + cx, v = fy y'' + cy

#include <array>
#include <string>

#include "vision/camera/camera_model.h"

namespace kinevis::vision {

struct PinholeBrownParameters {
  int width = 0;   // image size the intrinsics belong to (pixels), > 0
  int height = 0;
  double fx = 0.0;  // focal lengths (pixels), > 0
  double fy = 0.0;
  double cx = 0.0;  // principal point (pixels)
  double cy = 0.0;
  // OpenCV order: k1, k2, p1, p2, k3, k4, k5, k6 (dimensionless).
  std::array<double, 8> distortion{};
};

class PinholeBrownCamera final : public CameraModel {
 public:
  // Throws std::invalid_argument naming every bad parameter (see Validate()).
  explicit PinholeBrownCamera(const PinholeBrownParameters& parameters);

  const PinholeBrownParameters& parameters() const { return parameters_; }

  std::string_view Name() const override { return "pinhole-brown"; }
  int width() const override { return parameters_.width; }
  int height() const override { return parameters_.height; }
  bool IsCentral() const override { return true; }
  ProjectionStatus Project(const Eigen::Vector3d& p_C, Eigen::Vector2d* pixel,
                           Matrix23d* J_pixel_point = nullptr) const override;
  // Undistorts iteratively (Newton on the distortion map, tolerance 1e-12 in normalised
  // coordinates); kOutsideDomain where the distortion map folds over (its Jacobian is singular).
  ProjectionStatus BackProject(const Eigen::Vector2d& pixel, Ray* ray,
                               RayJacobian* J = nullptr) const override;
  std::string Validate() const override;

 private:
  PinholeBrownParameters parameters_;
};

}  // namespace kinevis::vision
