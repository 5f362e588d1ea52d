#pragma once

// The words every fixed-rate control loop shares (issue 17): how a law answers each step, what
// the loop does to the drives when it stops, and how a run ended. The DIAMOND loop
// (control/diamond/diamond_loop.h) and the hexapod servo loop (control/hexapod/servo_loop.h) use
// these, and their drives go through one DriveSupervisor (drive_supervisor.h).
//
// The law's state per step follows ros2_control's controller update(), which returns whether the
// step succeeded: here the answer is one of four, because a visual servo has two ways of not
// moving (holding for a frame, and refusing to go on) and one of finishing.

namespace kinevis::control {

// What a law returns each step.
enum class LawState {
  kRunning,  // its command is the command
  kHold,     // hold still (zero rate): waiting for a frame, a frame without the features
  kDone,     // finished: the line is followed and settled, the servo converged
  kStop,     // cannot go on: the loop stops the robot and ends with the law's reason
};
const char* ToString(LawState state);  // "running", "hold", "done", "stop"

// What the loop does to every drive when it stops on a fault, a limit or the law's kStop: a quick
// stop (the drive decelerates on its quick-stop ramp, then acts on its option code) or disable
// voltage at once (the drive stops applying torque; a brake, if any, holds the axis).
enum class StopAction { kQuickStop, kDisable };
const char* ToString(StopAction action);  // "quick stop", "disable"

// How a run ended.
enum class LoopOutcome {
  kCompleted,   // the law finished: the line followed, the servo converged
  kDriveFault,  // a drive fault or a lost link (the drives are in the safe state)
  kLawStop,     // the law stopped (features lost, camera stale, singular, not settled)
  kLimit,       // a joint, stroke, separation or workspace limit, or the RCM closure
  kTimeout,
  kNotStarted,  // the drives' mode could not be selected
};
const char* ToString(LoopOutcome outcome);

}  // namespace kinevis::control
