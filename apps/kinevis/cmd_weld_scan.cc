// kinevis scan | record scan | weld-path | weld-run (issue 7, seed 004): the weld-repair chain on
// the weld cell (rigs/weld/weld_rig.h: the simulated cell by default, or a deployment file).
//
//   scan        the scanner sweeps its rotating laser over the workpiece from where the robot
//               stands (or --at): per image, the stripes (vision/laser/laser_stripes.h), the laser
//               angle from their crossing (eq. 11) and the rotating stripe's points (eq. 9)
//               (vision/laser/scan_lines.h); with the joint readings, into the robot base frame
//               with the scanner mount (eq. 51-55, calibration/weld_mount/scan_cloud.h); written
//               as binary PLY with normals + YAML sidecar (docs/point-clouds.md). On the simulated
//               cell also the map's error against the true surface.
//   record scan the images and joints of that sweep as a dataset (scan --dataset rebuilds the
//               map from it, e.g. with another calibration).
//   weld-path   the map to a weld plan (control/weld/weld_planner.h), YAML + top view + section.
//   weld-run    streams a plan's joint trajectory to the robot over Modbus with flow control,
//               arc on for the arc-on segments; on an alarm or a lost link the driver stops the
//               robot with the arc off. On the simulated cell, the executed path against the plan
//               and the true surface: stand-off error along the path.
//
// The jobs: rigs/weld/weld_repair_jobs.h; this file parses, binds, calls and prints.

#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "apps/kinevis/cli_common.h"
#include "apps/kinevis/commands.h"
#include "common/units.h"
#include "control/weld/weld_plan_io.h"
#include "control/weld/weld_planner.h"
#include "rigs/weld/weld_repair_jobs.h"
#include "rigs/weld/weld_rig.h"

namespace kinevis::cli {

using rigs::WeldRig;
using rigs::WeldRigOptions;
using rigs::WeldWorkpiece;
namespace {

// "θ1,θ2,pz3,θ4,θ5" in deg, deg, mm, deg, deg.
robots::Vector5d ParseJoints(const std::string& text, const char* option) {
  std::stringstream in(text);
  std::vector<double> v;
  for (std::string f; std::getline(in, f, ',');) {
    char* end = nullptr;
    const double x = std::strtod(f.c_str(), &end);
    if (f.empty() || end != f.c_str() + f.size() || !std::isfinite(x)) {
      throw std::invalid_argument(std::string(option) + " \"" + text + "\": \"" + f +
                                  "\" is not a number");
    }
    v.push_back(x);
  }
  if (v.size() != 5) {
    throw std::invalid_argument(std::string(option) + " \"" + text +
                                "\": need 5 values theta1,theta2,pz3,theta4,theta5 (deg, deg, "
                                "mm, deg, deg), got " +
                                std::to_string(v.size()));
  }
  robots::Vector5d q;
  q << v[0] * common::kDeg, v[1] * common::kDeg, v[2] * 1e-3, v[3] * common::kDeg,
      v[4] * common::kDeg;
  return q;
}

struct ScanOptions {
  std::string config;
  std::string at;  // joints to scan from; empty: where the robot stands
  rigs::ScanJobOptions job;
};

rigs::ScanJobOptions Job(const ScanOptions& o) {
  rigs::ScanJobOptions job = o.job;
  if (!o.at.empty()) job.at = ParseJoints(o.at, "--at");
  job.stop_requested = StopRequested;
  return job;
}

int RunScan(const ScanOptions& o) {
  const rigs::ScanJobOptions job = Job(o);
  std::unique_ptr<WeldRig> rig;
  if (job.dataset.empty()) {
    WeldRigOptions ro;
    ro.config = o.config;
    ro.workpiece = WeldWorkpiece::kFromConfig;
    rig = std::make_unique<WeldRig>(ro);
  }
  const rigs::ScanJobReport r = rigs::ScanWorkpiece(rig.get(), job);
  const rigs::ScanFrames& frames = r.frames;
  if (frames.lines.empty()) {
    std::printf("scan: no usable frame of %d (%s)\n", frames.frames, frames.first_failure.c_str());
    return kExitJobFailed;
  }
  std::printf("scan: %d frames, %zu scan lines, %zu points (%.1f s)\n", frames.frames,
              frames.lines.size(), r.points, r.wall_seconds);
  std::printf("  scanner: %s\n  mount: %s\n", r.scanner_source.c_str(), r.mount_source.c_str());
  if (frames.failed > 0) {
    std::printf("  %d frames without a usable line; first: %s\n", frames.failed,
                frames.first_failure.c_str());
  }
  std::printf("  normals: %zu estimated, %zu missing\n", r.normals_estimated, r.normals_missing);
  if (rig && rig->simulated()) {
    std::printf("  laser angle: eq. 11 vs commanded stepper, max |d cot theta_y| %.5f\n",
                frames.max_angle_deviation);
  }
  if (r.has_truth) {
    std::printf("  simulation truth: map vs true surface: mean %.3f mm, rms %.3f mm, max %.3f mm\n",
                1e3 * r.truth_mean_error, 1e3 * r.truth_rms_error, 1e3 * r.truth_max_error);
  }
  std::printf("wrote %s and %s\n", r.ply_path.c_str(), r.sidecar_path.c_str());
  return kExitOk;
}

int RunRecordScan(const ScanOptions& o) {
  rigs::ScanJobOptions job = Job(o);
  job.record = job.out;
  std::string scanner_source;
  const vision::laser::ScannerGeometry geometry =
      rigs::LoadScannerGeometry(job.scanner, &scanner_source);
  WeldRigOptions ro;
  ro.config = o.config;
  WeldRig rig(ro);
  const vision::laser::ScannerModel model(rig.camera_model(), geometry);
  const rigs::ScanFrames frames = rigs::SweepScanner(&rig, model, job);
  std::printf("recorded %d frames into %s (%d without a usable line)\n", frames.frames,
              job.out.c_str(), frames.failed);
  return kExitOk;
}

struct WeldPathOptions {
  std::string map;
  std::string out = "weld_path.yaml";
  std::string top;
  std::string section;
  double bead_width_mm = 6.0;
  double overlap = 0.4;
  double layer_height_mm = 1.5;
  double stand_off_mm = 15.0;
  double travel_speed_mm_s = 8.0;
  double margin_mm = 3.0;
  double depth_threshold_mm = 0.5;
  double grid_cell_mm = 1.0;
  std::string pattern = "raster";
};

int RunWeldPath(const WeldPathOptions& o) {
  control::WeldPlanOptions options;
  options.bead_width = 1e-3 * o.bead_width_mm;
  options.overlap = o.overlap;
  options.layer_height = 1e-3 * o.layer_height_mm;
  options.stand_off = 1e-3 * o.stand_off_mm;
  options.travel_speed = 1e-3 * o.travel_speed_mm_s;
  options.margin = 1e-3 * o.margin_mm;
  options.depth_threshold = 1e-3 * o.depth_threshold_mm;
  options.grid_cell = 1e-3 * o.grid_cell_mm;
  if (o.pattern == "raster") {
    options.pattern = control::BeadPattern::kRaster;
  } else if (o.pattern == "zigzag") {
    options.pattern = control::BeadPattern::kZigZag;
  } else {
    throw std::invalid_argument("--pattern \"" + o.pattern + "\": raster or zigzag");
  }
  const rigs::WeldPathRun run = rigs::PlanWeldPath(o.map, options, o.out, o.top, o.section);
  const control::WeldPlan& plan = run.plan;
  const double wall = run.wall_seconds;
  const control::WeldPlanSummary& s = plan.summary;
  std::printf("weld-path: %s from %zu points (%.2f s)\n", control::ToString(s.status), s.map_points,
              wall);
  std::printf(
      "  %d damaged regions (%.1f mm^2), %d rejected; %d layers, %d beads (%d executable)\n",
      s.regions, 1e6 * s.damaged_area, s.rejected_regions, s.layers, s.beads, s.executable_beads);
  std::printf(
      "  coverage %.1f %% (executable beads %.1f %%); weld length %.1f mm, arc %.1f s, "
      "total %.1f s\n",
      100.0 * s.coverage, 100.0 * s.coverage_executable, 1e3 * s.weld_length, s.arc_time,
      s.total_time);
  std::printf(
      "  torch tilt max %.2f deg, mean %.2f deg; %d unreachable points; max joint speed "
      "%.0f %% of the limit\n",
      s.max_tilt / common::kDeg, s.mean_tilt / common::kDeg, s.unreachable_points,
      100.0 * s.max_joint_speed_ratio);
  for (const control::WeldRegionPlan& r : plan.regions) {
    std::printf(
        "  region %d: %.1f mm^2, max depth %.2f mm, %zu layers%s\n", r.region.id,
        1e6 * r.region.area, 1e3 * r.region.max_depth, r.layers.size(),
        r.region.touches_map_edge ? " (touches the map's edge: may continue beyond it)" : "");
  }
  for (const std::string& w : s.warnings) std::printf("  warning: %s\n", w.c_str());
  std::printf("wrote %s", o.out.c_str());
  if (!run.top.empty()) std::printf(", %s, %s", run.top.c_str(), run.section.c_str());
  std::printf("\n");
  switch (s.status) {
    case control::WeldPlanStatus::kPlanned:
    case control::WeldPlanStatus::kNothingToRepair:
      return kExitOk;
    default:
      return kExitJobFailed;
  }
}

struct WeldRunOptions {
  std::string plan;
  std::string config;
  bool no_arc = false;
  std::string log;
};

int RunWeldRun(const WeldRunOptions& o) {
  const control::WeldPlanFile file = control::ReadWeldPlan(o.plan);
  if (file.plan.trajectory.empty()) {
    std::printf("weld-run: %s has no trajectory (%s)\n", o.plan.c_str(),
                control::ToString(file.plan.summary.status));
    return kExitJobFailed;
  }
  WeldRigOptions ro;
  ro.config = o.config;
  WeldRig rig(ro);
  rigs::WeldRunOptions job;
  job.arc = !o.no_arc;
  job.stop_requested = StopRequested;  // Ctrl-C: the driver stops the robot, arc off
  const rigs::WeldRunReport r = rigs::RunWeldPlan(&rig, file.plan, job);
  switch (r.outcome) {
    case rigs::WeldRunOutcome::kNoTrajectory:
      std::printf("weld-run: %s: %s\n", o.plan.c_str(), r.message.c_str());
      return kExitJobFailed;
    case rigs::WeldRunOutcome::kStartNotReached:
    case rigs::WeldRunOutcome::kWeldParameters:
    case rigs::WeldRunOutcome::kArcOnFailed:
      std::printf("weld-run: %s\n", r.message.c_str());
      return kExitHardware;
    default:
      break;
  }
  const hal::WeldStreamReport& report = r.stream;
  std::printf(
      "weld-run: %zu of %zu segments executed in %.1f s, highest buffer level %d, %llu "
      "waits\n",
      report.executed, report.total, std::chrono::duration<double>(report.elapsed).count(),
      report.max_buffer_level, static_cast<unsigned long long>(report.buffer_full_waits));
  if (r.outcome != rigs::WeldRunOutcome::kCompleted) {
    std::printf("weld-run: stopped: %s; safe state (motion stopped, arc off) %s\n",
                report.message.c_str(),
                report.safe_state_confirmed ? "confirmed" : "NOT confirmed");
    return r.outcome == rigs::WeldRunOutcome::kCancelled ? kExitJobFailed : kExitHardware;
  }
  if (!r.arc_off_error.empty()) std::printf("weld-run: arc off: %s\n", r.arc_off_error.c_str());
  if (r.has_truth) {
    const control::StandOffComparison& c = r.planned_surface;
    std::printf(
        "  stand-off vs the planned surface (true robot): mean |e| %.3f mm, rms %.3f mm, "
        "max %.3f mm over %.1f mm of arc-on path (%zu samples)\n",
        1e3 * c.mean_abs_error, 1e3 * c.rms_error, 1e3 * c.max_abs_error, 1e3 * c.path_length,
        c.samples.size());
    if (r.true_surface_points > 0) {
      std::printf(
          "  simulation truth: stand-off vs the true surface, bottom layer: mean |e| %.3f "
          "mm, rms %.3f mm, max %.3f mm over %d points (%.1f mm of arc-on path)\n",
          1e3 * r.true_surface_mean_abs, 1e3 * r.true_surface_rms, 1e3 * r.true_surface_max,
          r.true_surface_points, 1e3 * r.true_surface_path);
    }
    if (!o.log.empty()) {
      std::ofstream log(o.log);
      log << "trajectory_index,path_mm,stand_off_mm,error_mm,axis_error_deg\n";
      for (const control::StandOffSample& s : c.samples) {
        log << s.trajectory_index << "," << 1e3 * s.path_position << "," << 1e3 * s.stand_off << ","
            << 1e3 * s.error << "," << s.axis_error / common::kDeg << "\n";
      }
      if (!log) throw std::runtime_error("cannot write " + o.log);
      std::printf("wrote %s\n", o.log.c_str());
    }
  }
  return kExitOk;
}

}  // namespace

void AddWeldScanCommands(const Parents& parents, CommandList* commands) {
  CLI::App& app = *parents.app;
  CLI::App* record = parents.record;
  auto add_scan_options = [](CLI::App* c, ScanOptions* o) {
    c->add_option("--config", o->config,
                  "Weld-cell world config or deployment file (default: the built-in simulated "
                  "cell)")
        ->check(CLI::ExistingFile);
    c->add_option("--scanner", o->job.scanner,
                  "Scanner calibration YAML (kinevis calibrate scanner; default: the nominal "
                  "geometry of seed 004 Table 2)")
        ->check(CLI::ExistingFile);
    c->add_option("--mount", o->job.mount,
                  "Scanner-mount calibration YAML (kinevis calibrate scanner-mount; default: the "
                  "nominal CAD mount). With --dh there, its D-H errors too")
        ->check(CLI::ExistingFile);
    c->add_option("--at", o->at,
                  "Move here first: theta1,theta2,pz3,theta4,theta5 in deg, deg, mm, deg, deg "
                  "(default: scan from where the robot stands)");
    c->add_option("--lines", o->job.lines, "Frames in the sweep (2-2000)")
        ->check(CLI::Range(2, 2000))
        ->capture_default_str();
    c->add_option("--depth", o->job.depth,
                  "Expected camera-to-surface distance, m: the simulated stepper's sweep puts the "
                  "stripe from 5 % to 95 % of the image height there (0.1-2)")
        ->check(CLI::Range(0.1, 2.0))
        ->capture_default_str();
  };
  auto so = std::make_shared<ScanOptions>();
  CLI::App* scan = app.add_subcommand(
      "scan",
      "Scan the workpiece with the laser scanner into a point cloud in the robot base frame "
      "(binary PLY with normals + YAML sidecar; docs/point-clouds.md)");
  add_scan_options(scan, so.get());
  scan->add_option("--dataset", so->job.dataset, "Rebuild the map from a recorded scan dataset")
      ->check(CLI::ExistingDirectory);
  scan->add_option("--record", so->job.record, "Also keep the frames as a scan dataset here");
  scan->add_option("--out", so->job.out, "The map: X.ply and its sidecar X.yaml")
      ->capture_default_str();
  scan->get_option("--dataset")->excludes("--config")->excludes("--record")->excludes("--at");
  commands->push_back({scan, [so] { return RunScan(*so); }});

  auto rso = std::make_shared<ScanOptions>();
  CLI::App* rs = record->add_subcommand(
      "scan",
      "Record a laser sweep (images + joint readings) as a scan dataset (docs/point-clouds.md)");
  add_scan_options(rs, rso.get());
  rs->add_option("--out", rso->job.out, "Dataset directory to create")->required();
  commands->push_back({rs, [rso] { return RunRecordScan(*rso); }});

  auto po = std::make_shared<WeldPathOptions>();
  CLI::App* wp = app.add_subcommand(
      "weld-path",
      "Plan the weld repair of a scanned map: damaged regions, layers, beads, torch IK; YAML plan "
      "+ top view + section PNGs (docs/weld-paths.md)");
  wp->add_option("--map", po->map, "The scanned map (X.ply with its sidecar X.yaml)")
      ->required()
      ->check(CLI::ExistingFile);
  wp->add_option("--out", po->out, "The plan YAML")->capture_default_str();
  wp->add_option("--top", po->top, "Top-view PNG (default: OUT_top.png)");
  wp->add_option("--section", po->section, "Section PNG (default: OUT_section.png)");
  wp->add_option("--bead-width-mm", po->bead_width_mm, "Bead width, mm (1-30)")
      ->check(CLI::Range(1.0, 30.0))
      ->capture_default_str();
  wp->add_option("--overlap", po->overlap, "Overlap of neighbouring passes, fraction (0-0.8)")
      ->check(CLI::Range(0.0, 0.8))
      ->capture_default_str();
  wp->add_option("--layer-height-mm", po->layer_height_mm, "Layer height, mm (0.2-10)")
      ->check(CLI::Range(0.2, 10.0))
      ->capture_default_str();
  wp->add_option("--stand-off-mm", po->stand_off_mm, "Contact-tip-to-work distance, mm (3-40)")
      ->check(CLI::Range(3.0, 40.0))
      ->capture_default_str();
  wp->add_option("--travel-speed-mm-s", po->travel_speed_mm_s, "Welding speed, mm/s (1-30)")
      ->check(CLI::Range(1.0, 30.0))
      ->capture_default_str();
  wp->add_option("--margin-mm", po->margin_mm, "Extension beyond the damage, mm (0-50)")
      ->check(CLI::Range(0.0, 50.0))
      ->capture_default_str();
  wp->add_option("--depth-threshold-mm", po->depth_threshold_mm,
                 "Depth below the reference that counts as damage, mm (0.05-10)")
      ->check(CLI::Range(0.05, 10.0))
      ->capture_default_str();
  wp->add_option("--grid-cell-mm", po->grid_cell_mm,
                 "Depth-grid cell, mm (0.05-5): at least the scan-line spacing, or the map has "
                 "empty rows that split the damage")
      ->check(CLI::Range(0.05, 5.0))
      ->capture_default_str();
  wp->add_option("--pattern", po->pattern, "raster or zigzag")->capture_default_str();
  commands->push_back({wp, [po] { return RunWeldPath(*po); }});

  auto ro = std::make_shared<WeldRunOptions>();
  CLI::App* wr = app.add_subcommand(
      "weld-run",
      "Stream a weld plan's joint trajectory to the weld robot over Modbus (flow control, arc on "
      "for the arc-on segments; stops with the arc off on an alarm or a lost link)");
  wr->add_option("plan", ro->plan, "The plan YAML (kinevis weld-path)")
      ->required()
      ->check(CLI::ExistingFile);
  wr->add_option("--config", ro->config,
                 "Weld-cell world config or deployment file (default: the built-in simulated "
                 "cell)")
      ->check(CLI::ExistingFile);
  wr->add_flag("--no-arc", ro->no_arc, "Dry run: the motion with the arc disabled");
  wr->add_option("--log", ro->log,
                 "Simulated cell: CSV of the stand-off along the path (docs/weld-paths.md)");
  commands->push_back({wr, [ro] { return RunWeldRun(*ro); }});
}

}  // namespace kinevis::cli
