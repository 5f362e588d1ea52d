#pragma once

// The device side of a CiA 402 drive, independent of the transport: the power state machine
// driven by the controlword, the operation modes, a motion model, following-error and limit
// supervision, fault reaction and quick stop ramps, and a plant hook so that sim/ can couple a
// robot model. Both drive simulators (CANopen and RS485/Modbus) wrap one of these.
//
// Units are the drive's: counts, counts/s, counts/s^2, per mille of rated torque. Thread-safe:
// every public method takes the device's mutex; the plant hook runs under it (it must not call
// back into the device), the fault callback after it has been released.
//
// Behaviour, in the terms of CiA 402-2:
//  - Power-up: Not ready to switch on; the first Step() performs transition 1 (-> Switch on
//    disabled). Controlword commands take effect at once in SetControlword() (the transitions
//    of kCia402Transitions); Step() performs the automatic ones (1, 12 after a completed quick
//    stop, 13/14 fault reaction).
//  - Operation enabled: the axis follows the set-point of the mode of operation (0x6061 follows
//    0x6060 at once; default mode 8, CSP, to match the default PDO mapping of controlword and
//    target position). In every other state the power stage holds nothing: the axis brakes to
//    standstill with the acceleration limit (a holding brake), and with a plant hook the motion
//    model is re-synchronised to the plant's actual values.
//  - CSP: each SetTargetPosition() is a new set-point; the drive interpolates linearly from where
//    its position demand is to the new set-point over the time between the last two set-points
//    (at most 0.1 s; the first set-point, or one after a longer pause, is a step), with that
//    slope as velocity feed-forward. Stepped once per set-point (once per SYNC) with the cycle
//    time, the axis thus tracks a ramp without lag. After enabling operation (or switching to
//    CSP) the position demand is the target position: write the actual position to the target
//    before enabling, or the step shows as a following error, as on a real drive.
//  - PP: a rising edge of controlword bit 4 (new set-point) latches the target position and sets
//    statusword bit 12 (set-point acknowledge) until bit 4 falls; moves are absolute and change
//    immediately. Halt (bit 8) in PP/PV/PT stops with the profile acceleration.
//  - PV, CSV: target velocity; CST, PT: target torque (motion_model.h).
//  - Quick stop (option code 0x605A): 0 disables at once; 1 and 5 stop with the profile
//    acceleration, 2 and 6 (and 3, 4, 7, 8) with the acceleration limit (the quick stop ramp);
//    1..4 then go to Switch on disabled, 5..8 stay in Quick stop active (Enable operation resumes).
//  - Fault reaction: stops with the quick stop ramp and enters Fault after
//    fault_reaction_time_s; the fault callback then reports the error code (0x603F). A fault
//    reset (rising edge of bit 7) clears it and calls the callback with 0.
//  - Supervision in Operation enabled: following error (position demand - actual, PP and CSP)
//    beyond the window (0x6065) -> fault 0x8611; a position limit reached in a velocity or torque
//    mode -> fault 0x8612 (in the position modes targets are clamped to the limits instead, with
//    statusword bit 11 "internal limit active").
//  - Statusword: the state bits of Cia402StatuswordBits(), plus bit 9 remote (always), bit 10
//    target reached, bit 11 internal limit active, bit 12 (PP set-point acknowledge, CSx "drive
//    follows the command value", PV speed zero) and bit 13 following error.

#include <cstdint>
#include <functional>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "hal/drive/cia402.h"
#include "hal/mock/motion_model.h"

namespace kinevis::hal {

// A plant coupled to the drive: called every Step() with the commanded motion; returns the
// actual position/velocity/torque the drive then reports (e.g. a leg of a simulated hexapod that
// cannot follow because the platform is at a singularity). Default: the motion model is the plant.
struct PlantFeedback {
  int32_t position = 0;  // counts
  int32_t velocity = 0;  // counts/s
  int16_t torque = 0;    // per mille
};
using PlantHook = std::function<PlantFeedback(const AxisState& commanded, double dt_s)>;

class Cia402Device {
 public:
  struct Options {
    MotionLimits limits;                      // see motion_model.h
    uint32_t supported_modes = 0x38D;         // 0x6502: bit (mode - 1) for modes 1, 3, 4, 8, 9, 10
    int16_t quick_stop_option_code = 2;       // 0x605A: 2 = quick stop ramp, then disabled
    double fault_reaction_time_s = 0.01;      // Fault reaction active -> Fault
    uint32_t following_error_window = 10000;  // counts; 0x6065; 0xFFFFFFFF disables
  };

  // Everything a transport maps to objects or registers, read under one lock.
  struct Snapshot {
    Cia402State state = Cia402State::kNotReadyToSwitchOn;
    uint16_t statusword = 0;              // 0x6041
    uint16_t controlword = 0;             // 0x6040 (last written)
    int8_t mode = 0;                      // 0x6060 (last accepted)
    int8_t mode_display = 0;              // 0x6061
    int32_t position = 0;                 // 0x6064
    int32_t velocity = 0;                 // 0x606C
    int16_t torque = 0;                   // 0x6077
    int32_t following_error = 0;          // 0x60F4
    uint16_t error_code = 0;              // 0x603F
    int32_t target_position = 0;          // 0x607A
    int32_t target_velocity = 0;          // 0x60FF
    int16_t target_torque = 0;            // 0x6071
    uint32_t profile_velocity = 0;        // 0x6081
    uint32_t profile_acceleration = 0;    // 0x6083
    uint32_t max_velocity = 0;            // 0x607F
    int32_t position_limit_min = 0;       // 0x607D.1
    int32_t position_limit_max = 0;       // 0x607D.2
    int16_t quick_stop_option_code = 0;   // 0x605A
    uint32_t following_error_window = 0;  // 0x6065
    uint32_t supported_modes = 0;         // 0x6502
  };

  // Throws ConfigError naming every bad option (ValidateOptions()).
  explicit Cia402Device(Options options);
  // Empty when the options are usable; otherwise every problem with its value, "; "-separated.
  // Bits of supported_modes for modes the simulator does not implement (homing, interpolated
  // position, ...) are not an error: they are left out of 0x6502.
  static std::string ValidateOptions(const Options& options);

  // Host side inputs (from PDOs / registers / SDO).
  void SetControlword(uint16_t cw);
  // Returns false (and ignores it) for a mode not in supported_modes.
  bool SetModeOfOperation(int8_t mode);
  void SetTargetPosition(int32_t counts);
  void SetTargetVelocity(int32_t counts_per_s);
  void SetTargetTorque(int16_t per_mille);
  void SetProfile(uint32_t velocity, uint32_t acceleration);  // PP/PV ramps
  // Ignored when min > max (the transports refuse such values before they get here).
  void SetPositionLimits(int32_t min, int32_t max);
  // 0x605A; returns false (and ignores it) outside 0..8.
  bool SetQuickStopOptionCode(int16_t code);
  // 0x6065; 0xFFFFFFFF disables the supervision.
  void SetFollowingErrorWindow(uint32_t counts);
  // 0x607F (the velocity limit of every mode); returns false (and ignores it) for 0.
  bool SetMaxVelocity(uint32_t counts_per_s);

  // Advances the drive by dt (s): state-machine automatic transitions, motion, supervision.
  // In cyclic modes the caller steps on every SYNC / cycle with the cycle time.
  void Step(double dt_s);

  // Power-on reset (NMT reset node): Not ready to switch on, fault cleared, set-points, mode and
  // parameters back to the options. The axis keeps its position (the motor has not moved); the
  // plant hook and fault callback stay.
  void Reset();

  // Outputs.
  uint16_t statusword() const;
  Cia402State state() const;
  int8_t mode_display() const;
  int32_t position() const;
  int32_t velocity() const;
  int16_t torque() const;
  int32_t following_error() const;
  uint16_t error_code() const;  // 0x603F; 0 when no fault
  Snapshot snapshot() const;
  // The commanded motion (the motion model's state).
  AxisState commanded() const;

  // Fault injection and coupling.
  void RaiseFault(uint16_t error_code);  // -> Fault reaction active -> Fault
  void SetPlantHook(PlantHook hook);
  // Called when the device enters Fault (with the error code): the CAN sim sends an EMCY.
  // Called with 0 when a fault reset clears the fault. Runs on the thread that caused the
  // change (Step(), SetControlword()), after the device's mutex has been released.
  void SetFaultCallback(std::function<void(uint16_t)> callback);

 private:
  // All below require mutex_ held.
  void ApplyCommandLocked(Cia402Command command);
  void EnterLocked(Cia402State next);
  void FaultLocked(uint16_t error_code);
  void StepMotionLocked(double dt, double t_end);
  void UpdateOutputsLocked(double dt);
  void ResetModeStateLocked();
  void ResetLocked();
  double CspDemandLocked(double t) const;
  double CspFeedForwardLocked(double t) const;
  uint16_t StatuswordLocked() const;
  std::optional<DriveMode> ModeLocked() const;
  void TakeCallbacksLocked(std::vector<uint16_t>* out);
  void FireCallbacks(const std::vector<uint16_t>& codes);

  mutable std::mutex mutex_;
  Options options_;
  AxisMotionModel model_;
  Cia402State state_ = Cia402State::kNotReadyToSwitchOn;
  uint16_t controlword_ = 0;
  int8_t mode_ = 8;
  int32_t target_position_ = 0;
  int32_t target_velocity_ = 0;
  int16_t target_torque_ = 0;
  uint32_t profile_velocity_ = 0;
  uint32_t profile_acceleration_ = 0;
  int32_t limit_min_ = 0;
  int32_t limit_max_ = 0;
  int16_t quick_stop_option_code_ = 2;
  uint32_t following_error_window_ = 0;
  uint16_t error_code_ = 0;
  double fault_reaction_elapsed_s_ = 0;

  // Device time (sum of the steps), for the CSP interpolator.
  double time_s_ = 0;
  double last_setpoint_time_s_ = -1;
  double csp_from_ = 0;
  double csp_to_ = 0;
  double csp_start_s_ = 0;
  double csp_interval_s_ = 0;  // 0: no interpolation (a step)
  double position_demand_ = 0;

  int32_t pp_target_ = 0;
  bool setpoint_acknowledge_ = false;

  // Actual values (plant or model) after the last step.
  int32_t position_actual_ = 0;
  int32_t velocity_actual_ = 0;
  int16_t torque_actual_ = 0;
  int32_t following_error_ = 0;
  bool following_error_flag_ = false;
  bool limit_active_ = false;

  PlantHook plant_;
  std::function<void(uint16_t)> fault_callback_;
  std::vector<uint16_t> pending_callbacks_;
};

}  // namespace kinevis::hal
