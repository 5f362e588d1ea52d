#pragma once

// The DIAMOND's fixed-rate control loop (issue 8, seed 001 §V): one cycle per period on a
// common::Clock over a hal::DriveBus of the two RS485 drives (joint i = bus.drives()[i]; Modbus RTU
// on the real robot and on DiamondWorld's pty), a DiamondLaw (diamond_laws.h) turning the joint
// readings (and camera frames) into joint velocities, which the loop integrates into cyclic
// synchronous position (CSP) set-points after its safety layer.
//
// One cycle: sleep until the deadline → bus Cycle() (sends last cycle's set-points, reads the
// positions) → law → safety → set-points for the next Cycle(). The deadlines are a fixed grid
// (start + k·period); a cycle that wakes more than one period late re-synchronises the grid
// (counted as missed deadlines) instead of bursting.
//
// Safety, checked every cycle (never by exceptions):
//  - drive fault or lost link (Cycle() error, a drive in fault, or more than
//    max_consecutive_cycle_timeouts late answers in a row): both drives to the safe state
//    (stop_action), the run ends with kDriveFault naming the drive, the error code and its text;
//  - the law's kStop (marker lost, camera stale, singular, not settled): zero velocity, both
//    drives to the safe state, kLawStop with the law's reason;
//  - limits: the commanded joints, and where they would stop (two cycles at the commanded rate
//    and braking at stop_deceleration), must be within the model's θ limits less theta_margin,
//    its limb separation limits less separation_margin, and map by the model's forward
//    kinematics into its (φ, γ) workspace box; otherwise nothing beyond is commanded, the robot
//    holds and is put in the safe state, kLimit names the condition (DiamondReachability);
//  - the RCM: the commanded joints' forward kinematics must close (both limbs meet the tool axis:
//    |w_i · u − cos β| <= 1e-9): a commanded motion is only ever a motion of the joints of a
//    closed spherical mechanism, so the tool point stays on the sphere about the RCM; the largest
//    residual is reported (rcm_closure_max);
//  - rates: joint velocities are scaled uniformly to max_joint_velocity and their change per
//    cycle to max_joint_acceleration (the direction of motion is kept).
//  - following: the set-points never lead the readings by more than max_command_lead. The
//    set-points integrate the law's rates; when the drives cannot follow (a slow line, a loaded
//    host, a drive at its own limits) a law acting on the readings would keep integrating into
//    set-points running away from the joints — windup, which shows as a growing oscillation of
//    the joints at the velocity limit. Held at the readings plus the lead, the loop stays a
//    rate command on where the joints are.
//  The law's kDone ends the run with kCompleted and the drives holding position, enabled.
//
// Timing statistics (PeriodStatistics, control/common/fixed_rate.h; the deadline grid is its
// DeadlineGrid): from the loop clock's time at each wake-up: the periods
// between consecutive wake-ups, the lateness of each wake-up past its deadline, the time Cycle()
// took (the two Modbus round trips) and the time the law and safety took. With a SteadyClock
// these are real; with a stepped world the periods are exact by construction and only the
// counts mean anything.
//
// Logs: one DiamondLoopSample per cycle, kept in memory (reserved before the run; no I/O or
// allocation in the cycle), written after the run as CSV (WriteDiamondLogCsv; columns in
// docs/diamond-control.md).

#include <Eigen/Core>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "common/clock.h"
#include "control/common/drive_supervisor.h"
#include "control/common/fixed_rate.h"  // PeriodStatistics, DeadlineGrid
#include "control/common/loop.h"
#include "control/diamond/diamond_laws.h"
#include "hal/drive/motor_drive.h"
#include "robots/diamond/diamond_model.h"

namespace kinevis::control {

struct DiamondLoopOptions {
  double cycle_period_s = 0.001;           // target 1 kHz; > 0, <= 0.1
  double max_joint_velocity = 1.0;         // rad/s, > 0
  double max_joint_acceleration = 20.0;    // rad/s², > 0
  double stop_deceleration = 10.0;         // rad/s² assumed for stopping distances, > 0
  double max_command_lead = 0.02;          // rad, set-points ahead of the readings, > 0
  double theta_margin = 0.01;              // rad kept from θ limits, >= 0
  double separation_margin = 0.01;         // rad kept from the separation limits, >= 0
  int max_consecutive_cycle_timeouts = 3;  // >= 0
  double timeout_s = 20.0;                 // > 0: the run ends with kTimeout
  StopAction stop_action = StopAction::kQuickStop;
  bool keep_samples = true;      // false: no per-cycle log (long real-time runs)
  std::string Validate() const;  // empty when usable, else every bad field and its value
};

// How a run ended (control/common/loop.h): kLimit is a joint, separation or workspace limit or
// the RCM closure; kLawStop the law's kStop (marker lost, camera stale, singular, not settled).
using DiamondLoopOutcome = LoopOutcome;

struct DiamondLoopSample {
  double time_s = 0.0;
  double period_s = 0.0;  // since the previous wake-up (0 for the first)
  double lateness_s = 0.0;
  double io_s = 0.0;
  Eigen::Vector2d q = Eigen::Vector2d::Zero();          // readings (rad)
  Eigen::Vector2d q_command = Eigen::Vector2d::Zero();  // set-points (rad)
  Eigen::Vector2d q_dot = Eigen::Vector2d::Zero();      // commanded rates after safety (rad/s)
  DiamondLawOutput law;                                 // task, references, pixels, state
};

struct DiamondLoopReport {
  DiamondLoopOutcome outcome = DiamondLoopOutcome::kNotStarted;
  std::string message;  // what ended the run, naming the drive / condition and the cause
  int faulted_drive = -1;
  double duration_s = 0.0;
  uint64_t cycles = 0;
  uint64_t cycle_timeouts = 0;
  uint64_t velocity_scaled_cycles = 0;
  uint64_t acceleration_limited_cycles = 0;
  uint64_t lead_limited_cycles = 0;  // set-points held at the readings + max_command_lead
  uint64_t hold_cycles = 0;
  double rcm_closure_max = 0.0;  // largest |w_i · u − cos β| of the commanded joints
  PeriodStatistics timing;
  Eigen::Vector2d final_q = Eigen::Vector2d::Zero();
  std::vector<DiamondLoopSample> samples;
};

class DiamondControlLoop {
 public:
  // bus: two drives (joint i = bus->drives()[i]), configured and enabled by the caller, with
  // SI scaling to the joint readings q (rad). clock: the bus's clock (it paces the cycles).
  // model: the limits and the forward kinematics for the safety checks (the controller's model).
  // All pointers must outlive the loop. Throws std::invalid_argument for invalid options, a bus
  // without two drives, an invalid model or null pointers, naming each.
  DiamondControlLoop(hal::DriveBus* bus, common::Clock* clock, const robots::DiamondModel& model,
                     DiamondLoopOptions options = {});

  // Runs `law` until an outcome. observer (may be empty) sees each sample as it is made (tests
  // inject faults from it). Run-time faults are the report, never exceptions.
  DiamondLoopReport Run(DiamondLaw* law,
                        const std::function<void(const DiamondLoopSample&)>& observer = {});

  const DiamondLoopOptions& options() const { return options_; }

 private:
  bool SetCommand(const Eigen::Vector2d& q_command);
  void HoldAndSettle(Eigen::Vector2d* q_command);
  void SafeState(DiamondLoopReport* report);
  // Empty when q (and its forward kinematics) is inside the margins; otherwise why not.
  std::string CheckLimits(const Eigen::Vector2d& q, robots::DiamondData* data) const;

  hal::DriveBus* bus_;
  common::Clock* clock_;
  robots::DiamondModel model_;
  DiamondLoopOptions options_;
  std::vector<hal::MotorDrive*> drives_;
  std::unique_ptr<DriveSupervisor> supervisor_;
};

// CSV of the samples (docs/diamond-control.md). Throws std::runtime_error naming the file when
// it cannot be written.
void WriteDiamondLogCsv(const std::string& path, const std::vector<DiamondLoopSample>& samples);

// Straightness (seed 001 §V-C, Table III): the RMS distance of 2-D points from their total
// least-squares line (m for points in m). 0 for fewer than 3 points.
double Straightness(const std::vector<Eigen::Vector2d>& points);

}  // namespace kinevis::control
