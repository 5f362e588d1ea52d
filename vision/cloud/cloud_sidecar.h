#pragma once

// The YAML sidecar of a PLY point cloud (docs/point-clouds.md): what the numbers in the PLY mean
// (units, frame) and what made them (robot, mount and scanner calibration, date, counts), so that
// a map can be traced back and refused when it does not fit. Written as MAP.yaml beside MAP.ply:
//
//   kind: kinevis-point-cloud        version: 1
//   ply: map.ply                     (relative to the sidecar's directory)
//   units: m                         frame: "0"   frame_description: robot base frame
//   created: 2024-05-01T12:00:00Z    source: kinevis scan (sim weld-cell)
//   counts: {points, scan_lines, normals_estimated, normals_missing, has_confidence}
//   robot: {calibration: FILE-or-text, dh: [{a_mm, alpha_deg, d_mm, theta_offset_deg, prismatic}],
//           torch: {position_mm: [x, y, z], rpy_deg: [r, p, y]}}
//   mount: {calibration: FILE-or-text, X_5C: {position_mm: [...], rpy_deg: [...]}}
//   scanner: {calibration: FILE-or-text, parameters: {name_with_unit: value, ...}}
//
// rpy_deg is roll-pitch-yaw: R = Rz(yaw) Ry(pitch) Rx(roll), the convention of the sim configs.
// In memory everything is SI (m, rad); the file carries mm and degrees, with the unit in the key.

#include <Eigen/Geometry>
#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "vision/cloud/point_cloud.h"

namespace kinevis::vision::cloud {

// One standard D–H link as used (robots/weld5/weld5_model.h's DhJoint, kept free of robots/ here).
struct SidecarDhLink {
  double a = 0.0;             // m
  double alpha = 0.0;         // rad
  double d = 0.0;             // m
  double theta_offset = 0.0;  // rad
  bool prismatic = false;
};

struct CloudSidecar {
  std::string ply;  // the PLY's file name, relative to the sidecar's directory; not empty
  std::string units = "m";
  std::string frame = "0";
  std::string frame_description = "robot base frame";
  std::string created;  // UTC ISO 8601; WriteCloud fills it when empty
  std::string source;   // the program (and world) that made the map

  std::uint64_t points = 0;
  std::uint64_t scan_lines = 0;
  std::uint64_t normals_estimated = 0;
  std::uint64_t normals_missing = 0;
  bool has_confidence = false;

  std::string robot_calibration;  // where the robot model came from (file, or "nominal ...")
  std::vector<SidecarDhLink> robot_dh;
  Eigen::Isometry3d X_5T = Eigen::Isometry3d::Identity();  // torch in link 5
  std::string mount_calibration;                           // where X_5C came from
  Eigen::Isometry3d X_5C = Eigen::Isometry3d::Identity();  // scanner camera in link 5
  std::string scanner_calibration;                         // where the scanner model came from
  // Scanner parameters as the caller names them, the unit in the name ("rotating_b_y_mm").
  std::map<std::string, double> scanner_parameters;
};

// Writes `sidecar` as YAML to `path`. Throws std::invalid_argument naming the file when ply is
// empty or the poses are not finite, std::runtime_error naming it on I/O failure.
void WriteCloudSidecar(const std::string& path, const CloudSidecar& sidecar);

// Reads and checks a sidecar: kind and version, units "m", every key present with the right type
// and finite values, poses with orthonormal rotation. Throws std::invalid_argument naming the file,
// the key and what is wrong.
CloudSidecar ReadCloudSidecar(const std::string& path);

// Writes the PLY (directory of sidecar_path / sidecar.ply) and the sidecar, with the counts filled
// from `cloud` (points, normals_estimated, normals_missing, has_confidence; scan_lines as given).
// Throws as WritePly and WriteCloudSidecar.
void WriteCloud(const std::string& sidecar_path, const PointCloud& cloud, CloudSidecar sidecar);

// Reads a sidecar and its PLY and checks they agree (point count, normals, confidence). Throws
// std::invalid_argument naming the file and what is wrong.
PointCloud ReadCloud(const std::string& sidecar_path, CloudSidecar* sidecar = nullptr);

}  // namespace kinevis::vision::cloud
