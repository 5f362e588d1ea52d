// Issue 6, experiments 2 and 3 (seed 002 §V-B, Fig. 10): leg-direction visual servoing of the
// simulated hexapod from rendered camera images, with three sets of base attachment points A_j in
// the camera frame C, as in the seed:
//   E3 hand        CAD A_j carried into C by a hand-measured camera pose: the true camera pose
//                  off by --hand-error-mm in position and --hand-error-deg in orientation (fixed
//                  sizes, seeded random directions), so that the A_j are 1–2 cm off; optionally
//                  each A_j moved by --hand-point-error-mm more (a CAD unlike the robot as built);
//   E2 calibrated  A_j from the seed's calibration (eq. 14), really run: --poses poses planned on
//                  the workspace limits (calibration::PlanCalibrationPoses, every leg in the image
//                  by the hand pose), the simulated robot driven to each and a frame grabbed, the
//                  recorded dataset calibrated in --passes passes (leg edges -> limb normals ->
//                  CalibrateHexapod, calibration/hexapod/dataset_calibration.h), the first pass
//                  predicting the legs from the hand pose; or the file --calibrated;
//   E1 cad+fit     CAD A_j carried into C by the rigid transformation fitted to the calibrated
//                  points (seed eq. 15).
// Experiment 2 is the perspective camera (as in the seed), experiment 3 the central catadioptric
// one between the legs (servoing the seed had not achieved); both are sim::DefaultHexapodCameras(),
// at --fps, once per --image-noise level (the world cameras' render.noise_sigma, grey levels).
//
// Every calibration and every run uses a fresh stepped sim::HexapodWorld (same seed: the same true
// robot and image noise), the host's six CiA 402 drives on its virtual CAN bus, and the camera
// opened as a host would ("sim:NAME"). Features fed back (--features): `image`, the leg directions
// extracted from each rendered frame by control::ImageLegFeatureSource (legs predicted from the
// drive readings by the nominal model with the run's own camera pose and A_j), or `truth`, the
// true directions plus --noise rad per component. Desired features (--desired): `image`, teach by
// showing as in the seed (the robot is driven to the target by nominal inverse kinematics,
// --teach-frames frames are averaged there, it is driven back home), so that the extraction's own
// bias cancels at the goal, which is the pose the robot had when taught; or `model`, u* of the
// nominal model at the target with the run's camera pose (|e| then stops at the model's error).
// The target is seed Fig. 9's kind of large displacement (54 mm, 8.7°). The loop (gain --gain,
// control::ServoLoop's defaults otherwise) runs a fixed --duration with no convergence stop, so
// that the tail can be measured.
//
// Measured per run, from the camera frames (t from the start of the loop):
//   e0        measured |e| of the first frame;
//   floor     median measured |e| over the last --floor-window seconds (once the platform is
//             still: the per-frame error of the six measured leg directions), peak its maximum;
//   true flr  the same for the true |e|: the true directions at the plant's pose against those
//             at the goal (simulation truth: what perfect features would show);
//   bias      |u* − true directions at the goal|: the extraction's error that teaching cancels;
//   t(1e-4)   first time the measured |e| <= 1e-4 (the issue's figure; "-" when the floor is
//   above); tau       time constant of the exponential phase: least-squares fit of log|e| = a −
//   t/tau over
//             the frames with |e| <= e0/2 before |e| first reaches the cut-off max(1e-4, 3·floor),
//             and the fit's R²;
//   C         envelope constant: the smallest C with |e(t)| <= C·e0·exp(−t/tau) up to the cut-off
//             (C = 1: under the fitted exponential from the start; after the cut-off |e| stays
//             within [0, peak]);
//   rebound   max over t before the cut-off of (|e(t)| − min_{s<=t} |e(s)|) / e0, the
//             non-monotonic part of the measured error (what Fig. 10 shows); true reb, the same of
//             the true |e| (cut-off from its own floor): the part that is motion, not measurement;
//   past      max over t of the platform position's excursion beyond the goal along the line from
//             the start to the goal (mm), the overshoot of the pose itself; past rest, the same
//             beyond where the platform came to rest (the classical overshoot: "past" also counts
//             a resting error that happens to lie beyond the goal);
//   pose      the true platform pose (world.plant().X_BP) at the end against the goal, mm and deg;
//   |dA|      max_j |A_j − A_j true| (mm), and |dA|-t the same once the six errors' common
//             translation is removed: the law is exactly invariant to that translation (see
//             MaxPointErrorBeyondTranslation), so only the rest can change the closed loop.
// And once per camera and noise level (--probe, with the calibrated run's predictions), what sets
// the floor: at the goal, the per-frame scatter of the measured directions with the platform still,
// and how much the mean of --teach-frames frames changes when the platform is moved by 0.01–1 mm
// along x or 0.01–1° about z, against how much the true directions change.
// Files: DIR/NAME.csv (every loop cycle, control/README.md), DIR/NAME-frames.csv (per frame: t,
// measured and true |e|, pose error), DIR/NAME.png (measured and true |e|, log scale); per camera
// and noise level DIR/CAMERA-nN-convergence.png (the three measured |e| curves), the recorded
// calibration dataset DIR/CAMERA-nN-dataset/ and its result DIR/CAMERA-nN-calibration.yaml
// (readable by --calibrated and by `kinevis servo hexapod --calib`); DIR/summary.csv, the tables.

#include <spdlog/spdlog.h>

#include <CLI/CLI.hpp>
#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>
#include <random>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "calibration/hexapod/dataset_calibration.h"
#include "calibration/hexapod/hexapod_calibration_io.h"
#include "calibration/hexapod/hexapod_dataset.h"
#include "calibration/hexapod/leg_calibration.h"
#include "calibration/hexapod/pose_planner.h"
#include "common/clock.h"
#include "common/units.h"
#include "control/hexapod/image_leg_features.h"
#include "control/hexapod/leg_servo.h"
#include "control/hexapod/servo_loop.h"
#include "hal/camera/camera_factory.h"
#include "hal/canopen/canopen_master.h"
#include "hal/drive/cia402_can_drive.h"
#include "rigs/hexapod/hexapod_rig.h"
#include "sim/hexapod_world.h"
#include "vision/camera/camera_file.h"
#include "vision/plot/line_plot.h"
#include "vision/render/scenes/hexapod_scene.h"

namespace {

namespace fs = std::filesystem;
namespace kv = kinevis;
using namespace std::chrono_literals;
using kv::control::LegDirections;
using kv::control::LegPoints;
using kv::robots::kHexapodLegs;
using kv::robots::Vector6d;

constexpr double kIssueThreshold = 1e-4;  // the issue's |e| figure
// `kinevis servo hexapod`'s arrival test: the law's low-passed remaining displacement below these.
constexpr double kArriveTranslation = 0.2e-3;                // m
constexpr double kArriveRotation = 0.05 * kv::common::kDeg;  // rad

struct Args {
  std::string out = "hexapod-servo-convergence";
  std::string features = "image";
  std::string camera = "both";
  std::string desired = "image";
  std::vector<double> image_noise{1.0, 0.0};
  int supersampling = 0;  // 0: the world camera's
  std::string calibrated;
  int poses = 60;
  int passes = 2;
  double hand_error_mm = 12.0;
  double hand_error_deg = 0.3;
  double hand_point_error_mm = 0.0;
  double noise = 1e-5;
  double gain = 1.0;
  double fps = 10.0;
  double duration_s = 12.0;
  double floor_window_s = 3.0;
  int teach_frames = 10;
  double move_speed = 0.08;
  bool probe = true;
  unsigned seed = 2;
};

double RotationDeg(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  return Eigen::AngleAxisd(a.linear() * b.linear().transpose()).angle() / kv::common::kDeg;
}

double MaxPointError(const LegPoints& p, const LegPoints& truth) {
  double worst = 0;
  for (int j = 0; j < kHexapodLegs; ++j) worst = std::max(worst, (p[j] - truth[j]).norm());
  return worst;
}

// The same after removing the common translation of the six errors. The law is exactly invariant
// to a translation δ of all the A_j in C: with A_j + δ, L becomes L·M and D_inv becomes D_inv·M,
// M = [[I, −[δ]×], [0, I]] (control/hexapod/leg_servo.h's L and eq. 7), and (L M)⁺ = M⁻¹ L⁺ for L
// of full column rank, so q̇ = −λ D_inv M M⁻¹ L⁺ e is unchanged. Only the rest of an error can
// change the closed loop.
double MaxPointErrorBeyondTranslation(const LegPoints& p, const LegPoints& truth) {
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (int j = 0; j < kHexapodLegs; ++j) mean += (p[j] - truth[j]) / kHexapodLegs;
  double worst = 0;
  for (int j = 0; j < kHexapodLegs; ++j) {
    worst = std::max(worst, (p[j] - truth[j] - mean).norm());
  }
  return worst;
}

double Median(std::vector<double> v) {
  if (v.empty()) return std::nan("");
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

// A calibration given on the command line: the YAML of `kinevis calibrate hexapod` (A_j and the
// rigid fit), or six lines "x y z" (m, in C).
LegPoints ReadPoints(const std::string& path) {
  const std::string ext = fs::path(path).extension().string();
  LegPoints p;
  if (ext == ".yaml" || ext == ".yml") {
    const kv::calibration::HexapodCalibrationFile file =
        kv::calibration::ReadHexapodCalibration(path);
    for (int j = 0; j < kHexapodLegs; ++j) {
      p[j] = file.result.p_C_A[j];
      if (!p[j].allFinite()) {
        throw std::runtime_error(path + ": leg " + std::to_string(j) + " has no estimate");
      }
    }
    return p;
  }
  std::ifstream in(path);
  if (!in) throw std::runtime_error(path + ": cannot read");
  int n = 0;
  std::string line;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream s(line);
    double x, y, z;
    if (!(s >> x >> y >> z)) throw std::runtime_error(path + ": bad line '" + line + "'");
    if (n >= kHexapodLegs) throw std::runtime_error(path + ": more than 6 points");
    p[n++] = Eigen::Vector3d(x, y, z);
  }
  if (n != kHexapodLegs) {
    throw std::runtime_error(path + ": expected 6 points, got " + std::to_string(n));
  }
  return p;
}

// One simulated set-up, built afresh for the calibration and for every servo run so that each
// starts from the same state: the kinevis hexapod rig (rigs/hexapod/hexapod_rig.h) on a stepped
// HexapodWorld at home with one camera, the host's six CiA 402 drives enabled on its CAN bus and
// the camera opened as a host would ("sim:NAME") — what `kinevis servo hexapod` runs on.
class SimRig {
 public:
  SimRig(kv::sim::WorldCameraConfig camera, const std::string& tag) {
    auto c = std::make_shared<kv::sim::HexapodWorldConfig>();
    c->network = "servo-convergence-" + tag;
    camera.name += "-" + tag;
    c->cameras = {camera};
    kv::rigs::HexapodRigOptions o;
    o.config = "servo-convergence " + tag;
    o.world = c;
    rig_ = std::make_unique<kv::rigs::HexapodRig>(o);
    rig_->Enable();
  }

  kv::sim::HexapodWorld& world() { return *rig_->world(); }
  kv::hal::canopen::CanopenMaster& master() { return rig_->master(); }
  kv::hal::Camera& camera() { return rig_->camera(); }
  const kv::robots::HexapodModel& nominal() const { return rig_->nominal(); }
  Vector6d Readings() const { return rig_->Readings(); }
  // The leg lengths the host knows: nominal q0 + the drive readings.
  Vector6d HostLegLengths() const {
    return kv::robots::LegLengthsFromJointPositions(nominal(), Readings());
  }

  // Drives the platform to X_BP as the host can: nominal inverse kinematics, the rig's cosine
  // ramp whose fastest leg peaks at `speed`, then 0.2 s of settling. Throws when a drive faults or
  // the pose is out of the nominal strokes.
  void MoveTo(const Eigen::Isometry3d& X_BP, double speed) {
    kv::robots::HexapodData ik;
    const kv::robots::Reachability reach = kv::robots::InverseKinematics(nominal(), X_BP, &ik);
    if (!reach.ok()) {
      throw std::runtime_error("move: pose not reachable: " + reach.Describe(nominal(), ik.q));
    }
    const std::string stopped =
        rig_->MoveTo(kv::robots::JointPositionsFromLegLengths(nominal(), ik.q), speed, 0.2);
    if (!stopped.empty()) throw std::runtime_error("move: " + stopped);
  }

  // A frame captured after now (the drives keep cycling, holding their targets, meanwhile).
  void GrabFresh(kv::hal::Image* image) {
    const std::string failed = rig_->GrabFresh(image);
    if (!failed.empty()) throw std::runtime_error("camera " + camera().name() + ": " + failed);
  }

 private:
  std::unique_ptr<kv::rigs::HexapodRig> rig_;
};

// One camera at one image-noise level.
struct Setup {
  std::string camera;  // "perspective" or "omni"
  kv::sim::WorldCameraConfig config;
  std::unique_ptr<kv::vision::CameraModel> model;
  Eigen::Isometry3d X_CB = Eigen::Isometry3d::Identity();  // the true camera pose
  std::string tag;                                         // "omni-n1"
};

struct Calibrated {
  LegPoints p_C_A{};
  std::string note;  // how it was obtained, and how well
};

// Seed 002 §IV on the simulated robot: plan, move, grab, record a dataset, calibrate it.
Calibrated CalibrateLive(const Args& args, const Setup& setup, const Eigen::Isometry3d& X_CB_hand) {
  SimRig rig(setup.config, setup.tag + "-calibration");
  const kv::robots::HexapodModel& nominal = rig.nominal();
  kv::calibration::PosePlannerOptions po;
  po.poses = args.poses;
  po.candidates = std::max(2000, args.poses);
  po.seed = args.seed;
  po.X_BP_nominal = rig.world().config().X_BP_home;
  po.X_CB = X_CB_hand;
  po.admissible = [&](const Eigen::Isometry3d& X_BP) {
    return kv::calibration::AllLegsInView(nominal, *setup.model, X_CB_hand, X_BP);
  };
  const kv::calibration::PosePlan plan = kv::calibration::PlanCalibrationPoses(nominal, po);
  for (const std::string& w : plan.warnings) spdlog::warn("{}: planner: {}", setup.tag, w);
  if (plan.X_BP.size() < 2) throw std::runtime_error(setup.tag + ": no calibration poses");

  kv::calibration::HexapodDataset dataset;
  dataset.directory = args.out + "/" + setup.tag + "-dataset";
  fs::remove_all(dataset.directory);  // ours, from an earlier run of this program
  dataset.nominal = nominal;
  dataset.camera_name = setup.config.name;
  dataset.camera_model = setup.config.model;
  dataset.X_BC_hint = X_CB_hand.inverse();
  dataset.source = "hexapod_servo_convergence: simulated world, image noise " +
                   std::to_string(setup.config.render.noise_sigma) + " grey levels";
  kv::calibration::CreateHexapodDataset(&dataset);
  kv::hal::Image image;
  for (size_t k = 0; k < plan.X_BP.size(); ++k) {
    rig.MoveTo(plan.X_BP[k], args.move_speed);
    rig.GrabFresh(&image);
    if (image.format != kv::hal::PixelFormat::kMono8) {
      throw std::runtime_error(setup.tag + ": the camera does not deliver mono8");
    }
    kv::calibration::HexapodDatasetPose pose;
    pose.index = static_cast<int>(k);
    char name[48];
    std::snprintf(name, sizeof name, "images/pose_%03zu.png", k);
    pose.image = name;
    pose.s = rig.Readings();
    pose.X_BP_commanded = plan.X_BP[k];
    kv::calibration::AppendHexapodDatasetPose(dataset, pose, image.data.data(), image.width,
                                              image.height, image.stride);
  }

  kv::calibration::DatasetCalibrationOptions co;
  co.passes = args.passes;
  const kv::calibration::DatasetCalibrationResult run = kv::calibration::CalibrateHexapodDataset(
      kv::calibration::ReadHexapodDataset(dataset.directory), *setup.model, co);
  kv::calibration::HexapodCalibrationMetadata metadata;
  metadata.camera = setup.config.name + " (" + setup.config.model + ")";
  metadata.source = "dataset " + dataset.directory;
  kv::calibration::WriteHexapodCalibration(args.out + "/" + setup.tag + "-calibration.yaml",
                                           run.result, metadata);
  if (!run.result.ok()) {
    std::string why;
    for (const std::string& e : run.result.errors) why += "; " + e;
    throw std::runtime_error(setup.tag + ": calibration failed" + why);
  }
  Calibrated c;
  for (int j = 0; j < kHexapodLegs; ++j) c.p_C_A[j] = run.result.p_C_A[j];
  char note[160];
  std::snprintf(note, sizeof note, "%zu poses, %d pass(es), rigid fit rms %.2f mm",
                plan.X_BP.size(), run.passes_run, 1e3 * run.result.rigid_fit_rms);
  c.note = note;
  return c;
}

// One set of A_j with the camera pose the host believes (for the leg predictions).
struct Variant {
  std::string name;
  LegPoints p_C_A{};
  Eigen::Isometry3d X_CB = Eigen::Isometry3d::Identity();
};

// Per camera frame of a run: the measured |e|, and from the simulation's truth the |e| perfect
// features would give (true directions at the plant's pose against those at the goal) and the
// platform's pose error.
struct Trace {
  std::vector<double> t, e, e_true, pose_mm, pose_deg;
  std::vector<double> along_mm;  // (p − p_goal) · (unit start -> goal): > 0 is past the goal
};

// The true leg directions in C at X_BP.
LegDirections TrueDirections(const kv::robots::HexapodModel& truth, const Eigen::Isometry3d& X_CB,
                             const Eigen::Isometry3d& X_BP) {
  kv::robots::HexapodData data;
  kv::robots::InverseKinematics(truth, X_BP, &data);
  LegDirections u;
  for (int j = 0; j < kHexapodLegs; ++j) u[j] = X_CB.linear() * data.u_B[j];
  return u;
}

double ErrorNorm(const LegDirections& u, const LegDirections& u_star) {
  double sum = 0;
  for (int j = 0; j < kHexapodLegs; ++j) sum += (u[j] - u_star[j]).squaredNorm();
  return std::sqrt(sum);
}

struct RunResult {
  std::string camera, name;
  double image_noise = 0;
  double ap_error_mm = 0, ap_shape_error_mm = 0;
  double e0 = 0, floor = 0, peak = 0, t_issue = -1, tau = 0, tau_r2 = 0, envelope = 0;
  double true_floor = 0;  // median true |e| over the floor window
  double t_arrive = -1;   // first time the remaining displacement met kArrive*
  double teach_bias = 0;  // |u* − u_true(goal)|: the extraction's bias at the goal
  double rebound = 0, true_rebound = 0, past_mm = 0, past_rest_mm = 0, pose_mm = 0, pose_deg = 0;
  uint64_t frames = 0, holds = 0, legs_missed = 0;
  std::string outcome;
  Trace trace;
};

// The next `frames` camera frames in which all six legs were seen, the robot held where it is.
std::vector<LegDirections> CollectFrames(SimRig* rig, kv::control::LegFeatureSource* source,
                                         int frames, double fps) {
  std::vector<LegDirections> out;
  int partial = 0;
  kv::common::Clock& clock = rig->world().clock();
  rig->master().RunCyclesUntil(clock.Now() + kv::common::FromSeconds((2.0 * frames + 5) / fps),
                               [&] {
                                 kv::control::LegFeatureFrame f;
                                 if (!source->Poll(clock.Now(), &f)) return false;
                                 for (int j = 0; j < kHexapodLegs; ++j) {
                                   if (!f.visible[j]) {
                                     ++partial;
                                     return false;
                                   }
                                 }
                                 out.push_back(f.u_C);
                                 return static_cast<int>(out.size()) >= frames;
                               });
  if (static_cast<int>(out.size()) < frames) {
    throw std::runtime_error("only " + std::to_string(out.size()) + " of " +
                             std::to_string(frames) + " frames saw all six legs (" +
                             std::to_string(partial) + " did not)");
  }
  return out;
}

LegDirections Mean(const std::vector<LegDirections>& frames) {
  LegDirections u;
  for (int j = 0; j < kHexapodLegs; ++j) {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    for (const LegDirections& f : frames) sum += f[j];
    u[j] = sum.normalized();
  }
  return u;
}

// max over t, before |e| first reaches `cut`, of (|e(t)| − min_{s<=t} |e(s)|) / |e(0)|.
double Rebound(const std::vector<double>& e, double cut) {
  double rebound = 0, running_min = std::numeric_limits<double>::infinity();
  for (size_t i = 0; i < e.size() && e[i] > cut; ++i) {
    running_min = std::min(running_min, e[i]);
    rebound = std::max(rebound, (e[i] - running_min) / e.front());
  }
  return rebound;
}

// The figures of the header comment, from the frames' |e|.
void Analyse(const Args& args, RunResult* r) {
  const std::vector<double>& t = r->trace.t;
  const std::vector<double>& e = r->trace.e;
  if (e.empty()) return;
  r->e0 = e.front();
  std::vector<double> tail;
  for (size_t i = 0; i < e.size(); ++i) {
    if (t[i] >= t.back() - args.floor_window_s) tail.push_back(e[i]);
  }
  r->floor = Median(tail);
  r->peak = *std::max_element(tail.begin(), tail.end());
  tail.clear();
  for (size_t i = 0; i < e.size(); ++i) {
    if (t[i] >= t.back() - args.floor_window_s) tail.push_back(r->trace.e_true[i]);
  }
  r->true_floor = Median(tail);
  const double cut = std::max(kIssueThreshold, 3 * r->floor);
  size_t n_cut = e.size();
  for (size_t i = 0; i < e.size(); ++i) {
    if (r->t_issue < 0 && e[i] <= kIssueThreshold) r->t_issue = t[i];
    if (n_cut == e.size() && e[i] <= cut) n_cut = i;
  }
  // Least squares of log|e| against t over the exponential phase.
  double n = 0, st = 0, sy = 0, stt = 0, sty = 0, syy = 0;
  for (size_t i = 0; i < n_cut; ++i) {
    if (e[i] > 0.5 * r->e0) continue;
    const double y = std::log(e[i]);
    n += 1;
    st += t[i];
    sy += y;
    stt += t[i] * t[i];
    sty += t[i] * y;
    syy += y * y;
  }
  const double var_t = stt - st * st / std::max(n, 1.0);
  const double cov = sty - st * sy / std::max(n, 1.0);
  const double var_y = syy - sy * sy / std::max(n, 1.0);
  if (n >= 5 && var_t > 0 && cov < 0) {
    r->tau = -var_t / cov;
    r->tau_r2 = var_y > 0 ? cov * cov / (var_t * var_y) : 1.0;
    for (size_t i = 0; i < n_cut; ++i) {
      r->envelope = std::max(r->envelope, e[i] / (r->e0 * std::exp(-(t[i] - t[0]) / r->tau)));
    }
  } else {
    r->tau = std::nan("");
    r->envelope = std::nan("");
  }
  r->rebound = Rebound(e, cut);
  r->true_rebound = Rebound(r->trace.e_true, std::max(kIssueThreshold, 3 * r->true_floor));
}

// One row per camera frame: t (s), measured |e|, true |e|, pose error (mm, deg).
void WriteFramesCsv(const std::string& path, const Trace& trace) {
  std::ofstream out(path);
  if (!out) throw std::runtime_error(path + ": cannot write");
  out << "time_s,error_norm,true_error_norm,pose_error_mm,pose_error_deg\n";
  out.precision(10);
  for (size_t i = 0; i < trace.t.size(); ++i) {
    out << trace.t[i] << ',' << trace.e[i] << ',' << trace.e_true[i] << ',' << trace.pose_mm[i]
        << ',' << trace.pose_deg[i] << '\n';
  }
  if (!out) throw std::runtime_error(path + ": write failed");
}

kv::vision::plot::LinePlotOptions ErrorPlotOptions(const std::string& title) {
  kv::vision::plot::LinePlotOptions o;
  o.title = title;
  o.x_label = "time (s)";
  o.y_label = "|e|";
  o.y_scale = kv::vision::plot::AxisScale::kLog10;
  return o;
}

void AddIssueLine(double t_end, kv::vision::plot::LinePlot* plot) {
  kv::vision::plot::Series line;
  line.name = "1e-4 (issue)";
  line.thickness_px = 1;
  line.x = {0.0, t_end};
  line.y = {kIssueThreshold, kIssueThreshold};
  plot->AddSeries(std::move(line));
}

// One run: the measured |e| and the true |e| (what perfect features would give).
void WriteRunPlot(const std::string& path, const std::string& title, const Trace& trace) {
  kv::vision::plot::LinePlot plot(ErrorPlotOptions(title));
  kv::vision::plot::Series measured;
  measured.name = "|e| measured";
  measured.x = trace.t;
  measured.y = trace.e;
  plot.AddSeries(std::move(measured));
  kv::vision::plot::Series truth;
  truth.name = "|e| true (simulation)";
  truth.x = trace.t;
  truth.y = trace.e_true;
  plot.AddSeries(std::move(truth));
  AddIssueLine(trace.t.empty() ? 1.0 : trace.t.back(), &plot);
  plot.WritePng(path);
}

RunResult RunServo(const Args& args, const Setup& setup, const Variant& variant,
                   const LegPoints& p_C_A_true, const Eigen::Isometry3d& X_BP_target) {
  const std::string name = setup.tag + "-" + variant.name;
  SimRig rig(setup.config, name);
  const kv::robots::HexapodModel& nominal = rig.nominal();
  kv::sim::HexapodWorld& world = rig.world();

  std::unique_ptr<kv::control::LegFeatureSource> source;
  kv::control::ImageLegFeatureSource* image_source = nullptr;
  if (args.features == "image") {
    kv::control::ImageLegFeatureOptions fo;
    fo.p_C_A = variant.p_C_A;
    auto s = std::make_unique<kv::control::ImageLegFeatureSource>(
        &rig.camera(), setup.model.get(), nominal, variant.X_CB,
        [&rig] { return rig.HostLegLengths(); }, fo);
    image_source = s.get();
    source = std::move(s);
  } else {
    kv::control::GroundTruthFeatureOptions fo;
    fo.fps = args.fps;
    fo.noise_sigma = args.noise;
    fo.seed = args.seed;
    source = std::make_unique<kv::control::GroundTruthLegFeatureSource>(
        world.true_model(), setup.X_CB, [&world] { return world.plant().X_BP; }, fo);
  }

  LegDirections u_star;
  Eigen::Isometry3d X_BP_goal = X_BP_target;
  if (args.desired == "image") {
    const Eigen::Isometry3d home = world.plant().X_BP;
    rig.MoveTo(X_BP_target, args.move_speed);
    X_BP_goal = world.plant().X_BP;  // where the true robot went: the pose being taught
    u_star = Mean(CollectFrames(&rig, source.get(), args.teach_frames, args.fps));
    rig.MoveTo(home, args.move_speed);
  } else {
    kv::control::DesiredLegDirections(nominal, X_BP_target, variant.X_CB, &u_star);
  }

  kv::control::LegServoOptions lo;
  lo.gain = args.gain;
  kv::control::LegServo law(variant.p_C_A, lo);
  law.SetDesired(u_star);
  kv::control::ServoLoopOptions o;
  o.timeout_s = args.duration_s;
  o.convergence_threshold = 1e-12;  // never: the loop runs the whole duration
  o.stale_camera_timeout_s = 3.0 / args.fps;
  kv::control::ServoLoop loop(&rig.master(), &world.clock(), source.get(), nominal, &law, o);

  RunResult r;
  r.camera = setup.camera;
  r.name = variant.name;
  r.image_noise = setup.config.render.noise_sigma;
  r.ap_error_mm = 1e3 * MaxPointError(variant.p_C_A, p_C_A_true);
  r.ap_shape_error_mm = 1e3 * MaxPointErrorBeyondTranslation(variant.p_C_A, p_C_A_true);
  const Eigen::Vector3d p0 = world.plant().X_BP.translation();
  const Eigen::Vector3d approach = (X_BP_goal.translation() - p0).normalized();
  const LegDirections u_goal_true = TrueDirections(world.true_model(), setup.X_CB, X_BP_goal);
  r.teach_bias = ErrorNorm(u_star, u_goal_true);
  const kv::control::ServoLoopReport report = loop.Run([&](const kv::control::ServoLoopSample& s) {
    const Eigen::Isometry3d X_BP = world.plant().X_BP;
    const Eigen::Vector3d p = X_BP.translation();
    r.past_mm = std::max(r.past_mm, 1e3 * (p - X_BP_goal.translation()).dot(approach));
    if (!s.new_frame || !std::isfinite(s.error_norm)) return;
    r.trace.t.push_back(s.time_s);
    r.trace.e.push_back(s.error_norm);
    r.trace.e_true.push_back(
        ErrorNorm(TrueDirections(world.true_model(), setup.X_CB, X_BP), u_goal_true));
    r.trace.pose_mm.push_back(1e3 * (p - X_BP_goal.translation()).norm());
    r.trace.pose_deg.push_back(RotationDeg(X_BP, X_BP_goal));
    r.trace.along_mm.push_back(1e3 * (p - X_BP_goal.translation()).dot(approach));
  });
  r.outcome = report.outcome == kv::control::ServoLoopOutcome::kTimeout
                  ? "ran"
                  : kv::control::ServoOutcomeName(report.outcome);
  if (report.outcome != kv::control::ServoLoopOutcome::kTimeout) {
    spdlog::warn("{}: {}", name, report.message);
  }
  r.frames = report.frames;
  for (const kv::control::ServoLoopSample& s : report.samples) {
    if (s.new_frame && s.remaining_translation <= kArriveTranslation &&
        s.remaining_rotation <= kArriveRotation) {
      r.t_arrive = s.time_s;
      break;
    }
  }
  r.holds = report.hold_cycles_leg_lost + report.hold_cycles_stale_camera + report.hold_cycles_law;
  if (image_source != nullptr) r.legs_missed = image_source->counters().legs_not_visible;
  Analyse(args, &r);
  const Eigen::Isometry3d X_BP_end = world.plant().X_BP;
  r.pose_mm = 1e3 * (X_BP_end.translation() - X_BP_goal.translation()).norm();
  r.pose_deg = RotationDeg(X_BP_end, X_BP_goal);
  const double along_end = 1e3 * (X_BP_end.translation() - X_BP_goal.translation()).dot(approach);
  for (const double a : r.trace.along_mm) r.past_rest_mm = std::max(r.past_rest_mm, a - along_end);

  kv::control::WriteServoLogCsv(args.out + "/" + name + ".csv", report.samples);
  WriteFramesCsv(args.out + "/" + name + "-frames.csv", r.trace);
  WriteRunPlot(args.out + "/" + name + ".png",
               "leg-direction servo, " + setup.config.name + ", A_j: " + variant.name, r.trace);
  return r;
}

// How the measured leg directions respond at the goal (--features image, with one run's
// predictions): their per-frame scatter with the platform still, and the change of the mean of
// --teach-frames frames when the platform is moved by small steps, against the true change. A
// smooth measurement changes as the truth does; where it changes by more than the truth and the
// noise, the servo has no unique resting point at that scale.
struct ProbeStep {
  double size = 0;        // mm, or degrees when rotation
  bool rotation = false;  // about B's z axis through the platform origin, else along B's x
  double measured = 0, truth = 0;
};
struct ProbeResult {
  double scatter = 0;     // median over the frames of |u_frame − u_mean| (six legs stacked)
  double mean_noise = 0;  // what is left of it in the difference of two means
  std::vector<ProbeStep> steps;
};

ProbeResult Probe(const Args& args, const Setup& setup, const Variant& variant,
                  const Eigen::Isometry3d& X_BP_target) {
  SimRig rig(setup.config, setup.tag + "-probe");
  kv::control::ImageLegFeatureOptions fo;
  fo.p_C_A = variant.p_C_A;
  kv::control::ImageLegFeatureSource source(
      &rig.camera(), setup.model.get(), rig.nominal(), variant.X_CB,
      [&rig] { return rig.HostLegLengths(); }, fo);
  ProbeResult out;
  const int n = std::max(2, args.teach_frames);
  rig.MoveTo(X_BP_target, args.move_speed);
  const LegDirections truth0 =
      TrueDirections(rig.world().true_model(), setup.X_CB, rig.world().plant().X_BP);
  const std::vector<LegDirections> frames = CollectFrames(&rig, &source, n, args.fps);
  const LegDirections u0 = Mean(frames);
  std::vector<double> scatter;
  for (const LegDirections& f : frames) scatter.push_back(ErrorNorm(f, u0));
  out.scatter = Median(scatter);
  out.mean_noise = out.scatter * std::sqrt(2.0 / n);
  for (const double size : {0.01, 0.03, 0.1, 0.3, 1.0}) {
    for (const bool rotation : {false, true}) {
      Eigen::Isometry3d X = X_BP_target;
      if (rotation) {
        X.linear() = Eigen::AngleAxisd(size * kv::common::kDeg, Eigen::Vector3d::UnitZ()).matrix() *
                     X.linear();
      } else {
        X.translation().x() += 1e-3 * size;
      }
      rig.MoveTo(X, args.move_speed);
      const LegDirections truth =
          TrueDirections(rig.world().true_model(), setup.X_CB, rig.world().plant().X_BP);
      const LegDirections u = Mean(CollectFrames(&rig, &source, n, args.fps));
      out.steps.push_back({size, rotation, ErrorNorm(u, u0), ErrorNorm(truth, truth0)});
    }
  }
  return out;
}

void PrintProbe(const ProbeResult& p, int frames) {
  std::printf(
      "  probe at the goal: per-frame scatter of the directions %.2e (in the difference of "
      "two %d-frame means: %.2e)\n  %-12s",
      p.scatter, frames, p.mean_noise, "step");
  for (const ProbeStep& s : p.steps) {
    char text[24];
    std::snprintf(text, sizeof text, "%s%g%s", s.rotation ? "rz " : "x ", s.size,
                  s.rotation ? "deg" : "mm");
    std::printf(" %10s", text);
  }
  std::printf("\n  %-12s", "|du| meas");
  for (const ProbeStep& s : p.steps) std::printf(" %10.2e", s.measured);
  std::printf("\n  %-12s", "|du| true");
  for (const ProbeStep& s : p.steps) std::printf(" %10.2e", s.truth);
  std::printf("\n");
}

// The three |e| curves of one camera and noise level in one plot.
void WriteCombinedPlot(const std::string& path, const std::string& title,
                       const std::vector<RunResult>& runs) {
  kv::vision::plot::LinePlot plot(ErrorPlotOptions(title));
  double t_end = 1.0;
  for (const RunResult& r : runs) {
    kv::vision::plot::Series s;
    s.name = r.name;
    s.x = r.trace.t;
    s.y = r.trace.e;
    if (!s.x.empty()) t_end = std::max(t_end, s.x.back());
    plot.AddSeries(std::move(s));
  }
  AddIssueLine(t_end, &plot);
  plot.WritePng(path);
}

std::string Num(double v, const char* format) {
  if (!std::isfinite(v) || v < 0) return "-";
  char text[32];
  std::snprintf(text, sizeof text, format, v);
  return text;
}

// The summary, in two tables: how |e| converges, and the overshoot and where the platform ended.
void PrintConvergenceTable(const std::vector<RunResult>& runs) {
  std::printf("%-11s %5s %-13s %7s %9s %9s %9s %9s %8s %6s %6s %6s %6s\n", "camera", "noise", "A_j",
              "e0", "floor", "peak", "true flr", "bias", "t(1e-4)", "t arr", "tau s", "fit R2",
              "C");
  for (const RunResult& r : runs) {
    std::printf("%-11s %5.1f %-13s %7.4f %9.2e %9.2e %9.2e %9.2e %8s %6s %6s %6.3f %6s\n",
                r.camera.c_str(), r.image_noise, r.name.c_str(), r.e0, r.floor, r.peak,
                r.true_floor, r.teach_bias, Num(r.t_issue, "%.2f").c_str(),
                Num(r.t_arrive, "%.2f").c_str(), Num(r.tau, "%.3f").c_str(), r.tau_r2,
                Num(r.envelope, "%.2f").c_str());
  }
}

void PrintOvershootTable(const std::vector<RunResult>& runs) {
  std::printf("%-11s %5s %-13s %7s %7s %8s %9s %8s %9s %8s %9s %8s %6s %6s\n", "camera", "noise",
              "A_j", "|dA|mm", "|dA|-t", "rebound%", "true reb%", "past mm", "past rest", "pose mm",
              "pose deg", "outcome", "frames", "holds");
  for (const RunResult& r : runs) {
    std::printf(
        "%-11s %5.1f %-13s %7.2f %7.2f %8.3f %9.3f %8.3f %9.3f %8.3f %9.4f %8s %6llu %6llu\n",
        r.camera.c_str(), r.image_noise, r.name.c_str(), r.ap_error_mm, r.ap_shape_error_mm,
        100 * r.rebound, 100 * r.true_rebound, r.past_mm, r.past_rest_mm, r.pose_mm, r.pose_deg,
        r.outcome.c_str(), static_cast<unsigned long long>(r.frames),
        static_cast<unsigned long long>(r.holds));
  }
}

void WriteSummaryCsv(const std::string& path, const std::vector<RunResult>& runs) {
  std::ofstream out(path);
  if (!out) throw std::runtime_error(path + ": cannot write");
  out << "camera,image_noise,A_j,ap_error_mm,ap_error_beyond_translation_mm,e0,floor,peak,"
         "true_floor,teach_bias,t_1e-4_s,t_arrive_s,tau_s,tau_r2,envelope_C,rebound,true_rebound,"
         "past_mm,past_rest_mm,pose_mm,pose_deg,outcome,frames,hold_cycles,legs_missed\n";
  out.precision(6);
  for (const RunResult& r : runs) {
    out << r.camera << ',' << r.image_noise << ',' << r.name;
    for (const double v :
         {r.ap_error_mm, r.ap_shape_error_mm, r.e0, r.floor, r.peak, r.true_floor, r.teach_bias,
          r.t_issue, r.t_arrive, r.tau, r.tau_r2, r.envelope, r.rebound, r.true_rebound, r.past_mm,
          r.past_rest_mm, r.pose_mm, r.pose_deg}) {
      out << ',' << v;
    }
    out << ',' << r.outcome << ',' << r.frames << ',' << r.holds << ',' << r.legs_missed << '\n';
  }
  if (!out) throw std::runtime_error(path + ": write failed");
}

}  // namespace

int main(int argc, char** argv) {
  Args args;
  CLI::App app{
      "Hexapod leg-direction servo convergence from rendered images with hand, calibrated and "
      "CAD+fit A_j, perspective and catadioptric cameras (seed 002 Fig. 10; issue 6 exp. 2, 3)"};
  app.add_option("--out", args.out, "output directory (logs, plots, datasets, calibrations)")
      ->capture_default_str();
  app.add_option("--features", args.features,
                 "fed-back leg directions: image (extracted from rendered frames) or truth")
      ->capture_default_str()
      ->check(CLI::IsMember({"image", "truth"}));
  app.add_option("--camera", args.camera, "perspective (experiment 2), omni (experiment 3) or both")
      ->capture_default_str()
      ->check(CLI::IsMember({"perspective", "omni", "both"}));
  app.add_option("--desired", args.desired,
                 "desired features: image (teach by showing at the target) or model (nominal "
                 "model at the target)")
      ->capture_default_str()
      ->check(CLI::IsMember({"image", "model"}));
  app.add_option("--image-noise", args.image_noise,
                 "image noise sigma(s) of the world's cameras, grey levels; one full set of runs "
                 "(calibration included) per value")
      ->delimiter(',')
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  app.add_option("--supersampling", args.supersampling,
                 "anti-aliasing of the rendered edges, s x s samples per edge pixel on a regular "
                 "grid (edge error up to 1/(2s) px); 0: the world camera's (4)")
      ->capture_default_str()
      ->check(CLI::Range(0, 32));
  app.add_option("--calibrated", args.calibrated,
                 "calibrated A_j instead of calibrating: a kinevis calibration YAML or six lines "
                 "'x y z' (m, in C); needs one --camera")
      ->check(CLI::ExistingFile);
  app.add_option("--poses", args.poses, "calibration poses (seed: 60)")
      ->capture_default_str()
      ->check(CLI::Range(6, 500));
  app.add_option("--passes", args.passes, "calibration extraction passes")
      ->capture_default_str()
      ->check(CLI::Range(1, 5));
  app.add_option("--hand-error-mm", args.hand_error_mm, "hand-measured camera position error, mm")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  app.add_option("--hand-error-deg", args.hand_error_deg,
                 "hand-measured camera orientation error, degrees")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  app.add_option("--hand-point-error-mm", args.hand_point_error_mm,
                 "E3 hand: each A_j moved by this much more in its own random direction, mm (a "
                 "CAD that does not match the robot as built; no camera pose explains it)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  app.add_option("--noise", args.noise, "--features truth: noise, rad per component of u")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  app.add_option("--gain", args.gain, "servo gain lambda, 1/s")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  app.add_option("--fps", args.fps, "camera frame rate, 1/s")
      ->capture_default_str()
      ->check(CLI::Range(1.0, 250.0));
  app.add_option("--duration", args.duration_s, "simulated seconds of servoing per run")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  app.add_option("--floor-window", args.floor_window_s,
                 "the |e| floor is the median over the last this many seconds")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  app.add_option("--teach-frames", args.teach_frames,
                 "frames averaged at the target (--desired image) and per probe step")
      ->capture_default_str()
      ->check(CLI::Range(1, 1000));
  app.add_flag("--probe,!--no-probe", args.probe,
               "--features image: probe the measurement's scatter and smoothness at the goal "
               "(small platform steps, measured against true change of the directions)")
      ->capture_default_str();
  app.add_option("--seed", args.seed, "seed of the hand-pose error and the pose planner")
      ->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  spdlog::set_level(spdlog::level::warn);

  try {
    if (!args.calibrated.empty() && args.camera == "both") {
      throw std::invalid_argument("--calibrated: A_j are in one camera's frame; give --camera");
    }
    if (args.floor_window_s >= args.duration_s) {
      throw std::invalid_argument("--floor-window must be shorter than --duration");
    }
    fs::create_directories(args.out);
    const kv::sim::HexapodWorldConfig defaults;
    const kv::robots::HexapodModel& nominal = defaults.nominal;
    const kv::robots::HexapodModel truth = kv::sim::TrueHexapodModel(defaults);
    // Seed Fig. 9: a large displacement: 4 cm sideways, 2 cm back, 3 cm up, 6°, 4° and 5°.
    Eigen::Isometry3d target = defaults.X_BP_home;
    target.translation() += Eigen::Vector3d(0.04, -0.02, 0.03);
    target.linear() = (Eigen::AngleAxisd(5 * kv::common::kDeg, Eigen::Vector3d::UnitZ()) *
                       Eigen::AngleAxisd(4 * kv::common::kDeg, Eigen::Vector3d::UnitY()) *
                       Eigen::AngleAxisd(6 * kv::common::kDeg, Eigen::Vector3d::UnitX()))
                          .toRotationMatrix();
    const double move_mm = 1e3 * (target.translation() - defaults.X_BP_home.translation()).norm();
    const double move_deg = RotationDeg(target, defaults.X_BP_home);

    // The hand measurement of the camera pose: off by fixed sizes in seeded random directions.
    std::mt19937 rng(args.seed);
    std::normal_distribution<double> normal(0.0, 1.0);
    const Eigen::Vector3d dt = Eigen::Vector3d(normal(rng), normal(rng), normal(rng)).normalized();
    const Eigen::Vector3d dr = Eigen::Vector3d(normal(rng), normal(rng), normal(rng)).normalized();
    LegPoints d_point;
    for (Eigen::Vector3d& d : d_point) {
      d = Eigen::Vector3d(normal(rng), normal(rng), normal(rng)).normalized();
    }

    std::printf(
        "hexapod leg-direction servo: features %s, desired %s, gain %.2f 1/s, %.0f fps, %.1f s "
        "per run; target %.1f mm / %.1f deg from home\n",
        args.features.c_str(), args.desired.c_str(), args.gain, args.fps, args.duration_s, move_mm,
        move_deg);

    std::vector<RunResult> all;
    for (const kv::sim::WorldCameraConfig& camera : kv::sim::DefaultHexapodCameras()) {
      const std::string short_name = camera.name == "hexapod-perspective" ? "perspective" : "omni";
      if (args.camera != "both" && args.camera != short_name) continue;
      const Eigen::Isometry3d X_CB_true = camera.X_WC.inverse();
      LegPoints p_C_A_true;
      for (int j = 0; j < kHexapodLegs; ++j) p_C_A_true[j] = X_CB_true * truth.p_B_A[j];
      // E3: CAD points through the hand-measured camera pose (the camera's pose in B perturbed:
      // a rotation error turns the whole scene about the camera's viewpoint).
      Eigen::Isometry3d X_BC_hand = camera.X_WC;
      X_BC_hand.translation() += 1e-3 * args.hand_error_mm * dt;
      X_BC_hand.linear() = camera.X_WC.linear() *
                           Eigen::AngleAxisd(args.hand_error_deg * kv::common::kDeg, dr).matrix();
      const Eigen::Isometry3d X_CB_hand = X_BC_hand.inverse();
      LegPoints p_C_A_hand = kv::control::AttachmentPointsInCamera(nominal, X_CB_hand);
      for (int j = 0; j < kHexapodLegs; ++j) {
        p_C_A_hand[j] += 1e-3 * args.hand_point_error_mm * (X_CB_hand.linear() * d_point[j]);
      }

      for (const double sigma : args.image_noise) {
        Setup setup;
        setup.camera = short_name;
        setup.config = camera;
        setup.config.fps = args.fps;
        setup.config.render.noise_sigma = sigma;
        if (args.supersampling > 0) setup.config.render.supersampling = args.supersampling;
        setup.model = kv::vision::OpenCameraModel(camera.model);
        setup.X_CB = X_CB_true;
        char tag[64];
        std::snprintf(tag, sizeof tag, "%s-n%g", short_name.c_str(), sigma);
        setup.tag = tag;
        if (!kv::calibration::AllLegsInView(nominal, *setup.model, X_CB_true, target)) {
          spdlog::warn("{}: the target pose does not show every leg", setup.tag);
        }

        const auto start = std::chrono::steady_clock::now();
        Calibrated calibrated;
        if (!args.calibrated.empty()) {
          calibrated.p_C_A = ReadPoints(args.calibrated);
          calibrated.note = "from " + args.calibrated;
        } else {
          calibrated = CalibrateLive(args, setup, X_CB_hand);
        }
        // E1: CAD + rigid fit (seed eq. 15).
        std::vector<Eigen::Vector3d> measured(calibrated.p_C_A.begin(), calibrated.p_C_A.end());
        std::vector<Eigen::Vector3d> cad(nominal.p_B_A.begin(), nominal.p_B_A.end());
        Eigen::Isometry3d X_CB_fit;
        if (!kv::calibration::FitRigidTransform(measured, cad, &X_CB_fit)) {
          throw std::runtime_error(setup.tag + ": no rigid fit of the calibrated points");
        }
        const std::vector<Variant> variants = {
            {"E3_hand", p_C_A_hand, X_CB_hand},
            {"E2_calibrated", calibrated.p_C_A, X_CB_fit},
            {"E1_cad_fit", kv::control::AttachmentPointsInCamera(nominal, X_CB_fit), X_CB_fit}};
        std::printf(
            "%s (%s, noise %.1f): calibration %s; |A_j - A_j true| max: hand %.1f mm, "
            "calibrated %.1f mm, CAD+fit %.1f mm\n",
            setup.tag.c_str(), camera.name.c_str(), sigma, calibrated.note.c_str(),
            1e3 * MaxPointError(variants[0].p_C_A, p_C_A_true),
            1e3 * MaxPointError(variants[1].p_C_A, p_C_A_true),
            1e3 * MaxPointError(variants[2].p_C_A, p_C_A_true));
        std::fflush(stdout);
        if (args.probe && args.features == "image") {
          PrintProbe(Probe(args, setup, variants[1], target), std::max(2, args.teach_frames));
        }
        std::vector<RunResult> runs;
        for (const Variant& v : variants) {
          runs.push_back(RunServo(args, setup, v, p_C_A_true, target));
          const RunResult& r = runs.back();
          std::printf(
              "  %-13s floor %.2e (true %.2e), tau %s s, rebound %.3f %%, past %.3f mm, "
              "pose %.3f mm %.4f deg\n",
              r.name.c_str(), r.floor, r.true_floor, Num(r.tau, "%.3f").c_str(), 100 * r.rebound,
              r.past_mm, r.pose_mm, r.pose_deg);
          std::fflush(stdout);
        }
        WriteCombinedPlot(args.out + "/" + setup.tag + "-convergence.png",
                          "|e|, " + camera.name + ", image noise " + Num(sigma, "%.1f") +
                              ", features " + args.features,
                          runs);
        std::printf(
            "  (%.0f s wall)\n",
            std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
        all.insert(all.end(), runs.begin(), runs.end());
      }
    }
    std::printf(
        "\nsummary. floor, peak: median and max |e| over the last %.1f s; true flr: the same "
        "for the |e| of the true directions (simulation); bias: |u* - u_true| at the goal; "
        "t arr: remaining displacement <= 0.2 mm, 0.05 deg; tau, C: |e| <= C e0 exp(-t/tau) until "
        "|e| <= max(1e-4, 3 floor)\n",
        args.floor_window_s);
    PrintConvergenceTable(all);
    std::printf(
        "\n|dA|: max |A_j - A_j true|; |dA|-t: the same without the errors' common "
        "translation (to which the law is invariant); rebound, true reb: overshoot of the "
        "measured and the true |e|; past, past rest: of the position beyond the goal and beyond "
        "where it came to rest; pose: true platform pose vs the goal "
        "at the end\n");
    PrintOvershootTable(all);
    WriteSummaryCsv(args.out + "/summary.csv", all);
    std::printf("logs, plots, datasets and calibrations in %s/\n", args.out.c_str());
  } catch (const std::exception& e) {
    std::fprintf(stderr, "hexapod_servo_convergence: %s\n", e.what());
    return 1;
  }
  return 0;
}
