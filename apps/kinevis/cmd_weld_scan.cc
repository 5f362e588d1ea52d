// kinevis scan | record scan | weld-path | weld-run (issue 7, seed 004): the weld-repair chain on
// the weld cell (apps/kinevis/weld_rig.h: the simulated cell by default, or a deployment file).
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

#include <spdlog/spdlog.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "apps/kinevis/cli_common.h"
#include "apps/kinevis/commands.h"
#include "calibration/laser_scanner/laser_scanner_calibration_io.h"
#include "calibration/weld_mount/mount_calibration_io.h"
#include "calibration/weld_mount/scan_cloud.h"
#include "calibration/weld_mount/scan_dataset.h"
#include "common/units.h"
#include "control/weld/weld_plan_io.h"
#include "control/weld/weld_planner.h"
#include "hal/weld/weld_robot_client.h"
#include "rigs/weld/weld_rig.h"
#include "sim/weld_cell_world.h"
#include "vision/camera/camera_file.h"
#include "vision/cloud/cloud_sidecar.h"
#include "vision/laser/scan_lines.h"
#include "vision/render/scenes/laser_scene.h"

namespace kinevis::cli {

using rigs::WeldRig;
using rigs::WeldRigOptions;
using rigs::WeldWorkpiece;
namespace {

namespace fs = std::filesystem;

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

// The sidecar path for a map named X.ply or X.yaml.
std::string SidecarPath(const std::string& map) {
  fs::path p(map);
  if (p.extension() == ".yaml") return map;
  return p.replace_extension(".yaml").string();
}

struct ScanOptions {
  std::string config;
  std::string scanner;  // scanner calibration YAML; empty: the nominal geometry (seed Table 2)
  std::string mount;    // scanner-mount calibration YAML; empty: the nominal (CAD) mount
  std::string at;       // joints to scan from; empty: where the robot stands
  std::string dataset;  // rebuild from a recorded scan
  std::string record;   // keep the images as a dataset
  std::string out = "map.ply";
  int lines = 300;
  double depth = 0.40;
};

struct ScanFrames {
  std::vector<calibration::ScanLine> lines;
  int frames = 0;
  int failed = 0;
  double max_angle_deviation = 0.0;  // |eq. 11 − commanded| over the frames (simulated cell)
  std::string first_failure;
};

vision::laser::ScannerGeometry LoadScanner(const std::string& path, std::string* source) {
  if (path.empty()) {
    *source = "nominal (seed 004 Table 2; no --scanner calibration given)";
    return vision::laser::ScannerGeometry::Seed004();
  }
  const calibration::LaserScannerCalibrationFile file =
      calibration::ReadLaserScannerCalibration(path);
  if (!file.result.rotating_calibrated || !file.result.fixed_calibrated) {
    throw std::invalid_argument("--scanner " + path +
                                ": both lasers must be calibrated (the crossing needs the fixed "
                                "laser, the points the rotating one)");
  }
  *source = path;
  return file.result.geometry;
}

void AddLine(vision::laser::ScanLineTriangulator* triangulator, const vision::ImageView8& view,
             const robots::Vector5d& q, double commanded, ScanFrames* out) {
  vision::laser::ScanLineResult r;
  triangulator->Process(view, &r, commanded);
  ++out->frames;
  if (std::isfinite(commanded) &&
      (r.ok() || r.status == vision::laser::ScanLineStatus::kAngleInconsistent)) {
    out->max_angle_deviation =
        std::max(out->max_angle_deviation, std::abs(r.cot_theta_y - commanded));
  }
  if (!r.ok()) {
    ++out->failed;
    if (out->first_failure.empty()) {
      out->first_failure = "frame " + std::to_string(out->frames - 1) + ": " + ToString(r.status) +
                           (r.status == vision::laser::ScanLineStatus::kNoCrossing
                                ? std::string(" (") + vision::laser::ToString(r.crossing) + ")"
                                : std::string());
    }
    if (r.status != vision::laser::ScanLineStatus::kTooFewPoints) return;
  }
  calibration::ScanLine line;
  line.q = q;
  line.p_C = std::move(r.p_C);
  line.confidence = std::move(r.confidence);
  out->lines.push_back(std::move(line));
}

// Sweeps on the rig; keeps the frames in `record` when it is not empty.
ScanFrames SweepOnRig(WeldRig* rig, const vision::laser::ScannerModel& model, const ScanOptions& o,
                      const std::string& record) {
  if (!o.at.empty()) {
    const std::string moved = rig->MoveTo(ParseJoints(o.at, "--at"), 0.5);
    if (!moved.empty()) throw std::runtime_error("scan: moving to --at: " + moved);
  }
  calibration::ScanDataset dataset;
  if (!record.empty()) {
    dataset.directory = record;
    dataset.camera_model = rig->camera_model_spec();
    dataset.source = rig->simulated() ? "kinevis scan, simulated weld cell " + rig->config_path()
                                      : "kinevis scan, weld cell " + rig->config_path();
    calibration::CreateScanDataset(&dataset);
  }
  vision::laser::ScanLineTriangulator triangulator(model);
  // The simulated scanner's stepper takes the host's angles; a real one sweeps on its own and
  // the host takes frames while it does (eq. 11 reads the angle from each).
  std::vector<double> sweep;
  if (rig->simulated()) {
    sweep = vision::laser::PlanSweep(model, o.depth, o.lines);
    rig->SetLasers(true, true);
  }
  ScanFrames out;
  hal::Image image;
  for (int k = 0; k < o.lines; ++k) {
    const double commanded = rig->simulated() ? sweep[static_cast<size_t>(k)] : std::nan("");
    if (rig->simulated()) rig->SetLaserAngle(commanded);
    robots::Vector5d q;
    const std::string grabbed = rig->GrabFresh(&image, &q);
    if (!grabbed.empty())
      throw std::runtime_error("scan: frame " + std::to_string(k) + ": " + grabbed);
    const vision::ImageView8 view{image.data.data(), image.width, image.height, image.stride};
    if (!record.empty()) {
      calibration::ScanDatasetFrame f;
      f.q = q;
      f.commanded_cot_theta_y = commanded;
      calibration::AppendScanFrame(&dataset, f, image.data.data(), image.width, image.height,
                                   image.stride);
    }
    AddLine(&triangulator, view, q, commanded, &out);
    if ((k + 1) % 50 == 0) spdlog::info("scan: {}/{} frames", k + 1, o.lines);
  }
  if (rig->simulated()) rig->SetLaserAngle(rig->world()->config().cot_theta_y);
  return out;
}

ScanFrames SweepFromDataset(const calibration::ScanDataset& d,
                            const vision::laser::ScannerModel& model) {
  vision::laser::ScanLineTriangulator triangulator(model);
  ScanFrames out;
  const int w = model.camera().width(), h = model.camera().height();
  for (const calibration::ScanDatasetFrame& f : d.frames) {
    std::vector<uint8_t> pixels = calibration::ReadScanFrameImage(d, f, w, h);
    const vision::ImageView8 view{pixels.data(), w, h, static_cast<size_t>(w)};
    AddLine(&triangulator, view, f.q, f.commanded_cot_theta_y, &out);
  }
  return out;
}

// Signed distance (m) along z_S of p_0 from the true surface of the simulated workpiece.
double TrueSurfaceError(const vision::render::LaserScene& truth, const Eigen::Isometry3d& X_0S,
                        const Eigen::Vector3d& p_0) {
  const Eigen::Vector3d p_S = X_0S.inverse() * p_0;
  return p_S.z() - truth.Height(p_S.x(), p_S.y());
}

int RunScan(const ScanOptions& o) {
  std::string scanner_source;
  const vision::laser::ScannerGeometry geometry = LoadScanner(o.scanner, &scanner_source);
  std::unique_ptr<WeldRig> rig;
  std::unique_ptr<vision::CameraModel> dataset_camera;
  robots::Weld5Model robot = sim::WeldCellWorldConfig().nominal;
  Eigen::Isometry3d X_5C = sim::NominalScannerMount();
  std::string mount_source = "nominal (CAD; no --mount calibration given)";
  std::string robot_source = "nominal (seed 004 D-H, built-in)";
  ScanFrames frames;
  const auto t0 = std::chrono::steady_clock::now();
  if (o.dataset.empty()) {
    WeldRigOptions ro;
    ro.config = o.config;
    ro.workpiece = WeldWorkpiece::kFromConfig;
    rig = std::make_unique<WeldRig>(ro);
    robot = rig->nominal();
    X_5C = rig->X_5C_nominal();
    robot_source = rig->robot_description().empty() ? "nominal (" + rig->config_path() + ")"
                                                    : rig->robot_description();
    const vision::laser::ScannerModel model(rig->camera_model(), geometry);
    frames = SweepOnRig(rig.get(), model, o, o.record);
  } else {
    const calibration::ScanDataset d = calibration::ReadScanDataset(o.dataset);
    dataset_camera = vision::OpenCameraModel(d.camera_model);
    const vision::laser::ScannerModel model(*dataset_camera, geometry);
    frames = SweepFromDataset(d, model);
  }
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (!o.mount.empty()) {
    // The calibrated mount, and the D-H errors when they were estimated with it.
    const calibration::ScannerMountCalibrationFile mount =
        calibration::ReadScannerMountCalibration(o.mount);
    X_5C = calibration::ReadScannerMount(o.mount);
    mount_source = o.mount;
    if (mount.dh_estimated) {
      robot = calibration::CalibratedRobot(mount, robot);
      robot_source += " + D-H errors from " + o.mount;
    }
  }
  if (frames.lines.empty()) {
    std::printf("scan: no usable frame of %d (%s)\n", frames.frames, frames.first_failure.c_str());
    return kExitJobFailed;
  }
  const calibration::ScanCloud cloud = calibration::ScansToCloud(robot, X_5C, frames.lines);
  vision::cloud::CloudSidecar sidecar =
      calibration::MakeCloudSidecar(robot, robot_source, X_5C, mount_source, frames.lines.size());
  const std::string sidecar_path = SidecarPath(o.out);
  sidecar.ply = fs::path(o.out).replace_extension(".ply").filename().string();
  sidecar.source = o.dataset.empty() ? (rig->simulated() ? "kinevis scan (simulated weld cell)"
                                                         : "kinevis scan (weld cell)")
                                     : "kinevis scan --dataset " + o.dataset;
  sidecar.scanner_calibration = scanner_source;
  sidecar.scanner_parameters = {{"rotating_b_y_mm", 1e3 * geometry.rotating_b_y},
                                {"rotating_d_y_mm", 1e3 * geometry.rotating_d_y},
                                {"fixed_b_x_prime_mm", 1e3 * geometry.fixed_b_x_prime},
                                {"fixed_cot_theta_x", geometry.fixed_cot_theta_x}};
  vision::cloud::WriteCloud(sidecar_path, cloud.cloud, sidecar);

  std::printf("scan: %d frames, %zu scan lines, %zu points (%.1f s)\n", frames.frames,
              frames.lines.size(), cloud.cloud.size(), wall);
  std::printf("  scanner: %s\n  mount: %s\n", scanner_source.c_str(), mount_source.c_str());
  if (frames.failed > 0) {
    std::printf("  %d frames without a usable line; first: %s\n", frames.failed,
                frames.first_failure.c_str());
  }
  std::printf("  normals: %zu estimated, %zu missing\n", cloud.normals.estimated,
              cloud.normals.missing);
  if (rig && rig->simulated()) {
    std::printf("  laser angle: eq. 11 vs commanded stepper, max |d cot theta_y| %.5f\n",
                frames.max_angle_deviation);
    const vision::render::LaserScene truth(rig->world()->config().workpiece);
    double sum2 = 0.0, worst = 0.0, sum = 0.0;
    for (const Eigen::Vector3f& p : cloud.cloud.points) {
      const double e = TrueSurfaceError(truth, rig->world()->config().X_0S, p.cast<double>());
      sum += e;
      sum2 += e * e;
      worst = std::max(worst, std::abs(e));
    }
    const double n = static_cast<double>(cloud.cloud.size());
    std::printf("  simulation truth: map vs true surface: mean %.3f mm, rms %.3f mm, max %.3f mm\n",
                1e3 * sum / n, 1e3 * std::sqrt(sum2 / n), 1e3 * worst);
  }
  std::printf("wrote %s and %s\n", (fs::path(sidecar_path).parent_path() / sidecar.ply).c_str(),
              sidecar_path.c_str());
  return kExitOk;
}

int RunRecordScan(const ScanOptions& o) {
  std::string scanner_source;
  const vision::laser::ScannerGeometry geometry = LoadScanner(o.scanner, &scanner_source);
  WeldRigOptions ro;
  ro.config = o.config;
  WeldRig rig(ro);
  const vision::laser::ScannerModel model(rig.camera_model(), geometry);
  const ScanFrames frames = SweepOnRig(&rig, model, o, o.out);
  std::printf("recorded %d frames into %s (%d without a usable line)\n", frames.frames,
              o.out.c_str(), frames.failed);
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
  vision::cloud::CloudSidecar sidecar;
  const std::string sidecar_path = SidecarPath(o.map);
  const vision::cloud::PointCloud cloud = vision::cloud::ReadCloud(sidecar_path, &sidecar);
  if (sidecar.frame != "0") {
    throw std::invalid_argument("--map " + o.map + ": points are in frame \"" + sidecar.frame +
                                "\", the planner needs the robot base frame \"0\"");
  }
  control::WeldMap map;
  map.p_0.reserve(cloud.size());
  for (const Eigen::Vector3f& p : cloud.points) map.p_0.push_back(p.cast<double>());
  if (cloud.has_normals() && cloud.CountMissingNormals() == 0) {
    for (const Eigen::Vector3f& n : cloud.normals) map.n_0.push_back(n.cast<double>());
  }
  // The robot that made the map (its D-H in the sidecar) is the one the plan is for.
  robots::Weld5Model model = sim::WeldCellWorldConfig().nominal;
  if (sidecar.robot_dh.size() == static_cast<size_t>(robots::kWeld5Joints)) {
    for (int j = 0; j < robots::kWeld5Joints; ++j) {
      const vision::cloud::SidecarDhLink& l = sidecar.robot_dh[static_cast<size_t>(j)];
      robots::DhJoint& d = model.joints[static_cast<size_t>(j)];
      d.a = l.a;
      d.alpha = l.alpha;
      d.d = l.d;
      d.theta_offset = l.theta_offset;
      d.prismatic = l.prismatic;
    }
    model.X_5T = sidecar.X_5T;
  }
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
  const auto t0 = std::chrono::steady_clock::now();
  const control::WeldPlan plan = control::PlanWeldRepair(map, model, options);
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
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
  control::WeldPlanMetadata m;
  m.source = o.map;
  m.robot = sidecar.robot_calibration;
  control::WriteWeldPlan(o.out, plan, m);
  std::printf("wrote %s", o.out.c_str());
  if (!plan.regions.empty()) {
    const std::string top =
        o.top.empty() ? fs::path(o.out).replace_extension("").string() + "_top.png" : o.top;
    const std::string section =
        o.section.empty() ? fs::path(o.out).replace_extension("").string() + "_section.png"
                          : o.section;
    control::WriteWeldPlanTopView(top, plan);
    control::WriteWeldPlanSection(section, plan, 0);
    std::printf(", %s, %s", top.c_str(), section.c_str());
  }
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
  const control::WeldPlan& plan = file.plan;
  if (plan.trajectory.empty()) {
    std::printf("weld-run: %s has no trajectory (%s)\n", o.plan.c_str(),
                control::ToString(plan.summary.status));
    return kExitJobFailed;
  }
  WeldRigOptions ro;
  ro.config = o.config;
  WeldRig rig(ro);
  hal::WeldRobotClient& robot = rig.robot();
  // Where the plan starts: the robot must be there (the first segment is timed from q_start).
  const robots::Vector5d q0 = rig.Joints();
  if ((q0 - plan.options.q_start).cwiseAbs().maxCoeff() > 1e-3) {
    const std::string moved = rig.MoveTo(plan.options.q_start, 0.5);
    if (!moved.empty()) {
      std::printf("weld-run: moving to the plan's start: %s\n", moved.c_str());
      return kExitHardware;
    }
  }
  if (!o.no_arc) {
    hal::WeldParameters p;
    p.current = plan.options.process.current;
    p.voltage = plan.options.process.voltage;
    p.wire_feed_speed = plan.options.process.wire_feed_speed;
    if (const std::error_code ec = robot.SetWeldParameters(p)) {
      std::printf("weld-run: weld set-points: %s\n", ec.message().c_str());
      return kExitHardware;
    }
    if (const std::error_code ec = robot.ArcOn()) {
      std::printf("weld-run: arc enable: %s\n", ec.message().c_str());
      robot.Stop();
      return kExitHardware;
    }
  }
  // The joints read back after each completed segment: the executed targets.
  std::vector<control::ExecutedTorchPose> executed;
  std::vector<hal::WeldJoints> executed_joints;
  size_t last_executed = 0;
  size_t last_report = 0;
  const size_t total = plan.trajectory.size();
  std::atomic<bool> cancel{false};
  auto progress = [&](const hal::WeldStreamProgress& p) {
    if (StopRequested()) cancel = true;  // Ctrl-C: the driver stops the robot, arc off
    if (p.executed > last_executed) {
      // The status read that saw segment executed-1 complete: its joints are that target's
      // (within one poll period of motion along the next segment).
      executed_joints.push_back(p.joints);
      control::ExecutedTorchPose e;
      e.trajectory_index = p.executed - 1;
      executed.push_back(e);
      last_executed = p.executed;
    }
    if (p.executed >= last_report + total / 10 || p.executed == total) {
      spdlog::info("weld-run: {}/{} segments executed, buffer {}/{}, arc {}", p.executed, total,
                   p.buffer_level, p.buffer_capacity, p.arc_on ? "on" : "off");
      last_report = p.executed;
    }
  };
  hal::WeldStreamReport report;
  const std::error_code ec =
      robot.StreamTrajectory(plan.trajectory, progress, &cancel, hal::WeldStreamOptions(), &report);
  const std::error_code arc_off = robot.ArcOff();
  std::printf(
      "weld-run: %zu of %zu segments executed in %.1f s, highest buffer level %d, %llu "
      "waits\n",
      report.executed, report.total, std::chrono::duration<double>(report.elapsed).count(),
      report.max_buffer_level, static_cast<unsigned long long>(report.buffer_full_waits));
  if (ec) {
    std::printf("weld-run: stopped: %s; safe state (motion stopped, arc off) %s\n",
                report.message.c_str(),
                report.safe_state_confirmed ? "confirmed" : "NOT confirmed");
    return ec == std::errc::operation_canceled ? kExitJobFailed : kExitHardware;
  }
  if (arc_off) std::printf("weld-run: arc off: %s\n", arc_off.message().c_str());

  if (rig.simulated()) {
    // Executed torch poses through the TRUE kinematics; stand-off against the plan's surface
    // (the robot's error) and against the true surface (everything: scanner, mount, robot).
    const robots::Weld5Model& truth_robot = rig.world()->true_model();
    const vision::render::LaserScene truth(rig.world()->config().workpiece);
    const Eigen::Isometry3d& X_0S = rig.world()->config().X_0S;
    for (size_t i = 0; i < executed.size(); ++i) {
      robots::Vector5d q;
      for (int j = 0; j < 5; ++j) q(j) = executed_joints[i][static_cast<size_t>(j)];
      robots::Weld5Data fk;
      robots::Weld5ForwardKinematics(truth_robot, q, &fk);
      executed[i].X_0T = fk.X_0T;
    }
    const control::StandOffComparison c = control::CompareStandOff(plan, executed);
    std::printf(
        "  stand-off vs the planned surface (true robot): mean |e| %.3f mm, rms %.3f mm, "
        "max %.3f mm over %.1f mm of arc-on path (%zu samples)\n",
        1e3 * c.mean_abs_error, 1e3 * c.rms_error, 1e3 * c.max_abs_error, 1e3 * c.path_length,
        c.samples.size());
    // True stand-off on the bottom layers, whose deposition surface is the scanned one.
    double sum = 0.0, sum2 = 0.0, worst = 0.0, path = 0.0;
    int n = 0;
    Eigen::Vector3d previous = Eigen::Vector3d::Constant(std::nan(""));
    size_t previous_index = 0;
    for (const control::ExecutedTorchPose& e : executed) {
      const control::TrajectorySource& src = plan.trajectory_source[e.trajectory_index];
      if (src.layer != 0 || src.point < 0 || !plan.trajectory[e.trajectory_index].arc_on) continue;
      const control::WeldPoint& wp = plan.regions[static_cast<size_t>(src.region)]
                                         .layers[0]
                                         .beads[static_cast<size_t>(src.bead)]
                                         .points[static_cast<size_t>(src.point)];
      const Eigen::Vector3d tip = e.X_0T.translation();
      const Eigen::Vector3d axis = e.X_0T.linear().col(2);
      // The tip-to-surface distance along the axis: secant iteration on the height error.
      double t0 = wp.stand_off - 2e-3, t1 = wp.stand_off + 2e-3;
      double f0 = TrueSurfaceError(truth, X_0S, tip + t0 * axis);
      double f1 = TrueSurfaceError(truth, X_0S, tip + t1 * axis);
      for (int it = 0; it < 20 && std::abs(f1) > 1e-9 && f1 != f0; ++it) {
        const double t2 = t1 - f1 * (t1 - t0) / (f1 - f0);
        t0 = t1;
        f0 = f1;
        t1 = t2;
        f1 = TrueSurfaceError(truth, X_0S, tip + t1 * axis);
      }
      const double err = t1 - wp.stand_off;
      sum += std::abs(err);
      sum2 += err * err;
      worst = std::max(worst, std::abs(err));
      // Path length along consecutive arc-on targets only (not across air moves).
      if (previous.allFinite() && e.trajectory_index == previous_index + 1) {
        path += (tip - previous).norm();
      }
      previous = tip;
      previous_index = e.trajectory_index;
      ++n;
    }
    if (n > 0) {
      std::printf(
          "  simulation truth: stand-off vs the true surface, bottom layer: mean |e| %.3f "
          "mm, rms %.3f mm, max %.3f mm over %d points (%.1f mm of arc-on path)\n",
          1e3 * sum / n, 1e3 * std::sqrt(sum2 / n), 1e3 * worst, n, 1e3 * path);
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

void AddWeldScanCommands(CLI::App& app, CommandList* commands) {
  CLI::App* record = nullptr;
  for (CLI::App* sub : app.get_subcommands({})) {
    if (sub->get_name() == "record") record = sub;
  }
  if (record == nullptr) {
    record = app.add_subcommand("record", "Record calibration datasets on the robot");
  }
  auto add_scan_options = [](CLI::App* c, ScanOptions* o) {
    c->add_option("--config", o->config,
                  "Weld-cell world config or deployment file (default: the built-in simulated "
                  "cell)")
        ->check(CLI::ExistingFile);
    c->add_option("--scanner", o->scanner,
                  "Scanner calibration YAML (kinevis calibrate scanner; default: the nominal "
                  "geometry of seed 004 Table 2)")
        ->check(CLI::ExistingFile);
    c->add_option("--mount", o->mount,
                  "Scanner-mount calibration YAML (kinevis calibrate scanner-mount; default: the "
                  "nominal CAD mount). With --dh there, its D-H errors too")
        ->check(CLI::ExistingFile);
    c->add_option("--at", o->at,
                  "Move here first: theta1,theta2,pz3,theta4,theta5 in deg, deg, mm, deg, deg "
                  "(default: scan from where the robot stands)");
    c->add_option("--lines", o->lines, "Frames in the sweep (2-2000)")
        ->check(CLI::Range(2, 2000))
        ->capture_default_str();
    c->add_option("--depth", o->depth,
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
  scan->add_option("--dataset", so->dataset, "Rebuild the map from a recorded scan dataset")
      ->check(CLI::ExistingDirectory);
  scan->add_option("--record", so->record, "Also keep the frames as a scan dataset here");
  scan->add_option("--out", so->out, "The map: X.ply and its sidecar X.yaml")
      ->capture_default_str();
  scan->get_option("--dataset")->excludes("--config")->excludes("--record")->excludes("--at");
  commands->push_back({scan, [so] { return RunScan(*so); }});

  auto rso = std::make_shared<ScanOptions>();
  CLI::App* rs = record->add_subcommand(
      "scan",
      "Record a laser sweep (images + joint readings) as a scan dataset (docs/point-clouds.md)");
  add_scan_options(rs, rso.get());
  rs->add_option("--out", rso->out, "Dataset directory to create")->required();
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
