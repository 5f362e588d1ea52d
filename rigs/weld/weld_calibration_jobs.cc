#include "rigs/weld/weld_calibration_jobs.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <stdexcept>

#include "calibration/laser_scanner/laser_scanner_calibration_io.h"
#include "calibration/weld_mount/mount_calibration_io.h"
#include "calibration/weld_mount/mount_dataset.h"
#include "calibration/weld_mount/mount_plan.h"
#include "common/stopwatch.h"
#include "common/units.h"
#include "hal/common/error.h"
#include "hal/weld/weld_robot_client.h"
#include "rigs/deployment.h"
#include "robots/io/robot_description.h"
#include "sim/weld_cell_world.h"
#include "vision/camera/camera_file.h"
#include "vision/laser/laser_stripes.h"

namespace kinevis::rigs {
namespace {

namespace fs = std::filesystem;
// Stripe points below this confidence (laser_stripes.h) are not used; a stripe needs this many
// points to make a scan.
constexpr double kMinConfidence = 0.2;
constexpr size_t kMinPoints = 20;

const char* ToString(LaserAngleSource s) {
  return s == LaserAngleSource::kCommanded ? "the commanded stepper angle"
                                           : "eq. 11 from the stripes' crossing";
}

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

// The scanner the stripe points are triangulated with: the camera model and the laser geometry.
struct PointScanner {
  std::string description;                      // for the dataset and the output
  std::unique_ptr<vision::CameraModel> camera;  // null: the rig's camera model
  vision::laser::ScannerGeometry geometry;
};

PointScanner LoadPointScanner(const std::string& scanner_file, const WeldRig& rig) {
  PointScanner s;
  if (scanner_file.empty()) {
    s.geometry = vision::laser::FromSceneGeometry(rig.world()->config().scanner);
    char text[256];
    std::snprintf(text, sizeof text,
                  "the world config's scanner geometry (no --scanner given): b_y %.4f mm, d_y %.4f "
                  "mm, b_x' %.4f mm, cot theta_x %.5f; camera %s",
                  common::kMmPerM * s.geometry.rotating_b_y,
                  common::kMmPerM * s.geometry.rotating_d_y,
                  common::kMmPerM * s.geometry.fixed_b_x_prime, s.geometry.fixed_cot_theta_x,
                  rig.camera_model_spec().c_str());
    s.description = text;
    return s;
  }
  const calibration::LaserScannerCalibrationFile file = ReadCalibratedScanner(scanner_file);
  s.geometry = file.result.geometry;
  s.camera = vision::OpenCameraModel(file.metadata.camera);
  if (s.camera->width() != rig.camera_model().width() ||
      s.camera->height() != rig.camera_model().height()) {
    throw std::invalid_argument(
        "scanner calibration file " + scanner_file + ": camera " + file.metadata.camera + " is " +
        std::to_string(s.camera->width()) + "x" + std::to_string(s.camera->height()) +
        " but the scanner camera's frames are " + std::to_string(rig.camera_model().width()) + "x" +
        std::to_string(rig.camera_model().height()));
  }
  s.description = "scanner calibration " + fs::absolute(scanner_file).string() + " (camera " +
                  file.metadata.camera + ")";
  return s;
}

// The block's pose as the operator writes it down from the cell layout: standing at the board's
// centre, its long side along x_S. The calibration needs it to ~2 cm / ~10° only.
Eigen::Isometry3d LayoutBlockPose(const sim::WeldCellWorldConfig& c) {
  return c.X_0S * Eigen::Translation3d(0.0, 0.0, 0.5 * c.workpiece.gauge_size.z());
}

void Moved(WeldRig* rig, const std::string& result, const std::string& where) {
  if (!result.empty()) {
    // The rig has stopped the robot (its safe state); a failed move is a hardware fault.
    throw hal::HalError(rig->robot().name(), "move to " + where, result);
  }
}

// A real cell (a deployment file) cannot record the touches: refused before anything connects
// or moves.
[[noreturn]] void RefuseRealCell() {
  throw std::invalid_argument(
      "record scanner-mount: on a real cell the torch touches on the gauge block are made by an "
      "operator jogging the robot, and kinevis has no jog interface to record them; record the "
      "touches (joint readings + feature) and the scans in the dataset format "
      "(docs/scanner-mount-calibration.md, \"Dataset directory\") and run `kinevis calibrate "
      "scanner-mount --dataset DIR`");
}

robots::Weld5Model DatasetRobot(const calibration::MountDataset& d) {
  if (d.robot_description.empty()) return sim::WeldCellWorldConfig().nominal;
  try {
    return robots::LoadWeld5Description(d.robot_description).model;
  } catch (const std::exception& e) {
    throw std::invalid_argument("scanner mount dataset " + d.directory +
                                "/dataset.yaml: robot: " + e.what());
  }
}

}  // namespace

ScannerRecordReport RecordScannerDataset(WeldRig* rig, const ScannerRecordOptions& o) {
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
  ScannerRecordReport report;
  for (size_t k = 0; k < poses.size(); ++k) {
    if (o.stop_requested && o.stop_requested()) {
      throw std::runtime_error("record scanner: interrupted");
    }
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
    ++report.images;
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
      ++report.images;
    }
    ++report.board_poses;
    spdlog::info("record scanner: board pose {}/{} recorded", k + 1, poses.size());
  }
  rig->SetLaserAngle(rig->world()->config().cot_theta_y);
  return report;
}

calibration::LaserScannerCalibrationFile ReadCalibratedScanner(const std::string& path) {
  calibration::LaserScannerCalibrationFile file = calibration::ReadLaserScannerCalibration(path);
  if (!file.result.rotating_calibrated || !file.result.fixed_calibrated) {
    throw std::invalid_argument(
        "scanner calibration file " + path + ": " +
        (file.result.rotating_calibrated ? "the fixed" : "the rotating") +
        " laser is not calibrated (rotating_laser.calibrated / "
        "fixed_laser.calibrated; the stripe crossing needs the fixed laser, "
        "the points the rotating one); recalibrate with `kinevis calibrate "
        "scanner`");
  }
  return file;
}

ScannerCalibrationRun CalibrateScannerFromDataset(const std::string& dataset_dir,
                                                  const std::string& out) {
  ScannerCalibrationRun r;
  r.dataset = calibration::ReadLaserScannerDataset(dataset_dir);
  const std::unique_ptr<vision::CameraModel> camera =
      vision::OpenCameraModel(r.dataset.camera_model);
  const common::Stopwatch t0;
  r.run = calibration::CalibrateLaserScannerDataset(r.dataset, *camera, MakeStripeExtractor());
  r.wall_seconds = t0.Seconds();
  calibration::LaserScannerCalibrationMetadata m;
  m.camera = r.dataset.camera_model;
  m.camera_name = r.dataset.camera_name;
  m.source = dataset_dir;
  calibration::WriteLaserScannerCalibration(out, r.run.calibration, m);
  return r;
}

std::unique_ptr<WeldRig> OpenGaugeBlockRig(const std::string& config) {
  // A world config whose workpiece already is a board with the gauge block keeps its placement
  // (the truth the calibration must find); any other gets the default board with the block. A
  // deployment file (the real cell) has what the operator put there.
  WeldRigOptions ro;
  ro.config = config;
  ro.workpiece = WeldWorkpiece::kGaugeBlock;
  if (!IsWorldConfig(config, "weld-cell")) RefuseRealCell();
  if (!config.empty() && sim::LoadWeldCellWorldConfig(config).workpiece.gauge_block) {
    ro.workpiece = WeldWorkpiece::kFromConfig;
  }
  return std::make_unique<WeldRig>(ro);
}

Eigen::Isometry3d TrueGaugeBlockPose(const WeldRig& rig) {
  if (!rig.simulated()) {
    throw std::logic_error("TrueGaugeBlockPose: only a simulated cell knows the block's true pose");
  }
  const sim::WeldCellWorldConfig& c = rig.world()->config();
  return c.X_0S * c.workpiece.X_SB();
}

MountRecordReport RecordMountDataset(WeldRig* rig, const MountRecordOptions& o) {
  if (!rig->simulated()) RefuseRealCell();
  const sim::WeldCellWorldConfig& world = rig->world()->config();
  const PointScanner scanner = LoadPointScanner(o.scanner, *rig);
  const vision::CameraModel& camera = scanner.camera ? *scanner.camera : rig->camera_model();
  const vision::laser::ScannerModel model(camera, scanner.geometry);
  const std::vector<Eigen::Vector2d> views = calibration::MountViewPlan(o.views);
  const bool commanded_angle = o.laser_angle == LaserAngleSource::kCommanded;
  const auto stop = [&] { return o.stop_requested && o.stop_requested(); };
  MountRecordReport report;
  report.scanner = scanner.description;
  report.laser_angle = o.laser_angle;

  calibration::MountDataset d;
  d.directory = o.out;
  d.robot_description =
      rig->robot_description().empty() ? "" : fs::absolute(rig->robot_description()).string();
  d.scanner = scanner.description + "; rotating laser angle: " + ToString(o.laser_angle);
  d.block.size = world.workpiece.gauge_size;
  d.X_0B_guess = LayoutBlockPose(world);
  d.X_5C_guess = rig->X_5C_nominal();
  d.source = rig->config_path().empty() ? "simulated weld cell (defaults)"
                                        : "simulated weld cell " + rig->config_path();
  calibration::CreateMountDataset(&d);

  // Touches, at the block's true pose. The torch axis of this arm cannot point anywhere (θ5 turns
  // about it): approach axes on a grid around the board's normal, the most head-on first.
  const Eigen::Isometry3d X_0B = world.X_0S * world.workpiece.X_SB();
  const Eigen::Vector3d h = 0.5 * world.workpiece.gauge_size;
  for (const calibration::PlannedTouch& t : calibration::MountTouchPlan()) {
    if (stop()) throw std::runtime_error("record scanner-mount: interrupted");
    const calibration::BlockFeature f = calibration::BlockFeature::Parse(t.feature);
    const Eigen::Vector3d n_0 = calibration::TouchApproachNormal(f, X_0B.linear());
    const Eigen::Vector3d p_0 = X_0B * Eigen::Vector3d(t.fraction.cwiseProduct(h));
    bool reached = false;
    for (const Eigen::Vector3d& axis : calibration::TouchApproachAxes(n_0)) {
      // Where the host's model says the torch cannot get, the operator cannot either (the true
      // arm is within a millimetre of it): a quick check first, which keeps an unreachable face
      // from costing a full search on the true robot for every approach axis.
      robots::Weld5IkOptions quick;
      quick.max_iterations = 100;
      quick.position_tolerance = 1e-6;
      quick.axis_tolerance = 1e-6;
      if (!robots::Weld5InverseKinematics(rig->nominal(), p_0, axis, rig->Joints(), quick)
               .converged()) {
        continue;
      }
      robots::Vector5d q;
      if (!rig->OperatorTouch(p_0, axis, o.touch_sigma, &q)) continue;
      // The operator has jogged the torch there; the controller reports the joints.
      Moved(rig, rig->MoveTo(q, 0.5), std::string("touch ") + t.feature);
      calibration::MountTouch touch;
      touch.q = rig->Joints();
      touch.feature = f;
      calibration::AppendMountTouch(&d, touch);
      reached = true;
      break;
    }
    if (reached) {
      ++report.touches;
    } else {
      report.unreachable.push_back(t.feature);
    }
  }
  spdlog::info("record scanner-mount: {} touches", report.touches);

  // Scans, aimed at the block's guessed pose with what the host knows.
  vision::laser::LaserStripeExtractor extractor{vision::laser::LaserStripeOptions()};
  vision::laser::LaserStripes stripes;
  hal::Image image;
  robots::Vector5d home;
  for (int i = 0; i < robots::kWeld5Joints; ++i)
    home(i) = world.initial_joints[static_cast<size_t>(i)];
  // The stripe points of one laser, triangulated (eq. 9 at cot θ_y, or eq. 10), those below the
  // confidence floor left out.
  const auto triangulate = [&](vision::laser::Stripe which, double cot,
                               std::vector<Eigen::Vector3d>* p_C, std::vector<float>* confidence) {
    p_C->clear();
    confidence->clear();
    for (const vision::laser::StripePoint& p : stripes.stripe(which).points) {
      if (p.confidence < kMinConfidence) continue;
      Eigen::Vector3d point;
      const vision::laser::TriangulationStatus status =
          which == vision::laser::Stripe::kRotating
              ? model.TriangulateRotating(p.pixel, cot, &point)
              : model.TriangulateFixed(p.pixel, &point);
      if (status != vision::laser::TriangulationStatus::kOk) continue;
      p_C->push_back(point);
      confidence->push_back(static_cast<float>(p.confidence));
    }
  };
  std::vector<Eigen::Vector3d> p_C;
  std::vector<float> confidence;
  // What the host knows of the scanner's pose: the nominal robot with the CAD mount.
  const auto X_0C_host = [&](const robots::Vector5d& qq) -> Eigen::Isometry3d {
    return robots::DhForwardKinematics(rig->nominal().joints, qq) * rig->X_5C_nominal();
  };
  for (int v = 0; v < o.views; ++v) {
    if (stop()) throw std::runtime_error("record scanner-mount: interrupted");
    robots::Vector5d q = home;
    q(3) += views[static_cast<size_t>(v)].x();
    q(4) = views[static_cast<size_t>(v)].y();
    q = calibration::AimOpticalAxisAt(X_0C_host, d.X_0B_guess.translation(), q);
    Moved(rig, rig->MoveTo(q, 0.5), "view " + std::to_string(v));
    rig->SetLasers(true, true);
    bool fixed_done = false;
    for (const double commanded : calibration::MountLaserAngles()) {
      rig->SetLaserAngle(commanded);
      robots::Vector5d q_read;
      const std::string grabbed = rig->GrabFresh(&image, &q_read);
      if (!grabbed.empty()) throw hal::HalError("scanner camera", "grab", grabbed);
      const vision::ImageView8 view{image.data.data(), image.width, image.height, image.stride};
      extractor.Extract(view, &stripes);
      char where[80];
      std::snprintf(where, sizeof where, "view %d, commanded cot theta_y %.2f", v, commanded);
      // Eq. (11) from the stripes' crossing: the angle itself in crossing mode, a check otherwise.
      double eq11 = std::nan("");
      std::string no_angle;
      if (!stripes.crossing.found()) {
        no_angle = std::string("no stripe crossing (") + ToString(stripes.crossing.status) + ")";
      } else if (const vision::laser::TriangulationStatus st =
                     model.CotThetaYFromIntersection(stripes.crossing.pixel, &eq11);
                 st != vision::laser::TriangulationStatus::kOk) {
        no_angle = "eq. 11 failed at the crossing (" + std::string(ToString(st)) + ")";
        eq11 = std::nan("");
      } else {
        report.eq11_deviation.push_back(eq11 - commanded);
      }
      const double cot = commanded_angle ? commanded : eq11;
      if (std::isnan(cot)) {
        report.skipped.push_back(std::string(where) + ": rotating stripe: " + no_angle);
      } else {
        triangulate(vision::laser::Stripe::kRotating, cot, &p_C, &confidence);
        if (p_C.size() < kMinPoints) {
          report.skipped.push_back(std::string(where) +
                                   ": rotating stripe: " + std::to_string(p_C.size()) + " points");
        } else {
          calibration::MountDatasetScan scan;
          scan.q = q_read;
          scan.laser = "rotating";
          scan.cot_theta_y = cot;
          calibration::AppendMountScan(&d, scan, &p_C, confidence, image.data.data(), image.width,
                                       image.height, image.stride);
          ++report.scans;
          report.points += static_cast<int>(p_C.size());
        }
      }
      if (!fixed_done && o.fixed_laser) {
        // The fixed laser's stripe does not move with the stepper: once per viewpoint.
        triangulate(vision::laser::Stripe::kFixed, 0.0, &p_C, &confidence);
        if (p_C.size() >= kMinPoints) {
          calibration::MountDatasetScan scan;
          scan.q = q_read;
          scan.laser = "fixed";
          scan.cot_theta_y = 0.0;  // not used by the fixed laser
          calibration::AppendMountScan(&d, scan, &p_C, confidence);
          ++report.scans;
          report.points += static_cast<int>(p_C.size());
          fixed_done = true;
        }
      }
    }
    if (o.fixed_laser && !fixed_done) {
      report.skipped.push_back("view " + std::to_string(v) + ": fixed stripe: too few points");
    }
    spdlog::info("record scanner-mount: view {}/{} recorded", v + 1, o.views);
  }
  rig->SetLaserAngle(world.cot_theta_y);
  return report;
}

MountCalibrationRun CalibrateScannerMountFromDataset(const std::string& dataset_dir,
                                                     const MountCalibrateOptions& o,
                                                     const WeldRig* rig) {
  MountCalibrationRun r;
  r.dataset = calibration::ReadMountDataset(dataset_dir);
  const robots::Weld5Model robot = rig ? rig->nominal() : DatasetRobot(r.dataset);
  // The fixed laser's points are left out unless asked for: eq. (10) triangulates them over its
  // short base b_x' (6.7 mm in seed 004 against ~100 mm for the rotating laser), so their depth is
  // ~15x less precise (0.1 px of stripe position: ~1 mm at 0.4 m) and they would pull the mount.
  calibration::MountDataset used = r.dataset;
  if (!o.use_fixed_laser) {
    used.scans.clear();
    for (const calibration::MountDatasetScan& scan : r.dataset.scans) {
      if (scan.laser != "fixed") used.scans.push_back(scan);
    }
  }
  r.fixed_left_out = r.dataset.scans.size() - used.scans.size();
  r.data = calibration::MountCalibrationDataFromDataset(used, robot);
  for (const calibration::MountScan& s : r.data.scans) r.points += s.p_C.size();
  if (r.data.touches.empty() || r.data.scans.empty()) return r;

  calibration::MountCalibrationOptions options;
  options.estimate_dh = o.estimate_dh;
  options.touch_sigma = o.touch_sigma;
  options.scan_sigma = o.scan_sigma;
  const common::Stopwatch t0;
  r.summary = calibration::CalibrateScannerMount(r.data, options);
  r.wall_seconds = t0.Seconds();
  r.calibrated = true;
  const calibration::MountCalibrationSummary& s = r.summary;

  if (rig && rig->simulated()) {
    const sim::WeldCellWorldConfig& c = rig->world()->config();
    r.has_truth = true;
    r.truth.position_error = s.X_5C.translation() - c.X_5C.translation();
    r.truth.angle_error = Eigen::AngleAxisd(c.X_5C.linear().transpose() * s.X_5C.linear()).angle();
    r.truth.cad_position_error = (r.data.X_5C_guess.translation() - c.X_5C.translation()).norm();
    r.truth.cad_angle_error =
        Eigen::AngleAxisd(c.X_5C.linear().transpose() * r.data.X_5C_guess.linear()).angle();
    const Eigen::Isometry3d X_0B = TrueGaugeBlockPose(*rig);
    r.truth.block_position_error = (s.X_0B.translation() - X_0B.translation()).norm();
    r.truth.block_angle_error =
        Eigen::AngleAxisd(X_0B.linear().transpose() * s.X_0B.linear()).angle();
  }
  calibration::ScannerMountCalibrationMetadata m;
  m.source = dataset_dir;
  m.robot = r.dataset.robot_description;
  m.scanner = r.dataset.scanner;
  m.X_5C_guess = r.data.X_5C_guess;
  m.X_0B_guess = r.data.X_0B_guess;
  m.block = r.data.block;
  calibration::WriteScannerMountCalibration(o.out, s, m);
  return r;
}

}  // namespace kinevis::rigs
