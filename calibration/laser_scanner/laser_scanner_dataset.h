#pragma once

// A recorded laser-scanner calibration dataset (issue 7): board images with the lasers off (for
// the board pose) and on (stripes) at several board poses and stepper positions, so that the
// calibration can be rerun from one recording. Format (docs/laser-scanner-calibration.md):
//
//   DIR/dataset.yaml   kind, version, camera (model spec or a copied file), board dot grid (mm),
//                      source, created
//   DIR/images.csv     image,board_pose,lasers,rotating_step   (lasers: off | on)
//   DIR/images/*.png   8-bit grey, camera-sized
//   DIR/stripes/*.csv  optional, per lasers-on image: laser,u_px,v_px (laser: fixed | rotating),
//                      stripe pixels extracted beforehand (or the simulator's ground truth)
//
// Every board_pose needs exactly one lasers-off image (the dots; the stripes would cut them)
// and any number of lasers-on images taken without moving the board.

#include <Eigen/Core>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "calibration/laser_scanner/board_pose.h"
#include "calibration/laser_scanner/laser_scanner_calibration.h"
#include "vision/render/renderer.h"
#include "vision/render/scenes/laser_scene.h"

namespace kinevis::calibration {

struct LaserScannerDatasetImage {
  std::string image;   // relative to the directory ("images/pose00_off.png")
  int board_pose = 0;  // >= 0: images with the same index share the board's pose
  bool lasers_on = false;
  int rotating_step = 0;  // the stepper position (lasers-on images)
  std::string stripes;    // relative path of the stripe CSV, "" when none
};

struct LaserScannerDataset {
  std::string directory;
  std::string camera_model;  // vision::OpenCameraModel spec, relative files resolved on read
  std::string camera_name;
  vision::render::DotGrid board;  // geometry only (rows, cols, pitch, radius)
  std::string source;
  std::string created;  // UTC ISO 8601; filled on create when empty
  std::vector<LaserScannerDatasetImage> images;
};

// Creates the directory (and images/, stripes/), writes dataset.yaml and the header of images.csv.
// Throws std::invalid_argument when it already holds a dataset, std::runtime_error on I/O.
void CreateLaserScannerDataset(LaserScannerDataset* dataset);

// Writes the PNG (and the stripe CSV when `fixed` or `rotating` is not null) and appends the row
// to images.csv (flushed). Fills entry->stripes when stripes are written. Throws
// std::runtime_error naming the file on I/O failure.
void AppendLaserScannerDatasetImage(LaserScannerDataset* dataset, LaserScannerDatasetImage entry,
                                    const uint8_t* pixels, int width, int height, size_t stride,
                                    const std::vector<Eigen::Vector2d>* fixed = nullptr,
                                    const std::vector<Eigen::Vector2d>* rotating = nullptr);

// Throws std::invalid_argument naming the file, line or key and what is wrong.
LaserScannerDataset ReadLaserScannerDataset(const std::string& directory);

// An image as 8-bit grey pixels; throws std::invalid_argument naming the file.
std::vector<uint8_t> ReadLaserScannerDatasetImage(const LaserScannerDataset& dataset,
                                                  const LaserScannerDatasetImage& entry, int* width,
                                                  int* height);
// The stripe CSV of an entry; throws std::invalid_argument naming the file and line.
void ReadLaserScannerDatasetStripes(const LaserScannerDataset& dataset,
                                    const LaserScannerDatasetImage& entry,
                                    std::vector<Eigen::Vector2d>* fixed,
                                    std::vector<Eigen::Vector2d>* rotating);

// Stripe extraction from a lasers-on image (e.g. vision/laser/laser_stripes.h's).
using StripeExtractor =
    std::function<void(const vision::ImageView8& image, std::vector<Eigen::Vector2d>* fixed,
                       std::vector<Eigen::Vector2d>* rotating)>;

struct LaserScannerDatasetCalibration {
  LaserScannerCalibration calibration;
  std::vector<int> board_pose_ids;     // per estimated board pose
  std::vector<BoardPose> board_poses;  // same order
  std::vector<std::string> skipped;    // board poses / images left out, and why
};

// Board pose from each lasers-off image, stripes from `extractor` (when set) or the dataset's
// stripe CSVs, then CalibrateLaserScanner. A board pose whose grid is not found is skipped (and
// listed). Throws std::invalid_argument when an image has neither stripes nor an extractor, or
// a board pose has no (or two) lasers-off images.
LaserScannerDatasetCalibration CalibrateLaserScannerDataset(
    const LaserScannerDataset& dataset, const vision::CameraModel& camera,
    const StripeExtractor& extractor = {}, const LaserScannerCalibrationOptions& options = {},
    const BoardPoseOptions& board_options = {});

}  // namespace kinevis::calibration
