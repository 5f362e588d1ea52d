#pragma once

// The hexapod leg-direction servo loop (issue 6, seed 002 §V-B): runs on a common::Clock at the
// drive cycle over a hal::DriveBus of six drives (leg j = drive j of bus.drives()), takes leg
// directions from a LegFeatureSource at the camera's own rate, runs the LegServo law once per
// camera frame and holds the last leg rates between frames, and commands them in cyclic
// synchronous velocity (CSV) or, by integrating them, cyclic synchronous position (CSP).
//
// The cycles are paced on a DeadlineGrid and the drives supervised by a DriveSupervisor
// (control/common/): the same pacing, fault detection and safe stop as the DIAMOND's loop.
//
// Safety, checked every cycle (never by exceptions):
//  - drive fault or heartbeat loss (DriveBus::Cycle() error, or a drive in fault): every drive
//    is quick-stopped (or disabled), the run ends with kDriveFault naming the drive and cause;
//    a cycle in which not every drive answered in time (Errc::kTimeout, the drives are not in
//    fault) is tolerated up to max_consecutive_cycle_timeouts times in a row;
//  - stroke: a leg whose predicted stopping point (current length + commanded rate over two
//    cycles + braking distance at stop_deceleration) would leave
//    [leg_length_min + stroke_margin, leg_length_max − stroke_margin] stops everything: zero
//    rates are commanded, the run ends with kLimit naming the leg. Nothing beyond the limits is
//    ever commanded;
//  - velocity: leg rates are scaled uniformly so that the fastest is at most max_leg_velocity
//    (the direction of motion is kept);
//  - following (CSP): the integrated set-points never lead the readings by more than
//    max_command_lead. When the drives cannot follow (their own velocity limit, a loaded host) a
//    set-point integrating the law's rates would run away from the legs — windup — and the legs
//    would overshoot once they catch up. Held at the readings plus the lead, CSP stays a rate
//    command on where the legs are (the DIAMOND's loop does the same);
//  - a leg lost from the image (fewer than min_visible_legs visible) holds: zero rates for all
//    legs until the legs are seen again (counted and reported);
//  - a stale camera (no frame for stale_camera_timeout_s) holds likewise;
//  - the law refusing (too few legs, rank < 6, bad input) holds likewise;
//  - convergence: ‖e‖ <= convergence_threshold (or, when set, the remaining displacement below
//    convergence_translation and convergence_rotation) for convergence_dwell_s -> kCompleted;
//  - timeout_s -> kTimeout.
// Every ending commands zero rates and runs cycles until the legs are at rest (at most 1 s).
//
// Logs: per-cycle samples kept in memory (reserved before the run; no I/O in the loop) and
// written after the run as CSV (columns documented in control/README.md) and a convergence plot
// PNG (error norm vs time, log scale).

#include <Eigen/Geometry>
#include <cstdint>
#include <functional>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "common/clock.h"
#include "control/common/drive_supervisor.h"
#include "control/common/fixed_rate.h"
#include "control/common/loop.h"
#include "control/hexapod/leg_servo.h"
#include "hal/drive/motor_drive.h"
#include "robots/hexapod/hexapod_model.h"

namespace kinevis::control {

// One camera frame's features.
struct LegFeatureFrame {
  common::Duration timestamp{0};  // when the image was taken (loop clock)
  LegDirections u_C{};            // unit leg directions in C (valid where visible)
  LegMask visible{};
  uint64_t sequence = 0;
};

// Where the loop gets leg directions: image extraction (the lead plugs it in) or ground truth.
class LegFeatureSource {
 public:
  virtual ~LegFeatureSource() = default;
  // Called once per loop cycle at `now`; returns true and fills *frame when a new camera frame
  // is available (its features), false when none is due yet. Must not block for long.
  virtual bool Poll(common::Duration now, LegFeatureFrame* frame) = 0;
};

struct GroundTruthFeatureOptions {
  double fps = 50.0;             // camera frame rate, > 0
  double noise_sigma = 0.0;      // per component of u (rad, before renormalising), >= 0
  uint32_t seed = 1;             // of the noise
  std::string Validate() const;  // empty when usable, else every bad field and its value
};

// Ground truth: u_j = R_CB u_j(X_BP) of the true model at the pose `pose()` returns at the
// moment of the frame (e.g. [&world] { return world.plant().X_BP; }), plus optional noise.
// Legs can be hidden (visible = false) and the camera paused (no frames: a stale camera).
class GroundTruthLegFeatureSource final : public LegFeatureSource {
 public:
  using PoseProvider = std::function<Eigen::Isometry3d()>;
  // Throws std::invalid_argument with options.Validate()'s message or for an empty provider.
  GroundTruthLegFeatureSource(robots::HexapodModel true_model, const Eigen::Isometry3d& X_CB,
                              PoseProvider pose, GroundTruthFeatureOptions options = {});
  bool Poll(common::Duration now, LegFeatureFrame* frame) override;
  void SetLegHidden(int leg, bool hidden);
  void SetPaused(bool paused);
  uint64_t frames() const { return sequence_; }

 private:
  robots::HexapodModel model_;
  Eigen::Isometry3d X_CB_;
  PoseProvider pose_;
  GroundTruthFeatureOptions options_;
  std::mt19937 rng_;
  std::normal_distribution<double> noise_{0.0, 1.0};
  robots::HexapodData data_;
  LegMask hidden_{};
  bool paused_ = false;
  bool started_ = false;
  common::Duration next_frame_{0};
  uint64_t sequence_ = 0;
};

enum class DriveCommandMode { kVelocity, kPosition };  // CSV, or CSP by integrating q̇

struct ServoLoopOptions {
  double cycle_period_s = 0.004;  // drive cycle, > 0
  DriveCommandMode command_mode = DriveCommandMode::kVelocity;
  double max_leg_velocity = 0.05;  // m/s, > 0
  double stroke_margin = 0.001;    // m, >= 0, kept from both stroke ends
  double stop_deceleration = 0.5;  // m/s^2, > 0: braking assumed for stopping distances
  // CSP: how far (m, > 0) the integrated set-point may lead a leg's reading (anti-windup).
  // 5 mm is 25 cycles at 5 cm/s: never reached by drives that follow, reached at once by one
  // that cannot.
  double max_command_lead = 0.005;
  int min_visible_legs = 6;             // 3..6; fewer visible -> hold
  double stale_camera_timeout_s = 0.1;  // no frame for this long -> hold, > 0
  double convergence_threshold = 1e-4;  // on ‖e‖, > 0
  // Also converged when the law's remaining displacement (LegServoResult::
  // remaining_displacement at the platform centre) stays below both of these: for desired
  // features the true robot cannot reach exactly (u* from a model pose), where ‖e‖ stops at a
  // floor above zero while the platform has arrived. 0 = off (the default). m and rad, >= 0.
  double convergence_translation = 0.0;
  double convergence_rotation = 0.0;
  // Time constant (s, >= 0; 0 = none) of the first-order low-pass over the frames through which
  // the remaining displacement is judged (one frame's carries the features' noise).
  double convergence_filter_s = 0.5;
  double convergence_dwell_s = 0.2;  // >= 0
  double timeout_s = 10.0;           // > 0
  // Cycles in a row whose answers were late (DriveBus::Cycle() == Errc::kTimeout, no drive in
  // fault) before the run ends as a drive fault, >= 0. A single late TPDO on a busy bus or a USB
  // adapter is not worth stopping the machine; a drive that stays silent is (and its heartbeat
  // supervision faults it anyway).
  int max_consecutive_cycle_timeouts = 3;
  StopAction stop_action = StopAction::kQuickStop;
  std::string Validate() const;  // empty when usable, else every bad field and its value
};

enum class ServoLoopState {
  kRunning,
  kHoldLegLost,
  kHoldStaleCamera,
  kHoldLaw,
  kWaitFirstFrame,
  kStopping,
};
const char* ToString(ServoLoopState state);

// How a run ended (control/common/loop.h): kCompleted when converged, kLimit at a stroke limit,
// kDriveFault, kTimeout, kNotStarted (a drive refused the mode).
using ServoLoopOutcome = LoopOutcome;
// The servo's words for an outcome: "converged" (kCompleted), "stroke limit" (kLimit), else
// ToString(outcome).
const char* ServoOutcomeName(LoopOutcome outcome);

// One loop cycle, as logged.
struct ServoLoopSample {
  double time_s = 0;      // since the start of the run
  double error_norm = 0;  // ‖e‖ of the last frame (NaN before the first)
  // |δp| (m) and |δθ| (rad) of the remaining displacement (LegServoResult), low-passed over the
  // frames (convergence_filter_s).
  double remaining_translation = 0;
  double remaining_rotation = 0;
  LegDirections u_C{};  // last measured directions
  LegMask visible{};
  Vector6d q = Vector6d::Zero();      // leg lengths (m) = q0 + drive positions
  Vector6d q_dot = Vector6d::Zero();  // commanded leg rates (m/s), after the safety layer
  // Commanded leg lengths (m): q0 + the CSP set-points; in CSV the readings q.
  Vector6d q_command = Vector6d::Zero();
  ServoLoopState state = ServoLoopState::kWaitFirstFrame;
  bool new_frame = false;
};

struct ServoLoopReport {
  ServoLoopOutcome outcome = ServoLoopOutcome::kNotStarted;
  std::string message;     // what ended the run, naming the drive or leg and the cause
  int faulted_drive = -1;  // index in bus.drives() of the drive that faulted first
  int stroke_leg = -1;     // leg that would have left its stroke
  double duration_s = 0;
  double final_error_norm = 0;
  double time_to_threshold_s = -1;  // first frame meeting the convergence test; -1 if none
  bool converged_by_error = true;   // kConverged by ‖e‖ (else by the remaining displacement)
  uint64_t cycles = 0, frames = 0, law_steps = 0;
  uint64_t hold_cycles_leg_lost = 0, hold_cycles_stale_camera = 0, hold_cycles_law = 0;
  uint64_t velocity_scaled_cycles = 0;
  uint64_t lead_limited_cycles = 0;  // CSP set-points held at the readings + max_command_lead
  uint64_t cycle_timeouts = 0;       // cycles in which not every drive answered in time
  LegMask legs_lost{};               // legs that were hidden at least once
  Vector6d final_q = Vector6d::Zero();
  PeriodStatistics timing;  // of the cycles: periods, lateness, bus I/O and compute time
  std::vector<ServoLoopSample> samples;  // every cycle
};

// The leg-direction servo as a law of the loop skeleton (control/common/loop.h): each cycle
// Step() polls the feature source; on a camera frame it runs the LegServo law and judges the
// frame (legs visible, the law's answer, convergence), between frames it holds the last answer.
// It returns a LawState per cycle like the DIAMOND's laws: kRunning with the leg rates, kHold
// (waiting for the first frame, legs lost, the law refusing, a stale camera: zero rates), kDone
// when the convergence test has held for convergence_dwell_s. The loop applies the safety layer.
// The options are the ServoLoopOptions' (min_visible_legs, stale_camera_timeout_s and the
// convergence fields).
struct LegLawOutput {
  LawState state = LawState::kHold;
  Vector6d q_dot = Vector6d::Zero();                        // m/s, zero unless kRunning
  ServoLoopState detail = ServoLoopState::kWaitFirstFrame;  // which running or hold state
  bool new_frame = false;
  double error_norm = 0;  // ‖e‖ of the last frame (NaN before the first)
  double remaining_translation = 0, remaining_rotation = 0;  // low-passed (ServoLoopSample)
  LegDirections u_C{};                                       // of the last frame
  LegMask visible{};
  bool converged_by_error = true;  // kDone by ‖e‖, else by the remaining displacement
};

class LegDirectionLaw {
 public:
  // source and law must outlive this; options as validated by ServoLoopOptions::Validate().
  LegDirectionLaw(LegFeatureSource* source, LegServo* law, const ServoLoopOptions& options);
  // A new run starting at `now`: resets the law and the convergence test.
  void Start(common::Duration now);
  // One cycle at `now` (t s into the run) with the leg lengths q (m).
  const LegLawOutput& Step(common::Duration now, double t, const Vector6d& q);

  uint64_t frames() const { return frames_; }
  uint64_t law_steps() const { return law_steps_; }
  const LegMask& legs_lost() const { return legs_lost_; }              // hidden at least once
  double time_to_threshold_s() const { return time_to_threshold_s_; }  // -1: never met

 private:
  LegFeatureSource* source_;
  LegServo* law_;
  ServoLoopOptions options_;
  LegLawOutput out_;
  LegFeatureFrame frame_;
  Vector6d q_dot_ = Vector6d::Zero();  // the last frame's rates, held between frames
  bool have_frame_ = false;
  common::Duration last_frame_time_{0};
  double converged_since_ = -1;
  Vector6d filtered_displacement_ = Vector6d::Zero();
  bool have_displacement_ = false;
  common::Duration last_displacement_time_{0};
  uint64_t frames_ = 0, law_steps_ = 0;
  LegMask legs_lost_{};
  double time_to_threshold_s_ = -1;
};

class ServoLoop {
 public:
  // bus: six drives, leg j = bus->drives()[j], configured and enabled by the caller. clock: the
  // bus's clock (SleepUntil paces the cycles). model: q0 and the strokes (the nominal model the
  // host knows). law: with its desired features set. All must outlive the loop. Throws
  // std::invalid_argument for invalid options, a bus without six drives or null pointers.
  ServoLoop(hal::DriveBus* bus, common::Clock* clock, LegFeatureSource* source,
            const robots::HexapodModel& model, LegServo* law, ServoLoopOptions options = {});

  // Runs until an outcome. observer (may be empty) sees every sample as it is made (tests
  // inject faults from it). Does not throw for run-time faults: they are the report.
  ServoLoopReport Run(const std::function<void(const ServoLoopSample&)>& observer = {});

 private:
  // Commands the rates: CSV directly; CSP integrated into *s_target, held within
  // max_command_lead of the readings s. Returns true when the lead limit acted.
  bool SetRates(const Vector6d& q_dot, const Vector6d& s, Vector6d* s_target);
  void StopAndSettle(Vector6d* s_target);

  hal::DriveBus* bus_;
  common::Clock* clock_;
  LegFeatureSource* source_;
  robots::HexapodModel model_;
  LegServo* law_;
  ServoLoopOptions options_;
  std::vector<hal::MotorDrive*> drives_;
  std::unique_ptr<LegDirectionLaw> step_law_;
  std::unique_ptr<DriveSupervisor> supervisor_;
};

// CSV of the samples (control/README.md). Throws std::runtime_error naming the file when it
// cannot be written.
void WriteServoLogCsv(const std::string& path, const std::vector<ServoLoopSample>& samples);
// Convergence plot: ‖e‖ vs time, log scale, with the threshold as a second series. Throws
// std::runtime_error naming the file when it cannot be written.
void WriteConvergencePlot(const std::string& path, const std::vector<ServoLoopSample>& samples,
                          double threshold, const std::string& title);

}  // namespace kinevis::control
