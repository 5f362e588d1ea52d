// The DIAMOND jobs (diamond_jobs.h): record, calibrate, servo on a DiamondRig.

#include "rigs/diamond/diamond_jobs.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "calibration/diamond/diamond_calibration_io.h"
#include "common/stopwatch.h"
#include "common/units.h"
#include "control/diamond/camera_marker_source.h"
#include "hal/common/error.h"
#include "hal/common/realtime.h"
#include "hal/drive/rs485_drive.h"
#include "sim/diamond_world.h"
#include "vision/camera/camera_file.h"
#include "vision/diamond/spherical_positioning.h"

namespace kinevis::rigs {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

// --- record -------------------------------------------------------------------------------------

// `n` of the task points the camera sees, spread evenly over the visible workspace and ordered
// nearest-first from `start` (short moves).
std::vector<Eigen::Vector2d> PlanTaskPoints(const DiamondRig& rig, const DiamondRecordOptions& o,
                                            const Eigen::Vector2d& start) {
  // The nominal model predicts where the marker is; the true robot puts it elsewhere (the
  // a-priori R is 10 % short of the seed's identified one: up to ~100 px at the image's edge).
  const double margin_px =
      o.margin_px >= 0 ? o.margin_px
                       : 0.1 * std::min(rig.camera_model().width(), rig.camera_model().height());
  std::vector<Eigen::Vector2d> grid;
  // A grid a few times finer than the samples, for the sampling below to choose from.
  for (int g = 16; g <= 400; g = g * 5 / 4 + 1) {
    grid = calibration::DiamondVisibleTaskGrid(rig.nominal(), rig.camera_model(), rig.X_OC(), g, g,
                                               o.inset, margin_px);
    if (static_cast<int>(grid.size()) >= 4 * o.samples) break;
  }
  if (static_cast<int>(grid.size()) < o.samples) {
    throw std::invalid_argument(
        "only " + std::to_string(grid.size()) + " task points of the workspace " +
        "put the marker in the image of camera " + rig.camera_name() + " (" +
        std::to_string(o.samples) + " asked for); is its pose in " +
        (rig.config_path().empty() ? std::string("the built-in world") : rig.config_path()) +
        " right?");
  }
  // Farthest-point sampling: each next point is the grid point farthest from those chosen, so
  // that any n cover the visible workspace evenly, its border included (both φ and γ must vary
  // for α, β and the offsets to be told apart).
  std::vector<Eigen::Vector2d> chosen;
  std::vector<double> distance(grid.size(), std::numeric_limits<double>::infinity());
  size_t next = 0;
  for (size_t i = 1; i < grid.size(); ++i) {
    if ((grid[i] - start).norm() < (grid[next] - start).norm()) next = i;
  }
  while (static_cast<int>(chosen.size()) < o.samples) {
    chosen.push_back(grid[next]);
    for (size_t i = 0; i < grid.size(); ++i) {
      distance[i] = std::min(distance[i], (grid[i] - grid[next]).norm());
    }
    next =
        static_cast<size_t>(std::max_element(distance.begin(), distance.end()) - distance.begin());
  }
  std::vector<Eigen::Vector2d> ordered;
  Eigen::Vector2d here = start;
  while (!chosen.empty()) {
    size_t best = 0;
    for (size_t i = 1; i < chosen.size(); ++i) {
      if ((chosen[i] - here).cwiseAbs().maxCoeff() < (chosen[best] - here).cwiseAbs().maxCoeff()) {
        best = i;
      }
    }
    here = chosen[best];
    ordered.push_back(here);
    chosen.erase(chosen.begin() + static_cast<std::ptrdiff_t>(best));
  }
  return ordered;
}

void WriteSimulationTruth(const std::string& dir, const DiamondRig& rig) {
  const robots::DiamondModel& t = rig.world()->true_model();
  const Eigen::Isometry3d& X = rig.X_OC();  // the simulated rig's camera pose is the true one
  const Eigen::Vector3d ypr = X.linear().eulerAngles(2, 1, 0);
  const std::string path = (fs::path(dir) / kDiamondTruthFile).string();
  std::FILE* f = std::fopen(path.c_str(), "w");
  if (f == nullptr) throw std::runtime_error("cannot write " + path);
  std::fprintf(f,
               "# The simulated world's truth when this dataset was recorded (kinevis record "
               "diamond); for comparison only,\n# never read by the identification. SI units.\n");
  std::fprintf(f, "kind: kinevis-diamond-simulation-truth\nversion: 1\n");
  std::fprintf(f, "recorded_on: \"%s\"\n",
               rig.config_path().empty() ? "built-in" : rig.config_path().c_str());
  std::fprintf(f, "radius: %.17g\nalpha: %.17g\nbeta: %.17g\n", t.radius, t.alpha, t.beta);
  std::fprintf(f, "joint_offsets: [%.17g, %.17g]\n", t.joint_offsets[0], t.joint_offsets[1]);
  std::fprintf(f,
               "camera_pose: {position: [%.17g, %.17g, %.17g], rpy_deg: [%.17g, %.17g, "
               "%.17g]}\n",
               X.translation().x(), X.translation().y(), X.translation().z(), ypr[2] / common::kDeg,
               ypr[1] / common::kDeg, ypr[0] / common::kDeg);
  if (std::fclose(f) != 0) throw std::runtime_error("cannot write " + path);
}

bool ReadSimulationTruth(const std::string& dir, DiamondSimulationTruth* truth) {
  const std::string path = (fs::path(dir) / kDiamondTruthFile).string();
  if (!fs::exists(path)) return false;
  sim::internal::WorldConfigReader r(path, "");
  if (r.Text("kind", "") != "kinevis-diamond-simulation-truth") {
    r.Problem("kind: expected kinevis-diamond-simulation-truth");
  }
  truth->model = robots::DiamondModel::SeedIdentified();
  truth->model.radius = r.Number("radius", NAN);
  truth->model.alpha = r.Number("alpha", NAN);
  truth->model.beta = r.Number("beta", NAN);
  const std::vector<double> o = r.Numbers("joint_offsets", 2, {NAN, NAN});
  truth->model.joint_offsets = {o[0], o[1]};
  truth->X_OC = r.Pose("camera_pose", Eigen::Isometry3d::Identity());
  r.CheckKeys("", {"kind", "version", "recorded_on", "radius", "alpha", "beta", "joint_offsets",
                   "camera_pose"});
  r.ThrowIfProblems();
  return true;
}

}  // namespace

std::string FormatTaskDeg(const Eigen::Vector2d& task) {
  char text[64];
  std::snprintf(text, sizeof text, "(%.2f, %.2f) deg", task[0] / common::kDeg,
                task[1] / common::kDeg);
  return text;
}

DiamondRecordSummary RecordDiamondDataset(DiamondRig* rig, const DiamondRecordOptions& o) {
  if (o.samples < 10 || !(o.speed > 0) || !(o.inset >= 0)) {
    throw std::invalid_argument("--samples must be >= 10, --speed > 0, inset >= 0");
  }
  const common::Stopwatch t0;
  DiamondRecordSummary summary;
  summary.simulated = rig->simulated();
  rig->Enable();
  robots::DiamondData data;
  robots::ForwardKinematics(rig->nominal(), rig->Readings(), &data);
  const Eigen::Vector2d home = data.valid ? data.task : Eigen::Vector2d(M_PI / 2, M_PI / 4);
  const std::vector<Eigen::Vector2d> tasks = PlanTaskPoints(*rig, o, home);
  summary.planned = static_cast<int>(tasks.size());
  spdlog::info("record diamond: {} task points planned", tasks.size());

  calibration::DiamondDataset dataset;
  dataset.directory = o.out;
  dataset.robot_file = rig->robot_description();
  dataset.nominal = rig->nominal();
  dataset.camera_name = rig->camera_name();
  dataset.camera_model = rig->camera_model_spec();
  dataset.X_OC = rig->X_OC();
  dataset.camera_distance_source = rig->camera_distance_source();
  dataset.source =
      (rig->simulated() ? "simulated world " : "deployment ") +
      (rig->config_path().empty() ? std::string("(built-in defaults)") : rig->config_path());
  calibration::CreateDiamondDataset(&dataset);
  if (rig->simulated()) {
    WriteSimulationTruth(o.out, *rig);
    summary.truth_file = (fs::path(o.out) / kDiamondTruthFile).string();
  }

  // Checked at once, so that the operator hears of a marker out of view while at the robot.
  vision::MarkerDetector detector(rig->detector_options());
  const Eigen::Vector2d centre =
      vision::TaskFromPoint<double>(Eigen::Vector3d(rig->X_OC().translation()));
  hal::Image image;
  for (size_t k = 0; k < tasks.size(); ++k) {
    if (o.stop_requested && o.stop_requested()) {
      summary.stopped = "interrupted";
      break;
    }
    // Where the camera looks: a marker the nominal model put in the image but the true robot did
    // not is looked for again nearer the view's centre (up to two retries).
    Eigen::Vector2d task = tasks[k];
    vision::MarkerDetection m;
    bool failed = false;
    for (int attempt = 0; attempt < 3; ++attempt) {
      if (attempt > 0) task += 0.3 * (centre - task);
      const control::DiamondLoopReport moved = rig->MoveTo(task, o.speed);
      if (moved.outcome != control::DiamondLoopOutcome::kCompleted) {
        summary.stopped = "moving to " + FormatTaskDeg(task) + ": " +
                          control::ToString(moved.outcome) + ": " + moved.message;
        summary.hardware_fault = moved.outcome == control::DiamondLoopOutcome::kDriveFault ||
                                 moved.outcome == control::DiamondLoopOutcome::kNotStarted;
        failed = true;
        break;
      }
      if (std::string why = rig->GrabFresh(&image); !why.empty()) {
        summary.stopped = why;
        summary.hardware_fault = true;
        failed = true;
        break;
      }
      m = detector.Detect(
          vision::ImageView8{image.data.data(), image.width, image.height, image.stride});
      if (m.found()) break;
      ++summary.retries;
    }
    if (failed) break;
    calibration::DiamondDatasetSample s;
    s.index = static_cast<int>(k);
    char name[48];
    std::snprintf(name, sizeof name, "images/sample_%04zu.png", k);
    s.image = name;
    s.q = rig->Readings();
    calibration::AppendDiamondDatasetSample(dataset, s, image.data.data(), image.width,
                                            image.height, image.stride);
    ++summary.recorded;
    if (!m.found()) {
      summary.marker_not_found.push_back(std::string(name) + " at " + FormatTaskDeg(task) + ": " +
                                         vision::ToString(m.status));
    }
    spdlog::debug("record diamond: sample {}/{} at {}", k + 1, tasks.size(), FormatTaskDeg(task));
  }
  if (!summary.hardware_fault) rig->MoveTo(home, o.speed);
  rig->Release();
  summary.wall_seconds = t0.Seconds();
  return summary;
}

// --- calibrate ----------------------------------------------------------------------------------

DiamondCalibrationRun CalibrateDiamondFromDataset(const DiamondCalibrateOptions& o) {
  if (o.residual != "pixel" && o.residual != "spherical") {
    throw std::invalid_argument("--residual " + o.residual + ": expected pixel or spherical");
  }
  DiamondCalibrationRun run;
  run.dataset = o.dataset;
  run.out = o.out;
  const calibration::DiamondDataset d = calibration::ReadDiamondDataset(o.dataset);
  const std::string camera_spec = d.camera_model.rfind("builtin:", 0) == 0
                                      ? d.camera_model
                                      : (fs::path(o.dataset) / d.camera_model).string();
  const std::unique_ptr<vision::CameraModel> camera = vision::OpenCameraModel(camera_spec);
  vision::MarkerDetector detector(DiamondDetectorOptions(*camera, d.X_OC, d.nominal));

  run.images = static_cast<int>(d.samples.size());
  std::vector<calibration::DiamondSample> samples;
  const common::Stopwatch t0;
  for (const calibration::DiamondDatasetSample& s : d.samples) {
    calibration::DiamondSample sample;
    sample.q = s.q;
    if (s.has_pixel) {
      sample.pixel = s.pixel;
      samples.push_back(sample);
      continue;
    }
    const std::string where = "sample " + std::to_string(s.index) + " (" + s.image + ")";
    if (s.image.empty()) {
      run.not_detected.push_back(where + ": no image and no pixel");
      continue;
    }
    int width = 0, height = 0;
    std::vector<uint8_t> pixels = calibration::ReadDiamondDatasetImage(d, s, &width, &height);
    if (width != camera->width() || height != camera->height()) {
      throw std::invalid_argument("" + where + " is " + std::to_string(width) + "x" +
                                  std::to_string(height) + " but the camera model " +
                                  d.camera_model + " is for " + std::to_string(camera->width()) +
                                  "x" + std::to_string(camera->height()));
    }
    const vision::MarkerDetection m = detector.Detect(
        vision::ImageView8{pixels.data(), width, height, static_cast<size_t>(width)});
    if (!m.found()) {
      run.not_detected.push_back(where + ": " + vision::ToString(m.status));
      continue;
    }
    sample.pixel = m.pixel;
    samples.push_back(sample);
  }
  run.detection_seconds = t0.Seconds();
  run.detected = static_cast<int>(samples.size());

  calibration::DiamondIdentificationOptions options;
  options.residual = o.residual == "spherical" ? calibration::DiamondResidual::kSpherical
                                               : calibration::DiamondResidual::kPixel;
  options.pixel_sigma = o.pixel_sigma;
  options.estimate_camera_distance = o.estimate_camera_distance;
  const common::Stopwatch t1;
  run.summary = calibration::IdentifyDiamond(samples, *camera, d.nominal, d.X_OC, options);
  run.identification_seconds = t1.Seconds();
  const calibration::DiamondIdentificationSummary& s = run.summary;
  bool all_identified = true;
  for (const calibration::DiamondParameterEstimate& p : s.parameters) {
    if (p.estimated && !p.identified) all_identified = false;
  }
  run.identified = s.ok() && s.identifiability.rank == s.identifiability.parameters &&
                   s.identifiability.parameters > 0 && all_identified;

  calibration::DiamondCalibrationMetadata metadata;
  metadata.camera = d.camera_name + " (" + d.camera_model + ")";
  metadata.robot =
      d.robot_file.empty() ? std::string("") : (fs::path(o.dataset) / d.robot_file).string();
  metadata.source = "dataset " + o.dataset + " (" + std::to_string(d.samples.size()) +
                    " samples, " + d.source + ")";
  calibration::WriteDiamondCalibration(o.out, s, metadata);
  run.has_truth = ReadSimulationTruth(o.dataset, &run.truth);
  return run;
}

// --- servo --------------------------------------------------------------------------------------

namespace {

struct ControllerModel {
  robots::DiamondModel model;
  Eigen::Isometry3d X_OC = Eigen::Isometry3d::Identity();
  std::string source;
};

ControllerModel LoadControllerModel(const DiamondRig& rig, const std::string& calib) {
  ControllerModel m;
  if (calib.empty()) {
    m.model = rig.nominal();
    m.X_OC = rig.X_OC();
    m.source = "a priori (" +
               (rig.robot_description().empty() ? std::string("built-in a-priori set")
                                                : rig.robot_description()) +
               ", camera pose of the config)";
    return m;
  }
  const calibration::DiamondCalibrationFile f = calibration::ReadDiamondCalibration(calib);
  if (!f.summary.ok()) {
    throw std::invalid_argument(calib + ": the identification did not converge (status " +
                                std::string(calibration::ToString(f.summary.status)) +
                                "); re-calibrate");
  }
  m.model = f.summary.model;
  m.X_OC = f.summary.X_OC;
  m.source = "identified (" + calib + ")";
  return m;
}

// Every point of the line must be in the controller's workspace (the loop would stop there).
void CheckLine(const robots::DiamondModel& model, const control::DiamondLine& line) {
  if (const std::string bad = line.Validate(); !bad.empty()) {
    throw std::invalid_argument("--from/--to: " + bad);
  }
  const auto check = [&](const char* name, const Eigen::Vector2d& p) {
    const robots::DiamondReachability reach = robots::CheckWorkspace(model, p);
    if (!reach.ok()) {
      throw std::invalid_argument(std::string(name) + " " + FormatTaskDeg(p) +
                                  " is not in the workspace: " + reach.Describe());
    }
  };
  check("--from", line.from);
  check("--to", line.to);
  for (int k = 0; k <= 50; ++k) {
    Eigen::Vector2d task, rate;
    if (!control::DiamondLineReference(line, model.radius, line.duration_s * k / 50.0, &task,
                                       &rate)) {
      throw std::invalid_argument(
          "the top-view line from --from to --to leaves the sphere's projection");
    }
    const robots::DiamondReachability reach = robots::CheckWorkspace(model, task);
    if (!reach.ok()) {
      throw std::invalid_argument(
          "the line from --from to --to leaves the "
          "workspace at " +
          FormatTaskDeg(task) + ": " + reach.Describe());
    }
  }
}

}  // namespace

DiamondServoRun ServoDiamond(DiamondRig* rig, const DiamondServoOptions& o) {
  DiamondServoRun run;
  const ControllerModel controller = LoadControllerModel(*rig, o.calib);
  const ControllerModel measure = o.measure_calib.empty() || o.measure_calib == o.calib
                                      ? controller
                                      : LoadControllerModel(*rig, o.measure_calib);
  run.model_source = controller.source;
  run.model = controller.model;
  run.X_OC = controller.X_OC;
  const vision::CameraModel& camera = rig->camera_model();
  const Eigen::Isometry3d X_CO = controller.X_OC.inverse();

  control::DiamondLine line;
  line.kind = o.law == DiamondServoLaw::kTaskPd ? o.kind : control::DiamondLineKind::kTaskLine;
  line.from = o.from;
  line.to = o.to;
  line.duration_s = o.duration_s;
  if (o.law == DiamondServoLaw::kTaskPd) {
    CheckLine(controller.model, line);
  } else {
    for (const auto& [name, p] : {std::pair<const char*, Eigen::Vector2d>{"--from", o.from},
                                  std::pair<const char*, Eigen::Vector2d>{"--to", o.to}}) {
      const robots::DiamondReachability reach = robots::CheckWorkspace(controller.model, p);
      if (!reach.ok()) {
        throw std::invalid_argument(std::string(name) + " " + FormatTaskDeg(p) +
                                    " is not in the workspace: " + reach.Describe());
      }
    }
    if (camera.Project(X_CO * robots::DiamondToolPoint(controller.model.radius, o.to[0], o.to[1]),
                       &run.target_pixel) != vision::ProjectionStatus::kOk ||
        run.target_pixel.x() < 0 || run.target_pixel.y() < 0 ||
        run.target_pixel.x() > camera.width() - 1 || run.target_pixel.y() > camera.height() - 1) {
      throw std::invalid_argument("--to " + FormatTaskDeg(o.to) +
                                  ": the marker there is not in the image of camera " +
                                  rig->camera_name());
    }
  }
  Eigen::Vector2d start = line.from, rate;
  control::DiamondLineReference(line, controller.model.radius, 0.0, &start, &rate);

  // Memory is locked before the drives are enabled: mlockall of this process takes longer than
  // the drives' 200 ms watchdog, and must not fall between two cycles.
  hal::RealtimeRequest lock;
  lock.lock_memory = o.rt_lock_memory;
  const hal::ScopedRealtime locked(lock);
  if (!rig->enabled()) rig->Enable();
  run.approach = rig->MoveTo(start, o.approach_speed, &controller.model);
  run.reached_start = run.approach.outcome == control::DiamondLoopOutcome::kCompleted;
  if (!run.reached_start) {
    rig->Release();  // the loop has put the drives in their safe state; the watchdog off too
    return run;
  }

  // The camera: on a stepped simulated clock polled once per cycle without waiting (a frame is
  // rendered and processed when one is due; simulated time stands still meanwhile); on a real
  // clock in a worker thread.
  control::CameraMarkerSourceOptions camera_options;
  camera_options.detector = rig->detector_options();
  camera_options.asynchronous = rig->real_time();
  auto camera_source =
      std::make_unique<control::CameraMarkerSource>(&rig->camera(), camera_options);
  control::MarkerFeatureSource& source = *camera_source;

  std::vector<Eigen::Vector2d> measured, truth;
  double position_sq = 0.0;
  const auto locate = [&](const Eigen::Vector2d& pixel) {
    const vision::SphereFix fix =
        vision::LocateOnSphere(camera, measure.X_OC, measure.model.radius, pixel);
    if (fix.ok()) measured.push_back(fix.p_O.head<2>());
  };
  run.simulated = rig->simulated();
  run.real_time = rig->real_time();
  const robots::DiamondModel* true_model = run.simulated ? &rig->world()->true_model() : nullptr;

  control::DiamondLoopOptions lo;
  lo.cycle_period_s = rig->cycle_period_s();
  lo.max_consecutive_cycle_timeouts = 20;
  lo.timeout_s = o.timeout_s;
  control::DiamondControlLoop loop(&rig->bus(), &rig->clock(), controller.model, lo);

  // Real-time priority for this thread only, now that the camera worker and the simulators run.
  hal::RealtimeRequest rt;
  rt.priority = o.rt_priority;
  rt.cpu = o.rt_cpu;
  rt.timer_slack_ns = o.timer_slack_ns;
  const hal::ScopedRealtime scheduled(rt);
  run.realtime = scheduled.grant().message;
  if (o.rt_lock_memory) run.realtime += "; " + locked.grant().message;

  if (o.law == DiamondServoLaw::kTaskPd) {
    // Settling on the line's end to two encoder counts can take more than the default second
    // when the drive line is slow (an RS485 bus shared with other traffic, a loaded host).
    control::DiamondPdOptions pd;
    pd.settle_timeout_s = 2.0;
    control::DiamondTaskPdLaw law(controller.model, line, pd);
    run.report = loop.Run(&law, [&](const control::DiamondLoopSample& s) {
      control::MarkerFrame frame;
      const bool polled = source.Poll(rig->clock().Now(), &frame);
      if (s.time_s > line.duration_s) return;
      if (polled) {
        ++run.frames;
        if (frame.found) {
          locate(frame.pixel);
        } else {
          ++run.frames_without_marker;
        }
      }
      if (true_model != nullptr) {
        const sim::DiamondPlantState p = rig->world()->plant();
        truth.push_back(p.p_O_T.head<2>());
        const Eigen::Vector3d wanted = robots::DiamondToolPoint(
            true_model->radius, s.law.task_reference[0], s.law.task_reference[1]);
        position_sq += (p.p_O_T - wanted).squaredNorm();
      }
    });
  } else {
    control::DiamondIbvsOptions ibvs;
    ibvs.gain = o.gain;
    ibvs.stale_camera_timeout_s = std::max(0.25, 3.0 / rig->camera_fps());
    ibvs.first_frame_timeout_s = std::max(1.0, 3.0 / rig->camera_fps());
    control::DiamondMarkerServo law(controller.model, camera, X_CO, &source, ibvs);
    law.SetTarget(run.target_pixel);
    run.report = loop.Run(&law, [&](const control::DiamondLoopSample& s) {
      if (s.law.new_frame) {
        ++run.frames;
        if (s.law.marker_found) {
          locate(s.law.pixel);
        } else {
          ++run.frames_without_marker;
        }
      }
      if (true_model != nullptr) truth.push_back(rig->world()->plant().p_O_T.head<2>());
    });
    for (auto it = run.report.samples.rbegin(); it != run.report.samples.rend(); ++it) {
      if (it->law.marker_found) {
        run.final_pixel_error = (it->law.pixel - run.target_pixel).norm();
        break;
      }
    }
  }
  // The safe state at once: the work below (the camera worker's shutdown, which may wait for a
  // frame, and the statistics) runs no bus cycles, and enabled drives would fault on the lost
  // heartbeat meanwhile and be found in fault by the next job.
  rig->Release();
  if (run.camera_error.empty()) run.camera_error = camera_source->error();
  camera_source.reset();  // the worker stops before the rig's camera is used again
  run.measured_points = static_cast<int>(measured.size());
  run.measured_straightness = control::Straightness(measured);
  if (true_model != nullptr) {
    const sim::DiamondPlantState p = rig->world()->plant();
    run.true_points = static_cast<int>(truth.size());
    run.true_straightness = control::Straightness(truth);
    run.true_position_rms = truth.empty() ? 0.0 : std::sqrt(position_sq / truth.size());
    Eigen::Vector2d d = p.task - o.to;
    d[0] *= std::sin(o.to[1]);  // azimuth error as an arc on the unit sphere
    run.true_final_task_error = d.norm();
    Eigen::Vector2d px;
    if (o.law == DiamondServoLaw::kMarkerIbvs &&
        camera.Project(rig->X_OC().inverse() * p.p_O_T, &px) == vision::ProjectionStatus::kOk) {
      run.true_final_pixel_error = (px - run.target_pixel).norm();
    }
  }
  if (!o.log.empty()) control::WriteDiamondLogCsv(o.log, run.report.samples);
  return run;
}

}  // namespace kinevis::rigs
