// Issue 6, experiment 1 in small (experiments/hexapod_calibration_accuracy.cc is the full one):
// the base attachment points A_j calibrated end to end — true perturbed robot, planned poses,
// rendered images, leg edges searched around the nominal prediction, CalibrateHexapod() — for the
// perspective 1024×780 camera (the harder of the seed's two: occlusions, legs ~1.2 m away, where a
// 0.1 px bias of the edge locator makes a ~0.5 % depth error), 20 poses, three draws of truth,
// camera mount and image noise, all seeded. With the same settings the experiment prints the same
// figures: hexapod_calibration_accuracy --cameras perspective --poses 20 --candidates 400
// --draws 3.
//
// Margins (measured: clean median 0.08–0.24 mm, max 1.1–1.7 mm, mean depth error −0.25 to
// −0.36 mm; perturbed median 0.9–2.2 mm): they hold with room, and the clean ones fail for the
// regression they guard — with the parabola edge locator, which the shading pulls 0.03–0.1 px into
// the legs, the same runs give clean medians 1.14–1.18 mm, maxima 3.4–4.8 mm and depth errors
// +1.25 to +1.54 mm (the legs look thinner, so farther).

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <memory>
#include <optional>
#include <random>
#include <vector>

#include "calibration/hexapod/leg_calibration.h"
#include "calibration/hexapod/pose_planner.h"
#include "common/units.h"
#include "robots/hexapod/hexapod_model.h"
#include "sim/hexapod_world.h"
#include "vision/camera/pinhole_camera.h"
#include "vision/hexapod/leg_edges.h"
#include "vision/render/renderer.h"
#include "vision/render/scenes/hexapod_scene.h"

namespace kinevis::calibration {
namespace {

namespace edges = vision::hexapod;
using robots::kHexapodLegs;

constexpr unsigned kSeed = 1;
constexpr int kCameraId = 1;  // the experiment's id of the perspective camera (mixed into seeds)

vision::PinholeBrownCamera Perspective() {
  vision::PinholeBrownParameters p;
  p.width = 1024;
  p.height = 780;
  p.fx = p.fy = 1300.0;
  p.cx = 511.5;
  p.cy = 389.5;
  return vision::PinholeBrownCamera(p);
}

// 1.15 m from (0, 0, 0.2) m towards sim::DefaultHexapodCameras()' perspective eye: 30° round
// from the front, 25° up (the robot fills the image).
Eigen::Isometry3d DrawnX_CB() {
  const Eigen::Vector3d target(0.0, 0.0, 0.2);
  const Eigen::Vector3d direction = (Eigen::Vector3d(0.85, -1.47, 1.0) - target).normalized();
  return vision::render::CameraLookingAt(target + 1.15 * direction, target,
                                         Eigen::Vector3d::UnitZ())
      .inverse();
}

std::mt19937_64 Generator(int draw, int variant, int pass, int pose) {
  std::seed_seq s{kSeed,
                  static_cast<unsigned>(draw),
                  static_cast<unsigned>(kCameraId),
                  static_cast<unsigned>(variant),
                  static_cast<unsigned>(pass),
                  static_cast<unsigned>(pose)};
  return std::mt19937_64(s);
}

Eigen::Vector3d RandomUnit(std::mt19937_64* rng) {
  std::normal_distribution<double> normal(0.0, 1.0);
  return Eigen::Vector3d(normal(*rng), normal(*rng), normal(*rng)).normalized();
}

// The extra perturbation: N(0, 0.5²) px per image axis on every edge point, 10 % of them moved
// 5–40 px across the true limb curve, either side (the fit is not told which).
void PerturbLimbPoints(const vision::CameraModel& camera, const Eigen::Vector3d& n_true,
                       std::mt19937_64* rng, std::vector<edges::EdgePoint>* points) {
  std::normal_distribution<double> noise(0.0, 0.5);
  std::uniform_real_distribution<double> offset(5.0, 40.0);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  const int n = static_cast<int>(points->size());
  std::vector<int> order(n);
  for (int i = 0; i < n; ++i) order[i] = i;
  std::shuffle(order.begin(), order.end(), *rng);
  std::vector<char> is_outlier(n, 0);
  for (int i = 0; i < static_cast<int>(std::lround(0.1 * n)); ++i) is_outlier[order[i]] = 1;
  for (int i = 0; i < n; ++i) {
    edges::EdgePoint& p = (*points)[i];
    const Eigen::Vector2d across = (p.d_ray_d_pixel.transpose() * n_true).normalized();
    for (int attempt = 0; attempt < 8; ++attempt) {
      Eigen::Vector2d pixel = p.pixel + Eigen::Vector2d(noise(*rng), noise(*rng));
      if (is_outlier[i]) pixel += (unit(*rng) < 0.5 ? -1.0 : 1.0) * offset(*rng) * across;
      edges::EdgePoint moved = p;
      if (camera.InImage(pixel) && edges::MakeEdgePoint(camera, pixel, &moved)) {
        p = moved;
        break;
      }
    }
  }
}

struct Figures {
  bool all_legs = false;
  double median_mm = 0.0, max_mm = 0.0, depth_mm = 0.0;
};

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

// One draw of the experiment: clean (perturb = false) or with the extra edge perturbation.
Figures RunDraw(int draw, bool perturb) {
  const vision::PinholeBrownCamera camera = Perspective();
  const robots::HexapodModel nominal = robots::HexapodModel::Default();
  const Eigen::Isometry3d X_CB_drawn = DrawnX_CB();
  PosePlannerOptions plan_options;
  plan_options.poses = 20;
  plan_options.candidates = 400;
  plan_options.seed = 1;
  plan_options.X_CB = X_CB_drawn;
  plan_options.admissible = [&](const Eigen::Isometry3d& X_BP) {
    return AllLegsInView(nominal, camera, X_CB_drawn, X_BP);
  };
  const PosePlan plan = PlanCalibrationPoses(nominal, plan_options);
  EXPECT_EQ(plan.X_BP.size(), 20u);

  sim::HexapodWorldConfig config;  // perturbations 0.5 / 0.5 / 1 mm
  config.seed = kSeed + static_cast<unsigned>(draw);
  const robots::HexapodModel truth = sim::TrueHexapodModel(config);
  std::mt19937_64 mount = Generator(draw, 0, 0, -1);
  Eigen::Isometry3d X_BC_true = X_CB_drawn.inverse();
  X_BC_true.translation() += 0.010 * RandomUnit(&mount);
  X_BC_true.linear() =
      Eigen::AngleAxisd(common::kPi / 180.0, RandomUnit(&mount)).toRotationMatrix() *
      X_BC_true.linear();
  const Eigen::Isometry3d X_CB_true = X_BC_true.inverse();

  // The drives at the nominal IK of each planned pose; the true platform where the true robot's
  // FK of those leg lengths puts it; its image.
  vision::render::RenderOptions ro;
  ro.supersampling = 4;
  ro.noise_sigma = 1.0;
  ro.seed = 1000u * kSeed + static_cast<unsigned>(draw);
  vision::render::Renderer renderer(camera, ro);
  std::vector<std::vector<uint8_t>> images;
  std::vector<Eigen::Isometry3d> planned, X_BP_true;
  robots::HexapodData ik, fk;
  for (size_t k = 0; k < plan.X_BP.size(); ++k) {
    robots::InverseKinematics(nominal, plan.X_BP[k], &ik);
    const robots::Vector6d q_true = robots::LegLengthsFromJointPositions(
        truth, robots::JointPositionsFromLegLengths(nominal, ik.q));
    const robots::ForwardKinematicsSummary f = robots::ForwardKinematics(
        truth, q_true, plan.X_BP[k], robots::ForwardKinematicsOptions{}, &fk);
    if (!f.converged()) continue;
    std::vector<uint8_t> pixels(static_cast<size_t>(camera.width()) * camera.height(), 0);
    renderer.Render(vision::render::HexapodScene(truth, f.X_BP, X_CB_true), k,
                    vision::ImageView8{pixels.data(), camera.width(), camera.height(),
                                       static_cast<size_t>(camera.width())});
    images.push_back(std::move(pixels));
    planned.push_back(plan.X_BP[k]);
    X_BP_true.push_back(f.X_BP);
  }

  // Two passes as calibration/hexapod/dataset_calibration.cc: the second searches around the
  // first's rigid fit and estimated A_j.
  const edges::LegEdgeOptions edge_options;
  auto workspace = std::make_unique<edges::LegEdgeWorkspace>();
  Eigen::Isometry3d X_CB = X_CB_drawn;
  std::optional<std::array<Eigen::Vector3d, kHexapodLegs>> p_C_A;
  HexapodCalibrationResult result;
  for (int pass = 0; pass < 2; ++pass) {
    HexapodCalibrationData data;
    data.leg_radius = nominal.leg_radius;
    data.configurations.resize(images.size());
    for (size_t k = 0; k < images.size(); ++k) {
      auto predictions = edges::PredictLegs(nominal, planned[k], X_CB);
      if (p_C_A) {
        for (int j = 0; j < kHexapodLegs; ++j) predictions[j].p_C_A = (*p_C_A)[j];
      }
      const vision::ImageView8 view{images[k].data(), camera.width(), camera.height(),
                                    static_cast<size_t>(camera.width())};
      edges::ObserveLegs(view, camera, predictions, edge_options, workspace.get());
      if (perturb) {
        std::mt19937_64 rng = Generator(draw, 1, pass, static_cast<int>(k));
        const auto true_legs = edges::PredictLegs(truth, X_BP_true[k], X_CB_true);
        for (int j = 0; j < kHexapodLegs; ++j) {
          if (!workspace->observations[j].visible) continue;
          Eigen::Vector3d n_true[2];
          vision::render::PredictCylinderLimbs(true_legs[j].p_C_A, true_legs[j].p_C_B,
                                               truth.leg_radius, &n_true[0], &n_true[1]);
          for (int limb = 0; limb < 2; ++limb) {
            PerturbLimbPoints(camera, n_true[limb], &rng, &workspace->points[j][limb]);
          }
        }
        edges::RefitObservedLegs(predictions, edge_options, workspace.get());
      }
      for (int j = 0; j < kHexapodLegs; ++j) {
        const edges::LegObservation& o = workspace->observations[j];
        if (o.visible) data.configurations[k][j] = LegLimbs{o.limbs[0].n_C, o.limbs[1].n_C};
      }
    }
    result = CalibrateHexapod(data, nominal);
    if (!result.ok() || !result.rigid_fit) break;
    X_CB = result.X_CB;
    p_C_A = result.p_C_A;
  }

  Figures figures;
  figures.all_legs = result.ok();
  if (!figures.all_legs) return figures;
  std::vector<double> errors;
  for (int j = 0; j < kHexapodLegs; ++j) {
    const Eigen::Vector3d a_true = X_CB_true * truth.p_B_A[j];
    const Eigen::Vector3d e = result.p_C_A[j] - a_true;
    errors.push_back(1e3 * e.norm());
    figures.depth_mm += 1e3 * e.dot(a_true.normalized()) / kHexapodLegs;
  }
  figures.median_mm = Median(errors);
  figures.max_mm = *std::max_element(errors.begin(), errors.end());
  std::printf("[draw %d %s] |A - A_true| median %.2f mm, max %.2f mm, mean depth error %+.2f mm\n",
              draw, perturb ? "perturbed" : "clean", figures.median_mm, figures.max_mm,
              figures.depth_mm);
  return figures;
}

TEST(HexapodCalibrationAccuracyTest, RenderedEdgesGiveMillimetreAccuracyAndNoDepthBias) {
  for (int draw = 0; draw < 3; ++draw) {
    const Figures f = RunDraw(draw, false);
    ASSERT_TRUE(f.all_legs) << "draw " << draw;
    EXPECT_LT(f.median_mm, 0.6) << "draw " << draw;
    EXPECT_LT(f.max_mm, 2.5) << "draw " << draw;
    // A bias of the edge locator on the apparent leg width is a depth error (eq. 14 is linear in
    // R): +1.3 to +1.5 mm with the parabola locator.
    EXPECT_LT(std::abs(f.depth_mm), 0.9) << "draw " << draw;
  }
}

TEST(HexapodCalibrationAccuracyTest, ExtraEdgeNoiseAndOutliersStillMeetTheIssueTarget) {
  for (int draw = 0; draw < 3; ++draw) {
    const Figures f = RunDraw(draw, true);
    ASSERT_TRUE(f.all_legs) << "draw " << draw;
    EXPECT_LT(f.median_mm, 4.0) << "draw " << draw;  // issue 6: <= 4 mm (seed: 8 mm)
  }
}

}  // namespace
}  // namespace kinevis::calibration
