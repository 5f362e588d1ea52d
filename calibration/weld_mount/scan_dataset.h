#pragma once

// A recorded laser sweep (issue 7; docs/point-clouds.md "Scan datasets"): the scanner images of
// one `kinevis scan` with the joint readings at each, so that the map can be rebuilt later with
// another scanner or mount calibration. Layout:
//
//   DIR/scan.yaml     kind: kinevis-scan-dataset, version: 1, camera (the scanner camera model
//                     spec), source, created
//   DIR/frames.csv    frame,image,theta1_deg,theta2_deg,pz3_mm,theta4_deg,theta5_deg,
//                     commanded_cot_theta_y   (empty when the stepper swept on its own)
//   DIR/images/*.png  8-bit grey scanner images, paths relative to DIR
//
// Joints in degrees and mm at the file edge, SI in memory.

#include <cstdint>
#include <string>
#include <vector>

#include "robots/weld5/weld5_model.h"

namespace kinevis::calibration {

struct ScanDatasetFrame {
  robots::Vector5d q = robots::Vector5d::Zero();  // rad / m
  std::string image;                              // relative to the directory
  double commanded_cot_theta_y = std::nan("");    // NaN: not commanded
};

struct ScanDataset {
  std::string directory;
  std::string camera_model;  // spec ("builtin:tsai-seed004" or a camera file)
  std::string source;
  std::string created;  // UTC ISO 8601, filled on create when empty
  std::vector<ScanDatasetFrame> frames;
};

// Creates DIR/images, writes scan.yaml and the CSV header. Throws std::invalid_argument when DIR
// already holds a scan dataset, std::runtime_error naming the path on I/O failure.
void CreateScanDataset(ScanDataset* dataset);

// Writes the image (images/frame_NNNN.png; width x height 8-bit grey, `stride` bytes per row) and
// appends the row (flushed). Throws std::invalid_argument for non-finite joints, std::runtime_error
// on I/O failure.
void AppendScanFrame(ScanDataset* dataset, ScanDatasetFrame frame, const uint8_t* pixels, int width,
                     int height, size_t stride);

// Reads and checks a dataset (keys, the CSV's header, field count and numbers, that each image
// exists). Throws std::invalid_argument naming the file, the line or key and what is wrong.
ScanDataset ReadScanDataset(const std::string& directory);

// The frame's image as 8-bit grey (pixels row-major, stride = width). Throws std::invalid_argument
// naming the file when it cannot be read or is not `width` x `height`.
std::vector<uint8_t> ReadScanFrameImage(const ScanDataset& dataset, const ScanDatasetFrame& frame,
                                        int width, int height);

}  // namespace kinevis::calibration
