#pragma once

// A recorded scanner-mount calibration dataset (issue 7; docs/scanner-mount-calibration.md): the
// touches and the scans of the gauge block with their joint readings, so that the calibration can
// be rerun from one recording. Layout:
//
//   DIR/dataset.yaml    kind: kinevis-scanner-mount-dataset, version: 1, robot (description
//                       file or ""), scanner (scanner calibration or camera spec the points were
//                       made with), block: {size_mm, guess: {position_mm, rpy_deg}},
//                       mount_guess: {position_mm, rpy_deg}, source, created
//   DIR/touches.csv     touch,feature,theta1_deg,theta2_deg,pz3_mm,theta4_deg,theta5_deg
//   DIR/scans.csv       scan,theta1_deg,theta2_deg,pz3_mm,theta4_deg,theta5_deg,laser,
//                       cot_theta_y,points,image
//   DIR/points/*.csv    x_mm,y_mm,z_mm,confidence: stripe points in the camera frame C
//   DIR/images/*.png    8-bit grey scanner images (optional)
//
// feature: BlockFeature names ("top", "board", "+x", "-y+z", ...). laser: fixed | rotating.
// points and image are paths relative to DIR; each scan has at least one of them. A scan with only
// an image needs the stripe extraction and scanner model (vision/laser/) before calibration.

#include <Eigen/Geometry>
#include <string>
#include <vector>

#include "calibration/weld_mount/mount_calibration.h"

namespace kinevis::calibration {

struct MountDatasetScan {
  robots::Vector5d q = robots::Vector5d::Zero();  // rad / m in memory
  std::string laser = "rotating";                 // "fixed" or "rotating"
  double cot_theta_y = 0.0;                       // the rotating laser's angle at the scan
  std::string points;                             // relative path of the points CSV, "" when none
  std::string image;                              // relative path of the PNG, "" when none
};

struct MountDataset {
  std::string directory;
  std::string robot_description;  // "" : the nominal seed robot with its default torch
  std::string scanner;            // the scanner calibration / camera spec the points came from
  GaugeBlock block;
  Eigen::Isometry3d X_0B_guess = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d X_5C_guess = Eigen::Isometry3d::Identity();
  std::string source;
  std::string created;  // UTC ISO 8601; filled on create when empty
  std::vector<MountTouch> touches;
  std::vector<MountDatasetScan> scans;
};

// Creates DIR (and points/, images/), writes dataset.yaml and the CSV headers. Throws
// std::invalid_argument when DIR already holds a dataset or the block is invalid,
// std::runtime_error naming the file on I/O failure.
void CreateMountDataset(MountDataset* dataset);

// Appends a touch row (flushed). Throws std::invalid_argument for non-finite joints or an invalid
// feature, std::runtime_error on I/O.
void AppendMountTouch(MountDataset* dataset, const MountTouch& touch);

// Writes the scan's points (points/scan_NNNN.csv, when `p_C` is not null) and image
// (images/scan_NNNN.png, when `pixels` is not null; width × height 8-bit grey with `stride` bytes
// per row) and appends the row to scans.csv. `confidence` is empty or one per point. Throws as
// above.
void AppendMountScan(MountDataset* dataset, MountDatasetScan scan,
                     const std::vector<Eigen::Vector3d>* p_C,
                     const std::vector<float>& confidence = {}, const uint8_t* pixels = nullptr,
                     int width = 0, int height = 0, size_t stride = 0);

// Reads and checks a dataset: dataset.yaml's keys, both CSVs (header, field count, numbers,
// features, laser names), and that every referenced points or image file exists. Throws
// std::invalid_argument naming the file, the line or key, and what is wrong.
MountDataset ReadMountDataset(const std::string& directory);

// The stripe points (m, in C) and confidences of a scan; throws std::invalid_argument naming the
// file and line when it is malformed, or when the scan has no points file.
std::vector<Eigen::Vector3d> ReadMountScanPoints(const MountDataset& dataset,
                                                 const MountDatasetScan& scan,
                                                 std::vector<float>* confidence = nullptr);

// The calibration input from a dataset whose scans all have points: `robot` (the model the
// dataset's robot description names, loaded by the caller) with the dataset's guesses, touches
// and scans. Throws std::invalid_argument naming the scan that has only an image.
MountCalibrationData MountCalibrationDataFromDataset(const MountDataset& dataset,
                                                     const robots::Weld5Model& robot);

}  // namespace kinevis::calibration
