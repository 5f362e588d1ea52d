#pragma once

// Pinhole camera with Brown–Conrady distortion, identical to OpenCV's model (cv::projectPoints with
// up to 8 coefficients k1 k2 p1 p2 k3 k4 k5 k6; k4..k6 form OpenCV's rational model and are zero
// for plain Brown). Frames and pixel convention: see camera_model.h.
//
//   x' = X/Z, y' = Y/Z, r² = x'² + y'²
//   radial = (1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶)
//   x'' = x' radial + 2 p1 x'y' + p2 (r² + 2x'²)
//   y'' = y' radial + p1 (r² + 2y'²) + 2 p2 x'y'
//   u = fx x'' + cx, v = fy y'' + cy
//
// Domain. A distortion polynomial is only a lens model up to the radius where the radial map
// r -> r·radial(r²) stops increasing (or the rational denominator reaches zero): beyond it the
// model folds back and two directions would share a pixel. The constructor finds that radius
// (max_undistorted_radius(), +inf when there is none within 87° off axis); Project returns
// kOutsideDomain for points at or beyond it, and for points where the full 2-D distortion map
// (tangential terms included) has a non-positive Jacobian determinant. OpenCV applies no such
// limit; inside the domain the pixels are OpenCV's to rounding (tested to 1e-9 px).

#include <array>
#include <string>

#include "vision/camera/camera_model.h"

namespace kinevis::vision {

// YAML-friendly (the ROS camera_info reader in camera_info_yaml.h fills it).
struct PinholeBrownParameters {
  int width = 0;  // image size the intrinsics belong to (pixels), > 0
  int height = 0;
  double fx = 0.0;  // focal lengths (pixels), finite and > 0
  double fy = 0.0;
  double cx = 0.0;  // principal point (pixels), finite
  double cy = 0.0;
  // OpenCV order: k1, k2, p1, p2, k3, k4, k5, k6 (dimensionless, finite).
  std::array<double, 8> distortion{};
};

class PinholeBrownCamera final : public CameraModel {
 public:
  // Throws std::invalid_argument naming every bad parameter (see Validate()).
  explicit PinholeBrownCamera(const PinholeBrownParameters& parameters);

  const PinholeBrownParameters& parameters() const { return parameters_; }
  // Largest normalised radius r = |(x', y')| of the model's domain (see above); +inf if unlimited.
  double max_undistorted_radius() const { return max_radius_; }

  std::string_view Name() const override { return "pinhole-brown"; }
  int width() const override { return parameters_.width; }
  int height() const override { return parameters_.height; }
  bool IsCentral() const override { return true; }
  // kBehindCamera when Z <= 0; kOutsideDomain outside the distortion's domain (see above).
  ProjectionStatus Project(const Eigen::Vector3d& p_C, Eigen::Vector2d* pixel,
                           Matrix23d* J_pixel_point = nullptr) const override;
  // Undistorts by Newton's method on the 2-D distortion map (exact Jacobian, step halving that
  // keeps every iterate inside the domain), from (x'', y'') as the starting point; converged when
  // |distort(x', y') - (x'', y'')| <= 1e-12 in normalised coordinates (it usually reaches ~1e-16).
  // kOutsideDomain when the pixel has no preimage inside the domain (it lies beyond the fold of
  // the distortion, e.g. in the corners of a strong barrel model extrapolated past its data);
  // kNoConvergence when 50 iterations do not reach the tolerance. The ray origin is (0, 0, 0).
  ProjectionStatus BackProject(const Eigen::Vector2d& pixel, Ray* ray,
                               RayJacobian* J = nullptr) const override;
  // Checks: width, height > 0; fx, fy finite and > 0; cx, cy finite; every coefficient finite.
  std::string Validate() const override;

 private:
  PinholeBrownParameters parameters_;
  double max_radius_ = 0.0;  // see max_undistorted_radius()
  double max_radius2_ = 0.0;
};

}  // namespace kinevis::vision
