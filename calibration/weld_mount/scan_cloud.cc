#include "calibration/weld_mount/scan_cloud.h"

#include <stdexcept>

namespace kinevis::calibration {

std::string ScanCloudOptions::Validate() const { return normals.Validate(); }

ScanCloud ScansToCloud(const robots::Weld5Model& robot, const Eigen::Isometry3d& X_5C,
                       const std::vector<ScanLine>& lines, const ScanCloudOptions& options) {
  const std::string bad = options.Validate();
  if (!bad.empty()) throw std::invalid_argument("ScansToCloud: options: normals: " + bad);
  const Eigen::Matrix3d R = X_5C.linear();
  if (!X_5C.matrix().allFinite() ||
      (R.transpose() * R - Eigen::Matrix3d::Identity()).norm() > 1e-6 || R.determinant() <= 0.0) {
    throw std::invalid_argument("ScansToCloud: the mount X_5C is not a rigid transform");
  }
  std::size_t total = 0;
  std::size_t with_confidence = 0;
  for (std::size_t l = 0; l < lines.size(); ++l) {
    const ScanLine& line = lines[l];
    const std::string where = "ScansToCloud: line " + std::to_string(l) + ": ";
    if (!line.q.allFinite()) throw std::invalid_argument(where + "joint readings not finite");
    if (!line.confidence.empty()) {
      ++with_confidence;
      if (line.confidence.size() != line.p_C.size()) {
        throw std::invalid_argument(where + std::to_string(line.confidence.size()) +
                                    " confidences for " + std::to_string(line.p_C.size()) +
                                    " points");
      }
    }
    total += line.p_C.size();
  }
  // A line with no points says nothing about confidence.
  std::size_t nonempty = 0;
  for (const ScanLine& line : lines) nonempty += line.p_C.empty() ? 0 : 1;
  const bool confidence = with_confidence > 0;
  if (confidence && with_confidence < nonempty) {
    throw std::invalid_argument("ScansToCloud: " + std::to_string(with_confidence) + " of " +
                                std::to_string(nonempty) +
                                " lines have confidences; expected all or none");
  }

  ScanCloud out;
  out.cloud.points.resize(total);
  if (confidence) out.cloud.confidence.resize(total);
  out.line_offsets.reserve(lines.size() + 1);
  out.line_offsets.push_back(0);
  out.viewpoints_0.reserve(lines.size());
  std::size_t k = 0;
  for (std::size_t l = 0; l < lines.size(); ++l) {
    const ScanLine& line = lines[l];
    // Seed eq. (51): X_0C = X_05(q) · X_5C; then p_0 = X_0C · p_C (eq. 55's point).
    const Eigen::Isometry3d X_0C = robots::DhForwardKinematics(robot.joints, line.q) * X_5C;
    const Eigen::Matrix3d R_0C = X_0C.linear();
    const Eigen::Vector3d t_0C = X_0C.translation();
    for (std::size_t i = 0; i < line.p_C.size(); ++i, ++k) {
      const Eigen::Vector3d& p_C = line.p_C[i];
      if (!p_C.allFinite()) {
        throw std::invalid_argument("ScansToCloud: line " + std::to_string(l) + ": point " +
                                    std::to_string(i) + " not finite");
      }
      out.cloud.points[k] = (R_0C * p_C + t_0C).cast<float>();
      if (confidence && !line.confidence.empty()) {
        const float c = line.confidence[i];
        if (!(c >= 0.0f && c <= 1.0f)) {
          throw std::invalid_argument("ScansToCloud: line " + std::to_string(l) + ": point " +
                                      std::to_string(i) + ": confidence " + std::to_string(c) +
                                      " outside [0, 1]");
        }
        out.cloud.confidence[k] = c;
      }
    }
    out.line_offsets.push_back(k);
    out.viewpoints_0.push_back(t_0C.cast<float>());
  }
  if (options.estimate_normals) {
    out.normals = vision::cloud::EstimateScanNormals(
        out.cloud.points, out.line_offsets, out.viewpoints_0, options.normals, &out.cloud.normals);
  }
  return out;
}

vision::cloud::CloudSidecar MakeCloudSidecar(const robots::Weld5Model& robot,
                                             const std::string& robot_calibration,
                                             const Eigen::Isometry3d& X_5C,
                                             const std::string& mount_calibration,
                                             std::size_t scan_lines) {
  vision::cloud::CloudSidecar s;
  s.robot_calibration = robot_calibration;
  for (const robots::DhJoint& j : robot.joints) {
    vision::cloud::SidecarDhLink l;
    l.a = j.a;
    l.alpha = j.alpha;
    l.d = j.d;
    l.theta_offset = j.theta_offset;
    l.prismatic = j.prismatic;
    s.robot_dh.push_back(l);
  }
  s.X_5T = robot.X_5T;
  s.X_5C = X_5C;
  s.mount_calibration = mount_calibration;
  s.scan_lines = scan_lines;
  return s;
}

}  // namespace kinevis::calibration
