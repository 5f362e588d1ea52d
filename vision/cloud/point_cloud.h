#pragma once

// Point clouds (issue 7): the scanned maps of seed 004 (§4.3, eq. 51–55), points with normals and
// an optional per-point confidence, stored as binary little-endian PLY with a YAML sidecar
// (docs/point-clouds.md). The frame the points are in is not part of this struct: it is the
// sidecar's (cloud_sidecar.h); maps of the weld cell are in the robot base frame 0.
//
// Coordinates are stored as float (what the PLY holds), in metres: a float keeps 0.06 µm at 1 m,
// far below the scanner's 0.1 mm noise, and a file round trip is then bit-exact.

#include <Eigen/Core>
#include <cstddef>
#include <string>
#include <vector>

namespace kinevis::vision::cloud {

struct PointCloud {
  std::vector<Eigen::Vector3f> points;  // (m), finite
  // Empty (no normals) or one per point: unit length (|n| − 1 within 1e-3), or exactly zero where
  // no normal could be estimated (scan_normals.h).
  std::vector<Eigen::Vector3f> normals;
  // Empty (none) or one per point, each in [0, 1] (e.g. the stripe extractor's confidence).
  std::vector<float> confidence;

  std::size_t size() const { return points.size(); }
  bool has_normals() const { return !normals.empty(); }
  bool has_confidence() const { return !confidence.empty(); }
  // Points whose normal is the zero vector (0 when there are no normals).
  std::size_t CountMissingNormals() const;

  // Empty when consistent; otherwise the first problem per kind, naming the array, the index and
  // the value ("normals[12] has length 0.5; expected 1 or 0").
  std::string Validate() const;
};

}  // namespace kinevis::vision::cloud
