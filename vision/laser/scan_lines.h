#pragma once

// One scan line per image of a laser sweep (seed 004 §2, eq. 9 and 11; issue 7): the rotating
// laser's stripe, extracted with sub-pixel accuracy (laser_stripes.h), triangulated into points in
// the scanner camera frame C at the laser angle that eq. (11) reads off the image of the two
// stripes' intersection. The host never needs the stepper's angle: it follows from each image, so
// the same code runs on a real scanner sweeping on its own and on the simulated one.
//
// Also the sweep a host plans when it does drive the stepper (the simulated cell; a scanner whose
// stepper takes commands): the angles that move the stripe evenly over the image rows at an
// expected working distance.
//
// Units SI (m, rad); pixels as in camera_model.h.

#include <Eigen/Core>
#include <string>
#include <vector>

#include "vision/laser/laser_stripes.h"
#include "vision/laser/scanner_model.h"

namespace kinevis::vision::laser {

enum class ScanLineStatus {
  kOk,
  kNoCrossing,         // the two stripes' intersection was not found (crossing status says why)
  kAngleFailed,        // eq. (11) failed at the crossing (behind the camera, degenerate)
  kTooFewPoints,       // fewer than min_points rotating stripe points were triangulated
  kAngleInconsistent,  // eq. (11)'s angle disagrees with the caller's expected one (see options)
};
const char* ToString(ScanLineStatus status);

struct ScanLineOptions {
  LaserStripeOptions stripes;  // both stripes are searched: the crossing needs the fixed one
  // Stripe points below this confidence are dropped, [0, 1).
  double min_confidence = 0.2;
  // A line with fewer triangulated points is reported as kTooFewPoints (its points are kept), >= 1.
  int min_points = 20;
  // When an expected angle is given to Process (a commanded stepper), |cot θ_y(eq. 11) − expected|
  // above this marks the line kAngleInconsistent (a skipped step, a wrong calibration), > 0.
  double max_angle_deviation = 0.02;
  // Also triangulate the fixed laser's stripe (eq. 10) into fixed_p_C.
  bool fixed_points = false;
  std::string Validate() const;  // empty when usable, else every bad field and its value
};

struct ScanLineResult {
  ScanLineStatus status = ScanLineStatus::kNoCrossing;
  CrossingStatus crossing = CrossingStatus::kNotSearched;
  Eigen::Vector2d crossing_pixel = Eigen::Vector2d::Zero();
  double cot_theta_y = 0.0;  // eq. (11) at the crossing (valid unless kNoCrossing/kAngleFailed)
  double cot_theta_y_sigma = 0.0;          // from the crossing's pixel covariance
  std::vector<Eigen::Vector3d> p_C;        // rotating stripe points in C (m), in column order
  std::vector<float> confidence;           // one per point, the stripe point's confidence
  std::vector<Eigen::Vector3d> fixed_p_C;  // options.fixed_points only
  int stripe_points = 0;                   // rotating stripe points found in the image
  int dropped_low_confidence = 0;
  int dropped_triangulation = 0;  // behind the camera / not back-projectable
  bool ok() const { return status == ScanLineStatus::kOk; }
};

class ScanLineTriangulator {
 public:
  // `model` must outlive the triangulator. Throws std::invalid_argument naming every bad option.
  ScanLineTriangulator(const ScannerModel& model, const ScanLineOptions& options = {});

  // Extracts the stripes of `image` (the scanner camera's size) and triangulates the rotating
  // one into *result. `expected_cot_theta_y` (NaN: none) checks eq. (11) against a commanded
  // angle. Throws std::invalid_argument for an image that is not the camera's size (names both).
  void Process(const vision::ImageView8& image, ScanLineResult* result,
               double expected_cot_theta_y = std::nan(""));

  const ScanLineOptions& options() const { return options_; }

 private:
  const ScannerModel& model_;
  ScanLineOptions options_;
  LaserStripeExtractor extractor_;
  LaserStripes stripes_;
};

// The stepper angles (as cot θ_y, in sweep order) that put the rotating stripe on `lines` evenly
// spaced image rows between row_margin and 1 − row_margin of the height, on the central column,
// for a surface at `depth` (m, along the optical axis) from the camera. Throws
// std::invalid_argument for lines < 2, depth <= |d_y|, a margin outside [0, 0.45], or rows the
// camera cannot back-project.
std::vector<double> PlanSweep(const ScannerModel& model, double depth, int lines,
                              double row_margin = 0.05);

}  // namespace kinevis::vision::laser
