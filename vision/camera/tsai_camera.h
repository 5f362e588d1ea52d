#pragma once

// Tsai's radial-alignment-constraint (RAC) camera model (Tsai 1987; Lenz & Tsai 1987), as used by
// seed 004 (§5.1, eq. 23–25, Table 1) for the camera of the laser-triangulation scanner.
// Frames and pixel convention: see camera_model.h (C at the optical centre, z forward, x right,
// y down; pixel (0, 0) the centre of the top-left pixel).
//
// Tsai's chain, point p_C = (x, y, z) in C to pixel (u, v):
//   undistorted sensor coordinates (mm):  X_u = f x / z,  Y_u = f y / z
//   radial distortion, written from distorted to undistorted (the direction Tsai writes it):
//     X_u = X_d g(r_d²),  Y_u = Y_d g(r_d²),  r_d² = X_d² + Y_d²  (mm²)
//       kTsai      g = 1 + κ1 r_d²              (Tsai 1987, step 3, first radial term)
//       kDivision  g = 1 / (1 - κ1 r_d²)        (seed 004, eq. 23, as the seed writes it)
//     Both agree to first order in κ1 r_d²; κ1 > 0 is barrel distortion.
//   pixels:  u = s_x X_d / d'_x + C_x,  v = Y_d / d_y + C_y
// With κ1 = 0 this is the pinhole camera fx = f s_x / d'_x, fy = f / d_y (pixels), cx = C_x,
// cy = C_y.
//
// Back-projection is direct. Projection inverts the distortion radially in closed form: kTsai
// solves the cubic κ1 r_d³ + r_d - r_u = 0 (trigonometric/hyperbolic root of the physical branch,
// free of Cardano's cancellation), kDivision the quadratic κ1 r_u r_d² + r_d - r_u = 0; no
// iteration.
//
// Domain: the model is a lens only where r_u(r_d) = r_d g(r_d²) increases:
//   kTsai, κ1 < 0:      r_d² < -1/(3 κ1)   (r_u < (2/3) r_d,max)
//   kDivision, κ1 > 0:  r_d² < 1/κ1        (the pole; every r_u is reached)
//   kDivision, κ1 < 0:  r_d² < -1/κ1       (r_u < r_d,max / 2)
//   otherwise unlimited. Outside it Project/BackProject return kOutsideDomain, and Validate()
//   rejects a κ1 whose domain ends inside the image.
//
// Units: lengths on the sensor in millimetres as Tsai and the seed give them (names say so);
// points p_C in metres (only the ratios x/z, y/z matter).

#include <string>

#include "vision/camera/camera_model.h"

namespace kinevis::vision {

enum class TsaiDistortionForm {
  kTsai,      // X_u = X_d (1 + κ1 r_d²)
  kDivision,  // X_u = X_d / (1 - κ1 r_d²), seed 004 eq. (23)
};

// "tsai" / "division" (the YAML spelling of distortion_form).
std::string_view ToString(TsaiDistortionForm form);

// YAML-friendly: one scalar per field.
struct TsaiParameters {
  int width = 0;  // image size (pixels), > 0
  int height = 0;
  double focal_length_mm = 0.0;  // f, effective focal length (mm), finite and > 0
  double cx = 0.0;               // image centre (C_x, C_y) (pixels), finite
  double cy = 0.0;
  // d'_x: effective horizontal centre-to-centre pixel distance (mm per pixel), Tsai's
  // d_x N_cx / N_fx (= d_x for a digital sensor read out pixel by pixel); finite and > 0.
  double pixel_pitch_x_mm = 0.0;
  double pixel_pitch_y_mm = 0.0;  // d_y (mm per pixel), finite and > 0
  double scale_x = 1.0;           // s_x, horizontal uncertainty scale factor, finite and > 0
  double kappa1_per_mm2 = 0.0;    // κ1 (mm⁻²), finite; with r_d in mm
  TsaiDistortionForm distortion_form = TsaiDistortionForm::kTsai;

  // Pinhole-equivalent focal lengths (pixels): fx = f s_x / d'_x, fy = f / d_y.
  double fx() const { return focal_length_mm * scale_x / pixel_pitch_x_mm; }
  double fy() const { return focal_length_mm / pixel_pitch_y_mm; }

  // Empty when usable, otherwise one message naming every bad field and its value.
  std::string Validate() const;

  // Seed 004, Table 1: Lumenera LW230, 1616×1216, f = 9.43773 mm, centre (738, 585) px,
  // scale factors 227.27 px/mm (d'_x = d_y = 1/227.27 mm = 4.4 µm, s_x = 1), k = 9.4604e-9 per
  // pixel² in the division form of eq. (23), i.e. κ1 = k · 227.27² = 4.8864e-4 mm⁻².
  static TsaiParameters Seed004();
};

// Converts a distortion coefficient given per pixel² of r measured in vertical pixels (seed 004,
// eq. 23: r² = μ²(u - C_x)² + (v - C_y)², μ = fy/fx, so r = r_d / d_y) to κ1 per mm².
double Kappa1PerMm2FromPerPixel2(double k_per_px2, double pixel_pitch_y_mm);

class TsaiCamera final : public CameraModel {
 public:
  // Throws std::invalid_argument naming every bad parameter (see TsaiParameters::Validate()).
  explicit TsaiCamera(const TsaiParameters& parameters);

  const TsaiParameters& parameters() const { return parameters_; }
  // Largest distorted radius r_d (mm) of the domain; +inf when unlimited.
  double max_distorted_radius_mm() const { return max_rd_mm_; }

  std::string_view Name() const override { return "tsai"; }
  int width() const override { return parameters_.width; }
  int height() const override { return parameters_.height; }
  bool IsCentral() const override { return true; }
  // kBehindCamera when z <= 0; kOutsideDomain when the point is beyond the distortion's domain.
  ProjectionStatus Project(const Eigen::Vector3d& p_C, Eigen::Vector2d* pixel,
                           Matrix23d* J_pixel_point = nullptr) const override;
  // Direct (no iteration); kOutsideDomain beyond the domain. The ray origin is (0, 0, 0).
  ProjectionStatus BackProject(const Eigen::Vector2d& pixel, Ray* ray,
                               RayJacobian* J = nullptr) const override;
  std::string Validate() const override { return parameters_.Validate(); }

 private:
  TsaiParameters parameters_;
  double max_rd_mm_ = 0.0;  // see max_distorted_radius_mm()
};

}  // namespace kinevis::vision
