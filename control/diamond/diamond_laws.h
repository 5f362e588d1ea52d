#pragma once

// DIAMOND control laws (issue 8, seed 001 §V-C): the task-space PD on (φ, γ) that follows the
// validation lines, and the ViSP image-based visual servo of the tool marker. Both are
// DiamondLaw objects run once per cycle by DiamondControlLoop (diamond_loop.h), which owns the
// drives, the safety layer and the logs; a law only turns joint readings (and camera frames) into
// a joint velocity command.
//
// Frames (robots/diamond/diamond_model.h, camera_model.h): O the RCM frame, C the camera frame;
// X_CO is the pose of O in C. q joint readings (rad), (φ, γ) task coordinates (rad), p_O_T the
// tool point (marker) in O (m). Pixels in the OpenCV convention; (x, y) normalised image
// coordinates x = X/Z, y = Y/Z of a point in C.
//
// No ViSP in this header (vpServo lives in the .cc).

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cmath>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include "common/clock.h"
#include "control/common/loop.h"
#include "robots/diamond/diamond_model.h"
#include "vision/camera/camera_model.h"
#include "vision/diamond/marker_detector.h"

namespace kinevis::control {

// ---------------------------------------------------------------------------------------------
// What a law sees and returns each cycle.

struct DiamondCycleInput {
  common::Duration now{0};                      // loop clock
  double t = 0.0;                               // s since the start of the run
  double dt = 0.0;                              // nominal cycle period (s)
  Eigen::Vector2d q = Eigen::Vector2d::Zero();  // joint readings (rad)
};

// The law's answer each cycle (control/common/loop.h): kRunning (q_dot is the command), kHold
// (q_dot zero: waiting for a frame, a frame without the marker), kDone (the line is followed and
// settled, or the servo converged), kStop (the loop stops the robot and ends with `reason`).
using DiamondLawState = LawState;

struct DiamondLawOutput {
  DiamondLawState state = DiamondLawState::kHold;
  Eigen::Vector2d q_dot = Eigen::Vector2d::Zero();  // rad/s, zero unless kRunning
  const char* reason = "";  // static text for kStop (and kHold), e.g. "marker lost"
  // For the logs (NaN when the law has none): (φ, γ) of the readings by the law's model and
  // the reference; the marker's pixel, its target and whether this cycle brought a frame.
  Eigen::Vector2d task = Eigen::Vector2d::Constant(NAN);
  Eigen::Vector2d task_reference = Eigen::Vector2d::Constant(NAN);
  Eigen::Vector2d pixel = Eigen::Vector2d::Constant(NAN);
  Eigen::Vector2d pixel_reference = Eigen::Vector2d::Constant(NAN);
  bool new_frame = false;
  bool marker_found = false;
};

class DiamondLaw {
 public:
  virtual ~DiamondLaw() = default;
  // A new run starts at joint readings q (rad). Resets the law's state.
  virtual void Start(const Eigen::Vector2d& q, common::Duration now) = 0;
  // One cycle. Never throws, never blocks; no heap allocation for the PD law.
  virtual DiamondLawOutput Step(const DiamondCycleInput& input) = 0;
};

// ---------------------------------------------------------------------------------------------
// Validation lines (seed 001 §V-C, Table III).
//
// The seed names two lines by task coordinates: vertical φ = π/2, γ from π/6 to π/2 (we run from
// 32° to 83°: the workspace box is [30°, 85°], γ = π/2 needs the limbs on top of each other, and
// a line ending on the box's edge would trip the stopping-distance check), and horizontal
// γ = π/4, φ from π/3 to 2π/3. It measures them in the image of a camera looking down the base axis
// (the top view), so two readings of "line" are offered:
//   kTaskLine: straight in (φ, γ): φ const is a meridian, γ const a parallel of the sphere;
//   kTopViewLine: straight in the top view, the orthogonal projection of the tool point on the
//     base plane (x_O, y_O): p_xy = R sin γ (cos φ, sin φ) with the law's model R; the end
//     points are given as (φ, γ). The vertical line is then the same meridian; the horizontal
//     one is the chord y_O = const through (π/2, π/4), with γ rising towards its ends.
// Progress along the line is the quintic s(τ) = 10τ³ − 15τ⁴ + 6τ⁵, τ = t/duration (zero
// velocity and acceleration at both ends).
enum class DiamondLineKind { kTaskLine, kTopViewLine };
const char* ToString(DiamondLineKind kind);

struct DiamondLine {
  DiamondLineKind kind = DiamondLineKind::kTaskLine;
  Eigen::Vector2d from{M_PI / 2, 32 * M_PI / 180};  // (φ, γ) (rad)
  Eigen::Vector2d to{M_PI / 2, 83 * M_PI / 180};
  double duration_s = 3.0;  // > 0

  // Seed 001 §V-C case 1 (vertical) and case 2 (horizontal), as above.
  static DiamondLine SeedVertical(DiamondLineKind kind = DiamondLineKind::kTaskLine);
  static DiamondLine SeedHorizontal(DiamondLineKind kind = DiamondLineKind::kTaskLine);
  // Empty when usable: finite end points, duration > 0.
  std::string Validate() const;
};

// The reference at time t (s; clamped to [0, duration]) for a model of radius `radius` (m, used
// by kTopViewLine): (φ, γ) and its rate. Returns false (outputs untouched) when a top-view point
// lies outside the sphere's projection (|p_xy| > R).
bool DiamondLineReference(const DiamondLine& line, double radius, double t, Eigen::Vector2d* task,
                          Eigen::Vector2d* task_rate);

// ---------------------------------------------------------------------------------------------
// Task-space PD (seed 001 §V-C "simple PD in task space").
//
// The seed's PD outputs motor torques through a force distribution; our drives run their own
// position loops (CSP), so the law is the kinematic form of the same PD: with the model's
// forward kinematics x = (φ, γ)(q) of the readings and the reference x*(t), ẋ*(t),
//   e = x* − x,   u = ẋ* + Kp e + Kd ė_f,   q̇ = J(q)⁻¹ u,
// J = robots::TaskJacobian (d(φ, γ)/dq), ė_f the first-order low-passed (derivative_filter_s)
// finite difference of e over the cycles. The model is the one the controller believes (a priori
// or identified): a wrong model is what the straightness validation exposes.
struct DiamondPdOptions {
  double kp = 30.0;                    // 1/s, > 0
  double kd = 0.0;                     // dimensionless (s · 1/s), >= 0
  double derivative_filter_s = 0.005;  // s, >= 0
  // Settled: after the line's duration, |e| (rad, both axes) below settle_tolerance for
  // settle_dwell_s -> kDone; not settled within settle_timeout_s after the end -> kStop.
  double settle_tolerance = 1e-4;
  double settle_dwell_s = 0.05;
  double settle_timeout_s = 1.0;
  // σ_max/σ_min of TaskJacobian above this -> kStop ("near a singularity"), > 1.
  double max_condition = 1e3;
  std::string Validate() const;  // empty when usable, else every bad field and its value
};

class DiamondTaskPdLaw final : public DiamondLaw {
 public:
  // Throws std::invalid_argument naming every bad option, model field or line field.
  DiamondTaskPdLaw(const robots::DiamondModel& model, const DiamondLine& line,
                   DiamondPdOptions options = {});
  void Start(const Eigen::Vector2d& q, common::Duration now) override;
  DiamondLawOutput Step(const DiamondCycleInput& input) override;

  const robots::DiamondModel& model() const { return model_; }
  const DiamondLine& line() const { return line_; }

 private:
  robots::DiamondModel model_;
  DiamondLine line_;
  DiamondPdOptions options_;
  robots::DiamondData data_;
  Eigen::Vector2d e_prev_ = Eigen::Vector2d::Zero();
  Eigen::Vector2d e_rate_ = Eigen::Vector2d::Zero();
  bool have_prev_ = false;
  double settled_since_ = -1.0;
};

// ---------------------------------------------------------------------------------------------
// Image Jacobian of the marker with respect to the joints.
//
// The marker T is fixed to the tool, p_C = X_CO p_O_T(q), so
//   d(x, y)/dq = J_n(p_C) · R_CO · dp_O_T/dq,   J_n = [[1/Z, 0, −x/Z], [0, 1/Z, −y/Z]]
// (the image Jacobian of a point moving in front of a fixed camera, = −(translational part of
// ViSP's point interaction matrix), times robots::ToolPointJacobian). In pixels the camera
// model's own Jacobian ∂pixel/∂p_C replaces J_n (distortion included).
// data: ForwardKinematics(model, q) with data.valid. Return false when T is not in front of the
// camera (Z <= 0) or the camera model cannot project it; outputs untouched then.
bool MarkerNormalizedJacobian(const Eigen::Isometry3d& X_CO, const robots::DiamondModel& model,
                              const robots::DiamondData& data, Eigen::Vector2d* xy,
                              Eigen::Matrix2d* J);
bool MarkerPixelJacobian(const vision::CameraModel& camera, const Eigen::Isometry3d& X_CO,
                         const robots::DiamondModel& model, const robots::DiamondData& data,
                         Eigen::Vector2d* pixel, Eigen::Matrix2d* J);

// ---------------------------------------------------------------------------------------------
// Where the visual servo gets the marker: one camera frame's detection.
struct MarkerFrame {
  common::Duration timestamp{0};  // when the image was taken (loop clock)
  bool found = false;
  Eigen::Vector2d pixel = Eigen::Vector2d::Zero();  // detected marker centre (px), when found
  double confidence = 0.0;
  vision::MarkerStatus status = vision::MarkerStatus::kNotFound;
  uint64_t sequence = 0;
};

class MarkerFeatureSource {
 public:
  virtual ~MarkerFeatureSource() = default;
  // Called once per loop cycle; true with *frame filled when a new camera frame was processed
  // (found or not), false when none is due. Must not block for long.
  virtual bool Poll(common::Duration now, MarkerFrame* frame) = 0;
};

// Images from a grabber, through the MarkerDetector: the search window follows the last
// detection (the whole image until the first and after a loss).
class DetectedMarkerSource final : public MarkerFeatureSource {
 public:
  // Returns true and a view of a new image (valid until the next call) when a frame is due at
  // `now`, with its capture time; false otherwise.
  using Grabber = std::function<bool(common::Duration now, vision::ImageView8* image,
                                     common::Duration* timestamp)>;
  // Throws std::invalid_argument for an empty grabber or bad detector options.
  DetectedMarkerSource(Grabber grabber, vision::MarkerDetectorOptions options = {});
  bool Poll(common::Duration now, MarkerFrame* frame) override;
  uint64_t frames() const { return sequence_; }

 private:
  Grabber grabber_;
  vision::MarkerDetector detector_;
  bool have_last_ = false;
  Eigen::Vector2d last_ = Eigen::Vector2d::Zero();
  uint64_t sequence_ = 0;
};

// ---------------------------------------------------------------------------------------------
// Image-based visual servo of the marker (ViSP).
//
// Feature: the marker's normalised image point s = (x, y) (vpFeaturePoint), from the detected
// pixel back-projected through the camera model (distortion removed); s* from the target pixel
// likewise. Depth Z of the current point from the model: p_C = X_CO p_O_T(q). vpServo
// EYETOHAND_L_cVf_fJe with f = O: cVf the twist transform of X_CO, fJe = [dp_O_T/dq; 0₃ₓ₂] (the
// tool point's velocity; a point feature sees nothing of the tool's rotation about it), so
// ViSP's task Jacobian is −L_s cVf fJe = MarkerNormalizedJacobian and
//   q̇ = −λ (d s/dq)⁺ (s − s*)
// (CURRENT interaction matrix, pseudo-inverse). The law runs at each camera frame and holds its
// q̇ between frames. The model (robot and camera pose) only shapes the Jacobian: the loop is
// closed on the image, so the a-priori model converges too (it is only slower or faster).
struct DiamondIbvsOptions {
  double gain = 4.0;  // λ (1/s), > 0
  // Converged when |pixel − target| (px) stays below this for convergence_dwell_s -> kDone.
  // Must exceed the detector's error floor, or the law chatters on it without ever dwelling: on
  // the worlds' 4× supersampled renders the detected point jumps by the renderer's 1/4-px edge
  // quantisation (up to 0.18 px; marker_detector_test.cc), so 0.3 px.
  double convergence_px = 0.3;
  double convergence_dwell_s = 0.3;
  // A frame without the marker holds (zero q̇); this many consecutive ones -> kStop ("marker
  // lost"), >= 1. No frame for stale_camera_timeout_s -> kStop ("camera stale"), > 0.
  int max_lost_frames = 3;
  double stale_camera_timeout_s = 0.25;
  // The first frame must come within this, > 0 (else kStop "no camera frame").
  double first_frame_timeout_s = 1.0;
  // σ_max/σ_min of d s/dq above this -> kStop ("image Jacobian singular"), > 1.
  double max_condition = 1e3;
  std::string Validate() const;  // empty when usable, else every bad field and its value
};

class DiamondMarkerServo final : public DiamondLaw {
 public:
  // camera and source must outlive the law. X_CO: pose of O in C (the camera placement, from
  // calibration or the deployment). Throws std::invalid_argument naming every bad option or
  // model field, a non-finite X_CO or a null source.
  DiamondMarkerServo(const robots::DiamondModel& model, const vision::CameraModel& camera,
                     const Eigen::Isometry3d& X_CO, MarkerFeatureSource* source,
                     DiamondIbvsOptions options = {});
  ~DiamondMarkerServo() override;
  DiamondMarkerServo(const DiamondMarkerServo&) = delete;
  DiamondMarkerServo& operator=(const DiamondMarkerServo&) = delete;

  // Target marker pixel. Throws std::invalid_argument when it is not finite, not on the image
  // or cannot be back-projected.
  void SetTarget(const Eigen::Vector2d& pixel);
  const Eigen::Vector2d& target() const { return target_px_; }

  void Start(const Eigen::Vector2d& q, common::Duration now) override;
  DiamondLawOutput Step(const DiamondCycleInput& input) override;

  // The law for one frame, outside the loop (tests, bench): q̇ from the detected pixel at joint
  // readings q. Returns false when it cannot (invalid FK, not in front, singular).
  bool Compute(const Eigen::Vector2d& q, const Eigen::Vector2d& pixel, Eigen::Vector2d* q_dot,
               Eigen::Matrix2d* task_jacobian = nullptr);

 private:
  struct Impl;
  robots::DiamondModel model_;
  const vision::CameraModel& camera_;
  Eigen::Isometry3d X_CO_;
  MarkerFeatureSource* source_;
  DiamondIbvsOptions options_;
  Eigen::Vector2d target_px_ = Eigen::Vector2d::Constant(NAN);
  Eigen::Vector2d target_xy_ = Eigen::Vector2d::Zero();
  bool has_target_ = false;
  std::unique_ptr<Impl> impl_;
  // Run state.
  common::Duration start_{0};
  common::Duration last_frame_{0};
  bool have_frame_ = false;
  int lost_frames_ = 0;
  Eigen::Vector2d q_dot_ = Eigen::Vector2d::Zero();
  Eigen::Vector2d last_pixel_ = Eigen::Vector2d::Constant(NAN);
  double converged_since_ = -1.0;
  robots::DiamondData data_;
};

}  // namespace kinevis::control
