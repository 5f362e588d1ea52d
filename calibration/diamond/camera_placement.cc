#include "calibration/diamond/camera_placement.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <stdexcept>

#include "vision/plot/line_plot.h"

namespace kinevis::calibration {
namespace {

std::string Fmt(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.6g", v);
  return buf;
}

void CheckGeometry(const char* what, double radius, double camera_distance, double delta) {
  if (!(std::isfinite(radius) && radius > 0) ||
      !(std::isfinite(camera_distance) && camera_distance > radius) ||
      !(delta >= 0 && delta <= M_PI)) {
    throw std::invalid_argument(std::string(what) + ": radius = " + Fmt(radius) +
                                " m (need > 0), camera_distance = " + Fmt(camera_distance) +
                                " m (need > radius), delta = " + Fmt(delta) +
                                " rad (need [0, pi])");
  }
}

}  // namespace

double SphereViewAngle(double radius, double camera_distance, double delta) {
  CheckGeometry("SphereViewAngle", radius, camera_distance, delta);
  return std::atan2(radius * std::sin(delta), camera_distance - radius * std::cos(delta));
}

double SphereViewAngleRate(double radius, double camera_distance, double delta) {
  CheckGeometry("SphereViewAngleRate", radius, camera_distance, delta);
  const double D = camera_distance, R = radius, c = std::cos(delta);
  return R * (D * c - R) / (D * D - 2 * D * R * c + R * R);
}

double SphereViewElasticity(double radius, double camera_distance, double delta) {
  CheckGeometry("SphereViewElasticity", radius, camera_distance, delta);
  if (delta < 1e-8) return 1.0;
  return delta / SphereViewAngle(radius, camera_distance, delta) *
         SphereViewAngleRate(radius, camera_distance, delta);
}

double SeedSensitivityEq28(double radius, double camera_distance, double delta, double epsilon) {
  CheckGeometry("SeedSensitivityEq28", radius, camera_distance, delta);
  if (!(epsilon >= 0)) {
    throw std::invalid_argument("SeedSensitivityEq28: epsilon = " + Fmt(epsilon) + " (need >= 0)");
  }
  const double r = camera_distance - radius;
  const double theta = SphereViewAngle(radius, camera_distance, delta);
  // Rδ/(rθ) → 1 as δ → 0 (θ ≈ Rδ/r).
  const double lead = delta < 1e-8 ? 1.0 : radius * delta / (r * theta);
  return lead * (std::cos(theta + delta) - epsilon * std::sin(theta + delta)) *
         (std::cos(theta) - std::tan(delta / 2) * std::sin(theta));
}

double MaxVisibleCentralAngle(double radius, double camera_distance) {
  CheckGeometry("MaxVisibleCentralAngle", radius, camera_distance, 0.0);
  return std::acos(radius / camera_distance);
}

std::string CameraPlacementOptions::Validate() const {
  std::vector<std::string> p;
  if (!(std::isfinite(radius) && radius > 0)) p.push_back("radius = " + Fmt(radius) + " m");
  if (!(std::isfinite(weight) && weight > 0)) p.push_back("weight = " + Fmt(weight));
  if (!(half_view_angle > 0 && half_view_angle < M_PI / 2)) {
    p.push_back("half_view_angle = " + Fmt(half_view_angle) + " rad (need (0, pi/2))");
  }
  if (!(roi_polar_extent > 0 && roi_polar_extent <= M_PI)) {
    p.push_back("roi_polar_extent = " + Fmt(roi_polar_extent) + " rad (need (0, pi])");
  }
  if (!(min_distance_factor > 1 && max_distance_factor > min_distance_factor &&
        std::isfinite(max_distance_factor))) {
    p.push_back("min_distance_factor = " + Fmt(min_distance_factor) +
                ", max_distance_factor = " + Fmt(max_distance_factor) + " (need 1 < min < max)");
  }
  if (curve_points < 10)
    p.push_back("curve_points = " + std::to_string(curve_points) + " (need >= 10)");
  std::string out;
  for (const std::string& s : p) out += (out.empty() ? "" : "; ") + s;
  return out;
}

BenefitTerms EvaluateBenefit(const CameraPlacementOptions& o, double distance) {
  if (const std::string bad = o.Validate(); !bad.empty()) {
    throw std::invalid_argument("camera placement options: " + bad);
  }
  const double R = o.radius, r = distance;
  if (!(std::isfinite(r) && r > R)) {
    throw std::invalid_argument("EvaluateBenefit: distance = " + Fmt(r) +
                                " m (need > radius = " + Fmt(R) + " m)");
  }
  const double A2 = r * r - R * R;
  const double A = std::sqrt(A2);
  const double t2 = std::tan(o.half_view_angle) * std::tan(o.half_view_angle);
  const double cap = 1.0 - std::cos(o.roi_polar_extent);
  BenefitTerms b;
  b.distance = r;
  b.roi = 2.0 * std::acos(R / r) * R * R * cap;                 // eq. (30)
  b.waste = M_PI * r * r * (t2 - R * R / A2);                   // eq. (31)–(32)
  b.benefit = o.weight * b.roi - b.waste;                       // eq. (29)
  b.derivative = o.weight * 2.0 * R * R * cap * R / (r * A)     // d/dr of q S_ROI
                 - 2.0 * M_PI * r * t2                          // of −π r² tan²θ
                 - 2.0 * M_PI * R * R * R * R * r / (A2 * A2);  // of π R² r² / (r² − R²)
  return b;
}

CameraPlacement PlanCameraPlacement(const CameraPlacementOptions& o) {
  if (const std::string bad = o.Validate(); !bad.empty()) {
    throw std::invalid_argument("camera placement options: " + bad);
  }
  CameraPlacement plan;
  plan.full_view_distance = o.radius / std::sin(o.half_view_angle);
  const double r0 = o.min_distance_factor * o.radius;
  const double r1 = o.max_distance_factor * o.radius;
  const int n = o.curve_points;
  plan.curve.reserve(n);
  for (int i = 0; i < n; ++i) {
    const double r = r0 * std::pow(r1 / r0, static_cast<double>(i) / (n - 1));
    plan.curve.push_back(EvaluateBenefit(o, r));
  }
  double best = -std::numeric_limits<double>::infinity();
  for (int i = 0; i + 1 < n; ++i) {
    if (!(plan.curve[i].derivative > 0 && plan.curve[i + 1].derivative <= 0)) continue;
    double lo = plan.curve[i].distance, hi = plan.curve[i + 1].distance;
    for (int it = 0; it < 200 && hi - lo > 1e-13 * hi; ++it) {
      const double mid = 0.5 * (lo + hi);
      (EvaluateBenefit(o, mid).derivative > 0 ? lo : hi) = mid;
    }
    const BenefitTerms at = EvaluateBenefit(o, 0.5 * (lo + hi));
    if (at.benefit > best) {
      best = at.benefit;
      plan.found = true;
      plan.best_distance = at.distance;
      plan.at_best = at;
    }
  }
  if (!plan.found) {
    plan.notes.push_back("J has no interior maximum between " + Fmt(r0) + " and " + Fmt(r1) +
                         " m: with q = " + Fmt(o.weight) +
                         " and theta = " + Fmt(o.half_view_angle) +
                         " rad it only falls with the distance (the weight is too small for "
                         "this lens, or the range too short)");
  } else if (plan.at_best.waste < 0) {
    plan.notes.push_back(
        "the maximum at " + Fmt(plan.best_distance) +
        " m lies where S_waste < 0 (closer than R / sin(theta) = " + Fmt(plan.full_view_distance) +
        " m, the sphere does not fit in the view): the seed's model is "
        "extrapolated there");
  }
  return plan;
}

double HalfViewAngle(const vision::CameraModel& camera, ViewAxis axis) {
  const double w = camera.width(), h = camera.height();
  const Eigen::Vector2d centre((w - 1) / 2, (h - 1) / 2);
  const auto direction = [&camera](const Eigen::Vector2d& px) {
    vision::Ray ray;
    if (camera.BackProject(px, &ray) != vision::ProjectionStatus::kOk) {
      throw std::invalid_argument("HalfViewAngle: pixel (" + Fmt(px.x()) + ", " + Fmt(px.y()) +
                                  ") of camera " + std::string(camera.Name()) +
                                  " does not back-project");
    }
    return ray.d_C;
  };
  const Eigen::Vector3d axis_dir = direction(centre);
  const auto angle = [&](const Eigen::Vector2d& px) {
    return std::acos(std::clamp(direction(px).dot(axis_dir), -1.0, 1.0));
  };
  const double horizontal = std::min(angle({-0.5, centre.y()}), angle({w - 0.5, centre.y()}));
  const double vertical = std::min(angle({centre.x(), -0.5}), angle({centre.x(), h - 0.5}));
  const double diagonal = std::min({angle({-0.5, -0.5}), angle({w - 0.5, -0.5}),
                                    angle({-0.5, h - 0.5}), angle({w - 0.5, h - 0.5})});
  switch (axis) {
    case ViewAxis::kHorizontal:
      return horizontal;
    case ViewAxis::kVertical:
      return vertical;
    case ViewAxis::kDiagonal:
      return diagonal;
    case ViewAxis::kSmallest:
      return std::min({horizontal, vertical, diagonal});
  }
  return vertical;
}

void WriteBenefitPlot(const std::string& path, const CameraPlacementOptions& options,
                      const std::vector<double>& weights, double r_min, double r_max) {
  if (const std::string bad = options.Validate(); !bad.empty()) {
    throw std::invalid_argument("camera placement options: " + bad);
  }
  if (weights.empty()) throw std::invalid_argument("WriteBenefitPlot: no weights");
  if (r_min <= 0) r_min = 1.3 * options.radius;
  if (r_max <= 0) r_max = 4.0 * options.radius;
  if (!(r_min > options.radius && r_max > r_min)) {
    throw std::invalid_argument("WriteBenefitPlot: r_min = " + Fmt(r_min) +
                                " m, r_max = " + Fmt(r_max) + " m (need radius < r_min < r_max)");
  }
  vision::plot::LinePlotOptions po;
  char title[160];
  std::snprintf(title, sizeof title,
                "benefit J(r): R = %.3g m, theta = %.2f deg, beta = %.0f deg (seed 001 eq. 32)",
                options.radius, options.half_view_angle * 180 / M_PI,
                options.roi_polar_extent * 180 / M_PI);
  po.title = title;
  po.x_label = "camera distance from the RCM r (cm)";
  po.y_label = "J (cm^2)";
  po.x_min = r_min * 100;
  po.x_max = r_max * 100;
  vision::plot::LinePlot plot(po);
  double y_lo = std::numeric_limits<double>::infinity();
  std::vector<vision::plot::Series> markers;
  for (double q : weights) {
    CameraPlacementOptions o = options;
    o.weight = q;
    vision::plot::Series s;
    char name[64];
    std::snprintf(name, sizeof name, "q = %g", q);
    s.name = name;
    for (int i = 0; i < 400; ++i) {
      const double r = r_min + (r_max - r_min) * i / 399.0;
      const double J = EvaluateBenefit(o, r).benefit * 1e4;  // cm²
      s.x.push_back(r * 100);
      s.y.push_back(J);
      y_lo = std::min(y_lo, J);
    }
    plot.AddSeries(s);
    const CameraPlacement plan = PlanCameraPlacement(o);
    if (plan.found && plan.best_distance >= r_min && plan.best_distance <= r_max) {
      vision::plot::Series m;
      std::snprintf(name, sizeof name, "q = %g: max at %.2f cm", q, plan.best_distance * 100);
      m.name = name;
      m.x = {plan.best_distance * 100, plan.best_distance * 100};
      m.y = {plan.at_best.benefit * 1e4, plan.at_best.benefit * 1e4};
      m.thickness_px = 1;
      markers.push_back(m);
    }
  }
  for (vision::plot::Series& m : markers) {
    m.y[0] = y_lo;  // a vertical line from the bottom to the maximum
    plot.AddSeries(m);
  }
  plot.WritePng(path);
}

}  // namespace kinevis::calibration
