#pragma once

// CiA 402 (IEC 61800-7-201) drive profile: the power state machine, controlword commands,
// statusword states and operation modes, as pure functions shared by the host drivers (CANopen,
// RS485/Modbus) and the drive simulators. No I/O here.
//
// The transition table (kCia402Transitions) is the specification's Figure "state machine" with its
// numbered transitions 0..16; tests walk every row.

#include <array>
#include <cstdint>
#include <optional>

namespace kinevis::hal {

// Object dictionary indices of the CiA 402 objects kinevis uses.
namespace cia402 {
inline constexpr uint16_t kErrorCode = 0x603F;                // u16, last fault's error code
inline constexpr uint16_t kControlword = 0x6040;              // u16
inline constexpr uint16_t kStatusword = 0x6041;               // u16
inline constexpr uint16_t kQuickStopOptionCode = 0x605A;      // i16
inline constexpr uint16_t kModesOfOperation = 0x6060;         // i8
inline constexpr uint16_t kModesOfOperationDisplay = 0x6061;  // i8
inline constexpr uint16_t kPositionActualValue = 0x6064;      // i32, counts
inline constexpr uint16_t kFollowingErrorWindow = 0x6065;     // u32, counts
inline constexpr uint16_t kVelocityActualValue = 0x606C;      // i32, counts/s
inline constexpr uint16_t kTargetTorque = 0x6071;             // i16, per mille of rated torque
inline constexpr uint16_t kTorqueActualValue = 0x6077;        // i16, per mille of rated torque
inline constexpr uint16_t kTargetPosition = 0x607A;           // i32, counts
inline constexpr uint16_t kSoftwarePositionLimit = 0x607D;    // i32[2], counts (sub 1 min, 2 max)
inline constexpr uint16_t kMaxProfileVelocity = 0x607F;       // u32, counts/s
inline constexpr uint16_t kProfileVelocity = 0x6081;          // u32, counts/s
inline constexpr uint16_t kProfileAcceleration = 0x6083;      // u32, counts/s^2
inline constexpr uint16_t kTargetVelocity = 0x60FF;           // i32, counts/s
inline constexpr uint16_t kSupportedDriveModes = 0x6502;      // u32, bit (mode - 1) per mode

// Statusword bits.
inline constexpr uint16_t kSwReadyToSwitchOn = 1u << 0;
inline constexpr uint16_t kSwSwitchedOn = 1u << 1;
inline constexpr uint16_t kSwOperationEnabled = 1u << 2;
inline constexpr uint16_t kSwFault = 1u << 3;
inline constexpr uint16_t kSwVoltageEnabled = 1u << 4;
inline constexpr uint16_t kSwQuickStop = 1u << 5;  // 0 = quick stop active
inline constexpr uint16_t kSwSwitchOnDisabled = 1u << 6;
inline constexpr uint16_t kSwWarning = 1u << 7;
inline constexpr uint16_t kSwRemote = 1u << 9;
inline constexpr uint16_t kSwTargetReached = 1u << 10;
inline constexpr uint16_t kSwInternalLimit = 1u << 11;
inline constexpr uint16_t kSwOpModeSpecific12 = 1u << 12;  // PP: set-point ack; CSx: following
inline constexpr uint16_t kSwFollowingError = 1u << 13;    // PP/CSP: following error

// Controlword bits.
inline constexpr uint16_t kCwSwitchOn = 1u << 0;
inline constexpr uint16_t kCwEnableVoltage = 1u << 1;
inline constexpr uint16_t kCwQuickStop = 1u << 2;  // 0 = quick stop
inline constexpr uint16_t kCwEnableOperation = 1u << 3;
inline constexpr uint16_t kCwNewSetPoint = 1u << 4;           // PP
inline constexpr uint16_t kCwChangeSetImmediately = 1u << 5;  // PP
inline constexpr uint16_t kCwFaultReset = 1u << 7;
inline constexpr uint16_t kCwHalt = 1u << 8;
}  // namespace cia402

enum class Cia402State : uint8_t {
  kNotReadyToSwitchOn,
  kSwitchOnDisabled,
  kReadyToSwitchOn,
  kSwitchedOn,
  kOperationEnabled,
  kQuickStopActive,
  kFaultReactionActive,
  kFault,
};
const char* ToString(Cia402State state);

enum class Cia402Command : uint8_t {
  kNone,             // the controlword asks for no state change
  kShutdown,         // 0x06: xxxx.x110
  kSwitchOn,         // 0x07: xxxx.0111 (also "disable operation" from Operation enabled)
  kEnableOperation,  // 0x0F: xxxx.1111
  kDisableVoltage,   // 0x00: xxxx.xx0x
  kQuickStop,        // 0x02: xxxx.x01x
  kFaultReset,       // 0x80: rising edge of bit 7
};
const char* ToString(Cia402Command command);

// The controlword that issues `command` (fault reset: 0x80; the caller sends a word with bit 7
// clear first so that the device sees the rising edge). kNone gives 0x00.
uint16_t Cia402Controlword(Cia402Command command);

// The command a device reads from `controlword`, given the previous one (for the fault-reset
// edge). Decoding order as in the specification: fault reset edge, disable voltage, quick stop,
// shutdown, switch on, enable operation.
Cia402Command DecodeCia402Controlword(uint16_t controlword, uint16_t previous_controlword);

// The state a statusword reports (the mask/value pairs of the specification); nullopt for a
// statusword matching none (a broken drive or a corrupted frame).
std::optional<Cia402State> DecodeCia402Statusword(uint16_t statusword);

// The state bits of the statusword a device in `state` reports (bits 0-3, 5, 6, plus 4 "voltage
// enabled" where power is on). Other bits (warning, remote, target reached, ...) are the caller's.
uint16_t Cia402StatuswordBits(Cia402State state);

// One row of the transition table: in state `from`, `command` leads to `to` (transition number
// `number` of the specification). Transitions triggered by the device itself (0, 1, 13, 14, and
// 12 after a completed quick stop) have command kNone and are listed with automatic = true.
struct Cia402Transition {
  int number;
  Cia402State from;
  Cia402Command command;
  Cia402State to;
  bool automatic;
};
extern const std::array<Cia402Transition, 22> kCia402Transitions;

// Device side: the state after `command` in `state`, or `state` when the command does not apply
// there. `quick_stop_to_disabled`: quick stop option code 0..4 (the drive leaves Quick stop
// active for Switch on disabled once stopped; transition 12) versus 5..8 (it stays, and Enable
// operation resumes: transition 16).
Cia402State Cia402ApplyCommand(Cia402State state, Cia402Command command,
                               bool quick_stop_to_disabled = true);

// Host side: the next command that moves a drive from `current` towards `target`
// (kOperationEnabled, kSwitchOnDisabled, kSwitchedOn, kReadyToSwitchOn or kQuickStopActive);
// kNone when it is there or must wait (Not ready, Fault reaction active). From kFault the answer
// is kFaultReset (when `target` is not kFault).
Cia402Command Cia402NextCommand(Cia402State current, Cia402State target);

// Modes of operation (object 0x6060).
enum class DriveMode : int8_t {
  kProfilePosition = 1,
  kProfileVelocity = 3,
  kProfileTorque = 4,
  kCyclicSynchronousPosition = 8,
  kCyclicSynchronousVelocity = 9,
  kCyclicSynchronousTorque = 10,
};
const char* ToString(DriveMode mode);
// nullopt for a value that is not one of the six modes above.
std::optional<DriveMode> DriveModeFromValue(int value);
bool IsPositionMode(DriveMode m);
bool IsVelocityMode(DriveMode m);
bool IsTorqueMode(DriveMode m);
bool IsCyclicMode(DriveMode m);

}  // namespace kinevis::hal
