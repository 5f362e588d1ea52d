#pragma once

// Synthetic scanned maps for the weld planner tests and bench: the laser scene's blade
// (vision/render/scenes/laser_scene.h: a curved sheet with Gaussian cavitation pits) sampled on
// a jittered grid in its surface frame S, with Gaussian noise and outliers, expressed in the robot
// base frame 0 through X_0S.

#include <Eigen/Geometry>
#include <cmath>
#include <random>
#include <vector>

#include "control/weld/weld_planner.h"
#include "vision/render/scenes/laser_scene.h"

namespace kinevis::control::testing {

struct SyntheticBlade {
  vision::render::LaserSceneParameters scene;
  // The weld cell's default workpiece pose (sim::DefaultWorkpiecePose): x_S up along z_0, z_S
  // facing the robot along −x_0, centre 0.70 m in front of the robot.
  Eigen::Isometry3d X_0S = DefaultPose();
  double spacing = 0.25e-3;        // m between grid samples
  double noise = 0.02e-3;          // σ of the height noise (m)
  double outlier_fraction = 0.01;  // points moved by ±(1..5) mm along z_S
  bool normals = false;
  unsigned seed = 7;

  static Eigen::Isometry3d DefaultPose() {
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    X.linear() = Eigen::AngleAxisd(-M_PI / 2, Eigen::Vector3d::UnitY()).toRotationMatrix();
    X.translation() = Eigen::Vector3d(0.70, 0.045, 0.294);
    return X;
  }
  // The pit-free sheet: ½ k_xx x² + ½ k_yy y² + k_xy x y (m).
  double ReferenceHeight(double x, double y) const {
    return 0.5 * scene.curvature_xx * x * x + 0.5 * scene.curvature_yy * y * y +
           scene.curvature_xy * x * y;
  }
  Eigen::Vector3d ReferenceNormal0(double x, double y) const {
    const double gx = scene.curvature_xx * x + scene.curvature_xy * y;
    const double gy = scene.curvature_yy * y + scene.curvature_xy * x;
    return X_0S.linear() * Eigen::Vector3d(-gx, -gy, 1.0).normalized();
  }
  // True depth below the reference of the surface at (x, y) in S (m): Σ pits.
  double TrueDepth(double x, double y) const { return ReferenceHeight(x, y) - Height(x, y); }
  double Height(double x, double y) const {
    double h = ReferenceHeight(x, y);
    for (const auto& p : scene.pits) {
      const double d2 = (Eigen::Vector2d(x, y) - p.centre_S).squaredNorm();
      h -= p.depth * std::exp(-d2 / (2 * p.sigma * p.sigma));
    }
    return h;
  }

  WeldMap Make() const {
    const vision::render::LaserScene laser(scene);  // validates the scene's parameters
    std::mt19937 rng(seed);
    std::normal_distribution<double> gauss(0.0, noise);
    std::uniform_real_distribution<double> uni(0.0, 1.0);
    WeldMap map;
    const double hx = scene.half_extent.x(), hy = scene.half_extent.y();
    const int nx = static_cast<int>(2 * hx / spacing) + 1,
              ny = static_cast<int>(2 * hy / spacing) + 1;
    map.p_0.reserve(static_cast<size_t>(nx) * ny);
    for (int j = 0; j < ny; ++j) {
      for (int i = 0; i < nx; ++i) {
        const double x = std::min(hx, -hx + (i + 0.5 * (uni(rng) - 0.5)) * spacing);
        const double y = std::min(hy, -hy + (j + 0.5 * (uni(rng) - 0.5)) * spacing);
        double z = laser.Height(x, y) + gauss(rng);
        if (uni(rng) < outlier_fraction) {
          z += (uni(rng) < 0.5 ? -1.0 : 1.0) * (1e-3 + 4e-3 * uni(rng));
        }
        map.p_0.push_back(X_0S * Eigen::Vector3d(x, y, z));
        if (normals) {
          const double e = 1e-6;
          const double gx = (laser.Height(x + e, y) - laser.Height(x - e, y)) / (2 * e);
          const double gy = (laser.Height(x, y + e) - laser.Height(x, y - e)) / (2 * e);
          map.n_0.push_back(X_0S.linear() * Eigen::Vector3d(-gx, -gy, 1.0).normalized());
        }
      }
    }
    return map;
  }
};

// A blade 120 × 100 mm with the cell's curvatures and three pits: 4 mm deep (three layers),
// 1.2 mm and 0.8 mm deep, plus one too small to weld (0.9 mm deep, σ 0.6 mm: 1.3 mm² deeper than
// 0.5 mm).
inline SyntheticBlade DefaultTestBlade() {
  SyntheticBlade b;
  b.scene.surface = vision::render::LaserSurfaceKind::kBlade;
  b.scene.half_extent = Eigen::Vector2d(0.06, 0.05);
  b.scene.curvature_xx = 1.5;
  b.scene.curvature_yy = 0.5;
  b.scene.curvature_xy = 0.3;
  vision::render::CavitationPit a, c, d, tiny;
  a.centre_S = Eigen::Vector2d(0.015, -0.005);
  a.depth = 4.0e-3;
  a.sigma = 4.0e-3;
  c.centre_S = Eigen::Vector2d(-0.025, 0.020);
  c.depth = 1.2e-3;
  c.sigma = 3.0e-3;
  d.centre_S = Eigen::Vector2d(-0.030, -0.025);
  d.depth = 0.8e-3;
  d.sigma = 2.5e-3;
  tiny.centre_S = Eigen::Vector2d(0.035, 0.030);
  tiny.depth = 0.9e-3;
  tiny.sigma = 0.6e-3;
  b.scene.pits = {a, c, d, tiny};
  return b;
}

}  // namespace kinevis::control::testing
