#pragma once

// Calibration of the hexapod's base attachment points A_j from the image edges of its legs
// (seed 002 §IV-B, eq. 12–16). Per leg j, every robot configuration k in which the leg was seen
// gives two interpretation-plane normals n1, n2 (the planes through the camera's viewpoint tangent
// to the leg cylinder of radius R); the leg's axis passes through A_j, so (eq. 12–13)
//
//     n1ᵀ A_j = −R,   n2ᵀ A_j = −R,
//
// and stacking N configurations gives the 2N×3 linear system of eq. 14, solved here by
// iteratively re-weighted least squares (Huber, then optionally Tukey's biweight). A rigid fit of
// the six estimates to the CAD points gives the camera-to-base pose X_CB (eq. 15) and a global
// scale compares inter-point distances with the CAD (eq. 16). calibration/hexapod/README.md
// explains the estimators, the thresholds and where we depart from the seed.
//
// Frames as in robots/hexapod/hexapod_model.h: B the base, C the camera (for the unified model
// the mirror frame, seed F_m). Normals are unit vectors in C oriented so that the leg's axis lies
// on their negative side, n · p_C_A = −R (vision/render/scenes/hexapod_scene.h
// PredictCylinderLimbs). Lengths in m.
//
// Expected data problems (a leg seen in too few configurations, configurations too alike) are
// reported in the result (per-leg status, errors, warnings), not thrown. Malformed input (non-unit
// or non-finite normals, R <= 0, no configurations) and bad options throw std::invalid_argument.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cstdint>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "calibration/common/estimation.h"
#include "robots/hexapod/hexapod_model.h"

namespace kinevis::calibration {

// The two limb (edge) interpretation-plane normals of one leg in one configuration, unit, in C,
// oriented away from the leg: n · p_C_A = −R (seed eq. 3, 12–13).
struct LegLimbs {
  Eigen::Vector3d n1_C = Eigen::Vector3d::Zero();
  Eigen::Vector3d n2_C = Eigen::Vector3d::Zero();
};

// Limb normals per configuration; std::nullopt where the leg was not seen (occluded, out of the
// image, edge fit refused).
struct HexapodCalibrationData {
  double leg_radius = 0.0;  // R (m), > 0: the radius the edges were measured on
  std::vector<std::array<std::optional<LegLimbs>, robots::kHexapodLegs>> configurations;

  // Empty when usable, otherwise one message naming every bad field and its value: R not finite
  // or <= 0, no configurations, a normal that is not finite or not of unit norm (|1 − |n|| > 1e-6).
  std::string Validate() const;
};

enum class RobustLoss {
  kLeastSquares,  // plain (bare) least squares, for comparison
  kHuber,         // Huber's ψ (monotone: bounded but non-zero pull of outliers), IRLS
  kTukey,         // Tukey's biweight (redescending: outliers get weight 0), IRLS
  // Both robust losses start from a least-median-of-squares estimate and keep its MAD scale fixed
  // (an MM-estimator); see README for why the plain least-squares start fails on eq. 14.
};
const char* ToString(RobustLoss loss);  // "least-squares", "huber", "tukey"

// How eq. 16's global scale is estimated from the six estimates and the CAD points.
enum class ScaleEstimator {
  kLeastSquares,  // the scale of the least-squares similarity fit (Umeyama): default
  kMedianRatio,   // median of the 15 ratios |Â_j − Â_k| / |A_j − A_k|_CAD
  kMaxRatio,      // the seed's eq. 16 as printed (max of the ratios): biased upwards, see README
};
const char* ToString(ScaleEstimator estimator);  // "least-squares", "median-ratio", "max-ratio"

struct HexapodCalibrationOptions {
  RobustLoss loss = RobustLoss::kTukey;
  // Tuning constants in units of the robust scale s (95 % efficiency at the normal): residuals
  // |r| <= huber_k·s keep weight 1 (Huber), |r| >= tukey_c·s get weight 0 (Tukey). > 0.
  double huber_k = 1.345;
  double tukey_c = 4.685;
  int max_iterations = 50;  // per IRLS stage, >= 1
  // Robust start (Huber and Tukey): least median of squares over this many random pairs of
  // configurations (each pair's 4 equations give a candidate A_j; the candidate with the smallest
  // median |residual| over all of the leg's equations wins), >= 1. With 10 % outlying limbs a pair
  // is clean with probability 0.66, so 50 draws all fail with probability ~1e-23. Seeded: the
  // result is deterministic.
  int robust_start_samples = 50;
  uint64_t seed = 1;
  double step_tolerance = 1e-12;  // stop when |ΔA_j| <= this (m), >= 0
  // Floor of the robust scale s = 1.4826·median|r| (m), > 0: with exact data s would be 0.
  double min_scale = 1e-9;
  // Equations whose final weight is below this are listed as down-weighted, in [0, 1].
  double report_weight_below = 0.5;
  // Condition number σ_max/σ_min of the leg's 2N×3 system (unit rows, eq. 14). Above
  // warn_condition_number: a warning; above max_condition_number: the leg is refused
  // ("configurations too alike"). See README for why 300 and 1e4. 1 <= warn <= max.
  double warn_condition_number = 300.0;
  double max_condition_number = 1e4;
  // A leg needs this many configurations with both limbs, >= 2 (eq. 14 needs two different
  // leg directions; the condition number then checks "different").
  int min_configurations = 2;
  ScaleEstimator scale_estimator = ScaleEstimator::kLeastSquares;
  // When true, the reported p_C_A (and covariances) are divided by the estimated scale before the
  // rigid fit, compensating an error on R (eq. 16, "a posteriori").
  bool correct_scale = false;
  // Warn when |scale − 1| exceeds this (R or the CAD is off), >= 0.
  double warn_scale_deviation = 0.02;
  // Warn when a leg has more than this fraction of its equations down-weighted, in [0, 1].
  double warn_down_weighted_fraction = 0.25;

  // Empty when usable, otherwise one message naming every bad field and its value.
  std::string Validate() const;
};

enum class LegStatus {
  kEstimated,
  kTooFewConfigurations,    // fewer than min_configurations with both limbs
  kConfigurationsTooAlike,  // condition number above max_condition_number
};
const char* ToString(LegStatus status);  // "estimated", "too few configurations", ...

// One equation of eq. 14 that the robust fit down-weighted.
struct DownWeightedEquation {
  int configuration = 0;  // index into HexapodCalibrationData::configurations
  int leg = 0;            // 0..5
  int limb = 1;           // 1 or 2 (n1 or n2)
  double residual = 0.0;  // n·Â + R (m), signed point-to-plane distance
  double weight = 0.0;    // final IRLS weight in [0, 1)
};

struct LegCalibration {
  LegStatus status = LegStatus::kTooFewConfigurations;
  Eigen::Vector3d p_C_A = Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN());
  // σ² (JᵀWJ)⁻¹ (m²) with σ² = Σ w r² / (Σ w − 3) from the final weighted residuals. Meaningful
  // when estimated.
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
  double sigma = 0.0;           // σ (m): the point-to-plane noise the fit saw
  double condition_number = 0;  // σ_max/σ_min of the unweighted 2N×3 system; inf when singular
  int configurations = 0;       // configurations with both limbs of this leg
  int equations = 0;            // 2 × configurations
  int down_weighted = 0;        // equations with final weight < report_weight_below
  double residual_rms = 0.0;    // over all equations (m)
  double residual_max = 0.0;    // largest |r| over all equations (m)
  double residual_rms_inliers = 0.0;  // over equations with weight >= report_weight_below (m)
  int iterations = 0;                 // IRLS iterations
  double robust_scale = 0.0;          // s (m) the weights used: MAD of the robust start's residuals
  // |Â_j − X_CB A_j^CAD| after the rigid fit (m); NaN without a rigid fit.
  double rigid_fit_residual = std::numeric_limits<double>::quiet_NaN();
};

struct HexapodCalibrationResult {
  double leg_radius = 0.0;  // R used (m)
  int configurations = 0;   // in the data
  RobustLoss loss = RobustLoss::kTukey;
  std::array<LegCalibration, robots::kHexapodLegs> legs{};
  // Eq. 14's solution per leg (a copy of legs[j].p_C_A), divided by `scale` when
  // options.correct_scale; NaN for a refused leg.
  std::array<Eigen::Vector3d, robots::kHexapodLegs> p_C_A{};
  std::vector<DownWeightedEquation> down_weighted;  // every equation below report_weight_below

  // Eq. 15: X_CB minimising Σ |Â_j − X_CB A_j^CAD|² over the estimated legs (closed form,
  // Kabsch/Horn, proper rotation). Needs >= 3 estimated legs not on one line.
  bool rigid_fit = false;
  Eigen::Isometry3d X_CB = Eigen::Isometry3d::Identity();
  double rigid_fit_rms = std::numeric_limits<double>::quiet_NaN();  // over estimated legs (m)
  double rigid_fit_max = std::numeric_limits<double>::quiet_NaN();

  // Eq. 16: scale of the estimated base geometry relative to the CAD (1 = same size). Estimated
  // with options.scale_estimator; the other two estimates are reported for comparison. An error
  // on R scales every Â_j by R_used / R_true, so leg_radius / scale estimates the true radius.
  ScaleEstimator scale_estimator = ScaleEstimator::kLeastSquares;
  double scale = std::numeric_limits<double>::quiet_NaN();
  double scale_least_squares = std::numeric_limits<double>::quiet_NaN();
  double scale_median_ratio = std::numeric_limits<double>::quiet_NaN();
  double scale_max_ratio = std::numeric_limits<double>::quiet_NaN();
  bool scale_corrected = false;  // p_C_A were divided by scale

  std::vector<std::string> errors;    // one per refused leg, naming it and why
  std::vector<std::string> warnings;  // ill-conditioned legs, no rigid fit, scale far from 1, ...
  // The estimator contract's report: the 18 coordinates "legJ.p_C_A.x|y|z" (m) of `p_C_A`, σ and
  // covariance from one identifiability analysis of eq. 14's weighted system (the legs'
  // covariances, block-diagonal); a refused leg is unidentified. Residuals: point-to-plane (m).
  EstimationReport estimation;

  // True when all six legs were estimated.
  bool ok() const { return errors.empty(); }
};

// Solves eq. 14 for every leg, then eq. 15 and 16 against `cad` (only cad.p_B_A is used).
// Throws std::invalid_argument with data.Validate() / options.Validate()'s message, or when
// cad.p_B_A is not finite. Allocates (result vectors); not for a control cycle.
HexapodCalibrationResult CalibrateHexapod(const HexapodCalibrationData& data,
                                          const robots::HexapodModel& cad,
                                          const HexapodCalibrationOptions& options = {});

// --- building blocks, public for tests and for tools -----------------------------------------

// The rigid transform X_AB minimising Σ_i |p_A[i] − X_AB p_B[i]|² (Kabsch/Horn via SVD, with the
// reflection fix so the rotation is proper). Returns false when fewer than 3 points or the points
// are (numerically) collinear. Sizes must match.
bool FitRigidTransform(const std::vector<Eigen::Vector3d>& p_A,
                       const std::vector<Eigen::Vector3d>& p_B, Eigen::Isometry3d* X_AB);

// Scales of p_est relative to p_cad (matching indices, >= 2 points, all finite):
// least-squares similarity (Umeyama: s = Σ σ_i(Σ_cov) sign / Σ|p_cad − c_cad|²), the median and
// the max of the pairwise distance ratios. Returns false when p_cad's points coincide.
struct ScaleEstimates {
  double least_squares = 0.0;
  double median_ratio = 0.0;
  double max_ratio = 0.0;
};
bool EstimateScale(const std::vector<Eigen::Vector3d>& p_est,
                   const std::vector<Eigen::Vector3d>& p_cad, ScaleEstimates* scales);

}  // namespace kinevis::calibration
