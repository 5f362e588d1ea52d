#include "calibration/laser_scanner/scanner_accuracy.h"

#include <Eigen/Dense>
#include <cmath>
#include <random>
#include <stdexcept>

#include "calibration/laser_scanner/laser_scanner_calibration.h"
#include "calibration/laser_scanner/synthetic_stripes.h"
#include "vision/render/renderer.h"
#include "vision/render/scenes/laser_scene.h"

namespace kinevis::calibration {
namespace {

// Total-least-squares line through points: (point, unit direction).
std::pair<Eigen::Vector2d, Eigen::Vector2d> FitLine(const std::vector<Eigen::Vector2d>& p) {
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const auto& x : p) mean += x;
  mean /= static_cast<double>(p.size());
  Eigen::Matrix2d scatter = Eigen::Matrix2d::Zero();
  for (const auto& x : p) scatter += (x - mean) * (x - mean).transpose();
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eig(scatter);
  return {mean, eig.eigenvectors().col(1)};
}

}  // namespace

ScannerAccuracy EvaluateScannerAccuracy(const vision::CameraModel& camera,
                                        const vision::laser::ScannerGeometry& truth,
                                        const vision::laser::ScannerGeometry& used, double depth,
                                        AngleSource source, const ScannerAccuracyOptions& options) {
  if (!(options.noise_px >= 0.0) || options.scans < 1 || !(options.intersection_window_px > 10.0) ||
      !(depth > 0.0)) {
    throw std::invalid_argument(
        "EvaluateScannerAccuracy: noise_px >= 0, scans >= 1, "
        "intersection_window_px > 10 and depth > 0 needed");
  }
  const vision::laser::ScannerModel model(camera, used);
  vision::render::LaserSceneParameters p;
  p.surface = vision::render::LaserSurfaceKind::kBoard;
  p.half_extent = Eigen::Vector2d(0.2, 0.2);
  // A board tilted 10° about x and 8° about y: the stripe spans some depth.
  p.X_CS = Eigen::Translation3d(0.0, 0.0, depth) *
           Eigen::AngleAxisd(0.17, Eigen::Vector3d::UnitX()) *
           Eigen::AngleAxisd(0.14, Eigen::Vector3d::UnitY()) *
           Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX());
  p.scanner = vision::laser::ToSceneGeometry(truth);
  // The rotating stripe a little below the image centre (b = 0.03).
  const double cot = (truth.rotating_b_y - 0.03 * depth) / (depth - truth.rotating_d_y);
  p.rotating_cot_theta_y = cot;
  const vision::render::LaserScene scene(p);
  const std::vector<Eigen::Vector2d> rotating =
      ExactStripePixels(scene, camera, vision::render::LaserId::kRotating);
  const std::vector<Eigen::Vector2d> fixed =
      ExactStripePixels(scene, camera, vision::render::LaserId::kFixed);
  std::mt19937_64 rng(options.seed);
  std::normal_distribution<double> noise(0.0, options.noise_px);
  ScannerAccuracy out;
  out.depth = depth;
  double ssr = 0.0, bias = 0.0, cot_ssr = 0.0;
  for (int scan = 0; scan < options.scans; ++scan) {
    std::vector<Eigen::Vector2d> noisy_rotating = rotating, noisy_fixed = fixed;
    for (auto& px : noisy_rotating) px.y() += noise(rng);
    for (auto& px : noisy_fixed) px.x() += noise(rng);
    double cot_used = cot;
    if (source == AngleSource::kIntersection) {
      // Lines through each stripe near their crossing (found from the noise-free lines).
      const auto r0 = FitLine(rotating), f0 = FitLine(fixed);
      Eigen::Matrix2d A;
      A << r0.second, -f0.second;
      const Eigen::Vector2d guess =
          r0.first + A.colPivHouseholderQr().solve(f0.first - r0.first)(0) * r0.second;
      // The stripes are straight in undistorted (normalised) coordinates, not in pixels (the
      // lens's radial distortion bends them): lines are fitted there.
      std::vector<Eigen::Vector2d> near_r, near_f;
      auto collect = [&](const std::vector<Eigen::Vector2d>& list,
                         std::vector<Eigen::Vector2d>* near) {
        for (const auto& px : list) {
          Eigen::Vector2d ab;
          if ((px - guess).norm() < options.intersection_window_px &&
              model.Normalized(px, &ab) == vision::laser::TriangulationStatus::kOk) {
            near->push_back(ab);
          }
        }
      };
      collect(noisy_rotating, &near_r);
      collect(noisy_fixed, &near_f);
      if (near_r.size() < 3 || near_f.size() < 3) continue;
      const auto lr = FitLine(near_r), lf = FitLine(near_f);
      A << lr.second, -lf.second;
      const Eigen::Vector2d ab =
          lr.first + A.colPivHouseholderQr().solve(lf.first - lr.first)(0) * lr.second;
      Eigen::Vector2d crossing;
      if (camera.Project(Eigen::Vector3d(ab.x(), ab.y(), 1.0), &crossing) !=
          vision::ProjectionStatus::kOk) {
        continue;
      }
      if (model.CotThetaYFromIntersection(crossing, &cot_used) !=
          vision::laser::TriangulationStatus::kOk) {
        continue;
      }
      cot_ssr += (cot_used - cot) * (cot_used - cot);
    }
    for (size_t i = 0; i < rotating.size(); ++i) {
      Eigen::Vector3d truth_point, estimate;
      if (!IntersectBoard(camera, p.X_CS, rotating[i], &truth_point)) continue;
      if (model.TriangulateRotating(noisy_rotating[i], cot_used, &estimate) !=
          vision::laser::TriangulationStatus::kOk) {
        continue;
      }
      const double e = (estimate - truth_point).norm();
      ssr += e * e;
      bias += estimate.z() - truth_point.z();
      out.max = std::max(out.max, e);
      ++out.points;
    }
  }
  if (out.points > 0) {
    out.rms = std::sqrt(ssr / out.points);
    out.mean_depth_error = bias / out.points;
  }
  out.cot_error_rms = std::sqrt(cot_ssr / options.scans);
  return out;
}

std::vector<Eigen::Isometry3d> DefaultCalibrationPoses() {
  auto pose = [](double depth, double tilt_x, double tilt_y) {
    return Eigen::Isometry3d(Eigen::Translation3d(0.003, -0.004, depth) *
                             Eigen::AngleAxisd(tilt_x, Eigen::Vector3d::UnitX()) *
                             Eigen::AngleAxisd(tilt_y, Eigen::Vector3d::UnitY()) *
                             Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()));
  };
  return {pose(0.46, 0.3, 0.25), pose(0.5, -0.3, -0.25), pose(0.55, 0.25, -0.3),
          pose(0.6, -0.25, 0.3), pose(0.65, 0.0, 0.35)};
}

SimulatedCalibration SimulateScannerCalibration(const vision::CameraModel& camera,
                                                const vision::laser::ScannerGeometry& truth,
                                                const SimulatedCalibrationOptions& options) {
  const std::vector<Eigen::Isometry3d> poses =
      options.poses.empty() ? DefaultCalibrationPoses() : options.poses;
  vision::render::RenderOptions render;
  render.noise_sigma = 1.5;
  render.blur_sigma_px = 0.7;
  render.seed = options.seed;
  vision::render::Renderer renderer(camera, render);
  std::vector<uint8_t> pixels(static_cast<size_t>(camera.width()) * camera.height());
  const vision::ImageView8 view{pixels.data(), camera.width(), camera.height(),
                                static_cast<size_t>(camera.width())};
  std::mt19937_64 rng(options.seed);
  std::normal_distribution<double> noise(0.0, options.noise_px);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  SimulatedCalibration out;
  std::vector<LaserCalibrationImage> images;
  for (size_t i = 0; i < poses.size(); ++i) {
    vision::render::LaserSceneParameters p;
    p.surface = vision::render::LaserSurfaceKind::kBoard;
    p.half_extent = Eigen::Vector2d(0.15, 0.15);
    p.dot_grid = true;
    p.ambient = 0.5;
    p.X_CS = poses[i];
    p.scanner = vision::laser::ToSceneGeometry(truth);
    p.fixed_on = p.rotating_on = false;
    renderer.Render(vision::render::LaserScene(p), i, view);
    const BoardPose board = EstimateBoardPose(view, camera, p.dots);
    out.board_poses.push_back(board);
    if (!board.ok()) continue;
    out.board_translation_error_max =
        std::max(out.board_translation_error_max,
                 (board.X_CS.translation() - poses[i].translation()).norm());
    out.board_rotation_error_max =
        std::max(out.board_rotation_error_max,
                 Eigen::AngleAxisd(board.X_CS.linear().transpose() * poses[i].linear()).angle());
    for (int step : options.steps) {
      p.fixed_on = p.rotating_on = true;
      p.rotating_cot_theta_y = 1.0 / std::tan(options.theta0 + options.theta_per_step * step);
      const vision::render::LaserScene scene(p);
      LaserCalibrationImage image;
      image.name = "pose" + std::to_string(i) + "_step" + std::to_string(step);
      image.X_CS = board.X_CS;
      image.rotating_step = step;
      image.rotating_pixels = ExactStripePixels(scene, camera, vision::render::LaserId::kRotating);
      image.fixed_pixels = ExactStripePixels(scene, camera, vision::render::LaserId::kFixed);
      for (auto* list : {&image.rotating_pixels, &image.fixed_pixels}) {
        const int across = list == &image.rotating_pixels ? 1 : 0;
        for (Eigen::Vector2d& px : *list) {
          px(across) += noise(rng);
          if (uniform(rng) < options.outlier_fraction) {
            px(across) += (uniform(rng) < 0.5 ? -1.0 : 1.0) * (3.0 + 5.0 * uniform(rng));
          }
        }
      }
      images.push_back(std::move(image));
    }
  }
  if (images.empty()) {
    out.calibration.errors.push_back("no board pose found in the simulated images");
    return out;
  }
  out.calibration = CalibrateLaserScanner(images, camera);
  return out;
}

}  // namespace kinevis::calibration
