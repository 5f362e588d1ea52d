// kinevis record hexapod | calibrate hexapod | servo hexapod (issue 6, seed 002): record leg
// images at planned poses, calibrate the base attachment points A_j from the leg edges, and servo
// the platform from the leg directions — on the simulated world in this process or on real
// hardware, by the file given to --config (docs/hexapod-rig.md, docs/hexapod-calibration.md).

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

#include "apps/kinevis/cli_common.h"
#include "apps/kinevis/commands.h"
#include "apps/kinevis/hexapod_jobs.h"
#include "apps/kinevis/hexapod_rig.h"
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

namespace kinevis::cli {
namespace {

namespace fs = std::filesystem;
using robots::kHexapodLegs;

// --- record -------------------------------------------------------------------------------------

// Every leg is in the image: points at 15 %, 50 % and 85 % of its length project at least
// `margin_px` inside it (its very ends may be cut: the edges are not searched there).
bool LegsInView(const robots::HexapodModel& model, const vision::CameraModel& camera,
                const Eigen::Isometry3d& X_CB, const Eigen::Isometry3d& X_BP, double margin_px) {
  const Eigen::Isometry3d X_CP = X_CB * X_BP;
  for (int j = 0; j < kHexapodLegs; ++j) {
    const Eigen::Vector3d a = X_CB * model.p_B_A[j];
    const Eigen::Vector3d b = X_CP * model.p_P_B[j];
    for (const double t : {0.15, 0.5, 0.85}) {
      const Eigen::Vector3d p = a + t * (b - a);
      Eigen::Vector2d px;
      if (camera.Project(p, &px, nullptr) != vision::ProjectionStatus::kOk) return false;
      if (px.x() < margin_px || px.y() < margin_px || px.x() > camera.width() - 1 - margin_px ||
          px.y() > camera.height() - 1 - margin_px) {
        return false;
      }
    }
  }
  return true;
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
    return LegsInView(nominal, *camera, X_CB_hint, X_BP, 10.0);
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
    if (StopRequested()) {
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

namespace {

struct RecordCommandOptions {
  HexapodRigOptions rig;
  HexapodRecordOptions record;
};

int RunRecord(const RecordCommandOptions& o) {
  HexapodRig rig(o.rig);
  const HexapodRecordSummary s = RecordHexapodDataset(&rig, o.record);
  for (const std::string& w : s.warnings) std::printf("warning: %s\n", w.c_str());
  std::printf("recorded %d poses into %s\n", s.recorded, o.record.out.c_str());
  if (!s.stopped.empty()) {
    std::fprintf(stderr, "kinevis record hexapod: stopped: %s\n", s.stopped.c_str());
    return s.hardware_fault ? kExitHardware : kExitJobFailed;
  }
  return kExitOk;
}

// --- calibrate ----------------------------------------------------------------------------------

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

double Median(std::vector<double> v) {
  if (v.empty()) return std::nan("");
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

}  // namespace

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

void PrintHexapodCalibration(const HexapodCalibrationRun& run) {
  const calibration::HexapodCalibrationResult& r = run.calibration.result;
  std::printf(
      "hexapod calibration (seed 002 eq. 14-16), %d configurations, R = %.4f m, %s, "
      "%d pass(es)\n",
      r.configurations, r.leg_radius, calibration::ToString(r.loss), run.calibration.passes_run);
  std::printf(
      "leg  status                     A_j in C (mm)                      sigma_max(mm) "
      "cond   confs down-w  rigid-fit(mm)\n");
  for (int j = 0; j < kHexapodLegs; ++j) {
    const calibration::LegCalibration& l = r.legs[j];
    const double sigma = std::sqrt(std::max(
        0.0,
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(l.covariance).eigenvalues().maxCoeff()));
    std::printf("%3d  %-24s %9.2f %9.2f %9.2f   %8.3f  %6.1f %5d %6d %9.2f\n", j,
                calibration::ToString(l.status), 1e3 * r.p_C_A[j].x(), 1e3 * r.p_C_A[j].y(),
                1e3 * r.p_C_A[j].z(), 1e3 * sigma, l.condition_number, l.configurations,
                l.down_weighted, 1e3 * l.rigid_fit_residual);
  }
  if (r.rigid_fit) {
    std::printf("rigid fit X_CB (eq. 15): rms %.2f mm, max %.2f mm\n", 1e3 * r.rigid_fit_rms,
                1e3 * r.rigid_fit_max);
  }
  std::printf(
      "scale (eq. 16): %.5f (%s); least squares %.5f, median ratio %.5f, max ratio %.5f%s\n",
      r.scale, calibration::ToString(r.scale_estimator), r.scale_least_squares,
      r.scale_median_ratio, r.scale_max_ratio, r.scale_corrected ? ", corrected" : "");
  if (!std::isnan(run.calibration.last_pass_change)) {
    std::printf("largest change of an A_j in the last pass: %.3f mm\n",
                1e3 * run.calibration.last_pass_change);
  }
  for (const std::string& e : r.errors) std::printf("error: %s\n", e.c_str());
  for (const std::string& w : r.warnings) std::printf("warning: %s\n", w.c_str());
}

namespace {

struct CalibrateCommandOptions {
  HexapodRigOptions rig;
  HexapodRecordOptions record;
  HexapodCalibrateOptions calibrate;
};

int RunCalibrate(CalibrateCommandOptions o) {
  std::unique_ptr<HexapodRig> rig;
  robots::HexapodModel truth;
  Eigen::Isometry3d X_CB_true = Eigen::Isometry3d::Identity();
  bool have_truth = false;
  if (o.calibrate.dataset.empty()) {
    // Live: record first (into --record DIR, or a fresh directory beside --out).
    rig = std::make_unique<HexapodRig>(o.rig);
    if (o.record.out.empty()) {
      const fs::path out(o.calibrate.out);
      o.record.out = (out.parent_path() / (out.stem().string() + "-dataset")).string();
      for (int k = 2; fs::exists(fs::path(o.record.out) / "dataset.yaml"); ++k) {
        o.record.out =
            (out.parent_path() / (out.stem().string() + "-dataset-" + std::to_string(k))).string();
      }
    }
    const HexapodRecordSummary s = RecordHexapodDataset(rig.get(), o.record);
    std::printf("recorded %d poses into %s\n", s.recorded, o.record.out.c_str());
    for (const std::string& w : s.warnings) std::printf("warning: %s\n", w.c_str());
    if (!s.stopped.empty()) {
      std::fprintf(stderr, "kinevis calibrate hexapod: recording stopped: %s\n", s.stopped.c_str());
      return s.hardware_fault ? kExitHardware : kExitJobFailed;
    }
    if (rig->simulated()) {
      truth = rig->world()->true_model();
      X_CB_true = rig->X_BC_hint().inverse();  // the world's camera pose is the true one
      have_truth = true;
    }
    o.calibrate.dataset = o.record.out;
  }
  const HexapodCalibrationRun run = CalibrateHexapodFromDataset(o.calibrate);
  PrintHexapodCalibration(run);
  if (have_truth) {
    std::vector<double> errors;
    for (int j = 0; j < kHexapodLegs; ++j) {
      const Eigen::Vector3d& a = run.calibration.result.p_C_A[j];
      if (a.allFinite()) errors.push_back((a - X_CB_true * truth.p_B_A[j]).norm());
    }
    std::printf("simulation truth: |A_j estimated - A_j true| median %.2f mm, max %.2f mm\n",
                1e3 * Median(errors),
                errors.empty() ? NAN : 1e3 * *std::max_element(errors.begin(), errors.end()));
  }
  std::printf("wrote %s and %s\n", o.calibrate.out.c_str(), run.image.c_str());
  return run.calibration.result.ok() ? kExitOk : kExitJobFailed;
}

// --- servo --------------------------------------------------------------------------------------

Eigen::Isometry3d PoseFromValues(const std::vector<double>& v) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation() = Eigen::Vector3d(v[0], v[1], v[2]);
  X.linear() = (Eigen::AngleAxisd(v[5] * common::kDeg, Eigen::Vector3d::UnitZ()) *
                Eigen::AngleAxisd(v[4] * common::kDeg, Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(v[3] * common::kDeg, Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  return X;
}

}  // namespace

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

void PrintHexapodServo(const HexapodServoRun& run, const HexapodServoOptions& o) {
  const control::ServoLoopReport& r = run.report;
  std::printf("servo hexapod: %s after %.2f s: |e| = %.3g (threshold %.3g)",
              control::ToString(r.outcome), r.duration_s, r.final_error_norm, o.threshold);
  if (r.time_to_threshold_s >= 0) {
    std::printf(", convergence test first met at %.2f s", r.time_to_threshold_s);
  }
  std::printf(
      "\n  %llu cycles (%llu with late drive answers), %llu camera frames, holds: %llu leg "
      "lost, %llu stale camera, %llu law; velocity-limited cycles %llu\n",
      static_cast<unsigned long long>(r.cycles), static_cast<unsigned long long>(r.cycle_timeouts),
      static_cast<unsigned long long>(r.frames),
      static_cast<unsigned long long>(r.hold_cycles_leg_lost),
      static_cast<unsigned long long>(r.hold_cycles_stale_camera),
      static_cast<unsigned long long>(r.hold_cycles_law),
      static_cast<unsigned long long>(r.velocity_scaled_cycles));
  if (!r.message.empty()) std::printf("  %s\n", r.message.c_str());
  if (!run.camera_error.empty()) std::printf("  camera: %s\n", run.camera_error.c_str());
  if (!run.last_not_seen.empty()) std::printf("  last frame: %s\n", run.last_not_seen.c_str());
  if (run.simulated) {
    std::printf("  simulation truth: platform %.2f mm and %.3f deg from the target pose\n",
                1e3 * run.true_position_error, run.true_rotation_error / common::kDeg);
  }
  if (!o.log.empty()) std::printf("wrote %s\n", o.log.c_str());
  if (!o.plot.empty()) std::printf("wrote %s\n", o.plot.c_str());
}

namespace {

struct ServoCommandOptions {
  HexapodRigOptions rig;
  HexapodServoOptions servo;
  std::string target;
  std::vector<double> pose;
};

int RunServo(ServoCommandOptions o) {
  if (o.target.empty() == o.pose.empty()) {
    throw std::invalid_argument("give the target as --target FILE or as --pose X,Y,Z,R,P,Y");
  }
  o.servo.X_BP_target = o.target.empty() ? PoseFromValues(o.pose) : ReadTargetPose(o.target);
  HexapodRig rig(o.rig);
  const HexapodServoRun run = ServoHexapod(&rig, o.servo);
  PrintHexapodServo(run, o.servo);
  switch (run.report.outcome) {
    case control::ServoLoopOutcome::kConverged:
      return kExitOk;
    case control::ServoLoopOutcome::kDriveFault:
      return kExitHardware;
    default:
      return kExitJobFailed;
  }
}

void AddRigOptions(CLI::App* cmd, HexapodRigOptions* o) {
  cmd->add_option("--config", o->config,
                  "World config (world: hexapod, simulated in this process) or deployment file "
                  "(rig: hexapod, real hardware); default: the built-in simulated world "
                  "(docs/hexapod-rig.md)")
      ->check(CLI::ExistingFile);
  cmd->add_option("--camera", o->camera, "Camera name in the file (default: the first)");
}

void AddRecordOptions(CLI::App* cmd, HexapodRecordOptions* o) {
  cmd->add_option("--poses", o->poses, "Poses to plan and record (seed 002: 60)")
      ->capture_default_str()
      ->check(CLI::Range(2, 1000));
  cmd->add_option("--seed", o->seed, "Seed of the pose planner")->capture_default_str();
  cmd->add_option("--speed", o->speed, "Fastest leg speed between poses, m/s")
      ->capture_default_str()
      ->check(CLI::Range(1e-4, 1.0));
  cmd->add_option("--settle", o->settle_s, "Wait after each move before the image, s")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 10.0));
}

}  // namespace

void AddHexapodCommands(CLI::App& app, CLI::App& calibrate, CLI::App& servo,
                        CommandList* commands) {
  // record hexapod
  // `record` is shared with the other robots' recorders: made by whoever comes first.
  CLI::App* record = nullptr;
  for (CLI::App* sub : app.get_subcommands([](CLI::App*) { return true; })) {
    if (sub->get_name() == "record") record = sub;
  }
  if (record == nullptr) {
    record = app.add_subcommand("record", "Record calibration datasets on the robot");
    record->require_subcommand(1);
  }
  auto ro = std::make_shared<RecordCommandOptions>();
  CLI::App* rh = record->add_subcommand(
      "hexapod",
      "Move the hexapod through planned poses on its workspace limits and record an image and "
      "the joint readings at each (a dataset directory, docs/hexapod-rig.md)");
  AddRigOptions(rh, &ro->rig);
  AddRecordOptions(rh, &ro->record);
  rh->add_option("--out", ro->record.out, "Dataset directory to create")->required();
  rh->footer("Exit code 3 when a drive or the camera fails (the dataset keeps the poses before).");
  commands->push_back({rh, [ro] { return RunRecord(*ro); }});

  // calibrate hexapod
  auto co = std::make_shared<CalibrateCommandOptions>();
  CLI::App* ch = calibrate.add_subcommand(
      "hexapod",
      "Calibrate the base attachment points A_j in the camera frame from the image edges of the "
      "legs (seed 002): live (records --poses first) or from a recorded --dataset");
  AddRigOptions(ch, &co->rig);
  AddRecordOptions(ch, &co->record);
  ch->add_option("--dataset", co->calibrate.dataset,
                 "Calibrate from this recorded dataset instead of recording (no robot needed)")
      ->check(CLI::ExistingDirectory);
  ch->add_option("--record", co->record.out,
                 "Live: keep the recording in this directory (default: OUT-dataset beside --out)");
  ch->add_option("--out", co->calibrate.out,
                 "Calibration result YAML (docs/hexapod-calibration.md)")
      ->capture_default_str();
  ch->add_option("--image", co->calibrate.image,
                 "Re-projection PNG of the estimated and CAD points (default: --out with .png)");
  ch->add_option("--loss", co->calibrate.loss, "Robust loss of eq. 14")
      ->capture_default_str()
      ->check(CLI::IsMember({"tukey", "huber", "least-squares"}));
  ch->add_option("--scale", co->calibrate.scale, "Estimator of eq. 16's scale")
      ->capture_default_str()
      ->check(CLI::IsMember({"least-squares", "median-ratio", "max-ratio"}));
  ch->add_option("--edge-locator", co->calibrate.edge_locator,
                 "Sub-pixel edge locator (default: the dataset's, i.e. the camera config's): "
                 "step-ramp (accurate when the optics' blur is known) or parabola (blur-proof)")
      ->check(CLI::IsMember({"step-ramp", "parabola"}));
  ch->add_option("--edge-blur", co->calibrate.edge_blur_px,
                 "Optics' blur sigma (px) the step-ramp locator models (default: the dataset's)")
      ->check(CLI::Range(0.0, 3.0));
  ch->add_flag("--correct-scale", co->calibrate.correct_scale,
               "Divide the estimates by the scale (an error on the leg radius)");
  ch->add_option("--passes", co->calibrate.passes,
                 "Extraction rounds; each after the first searches around the previous estimate")
      ->capture_default_str()
      ->check(CLI::Range(1, 5));
  ch->excludes(ch->get_option("--record"));
  ch->get_option("--dataset")->excludes("--record")->excludes("--poses");
  ch->footer(
      "Exit code 1 when a leg could not be calibrated (the message names it and why), 2 for a "
      "bad file or option, 3 when a drive or the camera fails while recording.");
  commands->push_back({ch, [co] { return RunCalibrate(*co); }});

  // servo hexapod
  auto so = std::make_shared<ServoCommandOptions>();
  CLI::App* sh = servo.add_subcommand(
      "hexapod",
      "Leg-direction visual servoing (seed 002): drive the platform until the leg directions "
      "seen by the camera are those of the target pose");
  AddRigOptions(sh, &so->rig);
  sh->add_option("--calib", so->servo.calib, "Calibration result (kinevis calibrate hexapod)")
      ->required()
      ->check(CLI::ExistingFile);
  sh->add_option("--target", so->target,
                 "Target pose file: pose: {position: [x, y, z], rpy_deg: [r, p, y]} (platform in "
                 "the base frame, m and degrees)")
      ->check(CLI::ExistingFile);
  sh->add_option("--pose", so->pose, "Target pose as X,Y,Z,ROLL,PITCH,YAW (m, degrees)")
      ->expected(6)
      ->delimiter(',');
  sh->add_option("--gain", so->servo.gain, "Gain lambda of tau = -lambda L+ e, 1/s")
      ->capture_default_str()
      ->check(CLI::Range(1e-3, 100.0));
  sh->add_flag("--adaptive", so->servo.adaptive,
               "Adaptive gain (4 lambda near the goal, lambda far from it)");
  sh->add_option("--mode", so->servo.mode, "Drive mode: csv (velocity) or csp (integrated)")
      ->capture_default_str()
      ->check(CLI::IsMember({"csv", "csp"}));
  sh->add_option("--threshold", so->servo.threshold, "Converged when |e| stays below this")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  sh->add_option("--arrive-mm", so->servo.remaining_translation,
                 "... or when the motion the law still asks for is below this (mm) and "
                 "--arrive-deg")
      ->transform([](std::string v) { return std::to_string(std::stod(v) * 1e-3); })
      ->check(CLI::NonNegativeNumber);
  sh->add_option("--arrive-deg", so->servo.remaining_rotation, "(degrees); 0 disables the test")
      ->transform([](std::string v) { return std::to_string(std::stod(v) * M_PI / 180); })
      ->check(CLI::NonNegativeNumber);
  sh->add_option("--timeout", so->servo.timeout_s, "Give up after this many seconds")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  sh->add_option("--max-velocity", so->servo.max_leg_velocity, "Fastest leg rate, m/s")
      ->capture_default_str()
      ->check(CLI::Range(1e-4, 0.5));
  sh->add_option("--min-legs", so->servo.min_visible_legs,
                 "Fewest legs seen for the law to run; fewer holds the platform")
      ->capture_default_str()
      ->check(CLI::Range(3, 6));
  sh->add_option("--log", so->servo.log, "CSV log, one row per drive cycle (control/README.md)");
  sh->add_option("--plot", so->servo.plot, "Convergence plot PNG (|e| against time)");
  sh->footer(
      "Exit code 0 when converged, 1 on a timeout or a stroke limit, 2 for a bad file or "
      "option or an unreachable target, 3 on a drive fault or heartbeat loss (every drive is "
      "stopped).");
  commands->push_back({sh, [so] { return RunServo(*so); }});
}

}  // namespace kinevis::cli
