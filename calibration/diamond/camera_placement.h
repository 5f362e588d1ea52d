#pragma once

// Sensitivity of single-camera spherical positioning (seed 001 §IV-A, eq. 18–28) and the choice
// of the camera's distance from the RCM by the seed's benefit function (§IV-B, eq. 29–33).
// `kinevis plan-camera diamond --q 5` calls PlanCameraPlacement() and WriteBenefitPlot().
// calibration/diamond/README.md has the derivations and the comparison with the seed's 44.62 cm.
//
// Geometry (seed Fig. 2): the sphere of radius R about the RCM A, the camera F on an axis through
// A at distance D from it, looking at A; B' the sphere point nearest the camera (on the axis),
// r = D − R the camera's distance from the sphere (the seed's r in §IV-A). A sphere point J at the
// central angle δ from B' (angle B'AJ) is seen at the angle θ from the optical axis:
//     tan θ = R sin δ / (D − R cos δ)                           (sine rule in AFJ; seed eq. 18–20)
//     dθ/dδ = R (D cos δ − R) / (D² − 2 D R cos δ + R²)
//           = (R/r) cos(θ + δ) (cos θ − tan(δ/2) sin θ)         (seed eq. 25–27 with dδ → 0)
//     S = (δ/θ) dθ/dδ                                           (seed eq. 26–28, the elasticity)
// The seed's eq. (27)–(28) carry a factor (cos(θ+δ) − ε sin(θ+δ)), ε = tan(dδ/2), a finite-step
// remnant; at ε = 0 they equal the exact derivative above (verified to 1e-12 in the tests). J is
// visible up to δ_max = acos(R/D), where dθ/dδ = 0 (the silhouette: the view grazes the sphere).
//
// Benefit (eq. 29–32), r now the camera's distance from the RCM as in §IV-B (the seed reuses the
// letter): with α = acos(R/r) the half-angle of the cap the camera sees and θ the lens's half
// view angle,
//     S_ROI   = ∫₀^{2α} ∫₀^{β} R² sin ϑ dϑ dφ = 2 α R² (1 − cos β)     (eq. 30, R² not r²: eq. 31)
//     S_waste = π r² tan²θ − π R² / sin²α = π r² (tan²θ − R²/(r² − R²))
//     J(r)    = q S_ROI − S_waste                                        (eq. 29, 31, 32)
// S_waste is the field of view's disc in the plane through the RCM minus the sphere's silhouette
// there (radius R / sin α). β = π (the seed's "half sphere", eq. 31–32) or π/2 (its "quarter
// sphere" workspace, §V-B). Stationary points, dJ/dr = 0, with A² = r² − R²:
//     tan²θ = q (1 − cos β) R³ / (π A r²) − R⁴ / A⁴,
// which for β = π is the seed's eq. (33), tan²θ R⁻⁴ = 2q / (π A R r²) − A⁻⁴, exactly.
// J → +∞ as r → R (the silhouette term; S_waste < 0 for r < R / sin θ, where the sphere does not
// fit in the view and the model stops meaning "waste"): the optimum is the interior local
// maximum, which PlanCameraPlacement finds by bracketing dJ/dr on a grid and bisection.

#include <string>
#include <vector>

#include "vision/camera/camera_model.h"

namespace kinevis::calibration {

// --- sensitivity (eq. 18–28). R (m) > 0, D (m) > R, δ (rad) in [0, π]; throw
// std::invalid_argument otherwise. ---

// θ (rad) at which the sphere point at central angle δ is seen (also beyond δ_max, where it is
// hidden by the sphere).
double SphereViewAngle(double radius, double camera_distance, double delta);
// dθ/dδ (rad/rad), exact.
double SphereViewAngleRate(double radius, double camera_distance, double delta);
// S = (δ/θ) dθ/dδ; its limit 1 at δ = 0.
double SphereViewElasticity(double radius, double camera_distance, double delta);
// The seed's eq. (28) as printed, with r = D − R and ε = tan(dδ/2) >= 0.
double SeedSensitivityEq28(double radius, double camera_distance, double delta, double epsilon);
// δ_max = acos(R/D): the visible cap's half-angle.
double MaxVisibleCentralAngle(double radius, double camera_distance);

// --- camera placement (eq. 29–33) ---

struct CameraPlacementOptions {
  double radius = 0.2;             // R (m), > 0 (seed: 20 cm)
  double weight = 5.0;             // q, > 0 (seed: 5)
  double half_view_angle = 0.0;    // θ (rad), in (0, π/2): the lens's half field of view
  double roi_polar_extent = M_PI;  // β (rad), in (0, π]: π as eq. (31), π/2 as §V-B
  // Search range of the distance from the RCM, as multiples of R: 1 < min < max.
  double min_distance_factor = 1.001;
  double max_distance_factor = 20.0;
  int curve_points = 2000;  // >= 10: the grid dJ/dr is bracketed on (and the curve returned)

  // Empty when usable, otherwise every bad field and its value.
  std::string Validate() const;
};

struct BenefitTerms {
  double distance = 0.0;    // r (m)
  double roi = 0.0;         // S_ROI (m²)
  double waste = 0.0;       // S_waste (m²)
  double benefit = 0.0;     // J (m²)
  double derivative = 0.0;  // dJ/dr (m)
};

// J and its terms at distance r (m) > R. Throws std::invalid_argument for invalid options or r.
BenefitTerms EvaluateBenefit(const CameraPlacementOptions& options, double distance);

struct CameraPlacement {
  bool found = false;          // an interior local maximum of J in the search range
  double best_distance = 0.0;  // r* (m)
  BenefitTerms at_best;
  // r at which the sphere just fits in the view (S_waste = 0): R / sin θ (m). Below it the
  // waste term is negative.
  double full_view_distance = 0.0;
  std::vector<BenefitTerms> curve;  // on the search grid (geometric spacing)
  std::vector<std::string> notes;   // why nothing was found, a maximum in the S_waste < 0 range
};

// Throws std::invalid_argument with options.Validate()'s message.
CameraPlacement PlanCameraPlacement(const CameraPlacementOptions& options);

// The camera's half view angle (rad) from its model: the angle between the rays of the image
// centre ((w − 1)/2, (h − 1)/2) and of the middle of the nearer edge (kHorizontal: left/right,
// kVertical: top/bottom), or of the nearest corner (kDiagonal); kSmallest the least of the three.
// Throws std::invalid_argument when a needed pixel does not back-project (naming it).
enum class ViewAxis { kHorizontal, kVertical, kDiagonal, kSmallest };
double HalfViewAngle(const vision::CameraModel& camera, ViewAxis axis);

// The benefit function against the distance for each weight q in `weights` (same R, θ, β as
// `options`), as the seed's Fig. 5, with each curve's maximum marked, over [r_min, r_max] (m;
// 0 for automatic: 1.3 R to 4 R). Throws std::invalid_argument for bad options or an empty
// weight list, std::runtime_error when the PNG cannot be written.
void WriteBenefitPlot(const std::string& path, const CameraPlacementOptions& options,
                      const std::vector<double>& weights, double r_min = 0.0, double r_max = 0.0);

}  // namespace kinevis::calibration
