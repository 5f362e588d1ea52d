// kinevis record diamond | calibrate diamond | servo diamond | plan-camera diamond (issue 8, seed
// 001): record marker images at joint configurations spread over the workspace, identify R, α, β,
// the joint offsets and the camera pose from them, follow the seed's validation lines (task-space
// PD) or servo the marker (IBVS) with the a-priori or the identified parameters, and plan the
// camera's distance — on the simulated world in this process or on the real robot, by the file
// given to --config (docs/diamond-calibration.md, docs/diamond-control.md).

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "apps/kinevis/cli_common.h"
#include "apps/kinevis/commands.h"
#include "apps/kinevis/diamond_demo.h"
#include "calibration/diamond/camera_placement.h"
#include "common/stopwatch.h"
#include "common/units.h"
#include "rigs/diamond/diamond_rig.h"
#include "sim/diamond_world.h"
#include "vision/camera/camera_file.h"

namespace kinevis::cli {

using rigs::CalibrateDiamondFromDataset;
using rigs::DiamondCalibrateOptions;
using rigs::DiamondCalibrationRun;
using rigs::DiamondDetectorOptions;
using rigs::DiamondRecordOptions;
using rigs::DiamondRecordSummary;
using rigs::DiamondRig;
using rigs::DiamondRigOptions;
using rigs::DiamondServoLaw;
using rigs::DiamondServoOptions;
using rigs::DiamondServoRun;
using rigs::FormatTaskDeg;
using rigs::RecordDiamondDataset;
using rigs::ServoDiamond;

namespace {

namespace fs = std::filesystem;

}  // namespace

namespace {

struct RecordCommandOptions {
  DiamondRigOptions rig;
  DiamondRecordOptions record;
};

int RunRecord(const RecordCommandOptions& o) {
  DiamondRig rig(o.rig);
  const DiamondRecordSummary s = RecordDiamondDataset(&rig, o.record);
  std::printf(
      "recorded %d of %d samples (image + joint readings) into %s in %.1f s (%d moved nearer the "
      "view's centre to see the marker)\n",
      s.recorded, s.planned, o.record.out.c_str(), s.wall_seconds, s.retries);
  for (const std::string& m : s.marker_not_found) {
    std::printf("warning: marker not found in %s (calibrate will skip it)\n", m.c_str());
  }
  if (!s.truth_file.empty()) {
    std::printf("simulated world: its truth is in %s (for comparison only)\n",
                s.truth_file.c_str());
  }
  if (!s.stopped.empty()) {
    std::fprintf(stderr, "kinevis record diamond: stopped: %s\n", s.stopped.c_str());
    return s.hardware_fault ? kExitHardware : kExitJobFailed;
  }
  return kExitOk;
}

}  // namespace

void PrintDiamondCalibration(const DiamondCalibrationRun& run) {
  const calibration::DiamondIdentificationSummary& s = run.summary;
  std::printf(
      "diamond calibration (seed 001 eq. 2-7, 34-35) from %s: %d samples, marker found in %d "
      "(%.1f s), %d used; %s residuals, %s column scaling, sigma %.3g px\n",
      run.dataset.c_str(), run.images, run.detected, run.detection_seconds, s.samples_used,
      calibration::ToString(s.residual), calibration::ToString(s.scaling), s.pixel_sigma);
  for (const std::string& n : run.not_detected) std::printf("  not used: %s\n", n.c_str());
  for (size_t i = 0; i < s.rejected_samples.size(); ++i) {
    std::printf("  rejected: sample %d: %s\n", s.rejected_samples[i],
                i < s.rejected_reasons.size() ? s.rejected_reasons[i].c_str() : "");
  }
  std::printf(
      "status: %s after %d iterations (%.2f s); cost %.4g -> %.4g; a-posteriori variance "
      "factor %.3g\n",
      calibration::ToString(s.status), s.iterations, run.identification_seconds, s.initial_cost,
      s.final_cost, s.variance_factor);
  std::printf("  %-24s %14s %14s %12s  %-4s %s\n", "parameter", "initial", "identified", "sigma",
              "unit", "");
  for (int i = 0; i < calibration::kDiamondParameterCount; ++i) {
    const calibration::DiamondParameterEstimate& p = s.parameters[i];
    const char* state = !p.estimated ? "fixed (gauge)" : (p.identified ? "" : "NOT IDENTIFIED");
    std::printf("  %-24s %14.8f %14.8f %12.3g  %-4s %s\n", calibration::DiamondParameterName(i),
                p.initial, p.value, p.sigma, calibration::DiamondParameterUnit(i), state);
  }
  std::printf(
      "  R = %.3f mm +- %.3f, alpha = %.4f deg +- %.4f, beta = %.4f deg +- %.4f; joint "
      "offsets %.4f, %.4f deg (+- %.4f, %.4f)\n",
      1e3 * s.model.radius, 1e3 * s.parameters[calibration::kDiamondRadius].sigma,
      s.model.alpha / common::kDeg, s.parameters[calibration::kDiamondAlpha].sigma / common::kDeg,
      s.model.beta / common::kDeg, s.parameters[calibration::kDiamondBeta].sigma / common::kDeg,
      s.model.joint_offsets[0] / common::kDeg, s.model.joint_offsets[1] / common::kDeg,
      s.offset_sigma[0] / common::kDeg, s.offset_sigma[1] / common::kDeg);
  const calibration::IdentifiabilityReport& id = s.identifiability;
  std::printf("identifiability: rank %d of %d free parameters, condition number %.1f\n", id.rank,
              id.parameters, id.condition_number);
  for (const std::string& u : id.unidentified) std::printf("  unidentified: %s\n", u.c_str());
  for (const std::string& g : id.gauges) std::printf("  gauge: %s\n", g.c_str());
  for (const std::string& c : id.strong_correlations) {
    std::printf("  strong correlation: %s\n", c.c_str());
  }
  const calibration::ResidualStatistics& px = s.pixel_residuals;
  const calibration::ResidualStatistics& tk = s.task_residuals;
  std::printf(
      "residuals (seed Table II), %d samples: pixel (u, v) mean %.3f, %.3f  rms %.3f, %.3f  max "
      "%.3f, %.3f px\n",
      px.count, px.mean.x(), px.mean.y(), px.rms.x(), px.rms.y(), px.sup.x(), px.sup.y());
  std::printf(
      "  task (phi, gamma) by spherical positioning, %d samples: mean %.2e, %.2e  rms %.2e, "
      "%.2e  max %.2e, %.2e rad\n",
      tk.count, tk.mean.x(), tk.mean.y(), tk.rms.x(), tk.rms.y(), tk.sup.x(), tk.sup.y());
  std::printf("estimation: %s\n", s.estimation.BriefReport().c_str());
  for (const std::string& w : s.warnings) std::printf("warning: %s\n", w.c_str());
  if (run.has_truth) {
    const robots::DiamondModel& t = run.truth.model;
    const double h_true = 0.5 * (t.joint_offsets[0] - t.joint_offsets[1]);
    const double h = s.parameters[calibration::kDiamondHalfOffsetDifference].value;
    const double camera_angle =
        Eigen::AngleAxisd(s.X_OC.linear() * run.truth.X_OC.linear().transpose()).angle();
    std::printf(
        "simulation truth (%s): R %+.4f mm (%+.4f %%), alpha %+.4f mrad (%+.4f %%), beta %+.4f "
        "mrad (%+.4f %%); offset half-difference %+.4f mdeg; camera %.4f deg, %.3f mm off\n",
        rigs::kDiamondTruthFile, 1e3 * (s.model.radius - t.radius),
        100 * (s.model.radius / t.radius - 1), 1e3 * (s.model.alpha - t.alpha),
        100 * (s.model.alpha / t.alpha - 1), 1e3 * (s.model.beta - t.beta),
        100 * (s.model.beta / t.beta - 1), 1e3 * (h - h_true) / common::kDeg,
        camera_angle / common::kDeg,
        1e3 * (s.X_OC.translation() - run.truth.X_OC.translation()).norm());
  }
  std::printf("wrote %s\n", run.out.c_str());
  if (!run.identified) {
    std::printf(
        "identification FAILED: %s (status %s, rank %d of %d); see the identifiability report\n",
        s.ok() ? "a parameter is not identified" : "no converged solution",
        calibration::ToString(s.status), id.rank, id.parameters);
  }
}

namespace {

struct CalibrateCommandOptions {
  DiamondRigOptions rig;
  DiamondRecordOptions record;
  DiamondCalibrateOptions calibrate;
};

int RunCalibrate(CalibrateCommandOptions o) {
  if (o.calibrate.dataset.empty()) {
    // Live: record first (into --record DIR, or a fresh directory beside --out).
    DiamondRig rig(o.rig);
    if (o.record.out.empty()) {
      const fs::path out(o.calibrate.out);
      o.record.out = (out.parent_path() / (out.stem().string() + "-dataset")).string();
      for (int k = 2; fs::exists(fs::path(o.record.out) / "dataset.yaml"); ++k) {
        o.record.out =
            (out.parent_path() / (out.stem().string() + "-dataset-" + std::to_string(k))).string();
      }
    }
    const DiamondRecordSummary s = RecordDiamondDataset(&rig, o.record);
    std::printf("recorded %d samples into %s\n", s.recorded, o.record.out.c_str());
    for (const std::string& m : s.marker_not_found) {
      std::printf("warning: marker not found in %s\n", m.c_str());
    }
    if (!s.stopped.empty()) {
      std::fprintf(stderr, "kinevis calibrate diamond: recording stopped: %s\n", s.stopped.c_str());
      return s.hardware_fault ? kExitHardware : kExitJobFailed;
    }
    o.calibrate.dataset = o.record.out;
  }
  const DiamondCalibrationRun run = CalibrateDiamondFromDataset(o.calibrate);
  PrintDiamondCalibration(run);
  return run.identified ? kExitOk : kExitJobFailed;
}

}  // namespace

// --- servo --------------------------------------------------------------------------------------

namespace {}  // namespace

void PrintDiamondServo(const DiamondServoRun& run, const DiamondServoOptions& o) {
  const bool pd = o.law == DiamondServoLaw::kTaskPd;
  if (pd) {
    std::printf("servo diamond: task-space PD along the %s line from %s to %s in %.2f s\n",
                control::ToString(o.kind), FormatTaskDeg(o.from).c_str(),
                FormatTaskDeg(o.to).c_str(), o.duration_s);
  } else {
    std::printf(
        "servo diamond: marker IBVS (ViSP) from %s to the image of %s, target pixel (%.2f, "
        "%.2f), gain %.2f 1/s\n",
        FormatTaskDeg(o.from).c_str(), FormatTaskDeg(o.to).c_str(), run.target_pixel.x(),
        run.target_pixel.y(), o.gain);
  }
  std::printf("  model: %s: R = %.4f m, alpha = %.4f, beta = %.4f rad\n", run.model_source.c_str(),
              run.model.radius, run.model.alpha, run.model.beta);
  std::printf("  approach to the start: %s in %.2f s", control::ToString(run.approach.outcome),
              run.approach.duration_s);
  if (!run.reached_start) {
    std::printf(": %s\n", run.approach.message.c_str());
    return;
  }
  std::printf("\n");
  const control::DiamondLoopReport& r = run.report;
  std::printf(
      "  %s: %s after %.2f s, %llu cycles (%llu late drive answers, %llu velocity-limited, %llu "
      "lead-limited, %llu hold), RCM closure max %.1e\n",
      pd ? "line" : "servo", control::ToString(r.outcome), r.duration_s,
      static_cast<unsigned long long>(r.cycles), static_cast<unsigned long long>(r.cycle_timeouts),
      static_cast<unsigned long long>(r.velocity_scaled_cycles),
      static_cast<unsigned long long>(r.lead_limited_cycles),
      static_cast<unsigned long long>(r.hold_cycles), r.rcm_closure_max);
  if (!r.message.empty()) std::printf("  %s\n", r.message.c_str());
  if (!run.camera_error.empty()) std::printf("  %s\n", run.camera_error.c_str());
  std::printf("  loop: %.1f Hz (target %.1f Hz); %s\n", r.timing.rate_hz(),
              r.timing.target_s > 0 ? 1.0 / r.timing.target_s : 0.0, r.timing.Describe().c_str());
  std::printf("  scheduling: %s\n", run.realtime.c_str());
  if (!run.real_time) {
    std::printf(
        "  (stepped simulated clock: the periods are exact by construction; --real-time runs the "
        "world in real time and measures the jitter)\n");
  }
  std::printf(
      "  straightness (seed Table III): %.4f cm RMS from the least-squares line of the measured "
      "path (%d marker fixes of %d frames, top view, %d without the marker)\n",
      100 * run.measured_straightness, run.measured_points, run.frames, run.frames_without_marker);
  if (!pd) {
    std::printf("  final marker error: %.3f px (detected)\n", run.final_pixel_error);
  }
  if (run.simulated) {
    char position[96] = "";
    if (pd) {
      std::snprintf(position, sizeof position,
                    ", position RMS %.4f cm from the reference on the true sphere",
                    100 * run.true_position_rms);
    }
    std::printf(
        "  simulation truth: true path straightness %.4f cm (%d points)%s; final (phi, gamma) "
        "%.3f deg from --to",
        100 * run.true_straightness, run.true_points, position,
        run.true_final_task_error / common::kDeg);
    if (!pd) std::printf("; true marker %.3f px from the target", run.true_final_pixel_error);
    std::printf("\n");
  }
  if (!o.log.empty()) std::printf("wrote %s\n", o.log.c_str());
}

int DiamondServoExitCode(const DiamondServoRun& run) {
  if (!run.camera_error.empty()) return kExitHardware;
  const control::DiamondLoopOutcome outcome =
      run.reached_start ? run.report.outcome : run.approach.outcome;
  switch (outcome) {
    case control::DiamondLoopOutcome::kCompleted:
      return kExitOk;
    case control::DiamondLoopOutcome::kDriveFault:
    case control::DiamondLoopOutcome::kNotStarted:
      return kExitHardware;
    default:
      return kExitJobFailed;
  }
}

namespace {

struct ServoCommandOptions {
  DiamondRigOptions rig;
  DiamondServoOptions servo;
  std::string path = "line";
  std::string law = "pd";
  std::string kind = "top-view";
  std::vector<double> from_deg, to_deg;
};

int RunServo(ServoCommandOptions o) {
  o.servo.from = Eigen::Vector2d(o.from_deg[0], o.from_deg[1]) * common::kDeg;
  o.servo.to = Eigen::Vector2d(o.to_deg[0], o.to_deg[1]) * common::kDeg;
  o.servo.law = o.law == "ibvs" ? DiamondServoLaw::kMarkerIbvs : DiamondServoLaw::kTaskPd;
  o.servo.kind = o.kind == "task" ? control::DiamondLineKind::kTaskLine
                                  : control::DiamondLineKind::kTopViewLine;
  DiamondRig rig(o.rig);
  const DiamondServoRun run = ServoDiamond(&rig, o.servo);
  PrintDiamondServo(run, o.servo);
  return DiamondServoExitCode(run);
}

// --- plan-camera --------------------------------------------------------------------------------

struct PlanCameraOptions {
  std::vector<double> q = {5.0};
  double radius = 0.2;
  double half_angle_deg = 0.0;  // 0: from the camera model
  std::string camera = "builtin:tsai-seed004";
  std::string axis = "smallest";
  std::string roi = "half";
  std::string plot;
};

int RunPlanCamera(const PlanCameraOptions& o) {
  calibration::CameraPlacementOptions options;
  options.radius = o.radius;
  options.roi_polar_extent = o.roi == "quarter" ? M_PI / 2 : M_PI;
  std::string lens;
  if (o.half_angle_deg > 0) {
    options.half_view_angle = o.half_angle_deg * common::kDeg;
    lens = "--half-angle-deg";
  } else {
    const std::unique_ptr<vision::CameraModel> camera = vision::OpenCameraModel(o.camera);
    const calibration::ViewAxis axis = o.axis == "vertical"     ? calibration::ViewAxis::kVertical
                                       : o.axis == "horizontal" ? calibration::ViewAxis::kHorizontal
                                       : o.axis == "diagonal"   ? calibration::ViewAxis::kDiagonal
                                                                : calibration::ViewAxis::kSmallest;
    options.half_view_angle = calibration::HalfViewAngle(*camera, axis);
    lens = o.camera + " (" + std::to_string(camera->width()) + "x" +
           std::to_string(camera->height()) + ", " + o.axis + " half-angle)";
  }
  std::printf(
      "camera placement (seed 001 eq. 29-33): J(r) = q S_ROI - S_waste; R = %.2f cm, beta = "
      "%.0f deg (%s sphere), half view angle theta = %.2f deg from %s\n",
      100 * o.radius, options.roi_polar_extent / common::kDeg, o.roi.c_str(),
      options.half_view_angle / common::kDeg, lens.c_str());
  std::printf("  %6s | %12s %14s %12s %14s | %s\n", "q", "r* (cm)", "J(r*) (cm^2)", "dth/dd(0)",
              "delta_max(deg)", "note");
  int found = 0;
  for (const double q : o.q) {
    options.weight = q;
    const calibration::CameraPlacement plan = calibration::PlanCameraPlacement(options);
    if (!plan.found) {
      std::printf("  %6.2f | %12s %14s %12s %14s | no interior maximum", q, "-", "-", "-", "-");
      for (const std::string& n : plan.notes) std::printf("; %s", n.c_str());
      std::printf("\n");
      continue;
    }
    ++found;
    std::printf("  %6.2f | %12.2f %14.1f %12.4f %14.2f | %s\n", q, 100 * plan.best_distance,
                1e4 * plan.at_best.benefit,
                calibration::SphereViewAngleRate(o.radius, plan.best_distance, 0.0),
                calibration::MaxVisibleCentralAngle(o.radius, plan.best_distance) / common::kDeg,
                plan.at_best.waste < 0 ? "S_waste < 0 there (the sphere overfills the view)" : "");
  }
  {
    options.weight = o.q.front();
    const calibration::CameraPlacement plan = calibration::PlanCameraPlacement(options);
    std::printf("  the whole sphere fits in the view from R / sin(theta) = %.2f cm\n",
                100 * plan.full_view_distance);
  }
  // The seed's number: eq. (33) with beta = pi, tan^2 theta = 2 q R^3 / (pi A r^2) - R^4 / A^4,
  // A^2 = r^2 - R^2, solved for theta at the seed's R = 20 cm, q = 5, r* = 44.62 cm.
  const double r_seed = 0.4462, R_seed = 0.2, q_seed = 5.0;
  const double A = std::sqrt(r_seed * r_seed - R_seed * R_seed);
  const double t2 =
      2 * q_seed * std::pow(R_seed, 3) / (M_PI * A * r_seed * r_seed) - std::pow(R_seed / A, 4);
  const double seed_theta = std::atan(std::sqrt(t2));
  calibration::CameraPlacementOptions check;
  check.radius = R_seed;
  check.weight = q_seed;
  check.half_view_angle = seed_theta;
  const calibration::CameraPlacement seed_plan = calibration::PlanCameraPlacement(check);
  std::printf(
      "seed 001 reports 44.62 cm for R = 20 cm, q = 5 without stating its lens's view angle: eq. "
      "(33) puts the optimum there for theta = %.2f deg (beta = pi; planned with it: %.2f cm). "
      "The optimum moves with theta: a narrower view puts the camera farther away.\n",
      seed_theta / common::kDeg, seed_plan.found ? 100 * seed_plan.best_distance : NAN);
  if (!o.plot.empty()) {
    calibration::WriteBenefitPlot(o.plot, options, o.q);
    std::printf("wrote %s\n", o.plot.c_str());
  }
  return found > 0 ? kExitOk : kExitJobFailed;
}

void AddRigOptions(CLI::App* cmd, DiamondRigOptions* o) {
  cmd->add_option("--config", o->config,
                  "World config (world: diamond, simulated in this process, e.g. "
                  "config/diamond-sim.yaml) or deployment file (rig: diamond, the real robot or "
                  "a world in another process); default: the built-in simulated world with "
                  "config/diamond-sim.yaml's camera (docs/diamond-calibration.md)")
      ->check(CLI::ExistingFile);
}

void AddRecordOptions(CLI::App* cmd, DiamondRecordOptions* o) {
  o->stop_requested = StopRequested;  // Ctrl-C ends the recording between samples
  cmd->add_option("--samples", o->samples,
                  "Joint configurations to record, spread over the visible workspace")
      ->capture_default_str()
      ->check(CLI::Range(10, 2000));
  cmd->add_option("--speed", o->speed, "Mean task-space rate between configurations, rad/s")
      ->capture_default_str()
      ->check(CLI::Range(0.01, 2.0));
}

}  // namespace

// --- demo ---------------------------------------------------------------------------------------

DiamondDemoResult RunDiamondDemo(
    const std::string& out_dir, const std::function<void(bool ok, const std::string& what)>& expect,
    int samples) {
  DiamondDemoResult result;
  const common::Stopwatch t0;
  fs::create_directories(out_dir);
  DiamondRig rig(DiamondRigOptions{});
  char text[320];

  DiamondRecordOptions record;
  record.out = (fs::path(out_dir) / "diamond-dataset").string();
  if (fs::exists(record.out)) fs::remove_all(record.out);
  record.samples = samples;
  const DiamondRecordSummary recorded = RecordDiamondDataset(&rig, record);
  result.samples_recorded = recorded.recorded;
  result.dataset = record.out;
  expect(recorded.stopped.empty() && recorded.recorded == samples,
         "recorded " + std::to_string(recorded.recorded) +
             " configurations (marker image + joint readings over RS485) in " + record.out +
             (recorded.stopped.empty() ? "" : ": " + recorded.stopped));

  DiamondCalibrateOptions calibrate;
  calibrate.dataset = record.out;
  calibrate.out = (fs::path(out_dir) / "diamond_calib.yaml").string();
  const DiamondCalibrationRun run = CalibrateDiamondFromDataset(calibrate);
  result.calibration = calibrate.out;
  result.identified = run.identified;
  const calibration::DiamondIdentificationSummary& s = run.summary;
  std::snprintf(text, sizeof text,
                "identified R, alpha, beta, offsets and camera pose from %d marker detections "
                "(%s, rank %d of %d, condition %.0f)",
                run.detected, calibration::ToString(s.status), s.identifiability.rank,
                s.identifiability.parameters, s.identifiability.condition_number);
  expect(run.identified, text);
  const robots::DiamondModel& t = rig.world()->true_model();
  result.radius_error = s.model.radius / t.radius - 1;
  result.alpha_error = s.model.alpha / t.alpha - 1;
  result.beta_error = s.model.beta / t.beta - 1;
  std::snprintf(text, sizeof text,
                "R = %.4f m, alpha = %.4f, beta = %.4f rad from (0.2, pi/4, pi/4); errors "
                "against the truth %+.3f %%, %+.3f %%, %+.3f %% (target 0.2 %%)",
                s.model.radius, s.model.alpha, s.model.beta, 100 * result.radius_error,
                100 * result.alpha_error, 100 * result.beta_error);
  expect(std::max({std::abs(result.radius_error), std::abs(result.alpha_error),
                   std::abs(result.beta_error)}) < 0.002,
         text);

  // Straightness validation (seed Table III): the horizontal line straight in the top view, with
  // each parameter set in the controller; both paths measured by the camera with the identified
  // model (one measuring device), and the true path.
  DiamondServoOptions servo;
  const control::DiamondLine seed = control::DiamondLine::SeedHorizontal();
  servo.from = seed.from;
  servo.to = seed.to;
  servo.kind = control::DiamondLineKind::kTopViewLine;
  servo.measure_calib = calibrate.out;
  DiamondServoRun runs[2];
  for (int k = 0; k < 2; ++k) {
    servo.calib = k == 0 ? "" : calibrate.out;
    servo.log =
        (fs::path(out_dir) / (k == 0 ? "diamond_line_apriori.csv" : "diamond_line_identified.csv"))
            .string();
    (k == 0 ? result.log_apriori : result.log_identified) = servo.log;
    runs[k] = ServoDiamond(&rig, servo);
    std::snprintf(text, sizeof text,
                  "%s parameters: line followed (%s), straightness %.4f cm true / %.4f cm "
                  "measured (%d fixes), position RMS %.3f cm",
                  k == 0 ? "a-priori" : "identified", control::ToString(runs[k].report.outcome),
                  100 * runs[k].true_straightness, 100 * runs[k].measured_straightness,
                  runs[k].measured_points, 100 * runs[k].true_position_rms);
    expect(DiamondServoExitCode(runs[k]) == kExitOk && runs[k].measured_points >= 10, text);
  }
  result.straightness_apriori = runs[0].true_straightness;
  result.straightness_identified = runs[1].true_straightness;
  result.measured_apriori = runs[0].measured_straightness;
  result.measured_identified = runs[1].measured_straightness;
  result.position_apriori = runs[0].true_position_rms;
  result.position_identified = runs[1].true_position_rms;
  const double gain = result.straightness_apriori / std::max(1e-12, result.straightness_identified);
  std::snprintf(text, sizeof text,
                "straightness a priori -> identified: %.3f -> %.4f cm (x%.0f; seed 1.52 -> 0.59 "
                "cm; target x3), measured by the camera %.3f -> %.4f cm",
                100 * result.straightness_apriori, 100 * result.straightness_identified, gain,
                100 * result.measured_apriori, 100 * result.measured_identified);
  expect(gain >= 3.0, text);
  result.wall_seconds = t0.Seconds();
  return result;
}

void AddDiamondCommands(const Parents& parents, CommandList* commands) {
  CLI::App& calibrate = *parents.calibrate;
  CLI::App& servo = *parents.servo;
  // record diamond
  CLI::App* record = parents.record;
  auto ro = std::make_shared<RecordCommandOptions>();
  CLI::App* rd = record->add_subcommand(
      "diamond",
      "Move the DIAMOND through joint configurations spread over the workspace the camera sees "
      "(through its two RS485 drives) and record a marker image and the joint readings at each "
      "(a dataset directory, docs/diamond-calibration.md)");
  AddRigOptions(rd, &ro->rig);
  AddRecordOptions(rd, &ro->record);
  rd->add_option("--out", ro->record.out, "Dataset directory to create")->required();
  rd->footer(
      "Exit code 2 for a bad file or option, 3 when a drive or the camera fails (the dataset "
      "keeps the samples before), 1 when a move is stopped by the safety layer.");
  commands->push_back({rd, [ro] { return RunRecord(*ro); }});

  // calibrate diamond
  auto co = std::make_shared<CalibrateCommandOptions>();
  CLI::App* cd = calibrate.add_subcommand(
      "diamond",
      "Identify the DIAMOND's R, alpha, beta, joint offsets and camera pose from marker images "
      "(seed 001, Levenberg-Marquardt from the a-priori set 0.2 m, pi/4, pi/4): live (records "
      "--samples first) or from a recorded --dataset");
  AddRigOptions(cd, &co->rig);
  AddRecordOptions(cd, &co->record);
  cd->add_option("--dataset", co->calibrate.dataset,
                 "Calibrate from this recorded dataset instead of recording (no robot needed)")
      ->check(CLI::ExistingDirectory);
  cd->add_option("--record", co->record.out,
                 "Live: keep the recording in this directory (default: OUT-dataset beside --out)");
  cd->add_option("--out", co->calibrate.out,
                 "Calibration result YAML, also a robot description (docs/diamond-calibration.md)")
      ->capture_default_str();
  cd->add_option("--residual", co->calibrate.residual,
                 "pixel (re-projection, default) or spherical (the seed's (phi, gamma), eq. 6)")
      ->capture_default_str()
      ->check(CLI::IsMember({"pixel", "spherical"}));
  cd->add_option("--pixel-sigma", co->calibrate.pixel_sigma,
                 "A-priori marker noise, px (weights only: the covariance is re-scaled)")
      ->capture_default_str()
      ->check(CLI::Range(1e-3, 10.0));
  cd->add_flag("--free-distance", co->calibrate.estimate_camera_distance,
               "Also estimate the camera's distance from the RCM (the scale gauge: R then "
               "becomes unidentified and the command exits 1; for diagnosis)");
  cd->get_option("--dataset")->excludes("--record")->excludes("--config")->excludes("--samples");
  cd->footer(
      "Exit code 1 when the identification does not converge or a parameter is not identified "
      "(the report names it), 2 for a bad file or option, 3 when a drive or the camera fails "
      "while recording.");
  commands->push_back({cd, [co] { return RunCalibrate(*co); }});

  // servo diamond
  auto so = std::make_shared<ServoCommandOptions>();
  CLI::App* sd = servo.add_subcommand(
      "diamond",
      "Follow a line with the task-space PD (the seed's straightness validation, Table III) or "
      "servo the marker to a target with the image-based visual servo, through the two RS485 "
      "drives at a fixed rate");
  AddRigOptions(sd, &so->rig);
  sd->add_flag("--real-time", so->rig.real_time,
               "Simulated world only: run it in real time (steady clock), so that the printed "
               "loop rate and jitter are real (default: stepped simulated clock)");
  sd->add_option("--rt-priority", so->servo.rt_priority,
                 "SCHED_FIFO priority (1-99) of the control loop's thread during the run; needs "
                 "CAP_SYS_NICE or an rtprio limit, else reported as refused (default 0: normal)")
      ->check(CLI::Range(0, 99));
  sd->add_option("--rt-cpu", so->servo.rt_cpu,
                 "Pin the control loop's thread to this CPU during the run (default -1: any)")
      ->check(CLI::Range(-1, 1023));
  sd->add_option("--timer-slack-ns", so->servo.timer_slack_ns,
                 "Timer slack of the control loop's thread during the run (ns; default 1: wake "
                 "at the deadline; -1: the kernel's default, 50 us on Linux, 5 % of a period)")
      ->check(CLI::Range(-1L, 1000000000L));
  sd->add_flag("--rt-lock-memory", so->servo.rt_lock_memory,
               "mlockall the process during the run (no page faults in the loop)");
  sd->add_option("--calib", so->servo.calib,
                 "Calibration result (kinevis calibrate diamond): the controller's R, alpha, "
                 "beta, offsets and camera pose; default: the a-priori set and the config's "
                 "camera pose")
      ->check(CLI::ExistingFile);
  sd->add_option("--measure-calib", so->servo.measure_calib,
                 "Calibration that locates the detected marker for the measured path (default: "
                 "--calib, else the a-priori set)")
      ->check(CLI::ExistingFile);
  sd->add_option("--path", so->path, "Path to follow")
      ->capture_default_str()
      ->check(CLI::IsMember({"line"}));
  sd->add_option("--from", so->from_deg,
                 "Start (phi, gamma) in degrees: azimuth about the base "
                 "axis, polar angle from it")
      ->expected(2)
      ->delimiter(',')
      ->required();
  sd->add_option("--to", so->to_deg, "End (pd) or target (ibvs) (phi, gamma), degrees")
      ->expected(2)
      ->delimiter(',')
      ->required();
  sd->add_option("--law", so->law, "pd (task-space PD along the line) or ibvs (marker servo)")
      ->capture_default_str()
      ->check(CLI::IsMember({"pd", "ibvs"}));
  sd->add_option("--line", so->kind,
                 "pd: top-view (straight in the top view, the seed's measurement plane) or task "
                 "(straight in (phi, gamma): a meridian or a parallel)")
      ->capture_default_str()
      ->check(CLI::IsMember({"top-view", "task"}));
  sd->add_option("--duration", so->servo.duration_s, "pd: time along the line, s")
      ->capture_default_str()
      ->check(CLI::Range(0.2, 120.0));
  sd->add_option("--gain", so->servo.gain, "ibvs: gain lambda, 1/s")
      ->capture_default_str()
      ->check(CLI::Range(0.1, 50.0));
  sd->add_option("--speed", so->servo.approach_speed, "Mean rate of the move to --from, rad/s")
      ->capture_default_str()
      ->check(CLI::Range(0.01, 2.0));
  sd->add_option("--timeout", so->servo.timeout_s, "Give up the main run after this many s")
      ->capture_default_str()
      ->check(CLI::Range(0.5, 600.0));
  sd->add_option("--log", so->servo.log, "CSV log, one row per cycle (docs/diamond-control.md)");
  sd->footer(
      "Angles in degrees; (phi, gamma) as in robots/diamond/README.md; the seed's lines: "
      "--from 90,32 --to 90,83 (vertical), --from 60,45 --to 120,45 (horizontal). Exit code 0 "
      "when the line was followed and settled (pd) or the marker converged (ibvs), 1 on a lost "
      "marker, no convergence, a limit or a timeout, 2 for a bad file or option or a line "
      "outside the workspace, 3 on a drive fault, a lost link or a camera failure (both drives "
      "are stopped).");
  commands->push_back({sd, [so] { return RunServo(*so); }});

  // plan-camera diamond
  CLI::App* plan = parents.plan_camera;
  auto po = std::make_shared<PlanCameraOptions>();
  CLI::App* pd = plan->add_subcommand(
      "diamond",
      "The camera's best distance from the RCM by the seed's benefit function J = q S_ROI - "
      "S_waste (seed 001 eq. 29-33), and its plot (seed Fig. 5)");
  pd->add_option("--q", po->q,
                 "Weight(s) q of the ROI term, comma-separated (one table row each; all are "
                 "plotted)")
      ->capture_default_str()
      ->delimiter(',')
      ->check(CLI::PositiveNumber);
  pd->add_option("--R", po->radius, "Radius of the marker's sphere, m")
      ->capture_default_str()
      ->check(CLI::Range(0.001, 10.0));
  pd->add_option("--half-angle-deg", po->half_angle_deg,
                 "Lens half view angle, degrees (default: from --camera)")
      ->check(CLI::Range(0.5, 89.0));
  pd->add_option("--camera", po->camera,
                 "Camera model (builtin:NAME or a file) for the half view angle; default: the "
                 "simulated world's camera")
      ->capture_default_str();
  pd->add_option("--axis", po->axis,
                 "Which half-angle of the camera: vertical, horizontal, "
                 "diagonal or smallest")
      ->capture_default_str()
      ->check(CLI::IsMember({"vertical", "horizontal", "diagonal", "smallest"}));
  pd->add_option("--roi", po->roi,
                 "half (beta = pi, the seed's eq. 31-32) or quarter (beta = pi/2, its workspace)")
      ->capture_default_str()
      ->check(CLI::IsMember({"half", "quarter"}));
  pd->add_option("--plot", po->plot, "PNG of the benefit function against the distance");
  pd->get_option("--half-angle-deg")->excludes("--camera")->excludes("--axis");
  pd->footer("Exit code 1 when no weight has an interior maximum in 1.001 R .. 20 R.");
  commands->push_back({pd, [po] { return RunPlanCamera(*po); }});
}

}  // namespace kinevis::cli
