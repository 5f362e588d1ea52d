#include "vision/laser/scan_lines.h"

#include <cmath>
#include <sstream>
#include <stdexcept>

namespace kinevis::vision::laser {

const char* ToString(ScanLineStatus status) {
  switch (status) {
    case ScanLineStatus::kOk:
      return "ok";
    case ScanLineStatus::kNoCrossing:
      return "no crossing";
    case ScanLineStatus::kAngleFailed:
      return "angle failed";
    case ScanLineStatus::kTooFewPoints:
      return "too few points";
    case ScanLineStatus::kAngleInconsistent:
      return "angle inconsistent";
  }
  return "?";
}

std::string ScanLineOptions::Validate() const {
  std::ostringstream out;
  auto add = [&out](const std::string& text) { out << (out.tellp() > 0 ? "; " : "") << text; };
  const std::string s = stripes.Validate();
  if (!s.empty()) add("stripes: " + s);
  if (!(min_confidence >= 0.0 && min_confidence < 1.0)) {
    add("min_confidence = " + std::to_string(min_confidence) + " (0..1)");
  }
  if (min_points < 1) add("min_points = " + std::to_string(min_points) + " (>= 1)");
  if (!(max_angle_deviation > 0.0)) {
    add("max_angle_deviation = " + std::to_string(max_angle_deviation) + " (> 0)");
  }
  return out.str();
}

namespace {

LaserStripeOptions BothStripes(const ScanLineOptions& options) {
  const std::string problems = options.Validate();
  if (!problems.empty()) throw std::invalid_argument("scan line options: " + problems);
  LaserStripeOptions o = options.stripes;
  o.search_fixed = true;
  o.search_rotating = true;
  return o;
}

}  // namespace

ScanLineTriangulator::ScanLineTriangulator(const ScannerModel& model,
                                           const ScanLineOptions& options)
    : model_(model), options_(options), extractor_(BothStripes(options)) {
  options_.stripes = BothStripes(options);
}

void ScanLineTriangulator::Process(const vision::ImageView8& image, ScanLineResult* result,
                                   double expected_cot_theta_y) {
  const CameraModel& camera = model_.camera();
  if (image.width != camera.width() || image.height != camera.height()) {
    std::ostringstream m;
    m << "scan line: image is " << image.width << " x " << image.height << " px, the camera "
      << camera.Name() << " is " << camera.width() << " x " << camera.height();
    throw std::invalid_argument(m.str());
  }
  ScanLineResult& r = *result;
  r.status = ScanLineStatus::kNoCrossing;
  r.p_C.clear();
  r.confidence.clear();
  r.fixed_p_C.clear();
  r.cot_theta_y = 0.0;
  r.cot_theta_y_sigma = 0.0;
  r.dropped_low_confidence = 0;
  r.dropped_triangulation = 0;

  extractor_.Extract(image, &stripes_);
  const StripeResult& rotating = stripes_.stripe(Stripe::kRotating);
  r.stripe_points = static_cast<int>(rotating.points.size());
  r.crossing = stripes_.crossing.status;
  r.crossing_pixel = stripes_.crossing.pixel;
  if (!stripes_.crossing.found()) return;

  Eigen::RowVector2d J_pixel;
  if (model_.CotThetaYFromIntersection(stripes_.crossing.pixel, &r.cot_theta_y, &J_pixel) !=
          TriangulationStatus::kOk ||
      !std::isfinite(r.cot_theta_y)) {
    r.status = ScanLineStatus::kAngleFailed;
    return;
  }
  r.cot_theta_y_sigma =
      std::sqrt(std::max(0.0, (J_pixel * stripes_.crossing.covariance * J_pixel.transpose())(0)));

  for (const StripePoint& p : rotating.points) {
    if (p.confidence < options_.min_confidence) {
      ++r.dropped_low_confidence;
      continue;
    }
    Eigen::Vector3d p_C;
    if (model_.TriangulateRotating(p.pixel, r.cot_theta_y, &p_C) != TriangulationStatus::kOk ||
        !p_C.allFinite()) {
      ++r.dropped_triangulation;
      continue;
    }
    r.p_C.push_back(p_C);
    r.confidence.push_back(static_cast<float>(p.confidence));
  }
  if (options_.fixed_points) {
    for (const StripePoint& p : stripes_.stripe(Stripe::kFixed).points) {
      if (p.confidence < options_.min_confidence) continue;
      Eigen::Vector3d p_C;
      if (model_.TriangulateFixed(p.pixel, &p_C) == TriangulationStatus::kOk && p_C.allFinite()) {
        r.fixed_p_C.push_back(p_C);
      }
    }
  }
  if (static_cast<int>(r.p_C.size()) < options_.min_points) {
    r.status = ScanLineStatus::kTooFewPoints;
  } else if (std::isfinite(expected_cot_theta_y) &&
             std::abs(r.cot_theta_y - expected_cot_theta_y) > options_.max_angle_deviation) {
    r.status = ScanLineStatus::kAngleInconsistent;
  } else {
    r.status = ScanLineStatus::kOk;
  }
}

std::vector<double> PlanSweep(const ScannerModel& model, double depth, int lines,
                              double row_margin) {
  const ScannerGeometry& g = model.geometry();
  if (lines < 2) throw std::invalid_argument("sweep: lines = " + std::to_string(lines) + " (>= 2)");
  if (!(std::isfinite(depth) && depth > std::abs(g.rotating_d_y))) {
    throw std::invalid_argument(
        "sweep: depth = " + std::to_string(depth) +
        " m (must exceed |d_y| = " + std::to_string(std::abs(g.rotating_d_y)) + " m)");
  }
  if (!(row_margin >= 0.0 && row_margin <= 0.45)) {
    throw std::invalid_argument("sweep: row margin = " + std::to_string(row_margin) + " (0..0.45)");
  }
  const CameraModel& camera = model.camera();
  const double u = 0.5 * (camera.width() - 1);
  const double v0 = row_margin * (camera.height() - 1);
  const double v1 = (1.0 - row_margin) * (camera.height() - 1);
  std::vector<double> cot;
  cot.reserve(static_cast<size_t>(lines));
  for (int k = 0; k < lines; ++k) {
    const double v = v0 + (v1 - v0) * k / (lines - 1);
    Eigen::Vector2d ab;
    if (model.Normalized(Eigen::Vector2d(u, v), &ab) != TriangulationStatus::kOk) {
      throw std::invalid_argument("sweep: the camera cannot back-project row " + std::to_string(v));
    }
    // The rotating plane y + c z = b_y + d_y c through the point (a, b, 1) · depth:
    // c = (b_y − b depth) / (depth − d_y).
    cot.push_back((g.rotating_b_y - ab.y() * depth) / (depth - g.rotating_d_y));
  }
  return cot;
}

}  // namespace kinevis::vision::laser
