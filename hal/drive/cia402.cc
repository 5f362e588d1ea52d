#include "hal/drive/cia402.h"

namespace kinevis::hal {

using S = Cia402State;
using C = Cia402Command;

// IEC 61800-7-201 / CiA 402-2, state machine of the power drive system. Transition 0 (start ->
// Not ready to switch on) happens at power-up and is not listed. Transition 13 (fault -> Fault
// reaction active) can happen in every state but the two fault states; it is listed once, from
// Operation enabled, and the simulators apply it from any state.
const std::array<Cia402Transition, 22> kCia402Transitions = {{
    {1, S::kNotReadyToSwitchOn, C::kNone, S::kSwitchOnDisabled, true},
    {2, S::kSwitchOnDisabled, C::kShutdown, S::kReadyToSwitchOn, false},
    {3, S::kReadyToSwitchOn, C::kSwitchOn, S::kSwitchedOn, false},
    // "Switch on + enable operation" (0x0F) in Ready to switch on: transitions 3 and 4 at once.
    {3, S::kReadyToSwitchOn, C::kEnableOperation, S::kOperationEnabled, false},
    {4, S::kSwitchedOn, C::kEnableOperation, S::kOperationEnabled, false},
    {5, S::kOperationEnabled, C::kSwitchOn, S::kSwitchedOn, false},  // disable operation
    {6, S::kSwitchedOn, C::kShutdown, S::kReadyToSwitchOn, false},
    {7, S::kReadyToSwitchOn, C::kDisableVoltage, S::kSwitchOnDisabled, false},
    {7, S::kReadyToSwitchOn, C::kQuickStop, S::kSwitchOnDisabled, false},
    {8, S::kOperationEnabled, C::kShutdown, S::kReadyToSwitchOn, false},
    {9, S::kOperationEnabled, C::kDisableVoltage, S::kSwitchOnDisabled, false},
    {10, S::kSwitchedOn, C::kDisableVoltage, S::kSwitchOnDisabled, false},
    {10, S::kSwitchedOn, C::kQuickStop, S::kSwitchOnDisabled, false},
    {11, S::kOperationEnabled, C::kQuickStop, S::kQuickStopActive, false},
    {12, S::kQuickStopActive, C::kDisableVoltage, S::kSwitchOnDisabled, false},
    // Quick stop completed with quick stop option code 0..4.
    {12, S::kQuickStopActive, C::kNone, S::kSwitchOnDisabled, true},
    {13, S::kOperationEnabled, C::kNone, S::kFaultReactionActive, true},
    {14, S::kFaultReactionActive, C::kNone, S::kFault, true},
    {15, S::kFault, C::kFaultReset, S::kSwitchOnDisabled, false},
    // Quick stop option code 5..8 only: the drive stays in Quick stop active and may resume.
    {16, S::kQuickStopActive, C::kEnableOperation, S::kOperationEnabled, false},
    // Disable voltage and quick stop in Switch on disabled: no change (listed so that the table
    // says what a device does with every command a host may send there).
    {2, S::kSwitchOnDisabled, C::kDisableVoltage, S::kSwitchOnDisabled, false},
    {2, S::kSwitchOnDisabled, C::kQuickStop, S::kSwitchOnDisabled, false},
}};

const char* ToString(Cia402State state) {
  switch (state) {
    case S::kNotReadyToSwitchOn:
      return "Not ready to switch on";
    case S::kSwitchOnDisabled:
      return "Switch on disabled";
    case S::kReadyToSwitchOn:
      return "Ready to switch on";
    case S::kSwitchedOn:
      return "Switched on";
    case S::kOperationEnabled:
      return "Operation enabled";
    case S::kQuickStopActive:
      return "Quick stop active";
    case S::kFaultReactionActive:
      return "Fault reaction active";
    case S::kFault:
      return "Fault";
  }
  return "?";
}

const char* ToString(Cia402Command command) {
  switch (command) {
    case C::kNone:
      return "none";
    case C::kShutdown:
      return "shutdown";
    case C::kSwitchOn:
      return "switch on";
    case C::kEnableOperation:
      return "enable operation";
    case C::kDisableVoltage:
      return "disable voltage";
    case C::kQuickStop:
      return "quick stop";
    case C::kFaultReset:
      return "fault reset";
  }
  return "?";
}

uint16_t Cia402Controlword(Cia402Command command) {
  switch (command) {
    case C::kShutdown:
      return 0x06;
    case C::kSwitchOn:
      return 0x07;
    case C::kEnableOperation:
      return 0x0F;
    case C::kDisableVoltage:
      return 0x00;
    case C::kQuickStop:
      return 0x02;
    case C::kFaultReset:
      return 0x80;
    case C::kNone:
      return 0x00;
  }
  return 0x00;
}

Cia402Command DecodeCia402Controlword(uint16_t cw, uint16_t previous) {
  if ((cw & cia402::kCwFaultReset) != 0 && (previous & cia402::kCwFaultReset) == 0) {
    return C::kFaultReset;
  }
  if ((cw & 0x02) == 0x00) return C::kDisableVoltage;   // xxxx.xx0x
  if ((cw & 0x06) == 0x02) return C::kQuickStop;        // xxxx.x01x
  if ((cw & 0x07) == 0x06) return C::kShutdown;         // xxxx.x110
  if ((cw & 0x0F) == 0x07) return C::kSwitchOn;         // xxxx.0111
  if ((cw & 0x0F) == 0x0F) return C::kEnableOperation;  // xxxx.1111
  return C::kNone;
}

std::optional<Cia402State> DecodeCia402Statusword(uint16_t sw) {
  if ((sw & 0x4F) == 0x00) return S::kNotReadyToSwitchOn;
  if ((sw & 0x4F) == 0x40) return S::kSwitchOnDisabled;
  if ((sw & 0x6F) == 0x21) return S::kReadyToSwitchOn;
  if ((sw & 0x6F) == 0x23) return S::kSwitchedOn;
  if ((sw & 0x6F) == 0x27) return S::kOperationEnabled;
  if ((sw & 0x6F) == 0x07) return S::kQuickStopActive;
  if ((sw & 0x4F) == 0x0F) return S::kFaultReactionActive;
  if ((sw & 0x4F) == 0x08) return S::kFault;
  return std::nullopt;
}

uint16_t Cia402StatuswordBits(Cia402State state) {
  using namespace cia402;
  switch (state) {
    case S::kNotReadyToSwitchOn:
      return 0x00;
    case S::kSwitchOnDisabled:
      return kSwSwitchOnDisabled;
    case S::kReadyToSwitchOn:
      return kSwQuickStop | kSwReadyToSwitchOn;
    case S::kSwitchedOn:
      return kSwQuickStop | kSwVoltageEnabled | kSwSwitchedOn | kSwReadyToSwitchOn;
    case S::kOperationEnabled:
      return kSwQuickStop | kSwVoltageEnabled | kSwOperationEnabled | kSwSwitchedOn |
             kSwReadyToSwitchOn;
    case S::kQuickStopActive:
      return kSwVoltageEnabled | kSwOperationEnabled | kSwSwitchedOn | kSwReadyToSwitchOn;
    case S::kFaultReactionActive:
      return kSwVoltageEnabled | kSwFault | kSwOperationEnabled | kSwSwitchedOn |
             kSwReadyToSwitchOn;
    case S::kFault:
      return kSwFault;
  }
  return 0;
}

Cia402State Cia402ApplyCommand(Cia402State state, Cia402Command command,
                               bool quick_stop_to_disabled) {
  if (command == C::kNone) return state;
  for (const Cia402Transition& t : kCia402Transitions) {
    if (t.automatic || t.from != state || t.command != command) continue;
    if (t.number == 16 && quick_stop_to_disabled) continue;
    return t.to;
  }
  return state;
}

Cia402Command Cia402NextCommand(Cia402State current, Cia402State target) {
  if (current == target) return C::kNone;
  switch (current) {
    case S::kNotReadyToSwitchOn:
    case S::kFaultReactionActive:
      return C::kNone;  // the drive moves on by itself
    case S::kFault:
      return target == S::kFault ? C::kNone : C::kFaultReset;
    case S::kQuickStopActive:
      // The host cannot know the quick stop option code: leave through Switch on disabled.
      return C::kDisableVoltage;
    default:
      break;
  }
  switch (target) {
    case S::kSwitchOnDisabled:
      return C::kDisableVoltage;
    case S::kReadyToSwitchOn:
      return C::kShutdown;
    case S::kSwitchedOn:
      return current == S::kSwitchOnDisabled ? C::kShutdown : C::kSwitchOn;
    case S::kOperationEnabled:
      if (current == S::kSwitchOnDisabled) return C::kShutdown;
      if (current == S::kReadyToSwitchOn) return C::kSwitchOn;
      return C::kEnableOperation;
    case S::kQuickStopActive:
      return current == S::kOperationEnabled ? C::kQuickStop : C::kNone;
    default:
      return C::kNone;
  }
}

const char* ToString(DriveMode mode) {
  switch (mode) {
    case DriveMode::kProfilePosition:
      return "profile position (1)";
    case DriveMode::kProfileVelocity:
      return "profile velocity (3)";
    case DriveMode::kProfileTorque:
      return "profile torque (4)";
    case DriveMode::kCyclicSynchronousPosition:
      return "cyclic synchronous position (8)";
    case DriveMode::kCyclicSynchronousVelocity:
      return "cyclic synchronous velocity (9)";
    case DriveMode::kCyclicSynchronousTorque:
      return "cyclic synchronous torque (10)";
  }
  return "?";
}

std::optional<DriveMode> DriveModeFromValue(int value) {
  switch (value) {
    case 1:
    case 3:
    case 4:
    case 8:
    case 9:
    case 10:
      return static_cast<DriveMode>(value);
    default:
      return std::nullopt;
  }
}

bool IsPositionMode(DriveMode m) {
  return m == DriveMode::kProfilePosition || m == DriveMode::kCyclicSynchronousPosition;
}
bool IsVelocityMode(DriveMode m) {
  return m == DriveMode::kProfileVelocity || m == DriveMode::kCyclicSynchronousVelocity;
}
bool IsTorqueMode(DriveMode m) {
  return m == DriveMode::kProfileTorque || m == DriveMode::kCyclicSynchronousTorque;
}
bool IsCyclicMode(DriveMode m) { return static_cast<int>(m) >= 8; }

}  // namespace kinevis::hal
