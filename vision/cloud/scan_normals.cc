#include "vision/cloud/scan_normals.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <sstream>
#include <stdexcept>

namespace kinevis::vision::cloud {
namespace {

float Distance2(const Eigen::Vector3f& a, const Eigen::Vector3f& b) {
  return (a - b).squaredNorm();
}

// Index in [begin, end) of a point near p, walking downhill in distance from `start`.
std::size_t WalkToNearest(const std::vector<Eigen::Vector3f>& points, std::size_t begin,
                          std::size_t end, std::size_t start, const Eigen::Vector3f& p) {
  std::size_t s = std::clamp(start, begin, end - 1);
  float best = Distance2(points[s], p);
  while (s + 1 < end) {
    const float d = Distance2(points[s + 1], p);
    if (d >= best) break;
    best = d;
    ++s;
  }
  while (s > begin) {
    const float d = Distance2(points[s - 1], p);
    if (d >= best) break;
    best = d;
    --s;
  }
  return s;
}

std::size_t Nearest(const std::vector<Eigen::Vector3f>& points, std::size_t begin, std::size_t end,
                    const Eigen::Vector3f& p) {
  std::size_t s = begin;
  float best = Distance2(points[begin], p);
  for (std::size_t k = begin + 1; k < end; ++k) {
    const float d = Distance2(points[k], p);
    if (d < best) {
      best = d;
      s = k;
    }
  }
  return s;
}

}  // namespace

std::string ScanNormalOptions::Validate() const {
  std::ostringstream bad;
  const auto add = [&bad](const std::string& what) {
    if (bad.tellp() > 0) bad << "; ";
    bad << what;
  };
  if (line_window < 1) add("line_window = " + std::to_string(line_window) + " (expected >= 1)");
  if (point_window < 1) add("point_window = " + std::to_string(point_window) + " (expected >= 1)");
  if (!(radius > 0.0)) add("radius = " + std::to_string(radius) + " m (expected > 0)");
  if (min_neighbours < 3) {
    add("min_neighbours = " + std::to_string(min_neighbours) + " (expected >= 3)");
  }
  if (!(min_spread_ratio >= 1.0)) {
    add("min_spread_ratio = " + std::to_string(min_spread_ratio) + " (expected >= 1)");
  }
  if (!(min_width_ratio >= 0.0 && min_width_ratio < 1.0)) {
    add("min_width_ratio = " + std::to_string(min_width_ratio) + " (expected in [0, 1))");
  }
  return bad.str();
}

ScanNormalStats EstimateScanNormals(const std::vector<Eigen::Vector3f>& points,
                                    const std::vector<std::size_t>& line_offsets,
                                    const std::vector<Eigen::Vector3f>& viewpoints,
                                    const ScanNormalOptions& options,
                                    std::vector<Eigen::Vector3f>* normals) {
  const std::string bad = options.Validate();
  if (!bad.empty()) throw std::invalid_argument("EstimateScanNormals: options: " + bad);
  if (line_offsets.empty() || line_offsets.front() != 0 || line_offsets.back() != points.size()) {
    throw std::invalid_argument(
        "EstimateScanNormals: line_offsets must start at 0 and end at points.size() = " +
        std::to_string(points.size()));
  }
  const std::size_t lines = line_offsets.size() - 1;
  if (viewpoints.size() != lines) {
    throw std::invalid_argument("EstimateScanNormals: " + std::to_string(viewpoints.size()) +
                                " viewpoints for " + std::to_string(lines) + " lines");
  }
  for (std::size_t l = 0; l < lines; ++l) {
    if (line_offsets[l + 1] < line_offsets[l]) {
      throw std::invalid_argument("EstimateScanNormals: line_offsets[" + std::to_string(l + 1) +
                                  "] < line_offsets[" + std::to_string(l) + "]");
    }
  }
  normals->assign(points.size(), Eigen::Vector3f::Zero());
  ScanNormalStats stats;
  const float radius2 = static_cast<float>(options.radius * options.radius);
  const int W = options.line_window;
  const std::size_t w = static_cast<std::size_t>(options.point_window);
  std::vector<std::size_t> track(static_cast<std::size_t>(2 * W + 1));

  for (std::size_t j = 0; j < lines; ++j) {
    const std::size_t begin = line_offsets[j], end = line_offsets[j + 1];
    for (std::size_t i = begin; i < end; ++i) {
      const Eigen::Vector3f& p = points[i];
      Eigen::Vector3d sum = Eigen::Vector3d::Zero();
      Eigen::Matrix3d sum2 = Eigen::Matrix3d::Zero();
      int count = 0;
      const auto add_range = [&](std::size_t first, std::size_t last) {  // [first, last)
        for (std::size_t k = first; k < last; ++k) {
          if (Distance2(points[k], p) > radius2) continue;
          const Eigen::Vector3d d = (points[k] - p).cast<double>();
          sum += d;
          sum2 += d * d.transpose();
          ++count;
        }
      };
      add_range(i >= begin + w ? i - w : begin, std::min(end, i + w + 1));
      for (int dj = -W; dj <= W; ++dj) {
        if (dj == 0) continue;
        const long long jj = static_cast<long long>(j) + dj;
        if (jj < 0 || jj >= static_cast<long long>(lines)) continue;
        const std::size_t b = line_offsets[static_cast<std::size_t>(jj)];
        const std::size_t e = line_offsets[static_cast<std::size_t>(jj) + 1];
        if (b == e) continue;
        std::size_t& s = track[static_cast<std::size_t>(dj + W)];
        s = i == begin ? Nearest(points, b, e, p) : WalkToNearest(points, b, e, s, p);
        add_range(s >= b + w ? s - w : b, std::min(e, s + w + 1));
      }
      if (count < options.min_neighbours) {
        ++stats.missing;
        continue;
      }
      const Eigen::Vector3d mean = sum / count;
      Eigen::Matrix3d covariance = sum2 / count - mean * mean.transpose();
      const double trace = covariance.trace();
      if (!(trace > 0.0)) {
        ++stats.missing;
        continue;
      }
      covariance /= trace;
      Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen;
      eigen.computeDirect(covariance);
      const Eigen::Vector3d& lambda = eigen.eigenvalues();  // ascending
      const double width2 = options.min_width_ratio * options.min_width_ratio;
      if (!(lambda(1) > options.min_spread_ratio * std::max(lambda(0), 0.0)) ||
          !(lambda(1) >= width2 * lambda(2)) || !(lambda(1) > 1e-12)) {
        ++stats.missing;
        continue;
      }
      Eigen::Vector3f n = eigen.eigenvectors().col(0).normalized().cast<float>();
      if (n.dot(viewpoints[j] - p) < 0.0f) n = -n;
      (*normals)[i] = n;
      ++stats.estimated;
    }
  }
  return stats;
}

}  // namespace kinevis::vision::cloud
