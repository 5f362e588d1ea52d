// kinevis record scanner | calibrate scanner (issue 7, seed 004): the laser scanner's calibration
// (the jobs: rigs/weld/weld_calibration_jobs.h)
// on the weld cell (rigs/weld/weld_rig.h: the simulated cell by default, or a deployment file).
//
//   record scanner     the robot carries the scanner in front of the dot board to --poses board
//                      poses (0.50-0.55 m, tilted by up to 2°); at each, one image with the lasers
//                      off (the dots: the board pose) and one per stepper position with both lasers
//                      on; written as a dataset directory (docs/laser-scanner-calibration.md).
//   calibrate scanner  board poses from the dots, stripes from the images
//                      (vision/laser/laser_stripes.h), eq. 28/32/29 and the joint refinement
//                      (calibration/laser_scanner/); writes the result YAML. From --dataset, or
//                      recorded first on the cell (--config).

#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "apps/kinevis/cli_common.h"
#include "apps/kinevis/commands.h"
#include "rigs/weld/weld_calibration_jobs.h"
#include "rigs/weld/weld_rig.h"
#include "sim/weld_cell_world.h"

namespace kinevis::cli {

using rigs::WeldRig;
using rigs::WeldRigOptions;
using rigs::WeldWorkpiece;
namespace {

struct ScannerRecordCli {
  std::string config;
  rigs::ScannerRecordOptions job;
};

struct ScannerCalibrateOptions {
  std::string config;
  std::string dataset;
  std::string record;  // where to record first (with --config); default: a temporary directory
  std::string out = "scanner_calib.yaml";
  int poses = 6;
  int steps = 5;
};

int RunRecordScanner(const ScannerRecordCli& o) {
  WeldRigOptions ro;
  ro.config = o.config;
  ro.workpiece = WeldWorkpiece::kDotBoard;
  WeldRig rig(ro);
  rigs::ScannerRecordOptions job = o.job;
  job.stop_requested = StopRequested;
  const rigs::ScannerRecordReport r = rigs::RecordScannerDataset(&rig, job);
  std::printf("recorded %d board poses x (1 + %d) images into %s\n", r.board_poses, job.steps,
              job.out.c_str());
  return kExitOk;
}

int RunCalibrateScanner(const ScannerCalibrateOptions& o) {
  std::string dataset_dir = o.dataset;
  std::unique_ptr<WeldRig> rig;
  if (dataset_dir.empty()) {
    WeldRigOptions ro;
    ro.config = o.config;
    ro.workpiece = WeldWorkpiece::kDotBoard;
    rig = std::make_unique<WeldRig>(ro);
    rigs::ScannerRecordOptions r;
    r.stop_requested = StopRequested;
    r.poses = o.poses;
    r.steps = o.steps;
    r.out = o.record;
    if (r.out.empty()) {
      r.out = (std::filesystem::temp_directory_path() /
               ("kinevis-scanner-" + std::to_string(::getpid())))
                  .string();
      std::filesystem::remove_all(r.out);
    }
    rigs::RecordScannerDataset(rig.get(), r);
    dataset_dir = r.out;
  }
  const rigs::ScannerCalibrationRun job = rigs::CalibrateScannerFromDataset(dataset_dir, o.out);
  const calibration::LaserScannerDatasetCalibration& run = job.run;
  const double wall = job.wall_seconds;
  const calibration::LaserScannerCalibration& c = run.calibration;
  for (const std::string& s : run.skipped) std::printf("  skipped: %s\n", s.c_str());
  std::printf("  estimation: %s\n", c.estimation.BriefReport().c_str());
  for (const std::string& w : c.warnings) std::printf("  warning: %s\n", w.c_str());
  for (const std::string& e : c.errors) std::printf("  error: %s\n", e.c_str());
  std::printf("scanner calibration from %s: %zu board poses, %d images (%.1f s)\n",
              dataset_dir.c_str(), run.board_poses.size(), c.images, wall);
  const auto& g = c.geometry;
  std::printf(
      "  rotating laser: b_y %.4f +- %.4f mm, d_y %.4f +- %.4f mm (%d points, rms %.4f mm)\n",
      1e3 * g.rotating_b_y, 1e3 * c.b_y_sigma(), 1e3 * g.rotating_d_y, 1e3 * c.d_y_sigma(),
      c.rotating_points, 1e3 * c.rotating_residual_rms);
  std::printf(
      "  fixed laser: b_x' %.4f +- %.4f mm, cot theta_x %.5f +- %.5f (%d points, rms %.4f mm)\n",
      1e3 * g.fixed_b_x_prime, 1e3 * c.b_x_prime_sigma(), g.fixed_cot_theta_x,
      c.cot_theta_x_sigma(), c.fixed_points, 1e3 * c.fixed_residual_rms);
  if (rig && rig->simulated()) {
    const auto& t = rig->world()->config().scanner;
    std::printf(
        "  simulation truth: b_y %.4f mm (error %.4f), d_y %.4f mm (error %.4f), b_x' %.4f mm "
        "(error %.4f), cot theta_x %.5f (error %.6f)\n",
        1e3 * t.rotating_b_y, 1e3 * (g.rotating_b_y - t.rotating_b_y), 1e3 * t.rotating_d_y,
        1e3 * (g.rotating_d_y - t.rotating_d_y), 1e3 * t.fixed_b_x_prime,
        1e3 * (g.fixed_b_x_prime - t.fixed_b_x_prime), t.fixed_cot_theta_x,
        g.fixed_cot_theta_x - t.fixed_cot_theta_x);
  }
  std::printf("wrote %s\n", o.out.c_str());
  return c.ok() ? kExitOk : kExitJobFailed;
}

}  // namespace

void AddWeldCommands(const Parents& parents, CommandList* commands) {
  CLI::App& calibrate = *parents.calibrate;
  CLI::App* record = parents.record;
  auto ro = std::make_shared<ScannerRecordCli>();
  CLI::App* rs = record->add_subcommand(
      "scanner",
      "Record a laser-scanner calibration dataset: dot-board images with the lasers off and, per "
      "stepper position, on (simulated cell; docs/laser-scanner-calibration.md)");
  rs->add_option("--config", ro->config,
                 "Weld-cell world config (config/weld-cell-sim.yaml; default: built-in defaults)")
      ->check(CLI::ExistingFile);
  rs->add_option("--out", ro->job.out, "Dataset directory to create")->required();
  rs->add_option("--poses", ro->job.poses, "Board poses (1-8)")->check(CLI::Range(1, 8));
  rs->add_option("--steps", ro->job.steps, "Rotating-laser stepper positions per pose (2-15)")
      ->check(CLI::Range(2, 15));
  rs->add_option("--step-deg", ro->job.step_deg, "Rotating-laser angle per stepper step, deg")
      ->check(CLI::Range(0.05, 2.0));
  commands->push_back({rs, [ro] { return RunRecordScanner(*ro); }});

  auto co = std::make_shared<ScannerCalibrateOptions>();
  CLI::App* cs = calibrate.add_subcommand(
      "scanner",
      "Laser-scanner calibration (seed 004 eq. 26-32): b_y, d_y of the rotating laser, b_x' and "
      "cot theta_x of the fixed one, from a dataset or recorded on the cell first");
  cs->add_option("--config", co->config,
                 "Weld-cell world config to record on (default: the built-in simulated cell)")
      ->check(CLI::ExistingFile);
  cs->add_option("--dataset", co->dataset, "Calibrate from this recorded dataset directory")
      ->check(CLI::ExistingDirectory);
  cs->add_option("--record", co->record,
                 "With the cell: keep the recorded dataset in this directory");
  cs->add_option("--poses", co->poses, "Board poses to record (1-8)")->check(CLI::Range(1, 8));
  cs->add_option("--steps", co->steps, "Stepper positions per pose (2-15)")
      ->check(CLI::Range(2, 15));
  cs->add_option("--out", co->out, "Result YAML (docs/laser-scanner-calibration.md)");
  cs->get_option("--dataset")->excludes("--config")->excludes("--record");
  commands->push_back({cs, [co] { return RunCalibrateScanner(*co); }});
}

}  // namespace kinevis::cli
