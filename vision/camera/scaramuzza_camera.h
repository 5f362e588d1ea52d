#pragma once

// Scaramuzza's polynomial omnidirectional camera (OCamCalib), seed 003 eq. (2.2): a pixel seen
// through the affine sensor model maps to an ideal sensor point (a, b) at radius ρ = |(a, b)|,
// and sees the direction (a, b, f(ρ)) with f(ρ) = a0 + a1 ρ + a2 ρ² + a3 ρ³ + a4 ρ⁴ (ρ and f in
// pixels). Central: every ray starts at the single effective viewpoint.
//
// Conventions, OCamCalib vs kinevis (frames: see camera_model.h):
//   OCamCalib's cam2world/world2cam take image points as (row, column) and the affine model
//     [row - xc; col - yc] = [c d; e 1] [a; b],
//   so its sensor x axis runs along the rows (down) and y along the columns (right); its 3-D
//   direction is (a, b, f(ρ)) with z = x × y pointing out of the image towards the viewer, i.e.
//   opposite to the line of sight of the image centre (calibrations give a0 < 0).
//   kinevis C: origin at the viewpoint, x to the right (+u), y down (+v), z along the line of sight
//   of the distortion centre (the direction a perspective camera's z would have; for a fisheye the
//   optical axis, for a catadioptric camera looking up into its mirror the direction from the
//   mirror focus towards the camera):
//     p_C = (y_ocam, x_ocam, -z_ocam)    (a proper rotation: 180° about (1, 1, 0)/√2)
//   and pixels are (u, v) = (column, row), 0-based. calib_results.txt gives the centre as
//   "row column, starting from 0 (C convention)": u0 = its second number, v0 = its first. (Values
//   from the Matlab workspace, ocam_model.xc/yc, are 1-based: subtract 1.) c, d, e keep
//   OCamCalib's meaning and values, acting on (row, column) as above.
//
// Domain: the pixels of ideal radius ρ <= max_radius_px, and the directions they see: the angle
// φ between p_C and +z must be <= φ_max = φ(max_radius_px); otherwise kOutsideDomain. The model
// requires φ(ρ) = atan2(ρ, -f(ρ)) to increase strictly on [0, max_radius_px] (checked by
// Validate()).
//
// Projection (world → image) needs the inverse of φ(ρ). At construction it is fitted
// (OCamCalib's "invpol") to inverse_fit_tolerance_px over the whole valid radius; see
// InverseFit. Departure from OCamCalib: the fit is ρ = φ · G(φ) with G a Chebyshev series on
// [0, φ_max] (φ measured from +z_C instead of OCamCalib's elevation θ = φ - π/2, and ρ forced to
// 0 on the axis), of the lowest degree (<= 30) meeting the tolerance; OCamCalib's own invpol
// coefficients are therefore not used and need not be loaded.

#include <Eigen/Core>
#include <array>
#include <string>
#include <vector>

#include "vision/camera/camera_model.h"

namespace kinevis::vision {

struct ScaramuzzaParameters {
  int width = 0;  // image size the parameters belong to (pixels), > 0
  int height = 0;
  // f(ρ) coefficients a0..a4 (OCamCalib "ss", ascending); a_i in px^(1-i). a0 < 0.
  std::array<double, 5> poly{};
  double u0 = 0.0;  // distortion centre (pixels, kinevis convention: column, 0-based)
  double v0 = 0.0;  // (row, 0-based)
  double c = 1.0;   // OCamCalib affine [c d; e 1] on (row, column); c - d e != 0
  double d = 0.0;
  double e = 0.0;
  // Valid ideal-image radius (pixels), e.g. the mirror rim's image. 0: the distance from the
  // centre to the farthest image corner (in ideal coordinates).
  double max_radius_px = 0.0;
  // Maximum error of the fitted inverse polynomial (pixels), > 0.
  double inverse_fit_tolerance_px = 0.01;

  // An OCamCalib calibration of a 752×480 wide-angle camera, published as the example in the
  // README of zhangzichao/omni_cam (calib_results.txt: ss = -2.065170e+02 0 2.207161e-03
  // -4.879622e-06 1.865656e-08; centre row 241.800066, column 394.552874 (0-based); c, d, e =
  // 1.000330, 0.000219, 0.000257). Valid radius: the image corners (463.3 px, φ_max = 144.2°).
  static ScaramuzzaParameters Default();
};

// What construction found when it fitted the inverse polynomial.
struct InverseFit {
  bool fitted = false;         // false: the fit missed the tolerance; Project() root-finds f
  int degree = -1;             // degree of G (Chebyshev series), -1 when not fitted
  double max_error_px = 0.0;   // max pixel error of the fit over a 8193-point sweep of ρ
  double max_radius_px = 0.0;  // ρ_max actually used (pixels)
  double max_angle = 0.0;      // φ_max (rad)
};

enum class ScaramuzzaProjection {
  kRefined,            // fitted inverse, then Newton on f to machine precision (default)
  kInversePolynomial,  // fitted inverse only: OCamCalib's world2cam (error <= fit tolerance)
};

class ScaramuzzaCamera final : public CameraModel {
 public:
  // Validates and fits the inverse polynomial (allocates here only). Throws
  // std::invalid_argument naming every bad parameter (see Validate()).
  explicit ScaramuzzaCamera(const ScaramuzzaParameters& parameters,
                            ScaramuzzaProjection projection = ScaramuzzaProjection::kRefined);

  const ScaramuzzaParameters& parameters() const { return parameters_; }
  const InverseFit& inverse_fit() const { return fit_; }
  ScaramuzzaProjection projection() const { return projection_; }

  std::string_view Name() const override { return "scaramuzza"; }
  int width() const override { return parameters_.width; }
  int height() const override { return parameters_.height; }
  bool IsCentral() const override { return true; }
  // kOutsideDomain for p_C = 0 and for φ > φ_max. The Jacobian is that of the method used: exact
  // (implicit-function theorem on f) for kRefined or without a fit, of the fitted polynomial for
  // kInversePolynomial.
  ProjectionStatus Project(const Eigen::Vector3d& p_C, Eigen::Vector2d* pixel,
                           Matrix23d* J_pixel_point = nullptr) const override;
  // Closed form (seed 003 eq. 2.2). kOutsideDomain beyond max_radius_px. At the centre pixel with
  // a1 != 0 f is not differentiable; the a1 term is left out of the Jacobian there.
  ProjectionStatus BackProject(const Eigen::Vector2d& pixel, Ray* ray,
                               RayJacobian* J = nullptr) const override;
  std::string Validate() const override;

  // The exact inverse: ρ(φ) by safeguarded Newton on f (independent of the fit). Does not
  // allocate. For tests and for inspecting the fit.
  ProjectionStatus ExactRadius(double phi, double* rho) const;
  // The fitted inverse ρ = φ G(φ) (valid after a successful fit, φ in [0, φ_max]).
  double FittedRadius(double phi, double* drho_dphi = nullptr) const;

 private:
  double F(double rho, double* df = nullptr) const;
  // Root of h(ρ) = ρ z + f(ρ) r on [0, ρ_max], starting from rho_guess.
  ProjectionStatus SolveRadius(double r, double z, double rho_guess, double* rho) const;
  void FitInverse();

  ScaramuzzaParameters parameters_;
  ScaramuzzaProjection projection_;
  double rho_max_ = 0.0;
  double phi_max_ = 0.0;
  InverseFit fit_;
  std::vector<double> chebyshev_;             // G(φ) coefficients
  std::vector<double> chebyshev_derivative_;  // dG/dt coefficients, t = 2φ/φ_max - 1
};

}  // namespace kinevis::vision
