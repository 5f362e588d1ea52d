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
// Timing, two modes (options.asynchronous):
//  - synchronous (simulated worlds in stepped time, tests): Poll() is called by the loop every
//    drive cycle and never waits: it asks the camera for a frame only when one is due by the
//    camera's frame rate (a grab with a zero timeout) and extracts the edges in the caller's
//    thread (about 1–2 ms for six legs at 1024×768, bench/leg_edges_bench.cc). Deterministic.
//  - asynchronous (real cameras, and worlds in another process): a worker thread grabs frames
//    (blocking up to grab_timeout) and extracts the edges; Poll() only hands over the newest
//    finished frame and the current leg lengths, so a camera that is slow to deliver never
//    delays a drive cycle. The leg-length provider is still called from Poll() (the loop's
//    thread); the worker uses the latest q it was given. The worker is control/common's
//    LatestFrameWorker, the same as the DIAMOND marker's (camera_marker_source.h).
// A camera error is counted and reported (last_error()); the loop sees no frame and holds on its
// stale-camera rule, the safe reaction. The frame's timestamp is the capture time the camera
// reports.
//
// Frames and conventions as in control/hexapod/leg_servo.h and vision/hexapod/leg_edges.h.

#include <Eigen/Geometry>
#include <array>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "control/common/latest_frame.h"
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
  // A leg whose measured direction is further than this (rad) from the predicted one is not used
  // in that frame (reported not visible, counted): a gross extraction error (a frame's edge fitted
  // to a neighbour's shading, a perspective camera's ill-conditioned eq. 11) must not jerk the
  // platform. The prediction (nominal FK of the measured leg lengths, calibrated A_j and X_CB) is
  // good to a few mrad; 0 = off.
  double max_prediction_deviation = 0.03;
  // A worker thread grabs and processes the frames (see above); for a camera on a SteadyClock.
  // Must be false for a simulated camera on a stepped world's clock (it would step the world from
  // a second thread).
  bool asynchronous = false;
  // Asynchronous mode: the longest wait for one frame (ms, > 0); a longer gap is counted as a
  // camera error ("no frame") and the wait starts again.
  int grab_timeout_ms = 500;
  // Empty when usable, otherwise every bad field and its value.
  std::string Validate() const;
};

struct ImageLegFeatureCounters {
  uint64_t frames = 0;            // frames processed
  uint64_t camera_errors = 0;     // Grab() errors other than "no frame yet"
  uint64_t fk_failures = 0;       // frames predicted from the previous pose (FK did not converge)
  uint64_t legs_not_visible = 0;  // sum over frames of legs not measured (rejected included)
  uint64_t legs_rejected = 0;     // measured but too far from the prediction (gated out)
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

  bool Poll(common::Duration now, LegFeatureFrame* frame) override;

  // Copies (thread-safe in both modes): the observations of the last processed frame (the reasons
  // for the legs not seen), the platform pose its predictions were made at (nominal FK of the
  // measured q), the last camera or format error ("" when none so far; it names the camera and
  // the cause), and the counters.
  std::array<vision::hexapod::LegObservation, kHexapodLegs> last_observations() const;
  Eigen::Isometry3d last_predicted_pose() const;
  std::string last_error() const;
  ImageLegFeatureCounters counters() const;

 private:
  // Grabs one frame (waiting at most `timeout`) and, when there is one, extracts the legs with the
  // leg lengths q into *frame. Returns true when *frame holds a new frame.
  bool GrabAndProcess(std::chrono::milliseconds timeout, const Vector6d& q, LegFeatureFrame* frame);
  // Asynchronous mode, on the worker: waits for the first q, then GrabAndProcess.
  bool Produce(LegFeatureFrame* frame, const std::atomic<bool>& stopping);
  void RecordError(const std::string& text, uint64_t ImageLegFeatureCounters::*counter);

  hal::Camera* camera_;
  const vision::CameraModel* camera_model_;
  robots::HexapodModel model_;
  Eigen::Isometry3d X_CB_;
  LegLengthProvider leg_lengths_;
  ImageLegFeatureOptions options_;
  common::Duration period_{0};
  bool have_frame_ = false;
  common::Duration last_capture_{0};
  // Used by the thread that processes frames only.
  robots::HexapodData fk_data_;
  hal::Image image_;
  std::vector<uint8_t> grey_;  // converted pixels when the camera does not deliver mono8
  std::unique_ptr<vision::hexapod::LegEdgeWorkspace> workspace_;
  uint64_t sequence_ = 0;

  mutable std::mutex mutex_;  // guards what follows
  Eigen::Isometry3d X_BP_;
  std::array<vision::hexapod::LegObservation, kHexapodLegs> observations_{};
  std::string last_error_;
  ImageLegFeatureCounters counters_;
  // Asynchronous mode: the newest q from Poll() for the worker (control/common/latest_frame.h).
  Vector6d q_latest_ = Vector6d::Zero();
  bool have_q_ = false;
  std::condition_variable q_ready_;
  std::unique_ptr<LatestFrameWorker<LegFeatureFrame>> worker_;  // last: uses everything above
};

}  // namespace kinevis::control
