#pragma once

// Scanner mount calibration on the weld robot (seed 004 §4, the seed's A2S; issue 7): the pose
// X_5C of the laser scanner's camera frame C on link 5, from a gauge block standing on a board.
//
//   - The torch tip touches features of the block (faces, edges, corners, or the board around
//     it): the tip in the base frame is p_0T = FK(q) · X_5T · 0 at the touch's joint readings q.
//   - The scanner scans the block from several robot poses: stripe points p_C in the camera frame
//     (the scanner model's output), mapped to the base frame by p_0 = FK(q) · X_5C · p_C.
//   - One Ceres problem estimates X_5C and the block's pose X_0B so that the touched points lie on
//     the touched features and the scanned points on the block-on-board surface (point-to-surface
//     residuals, robust loss), optionally with the D–H error parameters of the arm (seed eq. 48–50)
//     — those the data identify; the others are held at their nominal values and named.
//
// Frames (robots/weld5/weld5_model.h defines 0, 5 and T; sim/weld_cell_world.h defines C):
//   B  the gauge block: origin at its centre, x_B along its length (100 mm), y_B along its width
//      (50 mm), z_B along its height (10 mm), up out of the board. The board's top is the plane
//      z_B = −h_z/2 (the block stands on it). Same frame as vision/render/scenes/laser_scene.h's
//      gauge block (X_CB there).
//
// Why the seed's eq. (49)–(50) is not used literally: it fits full 6-D pose errors ΔP = M − C of
// the end effector measured by an external system. Here nothing measures a pose: a touch
// measures a point on a plane (or line, or point) of the block and a scan point a point on its
// surface, so the residuals are geometric distances and their Jacobians (autodiff) play the part
// of eq. (50)'s J; the D–H error vector Δx (Δθ, Δα, Δd, Δa per link, eq. 48) is the same.
//
// Units SI (m, rad). Everything here is data or pure functions; no I/O.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <string>
#include <vector>

#include "calibration/common/estimation.h"
#include "robots/weld5/weld5_model.h"

namespace kinevis::calibration {

// The gauge block's size (m): 100 × 50 × 10 mm in the seed (§5.2).
struct GaugeBlock {
  Eigen::Vector3d size = Eigen::Vector3d(0.100, 0.050, 0.010);  // along x_B, y_B, z_B, each > 0
  Eigen::Vector3d half() const { return 0.5 * size; }
  std::string Validate() const;  // empty when usable
};

// A feature of the block touched by the torch, by the signs of the coordinates it fixes: each
// component of `sign` is −1, 0 or +1, not all 0; a non-zero s_k fixes p_B[k] = s_k · size_k / 2.
// One non-zero: a face ("+x", "-y", "top" = "+z", "board" = "-z": the board plane around the
// block), two: an edge ("+x+z", "-y-z" where a side meets the board), three: a corner
// ("+x-y+z"). A face touch is one equation, an edge two, a corner three.
struct BlockFeature {
  Eigen::Vector3i sign = Eigen::Vector3i(0, 0, 1);

  // "top", "board", or the signed axes in x, y, z order ("+x", "-x+z", "+x-y-z").
  std::string Name() const;
  int Equations() const { return sign.cwiseAbs().sum(); }
  bool Valid() const;
  // Parses Name()'s forms; throws std::invalid_argument quoting `text` when it is none of them.
  static BlockFeature Parse(const std::string& text);
};

// A touch: the torch tip on `feature`, at joint readings q (rad / m, robots::Weld5Model).
struct MountTouch {
  robots::Vector5d q = robots::Vector5d::Zero();
  BlockFeature feature;
};

// A scan: joint readings q and the stripe points p_C (m, in the camera frame C) of one image.
struct MountScan {
  robots::Vector5d q = robots::Vector5d::Zero();
  std::vector<Eigen::Vector3d> p_C;
};

struct MountCalibrationData {
  // The nominal robot (D–H, joint limits, torch X_5T: the tool the touches are made with).
  robots::Weld5Model robot = robots::Weld5Model::Seed(Eigen::Isometry3d::Identity());
  GaugeBlock block;
  // Initial guesses: the mount (the CAD value, e.g. sim::NominalScannerMount()) and the block's
  // pose in the base frame (from the cell layout; within ~2 cm and ~10° is enough: the block is
  // first fitted to the touches alone).
  Eigen::Isometry3d X_5C_guess = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d X_0B_guess = Eigen::Isometry3d::Identity();
  std::vector<MountTouch> touches;
  std::vector<MountScan> scans;

  // Empty when usable, otherwise every bad field and its value, "; "-separated: block size, a
  // guess that is not a rigid transform, a non-finite joint reading or point (named by index),
  // an invalid feature.
  std::string Validate() const;
};

enum class MountLoss { kNone, kHuber, kCauchy };
const char* ToString(MountLoss loss);  // "none", "huber", "cauchy"

struct MountCalibrationOptions {
  // Measurement noise (m, per axis), the residuals' scale: the torch tip on a touched feature,
  // and a scanned point (the scanner's noise plus the stripe's). > 0.
  double touch_sigma = 0.1e-3;
  double scan_sigma = 0.1e-3;
  // Robust loss on the residuals in units of their sigma: a first solve with coarse_k (the guess
  // can be millimetres off, tens of sigmas), then the final one with k. k, coarse_k > 0.
  MountLoss loss = MountLoss::kHuber;
  double k = 3.0;
  double coarse_k = 50.0;
  // Points used per scan, evenly spread along the stripe (0: all). Stripe points come every
  // ~0.1–0.3 mm; a few hundred per stripe carry the information. >= 0.
  int max_points_per_scan = 300;
  // Also estimate the D–H error parameters (Δa, Δα, Δd, Δθ of each link, eq. 48) that the data
  // identify together with the mount and the block.
  bool estimate_dh = false;
  // Relative singular value of the column-scaled Jacobian below which a direction counts as
  // unidentified (rank decision), in (0, 1).
  double rank_tolerance = 1e-6;
  // estimate_dh: a D–H error is estimated only when the part of its unit (column-scaled) Jacobian
  // column outside the span of the mount's, the block's and the D–H errors chosen before it
  // (column-pivoted QR) is above this; the others are held at nominal (summary.fixed_dh). (0, 1).
  double dh_min_independence = 1e-3;
  // Condition number of the column-scaled Jacobian (of the identified part) above which a
  // warning says the data separate the parameters badly, > 1.
  double warn_condition_number = 1e4;
  // Warn when the mount's position or orientation standard deviation exceeds these (m, rad), > 0.
  double warn_position_std = 0.2e-3;
  double warn_angle_std = 0.05 * M_PI / 180.0;
  int max_iterations = 100;  // per solve, >= 1
  int threads = 1;           // Ceres threads, >= 1

  std::string Validate() const;  // empty when usable, else every bad field and its value
};

enum class MountCalibrationStatus {
  kOk,            // converged, the mount identified
  kUnidentified,  // the data cannot fix some of the mount's 6 degrees of freedom (see summary)
  kNotConverged,  // the solver stopped without converging
};
const char* ToString(MountCalibrationStatus status);  // "ok", "unidentified", "not-converged"

struct ResidualStats {
  int count = 0;        // residuals (touches) or points (scans)
  double mean = 0.0;    // of the distances (m)
  double rms = 0.0;     // of the distances (m)
  double median = 0.0;  // of the absolute distances (m)
  double max = 0.0;     // (m)
  int beyond_k = 0;     // distances beyond k sigma (down-weighted by the robust loss)
};

struct MountCalibrationSummary {
  MountCalibrationStatus status = MountCalibrationStatus::kNotConverged;
  bool converged = false;
  int iterations = 0;         // all solves together
  double initial_cost = 0.0;  // of the final solve's problem at the guess, ½ Σ ρ(|r/σ|²)
  double final_cost = 0.0;
  double sigma_ratio = 0.0;  // √(2 cost / (m − n)): 1 when the sigmas describe the data

  Eigen::Isometry3d X_5C = Eigen::Isometry3d::Identity();  // the estimate
  Eigen::Isometry3d X_0B = Eigen::Isometry3d::Identity();
  robots::Weld5Model robot;  // the nominal with the estimated D–H errors applied

  ResidualStats touch;  // point-to-feature distance of each touch
  ResidualStats scan;   // point-to-surface distance of each scan point used

  // All parameters of the analysis, in this order: mount (6: "mount.rx", "mount.ry", "mount.rz"
  // rotation vector (rad) and "mount.x", "mount.y", "mount.z" (m), a right perturbation
  // X_5C · Exp), block (6, the same for X_0B: "block.rx" ... "block.z"), then when estimate_dh
  // the 20 D–H errors ("a1", "alpha1", "d1", "theta1", ..., "theta5"; m and rad).
  std::vector<std::string> parameter_names;
  Eigen::VectorXd correction;  // estimate minus guess (tangent at the guess), same order
  // Per parameter: estimated (not held at its nominal value), identified (the data fix it: no
  // unidentified direction involves it) and standard deviation (+inf when not identified).
  std::vector<bool> estimated;
  std::vector<bool> identified;
  Eigen::VectorXd std_dev;
  // Covariance of the estimated parameters in the tangent at the estimate (order of
  // parameter_names, rows/columns of the parameters not estimated are zero), scaled by
  // sigma_ratio²; entries of unidentified directions are +inf on the diagonal.
  Eigen::MatrixXd covariance;
  Eigen::Matrix<double, 6, 6> mount_covariance = Eigen::Matrix<double, 6, 6>::Zero();
  double mount_position_std = 0.0;  // √(largest eigenvalue) of the mount's position block (m)
  double mount_angle_std = 0.0;     // √(largest eigenvalue) of its rotation block (rad)

  // Identifiability: SVD of the column-scaled Jacobian (unit columns) of all parameters at the
  // solution, all 20 D–H errors included when estimate_dh: its rank, singular values
  // (descending), and each unidentified direction (relative singular value below
  // rank_tolerance) written as a combination of the parameters ("0.707 mount.x - 0.707 block.x",
  // scaled units). condition_number: σ_max/σ_min of the identified part of the ESTIMATED
  // parameters' scaled Jacobian.
  int rank = 0;
  double condition_number = 0.0;
  Eigen::VectorXd singular_values;
  std::vector<std::string> unidentified;
  std::vector<std::string> fixed_dh;  // D–H parameters held at nominal (not identifiable)

  std::vector<std::string> warnings;
  // The same in the estimator contract's shape: parameter values are the corrections above
  // (initial 0), σ from std_dev (0 for held D–H errors); status converged only when every
  // estimated parameter, the block's included, is identified (kOk needs only the mount).
  EstimationReport estimation;
  bool ok() const { return status == MountCalibrationStatus::kOk; }
};

// The calibration described at the top. Throws std::invalid_argument for bad options or data
// (Validate()s, with every problem) and when there are no touches or no scan points. Everything
// else (too few or degenerate data, no convergence) is reported in the summary.
MountCalibrationSummary CalibrateScannerMount(const MountCalibrationData& data,
                                              const MountCalibrationOptions& options = {});

// The estimator contract's report of a summary (what CalibrateScannerMount puts in `estimation`;
// the file reader uses it for files written before the contract).
EstimationReport MountEstimationReport(const MountCalibrationSummary& summary);

// Names of the 20 D–H error parameters in summary order ("a1", "alpha1", "d1", "theta1", ...).
std::vector<std::string> DhErrorNames();
// `model` with D–H errors `delta` (20, order of DhErrorNames()) added to a, α, d, θ offset.
robots::Weld5Model ApplyDhErrors(const robots::Weld5Model& model, const Eigen::VectorXd& delta);

}  // namespace kinevis::calibration
