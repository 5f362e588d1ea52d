#pragma once

// Intrinsics files of a pinhole + Brown camera in the layout of ROS's camera_info YAML
// (camera_calibration_parsers, parse_yml.cpp), which OpenCV's cv::FileStorage also reads:
//
//   %YAML 1.2
//   ---
//   image_width: 640                      # pixels
//   image_height: 480
//   camera_name: "camera"
//   camera_matrix: {rows: 3, cols: 3, data: [fx, 0, cx, 0, fy, cy, 0, 0, 1]}   # row-major, pixels
//   distortion_model: "plumb_bob"         # k1 k2 p1 p2 k3, or "rational_polynomial": + k4 k5 k6
//   distortion_coefficients: {rows: 1, cols: 5, data: [k1, k2, p1, p2, k3]}
//   rectification_matrix: {rows: 3, cols: 3, data: [1, 0, 0, 0, 1, 0, 0, 0, 1]}
//   projection_matrix: {rows: 3, cols: 4, data: [fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0]}
//   ...extra keys (calibration report), which ROS's parser ignores
//
// Matrices are written as block maps (rows/cols/data) exactly as ROS writes them. The header line
// is "%YAML 1.2" rather than OpenCV's "%YAML:1.0": OpenCV 4 needs some %YAML directive to open a
// file, yaml-cpp (ROS) accepts both, and PyYAML rejects "%YAML:1.0". See
// docs/camera-calibration.md.

#include <string>
#include <utility>
#include <vector>

#include "vision/camera/pinhole_camera.h"

namespace kinevis::vision {

// Additional content of an intrinsics file. The extra keys are written after the ROS keys; each
// name must match [A-Za-z_][A-Za-z0-9_]* and not be one of the ROS keys.
struct IntrinsicsFileExtras {
  std::string camera_name = "camera";
  std::vector<std::pair<std::string, double>> numbers;
  std::vector<std::pair<std::string, std::string>> strings;
  std::vector<std::pair<std::string, std::vector<double>>> number_lists;
  std::vector<std::pair<std::string, std::vector<std::string>>> string_lists;
};

// Writes `params` to `path`. The distortion model is "plumb_bob" with 5 coefficients when k4, k5
// and k6 are zero, otherwise "rational_polynomial" with 8. Numbers are written with the shortest
// representation that reads back exactly. Throws std::invalid_argument when params.Validate()-style
// checks fail (size or focal length not positive, non-finite values) or an extra key is bad, and
// std::runtime_error naming the path when the file cannot be written.
void WritePinholeIntrinsics(const std::string& path, const PinholeBrownParameters& params,
                            const IntrinsicsFileExtras& extras = {});

// Reads an intrinsics file in the layout above, with or without a %YAML header line (ROS writes
// none). Required keys: image_width, image_height, camera_matrix, distortion_coefficients.
// distortion_model is optional ("plumb_bob" assumed, as ROS does); rectification_matrix and
// projection_matrix are optional but must be 3×3 and 3×4 when present. A plumb_bob file may have
// 4 or 5 coefficients, a rational_polynomial one 8. The camera matrix must have zero skew and
// last row [0 0 1].
// Throws std::runtime_error "<path>: ..." when the file cannot be opened or parsed, and
// std::invalid_argument "<path>: <key>: ...; <key>: ..." naming every missing or bad key and its
// value (missing key, wrong matrix size, non-positive focal length or image size, unknown
// distortion model).
PinholeBrownParameters ReadPinholeIntrinsics(const std::string& path,
                                             std::string* camera_name = nullptr);

}  // namespace kinevis::vision
