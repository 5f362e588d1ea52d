// kinevis record scanner-mount | calibrate scanner-mount (issue 7, seed 004 §4): where the laser
// scanner sits on the weld arm (X_5C, the seed's A2S), from the gauge block standing on the board
// (apps/kinevis/weld_rig.h: the simulated cell by default, or a deployment file).
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

#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
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
#include "calibration/weld_mount/mount_calibration.h"
#include "calibration/weld_mount/mount_calibration_io.h"
#include "calibration/weld_mount/mount_dataset.h"
#include "common/units.h"
#include "hal/common/error.h"
#include "hal/weld/weld_robot_client.h"
#include "rigs/weld/weld_rig.h"
#include "robots/io/robot_description.h"
#include "sim/weld_cell_world.h"
#include "vision/camera/camera_file.h"
#include "vision/laser/laser_stripes.h"
#include "vision/laser/scanner_model.h"

namespace kinevis::cli {

using rigs::WeldRig;
using rigs::WeldRigOptions;
using rigs::WeldWorkpiece;
namespace {

namespace fs = std::filesystem;
constexpr int kMaxViews = 12;
// Stripe points below this confidence (laser_stripes.h) are not used; a stripe needs this many
// points to make a scan.
constexpr double kMinConfidence = 0.2;
constexpr size_t kMinPoints = 20;

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
  const calibration::LaserScannerCalibrationFile file =
      calibration::ReadLaserScannerCalibration(scanner_file);
  if (!file.result.rotating_calibrated || !file.result.fixed_calibrated) {
    throw std::invalid_argument("scanner calibration file " + scanner_file + ": " +
                                (file.result.rotating_calibrated ? "the fixed" : "the rotating") +
                                " laser is not calibrated (rotating_laser.calibrated / "
                                "fixed_laser.calibrated); recalibrate "
                                "with `kinevis calibrate scanner`");
  }
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

// The block's TRUE pose in a simulated cell (vision/render/scenes/laser_scene.h: the block's
// centre at gauge_centre_S on the board, h_z/2 above it, turned by gauge_heading about z_S).
Eigen::Isometry3d TrueBlockPose(const sim::WeldCellWorldConfig& c) {
  const vision::render::LaserSceneParameters& w = c.workpiece;
  return c.X_0S *
         Eigen::Translation3d(w.gauge_centre_S.x(), w.gauge_centre_S.y(), 0.5 * w.gauge_size.z()) *
         Eigen::AngleAxisd(w.gauge_heading, Eigen::Vector3d::UnitZ());
}

// The block's pose as the operator writes it down from the cell layout: standing at the board's
// centre, its long side along x_S. The calibration needs it to ~2 cm / ~10° only.
Eigen::Isometry3d LayoutBlockPose(const sim::WeldCellWorldConfig& c) {
  return c.X_0S * Eigen::Translation3d(0.0, 0.0, 0.5 * c.workpiece.gauge_size.z());
}

// The touches (feature, point in B as fractions of the half sizes): 4 on the top, 2 on the board,
// the sides (2 on +x, 1 on -x, 2 on +y, 1 on -y), an edge and a corner: 14 touches, 17 equations.
struct TouchPlan {
  const char* feature;
  double fx, fy, fz;
};
constexpr TouchPlan kTouches[] = {
    {"top", -0.7, -0.6, 1}, {"top", 0.7, -0.6, 1}, {"top", 0.6, 0.72, 1}, {"top", -0.6, 0.6, 1},
    {"board", 0, 1.8, -1},  {"board", 1.4, 0, -1}, {"+x", 1, -0.48, 0},   {"+x", 1, 0.48, 0},
    {"-x", -1, 0, 0},       {"+y", -0.6, 1, 0},    {"+y", 0.6, 1, 0},     {"-y", 0, -1, 0},
    {"+x+z", 1, 0, 1},      {"-x-y+z", -1, -1, 1},
};

// Scanner viewpoints as wrist joints relative to the home joints (Δθ4, θ5 in rad); θ1 and θ2 are
// then re-aimed at the block. Ordered so that the first few already turn the view both ways.
constexpr double kViews[kMaxViews][2] = {{0.0, 0.0},  {0.25, 0.5},  {-0.25, -0.5}, {0.0, 0.9},
                                         {0.0, -0.9}, {-0.25, 0.5}, {0.25, -0.5},  {0.3, 0.0},
                                         {-0.3, 0.0}, {0.15, 0.3},  {-0.15, -0.3}, {0.0, 0.3}};
// Rotating-laser angles per viewpoint (cot θ_y; the stripe crosses the optical axis at ~0.36,
// 0.39 and 0.43 m).
constexpr double kAngles[] = {0.22, 0.25, 0.28};

// θ1, θ2 of `q` turned (Gauss–Newton, numeric Jacobian) until the optical axis of the scanner, as
// the host models it (nominal robot, CAD mount), passes through p_0.
robots::Vector5d AimAt(const robots::Weld5Model& robot, const Eigen::Isometry3d& X_5C,
                       const Eigen::Vector3d& p_0, robots::Vector5d q) {
  const auto miss = [&](const robots::Vector5d& qq) -> Eigen::Vector2d {
    const Eigen::Vector3d p_C =
        (robots::DhForwardKinematics(robot.joints, qq) * X_5C).inverse() * p_0;
    return {p_C.x() / p_C.z(), p_C.y() / p_C.z()};
  };
  for (int it = 0; it < 30; ++it) {
    const Eigen::Vector2d m = miss(q);
    if (m.norm() < 1e-9) break;
    Eigen::Matrix2d J;
    for (int j = 0; j < 2; ++j) {
      robots::Vector5d qh = q;
      qh(j) += 1e-6;
      J.col(j) = (miss(qh) - m) / 1e-6;
    }
    const Eigen::Vector2d step = J.colPivHouseholderQr().solve(-m);
    q(0) += step(0);
    q(1) += step(1);
  }
  return q;
}

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

struct RecordReport {
  int touches = 0;
  std::vector<std::string> unreachable;
  int scans = 0;
  int points = 0;
  std::vector<std::string> skipped;
  std::string scanner;
  std::string laser_angle;
  std::vector<double> eq11_deviation;  // eq. (11)'s cot θ_y minus the commanded one, per image
};

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

bool IsWorldConfig(const std::string& config) {
  return config.empty() || sim::internal::WorldConfigReader(config, "weld-cell").Has("world");
}

RecordReport RecordMountDataset(WeldRig* rig, const MountRecordOptions& o) {
  if (!rig->simulated()) RefuseRealCell();
  const sim::WeldCellWorldConfig& world = rig->world()->config();
  const PointScanner scanner = LoadPointScanner(o.scanner, *rig);
  const vision::CameraModel& camera = scanner.camera ? *scanner.camera : rig->camera_model();
  const vision::laser::ScannerModel model(camera, scanner.geometry);
  if (o.laser_angle != "commanded" && o.laser_angle != "crossing") {
    throw std::invalid_argument("record scanner-mount: --laser-angle " + o.laser_angle +
                                " (expected commanded or crossing)");
  }
  RecordReport report;
  report.scanner = scanner.description;
  report.laser_angle = o.laser_angle;

  calibration::MountDataset d;
  d.directory = o.out;
  d.robot_description =
      rig->robot_description().empty() ? "" : fs::absolute(rig->robot_description()).string();
  d.scanner = scanner.description + "; rotating laser angle: " +
              (o.laser_angle == "commanded" ? "the commanded stepper angle"
                                            : "eq. 11 from the stripes' crossing");
  d.block.size = world.workpiece.gauge_size;
  d.X_0B_guess = LayoutBlockPose(world);
  d.X_5C_guess = rig->X_5C_nominal();
  d.source = rig->config_path().empty() ? "simulated weld cell (defaults)"
                                        : "simulated weld cell " + rig->config_path();
  calibration::CreateMountDataset(&d);

  // Touches, at the block's true pose. The torch axis of this arm cannot point anywhere (θ5 turns
  // about it): approach axes on a grid around the board's normal, the most head-on first.
  const Eigen::Isometry3d X_0B = TrueBlockPose(world);
  const Eigen::Vector3d h = 0.5 * world.workpiece.gauge_size;
  std::vector<Eigen::Vector3d> axes;
  for (int yaw = -40; yaw <= 40; yaw += 5) {
    for (int pitch = -60; pitch <= 60; pitch += 10) {
      const double a = yaw / common::kDegPerRad, b = pitch / common::kDegPerRad;
      axes.emplace_back(std::cos(a) * std::cos(b), std::sin(a) * std::cos(b), -std::sin(b));
    }
  }
  for (const TouchPlan& t : kTouches) {
    if (StopRequested()) throw std::runtime_error("record scanner-mount: interrupted");
    const calibration::BlockFeature f = calibration::BlockFeature::Parse(t.feature);
    Eigen::Vector3d n_B = f.sign.cast<double>();
    if (n_B.z() < 0.0) n_B.z() = 1.0;  // a board point is approached from above the board
    const Eigen::Vector3d n_0 = X_0B.linear() * n_B.normalized();
    const Eigen::Vector3d p_0 = X_0B * Eigen::Vector3d(t.fx * h.x(), t.fy * h.y(), t.fz * h.z());
    std::vector<Eigen::Vector3d> sorted = axes;
    std::sort(sorted.begin(), sorted.end(),
              [&](const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
                return a.dot(n_0) < b.dot(n_0);
              });
    bool reached = false;
    for (const Eigen::Vector3d& axis : sorted) {
      // At most 17° past the face's plane (a grazing approach of the tip); beyond, the torch
      // would come from inside the block.
      if (axis.dot(n_0) > 0.3) break;
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
      if (!rig->OperatorTouch(p_0, axis, o.touch_sigma_mm / common::kMmPerM, &q)) continue;
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
  for (int v = 0; v < o.views; ++v) {
    if (StopRequested()) throw std::runtime_error("record scanner-mount: interrupted");
    robots::Vector5d q = home;
    q(3) += kViews[v][0];
    q(4) = kViews[v][1];
    q = AimAt(rig->nominal(), rig->X_5C_nominal(), d.X_0B_guess.translation(), q);
    Moved(rig, rig->MoveTo(q, 0.5), "view " + std::to_string(v));
    rig->SetLasers(true, true);
    bool fixed_done = false;
    for (const double commanded : kAngles) {
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
      const double cot = o.laser_angle == "commanded" ? commanded : eq11;
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

void PrintRecordReport(const RecordReport& r, int views, const std::string& out) {
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
        r.laser_angle == "commanded" ? "the commanded stepper angle"
                                     : "eq. 11 from the stripes' crossing",
        std::sqrt(sum2 / r.eq11_deviation.size()), worst, r.eq11_deviation.size());
  }
}

std::unique_ptr<WeldRig> OpenGaugeBlockRig(const std::string& config) {
  // A world config whose workpiece already is a board with the gauge block keeps its placement
  // (the truth the calibration must find); any other gets the default board with the block. A
  // deployment file (the real cell) has what the operator put there.
  WeldRigOptions ro;
  ro.config = config;
  ro.workpiece = WeldWorkpiece::kGaugeBlock;
  if (!IsWorldConfig(config)) RefuseRealCell();
  if (!config.empty() && sim::LoadWeldCellWorldConfig(config).workpiece.gauge_block) {
    ro.workpiece = WeldWorkpiece::kFromConfig;
  }
  return std::make_unique<WeldRig>(ro);
}

int RunRecordScannerMount(const MountRecordOptions& o) {
  const std::unique_ptr<WeldRig> rig = OpenGaugeBlockRig(o.config);
  const RecordReport r = RecordMountDataset(rig.get(), o);
  PrintRecordReport(r, o.views, o.out);
  return r.touches > 0 && r.scans > 0 ? kExitOk : kExitJobFailed;
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
  for (const std::string& w : s.warnings) std::printf("  warning: %s\n", w.c_str());
}

int RunCalibrateScannerMount(const MountCalibrateOptions& o) {
  std::string dataset_dir = o.dataset;
  std::unique_ptr<WeldRig> rig;
  if (dataset_dir.empty()) {
    rig = OpenGaugeBlockRig(o.config);
    MountRecordOptions r;
    r.config = o.config;
    r.scanner = o.scanner;
    r.views = o.views;
    r.laser_angle = o.laser_angle;
    r.fixed_laser = o.fixed_laser;
    r.out = o.record;
    if (r.out.empty()) {
      r.out = (fs::temp_directory_path() / ("kinevis-scanner-mount-" + std::to_string(::getpid())))
                  .string();
      fs::remove_all(r.out);
    }
    const RecordReport report = RecordMountDataset(rig.get(), r);
    PrintRecordReport(report, r.views, r.out);
    dataset_dir = r.out;
  }
  const calibration::MountDataset dataset = calibration::ReadMountDataset(dataset_dir);
  const robots::Weld5Model robot = rig ? rig->nominal() : DatasetRobot(dataset);
  // The fixed laser's points are left out unless asked for: eq. (10) triangulates them over its
  // short base b_x' (6.7 mm in seed 004 against ~100 mm for the rotating laser), so their depth is
  // ~15x less precise (0.1 px of stripe position: ~1 mm at 0.4 m) and they would pull the mount.
  calibration::MountDataset used = dataset;
  if (!o.use_fixed_laser) {
    used.scans.clear();
    for (const calibration::MountDatasetScan& scan : dataset.scans) {
      if (scan.laser != "fixed") used.scans.push_back(scan);
    }
  }
  const size_t fixed_left_out = dataset.scans.size() - used.scans.size();
  const calibration::MountCalibrationData data =
      calibration::MountCalibrationDataFromDataset(used, robot);
  calibration::MountCalibrationOptions options;
  options.estimate_dh = o.dh;
  options.touch_sigma = o.touch_sigma_mm / common::kMmPerM;
  options.scan_sigma = o.scan_sigma_mm / common::kMmPerM;
  if (data.touches.empty() || data.scans.empty()) {
    std::printf("scanner mount calibration from %s: %zu touches, %zu scans: nothing to calibrate\n",
                dataset_dir.c_str(), data.touches.size(), data.scans.size());
    return kExitJobFailed;
  }
  size_t points = 0;
  for (const calibration::MountScan& s : data.scans) points += s.p_C.size();
  const auto t0 = std::chrono::steady_clock::now();
  const calibration::MountCalibrationSummary s = calibration::CalibrateScannerMount(data, options);
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::printf(
      "scanner mount calibration from %s: %zu touches, %zu scans (%zu stripe points), D-H errors "
      "%s (%.1f s)\n",
      dataset_dir.c_str(), data.touches.size(), data.scans.size(), points,
      o.dh ? "estimated" : "not estimated", wall);
  std::printf("  scanner: %s\n", dataset.scanner.c_str());
  if (fixed_left_out > 0) {
    std::printf(
        "  fixed-laser scans left out: %zu (eq. 10's short base b_x' makes their depth ~15x less "
        "precise; --use-fixed-laser to use them)\n",
        fixed_left_out);
  }
  PrintSummary(s, data);
  if (rig && rig->simulated()) {
    const sim::WeldCellWorldConfig& c = rig->world()->config();
    const Eigen::Vector3d e = s.X_5C.translation() - c.X_5C.translation();
    const double angle = Eigen::AngleAxisd(c.X_5C.linear().transpose() * s.X_5C.linear()).angle();
    const double cad_error = (data.X_5C_guess.translation() - c.X_5C.translation()).norm();
    const double cad_angle =
        Eigen::AngleAxisd(c.X_5C.linear().transpose() * data.X_5C_guess.linear()).angle();
    const Eigen::Isometry3d X_0B = TrueBlockPose(c);
    std::printf(
        "  simulation truth: mount error %.4f mm %s, %.4f deg (the CAD mount was %.3f mm, %.3f "
        "deg off); block error %.4f mm, %.4f deg\n",
        common::kMmPerM * e.norm(), Vec(e, common::kMmPerM, "%+.4f").c_str(),
        common::kDegPerRad * angle, common::kMmPerM * cad_error, common::kDegPerRad * cad_angle,
        common::kMmPerM * (s.X_0B.translation() - X_0B.translation()).norm(),
        common::kDegPerRad *
            Eigen::AngleAxisd(X_0B.linear().transpose() * s.X_0B.linear()).angle());
    if (o.dh) {
      std::printf(
          "    (with --dh the block's pose takes up the D-H errors held at nominal, d1 and theta1 "
          "among them: its error is not a measure of the calibration)\n");
    }
  }
  calibration::ScannerMountCalibrationMetadata m;
  m.source = dataset_dir;
  m.robot = dataset.robot_description;
  m.scanner = dataset.scanner;
  m.X_5C_guess = data.X_5C_guess;
  m.X_0B_guess = data.X_0B_guess;
  m.block = data.block;
  calibration::WriteScannerMountCalibration(o.out, s, m);
  std::printf("wrote %s\n", o.out.c_str());
  return s.ok() ? kExitOk : kExitJobFailed;
}

}  // namespace

void AddWeldMountCommands(CLI::App& app, CLI::App& calibrate, CommandList* commands) {
  CLI::App* record = nullptr;
  for (CLI::App* sub : app.get_subcommands({})) {
    if (sub->get_name() == "record") record = sub;
  }
  if (record == nullptr) {
    record = app.add_subcommand("record", "Record calibration datasets on the robot");
  }
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
