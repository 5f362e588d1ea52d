#pragma once

// Surface normals of a scanned map by PCA over neighbours across consecutive scan lines (issue 7,
// seed 004 §4.3). A scanner map is a sequence of stripes ("scan lines"), each ordered along the
// stripe; a surface patch around a point is spanned by its own line (along the stripe) and by the
// lines before and after it (across the stripes). The neighbours of point i on line j are:
//   - the points i − point_window … i + point_window of line j, and
//   - on each line j' with 0 < |j' − j| ≤ line_window, the points around the one nearest to it
//     (found by a walk from the previous point's nearest, so the search is O(window), not O(N)),
// kept when within `radius` of the point. The normal is the eigenvector of the neighbours'
// covariance with the smallest eigenvalue, oriented towards the line's viewpoint (the scanner's
// position when the line was taken): n · (viewpoint − p) > 0.
//
// Degenerate neighbourhoods give no normal (the zero vector) and are counted: fewer than
// min_neighbours neighbours, or neighbours that do not span a plane: the middle eigenvalue below
// min_spread_ratio times the smallest (not flat), or below min_width_ratio² times the largest
// (e.g. all on one stripe: a line's normal is undefined).
//
// Lines may be of any length (also 0). Allocation: the output only. Thread-safe (pure function).

#include <Eigen/Core>
#include <cstddef>
#include <string>
#include <vector>

namespace kinevis::vision::cloud {

struct ScanNormalOptions {
  int line_window = 2;            // lines on either side searched, >= 1
  int point_window = 3;           // points on either side of the nearest one, per line, >= 1
  double radius = 2e-3;           // neighbours farther than this are left out (m), > 0
  int min_neighbours = 6;         // including the point itself, >= 3
  double min_spread_ratio = 4.0;  // λ_mid / λ_min required (>= 1): the patch must be planar-ish
  // √(λ_mid / λ_max) required, in [0, 1): the patch must be two-dimensional, not a stripe with
  // noise (neighbours from one scan line only).
  double min_width_ratio = 0.05;

  // Empty when usable, otherwise every bad field and its value.
  std::string Validate() const;
};

struct ScanNormalStats {
  std::size_t estimated = 0;
  std::size_t missing = 0;  // too few neighbours or not spanning a plane
};

// points: all lines' points concatenated (m, any frame); line_offsets: size L + 1, non-decreasing,
// line_offsets[0] = 0 and line_offsets[L] = points.size(): line l is
// [line_offsets[l], line_offsets[l+1]); viewpoints: one per line (m, same frame). normals (not
// null) is resized to points.size(): unit normals or zero where missing. Throws
// std::invalid_argument when the sizes or offsets are inconsistent or the options are invalid.
ScanNormalStats EstimateScanNormals(const std::vector<Eigen::Vector3f>& points,
                                    const std::vector<std::size_t>& line_offsets,
                                    const std::vector<Eigen::Vector3f>& viewpoints,
                                    const ScanNormalOptions& options,
                                    std::vector<Eigen::Vector3f>* normals);

}  // namespace kinevis::vision::cloud
