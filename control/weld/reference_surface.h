#pragma once

// The undamaged reference surface of a scanned part (issue 7, weld path planner): a low-order
// polynomial heightfield in a local frame R found by PCA, fitted robustly so that cavitation pits
// (one-sided depressions) and scanner outliers do not pull it.
//
// Frames:
//   0  robot base frame (robots/weld5/weld5_model.h); the map's points are given in it (m).
//   R  the reference frame of the fit: origin at the map's centroid, x_R and y_R the two
//      principal directions of largest spread (PCA), z_R = x_R × y_R the normal of the best plane,
//      oriented OUT OF THE MATERIAL (towards where the scanner looked from: the side the map's
//      normals point to when they are given, else the side of `outward_hint_0`).
// Surface in R:  w = h(u, v) = Σ_k c_k φ_k(u / L, v / L), (u, v, w) = p_R, with the monomials
// φ_k(x, y) = x^(t−j) y^j of total degree t = 0..degree (k runs t-major, j = 0..t) and L a length
// scale (m) for conditioning. Heights, depths and coefficients are in m.
//
// Depth of a measured point below the reference: δ = h(u, v) − w, measured along z_R (not along
// the local normal; the two differ by the factor cos(slope), < 1 % for slopes < 8°; the summary
// reports the largest slope so that callers can judge).
//
// Robust estimator: a start from the medians of the heights over a coarse grid (pits cover a
// minority of each coarse cell; outliers do not move a median), then iteratively re-weighted
// least squares with Tukey's biweight at c = tukey_c · s, s = 1.4826 · median |r| (MAD, floored at
// min_scale) re-estimated every iteration. Points with weight 0 (|r| > c s) are outliers: the pits
// and the scanner's spikes.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <string>
#include <vector>

namespace kinevis::control {

struct ReferenceSurface {
  Eigen::Isometry3d X_0R = Eigen::Isometry3d::Identity();  // the fit's frame R in 0
  int degree = 2;                                          // 1..4
  double length_scale = 1.0;                               // L (m), > 0
  Eigen::VectorXd coefficients;                            // c_k (m), (degree+1)(degree+2)/2

  static int CoefficientCount(int degree) { return (degree + 1) * (degree + 2) / 2; }
  // h(u, v) (m) and its gradient (∂h/∂u, ∂h/∂v) (unitless); u, v in m, in R.
  double Height(double u, double v) const;
  Eigen::Vector2d Gradient(double u, double v) const;
  // Unit normal out of the material at (u, v): in R and in 0.
  Eigen::Vector3d NormalR(double u, double v) const;
  Eigen::Vector3d Normal0(double u, double v) const;
  // The surface point above (u, v), in 0 (m).
  Eigen::Vector3d Point0(double u, double v) const;
  // A point of 0 in R.
  Eigen::Vector3d ToR(const Eigen::Vector3d& p_0) const { return X_0R.inverse() * p_0; }
  // δ = h(u, v) − w of a point p_0 (m; positive below the reference, i.e. inside a pit).
  double Depth(const Eigen::Vector3d& p_0) const;
  // Where the line p_0 + t·u_0 (u_0 a direction in 0, not parallel to the surface) meets the
  // surface: t (m along u_0 normalised) by Newton's method from the vertical projection; false
  // when it does not converge in 50 steps or |u_0 · z_R| < 1e-3.
  bool IntersectLine(const Eigen::Vector3d& p_0, const Eigen::Vector3d& u_0, double* t) const;
};

struct ReferenceFitOptions {
  int degree = 2;           // polynomial degree, 1..4 (2: a quadric, a turbine blade's patch)
  double tukey_c = 4.685;   // Tukey's c in units of s, > 0 (95 % efficiency at the normal)
  int max_iterations = 30;  // IRLS iterations, >= 1
  double min_scale = 1e-6;  // floor of s (m), > 0: exact data would give s = 0
  double tolerance = 1e-9;  // stop when max |Δh| over the fit's extent drops below this (m), > 0
  int coarse_cells = 12;    // coarse grid for the median start, per axis, 2..100
  // Subsample stride bound for the scale and the IRLS: at most this many points are used, >= 100
  // (the scale and 6–15 coefficients need far fewer than a million points).
  int max_fit_points = 200000;
  // Out-of-material side when the map has no normals: z_R points towards this point (m, in 0).
  // The default, the robot base origin, is right for maps scanned from the robot (the scanner
  // sees the side of the part that faces the robot).
  Eigen::Vector3d outward_hint_0 = Eigen::Vector3d::Zero();

  std::string Validate() const;  // empty when usable, else every bad field and its value
};

enum class ReferenceFitStatus {
  kOk,
  kTooFewPoints,  // fewer than 3 × the coefficient count (and >= 10) finite points
  kDegenerate,    // the points lie on (nearly) a line or a point: no plane, no heightfield
};
const char* ToString(ReferenceFitStatus status);  // "ok", "too few points", "degenerate"

struct ReferenceFit {
  ReferenceFitStatus status = ReferenceFitStatus::kTooFewPoints;
  ReferenceSurface surface;
  std::string message;  // why, when not ok
  int points = 0;       // points the fit saw (after the subsample)
  int inliers = 0;      // with final weight > 0
  double inlier_fraction = 0.0;
  double robust_scale = 0.0;   // s (m)
  double inlier_rms = 0.0;     // RMS residual of the inliers (m): the scanner's noise as seen
  double max_slope_deg = 0.0;  // largest |∇h| over the fitted extent, as an angle (deg)
  int iterations = 0;
  Eigen::Vector2d uv_min = Eigen::Vector2d::Zero();  // extent of the points in R (m)
  Eigen::Vector2d uv_max = Eigen::Vector2d::Zero();
  std::vector<std::string> warnings;  // few inliers, steep surface, normals against z_R, ...
  bool ok() const { return status == ReferenceFitStatus::kOk; }
};

// Fits the reference surface to points p_0 (m, in 0). n_0 is empty or holds one unit normal per
// point (out of the material; they orient z_R and are checked against the fit). Non-finite points
// are skipped (counted in a warning). Throws std::invalid_argument for bad options or when n_0 is
// neither empty nor of p_0's size. Too few or degenerate points: a status, not an exception.
ReferenceFit FitReferenceSurface(const std::vector<Eigen::Vector3d>& p_0,
                                 const std::vector<Eigen::Vector3d>& n_0,
                                 const ReferenceFitOptions& options = {});

}  // namespace kinevis::control
