#pragma once

// The drive supervision of a fixed-rate control loop over a hal::DriveBus (issue 17), one copy
// for every loop (the DIAMOND's two RS485 drives, the hexapod's six CiA 402 drives on CAN):
//  - selecting the cyclic mode, first target = where the drive is (or zero velocity);
//  - the bus cycle: a cycle in which not every drive answered in time (Errc::kTimeout, no drive
//    in fault) is tolerated max_consecutive_cycle_timeouts times in a row; any other error, more
//    late cycles in a row, or a drive in fault is a fault, described naming the drive (its axis,
//    its name, link or device, the error code and the drive's own last error text);
//  - the one safe stop: StopAction on every drive that can take it, then bus cycles at the loop's
//    period until every drive is at rest (at most settle_timeout_s), because a drive receives its
//    controlword only with the cycles;
//  - paced settling cycles for a controlled stop (the loop brakes, the supervisor cycles).
//
// Nothing here throws or allocates once constructed, except the fault texts (built once, when the
// run ends).

#include <cstdint>
#include <functional>
#include <string>
#include <system_error>
#include <vector>

#include "common/clock.h"
#include "control/common/loop.h"
#include "hal/drive/motor_drive.h"

namespace kinevis::control {

struct DriveSupervisorOptions {
  double cycle_period_s = 0.001;  // the loop's period, paces the stop and settle cycles; > 0
  int max_consecutive_cycle_timeouts = 3;  // >= 0
  StopAction stop_action = StopAction::kQuickStop;
  // How the messages name drive i: "<axis_name> <i + first_axis_number> drive <drive name>",
  // e.g. "joint 1 drive arm1", "leg 0 drive leg0".
  std::string axis_name = "joint";
  int first_axis_number = 1;
  double rest_velocity = 1e-6;    // |velocity| (drive units/s) below which a drive is at rest, > 0
  double settle_timeout_s = 1.0;  // longest SafeStop() / Settle(), > 0
  std::string Validate() const;   // empty when usable, else every bad field and its value
};

// One bus cycle as the supervisor judged it.
struct SupervisedCycle {
  std::error_code error;  // what DriveBus::Cycle() returned
  bool late = false;      // not every drive answered in time (tolerated so far)
  bool fault = false;     // the run must stop: see FaultMessage()
};

class DriveSupervisor {
 public:
  // bus: expected_drives drives, configured and enabled by the caller. clock: the bus's clock.
  // Both must outlive the supervisor. Throws std::invalid_argument naming every problem (null
  // pointers, invalid options, the wrong number of drives).
  DriveSupervisor(hal::DriveBus* bus, common::Clock* clock, size_t expected_drives,
                  DriveSupervisorOptions options = {});

  const std::vector<hal::MotorDrive*>& drives() const { return drives_; }
  size_t size() const { return drives_.size(); }
  const DriveSupervisorOptions& options() const { return options_; }
  // "joint 1 drive arm1".
  std::string AxisName(size_t i) const;

  // Selects `mode` on every drive, each first given its current position (position modes) or
  // zero velocity (velocity and torque modes) as the target. Empty when every drive took it,
  // else "<axis> drive <name>: cannot select <mode>: <error>" of the first that did not, and
  // *failed_drive (when not null) its index.
  std::string SelectMode(hal::DriveMode mode, int* failed_drive = nullptr);

  // One bus cycle (sends the targets set since the last one, reads the drives).
  SupervisedCycle Cycle();
  // After a cycle with fault, at t s into the run: "drive fault at t = <t> s (bus <name>:
  // <error>[, N cycles in a row without every drive's answer]): <DriveFaults()>".
  // *faulted_drive (when not null): the first drive in fault, or -1.
  std::string FaultMessage(const SupervisedCycle& cycle, double t,
                           int* faulted_drive = nullptr) const;
  // Every drive in fault or with a fault source: "joint 1 drive arm1: link lost, error code
  // 0x8130 (<the drive's last error text>)", separated by "; ". *first (when not null): the index
  // of the first such drive, or -1.
  std::string DriveFaults(int* first = nullptr) const;

  // Late cycles since construction or the last ResetCounts() (a loop calls it when a run starts).
  uint64_t cycle_timeouts() const { return cycle_timeouts_; }
  void ResetCounts() {
    cycle_timeouts_ = 0;
    consecutive_timeouts_ = 0;
  }
  int consecutive_timeouts() const { return consecutive_timeouts_; }
  bool AllAtRest() const;
  // Drive positions / velocities (drive units) into out[0..size()).
  void Positions(double* out) const;

  // The safe state: options().stop_action on every drive that can take it (quick stop when
  // active; disable unless in fault or unconfigured), then bus cycles at the period until every
  // drive is at rest (at most settle_timeout_s; cycle errors do not end it, the stop is what
  // matters now). Empty, or "<name>: safe state not confirmed (<error>)" for each drive that
  // refused, separated by "; ".
  std::string SafeStop();

  // A controlled stop, drives still enabled: before each cycle `step()` sets the next targets and
  // returns false when it has finished; cycles at the period until then, until a cycle fails, or
  // settle_timeout_s. Returns false when a cycle failed.
  bool Settle(const std::function<bool()>& step);

 private:
  hal::DriveBus* bus_;
  common::Clock* clock_;
  DriveSupervisorOptions options_;
  std::vector<hal::MotorDrive*> drives_;
  uint64_t cycle_timeouts_ = 0;
  int consecutive_timeouts_ = 0;
};

}  // namespace kinevis::control
