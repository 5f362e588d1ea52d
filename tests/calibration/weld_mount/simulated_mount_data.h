#pragma once

// Simulated scanner-mount calibration data from the weld cell (sim/weld_cell_world.h): the board
// with the gauge block, touches made by IK on the TRUE robot (the real arm reaches the point; its
// controller reports the joints), and scans whose stripe points are the scene's exact stripes
// (LaserScene::StripeCurve) in the true camera frame, kept where the camera sees them, plus noise.
// Shared by the weld_mount tests (and the bench).

#include <Eigen/Geometry>
#include <algorithm>
#include <random>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "calibration/weld_mount/mount_calibration.h"
#include "calibration/weld_mount/mount_plan.h"
#include "robots/weld5/weld5_model.h"
#include "sim/weld_cell_world.h"

namespace kinevis::calibration::testing {

struct SimulatedMountOptions {
  double dh_length_sigma_mm = 0.0;  // the true robot's D–H errors (0: truth = nominal)
  double dh_angle_sigma_deg = 0.0;
  double touch_noise = 0.05e-3;  // m, per axis, on the touched point
  double scan_noise = 0.1e-3;    // m, per axis, on each stripe point
  double joint_noise = 0.0;      // rad (m for pz3), on every joint reading
  double stripe_spacing = 0.5e-3;
  // Scanner viewpoints, as wrist joints relative to the home joints: (Δθ4, θ5) in rad, θ1 and θ2
  // then re-aimed so that the optical axis passes through the block's centre. Δθ4 pitches the
  // view, θ5 turns the scanner about the torch axis (moving and rolling the camera). One scan per
  // (viewpoint, rotating-laser angle) and one of the fixed laser.
  std::vector<Eigen::Vector2d> wrist = {{0.0, 0.0},    {0.25, 0.5}, {-0.25, 0.5}, {0.25, -0.5},
                                        {-0.25, -0.5}, {0.0, 0.9},  {0.0, -0.9}};
  std::vector<double> cot_theta_y = {0.22, 0.25, 0.28};
  double pz3 = 0.2;  // the prismatic joint while scanning (m): the camera ~0.4 m from the block
  // Touch the side faces (and edges); false: the top face only.
  bool touch_sides = true;
  uint32_t seed = 7;
};

struct SimulatedMount {
  MountCalibrationData data;
  Eigen::Isometry3d X_5C_true = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d X_0B_true = Eigen::Isometry3d::Identity();
  robots::Weld5Model true_robot;
  sim::WeldCellWorldConfig config;
  std::vector<std::string> unreachable_touches;  // features IK could not reach (left out)
};

inline robots::Vector5d ToVector5(const std::array<double, 5>& q) {
  robots::Vector5d v;
  for (int i = 0; i < 5; ++i) v(i) = q[static_cast<size_t>(i)];
  return v;
}

inline std::array<double, 5> ToArray5(const robots::Vector5d& q) {
  std::array<double, 5> a{};
  for (int i = 0; i < 5; ++i) a[static_cast<size_t>(i)] = q(i);
  return a;
}

inline SimulatedMount MakeSimulatedMount(const SimulatedMountOptions& o = {}) {
  SimulatedMount s;
  sim::WeldCellWorldConfig& config = s.config;
  config.workpiece = sim::DefaultCalibrationBoard(/*gauge_block=*/true);
  config.dh_length_sigma_mm = o.dh_length_sigma_mm;
  config.dh_angle_sigma_deg = o.dh_angle_sigma_deg;
  sim::WeldCellWorld world(config);
  s.true_robot = world.true_model();
  s.X_5C_true = config.X_5C;
  const vision::render::LaserSceneParameters& w = config.workpiece;
  s.X_0B_true = config.X_0S * w.X_SB();

  std::mt19937 rng(o.seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  const auto noise3 = [&](double sigma) -> Eigen::Vector3d {
    const double x = normal(rng) * sigma, y = normal(rng) * sigma, z = normal(rng) * sigma;
    return {x, y, z};
  };
  const auto read_joints = [&](robots::Vector5d q) {
    for (int i = 0; i < 5; ++i) q(i) += o.joint_noise * normal(rng);
    return q;
  };

  MountCalibrationData& data = s.data;
  data.robot = world.nominal_model();
  data.block.size = w.gauge_size;
  data.X_5C_guess = sim::NominalScannerMount();
  // The layout's block pose: 5 mm and 2° off.
  data.X_0B_guess =
      s.X_0B_true * Eigen::Translation3d(0.004, -0.003, 0.002) *
      Eigen::AngleAxisd(2.0 * M_PI / 180.0, Eigen::Vector3d(0.3, 0.5, 0.8).normalized());

  const Eigen::Vector3d h = 0.5 * w.gauge_size;
  const Eigen::Matrix3d R_0B = s.X_0B_true.linear();
  const robots::Vector5d q_home = ToVector5(config.initial_joints);

  // Touches: the recording job's plan (mount_plan.h) on the faces, edges and corners of the
  // block and on the board. IK on the TRUE robot over the plan's approach axes, the most head-on
  // first; a second pass with more starts accepts more grazing approaches.
  for (const PlannedTouch& t : MountTouchPlan(o.touch_sides)) {
    const BlockFeature f = BlockFeature::Parse(t.feature);
    const Eigen::Vector3d n_0 = TouchApproachNormal(f, R_0B);
    const std::vector<Eigen::Vector3d> sorted = TouchApproachAxes(n_0, 0.6);
    const Eigen::Vector3d p_0 =
        s.X_0B_true * Eigen::Vector3d(t.fraction.cwiseProduct(h)) + noise3(o.touch_noise);
    bool reached = false;
    for (int pass = 0; pass < 2 && !reached; ++pass)
      for (size_t k = 0; k < sorted.size() && !reached; ++k) {
        // Beyond: from inside the block (the second pass accepts more grazing approaches).
        if (sorted[k].dot(n_0) > (pass == 0 ? 0.3 : 0.6)) break;
        robots::Weld5IkOptions ik;
        ik.extra_starts = pass == 0 ? 0 : 7;
        robots::Vector5d guess = q_home;
        guess(2) = 0.42;  // the torch reaches the block with the slide near 0.42-0.46 m
        const robots::Weld5IkResult r =
            robots::Weld5InverseKinematics(s.true_robot, p_0, sorted[k], guess, ik);
        if (!r.converged()) continue;
        MountTouch touch;
        touch.q = read_joints(r.q);
        touch.feature = f;
        data.touches.push_back(touch);
        reached = true;
      }
    if (!reached) s.unreachable_touches.push_back(t.feature);
  }

  // Scans: from each wrist setting, θ1 and θ2 re-aimed (mount_plan.h) until the block's centre is
  // on the TRUE scanner's optical axis.
  const vision::CameraModel& camera = world.scanner_camera();
  const auto X_0C = [&](const robots::Vector5d& q) { return world.TrueScannerPose(ToArray5(q)); };
  for (const Eigen::Vector2d& wrist : o.wrist) {
    robots::Vector5d q = q_home;
    q(2) = o.pz3;
    q(3) += wrist.x();
    q(4) = wrist.y();
    q = AimOpticalAxisAt(X_0C, s.X_0B_true.translation(), q, 1e-7, 20);
    const std::unique_ptr<vision::render::LaserScene> scene = world.SceneAt(ToArray5(q));
    const auto add_scan = [&](vision::render::LaserId id, double cot) {
      vision::render::LaserSceneParameters p = scene->parameters();
      p.rotating_cot_theta_y = cot;
      const vision::render::LaserScene lit(p);
      MountScan scan;
      scan.q = read_joints(q);
      for (const Eigen::Vector3d& p_C : lit.StripeCurve(id, o.stripe_spacing)) {
        Eigen::Vector2d pixel;
        if (camera.Project(p_C, &pixel) != vision::ProjectionStatus::kOk) continue;
        if (pixel.x() < 0 || pixel.y() < 0 || pixel.x() > camera.width() - 1 ||
            pixel.y() > camera.height() - 1) {
          continue;
        }
        scan.p_C.push_back(p_C + noise3(o.scan_noise));
      }
      if (!scan.p_C.empty()) data.scans.push_back(std::move(scan));
    };
    for (double cot : o.cot_theta_y) add_scan(vision::render::LaserId::kRotating, cot);
    add_scan(vision::render::LaserId::kFixed, o.cot_theta_y.front());
  }
  return s;
}

// Rotation angle (rad) and translation (m) between two poses.
inline double AngleBetween(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  return Eigen::AngleAxisd(a.linear().transpose() * b.linear()).angle();
}
inline double DistanceBetween(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  return (a.translation() - b.translation()).norm();
}

}  // namespace kinevis::calibration::testing
