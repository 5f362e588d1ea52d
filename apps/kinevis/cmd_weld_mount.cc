// kinevis record scanner-mount | calibrate scanner-mount (issue 7, seed 004 §4): where the laser
// scanner sits on the weld arm (X_5C, the seed's A2S), from the gauge block standing on the board
// (rigs/weld/weld_rig.h: the simulated cell by default, or a deployment file).
//
//   record scanner-mount     the operator touches the block's faces, edges and corners and the
//                            board with the torch tip (simulated: WeldRig::OperatorTouch on the
//                            TRUE robot at the block's TRUE pose, what a person sees), then the
//                            robot carries the scanner to --views viewpoints aimed at the block's
//                            guessed pose (nominal robot and CAD mount: what the host knows); at
//                            each, a few rotating-laser angles with both lasers on: the stripes are
//                            extracted, the rotating laser's angle read from their crossing (eq.
//                            11) and the points triangulated (eq. 9, 10) into p_C. Written as a
//                            mount dataset (calibration/weld_mount/mount_dataset.h).
//   calibrate scanner-mount  CalibrateScannerMount (calibration/weld_mount/mount_calibration.h)
//                            from the CAD mount, optionally with the D–H errors (--dh); prints the
//                            mount with σ, the correction from CAD, residuals, identifiability,
//                            warnings, and on the simulated cell the error against the truth;
//                            writes the result YAML (mount_calibration_io.h).
//
// The jobs: rigs/weld/weld_calibration_jobs.h; the plan: calibration/weld_mount/mount_plan.h.

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>

#include "apps/kinevis/cli_common.h"
#include "apps/kinevis/commands.h"
#include "calibration/weld_mount/mount_calibration.h"
#include "calibration/weld_mount/mount_plan.h"
#include "common/units.h"
#include "rigs/weld/weld_calibration_jobs.h"
#include "rigs/weld/weld_rig.h"

namespace kinevis::cli {

using rigs::WeldRig;
namespace {

namespace fs = std::filesystem;
constexpr int kMaxViews = calibration::kMaxMountViews;

struct MountRecordOptions {
  std::string config;
  std::string scanner;  // scanner calibration YAML; empty: the world config's scanner geometry
  std::string out;
  int views = 7;
  double touch_sigma_mm = 0.05;
  std::string laser_angle = "commanded";  // or "crossing" (eq. 11)
  bool fixed_laser = true;                // also the fixed laser's stripe, once per viewpoint
};

struct MountCalibrateOptions {
  std::string config;
  std::string scanner;
  std::string record;  // with the cell: where to record first; default a temporary directory
  std::string dataset;
  int views = 7;
  std::string laser_angle = "commanded";
  bool fixed_laser = true;
  bool use_fixed_laser = false;
  bool dh = false;
  double touch_sigma_mm = 0.1;
  double scan_sigma_mm = 0.1;
  std::string out = "mount_calib.yaml";
};

std::string Vec(const Eigen::Vector3d& v, double scale, const char* format = "%.3f") {
  std::string s = "[";
  for (int i = 0; i < 3; ++i) {
    char b[32];
    std::snprintf(b, sizeof b, format, scale * v(i));
    s += (i ? ", " : "") + std::string(b);
  }
  return s + "]";
}

Eigen::Vector3d Rpy(const Eigen::Matrix3d& R) {
  return {std::atan2(R(2, 1), R(2, 2)), std::asin(std::clamp(-R(2, 0), -1.0, 1.0)),
          std::atan2(R(1, 0), R(0, 0))};
}

void PrintRecordReport(const rigs::MountRecordReport& r, int views, const std::string& out) {
  std::printf("recorded %d touches and %d scans (%d stripe points) from %d views into %s\n",
              r.touches, r.scans, r.points, views, out.c_str());
  std::printf("  stripe points triangulated with %s\n", r.scanner.c_str());
  for (const std::string& f : r.unreachable) {
    std::printf("  unreachable touch: %s (no torch approach reaches it)\n", f.c_str());
  }
  for (const std::string& s : r.skipped) std::printf("  skipped: %s\n", s.c_str());
  if (!r.eq11_deviation.empty()) {
    double sum2 = 0.0, worst = 0.0;
    for (const double e : r.eq11_deviation) {
      sum2 += e * e;
      worst = std::max(worst, std::abs(e));
    }
    std::printf(
        "  rotating laser angle: %s; eq. 11 (stripe crossing) minus commanded cot theta_y: rms "
        "%.2g, max %.2g over %zu images (1e-3 is ~1.6 mm of depth at 0.4 m)\n",
        r.laser_angle == rigs::LaserAngleSource::kCommanded ? "the commanded stepper angle"
                                                            : "eq. 11 from the stripes' crossing",
        std::sqrt(sum2 / r.eq11_deviation.size()), worst, r.eq11_deviation.size());
  }
}

rigs::MountRecordOptions RecordJob(const std::string& scanner, const std::string& out, int views,
                                   double touch_sigma_mm, const std::string& laser_angle,
                                   bool fixed_laser) {
  rigs::MountRecordOptions r;
  r.scanner = scanner;
  r.out = out;
  r.views = views;
  r.touch_sigma = touch_sigma_mm / common::kMmPerM;
  r.laser_angle = laser_angle == "crossing" ? rigs::LaserAngleSource::kCrossing
                                            : rigs::LaserAngleSource::kCommanded;
  r.fixed_laser = fixed_laser;
  r.stop_requested = StopRequested;
  return r;
}

int RunRecordScannerMount(const MountRecordOptions& o) {
  const std::unique_ptr<WeldRig> rig = rigs::OpenGaugeBlockRig(o.config);
  const rigs::MountRecordReport r = rigs::RecordMountDataset(
      rig.get(),
      RecordJob(o.scanner, o.out, o.views, o.touch_sigma_mm, o.laser_angle, o.fixed_laser));
  PrintRecordReport(r, o.views, o.out);
  return r.touches > 0 && r.scans > 0 ? kExitOk : kExitJobFailed;
}

void PrintSummary(const calibration::MountCalibrationSummary& s,
                  const calibration::MountCalibrationData& data) {
  std::printf("  status: %s (%s, %d iterations, sigma ratio %.3f)\n", ToString(s.status),
              s.converged ? "converged" : "not converged", s.iterations, s.sigma_ratio);
  const Eigen::Matrix<double, 6, 6>& C = s.mount_covariance;
  Eigen::Vector3d sr, sp;
  for (int i = 0; i < 3; ++i) {
    sr(i) = std::sqrt(C(i, i));
    sp(i) = std::sqrt(C(3 + i, 3 + i));
  }
  std::printf("  mount X_5C: position %s mm +- %s mm\n",
              Vec(s.X_5C.translation(), common::kMmPerM).c_str(),
              Vec(sp, common::kMmPerM, "%.4f").c_str());
  std::printf("              rpy %s deg +- %s deg (about the camera axes)\n",
              Vec(Rpy(s.X_5C.linear()), common::kDegPerRad, "%.4f").c_str(),
              Vec(sr, common::kDegPerRad, "%.4f").c_str());
  std::printf("              1-sigma (largest direction): %.4f mm, %.4f deg\n",
              common::kMmPerM * s.mount_position_std, common::kDegPerRad * s.mount_angle_std);
  const Eigen::Vector3d dp = s.X_5C.translation() - data.X_5C_guess.translation();
  const Eigen::AngleAxisd dR(data.X_5C_guess.linear().transpose() * s.X_5C.linear());
  std::printf("  correction from the CAD mount: %s mm (%.3f mm), rotation %s deg (%.3f deg)\n",
              Vec(dp, common::kMmPerM).c_str(), common::kMmPerM * dp.norm(),
              Vec(Eigen::Vector3d(dR.angle() * dR.axis()), common::kDegPerRad).c_str(),
              common::kDegPerRad * dR.angle());
  std::printf(
      "  block X_0B: position %s mm, rpy %s deg (%.2f mm, %.2f deg from the guess)\n",
      Vec(s.X_0B.translation(), common::kMmPerM, "%.2f").c_str(),
      Vec(Rpy(s.X_0B.linear()), common::kDegPerRad, "%.2f").c_str(),
      common::kMmPerM * (s.X_0B.translation() - data.X_0B_guess.translation()).norm(),
      common::kDegPerRad *
          Eigen::AngleAxisd(data.X_0B_guess.linear().transpose() * s.X_0B.linear()).angle());
  std::printf(
      "  residuals: touches %d, rms %.4f mm, median %.4f mm, max %.4f mm, %d beyond k sigma\n",
      s.touch.count, common::kMmPerM * s.touch.rms, common::kMmPerM * s.touch.median,
      common::kMmPerM * s.touch.max, s.touch.beyond_k);
  std::printf(
      "             scan points %d, rms %.4f mm, median %.4f mm, max %.4f mm, %d beyond k sigma\n",
      s.scan.count, common::kMmPerM * s.scan.rms, common::kMmPerM * s.scan.median,
      common::kMmPerM * s.scan.max, s.scan.beyond_k);
  std::printf("  identifiability: rank %d of %zu parameters, condition number %.4g\n", s.rank,
              s.parameter_names.size(), s.condition_number);
  for (const std::string& u : s.unidentified) std::printf("    unidentified: %s\n", u.c_str());
  if (s.parameter_names.size() > 12) {
    std::printf("  D-H errors (estimated):");
    int shown = 0;
    for (size_t i = 12; i < s.parameter_names.size(); ++i) {
      if (!s.estimated[i]) continue;
      const std::string& n = s.parameter_names[i];
      const bool angle = n.rfind("alpha", 0) == 0 || n.rfind("theta", 0) == 0;
      const double k = angle ? common::kDegPerRad : common::kMmPerM;
      std::printf("%s %s %+.4f +- %.4f %s", shown++ % 4 == 0 ? "\n   " : ",", n.c_str(),
                  k * s.correction(static_cast<long>(i)), k * s.std_dev(static_cast<long>(i)),
                  angle ? "deg" : "mm");
    }
    std::printf("\n");
    std::string fixed;
    for (const std::string& f : s.fixed_dh) fixed += (fixed.empty() ? "" : ", ") + f;
    std::printf("  D-H errors held at nominal: %s\n", fixed.empty() ? "none" : fixed.c_str());
  }
  std::printf("  estimation: %s\n", s.estimation.BriefReport().c_str());
  for (const std::string& w : s.warnings) std::printf("  warning: %s\n", w.c_str());
}

int RunCalibrateScannerMount(const MountCalibrateOptions& o) {
  std::string dataset_dir = o.dataset;
  std::unique_ptr<WeldRig> rig;
  if (dataset_dir.empty()) {
    rig = rigs::OpenGaugeBlockRig(o.config);
    std::string out = o.record;
    if (out.empty()) {
      out = (fs::temp_directory_path() / ("kinevis-scanner-mount-" + std::to_string(::getpid())))
                .string();
      fs::remove_all(out);
    }
    // The recording's touch error is the simulated operator's default (0.05 mm), not the
    // calibration's residual scale.
    const rigs::MountRecordReport report = rigs::RecordMountDataset(
        rig.get(), RecordJob(o.scanner, out, o.views, MountRecordOptions().touch_sigma_mm,
                             o.laser_angle, o.fixed_laser));
    PrintRecordReport(report, o.views, out);
    dataset_dir = out;
  }
  rigs::MountCalibrateOptions options;
  options.estimate_dh = o.dh;
  options.use_fixed_laser = o.use_fixed_laser;
  options.touch_sigma = o.touch_sigma_mm / common::kMmPerM;
  options.scan_sigma = o.scan_sigma_mm / common::kMmPerM;
  options.out = o.out;
  const rigs::MountCalibrationRun run =
      rigs::CalibrateScannerMountFromDataset(dataset_dir, options, rig.get());
  const calibration::MountCalibrationData& data = run.data;
  if (!run.calibrated) {
    std::printf("scanner mount calibration from %s: %zu touches, %zu scans: nothing to calibrate\n",
                dataset_dir.c_str(), data.touches.size(), data.scans.size());
    return kExitJobFailed;
  }
  const calibration::MountCalibrationSummary& s = run.summary;
  std::printf(
      "scanner mount calibration from %s: %zu touches, %zu scans (%zu stripe points), D-H errors "
      "%s (%.1f s)\n",
      dataset_dir.c_str(), data.touches.size(), data.scans.size(), run.points,
      o.dh ? "estimated" : "not estimated", run.wall_seconds);
  std::printf("  scanner: %s\n", run.dataset.scanner.c_str());
  if (run.fixed_left_out > 0) {
    std::printf(
        "  fixed-laser scans left out: %zu (eq. 10's short base b_x' makes their depth ~15x less "
        "precise; --use-fixed-laser to use them)\n",
        run.fixed_left_out);
  }
  PrintSummary(s, data);
  if (run.has_truth) {
    const rigs::MountTruthComparison& t = run.truth;
    std::printf(
        "  simulation truth: mount error %.4f mm %s, %.4f deg (the CAD mount was %.3f mm, %.3f "
        "deg off); block error %.4f mm, %.4f deg\n",
        common::kMmPerM * t.position_error.norm(),
        Vec(t.position_error, common::kMmPerM, "%+.4f").c_str(), common::kDegPerRad * t.angle_error,
        common::kMmPerM * t.cad_position_error, common::kDegPerRad * t.cad_angle_error,
        common::kMmPerM * t.block_position_error, common::kDegPerRad * t.block_angle_error);
    if (o.dh) {
      std::printf(
          "    (with --dh the block's pose takes up the D-H errors held at nominal, d1 and theta1 "
          "among them: its error is not a measure of the calibration)\n");
    }
  }
  std::printf("wrote %s\n", o.out.c_str());
  return s.ok() ? kExitOk : kExitJobFailed;
}

}  // namespace

void AddWeldMountCommands(const Parents& parents, CommandList* commands) {
  CLI::App& calibrate = *parents.calibrate;
  CLI::App* record = parents.record;
  auto ro = std::make_shared<MountRecordOptions>();
  CLI::App* rs = record->add_subcommand(
      "scanner-mount",
      "Record a scanner-mount calibration dataset on the gauge block: torch touches on its faces, "
      "edges and corners, and scans from several wrist orientations (simulated cell; "
      "docs/scanner-mount-calibration.md)");
  rs->add_option("--config", ro->config,
                 "Weld-cell world config (config/weld-cell-sim.yaml; default: built-in defaults). "
                 "A board workpiece keeps its gauge-block placement, any other gets the default "
                 "board with the block")
      ->check(CLI::ExistingFile);
  rs->add_option("--scanner", ro->scanner,
                 "Scanner calibration YAML to triangulate the stripes with (kinevis calibrate "
                 "scanner; default: the world config's scanner geometry)")
      ->check(CLI::ExistingFile);
  rs->add_option("--out", ro->out, "Dataset directory to create")->required();
  rs->add_option("--views", ro->views,
                 "Scanner viewpoints (1-12, default 7), each with 3 rotating-laser angles and the "
                 "fixed laser")
      ->check(CLI::Range(1, kMaxViews));
  rs->add_option("--touch-sigma-mm", ro->touch_sigma_mm,
                 "Simulated operator's touch error, mm per axis (default 0.05)")
      ->check(CLI::Range(0.0, 5.0));
  rs->add_option("--laser-angle", ro->laser_angle,
                 "Rotating laser's angle per image: commanded (the stepper angle the host set) or "
                 "crossing (eq. 11 from the stripes' intersection; default commanded)")
      ->check(CLI::IsMember({"commanded", "crossing"}));
  rs->add_flag("!--no-fixed-laser", ro->fixed_laser,
               "Leave out the fixed laser's stripe (default: one fixed-laser scan per view)");
  commands->push_back({rs, [ro] { return RunRecordScannerMount(*ro); }});

  auto co = std::make_shared<MountCalibrateOptions>();
  CLI::App* cs = calibrate.add_subcommand(
      "scanner-mount",
      "Scanner-mount calibration (seed 004 section 4): the scanner camera's pose X_5C on link 5 "
      "from gauge-block touches and scans, optionally with the D-H errors; from a dataset or "
      "recorded on the cell first. Exit 1 when the mount is not identified or not converged");
  cs->add_option("--config", co->config,
                 "Weld-cell world config to record on (default: the built-in simulated cell)")
      ->check(CLI::ExistingFile);
  cs->add_option("--scanner", co->scanner,
                 "With the cell: scanner calibration YAML for the stripes (default: the world "
                 "config's scanner geometry)")
      ->check(CLI::ExistingFile);
  cs->add_option("--dataset", co->dataset,
                 "Calibrate from this recorded dataset directory (kinevis record scanner-mount)")
      ->check(CLI::ExistingDirectory);
  cs->add_option("--record", co->record,
                 "With the cell: keep the recorded dataset in this directory (default: a "
                 "temporary one)");
  cs->add_option("--views", co->views,
                 "With the cell: scanner viewpoints to record (1-12, "
                 "default 7)")
      ->check(CLI::Range(1, kMaxViews));
  cs->add_option("--laser-angle", co->laser_angle,
                 "With the cell: rotating laser's angle per image, commanded or crossing (eq. 11; "
                 "default commanded)")
      ->check(CLI::IsMember({"commanded", "crossing"}));
  cs->add_flag("!--no-fixed-laser", co->fixed_laser,
               "With the cell: leave out the fixed laser's stripe");
  cs->add_flag("--use-fixed-laser", co->use_fixed_laser,
               "Also use the fixed laser's scans (default: rotating-laser scans only; the fixed "
               "laser's short base makes its depth ~15x less precise)");
  cs->add_flag("--dh", co->dh,
               "Also estimate the D-H errors of the arm (seed eq. 48); those the data cannot "
               "separate from the mount and the block are held at nominal and named");
  cs->add_option("--touch-sigma-mm", co->touch_sigma_mm,
                 "Touch measurement sigma, mm per axis (residual scale; default 0.1)")
      ->check(CLI::Range(0.001, 10.0));
  cs->add_option("--scan-sigma-mm", co->scan_sigma_mm,
                 "Scan point sigma, mm per axis (residual scale; default 0.1)")
      ->check(CLI::Range(0.001, 10.0));
  cs->add_option("--out", co->out,
                 "Result YAML (default mount_calib.yaml; docs/scanner-mount-calibration.md)");
  cs->get_option("--dataset")
      ->excludes("--config")
      ->excludes("--record")
      ->excludes("--scanner")
      ->excludes("--views")
      ->excludes("--laser-angle")
      ->excludes("--no-fixed-laser");
  commands->push_back({cs, [co] { return RunCalibrateScannerMount(*co); }});
}

}  // namespace kinevis::cli
