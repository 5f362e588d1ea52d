#pragma once

// One interface for every camera model in kinevis: project a 3-D point to a pixel, back-project a
// pixel to a ray, each with its Jacobian.
//
// Frames and conventions (defined once, here):
//   C  the camera frame. For a perspective camera: origin at the optical centre, z along the
//      optical axis (forward), x to the right and y down in the image (OpenCV's convention). A
//      catadioptric model documents in its own header where C sits (e.g. the unified model puts it
//      at the mirror's single viewpoint, the non-single-viewpoint mirror at the lens's pinhole).
//   pixel  (u, v) in pixels: u to the right, v down, (0, 0) the centre of the top-left pixel
//      (OpenCV's convention; add 0.5 for the corner convention).
// Points are in metres. A ray is an origin p_C_O (m) and a unit direction d_C: the points the
// pixel sees are p_C_O + t d_C, t > 0. For a central (single-viewpoint) model the origin is the
// same for every pixel (the viewpoint); for a non-central model it is where the ray leaves the
// optics (e.g. the reflection point on the mirror).
//
// Jacobians are analytic (or exact by the implicit-function theorem where the model is defined
// implicitly) and every one is checked against central finite differences in the tests.
// Project/BackProject are const, do not allocate and are safe to call from several threads.

#include <Eigen/Core>
#include <string>
#include <string_view>

namespace kinevis::vision {

using Matrix23d = Eigen::Matrix<double, 2, 3>;
using Matrix32d = Eigen::Matrix<double, 3, 2>;

// Why a projection or back-projection has no result. kOk is the only success.
enum class ProjectionStatus {
  kOk,
  kBehindCamera,   // the point is not in front of the optics (z <= 0, or behind the mirror)
  kOutsideDomain,  // outside where the model is valid (beyond the mirror rim, beyond the
                   // distortion's monotonic range, outside the polynomial's fitted range)
  kNoConvergence,  // an iterative inverse did not converge to its tolerance
};

// "ok", "behind camera", "outside model domain", "no convergence".
std::string_view ToString(ProjectionStatus status);

// A ray in C: points p_C_O + t * d_C for t > 0; d_C has unit norm.
struct Ray {
  Eigen::Vector3d p_C_O = Eigen::Vector3d::Zero();
  Eigen::Vector3d d_C = Eigen::Vector3d::UnitZ();
};

// Jacobians of a back-projected ray with respect to the pixel.
struct RayJacobian {
  Matrix32d d_origin_d_pixel = Matrix32d::Zero();     // ∂p_C_O/∂(u, v), zero for central models
  Matrix32d d_direction_d_pixel = Matrix32d::Zero();  // ∂d_C/∂(u, v) of the unit direction
};

class CameraModel {
 public:
  virtual ~CameraModel() = default;

  // Short model name as used in files and on the command line, e.g. "pinhole-brown".
  virtual std::string_view Name() const = 0;
  // Image size the parameters belong to (pixels). Projection does not clip to it: a pixel outside
  // the image is returned as computed, so callers decide (see InImage()).
  virtual int width() const = 0;
  virtual int height() const = 0;
  // True for a single-viewpoint model (all rays share one origin).
  virtual bool IsCentral() const = 0;

  // Projects the point p_C (m, in C) to `pixel`. When `J_pixel_point` is not null it receives
  // ∂(u, v)/∂p_C (pixels per metre). On failure `pixel` and the Jacobian are left unspecified.
  virtual ProjectionStatus Project(const Eigen::Vector3d& p_C, Eigen::Vector2d* pixel,
                                   Matrix23d* J_pixel_point = nullptr) const = 0;

  // Back-projects `pixel` to the ray of points it sees. When `J` is not null it receives the
  // ray's derivatives with respect to the pixel.
  virtual ProjectionStatus BackProject(const Eigen::Vector2d& pixel, Ray* ray,
                                       RayJacobian* J = nullptr) const = 0;

  // Returns an empty string when the parameters are usable, otherwise one message naming every
  // bad parameter and its value.
  virtual std::string Validate() const = 0;

  // True when `pixel` lies on the image: -0.5 <= u < width - 0.5 and likewise for v.
  bool InImage(const Eigen::Vector2d& pixel) const {
    return pixel.x() >= -0.5 && pixel.y() >= -0.5 && pixel.x() < width() - 0.5 &&
           pixel.y() < height() - 0.5;
  }
};

}  // namespace kinevis::vision
