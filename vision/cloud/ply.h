#pragma once

// Binary little-endian PLY for point clouds (docs/point-clouds.md). Written:
//
//   ply
//   format binary_little_endian 1.0
//   comment kinevis point cloud, units m          (+ one "comment" line per entry of `comments`)
//   element vertex N
//   property float x            property float y            property float z
//   property float nx           property float ny           property float nz      (with normals)
//   property float confidence                                                      (optional)
//   end_header
//   N records of 4-byte IEEE-754 little-endian floats, in the order of the properties.
//
// Read: the same, and more leniently any PLY whose first element is `vertex` with scalar
// properties of the standard types, in any order: x, y, z (float) are required; nx, ny, nz (float)
// are read when all three are present; confidence (float) when present; other scalar properties
// are skipped; elements after `vertex` are ignored. A round trip Write → Read is bit-exact.

#include <string>
#include <vector>

#include "vision/cloud/point_cloud.h"

namespace kinevis::vision::cloud {

// Writes `cloud` to `path` (created or truncated). `comments` go into the header, one per line
// (no newlines inside). Throws std::invalid_argument when the cloud is inconsistent
// (PointCloud::Validate, message names the file) or a comment holds a newline;
// std::runtime_error naming the file when it cannot be written.
void WritePly(const std::string& path, const PointCloud& cloud,
              const std::vector<std::string>& comments = {});

// Reads a PLY written by WritePly (or compatible, see above). Throws std::invalid_argument naming
// the file and what is wrong: missing or unreadable file, not PLY, ASCII or big-endian format,
// missing x/y/z, a property that is not float, a list property in the vertex element, a truncated
// body (expected and actual bytes), a non-finite coordinate, a normal that is neither unit nor
// zero, a confidence outside [0, 1] (each with the vertex index). `comments` (if not null)
// receives the header's comment lines without the "comment " prefix.
PointCloud ReadPly(const std::string& path, std::vector<std::string>* comments = nullptr);

}  // namespace kinevis::vision::cloud
