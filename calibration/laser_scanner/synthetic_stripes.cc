#include "calibration/laser_scanner/synthetic_stripes.h"

#include <cmath>

namespace kinevis::calibration {

std::vector<Eigen::Vector2d> ExactStripePixels(const vision::render::LaserScene& scene,
                                               const vision::CameraModel& camera,
                                               vision::render::LaserId id, double spacing) {
  std::vector<Eigen::Vector2d> curve;
  for (const Eigen::Vector3d& p : scene.StripeCurve(id, spacing)) {
    Eigen::Vector2d pixel;
    if (camera.Project(p, &pixel) == vision::ProjectionStatus::kOk) curve.push_back(pixel);
  }
  // Along-stripe coordinate: u for the rotating laser, v for the fixed one.
  const int along = id == vision::render::LaserId::kRotating ? 0 : 1;
  const int across = 1 - along;
  std::vector<Eigen::Vector2d> out;
  for (size_t i = 1; i < curve.size(); ++i) {
    const Eigen::Vector2d& a = curve[i - 1];
    const Eigen::Vector2d& b = curve[i];
    if (std::abs(b(across) - a(across)) > 1.0 || a(along) == b(along)) continue;
    const double lo = std::min(a(along), b(along)), hi = std::max(a(along), b(along));
    // Integer coordinates in [lo, hi), so a sample on a segment boundary is taken once.
    for (double k = std::ceil(lo); k < hi; k += 1.0) {
      const double s = (k - a(along)) / (b(along) - a(along));
      Eigen::Vector2d pixel;
      pixel(along) = k;
      pixel(across) = a(across) + s * (b(across) - a(across));
      if (camera.InImage(pixel)) out.push_back(pixel);
    }
  }
  return out;
}

}  // namespace kinevis::calibration
