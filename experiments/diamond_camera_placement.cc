// Issue 8: the DIAMOND camera placement of seed 001 §IV-B (eq. 29–33) and its sensitivity
// analysis (§IV-A, eq. 18–28). Prints the optimal camera distance r* for the weights --q of the
// benefit function J = q S_ROI − S_waste (R = --radius), for
//   - the half view angle that reproduces the seed's 44.62 cm for q = 5 (solved from eq. 33),
//   - the seed's camera as kinevis models it (1280×640, f = --focal-px: vertical, horizontal and
//     diagonal half-angles), for the "half sphere" of eq. (31) (β = π) and the "quarter sphere"
//     of §V-B (β = π/2),
// whether r* lies where the model's waste term is negative (the sphere larger than the view), the
// sensitivity dθ/dδ and elasticity S at r* (eq. 27–28), and writes the seed's Fig. 5 as a PNG
// (--plot, default diamond_benefit.png) for the seed's angle and --q.
//
//   build-NAME/experiments/diamond_camera_placement [--q 1,3,5,8] [--plot out.png]

#include <CLI/CLI.hpp>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "calibration/diamond/camera_placement.h"
#include "vision/camera/pinhole_camera.h"

namespace kc = kinevis::calibration;

int main(int argc, char** argv) {
  double radius = 0.2;
  std::vector<double> weights = {1, 3, 5, 8};
  double focal_px = 1000.0;
  std::string plot = "diamond_benefit.png";
  CLI::App app{"DIAMOND camera placement, seed 001 eq. 29-33 (issue 8)"};
  app.add_option("--radius", radius, "sphere radius R (m)");
  app.add_option("--q", weights, "weights q of S_ROI");
  app.add_option("--focal-px", focal_px, "focal length of the 1280x640 camera (px)");
  app.add_option("--plot", plot, "PNG of the benefit function (empty: none)");
  CLI11_PARSE(app, argc, argv);

  // The half-angle for which eq. (33) puts the q = 5 optimum at 0.4462 m (β = π).
  const double r_seed = 0.4462, A = std::sqrt(r_seed * r_seed - radius * radius);
  const double t2 =
      2 * 5 * std::pow(radius, 3) / (M_PI * A * r_seed * r_seed) - std::pow(radius / A, 4);
  const double seed_theta = t2 > 0 ? std::atan(std::sqrt(t2)) : NAN;

  kinevis::vision::PinholeBrownParameters p;
  p.width = 1280;
  p.height = 640;
  p.fx = p.fy = focal_px;
  p.cx = 639.5;
  p.cy = 319.5;
  const kinevis::vision::PinholeBrownCamera camera(p);
  struct Lens {
    const char* name;
    double theta;
  };
  const Lens lenses[] = {
      {"seed's 44.62 cm (solved)", seed_theta},
      {"1280x640 vertical", kc::HalfViewAngle(camera, kc::ViewAxis::kVertical)},
      {"1280x640 horizontal", kc::HalfViewAngle(camera, kc::ViewAxis::kHorizontal)},
      {"1280x640 diagonal", kc::HalfViewAngle(camera, kc::ViewAxis::kDiagonal)},
  };
  std::printf(
      "R = %.3f m; J = q * 2 alpha R^2 (1 - cos beta) - pi r^2 (tan^2 theta - R^2/(r^2 - "
      "R^2)), alpha = acos(R/r)\n\n",
      radius);
  std::printf("%-26s %8s %6s %5s | %9s %10s %9s | %9s %8s %s\n", "lens", "theta", "beta", "q",
              "r* (cm)", "J* (cm^2)", "R/sin th", "dth/dd r*", "S(0.3)", "note");
  for (const Lens& lens : lenses) {
    for (double beta : {M_PI, M_PI / 2}) {
      for (double q : weights) {
        kc::CameraPlacementOptions o;
        o.radius = radius;
        o.weight = q;
        o.half_view_angle = lens.theta;
        o.roi_polar_extent = beta;
        const kc::CameraPlacement plan = kc::PlanCameraPlacement(o);
        if (!plan.found) {
          std::printf("%-26s %7.2f° %5.0f° %5.1f | %9s %10s %8.2f  | %9s %8s no interior maximum\n",
                      lens.name, lens.theta * 180 / M_PI, beta * 180 / M_PI, q, "-", "-",
                      plan.full_view_distance * 100, "-", "-");
          continue;
        }
        const double rate = kc::SphereViewAngleRate(radius, plan.best_distance, 0.0);
        const double s03 = kc::SphereViewElasticity(radius, plan.best_distance, 0.3);
        std::printf("%-26s %7.2f° %5.0f° %5.1f | %9.2f %10.1f %8.2f  | %9.3f %8.3f %s\n", lens.name,
                    lens.theta * 180 / M_PI, beta * 180 / M_PI, q, plan.best_distance * 100,
                    plan.at_best.benefit * 1e4, plan.full_view_distance * 100, rate, s03,
                    plan.at_best.waste < 0 ? "S_waste < 0 at r*" : "");
      }
    }
  }
  std::printf("\nsensitivity at the seed's r* = 44.62 cm (camera-to-sphere r = %.2f cm):\n",
              (r_seed - radius) * 100);
  std::printf("  delta (rad)  theta (rad)  dtheta/ddelta  S exact  S eq.28 (eps = 0.01)\n");
  for (double delta : {0.0, 0.2, 0.4, 0.6, 0.8, 1.0}) {
    std::printf("  %10.2f  %11.4f  %13.4f  %7.4f  %7.4f\n", delta,
                kc::SphereViewAngle(radius, r_seed, delta),
                kc::SphereViewAngleRate(radius, r_seed, delta),
                kc::SphereViewElasticity(radius, r_seed, delta),
                kc::SeedSensitivityEq28(radius, r_seed, delta, 0.01));
  }
  std::printf("  visible up to delta_max = acos(R/D) = %.4f rad\n",
              kc::MaxVisibleCentralAngle(radius, r_seed));
  if (!plot.empty() && std::isfinite(seed_theta)) {
    kc::CameraPlacementOptions o;
    o.radius = radius;
    o.half_view_angle = seed_theta;
    kc::WriteBenefitPlot(plot, o, weights);
    std::printf("\nwrote %s (theta = %.2f deg, beta = 180 deg)\n", plot.c_str(),
                seed_theta * 180 / M_PI);
  }
  return 0;
}
