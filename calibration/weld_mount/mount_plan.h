#pragma once

// The measurement plan of the scanner-mount calibration (seed 004 §4; mount_calibration.h): which
// features of the gauge block the torch touches, from which sides it may approach them, and where
// the scanner looks from. Shared by the recording job (rigs/weld/weld_calibration_jobs.h), the
// simulated data of the tests and the bench, so that what is tested is what the robot does.
//
// Frames as in mount_calibration.h: 0 the robot base, 5 link 5, C the scanner camera, B the block.
// Units SI (m, rad). Pure functions; no I/O.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <functional>
#include <vector>

#include "calibration/weld_mount/mount_calibration.h"
#include "robots/weld5/weld5_model.h"

namespace kinevis::calibration {

// A touch of the plan: a feature and the touched point in B as fractions of the block's half
// sizes (p_B = fraction ∘ size / 2).
struct PlannedTouch {
  const char* feature;
  Eigen::Vector3d fraction;
};

// 4 touches on the top, 2 on the board, the sides (2 on +x, 1 on −x, 2 on +y, 1 on −y), an edge
// and a corner: 14 touches, 17 equations; the six block-pose coordinates and the mount are then
// over-determined with every side seen. `sides = false`: the top and the board only (6 touches).
std::vector<PlannedTouch> MountTouchPlan(bool sides = true);

// The side from which the torch approaches `feature`, as a unit normal in the base frame:
// outside the block, and above the board for a feature on the board (s_z = −1 is approached from
// +z_B).
Eigen::Vector3d TouchApproachNormal(const BlockFeature& feature, const Eigen::Matrix3d& R_0B);

// Candidate torch axes (unit, pointing into the work, base frame) to touch a point whose approach
// normal is n_0, the most head-on (most against n_0) first, those with axis · n_0 <= max_dot
// only (0.3: at most 17° past the face's plane, a grazing approach of the tip; beyond, the torch
// would come from inside the block). The torch axis of the 5-DOF arm cannot point anywhere (θ5
// turns about it), so the candidates are a grid of yaw −40°…40° and pitch −60°…60° about +x_0 (the
// arm's reach direction) for the caller's IK to try in order.
std::vector<Eigen::Vector3d> TouchApproachAxes(const Eigen::Vector3d& n_0, double max_dot = 0.3);

// Scanner viewpoints, as wrist joints relative to the home joints: (Δθ4, θ5) in rad; θ1 and θ2 are
// then re-aimed at the block (AimOpticalAxisAt). Δθ4 pitches the view, θ5 turns the scanner
// about the torch axis. The first `count` (1..kMaxMountViews) of a fixed list ordered so that the
// first few already turn the view both ways.
inline constexpr int kMaxMountViews = 12;
std::vector<Eigen::Vector2d> MountViewPlan(int count);

// Rotating-laser angles per viewpoint (cot θ_y; at the plan's reach the stripe crosses the optical
// axis at ~0.36, 0.39 and 0.43 m).
std::vector<double> MountLaserAngles();

// θ1, θ2 of `q` turned (Gauss–Newton, numeric Jacobian) until the optical axis of the camera at
// pose X_0C(q) passes through p_0: |(x/z, y/z)| of p_0 in C below `tolerance`, or
// `max_iterations` steps. X_0C is the caller's model of the scanner: the nominal robot with the
// CAD mount on the host, the true ones in a simulation's truth.
robots::Vector5d AimOpticalAxisAt(
    const std::function<Eigen::Isometry3d(const robots::Vector5d&)>& X_0C,
    const Eigen::Vector3d& p_0, robots::Vector5d q, double tolerance = 1e-9,
    int max_iterations = 30);

}  // namespace kinevis::calibration
