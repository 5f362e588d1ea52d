#pragma once

// Planning the robot configurations for the leg-edge calibration (seed 002 §IV-B: "one uses robot
// configurations with the larger angles between each leg direction", §V: "60 robot
// configurations located on the workspace limits").
//
// Method (deterministic for a seed):
//  1. Candidates on the workspace limits: from the nominal pose, a seeded random direction in the
//     6-D pose space (translation scaled by translation_scale, rotation vector by rotation_scale)
//     is followed outwards until the pose stops being admissible; the last admissible pose
//     (bisected to 1e-4 of the step) is the candidate. Admissible = inverse kinematics within the
//     strokes shrunk by stroke_margin, no two leg cylinders closer than 2R + collision_margin
//     (segment– segment distance), the inverse differential's condition number below
//     max_jacobian_condition, and the caller's predicate (e.g. every leg visible to the camera).
//  2. Greedy farthest-point selection in leg-direction space: the distance between two poses is
//     the smallest, over the six legs, of the angle between that leg's directions; the first pose
//     is the candidate whose directions are farthest from the nominal's, each next one maximises
//     its distance to the poses already chosen. So every leg's direction is spread, not just the
//     average.
//
// Frames as in robots/hexapod/hexapod_model.h (B base, P platform, C camera, X_BP, X_CB).

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "calibration/hexapod/leg_calibration.h"
#include "robots/hexapod/hexapod_model.h"

namespace kinevis::vision {
class CameraModel;
}  // namespace kinevis::vision

namespace kinevis::calibration {

struct PosePlannerOptions {
  int poses = 60;         // N poses to plan, >= 2
  int candidates = 2000;  // candidates on the workspace limits, >= poses
  uint64_t seed = 1;      // of the candidate directions
  // The pose the directions start from; must be admissible. Default: HexapodModel::NominalPose().
  Eigen::Isometry3d X_BP_nominal = robots::HexapodModel::NominalPose();
  double translation_scale = 0.15;      // m per unit of the 6-D direction, > 0
  double rotation_scale = 0.6;          // rad per unit of the 6-D direction, > 0
  double stroke_margin = 0.005;         // keep q_j in [min + margin, max − margin] (m), >= 0
  double collision_margin = 0.005;      // legs closer than 2R + this collide (m), >= 0
  double max_jacobian_condition = 1e3;  // cond(D_inv) above this: too near a singularity, >= 1
  // Optional extra admissibility test (e.g. camera visibility of every leg); called with X_BP.
  std::function<bool(const Eigen::Isometry3d& X_BP)> admissible;
  // Optional camera pose: when set, the plan also reports the condition number of each leg's
  // eq. 14 system built from the predicted (noise-free) limb normals seen from C.
  std::optional<Eigen::Isometry3d> X_CB;

  // Empty when usable, otherwise one message naming every bad field and its value.
  std::string Validate() const;
};

struct LegSpread {
  double max_angle = 0.0;  // largest angle between two of the leg's planned directions (rad)
  // Smallest eigenvalue of (1/N) Σ_k (I − u_k u_kᵀ) in [0, 1]: how well the directions alone fix
  // A_j along every axis (0 when all directions are equal; eq. 14 is then singular along u).
  double direction_spread = 0.0;
  // Condition number of eq. 14 from predicted normals (needs options.X_CB; NaN otherwise, inf
  // when a leg's limbs cannot be predicted in at least 2 poses).
  double condition_number = std::numeric_limits<double>::quiet_NaN();
};

struct PosePlan {
  std::vector<Eigen::Isometry3d> X_BP;  // the planned poses, in planning order
  std::vector<robots::Vector6d> q;      // their leg lengths (m); s = q − q0 for the drives
  std::array<LegSpread, robots::kHexapodLegs> legs{};
  int candidates_tried = 0;           // directions drawn
  int candidates_admissible = 0;      // those that gave a pose (a direction whose first step is not
                                      // admissible gives none)
  std::vector<std::string> warnings;  // e.g. fewer admissible candidates than poses requested
};

// Plans the poses. Throws std::invalid_argument naming every bad option, every bad model field
// (model.Validate()) and a nominal pose that is not admissible.
PosePlan PlanCalibrationPoses(const robots::HexapodModel& model,
                              const PosePlannerOptions& options = {});

// True when X_BP is reachable within the strokes shrunk by stroke_margin, collision-free by the
// model (segment–segment distance between every pair of legs > 2R + collision_margin), and
// cond(D_inv) <= max_jacobian_condition. Does not call options.admissible.
bool PoseIsAdmissible(const robots::HexapodModel& model, const Eigen::Isometry3d& X_BP,
                      const PosePlannerOptions& options);

// The usual `admissible` test of a recording: every leg of `model` at X_BP is in the image of
// `camera` at X_CB — points at 15 %, 50 % and 85 % of its length (its very ends may be cut: the
// edges are not searched there) project at least `margin_px` inside the image.
bool AllLegsInView(const robots::HexapodModel& model, const vision::CameraModel& camera,
                   const Eigen::Isometry3d& X_CB, const Eigen::Isometry3d& X_BP,
                   double margin_px = 10.0);

// Smallest distance between the segments [p0, p1] and [q0, q1] (m).
double SegmentSegmentDistance(const Eigen::Vector3d& p0, const Eigen::Vector3d& p1,
                              const Eigen::Vector3d& q0, const Eigen::Vector3d& q1);

// Per-leg spread of a set of poses (max angle, direction spread; condition numbers when X_CB is
// given). Poses that are not reachable (IK kDegenerate) are skipped for that leg.
std::array<LegSpread, robots::kHexapodLegs> EvaluatePoseSpread(
    const robots::HexapodModel& model, const std::vector<Eigen::Isometry3d>& X_BP,
    const std::optional<Eigen::Isometry3d>& X_CB = std::nullopt);

// Noise-free calibration data: the limb normals (PredictCylinderLimbs) of every leg of `model` at
// every pose, seen from the origin of C with the base at X_CB; std::nullopt where no tangent plane
// exists (viewpoint inside a leg's cylinder). For planning, dry runs and tests.
HexapodCalibrationData PredictCalibrationData(const robots::HexapodModel& model,
                                              const Eigen::Isometry3d& X_CB,
                                              const std::vector<Eigen::Isometry3d>& X_BP);

}  // namespace kinevis::calibration
