// The hexapod jobs (hexapod_jobs.h): record, calibrate, servo on a HexapodRig.

#include "rigs/hexapod/hexapod_jobs.h"

#include <spdlog/spdlog.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "calibration/hexapod/dataset_calibration.h"
#include "calibration/hexapod/hexapod_calibration_io.h"
#include "calibration/hexapod/hexapod_dataset.h"
#include "calibration/hexapod/pose_planner.h"
#include "calibration/hexapod/reprojection_image.h"
#include "common/units.h"
#include "control/hexapod/image_leg_features.h"
#include "control/hexapod/leg_servo.h"
#include "control/hexapod/servo_loop.h"
#include "hal/canopen/canopen_master.h"
#include "hal/common/error.h"
#include "hal/drive/cia402_can_drive.h"
#include "sim/hexapod_world.h"
#include "vision/camera/camera_file.h"

namespace kinevis::rigs {
namespace {

namespace fs = std::filesystem;
using robots::kHexapodLegs;

// --- record -------------------------------------------------------------------------------------

calibration::RobustLoss ParseLoss(const std::string& text) {
  if (text == "tukey") return calibration::RobustLoss::kTukey;
  if (text == "huber") return calibration::RobustLoss::kHuber;
  return calibration::RobustLoss::kLeastSquares;
}

calibration::ScaleEstimator ParseScale(const std::string& text) {
  if (text == "median-ratio") return calibration::ScaleEstimator::kMedianRatio;
  if (text == "max-ratio") return calibration::ScaleEstimator::kMaxRatio;
  return calibration::ScaleEstimator::kLeastSquares;
}

}  // namespace

HexapodRecordSummary RecordHexapodDataset(HexapodRig* rig, const HexapodRecordOptions& o) {
  HexapodRecordSummary summary;
  const robots::HexapodModel& nominal = rig->nominal();
  const Eigen::Isometry3d X_CB_hint = rig->X_BC_hint().inverse();

  calibration::PosePlannerOptions plan_options;
  plan_options.poses = o.poses;
  plan_options.candidates = std::max(o.candidates, o.poses);
  plan_options.seed = o.seed;
  plan_options.X_BP_nominal = rig->home_pose();
  plan_options.X_CB = X_CB_hint;
  const vision::CameraModel* camera = &rig->camera_model();
  plan_options.admissible = [&](const Eigen::Isometry3d& X_BP) {
    return calibration::AllLegsInView(nominal, *camera, X_CB_hint, X_BP);
  };
  const calibration::PosePlan plan = calibration::PlanCalibrationPoses(nominal, plan_options);
  summary.warnings = plan.warnings;
  if (plan.X_BP.empty()) {
    throw std::invalid_argument("record hexapod: no admissible pose found (is the camera pose in " +
                                rig->config_path() + " right? every leg must be in the image)");
  }
  spdlog::info("record hexapod: {} poses planned from {} candidates ({} admissible)",
               plan.X_BP.size(), plan.candidates_tried, plan.candidates_admissible);

  calibration::HexapodDataset dataset;
  dataset.directory = o.out;
  dataset.robot_file = rig->robot_description();
  dataset.nominal = nominal;
  dataset.camera_name = rig->camera_name();
  dataset.camera_model = rig->camera_model_spec();
  dataset.X_BC_hint = rig->X_BC_hint();
  dataset.edge_locator = rig->edge_options().locator == vision::hexapod::EdgeLocator::kParabola
                             ? "parabola"
                             : "step-ramp";
  dataset.edge_blur_px = rig->edge_options().edge_blur_px;
  dataset.source =
      (rig->simulated() ? "simulated world " : "deployment ") +
      (rig->config_path().empty() ? std::string("(built-in defaults)") : rig->config_path());
  calibration::CreateHexapodDataset(&dataset);

  rig->Enable();
  hal::Image image;
  robots::HexapodData ik;
  for (size_t k = 0; k < plan.X_BP.size(); ++k) {
    if (o.stop_requested && o.stop_requested()) {
      summary.stopped = "interrupted";
      break;
    }
    robots::InverseKinematics(nominal, plan.X_BP[k], &ik);
    const robots::Vector6d s = robots::JointPositionsFromLegLengths(nominal, ik.q);
    if (std::string why = rig->MoveTo(s, o.speed, o.settle_s); !why.empty()) {
      summary.stopped = why;
      summary.hardware_fault = true;
      break;
    }
    if (std::string why = rig->GrabFresh(&image); !why.empty()) {
      summary.stopped = why;
      summary.hardware_fault = true;
      break;
    }
    calibration::HexapodDatasetPose pose;
    pose.index = static_cast<int>(k);
    char name[48];
    std::snprintf(name, sizeof name, "images/pose_%03zu.png", k);
    pose.image = name;
    pose.s = rig->Readings();
    pose.X_BP_commanded = plan.X_BP[k];
    if (image.format != hal::PixelFormat::kMono8) {
      throw hal::HalError(
          "camera " + rig->camera_name(), "record",
          std::string("frames are ") + hal::ToString(image.format) + ", the dataset needs mono8");
    }
    calibration::AppendHexapodDatasetPose(dataset, pose, image.data.data(), image.width,
                                          image.height, image.stride);
    ++summary.recorded;
    spdlog::info("record hexapod: pose {}/{} recorded", k + 1, plan.X_BP.size());
  }
  // Back home, then the safe state.
  if (!summary.hardware_fault) {
    robots::InverseKinematics(nominal, rig->home_pose(), &ik);
    rig->MoveTo(robots::JointPositionsFromLegLengths(nominal, ik.q), o.speed, 0.1);
  }
  rig->Disable();
  return summary;
}

HexapodCalibrationRun CalibrateHexapodFromDataset(const HexapodCalibrateOptions& o) {
  HexapodCalibrationRun run;
  const calibration::HexapodDataset dataset = calibration::ReadHexapodDataset(o.dataset);
  const std::unique_ptr<vision::CameraModel> camera = vision::OpenCameraModel(dataset.camera_model);
  calibration::DatasetCalibrationOptions options;
  options.passes = o.passes;
  options.calibration.loss = ParseLoss(o.loss);
  options.calibration.scale_estimator = ParseScale(o.scale);
  options.calibration.correct_scale = o.correct_scale;
  if (!o.edge_locator.empty() || o.edge_blur_px >= 0) {
    options.edge_locator_from_dataset = false;
    const std::string locator = !o.edge_locator.empty() ? o.edge_locator : dataset.edge_locator;
    options.edges.locator = locator == "parabola" ? vision::hexapod::EdgeLocator::kParabola
                                                  : vision::hexapod::EdgeLocator::kStepRamp;
    options.edges.edge_blur_px = o.edge_blur_px >= 0 ? o.edge_blur_px : dataset.edge_blur_px;
  }
  run.calibration = calibration::CalibrateHexapodDataset(dataset, *camera, options);

  calibration::HexapodCalibrationMetadata metadata;
  metadata.camera = dataset.camera_name + " (" + dataset.camera_model + ")";
  metadata.robot = dataset.robot_file.empty() ? std::string("")
                                              : (fs::path(o.dataset) / dataset.robot_file).string();
  metadata.source = "dataset " + o.dataset + " (" + std::to_string(dataset.poses.size()) +
                    " poses, " + dataset.source + ")";
  calibration::WriteHexapodCalibration(o.out, run.calibration.result, metadata);

  run.image = o.image;
  if (run.image.empty()) run.image = fs::path(o.out).replace_extension(".png").string();
  int width = 0, height = 0;
  std::vector<uint8_t> pixels =
      calibration::ReadDatasetImage(dataset, dataset.poses.front(), &width, &height);
  vision::ImageView8 view{pixels.data(), width, height, static_cast<size_t>(width)};
  calibration::WriteReprojectionImage(run.image, view, *camera, run.calibration.result,
                                      dataset.nominal);
  return run;
}

Eigen::Isometry3d ReadTargetPose(const std::string& path) {
  sim::internal::WorldConfigReader r(path, "");
  if (!r.Has("pose")) r.Problem("pose: missing ({position: [x, y, z], rpy_deg: [r, p, y]})");
  const Eigen::Isometry3d X = r.Pose("pose", Eigen::Isometry3d::Identity());
  r.CheckKeys("", {"pose"});
  r.ThrowIfProblems();
  return X;
}

HexapodServoRun ServoHexapod(HexapodRig* rig, const HexapodServoOptions& o) {
  HexapodServoRun run;
  const robots::HexapodModel& nominal = rig->nominal();
  const calibration::HexapodCalibrationFile calib = calibration::ReadHexapodCalibration(o.calib);
  std::string bad;
  for (int j = 0; j < kHexapodLegs; ++j) {
    if (!calib.result.p_C_A[j].allFinite()) bad += (bad.empty() ? "" : ", ") + std::to_string(j);
  }
  if (!bad.empty()) {
    throw std::invalid_argument(o.calib + ": legs " + bad +
                                " have no estimate; the servo needs all six A_j (re-calibrate)");
  }
  control::LegPoints p_C_A;
  for (int j = 0; j < kHexapodLegs; ++j) p_C_A[j] = calib.result.p_C_A[j];
  // The camera pose: the calibration's rigid fit (eq. 15), else the hand-measured hint.
  const Eigen::Isometry3d X_CB =
      calib.result.rigid_fit ? calib.result.X_CB : rig->X_BC_hint().inverse();
  if (!calib.result.rigid_fit) {
    spdlog::warn("servo hexapod: {} has no rigid fit; the camera pose comes from the config",
                 o.calib);
  }

  control::LegDirections u_star;
  const robots::Reachability reach =
      control::DesiredLegDirections(nominal, o.X_BP_target, X_CB, &u_star);
  if (!reach.ok()) {
    robots::HexapodData ik;
    robots::InverseKinematics(nominal, o.X_BP_target, &ik);
    throw std::invalid_argument("servo hexapod: the target pose is not reachable: " +
                                reach.Describe(nominal, ik.q));
  }

  control::LegServoOptions law_options;
  law_options.gain = o.gain;
  law_options.adaptive_gain = o.adaptive;
  law_options.gain_at_infinity = o.gain;
  law_options.gain_at_zero = 4 * o.gain;
  law_options.min_visible_legs = o.min_visible_legs;
  control::LegServo law(p_C_A, law_options);
  law.SetDesired(u_star);

  rig->Enable();
  control::ImageLegFeatureOptions feature_options;
  feature_options.edges = rig->edge_options();
  feature_options.p_C_A = p_C_A;
  // A real camera (or a world in another process) delivers frames when it does: grab and extract
  // in a worker thread so that the drive cycle never waits for the camera. The simulated world in
  // this process runs on its stepped clock from this thread only.
  feature_options.asynchronous = !rig->simulated();
  control::ImageLegFeatureSource source(
      &rig->camera(), &rig->camera_model(), nominal, X_CB,
      [rig, &nominal] { return robots::LegLengthsFromJointPositions(nominal, rig->Readings()); },
      feature_options);

  control::ServoLoopOptions loop_options;
  loop_options.cycle_period_s = rig->cycle_period_s();
  loop_options.command_mode =
      o.mode == "csp" ? control::DriveCommandMode::kPosition : control::DriveCommandMode::kVelocity;
  loop_options.max_leg_velocity = o.max_leg_velocity;
  loop_options.min_visible_legs = o.min_visible_legs;
  loop_options.stale_camera_timeout_s = std::max(0.1, 3.0 / rig->camera_fps());
  loop_options.convergence_threshold = o.threshold;
  loop_options.convergence_translation = o.remaining_translation;
  loop_options.convergence_rotation = o.remaining_rotation;
  loop_options.convergence_dwell_s = std::max(0.2, 3.0 / rig->camera_fps());
  loop_options.timeout_s = o.timeout_s;
  control::ServoLoop loop(&rig->master(), &rig->clock(), &source, nominal, &law, loop_options);
  run.report = loop.Run();
  run.feature_counters = source.counters();
  run.camera_error = source.last_error();
  for (int j = 0; j < kHexapodLegs; ++j) {
    if (!source.last_observations()[j].visible) {
      run.last_not_seen +=
          (run.last_not_seen.empty() ? "" : "; ") + source.last_observations()[j].reason;
    }
  }
  if (rig->simulated()) {
    const sim::HexapodPlantState state = rig->world()->plant();
    run.simulated = true;
    run.true_position_error = (state.X_BP.translation() - o.X_BP_target.translation()).norm();
    run.true_rotation_error =
        Eigen::AngleAxisd(state.X_BP.linear() * o.X_BP_target.linear().transpose()).angle();
  }
  rig->Disable();
  if (!o.log.empty()) control::WriteServoLogCsv(o.log, run.report.samples);
  if (!o.plot.empty()) {
    control::WriteConvergencePlot(o.plot, run.report.samples, o.threshold,
                                  "hexapod leg-direction servo: |e| (" + rig->camera_name() + ")");
  }
  return run;
}

}  // namespace kinevis::rigs
