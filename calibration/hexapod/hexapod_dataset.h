#pragma once

// A recorded hexapod calibration dataset (issue 6): the images of the legs at N platform poses
// with the joint readings, so that calibration can be run as often as wanted from one recording
// on the real robot. Written by `kinevis record hexapod`, read by `kinevis calibrate hexapod
// --dataset DIR`. The format is documented in docs/hexapod-rig.md:
//
//   DIR/dataset.yaml   kind, robot description, camera (name, model, pose hint), what made it
//   DIR/poses.csv      one row per pose: image file, actuator readings s_j (m), commanded pose
//   DIR/images/*.png   8-bit grey images, one per pose
//
// Frames as in robots/hexapod/hexapod_model.h (B base, P platform, C camera).

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <string>
#include <vector>

#include "robots/hexapod/hexapod_model.h"

namespace kinevis::calibration {

struct HexapodDatasetPose {
  int index = 0;
  std::string image;  // file name relative to the dataset directory ("images/pose_000.png")
  robots::Vector6d s = robots::Vector6d::Zero();  // actuator readings after settling (m)
  // The pose the recorder asked for (nominal inverse kinematics gave the leg targets): with the
  // nominal model, it seeds the leg predictions of the edge extraction.
  Eigen::Isometry3d X_BP_commanded = Eigen::Isometry3d::Identity();
};

struct HexapodDataset {
  std::string directory;
  // The nominal robot: a description file (copied into the directory as robot.yaml), or empty
  // for robots::HexapodModel::Default().
  std::string robot_file;
  robots::HexapodModel nominal = robots::HexapodModel::Default();
  std::string camera_name;
  // vision::OpenCameraModel spec: "builtin:NAME", or a file copied into the directory.
  std::string camera_model;
  // The camera pose in B as the recording's config gave it: seeds the predictions only.
  Eigen::Isometry3d X_BC_hint = Eigen::Isometry3d::Identity();
  // How the camera's leg edges are to be located (vision/hexapod/leg_edges.h): "step-ramp" or
  // "parabola", and the optics' blur σ (px) the step-ramp model includes. Written from the rig's
  // settings; absent in a file: step-ramp and 0.
  std::string edge_locator = "step-ramp";
  double edge_blur_px = 0.0;
  std::string source;   // what was recorded ("simulated world config/hexapod-sim.yaml", ...)
  std::string created;  // UTC, ISO 8601
  std::vector<HexapodDatasetPose> poses;
};

// Creates `directory` (and images/), copies the robot description and a camera model file into
// it and writes dataset.yaml and the header of poses.csv. `dataset.robot_file` and
// `dataset.camera_model` are the originals; on return they name the copies. Throws
// std::runtime_error naming the path when something cannot be written, std::invalid_argument
// when the directory already holds a dataset.
void CreateHexapodDataset(HexapodDataset* dataset);

// Writes the image (8-bit grey, row-major, `stride` bytes per row) as PNG and appends the pose
// to poses.csv (the row is flushed, so a recording cut short keeps every pose before the cut).
void AppendHexapodDatasetPose(const HexapodDataset& dataset, const HexapodDatasetPose& pose,
                              const uint8_t* pixels, int width, int height, size_t stride);

// Reads a dataset directory. Throws std::invalid_argument naming the file, the line or key and
// what is wrong (missing files, bad numbers, a robot description that does not load).
HexapodDataset ReadHexapodDataset(const std::string& directory);

// Reads an 8-bit grey PNG of the dataset. Throws std::invalid_argument naming the file.
std::vector<uint8_t> ReadDatasetImage(const HexapodDataset& dataset, const HexapodDatasetPose& pose,
                                      int* width, int* height);

}  // namespace kinevis::calibration
