// kinevis record scanner | calibrate scanner (issue 7, seed 004): the laser scanner's calibration
// on the weld cell (apps/kinevis/weld_rig.h: the simulated cell by default, or a deployment file).
//
//   record scanner     the robot carries the scanner in front of the dot board to --poses board
//                      poses (0.50-0.55 m, tilted by up to 2°); at each, one image with the lasers
//                      off (the dots: the board pose) and one per stepper position with both lasers
//                      on; written as a dataset directory (docs/laser-scanner-calibration.md).
//   calibrate scanner  board poses from the dots, stripes from the images
//                      (vision/laser/laser_stripes.h), eq. 28/32/29 and the joint refinement
//                      (calibration/laser_scanner/); writes the result YAML. From --dataset, or
//                      recorded first on the cell (--config).

#include <spdlog/spdlog.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "apps/kinevis/cli_common.h"
#include "apps/kinevis/commands.h"
#include "calibration/laser_scanner/laser_scanner_calibration_io.h"
#include "calibration/laser_scanner/laser_scanner_dataset.h"
#include "common/units.h"
#include "rigs/weld/weld_rig.h"
#include "sim/weld_cell_world.h"
#include "vision/camera/camera_file.h"
#include "vision/laser/laser_stripes.h"

namespace kinevis::cli {

using rigs::WeldRig;
using rigs::WeldRigOptions;
using rigs::WeldWorkpiece;
namespace {

struct ScannerRecordOptions {
  std::string config;
  std::string out;
  int poses = 6;
  int steps = 5;
  double step_deg = 0.45;
};

struct ScannerCalibrateOptions {
  std::string config;
  std::string dataset;
  std::string record;  // where to record first (with --config); default: a temporary directory
  std::string out = "scanner_calib.yaml";
  int poses = 6;
  int steps = 5;
};

// Board poses for the scanner calibration: the robot at its home (the scanner 0.40 m from the
// workpiece plane, looking at it), pulled back along the torch axis by pz3 and tilted by θ1 / θ2
// (θ5 rolls the scanner about its axis), so that the dots fill the view at 0.50-0.55 m and the
// depth spread across the board separates b from d (eq. 32). θ1 moves the image vertically (about
// 60 px per degree at this reach) and the grid fills 3/4 of the height, hence at most 2°.
std::vector<robots::Vector5d> BoardPoses(int n) {
  // θ1 (deg), θ2 (deg), pz3 (mm), θ4 (deg), θ5 (deg)
  const double table[][5] = {{0, 0, 100, 0, 0},       {-2, 0, 130, 0, 0},   {-1.5, 1.5, 120, 0, 0},
                             {0, -2, 150, 0, 3},      {0.7, 2, 140, 0, -3}, {-1, -1.5, 110, 2, 0},
                             {0.5, -1.5, 150, -2, 2}, {-2, 2, 125, 0, -2}};
  std::vector<robots::Vector5d> q;
  for (int k = 0; k < n; ++k) {
    const double* t = table[k % 8];
    robots::Vector5d v;
    v << t[0] * common::kDeg, t[1] * common::kDeg, t[2] * 1e-3, t[3] * common::kDeg,
        t[4] * common::kDeg;
    q.push_back(v);
  }
  return q;
}

// The stripes of a lasers-on image (both searched; the crossing is not needed here).
calibration::StripeExtractor MakeStripeExtractor() {
  auto extractor =
      std::make_shared<vision::laser::LaserStripeExtractor>(vision::laser::LaserStripeOptions());
  auto stripes = std::make_shared<vision::laser::LaserStripes>();
  return [extractor, stripes](const vision::ImageView8& image, std::vector<Eigen::Vector2d>* fixed,
                              std::vector<Eigen::Vector2d>* rotating) {
    extractor->Extract(image, stripes.get());
    fixed->clear();
    rotating->clear();
    for (const auto& p : stripes->stripe(vision::laser::Stripe::kFixed).points) {
      fixed->push_back(p.pixel);
    }
    for (const auto& p : stripes->stripe(vision::laser::Stripe::kRotating).points) {
      rotating->push_back(p.pixel);
    }
  };
}

// Records the dataset; returns the number of board poses recorded. Throws on a rig that cannot
// do it (a real cell: the lasers and the stepper have no host driver yet) or a failed move/grab.
int RecordScannerDataset(WeldRig* rig, const ScannerRecordOptions& o) {
  if (!rig->simulated()) {
    throw std::invalid_argument(
        "record scanner: on a real cell the host must switch the lasers and step the rotating "
        "laser per image, and kinevis has no driver for the scanner's laser controller yet; "
        "record the images by hand in the dataset format (docs/laser-scanner-calibration.md) "
        "and run `kinevis calibrate scanner --dataset DIR`");
  }
  calibration::LaserScannerDataset d;
  d.directory = o.out;
  d.camera_model = rig->camera_model_spec();
  d.camera_name = "weld-scanner";
  d.source = rig->config_path().empty() ? "simulated weld cell (defaults)"
                                        : "simulated weld cell " + rig->config_path();
  calibration::CreateLaserScannerDataset(&d);

  const double home = std::atan2(1.0, rig->world()->config().cot_theta_y);  // θ_y at step 0
  const std::vector<robots::Vector5d> poses = BoardPoses(o.poses);
  hal::Image image;
  for (size_t k = 0; k < poses.size(); ++k) {
    const std::string moved = rig->MoveTo(poses[k], 0.5);
    if (!moved.empty())
      throw std::runtime_error("record scanner: pose " + std::to_string(k) + ": " + moved);
    rig->SetLasers(false, false);
    std::string grabbed = rig->GrabFresh(&image, nullptr);
    if (!grabbed.empty()) throw std::runtime_error("record scanner: " + grabbed);
    char name[64];
    std::snprintf(name, sizeof name, "images/pose%02zu_off.png", k);
    calibration::LaserScannerDatasetImage off;
    off.image = name;
    off.board_pose = static_cast<int>(k);
    calibration::AppendLaserScannerDatasetImage(&d, off, image.data.data(), image.width,
                                                image.height, image.stride);
    rig->SetLasers(true, true);
    for (int s = 0; s < o.steps; ++s) {
      const int step = 2 * s - (o.steps - 1);  // symmetric about 0, 2 apart
      rig->SetLaserAngle(1.0 / std::tan(home + step * o.step_deg * common::kDeg));
      grabbed = rig->GrabFresh(&image, nullptr);
      if (!grabbed.empty()) throw std::runtime_error("record scanner: " + grabbed);
      std::snprintf(name, sizeof name, "images/pose%02zu_step%+03d.png", k, step);
      calibration::LaserScannerDatasetImage on;
      on.image = name;
      on.board_pose = static_cast<int>(k);
      on.lasers_on = true;
      on.rotating_step = step;
      calibration::AppendLaserScannerDatasetImage(&d, on, image.data.data(), image.width,
                                                  image.height, image.stride);
    }
    spdlog::info("record scanner: board pose {}/{} recorded", k + 1, poses.size());
  }
  rig->SetLaserAngle(rig->world()->config().cot_theta_y);
  return static_cast<int>(poses.size());
}

int RunRecordScanner(const ScannerRecordOptions& o) {
  WeldRigOptions ro;
  ro.config = o.config;
  ro.workpiece = WeldWorkpiece::kDotBoard;
  WeldRig rig(ro);
  const int n = RecordScannerDataset(&rig, o);
  std::printf("recorded %d board poses x (1 + %d) images into %s\n", n, o.steps, o.out.c_str());
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
    ScannerRecordOptions r;
    r.config = o.config;
    r.poses = o.poses;
    r.steps = o.steps;
    r.out = o.record;
    if (r.out.empty()) {
      r.out = (std::filesystem::temp_directory_path() /
               ("kinevis-scanner-" + std::to_string(::getpid())))
                  .string();
      std::filesystem::remove_all(r.out);
    }
    RecordScannerDataset(rig.get(), r);
    dataset_dir = r.out;
  }
  const calibration::LaserScannerDataset dataset =
      calibration::ReadLaserScannerDataset(dataset_dir);
  const std::unique_ptr<vision::CameraModel> camera = vision::OpenCameraModel(dataset.camera_model);
  const auto t0 = std::chrono::steady_clock::now();
  const calibration::LaserScannerDatasetCalibration run =
      calibration::CalibrateLaserScannerDataset(dataset, *camera, MakeStripeExtractor());
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const calibration::LaserScannerCalibration& c = run.calibration;
  for (const std::string& s : run.skipped) std::printf("  skipped: %s\n", s.c_str());
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
  calibration::LaserScannerCalibrationMetadata m;
  m.camera = dataset.camera_model;
  m.camera_name = dataset.camera_name;
  m.source = dataset_dir;
  calibration::WriteLaserScannerCalibration(o.out, c, m);
  std::printf("wrote %s\n", o.out.c_str());
  return c.ok() ? kExitOk : kExitJobFailed;
}

}  // namespace

void AddWeldCommands(CLI::App& app, CLI::App& calibrate, CommandList* commands) {
  CLI::App* record = nullptr;
  for (CLI::App* sub : app.get_subcommands({})) {
    if (sub->get_name() == "record") record = sub;
  }
  if (record == nullptr) {
    record = app.add_subcommand("record", "Record calibration datasets on the robot");
  }
  auto ro = std::make_shared<ScannerRecordOptions>();
  CLI::App* rs = record->add_subcommand(
      "scanner",
      "Record a laser-scanner calibration dataset: dot-board images with the lasers off and, per "
      "stepper position, on (simulated cell; docs/laser-scanner-calibration.md)");
  rs->add_option("--config", ro->config,
                 "Weld-cell world config (config/weld-cell-sim.yaml; default: built-in defaults)")
      ->check(CLI::ExistingFile);
  rs->add_option("--out", ro->out, "Dataset directory to create")->required();
  rs->add_option("--poses", ro->poses, "Board poses (1-8)")->check(CLI::Range(1, 8));
  rs->add_option("--steps", ro->steps, "Rotating-laser stepper positions per pose (2-15)")
      ->check(CLI::Range(2, 15));
  rs->add_option("--step-deg", ro->step_deg, "Rotating-laser angle per stepper step, deg")
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
