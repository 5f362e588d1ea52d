#include "vision/cloud/point_cloud.h"

#include <cmath>
#include <sstream>

namespace kinevis::vision::cloud {

std::size_t PointCloud::CountMissingNormals() const {
  std::size_t missing = 0;
  for (const Eigen::Vector3f& n : normals) missing += n.isZero(0.0f) ? 1 : 0;
  return missing;
}

std::string PointCloud::Validate() const {
  std::ostringstream bad;
  const auto sep = [&bad]() -> std::ostringstream& {
    if (bad.tellp() > 0) bad << "; ";
    return bad;
  };
  if (!normals.empty() && normals.size() != points.size()) {
    sep() << "normals has " << normals.size() << " entries for " << points.size() << " points";
  }
  if (!confidence.empty() && confidence.size() != points.size()) {
    sep() << "confidence has " << confidence.size() << " entries for " << points.size()
          << " points";
  }
  for (std::size_t i = 0; i < points.size(); ++i) {
    if (!points[i].allFinite()) {
      sep() << "points[" << i << "] is not finite";
      break;
    }
  }
  for (std::size_t i = 0; i < normals.size(); ++i) {
    const Eigen::Vector3f& n = normals[i];
    if (!n.allFinite() || (!n.isZero(0.0f) && std::abs(n.norm() - 1.0f) > 1e-3f)) {
      sep() << "normals[" << i << "] has length " << n.norm() << "; expected 1 or 0";
      break;
    }
  }
  for (std::size_t i = 0; i < confidence.size(); ++i) {
    if (!(confidence[i] >= 0.0f && confidence[i] <= 1.0f)) {
      sep() << "confidence[" << i << "] = " << confidence[i] << "; expected within [0, 1]";
      break;
    }
  }
  return bad.str();
}

}  // namespace kinevis::vision::cloud
