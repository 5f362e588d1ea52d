#pragma once

// The whole leg-edge calibration of seed 002 from a recorded dataset (issue 6): every image of
// the dataset goes through the leg-edge extraction (vision/hexapod/leg_edges.h), the limb normals
// of the legs it saw become eq. 14's equations, and CalibrateHexapod() solves eq. 14–16.
//
// Predictions. The edges are searched around where the nominal model puts each leg: the pose
// X_BP is the nominal forward kinematics of the recorded readings (q = q0 + s, warm-started from
// the commanded pose), the camera pose is the dataset's hand-measured hint. With `passes` > 1 the
// extraction is repeated with the previous pass's result: the rigid fit X_CB (eq. 15) for the
// platform ends and the estimated A_j for the base ends, which moves the search windows onto the
// legs when the hint was centimetres off and lets legs that were missed be found.
//
// Frames as in robots/hexapod/hexapod_model.h (B base, P platform, C camera).

#include <Eigen/Geometry>
#include <string>
#include <vector>

#include "calibration/hexapod/hexapod_dataset.h"
#include "calibration/hexapod/leg_calibration.h"
#include "vision/camera/camera_model.h"
#include "vision/hexapod/leg_edges.h"

namespace kinevis::calibration {

struct DatasetCalibrationOptions {
  vision::hexapod::LegEdgeOptions edges;
  // edges.locator and edges.edge_blur_px are taken from the dataset (what the recording rig knew
  // about its camera's optics) unless this is false.
  bool edge_locator_from_dataset = true;
  HexapodCalibrationOptions calibration;
  int passes = 2;  // extraction + calibration rounds, >= 1 (see above)
  // Empty when usable, otherwise every bad field and its value.
  std::string Validate() const;
};

// What the extraction saw in one image of the last pass.
struct DatasetPoseReport {
  int index = 0;             // pose index of the dataset
  int legs_seen = 0;         // legs with both limbs measured
  std::string not_seen;      // "leg 3: occluded (...); leg 5: ..." for the others
  bool fk_converged = true;  // nominal FK of the readings converged (else the commanded pose)
};

struct DatasetCalibrationResult {
  HexapodCalibrationResult result;  // of the last pass
  HexapodCalibrationData data;      // the normals of the last pass
  std::vector<DatasetPoseReport> poses;
  int passes_run = 0;
  // Largest change of an estimated A_j between the last two passes (m); NaN after one pass.
  double last_pass_change = 0.0;
};

// Runs the calibration on `dataset` seen through `camera` (the model of the camera that took the
// images; its size must equal the images'). Throws std::invalid_argument naming the problem for
// invalid options, a non-central camera, an image that cannot be read or does not match the
// camera, and CalibrateHexapod()'s errors. Expected data problems (legs not seen, configurations
// too alike) are in the result, not thrown.
DatasetCalibrationResult CalibrateHexapodDataset(const HexapodDataset& dataset,
                                                 const vision::CameraModel& camera,
                                                 const DatasetCalibrationOptions& options = {});

}  // namespace kinevis::calibration
