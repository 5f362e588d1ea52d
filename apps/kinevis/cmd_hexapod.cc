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
#include "rigs/hexapod/hexapod_jobs.h"
#include "rigs/hexapod/hexapod_rig.h"
#include "sim/hexapod_world.h"
#include "vision/camera/camera_file.h"

namespace kinevis::cli {
namespace {

namespace fs = std::filesystem;
using rigs::CalibrateHexapodFromDataset;
using rigs::HexapodCalibrateOptions;
using rigs::HexapodCalibrationRun;
using rigs::HexapodRecordOptions;
using rigs::HexapodRecordSummary;
using rigs::HexapodRig;
using rigs::HexapodRigOptions;
using rigs::HexapodServoOptions;
using rigs::HexapodServoRun;
using rigs::ReadTargetPose;
using rigs::RecordHexapodDataset;
using rigs::ServoHexapod;
using robots::kHexapodLegs;

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

double Median(std::vector<double> v) {
  if (v.empty()) return std::nan("");
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
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
  std::printf("estimation: %s\n", r.estimation.BriefReport().c_str());
  for (const std::string& e : r.errors) std::printf("error: %s\n", e.c_str());
  for (const std::string& w : r.warnings) std::printf("warning: %s\n", w.c_str());
}

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

void PrintHexapodServo(const HexapodServoRun& run, const HexapodServoOptions& o) {
  const control::ServoLoopReport& r = run.report;
  std::printf("servo hexapod: %s after %.2f s: |e| = %.3g (threshold %.3g)",
              control::ServoOutcomeName(r.outcome), r.duration_s, r.final_error_norm, o.threshold);
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
    case control::LoopOutcome::kCompleted:
      return kExitOk;
    case control::LoopOutcome::kDriveFault:
    case control::LoopOutcome::kNotStarted:
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
  o->stop_requested = StopRequested;  // Ctrl-C ends the recording between poses
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

void AddHexapodCommands(const Parents& parents, CommandList* commands) {
  CLI::App& calibrate = *parents.calibrate;
  CLI::App& servo = *parents.servo;
  // record hexapod
  CLI::App* record = parents.record;
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
