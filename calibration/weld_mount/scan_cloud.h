#pragma once

// Scans → a point cloud in the robot base frame (seed 004 §4.3, eq. 51–55; issue 7).
//
// The seed writes the chain as A0P = A01 · A12 · A2S · ASP (eq. 51): its scanner rides on the
// link after joint 2 (A2S carries pz3, eq. 54). In the kinevis cell the scanner is clamped to the
// torch on link 5 (sim/weld_cell_world.h), so the chain is the whole arm:
//
//   p_0 = X_05(q) · X_5C · p_C,     X_05(q) = Π_{i=1..5} X_{i−1,i}(q_i)   (eq. 33/47 with eq. 34),
//
// with X_5C the calibrated mount (mount_calibration.h) and q the joint readings of the scan; p_C
// is eq. 55's (x_c, y_c, z_c). Normals come from vision/cloud/scan_normals.h over consecutive scan
// lines, oriented towards the scanner (the camera's origin, X_05(q) · X_5C · 0, per line).

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <string>
#include <vector>

#include "robots/weld5/weld5_model.h"
#include "vision/cloud/cloud_sidecar.h"
#include "vision/cloud/point_cloud.h"
#include "vision/cloud/scan_normals.h"

namespace kinevis::calibration {

// One scan line: the stripe points of one image and the joint readings it was taken at.
struct ScanLine {
  robots::Vector5d q = robots::Vector5d::Zero();  // rad / m (robots::Weld5Model)
  std::vector<Eigen::Vector3d> p_C;               // stripe points in the camera frame C (m)
  std::vector<float> confidence;                  // empty, or one per point in [0, 1]
};

struct ScanCloudOptions {
  bool estimate_normals = true;
  vision::cloud::ScanNormalOptions normals;
  std::string Validate() const;  // the normal options' problems
};

struct ScanCloud {
  vision::cloud::PointCloud cloud;            // points in frame 0 (m), normals, confidence
  std::vector<std::size_t> line_offsets;      // size lines + 1: line l is [o[l], o[l+1])
  std::vector<Eigen::Vector3f> viewpoints_0;  // per line, the camera's origin in frame 0 (m)
  vision::cloud::ScanNormalStats normals;     // estimated / missing
};

// Eq. 51–55 for every point of every line, then the normals. Confidence is kept when every line
// has it (all or none: a line with and a line without throw). Throws std::invalid_argument
// naming the line (and point) for non-finite joints or points, a confidence of the wrong size or
// outside [0, 1], bad options, or a mount that is not a rigid transform.
ScanCloud ScansToCloud(const robots::Weld5Model& robot, const Eigen::Isometry3d& X_5C,
                       const std::vector<ScanLine>& lines, const ScanCloudOptions& options = {});

// The sidecar's robot, torch and mount entries from the model and mount that made the cloud;
// the rest (ply, source, scanner) is the caller's.
vision::cloud::CloudSidecar MakeCloudSidecar(const robots::Weld5Model& robot,
                                             const std::string& robot_calibration,
                                             const Eigen::Isometry3d& X_5C,
                                             const std::string& mount_calibration,
                                             std::size_t scan_lines);

}  // namespace kinevis::calibration
