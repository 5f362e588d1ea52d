#pragma once

// The laser-triangulation scanner of seed 004 (§2, eq. 1–11): a camera and two laser line
// projectors — a FIXED one whose plane is "parallel to the Y axis" and a ROTATING one (on a
// stepper) whose plane is "parallel to the X axis" — turning a stripe pixel into a 3-D point in
// the scanner camera frame C.
//
// Frame C: the camera frame of camera_model.h (origin at the optical centre, x right, y down in
// the image, z along the optical axis). Lengths in metres (the seed's mm at file edges only).
//
// The two laser planes in C (seed eq. 17–18 with eq. 8; the same planes as
// vision/render/scenes/laser_scene.h):
//   rotating:  y + cot θ_y z = b_y'   with b_y' = b_y + d_y cot θ_y            (eq. 8, 17)
//   fixed:     x + cot θ_x z = b_x'   (the seed calibrates b_x' = b_x + d_x cot θ_x only, §3)
// A pixel is back-projected through the camera model to its undistorted normalised coordinates
// (a, b) = (x_u / f, y_u / f) (for the Tsai camera exactly seed eq. 25's (A_x, B_y)); the point is
// the pixel's ray met by the laser's plane:
//   rotating (eq. 9):   p = b_y' / (cot θ_y + b) (a, b, 1)
//   fixed    (eq. 10):  p = b_x' / (cot θ_x + a) (a, b, 1)
// which is the seed's b'/(f cot θ + y_u) (x_u, y_u, f) divided through by f.
// The rotating laser's angle at a scan follows from the image of the two stripes' intersection
// (eq. 11): with q = (cot θ_x + a_int) / b_x' (the inverse depth of the intersection on the fixed
// plane)
//   cot θ_y = (b_y q − b_int) / (1 − d_y q).
// We re-derived eq. 11 from the two planes (the point on the fixed plane, put into the rotating
// plane's equation, solved for cot θ_y) and it agrees with the seed's form; its b_x is b_x'.
//
// Jacobians are analytic and checked against central differences in
// tests/vision/laser/scanner_model_test.cc. Parameters are ordered as ScannerParameter.
// All methods are const, allocate nothing and are thread-safe.

#include <Eigen/Core>
#include <string>
#include <string_view>

#include "vision/camera/camera_model.h"
#include "vision/render/scenes/laser_scene.h"

namespace kinevis::vision::laser {

// Index of each scanner parameter in the parameter Jacobians.
enum ScannerParameter : int {
  kRotatingBy = 0,    // b_y (m)
  kRotatingDy = 1,    // d_y (m)
  kFixedBxPrime = 2,  // b_x' (m)
  kFixedCotThetaX = 3,
  kRotatingCotThetaY = 4,  // the rotating laser's angle at the scan (an input, not a constant)
};
inline constexpr int kScannerParameters = 5;

using Matrix35d = Eigen::Matrix<double, 3, kScannerParameters>;
using RowVector5d = Eigen::Matrix<double, 1, kScannerParameters>;

// The scanner's constant geometry (the seed's Table 2), metres.
struct ScannerGeometry {
  double rotating_b_y = 0.101973;       // b_y (m): finite
  double rotating_d_y = -0.0160156;     // d_y (m): finite, the misalignment of eq. 8
  double fixed_b_x_prime = -0.0066788;  // b_x' (m): finite and |b_x'| >= 1e-5 (a plane through
                                        // the camera centre cannot triangulate)
  double fixed_cot_theta_x = -0.0922;   // cot θ_x: finite

  // Eq. 8: the rotating laser's base distance at angle cot θ_y (m).
  double RotatingBPrime(double cot_theta_y) const {
    return rotating_b_y + rotating_d_y * cot_theta_y;
  }
  // The planes as (n, w) with n · p = w, n = (0, 1, cot θ_y) resp. (1, 0, cot θ_x) (not unit).
  Eigen::Vector4d RotatingPlane(double cot_theta_y) const;
  Eigen::Vector4d FixedPlane() const;

  // Empty when usable, otherwise one message naming every bad field and its value.
  std::string Validate() const;

  // Seed 004, Table 2.
  static ScannerGeometry Seed004() { return ScannerGeometry{}; }
};

// The renderer's scanner geometry (laser_scene.h) and back: the same four numbers.
ScannerGeometry FromSceneGeometry(const render::LaserScannerGeometry& scene);
render::LaserScannerGeometry ToSceneGeometry(const ScannerGeometry& geometry);

enum class TriangulationStatus {
  kOk,
  kCameraFailed,     // the camera model could not back-project the pixel (outside its domain)
  kParallelToPlane,  // the pixel's ray is (numerically) parallel to the laser plane
  kBehindCamera,     // the ray meets the plane behind the camera (z <= 0)
  kDegenerate,       // eq. 11: 1 − d_y q = 0 (the intersection lies at depth d_y)
};
// "ok", "camera failed", "ray parallel to the laser plane", "behind the camera", "degenerate".
std::string_view ToString(TriangulationStatus status);

struct TriangulationJacobian {
  Matrix32d d_point_d_pixel = Matrix32d::Zero();       // ∂p_C/∂(u, v) (m per pixel)
  Matrix35d d_point_d_parameters = Matrix35d::Zero();  // ∂p_C/∂(b_y, d_y, b_x', cot θ_x, cot θ_y)
};

class ScannerModel {
 public:
  // `camera` must outlive the model and be central with its viewpoint at C's origin (the seed's
  // equations assume every ray starts there); throws std::invalid_argument otherwise, or when
  // geometry.Validate() reports a problem (the message names every bad field).
  ScannerModel(const CameraModel& camera, const ScannerGeometry& geometry);

  const CameraModel& camera() const { return camera_; }
  const ScannerGeometry& geometry() const { return geometry_; }

  // Undistorted normalised coordinates (a, b) of `pixel` (seed eq. 25) and ∂(a, b)/∂(u, v)
  // (per pixel) when J is not null. kCameraFailed when the camera cannot back-project it,
  // kBehindCamera when its ray does not point forwards (z <= 0).
  TriangulationStatus Normalized(const Eigen::Vector2d& pixel, Eigen::Vector2d* ab,
                                 Eigen::Matrix2d* J = nullptr) const;

  // Eq. 9: the point of the ROTATING laser's stripe seen at `pixel` (pixels) when the laser is at
  // `cot_theta_y` (finite). On failure p_C and J are unspecified.
  TriangulationStatus TriangulateRotating(const Eigen::Vector2d& pixel, double cot_theta_y,
                                          Eigen::Vector3d* p_C,
                                          TriangulationJacobian* J = nullptr) const;
  // Eq. 10: the point of the FIXED laser's stripe seen at `pixel`. The cot θ_y column of the
  // parameter Jacobian is zero.
  TriangulationStatus TriangulateFixed(const Eigen::Vector2d& pixel, Eigen::Vector3d* p_C,
                                       TriangulationJacobian* J = nullptr) const;
  // Eq. 11: the rotating laser's cot θ_y from the image `pixel` of the two stripes'
  // intersection, with its derivatives w.r.t. the pixel and the parameters (the cot θ_y column is
  // zero) when not null.
  TriangulationStatus CotThetaYFromIntersection(const Eigen::Vector2d& pixel, double* cot_theta_y,
                                                Eigen::RowVector2d* J_pixel = nullptr,
                                                RowVector5d* J_parameters = nullptr) const;

 private:
  const CameraModel& camera_;
  ScannerGeometry geometry_;
};

}  // namespace kinevis::vision::laser
