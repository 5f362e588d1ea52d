#pragma once

// Leg directions from camera images: the LegFeatureSource the hexapod servo loop uses on a real
// camera or on a simulated one (issue 6, seed 002 §IV-A). Every camera frame goes through
// vision::hexapod::ObserveLegs (the limb edges of each leg, their interpretation planes, eq. 11).
//
// Where the legs are searched. Each frame, the leg lengths q_j the drives report give, by forward
// kinematics of the nominal model (warm-started from the previous frame's pose), the platform pose
// X_BP; the camera pose X_CB (the calibration's rigid fit, seed eq. 15, or a hand estimate) puts
// the legs into C. When calibrated attachment points p_C_A are given they replace X_CB·p_B_A for
// the base ends. So the prediction is off only by the nominal model's error and X_CB's (a few mm
// after calibration, a few cm with a hand estimate: within LegEdgeOptions::search_half_width_px).
//
// Timing. Poll() is called by the loop every drive cycle and never waits: it asks the camera for
// a frame only when one is due by the camera's frame rate (a grab with a zero timeout), and then
// extracts the edges in the caller's thread (about 1–2 ms for six legs at 1024×768, see
// bench/leg_edges_bench.cc). A camera error is counted and reported (last_error()); the loop
// sees no frame and holds on its stale-camera rule, the safe reaction. The frame's timestamp is
// the capture time the camera reports.
//
// Frames and conventions as in control/hexapod/leg_servo.h and vision/hexapod/leg_edges.h.

#include <Eigen/Geometry>
#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "control/hexapod/servo_loop.h"
#include "hal/camera/camera.h"
#include "robots/hexapod/hexapod_model.h"
#include "vision/camera/camera_model.h"
#include "vision/hexapod/leg_edges.h"

namespace kinevis::control {

struct ImageLegFeatureOptions {
  vision::hexapod::LegEdgeOptions edges;
  // Calibrated base attachment points in C (seed eq. 14's solution); when set they are the base
  // ends of the predictions instead of X_CB·p_B_A of the nominal model.
  std::optional<LegPoints> p_C_A;
  // Empty when usable, otherwise every bad field and its value.
  std::string Validate() const;
};

struct ImageLegFeatureCounters {
  uint64_t frames = 0;            // frames processed
  uint64_t camera_errors = 0;     // Grab() errors other than "no frame yet"
  uint64_t fk_failures = 0;       // frames predicted from the previous pose (FK did not converge)
  uint64_t legs_not_visible = 0;  // sum over frames of legs not measured
  uint64_t format_errors = 0;     // frames of the wrong size or an unsupported pixel format
};

class ImageLegFeatureSource final : public LegFeatureSource {
 public:
  using LegLengthProvider = std::function<Vector6d()>;

  // camera: active (or made active by the caller before the first Poll), on the loop's clock;
  // frames of camera_model's size, mono8 (bgr8, rgb8 and mono16 are converted). model: the
  // nominal robot (q0, the platform points, the leg radius, the base points unless
  // options.p_C_A). X_CB: the pose of B in C. leg_lengths: the current q (m), e.g. q0 + the drive
  // readings. camera and camera_model must outlive the source. Throws std::invalid_argument
  // naming every bad argument (null pointers, an empty provider, invalid options or model, a
  // non-central camera model, non-finite calibrated points).
  ImageLegFeatureSource(hal::Camera* camera, const vision::CameraModel* camera_model,
                        robots::HexapodModel model, const Eigen::Isometry3d& X_CB,
                        LegLengthProvider leg_lengths, ImageLegFeatureOptions options = {});
  ~ImageLegFeatureSource() override;

  bool Poll(hal::Duration now, LegFeatureFrame* frame) override;

  // The observations of the last processed frame (reasons for the legs not seen).
  const std::array<vision::hexapod::LegObservation, kHexapodLegs>& last_observations() const;
  // The platform pose the last predictions were made at (nominal FK of the measured q).
  const Eigen::Isometry3d& last_predicted_pose() const { return X_BP_; }
  // The last camera or format error ("" when none so far), naming the camera and the cause.
  const std::string& last_error() const { return last_error_; }
  const ImageLegFeatureCounters& counters() const { return counters_; }

 private:
  hal::Camera* camera_;
  const vision::CameraModel* camera_model_;
  robots::HexapodModel model_;
  Eigen::Isometry3d X_CB_;
  LegLengthProvider leg_lengths_;
  ImageLegFeatureOptions options_;
  hal::Duration period_{0};
  bool have_frame_ = false;
  hal::Duration last_capture_{0};
  Eigen::Isometry3d X_BP_;
  robots::HexapodData fk_data_;
  hal::Image image_;
  std::vector<uint8_t> grey_;  // converted pixels when the camera does not deliver mono8
  std::unique_ptr<vision::hexapod::LegEdgeWorkspace> workspace_;
  std::string last_error_;
  ImageLegFeatureCounters counters_;
  uint64_t sequence_ = 0;
};

}  // namespace kinevis::control
