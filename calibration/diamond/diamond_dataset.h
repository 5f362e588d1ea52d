#pragma once

// A recorded DIAMOND calibration dataset (issue 8): the marker images at N joint configurations
// with the joint readings, so that identification can be run as often as wanted from one
// recording on the real robot. Format (docs/diamond-calibration.md):
//
//   DIR/dataset.yaml    kind, version, nominal robot, camera (name, model, pose X_OC and how its
//                       distance from the RCM was obtained: the scale gauge), source, created
//   DIR/samples.csv     index,image,q1_rad,q2_rad,u_px,v_px — one row per configuration; u_px,v_px
//                       empty when the marker has not been located yet (the detector fills
//                       them from the image), image empty when no image was stored
//   DIR/images/*.png    8-bit grey images
//
// Frames as in robots/diamond/diamond_model.h (O the RCM frame) and camera_model.h (C).

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <string>
#include <vector>

#include "calibration/diamond/diamond_identification.h"
#include "robots/diamond/diamond_model.h"

namespace kinevis::calibration {

struct DiamondDatasetSample {
  int index = 0;
  std::string image;  // file name relative to the directory ("images/sample_0000.png"), or ""
  Eigen::Vector2d q = Eigen::Vector2d::Zero();      // joint readings after settling (rad)
  bool has_pixel = false;                           // the marker pixel is known
  Eigen::Vector2d pixel = Eigen::Vector2d::Zero();  // (px), when has_pixel
};

struct DiamondDataset {
  std::string directory;
  // The nominal robot: a description file (copied in as robot.yaml), or empty for
  // robots::DiamondModel::APriori().
  std::string robot_file;
  robots::DiamondModel nominal = robots::DiamondModel::APriori();
  std::string camera_name;
  // vision::OpenCameraModel spec: "builtin:NAME", or a file copied into the directory.
  std::string camera_model;
  // The camera pose in O as set up or measured: identification starts from it and, with the
  // default gauge, keeps its distance from the RCM (which fixes the scale of R).
  Eigen::Isometry3d X_OC = Eigen::Isometry3d::Identity();
  // How that distance was obtained, in words ("simulated truth", "tape measure ±1 mm", ...).
  std::string camera_distance_source;
  std::string source;   // what was recorded ("simulated world config/diamond-sim.yaml", ...)
  std::string created;  // UTC, ISO 8601
  std::vector<DiamondDatasetSample> samples;
};

// Creates `directory` (and images/), copies the robot description and a camera model file into
// it, writes dataset.yaml and the header of samples.csv. On return robot_file and camera_model
// name the copies. Throws std::invalid_argument when the directory already holds a dataset or
// X_OC is not a rigid transform, std::runtime_error naming the path when something cannot be
// written.
void CreateDiamondDataset(DiamondDataset* dataset);

// Appends a sample to samples.csv (flushed: a recording cut short keeps every sample before the
// cut) and, when `pixels` is not null, writes the image (8-bit grey, row-major, `stride` bytes per
// row, width × height > 0) to sample.image as PNG. Throws std::invalid_argument for non-finite q
// or pixel, or pixels given without an image name; std::runtime_error when a file cannot be
// written.
void AppendDiamondDatasetSample(const DiamondDataset& dataset, const DiamondDatasetSample& sample,
                                const uint8_t* pixels = nullptr, int width = 0, int height = 0,
                                size_t stride = 0);

// Reads a dataset directory. Throws std::invalid_argument naming the file, the line or key and
// what is wrong (missing files, wrong kind/version, bad numbers, a wrong CSV header, a robot
// description that does not load, a pose that is not a rotation).
DiamondDataset ReadDiamondDataset(const std::string& directory);

// Reads a sample's 8-bit grey PNG. Throws std::invalid_argument naming the file.
std::vector<uint8_t> ReadDiamondDatasetImage(const DiamondDataset& dataset,
                                             const DiamondDatasetSample& sample, int* width,
                                             int* height);

// The samples with a known marker pixel, as identification input.
std::vector<DiamondSample> DiamondSamplesWithPixels(const DiamondDataset& dataset);

}  // namespace kinevis::calibration
