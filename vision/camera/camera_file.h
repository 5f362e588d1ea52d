#pragma once

// Camera model files and built-in parameter sets: one call turns a file (or a built-in name) into
// a CameraModel. Format: docs/camera-models.md.
//
//   - a pinhole + Brown intrinsics file in the ROS camera_info / OpenCV layout
//     (camera_info_yaml.h; recognised by its camera_matrix key), as `kinevis calibrate camera`
//     writes it;
//   - any model as YAML with a `model:` key ("pinhole-brown", "tsai", "unified", "scaramuzza",
//     "hyperbolic-mirror") and that model's parameter fields, SI or the unit in the key name.
//
// Built-in sets, for sanity checks and tests: "tsai-seed004", "unified-default",
// "scaramuzza-default", "hyperbolic-mirror-4mm", "hyperbolic-mirror-6mm" (seed 000's two lenses).

#include <memory>
#include <string>
#include <vector>

#include "vision/camera/camera_model.h"

namespace kinevis::vision {

// Reads `path`. Throws std::invalid_argument naming the file and every bad or missing key (and the
// model's own Validate() message), std::runtime_error when it cannot be read.
std::unique_ptr<CameraModel> LoadCameraModel(const std::string& path);

// A built-in parameter set by name; throws std::invalid_argument listing the names when unknown.
std::unique_ptr<CameraModel> BuiltinCameraModel(const std::string& name);
std::vector<std::string> BuiltinCameraModelNames();

// "builtin:NAME" → BuiltinCameraModel(NAME); anything else → LoadCameraModel(path).
std::unique_ptr<CameraModel> OpenCameraModel(const std::string& spec);

}  // namespace kinevis::vision
