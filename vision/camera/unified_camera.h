#pragma once

// Unified central catadioptric camera (Geyer–Daniilidis / Barreto sphere model, seed 002 §II-B)
// with Mei's generalised intrinsics and distortion, identical to OpenCV's cv::omnidir model
// (opencv_contrib ccalib; cv::omnidir::projectPoints is the test oracle).
//
// Frame C (this model's camera frame): origin at the single effective viewpoint (the mirror focus,
// the centre of the unit sphere; the seed's mirror frame F_m). z along the mirror axis, pointing
// from the viewpoint away from the conventional camera that looks at the mirror, i.e. the
// direction a perspective camera's z would have (for ξ = 0 the model IS a pinhole camera with
// C at its optical centre); x and y parallel to the image's u and v axes (right, down). This is
// exactly OpenCV's omnidir convention: cv::omnidir::projectPoints with rvec = tvec = 0 takes
// points in this frame. The perspective camera's centre sits at (0, 0, -ξ) in C.
//
//   X_s = p_C / |p_C|                                  (lift to the unit sphere)
//   x_u = X_s.x / (X_s.z + ξ),  y_u = X_s.y / (X_s.z + ξ)    (seed 002: normalised image plane)
//   r² = x_u² + y_u²,  radial = 1 + k1 r² + k2 r⁴
//   x_d = x_u radial + 2 p1 x_u y_u + p2 (r² + 2 x_u²)
//   y_d = y_u radial + p1 (r² + 2 y_u²) + 2 p2 x_u y_u
//   u = γ1 x_d + s y_d + u0,  v = γ2 y_d + v0           (K = [γ1 s u0; 0 γ2 v0; 0 0 1])
//
// Note OpenCV's skew s is in pixels (K(0,1)), not a dimensionless α·γ1.
//
// Domain: ξ ≤ 1: points with X_s.z + ξ <= 0 are kBehindCamera (for ξ = 1, parabolic, only the
// direction -z). ξ > 1 (fisheye-like): the perspective centre lies outside the sphere and only the
// cap X_s.z > -1/ξ is imaged injectively; other points are kOutsideDomain, and so are pixels
// whose undistorted point lies outside the image of the sphere, r² > 1 / (ξ² - 1).
// Distortion: where the distortion map's Jacobian has a non-positive determinant (the map folds
// over) both directions return kOutsideDomain.

#include <Eigen/Core>
#include <array>
#include <string>

#include "vision/camera/camera_model.h"

namespace kinevis::vision {

struct UnifiedParameters {
  int width = 0;  // image size the intrinsics belong to (pixels), > 0
  int height = 0;
  double xi = 0.0;      // mirror parameter ξ >= 0 (0 perspective, 0<ξ<1 hyperbolic, 1 parabolic)
  double gamma1 = 0.0;  // generalised focal lengths (pixels), > 0 (OpenCV K(0,0), K(1,1))
  double gamma2 = 0.0;
  double skew = 0.0;  // pixels (OpenCV K(0,1)); u = γ1 x_d + skew y_d + u0
  double u0 = 0.0;    // principal point (pixels, OpenCV K(0,2), K(1,2))
  double v0 = 0.0;
  // Mei's distortion, OpenCV omnidir order: k1, k2, p1, p2 (dimensionless).
  std::array<double, 4> distortion{};

  // A 640×480 paracatadioptric-like camera as in seed 002's omnidirectional experiment
  // (ξ = 0.95, γ = 230 px, centre at the image centre, no distortion). Illustrative values: the
  // seed gives no intrinsics; chosen so that the horizon (X_s.z = 0) images at r = γ/ξ ≈ 242 px.
  static UnifiedParameters Default();
};

// Why a line conic could not be formed or inverted.
enum class LineConicStatus {
  kOk,
  kDistorted,     // distortion is non-zero: a line's image is not a conic in pixel coordinates
  kInvalidInput,  // the normal is not a finite unit vector / the conic is not finite or zero
  kDegenerate,    // eq. (10) is undefined: the interpretation plane contains the mirror axis
};

std::string_view ToString(LineConicStatus status);

class UnifiedCamera final : public CameraModel {
 public:
  // Throws std::invalid_argument naming every bad parameter (see Validate()).
  explicit UnifiedCamera(const UnifiedParameters& parameters);

  const UnifiedParameters& parameters() const { return parameters_; }
  bool HasDistortion() const;

  std::string_view Name() const override { return "unified"; }
  int width() const override { return parameters_.width; }
  int height() const override { return parameters_.height; }
  bool IsCentral() const override { return true; }
  // kOutsideDomain also for p_C = 0 (the viewpoint itself).
  ProjectionStatus Project(const Eigen::Vector3d& p_C, Eigen::Vector2d* pixel,
                           Matrix23d* J_pixel_point = nullptr) const override;
  // The ray starts at the viewpoint (origin of C); its direction is LiftToSphere(pixel).
  ProjectionStatus BackProject(const Eigen::Vector2d& pixel, Ray* ray,
                               RayJacobian* J = nullptr) const override;
  std::string Validate() const override;

  // Lifts a pixel to the point X_s on the unit sphere (= the unit direction of the points the
  // pixel sees, in C). Undistorts by Newton's method on Mei's distortion (tolerance 1e-14 in
  // normalised coordinates, at most 100 iterations, else kNoConvergence), then applies Mei's
  // inverse of the sphere projection:
  //   X_s = η (x_u, y_u, 1) - (0, 0, ξ),  η = (ξ + sqrt(1 + (1 - ξ²) r²)) / (1 + r²).
  // J_sphere_pixel (optional) receives ∂X_s/∂(u, v) (per pixel). Does not allocate.
  ProjectionStatus LiftToSphere(const Eigen::Vector2d& pixel, Eigen::Vector3d* X_s,
                                Matrix32d* J_sphere_pixel = nullptr) const;

  // Image of a 3-D line (seed 002 eq. 1–2). n_C is the unit normal of the line's interpretation
  // plane (the plane through the viewpoint and the line), in C. Writes the 3×3 symmetric conic
  // Ω_p in homogeneous pixel coordinates, scaled to unit Frobenius norm: every projected point
  // p = (u, v, 1) of the line satisfies pᵀ Ω_p p = 0. Only defined without distortion
  // (kDistorted otherwise). The conic is the image of the whole great circle n·X_s = 0, i.e. of
  // the line and of its reflection through the viewpoint.
  LineConicStatus LineConic(const Eigen::Vector3d& n_C, Eigen::Matrix3d* Omega_pixel) const;

  // Inverse of LineConic, seed 002 eq. (10): Ω_m = Kᵀ Ω_p K, n = ω3 / |ω3| (third column).
  // The conic is known up to scale and sign, so n is returned with n.z > 0. kDegenerate when
  // |ω3| < 1e-9 |Ω_m| (n.z ≈ 0: the line's image passes through the principal point and eq. (10)
  // cannot recover n); kDistorted when distortion is non-zero.
  LineConicStatus InterpretationNormal(const Eigen::Matrix3d& Omega_pixel,
                                       Eigen::Vector3d* n_C) const;

 private:
  UnifiedParameters parameters_;
  Eigen::Matrix3d K_;
};

}  // namespace kinevis::vision
