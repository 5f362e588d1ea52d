// Issue 6, experiment 1 (seed 002 §V-A): accuracy of the base attachment points A_j calibrated
// from the image edges of the legs, for the seed's two cameras, in simulation, through the real
// pipeline end to end:
//
//   truth      sim::TrueHexapodModel(): the nominal HexapodModel::Default() with its base and
//              platform points moved by N(0, --base-sigma-mm / --platform-sigma-mm) per axis and
//              its joint offsets by N(0, --offset-sigma-mm); the camera is mounted off its drawn
//              pose by --camera-error-mm and --camera-error-deg (random directions);
//   poses      calibration::PlanCalibrationPoses() on the NOMINAL model, --poses poses, admissible
//              when every leg of the nominal robot projects inside the image (10 px margin, at 15,
//              50 and 85 % of its length) from the drawn camera pose; the drives are set to the
//              nominal inverse kinematics of each pose, so the TRUE platform goes where the true
//              robot's forward kinematics of those leg lengths puts it;
//   images     vision::render::Renderer + HexapodScene of the true robot at that true pose from
//              the true camera pose (supersampling 4, noise σ = 1 grey level);
//   edges      vision::hexapod::ObserveLegs() around the NOMINAL prediction (nominal model,
//              planned pose, drawn camera pose: what a user has), two passes as in
//              calibration/hexapod/dataset_calibration.cc (the second searches around the first
//              pass's estimate: the rigid fit X_CB for the platform ends, Â_j for the base ends);
//   extra      "perturbed" runs: every final edge point of every limb is moved by N(0, σ²I) in the
//              image (σ = --edge-noise-px, so σ across the edge) and --outlier-fraction of them are
//              replaced by outliers displaced 5–40 px across the true edge (either side); then the
//              limbs are refitted from scratch (MSAC start: the fit does not know which points
//              were made outliers, nor the unperturbed fit) by vision::hexapod::RefitObservedLegs;
//              "clean" runs use the rendered edges as they are;
//   estimate   calibration::CalibrateHexapod() (Tukey MM-estimator, eq. 14; rigid fit eq. 15;
//              scales eq. 16) against the nominal (CAD) base points.
//
// Measured, per camera and per run (and summarised over --draws draws of truth, camera mount,
// image noise and perturbation):
//   |Â−A|     |Â_j − A_j^true| (mm), A_j^true = X_CB_true · p_B_A_true: median and max over the
//             six legs; the target is a median of at most 4 mm;
//   seed fig  the seed's figure: sqrt(median_j |Â_j − X̂_CB A_j^CAD|²) after the rigid fit of
//             eq. 15 (seed: 12 mm omnidirectional, 8 mm perspective); rigid rms its RMS;
//   depth     mean over legs of the error component along the viewing ray of A_j (mm, + farther
//             than the truth): a bias of the edge locator on the apparent leg width shows here
//             (eq. 14 is linear in R: legs that look thinner look farther);
//   scale     eq. 16's three estimates (least-squares similarity, median and max ratio);
//   cond      range of the six legs' eq. 14 condition numbers; legs/pose, how many legs were seen
//             per pose (mean and minimum over the poses of the last pass);
//   edge px   signed pixel distance of the last pass's inlier edge points to the TRUE limb curves
//             (+ outside the leg): its mean is the edge locator's bias, and its RMS.
//
// Cameras: "omni" builtin:unified-default 640×480 between the legs (viewpoint 3 cm above the base
// centre, mirror axis up: the seed's "retina parallel to the base plane"); "perspective" a pinhole
// 1024×780 without distortion, f = --focal-px (1300 px), --distance (1.15 m) from (0, 0, 0.2) m in
// the direction of sim::DefaultHexapodCameras()' perspective camera (30° round from the front, 25°
// elevation: from straight in front, the seed's Fig. 2, pairs of legs hide each other); over the
// planned poses the leg axes then span u 133–919 and v 51–712 px: the robot fills the image.
// Both scenes have their plates on (the sim world's).
//
// Also for the diagnosis of the figures: --locator parabola (the first version's edge locator,
// biased into the legs by their shading), --blur-px (optics blur in the images) with
// --edge-blur-px (the blur the step-ramp locator models), --loss (eq. 14's estimator),
// --per-leg (every leg's error, configurations, down-weighted equations, edge bias).
//
// A full run (both cameras, 60 poses, 5 draws) takes ~15 s on one core. The same pipeline in
// small guards the figures in tests/calibration/hexapod/calibration_accuracy_test.cc.

#include <spdlog/spdlog.h>

#include <CLI/CLI.hpp>
#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <optional>
#include <random>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "calibration/hexapod/leg_calibration.h"
#include "calibration/hexapod/pose_planner.h"
#include "common/units.h"
#include "robots/hexapod/hexapod_model.h"
#include "sim/hexapod_world.h"
#include "vision/camera/camera_file.h"
#include "vision/camera/pinhole_camera.h"
#include "vision/hexapod/leg_edges.h"
#include "vision/render/renderer.h"
#include "vision/render/scenes/hexapod_scene.h"

namespace {

namespace calibration = kinevis::calibration;
namespace render = kinevis::vision::render;
namespace robots = kinevis::robots;
namespace vision = kinevis::vision;
namespace edges = kinevis::vision::hexapod;
using robots::kHexapodLegs;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

struct Args {
  std::string cameras = "omni,perspective";
  int poses = 60;
  int candidates = 2000;
  uint64_t plan_seed = 1;
  int draws = 5;
  unsigned seed = 1;
  double base_sigma_mm = 0.5;
  double platform_sigma_mm = 0.5;
  double offset_sigma_mm = 1.0;
  double camera_error_mm = 10.0;
  double camera_error_deg = 1.0;
  double edge_noise_px = 0.5;
  double outlier_fraction = 0.1;
  double outlier_min_px = 5.0;
  double outlier_max_px = 40.0;
  double focal_px = 1300.0;
  double distance = 1.15;
  int supersampling = 4;
  double image_noise = 1.0;
  double blur_px = 0.0;
  double edge_blur_px = 0.0;
  std::string locator = "step-ramp";
  std::string loss = "tukey";
  bool correct_scale = false;
  int passes = 2;
  bool list_poses = false;
  bool per_leg = false;
};

// One camera of the experiment: its model and the drawn (nominal) pose of B in C, which is also
// the user's hint; the true mount is drawn off it per draw.
struct CameraCase {
  std::string name;
  int id = 0;  // mixed into the random draws, so a camera's figures do not depend on --cameras
  std::string description;
  std::unique_ptr<vision::CameraModel> camera;
  Eigen::Isometry3d X_CB_drawn = Eigen::Isometry3d::Identity();
  double target_mm = 4.0;
  double seed_mm = 0.0;
};

CameraCase OmniCase() {
  CameraCase c;
  c.name = "omni";
  c.camera = vision::BuiltinCameraModel("unified-default");
  c.description =
      "builtin:unified-default 640x480 (xi 0.95, gamma 230 px), viewpoint 3 cm above the base "
      "centre, mirror axis up";
  Eigen::Isometry3d X_BC = Eigen::Isometry3d::Identity();
  X_BC.translation() = Eigen::Vector3d(0.0, 0.0, 0.03);
  c.X_CB_drawn = X_BC.inverse();
  c.seed_mm = 12.0;
  return c;
}

CameraCase PerspectiveCase(const Args& args) {
  CameraCase c;
  c.name = "perspective";
  c.id = 1;
  vision::PinholeBrownParameters p;
  p.width = 1024;
  p.height = 780;
  p.fx = p.fy = args.focal_px;
  p.cx = 511.5;
  p.cy = 389.5;
  c.camera = std::make_unique<vision::PinholeBrownCamera>(p);
  const Eigen::Vector3d target(0.0, 0.0, 0.2);
  // sim::DefaultHexapodCameras()' direction: eye (0.85, -1.47, 1.0) looking at (0, 0, 0.2).
  const Eigen::Vector3d direction = (Eigen::Vector3d(0.85, -1.47, 1.0) - target).normalized();
  const Eigen::Vector3d eye = target + args.distance * direction;
  c.X_CB_drawn = render::CameraLookingAt(eye, target, Eigen::Vector3d::UnitZ()).inverse();
  char text[256];
  std::snprintf(text, sizeof text,
                "pinhole 1024x780, f = %.0f px, no distortion, eye (%.3f, %.3f, %.3f) m looking "
                "at (0, 0, 0.2) m (%.2f m, 30 deg round, %.0f deg elevation)",
                args.focal_px, eye.x(), eye.y(), eye.z(), args.distance,
                std::asin(direction.z()) / kinevis::common::kDeg);
  c.description = text;
  c.seed_mm = 8.0;
  return c;
}

double Median(std::vector<double> v) {
  v.erase(std::remove_if(v.begin(), v.end(), [](double x) { return !std::isfinite(x); }), v.end());
  if (v.empty()) return kNaN;
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

Eigen::Vector3d RandomUnit(std::mt19937_64* rng) {
  std::normal_distribution<double> normal(0.0, 1.0);
  Eigen::Vector3d v(normal(*rng), normal(*rng), normal(*rng));
  return v.normalized();
}

// A generator for one (draw, camera, variant, pass, pose) cell, so that every run is
// reproducible on its own.
std::mt19937_64 Generator(unsigned seed, int draw, int camera, int variant, int pass, int pose) {
  std::seed_seq s{seed,
                  static_cast<unsigned>(draw),
                  static_cast<unsigned>(camera),
                  static_cast<unsigned>(variant),
                  static_cast<unsigned>(pass),
                  static_cast<unsigned>(pose)};
  return std::mt19937_64(s);
}

// The extra perturbation of one limb's edge points (the simulator's knowledge: the true limb
// plane n_true gives the direction across the edge): N(0, σ²) per image axis on every point, then
// a random `fraction` of them displaced by 5–40 px across the edge, either side. Points whose
// moved pixel cannot be back-projected are drawn again (at most 8 times, else left where they
// were). Returns the number of outliers made.
int PerturbLimbPoints(const vision::CameraModel& camera, const Eigen::Vector3d& n_true,
                      const Args& args, std::mt19937_64* rng,
                      std::vector<edges::EdgePoint>* points) {
  std::normal_distribution<double> noise(0.0, args.edge_noise_px);
  std::uniform_real_distribution<double> offset(args.outlier_min_px, args.outlier_max_px);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  const int n = static_cast<int>(points->size());
  // Which points become outliers: a random subset of round(fraction · n).
  std::vector<int> order(n);
  for (int i = 0; i < n; ++i) order[i] = i;
  std::shuffle(order.begin(), order.end(), *rng);
  const int outliers = static_cast<int>(std::lround(args.outlier_fraction * n));
  std::vector<char> is_outlier(n, 0);
  for (int i = 0; i < outliers; ++i) is_outlier[order[i]] = 1;
  int made = 0;
  for (int i = 0; i < n; ++i) {
    edges::EdgePoint& p = (*points)[i];
    // The image normal of the true limb curve at the point: the gradient of n · ray(pixel).
    const Eigen::Vector2d across = (p.d_ray_d_pixel.transpose() * n_true).normalized();
    for (int attempt = 0; attempt < 8; ++attempt) {
      Eigen::Vector2d pixel = p.pixel + Eigen::Vector2d(noise(*rng), noise(*rng));
      if (is_outlier[i]) pixel += (unit(*rng) < 0.5 ? -1.0 : 1.0) * offset(*rng) * across;
      edges::EdgePoint moved = p;
      if (camera.InImage(pixel) && edges::MakeEdgePoint(camera, pixel, &moved)) {
        p = moved;
        made += is_outlier[i];
        break;
      }
    }
  }
  return made;
}

// What one calibration run (all passes) gave.
struct Run {
  calibration::HexapodCalibrationResult result;
  std::array<double, kHexapodLegs> error{};  // |Â_j − A_j^true| (m), NaN when not estimated
  double median_mm = kNaN, max_mm = kNaN, seed_mm = kNaN, depth_mm = kNaN;
  double legs_per_pose = 0.0;
  int min_legs = kHexapodLegs;
  double cond_min = kNaN, cond_max = kNaN;
  long points = 0, outliers = 0;  // edge points of the last pass, and how many were made outliers
  // Signed pixel distance of the last pass's inlier edge points to the TRUE limb curve, + outside
  // the leg: mean (the edge locator's bias) and RMS.
  double edge_bias_px = kNaN, edge_rms_px = kNaN;
  std::array<double, kHexapodLegs> leg_bias_px{}, leg_rms_px{};
};

// The true robot at one planned pose and its rendered image.
struct Frame {
  Eigen::Isometry3d X_BP_true;
  std::vector<uint8_t> pixels;
};

Run Calibrate(const CameraCase& cc, int camera_index, const std::vector<Frame>& frames,
              const std::vector<Eigen::Isometry3d>& planned, const robots::HexapodModel& nominal,
              const robots::HexapodModel& truth, const Eigen::Isometry3d& X_CB_true,
              const Args& args, int draw, bool perturb) {
  const vision::CameraModel& camera = *cc.camera;
  edges::LegEdgeOptions edge_options;
  edge_options.locator =
      args.locator == "parabola" ? edges::EdgeLocator::kParabola : edges::EdgeLocator::kStepRamp;
  edge_options.edge_blur_px = args.edge_blur_px;
  calibration::HexapodCalibrationOptions calibration_options;
  calibration_options.loss = args.loss == "huber"           ? calibration::RobustLoss::kHuber
                             : args.loss == "least-squares" ? calibration::RobustLoss::kLeastSquares
                                                            : calibration::RobustLoss::kTukey;
  calibration_options.correct_scale = args.correct_scale;
  auto workspace = std::make_unique<edges::LegEdgeWorkspace>();
  Eigen::Isometry3d X_CB = cc.X_CB_drawn;
  std::optional<std::array<Eigen::Vector3d, kHexapodLegs>> p_C_A;
  Run run;
  std::vector<int> seen(frames.size(), 0);
  for (int pass = 0; pass < args.passes; ++pass) {
    calibration::HexapodCalibrationData data;
    data.leg_radius = nominal.leg_radius;
    data.configurations.resize(frames.size());
    run.points = run.outliers = 0;
    double bias_sum = 0.0, bias_sum2 = 0.0;
    long bias_count = 0;
    std::array<double, kHexapodLegs> leg_sum{}, leg_sum2{};
    std::array<long, kHexapodLegs> leg_count{};
    for (size_t k = 0; k < frames.size(); ++k) {
      // The prediction a user has: the nominal model at the planned pose (= the nominal forward
      // kinematics of the readings), the camera where the drawing (or the last pass) puts it.
      std::array<edges::LegPrediction, kHexapodLegs> predictions =
          edges::PredictLegs(nominal, planned[k], X_CB);
      if (p_C_A) {
        for (int j = 0; j < kHexapodLegs; ++j) {
          if ((*p_C_A)[j].allFinite()) predictions[j].p_C_A = (*p_C_A)[j];
        }
      }
      vision::ImageView8 view;
      view.data = const_cast<uint8_t*>(frames[k].pixels.data());
      view.width = camera.width();
      view.height = camera.height();
      view.stride = static_cast<size_t>(camera.width());
      edges::ObserveLegs(view, camera, predictions, edge_options, workspace.get());
      const std::array<edges::LegPrediction, kHexapodLegs> true_legs =
          edges::PredictLegs(truth, frames[k].X_BP_true, X_CB_true);
      if (perturb) {
        std::mt19937_64 rng =
            Generator(args.seed, draw, camera_index, 1, pass, static_cast<int>(k));
        for (int j = 0; j < kHexapodLegs; ++j) {
          if (!workspace->observations[j].visible) continue;
          Eigen::Vector3d n_true[2];
          render::PredictCylinderLimbs(true_legs[j].p_C_A, true_legs[j].p_C_B, truth.leg_radius,
                                       &n_true[0], &n_true[1]);
          for (int limb = 0; limb < 2; ++limb) {
            run.outliers +=
                PerturbLimbPoints(camera, n_true[limb], args, &rng, &workspace->points[j][limb]);
          }
        }
        edges::RefitObservedLegs(predictions, edge_options, workspace.get());
      }
      seen[k] = 0;
      for (int j = 0; j < kHexapodLegs; ++j) {
        const edges::LegObservation& o = workspace->observations[j];
        if (!o.visible) continue;
        Eigen::Vector3d n_true[2];
        render::PredictCylinderLimbs(true_legs[j].p_C_A, true_legs[j].p_C_B, truth.leg_radius,
                                     &n_true[0], &n_true[1]);
        for (int limb = 0; limb < 2; ++limb) {
          for (const edges::EdgePoint& e : workspace->points[j][limb]) {
            if (!e.inlier) continue;
            const double g = (e.d_ray_d_pixel.transpose() * n_true[limb]).norm();
            const double d = n_true[limb].dot(e.ray_C) / g;
            bias_sum += d;
            bias_sum2 += d * d;
            ++bias_count;
            leg_sum[j] += d;
            leg_sum2[j] += d * d;
            ++leg_count[j];
          }
        }
        data.configurations[k][j] = calibration::LegLimbs{o.limbs[0].n_C, o.limbs[1].n_C};
        ++seen[k];
        run.points += o.limbs[0].points + o.limbs[1].points;
      }
    }
    run.result = calibration::CalibrateHexapod(data, nominal, calibration_options);
    if (bias_count > 0) {
      run.edge_bias_px = bias_sum / bias_count;
      run.edge_rms_px = std::sqrt(bias_sum2 / bias_count);
    }
    for (int j = 0; j < kHexapodLegs; ++j) {
      run.leg_bias_px[j] = leg_count[j] > 0 ? leg_sum[j] / leg_count[j] : kNaN;
      run.leg_rms_px[j] = leg_count[j] > 0 ? std::sqrt(leg_sum2[j] / leg_count[j]) : kNaN;
    }
    if (!run.result.rigid_fit) break;
    X_CB = run.result.X_CB;
    p_C_A = run.result.p_C_A;
  }

  // Figures of the last pass.
  std::vector<double> errors, residual2;
  double depth = 0.0;
  int estimated = 0;
  for (int j = 0; j < kHexapodLegs; ++j) {
    const calibration::LegCalibration& leg = run.result.legs[j];
    run.error[j] = kNaN;
    if (leg.status != calibration::LegStatus::kEstimated) continue;
    const Eigen::Vector3d a_true = X_CB_true * truth.p_B_A[j];
    const Eigen::Vector3d e = run.result.p_C_A[j] - a_true;
    run.error[j] = e.norm();
    errors.push_back(e.norm());
    depth += e.dot(a_true.normalized());
    ++estimated;
    if (std::isfinite(leg.rigid_fit_residual))
      residual2.push_back(std::pow(leg.rigid_fit_residual, 2));
    run.cond_min = std::isnan(run.cond_min) ? leg.condition_number
                                            : std::min(run.cond_min, leg.condition_number);
    run.cond_max = std::isnan(run.cond_max) ? leg.condition_number
                                            : std::max(run.cond_max, leg.condition_number);
  }
  if (estimated > 0) {
    run.median_mm = 1e3 * Median(errors);
    run.max_mm = 1e3 * *std::max_element(errors.begin(), errors.end());
    run.depth_mm = 1e3 * depth / estimated;
  }
  run.seed_mm = 1e3 * std::sqrt(Median(residual2));
  long total = 0;
  for (int s : seen) {
    total += s;
    run.min_legs = std::min(run.min_legs, s);
  }
  run.legs_per_pose = frames.empty() ? 0.0 : static_cast<double>(total) / frames.size();
  return run;
}

void PrintPlan(const calibration::PosePlan& plan, const Args& args,
               const robots::HexapodModel& nominal, const CameraCase& cc) {
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(1e9), hi = -lo;
  double tilt_max = 0.0, yaw_max = 0.0;
  const Eigen::Vector3d p0 = robots::HexapodModel::NominalPose().translation();
  for (const Eigen::Isometry3d& X : plan.X_BP) {
    const Eigen::Vector3d d = 1e3 * (X.translation() - p0);
    lo = lo.cwiseMin(d);
    hi = hi.cwiseMax(d);
    const Eigen::Vector3d z = X.linear().col(2);
    tilt_max = std::max(tilt_max, std::acos(std::clamp(z.z(), -1.0, 1.0)) / kinevis::common::kDeg);
    const Eigen::AngleAxisd aa(X.linear());
    yaw_max = std::max(yaw_max, std::abs(aa.angle() * aa.axis().z()) / kinevis::common::kDeg);
  }
  double angle_lo = 1e9, angle_hi = 0.0;
  for (const calibration::LegSpread& s : plan.legs) {
    angle_lo = std::min(angle_lo, s.max_angle / kinevis::common::kDeg);
    angle_hi = std::max(angle_hi, s.max_angle / kinevis::common::kDeg);
  }
  std::printf(
      "poses: %zu from calibration::PlanCalibrationPoses(nominal; seed %llu, %d candidates, %d "
      "admissible; admissible = every nominal leg >= 10 px inside the image at 15/50/85 %% of "
      "its length, seen from the drawn camera pose)\n",
      plan.X_BP.size(), static_cast<unsigned long long>(args.plan_seed), plan.candidates_tried,
      plan.candidates_admissible);
  std::printf(
      "       platform offset from the nominal pose x [%.0f, %.0f] y [%.0f, %.0f] z [%.0f, %.0f] "
      "mm, tilt <= %.1f deg, |rotation about z| <= %.1f deg; per-leg largest angle between "
      "directions %.0f-%.0f deg\n",
      lo.x(), hi.x(), lo.y(), hi.y(), lo.z(), hi.z(), tilt_max, yaw_max, angle_lo, angle_hi);
  // Where the legs are in the image over the plan (nominal robot, drawn camera pose): how much of
  // the image the robot fills.
  Eigen::Vector2d px_lo = Eigen::Vector2d::Constant(1e9), px_hi = -px_lo;
  for (const Eigen::Isometry3d& X : plan.X_BP) {
    for (const edges::LegPrediction& leg : edges::PredictLegs(nominal, X, cc.X_CB_drawn)) {
      for (double t = 0.0; t <= 1.0; t += 0.05) {
        Eigen::Vector2d px;
        if (cc.camera->Project(leg.p_C_A + t * (leg.p_C_B - leg.p_C_A), &px) !=
            vision::ProjectionStatus::kOk) {
          continue;
        }
        px_lo = px_lo.cwiseMin(px);
        px_hi = px_hi.cwiseMax(px);
      }
    }
  }
  std::printf(
      "       leg axes in the image over the poses: u [%.0f, %.0f], v [%.0f, %.0f] px of %dx%d\n",
      px_lo.x(), px_hi.x(), px_lo.y(), px_hi.y(), cc.camera->width(), cc.camera->height());
  for (const std::string& w : plan.warnings) std::printf("       planner warning: %s\n", w.c_str());
  if (args.list_poses) {
    for (size_t k = 0; k < plan.X_BP.size(); ++k) {
      const Eigen::Isometry3d& X = plan.X_BP[k];
      const Eigen::AngleAxisd aa(X.linear());
      const Eigen::Vector3d r = aa.angle() / kinevis::common::kDeg * aa.axis();
      std::printf(
          "       pose %2zu: p_BP (%7.1f %7.1f %7.1f) mm, rotation vector (%6.2f %6.2f %6.2f) "
          "deg\n",
          k, 1e3 * X.translation().x(), 1e3 * X.translation().y(), 1e3 * X.translation().z(), r.x(),
          r.y(), r.z());
    }
  }
}

struct Spread {
  std::vector<double> median, max, seed, depth;
};

void PrintRunLine(int draw, const char* variant, const Run& r) {
  std::printf(
      "%4d  %-9s  %4.2f (%d)  %5.0f-%-5.0f  %7.2f %7.2f  %7.2f %7.2f  %+7.2f  %.4f/%.4f/%.4f  "
      "%+6.3f %5.3f %s\n",
      draw, variant, r.legs_per_pose, r.min_legs, r.cond_min, r.cond_max, r.median_mm, r.max_mm,
      r.seed_mm, 1e3 * r.result.rigid_fit_rms, r.depth_mm, r.result.scale_least_squares,
      r.result.scale_median_ratio, r.result.scale_max_ratio, r.edge_bias_px, r.edge_rms_px,
      r.result.ok() ? "" : ("errors: " + std::to_string(r.result.errors.size())).c_str());
}

std::string Range(const std::vector<double>& v) {
  if (v.empty()) return "-";
  char text[96];
  std::snprintf(text, sizeof text, "%.2f [%.2f, %.2f]", Median(v),
                *std::min_element(v.begin(), v.end()), *std::max_element(v.begin(), v.end()));
  return text;
}

}  // namespace

int main(int argc, char** argv) {
  Args args;
  CLI::App app{
      "Hexapod base attachment points A_j calibrated from rendered leg edges, against the truth, "
      "for the omnidirectional (640x480) and perspective (1024x780) cameras (issue 6, experiment "
      "1; seed 002 section V-A: 12 mm and 8 mm; target <= 4 mm). See the header of "
      "experiments/hexapod_calibration_accuracy.cc for what is measured."};
  app.add_option("--cameras", args.cameras, "comma-separated: omni, perspective");
  app.add_option("--poses", args.poses, "planned robot configurations per calibration");
  app.add_option("--candidates", args.candidates, "pose planner candidates");
  app.add_option("--plan-seed", args.plan_seed, "pose planner seed");
  app.add_option("--draws", args.draws,
                 "independent draws of truth, camera mount, image noise and perturbation");
  app.add_option("--seed", args.seed,
                 "base seed: draw d uses the truth seed seed + d and generators seeded by (seed, "
                 "d, camera, run, pass, pose)");
  app.add_option("--base-sigma-mm", args.base_sigma_mm, "truth: base points vs CAD, per axis");
  app.add_option("--platform-sigma-mm", args.platform_sigma_mm,
                 "truth: platform points vs CAD, per axis");
  app.add_option("--offset-sigma-mm", args.offset_sigma_mm, "truth: joint offsets q0 vs CAD");
  app.add_option("--camera-error-mm", args.camera_error_mm,
                 "true camera mount off its drawn pose (the user's hint), random direction");
  app.add_option("--camera-error-deg", args.camera_error_deg,
                 "true camera mount rotation off the drawn one, random axis");
  app.add_option("--edge-noise-px", args.edge_noise_px,
                 "perturbed runs: N(0, sigma) per image axis on every edge point");
  app.add_option("--outlier-fraction", args.outlier_fraction,
                 "perturbed runs: fraction of the edge points made outliers");
  app.add_option("--outlier-min-px", args.outlier_min_px, "outlier displacement, smallest");
  app.add_option("--outlier-max-px", args.outlier_max_px, "outlier displacement, largest");
  app.add_option("--focal-px", args.focal_px, "perspective camera focal length (px)");
  app.add_option("--distance", args.distance, "perspective camera distance from (0, 0, 0.2) m (m)");
  app.add_option("--supersampling", args.supersampling, "renderer supersampling of edge pixels");
  app.add_option("--image-noise", args.image_noise, "renderer noise sigma (grey levels)");
  app.add_option("--blur-px", args.blur_px, "renderer Gaussian blur sigma (px), 0 = sharp");
  app.add_option(
      "--edge-blur-px", args.edge_blur_px,
      "blur sigma (px) the step-ramp edge locator models (LegEdgeOptions::edge_blur_px)");
  app.add_option("--locator", args.locator,
                 "sub-pixel edge locator of the leg edges: step-ramp (default) or parabola")
      ->check(CLI::IsMember({"step-ramp", "parabola"}));
  app.add_option("--loss", args.loss, "eq. 14 estimator: tukey (default), huber, least-squares")
      ->check(CLI::IsMember({"tukey", "huber", "least-squares"}));
  app.add_flag("--correct-scale", args.correct_scale,
               "divide the A_j by the estimated scale (eq. 16) before comparing");
  app.add_option("--passes", args.passes, "extraction + calibration passes (>= 1)");
  app.add_flag("--list-poses", args.list_poses, "print every planned pose");
  app.add_flag("--per-leg", args.per_leg, "print every leg's error per run");
  CLI11_PARSE(app, argc, argv);
  spdlog::set_level(spdlog::level::warn);

  try {
    if (args.poses < 2 || args.draws < 1 || args.passes < 1 || args.supersampling < 1 ||
        !(args.outlier_fraction >= 0.0 && args.outlier_fraction <= 1.0) ||
        !(args.outlier_min_px <= args.outlier_max_px)) {
      throw std::invalid_argument(
          "bad options: need --poses >= 2, --draws >= 1, --passes >= 1, --supersampling >= 1, "
          "--outlier-fraction in [0, 1], --outlier-min-px <= --outlier-max-px");
    }
    std::vector<CameraCase> cases;
    std::stringstream list(args.cameras);
    for (std::string name; std::getline(list, name, ',');) {
      if (name == "omni") {
        cases.push_back(OmniCase());
      } else if (name == "perspective") {
        cases.push_back(PerspectiveCase(args));
      } else {
        throw std::invalid_argument("--cameras: unknown camera '" + name + "' (omni, perspective)");
      }
    }
    const auto t0 = std::chrono::steady_clock::now();
    const robots::HexapodModel nominal = robots::HexapodModel::Default();
    std::printf(
        "hexapod calibration accuracy (seed 002 section V-A): %d poses, %d draws, %d passes; "
        "truth: base/platform points sigma %.2f/%.2f mm, joint offsets %.2f mm, camera mount "
        "%.1f mm / %.2f deg off the drawn pose; images: supersampling %d, noise sigma %.1f, "
        "blur %.2f px; edges: %s locator (modelled blur %.2f px); perturbed runs: +N(0, %.2f px) "
        "per axis, %.0f %% "
        "outliers at %.0f-%.0f px across the edge\n",
        args.poses, args.draws, args.passes, args.base_sigma_mm, args.platform_sigma_mm,
        args.offset_sigma_mm, args.camera_error_mm, args.camera_error_deg, args.supersampling,
        args.image_noise, args.blur_px, args.locator.c_str(), args.edge_blur_px, args.edge_noise_px,
        100.0 * args.outlier_fraction, args.outlier_min_px, args.outlier_max_px);

    for (size_t ci = 0; ci < cases.size(); ++ci) {
      const CameraCase& cc = cases[ci];
      const vision::CameraModel& camera = *cc.camera;
      std::printf("\n== %s: %s\n", cc.name.c_str(), cc.description.c_str());
      calibration::PosePlannerOptions plan_options;
      plan_options.poses = args.poses;
      plan_options.candidates = std::max(args.candidates, args.poses);
      plan_options.seed = args.plan_seed;
      plan_options.X_CB = cc.X_CB_drawn;
      plan_options.admissible = [&](const Eigen::Isometry3d& X_BP) {
        return calibration::AllLegsInView(nominal, camera, cc.X_CB_drawn, X_BP);
      };
      const calibration::PosePlan plan = calibration::PlanCalibrationPoses(nominal, plan_options);
      PrintPlan(plan, args, nominal, cc);
      if (plan.X_BP.size() < 2) throw std::runtime_error(cc.name + ": fewer than 2 poses planned");

      std::printf(
          "draw  edges      legs/pose  cond eq.14    |A-A*| mm       seed fig  rigid   depth    "
          "scale ls/median/max     edge px\n"
          "                 mean(min)  min-max       median     max  mm       rms mm  mm       "
          "                        bias   rms\n");
      Spread clean, perturbed;
      for (int draw = 0; draw < args.draws; ++draw) {
        kinevis::sim::HexapodWorldConfig config;
        config.base_point_sigma_mm = args.base_sigma_mm;
        config.platform_point_sigma_mm = args.platform_sigma_mm;
        config.joint_offset_sigma_mm = args.offset_sigma_mm;
        config.seed = args.seed + static_cast<unsigned>(draw);
        const robots::HexapodModel truth = kinevis::sim::TrueHexapodModel(config);
        std::mt19937_64 mount = Generator(args.seed, draw, cc.id, 0, 0, -1);
        Eigen::Isometry3d X_BC_true = cc.X_CB_drawn.inverse();
        X_BC_true.translation() += 1e-3 * args.camera_error_mm * RandomUnit(&mount);
        X_BC_true.linear() =
            Eigen::AngleAxisd(args.camera_error_deg * kinevis::common::kDeg, RandomUnit(&mount))
                .toRotationMatrix() *
            X_BC_true.linear();
        const Eigen::Isometry3d X_CB_true = X_BC_true.inverse();

        render::RenderOptions ro;
        ro.supersampling = args.supersampling;
        ro.noise_sigma = args.image_noise;
        ro.blur_sigma_px = args.blur_px;
        ro.seed = 1000u * args.seed + static_cast<unsigned>(draw);
        render::Renderer renderer(camera, ro);
        std::vector<Frame> frames;
        std::vector<Eigen::Isometry3d> planned;
        robots::HexapodData ik, fk;
        for (size_t k = 0; k < plan.X_BP.size(); ++k) {
          // The drives go to the nominal IK of the planned pose; the true platform follows the
          // true robot's FK of the resulting leg lengths.
          robots::InverseKinematics(nominal, plan.X_BP[k], &ik);
          const robots::Vector6d s = robots::JointPositionsFromLegLengths(nominal, ik.q);
          const robots::Vector6d q_true = robots::LegLengthsFromJointPositions(truth, s);
          const robots::ForwardKinematicsSummary f = robots::ForwardKinematics(
              truth, q_true, plan.X_BP[k], robots::ForwardKinematicsOptions{}, &fk);
          if (!f.converged()) continue;  // the true robot cannot assemble there: skip the pose
          Frame frame;
          frame.X_BP_true = f.X_BP;
          frame.pixels.assign(static_cast<size_t>(camera.width()) * camera.height(), 0);
          const render::HexapodScene scene(truth, f.X_BP, X_CB_true);
          renderer.Render(scene, k,
                          vision::ImageView8{frame.pixels.data(), camera.width(), camera.height(),
                                             static_cast<size_t>(camera.width())});
          frames.push_back(std::move(frame));
          planned.push_back(plan.X_BP[k]);
        }
        for (int variant = 0; variant < 2; ++variant) {
          const bool perturb = variant == 1;
          const Run r =
              Calibrate(cc, cc.id, frames, planned, nominal, truth, X_CB_true, args, draw, perturb);
          PrintRunLine(draw, perturb ? "perturbed" : "clean", r);
          if (args.per_leg) {
            std::printf("                 edge points %ld", r.points);
            if (perturb) std::printf(" (%ld made outliers)", r.outliers);
            std::printf("\n");
            for (int j = 0; j < kHexapodLegs; ++j) {
              const calibration::LegCalibration& leg = r.result.legs[j];
              std::printf(
                  "                 leg %d: |A-A*| %6.2f mm, %2d configurations, %3d equations "
                  "down-weighted, sigma %.2f mm, cond %.0f, edges bias %+.3f rms %.3f px\n",
                  j, 1e3 * r.error[j], leg.configurations, leg.down_weighted, 1e3 * leg.sigma,
                  leg.condition_number, r.leg_bias_px[j], r.leg_rms_px[j]);
            }
          }
          for (const std::string& e : r.result.errors) std::printf("      error: %s\n", e.c_str());
          Spread& s = perturb ? perturbed : clean;
          s.median.push_back(r.median_mm);
          s.max.push_back(r.max_mm);
          s.seed.push_back(r.seed_mm);
          s.depth.push_back(r.depth_mm);
        }
      }
      std::printf("%s over %d draws, median [min, max] of the per-draw figures (mm):\n",
                  cc.name.c_str(), args.draws);
      for (const auto& [label, s] :
           {std::pair<const char*, const Spread*>{"clean", &clean}, {"perturbed", &perturbed}}) {
        const double worst_median = *std::max_element(s->median.begin(), s->median.end());
        std::printf(
            "  %-9s median |A-A*| %s, max |A-A*| %s, seed figure %s, depth %s -> target "
            "<= %.0f mm %s (seed %.0f mm)\n",
            label, Range(s->median).c_str(), Range(s->max).c_str(), Range(s->seed).c_str(),
            Range(s->depth).c_str(), cc.target_mm,
            worst_median <= cc.target_mm ? "met by every draw" : "MISSED", cc.seed_mm);
      }
    }
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::printf("\n%.1f s\n", seconds);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "hexapod_calibration_accuracy: %s\n", e.what());
    return 1;
  }
  return 0;
}
