#include "rigs/weld/weld_repair_jobs.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <memory>
#include <stdexcept>

#include "calibration/weld_mount/mount_calibration_io.h"
#include "calibration/weld_mount/scan_dataset.h"
#include "common/stopwatch.h"
#include "control/weld/weld_plan_io.h"
#include "rigs/weld/weld_calibration_jobs.h"
#include "sim/weld_cell_world.h"
#include "vision/camera/camera_file.h"
#include "vision/cloud/cloud_sidecar.h"
#include "vision/laser/scan_lines.h"
#include "vision/render/scenes/laser_scene.h"

namespace kinevis::rigs {
namespace {

namespace fs = std::filesystem;

// The sidecar path for a map named X.ply or X.yaml.
std::string SidecarPath(const std::string& map) {
  fs::path p(map);
  if (p.extension() == ".yaml") return map;
  return p.replace_extension(".yaml").string();
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

ScanFrames SweepDataset(const calibration::ScanDataset& d,
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

}  // namespace

vision::laser::ScannerGeometry LoadScannerGeometry(const std::string& path, std::string* source) {
  if (path.empty()) {
    *source = "nominal (seed 004 Table 2; no --scanner calibration given)";
    return vision::laser::ScannerGeometry::Seed004();
  }
  const calibration::LaserScannerCalibrationFile file = ReadCalibratedScanner(path);
  *source = path;
  return file.result.geometry;
}

ScanFrames SweepScanner(WeldRig* rig, const vision::laser::ScannerModel& model,
                        const ScanJobOptions& o) {
  if (o.at) {
    const std::string moved = rig->MoveTo(*o.at, 0.5);
    if (!moved.empty()) throw std::runtime_error("scan: moving to --at: " + moved);
  }
  calibration::ScanDataset dataset;
  if (!o.record.empty()) {
    dataset.directory = o.record;
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
    if (o.stop_requested && o.stop_requested()) throw std::runtime_error("scan: interrupted");
    const double commanded = rig->simulated() ? sweep[static_cast<size_t>(k)] : std::nan("");
    if (rig->simulated()) rig->SetLaserAngle(commanded);
    robots::Vector5d q;
    const std::string grabbed = rig->GrabFresh(&image, &q);
    if (!grabbed.empty())
      throw std::runtime_error("scan: frame " + std::to_string(k) + ": " + grabbed);
    const vision::ImageView8 view{image.data.data(), image.width, image.height, image.stride};
    if (!o.record.empty()) {
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

ScanJobReport ScanWorkpiece(WeldRig* rig, const ScanJobOptions& o) {
  if ((rig == nullptr) == o.dataset.empty()) {
    throw std::invalid_argument("scan: give either the cell or a scan dataset, not both");
  }
  ScanJobReport r;
  r.geometry = LoadScannerGeometry(o.scanner, &r.scanner_source);
  robots::Weld5Model robot = sim::WeldCellWorldConfig().nominal;
  Eigen::Isometry3d X_5C = sim::NominalScannerMount();
  r.mount_source = "nominal (CAD; no --mount calibration given)";
  r.robot_source = "nominal (seed 004 D-H, built-in)";
  const common::Stopwatch t0;
  if (rig != nullptr) {
    robot = rig->nominal();
    X_5C = rig->X_5C_nominal();
    r.robot_source = rig->robot_description().empty() ? "nominal (" + rig->config_path() + ")"
                                                      : rig->robot_description();
    const vision::laser::ScannerModel model(rig->camera_model(), r.geometry);
    r.frames = SweepScanner(rig, model, o);
  } else {
    const calibration::ScanDataset d = calibration::ReadScanDataset(o.dataset);
    const std::unique_ptr<vision::CameraModel> camera = vision::OpenCameraModel(d.camera_model);
    const vision::laser::ScannerModel model(*camera, r.geometry);
    r.frames = SweepDataset(d, model);
  }
  r.wall_seconds = t0.Seconds();
  if (!o.mount.empty()) {
    // The calibrated mount, and the D-H errors when they were estimated with it.
    const calibration::ScannerMountCalibrationFile mount =
        calibration::ReadScannerMountCalibration(o.mount);
    X_5C = calibration::ReadScannerMount(o.mount);
    r.mount_source = o.mount;
    if (mount.dh_estimated) {
      robot = calibration::CalibratedRobot(mount, robot);
      r.robot_source += " + D-H errors from " + o.mount;
    }
  }
  if (r.frames.lines.empty()) return r;

  const calibration::ScanCloud cloud = calibration::ScansToCloud(robot, X_5C, r.frames.lines);
  vision::cloud::CloudSidecar sidecar = calibration::MakeCloudSidecar(
      robot, r.robot_source, X_5C, r.mount_source, r.frames.lines.size());
  r.sidecar_path = SidecarPath(o.out);
  sidecar.ply = fs::path(o.out).replace_extension(".ply").filename().string();
  sidecar.source = rig == nullptr     ? "kinevis scan --dataset " + o.dataset
                   : rig->simulated() ? "kinevis scan (simulated weld cell)"
                                      : "kinevis scan (weld cell)";
  sidecar.scanner_calibration = r.scanner_source;
  sidecar.scanner_parameters = {{"rotating_b_y_mm", 1e3 * r.geometry.rotating_b_y},
                                {"rotating_d_y_mm", 1e3 * r.geometry.rotating_d_y},
                                {"fixed_b_x_prime_mm", 1e3 * r.geometry.fixed_b_x_prime},
                                {"fixed_cot_theta_x", r.geometry.fixed_cot_theta_x}};
  vision::cloud::WriteCloud(r.sidecar_path, cloud.cloud, sidecar);
  r.ply_path = (fs::path(r.sidecar_path).parent_path() / sidecar.ply).string();
  r.points = cloud.cloud.size();
  r.normals_estimated = cloud.normals.estimated;
  r.normals_missing = cloud.normals.missing;

  if (rig != nullptr && rig->simulated() && r.points > 0) {
    const vision::render::LaserScene truth(rig->world()->config().workpiece);
    double sum2 = 0.0, worst = 0.0, sum = 0.0;
    for (const Eigen::Vector3f& p : cloud.cloud.points) {
      const double e = TrueSurfaceError(truth, rig->world()->config().X_0S, p.cast<double>());
      sum += e;
      sum2 += e * e;
      worst = std::max(worst, std::abs(e));
    }
    const double n = static_cast<double>(r.points);
    r.has_truth = true;
    r.truth_mean_error = sum / n;
    r.truth_rms_error = std::sqrt(sum2 / n);
    r.truth_max_error = worst;
  }
  return r;
}

WeldPathRun PlanWeldPath(const std::string& map_path, const control::WeldPlanOptions& options,
                         const std::string& out, const std::string& top,
                         const std::string& section) {
  vision::cloud::CloudSidecar sidecar;
  const std::string sidecar_path = SidecarPath(map_path);
  const vision::cloud::PointCloud cloud = vision::cloud::ReadCloud(sidecar_path, &sidecar);
  if (sidecar.frame != "0") {
    throw std::invalid_argument("--map " + map_path + ": points are in frame \"" + sidecar.frame +
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
  WeldPathRun r;
  const common::Stopwatch t0;
  r.plan = control::PlanWeldRepair(map, model, options);
  r.wall_seconds = t0.Seconds();
  control::WeldPlanMetadata m;
  m.source = map_path;
  m.robot = sidecar.robot_calibration;
  control::WriteWeldPlan(out, r.plan, m);
  if (!r.plan.regions.empty()) {
    const std::string stem = fs::path(out).replace_extension("").string();
    r.top = top.empty() ? stem + "_top.png" : top;
    r.section = section.empty() ? stem + "_section.png" : section;
    control::WriteWeldPlanTopView(r.top, r.plan);
    control::WriteWeldPlanSection(r.section, r.plan, 0);
  }
  return r;
}

const char* ToString(WeldRunOutcome outcome) {
  switch (outcome) {
    case WeldRunOutcome::kCompleted:
      return "completed";
    case WeldRunOutcome::kNoTrajectory:
      return "no trajectory";
    case WeldRunOutcome::kStartNotReached:
      return "start not reached";
    case WeldRunOutcome::kWeldParameters:
      return "weld parameters refused";
    case WeldRunOutcome::kArcOnFailed:
      return "arc did not come on";
    case WeldRunOutcome::kCancelled:
      return "cancelled";
    case WeldRunOutcome::kStopped:
      return "stopped";
  }
  return "?";
}

WeldRunReport RunWeldPlan(WeldRig* rig, const control::WeldPlan& plan, const WeldRunOptions& o) {
  WeldRunReport r;
  if (plan.trajectory.empty()) {
    r.outcome = WeldRunOutcome::kNoTrajectory;
    r.message =
        std::string("the plan has no trajectory (") + control::ToString(plan.summary.status) + ")";
    return r;
  }
  hal::WeldRobotClient& robot = rig->robot();
  // Where the plan starts: the robot must be there (the first segment is timed from q_start).
  const robots::Vector5d q0 = rig->Joints();
  if ((q0 - plan.options.q_start).cwiseAbs().maxCoeff() > 1e-3) {
    const std::string moved = rig->MoveTo(plan.options.q_start, 0.5);
    if (!moved.empty()) {
      r.outcome = WeldRunOutcome::kStartNotReached;
      r.message = "moving to the plan's start: " + moved;
      return r;
    }
  }
  if (o.arc) {
    hal::WeldParameters p;
    p.current = plan.options.process.current;
    p.voltage = plan.options.process.voltage;
    p.wire_feed_speed = plan.options.process.wire_feed_speed;
    if (const std::error_code ec = robot.SetWeldParameters(p)) {
      r.outcome = WeldRunOutcome::kWeldParameters;
      r.message = "weld set-points: " + ec.message();
      return r;
    }
    if (const std::error_code ec = robot.ArcOn()) {
      r.outcome = WeldRunOutcome::kArcOnFailed;
      r.message = "arc enable: " + ec.message();
      robot.Stop();
      return r;
    }
  }
  std::vector<hal::WeldJoints> executed_joints;
  size_t last_executed = 0;
  size_t last_report = 0;
  const size_t total = plan.trajectory.size();
  std::atomic<bool> cancel{false};
  auto progress = [&](const hal::WeldStreamProgress& p) {
    if (o.stop_requested && o.stop_requested()) cancel = true;  // the driver stops, arc off
    if (p.executed > last_executed) {
      // The status read that saw segment executed-1 complete: its joints are that target's
      // (within one poll period of motion along the next segment).
      executed_joints.push_back(p.joints);
      control::ExecutedTorchPose e;
      e.trajectory_index = p.executed - 1;
      r.executed.push_back(e);
      last_executed = p.executed;
    }
    if (p.executed >= last_report + total / 10 || p.executed == total) {
      spdlog::info("weld-run: {}/{} segments executed, buffer {}/{}, arc {}", p.executed, total,
                   p.buffer_level, p.buffer_capacity, p.arc_on ? "on" : "off");
      last_report = p.executed;
    }
  };
  const std::error_code ec = robot.StreamTrajectory(plan.trajectory, progress, &cancel,
                                                    hal::WeldStreamOptions(), &r.stream);
  // Whatever happened: the arc off.
  if (const std::error_code arc_off = robot.ArcOff()) r.arc_off_error = arc_off.message();
  if (ec) {
    r.outcome =
        ec == std::errc::operation_canceled ? WeldRunOutcome::kCancelled : WeldRunOutcome::kStopped;
    r.message = r.stream.message;
    return r;
  }
  r.outcome = WeldRunOutcome::kCompleted;
  if (!rig->simulated()) return r;

  // Executed torch poses through the TRUE kinematics; stand-off against the plan's surface (the
  // robot's error) and against the true surface (everything: scanner, mount, robot).
  const robots::Weld5Model& truth_robot = rig->world()->true_model();
  const vision::render::LaserScene truth(rig->world()->config().workpiece);
  const Eigen::Isometry3d& X_0S = rig->world()->config().X_0S;
  for (size_t i = 0; i < r.executed.size(); ++i) {
    robots::Vector5d q;
    for (int j = 0; j < 5; ++j) q(j) = executed_joints[i][static_cast<size_t>(j)];
    robots::Weld5Data fk;
    robots::Weld5ForwardKinematics(truth_robot, q, &fk);
    r.executed[i].X_0T = fk.X_0T;
  }
  r.has_truth = true;
  r.planned_surface = control::CompareStandOff(plan, r.executed);
  // True stand-off on the bottom layers, whose deposition surface is the scanned one.
  double sum = 0.0, sum2 = 0.0, worst = 0.0, path = 0.0;
  int n = 0;
  Eigen::Vector3d previous = Eigen::Vector3d::Constant(std::nan(""));
  size_t previous_index = 0;
  for (const control::ExecutedTorchPose& e : r.executed) {
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
  r.true_surface_points = n;
  if (n > 0) {
    r.true_surface_mean_abs = sum / n;
    r.true_surface_rms = std::sqrt(sum2 / n);
    r.true_surface_max = worst;
    r.true_surface_path = path;
  }
  return r;
}

}  // namespace kinevis::rigs
