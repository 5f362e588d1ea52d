#pragma once

// The Modbus register map of the 5-DOF weld-repair robot controller (seed 004: joints θ1, θ2
// rotary, pz3 prismatic, θ4, θ5 rotary), the single source that the host driver
// (hal/weld/weld_robot_client.h) and the simulator (hal/mock/weld_robot_sim.h) both use.
// docs/weld-robot-modbus.md is the prose version of this file, with the rules of the protocol.
//
// Conventions:
//  - Addresses are protocol (PDU) addresses, 0-based.
//  - A 32-bit value occupies two consecutive registers, HIGH word first (at the lower address),
//    then the low word ("big-endian word order", mbpoll's -B). Signed values are two's
//    complement.
//  - Units on the wire (register units) are fixed integers: joint angles in µrad, pz3 in µm,
//    joint speeds in µrad/s and µm/s, durations in ms, current in 0.1 A, voltage in 0.1 V, wire
//    feed speed in 0.1 mm/s. kJointUnitsPerSi etc. convert SI values to register units; nothing
//    but the driver edge and the simulator's register edge should use them.
//  - Joint angles are the controller's joint values; the D-H offsets of seed 004 (θ1 + 0.1097°,
//    θ2 + 89.602°) belong to the kinematic model (robots/), not to this map.
//
// Input registers (function 0x04, read-only):
//    0        identity magic kIdentityMagic
//    1        map version kMapVersion
//    2        joint count (5)
//    3        trajectory buffer capacity, segments
//    4        longest segment duration accepted, ms
//    5        largest welding current set-point, 0.1 A
//    6        largest arc voltage set-point, 0.1 V
//    7        largest wire feed speed set-point, 0.1 mm/s
//    8-9      serial number (u32)
//   10-39     joint limits, 6 registers per joint j at 10 + 6 j: minimum (i32), maximum (i32),
//             largest speed (u32)
//  100        motion state (MotionState)
//  101        alarm code (Alarm; 0 = none)
//  102        buffer level: segments accepted and not yet completed, the executing one included
//  103        buffer free: capacity - level
//  104        arc enable (0/1): ARC ON was commanded and not revoked
//  105        arc on (0/1): the arc burns now (see the interlock below)
//  106-107    last accepted sequence number (u32)
//  108-109    last completed sequence number (u32)
//  110-111    sequence number of the segment that raised the alarm (u32; 0 if none)
//  112-121    actual joints (5 x i32, µrad / µm)
//  122-124    weld set-points in force: current (0.1 A), voltage (0.1 V), wire feed (0.1 mm/s)
//
// Holding registers (functions 0x03, 0x06, 0x10):
//  200        command (Command), written with 0x06 or 0x10; reads back 0 once executed
//  210-212    weld set-points: current (0.1 A), voltage (0.1 V), wire feed (0.1 mm/s)
//  300-313    trajectory segment, written in ONE 0x10 request of exactly 14 registers:
//             300-301 sequence number (u32), 302-311 five joint targets (i32, µrad / µm),
//             312 duration (ms, 1..max), 313 flags (kSegmentFlagArcOn)
//
// The arc interlock: the arc burns (register 105) only while all of these hold: no alarm, arc
// enabled (ARC ON commanded), all three weld set-points non-zero, and a segment flagged arc-on is
// being executed. It goes out by itself when the buffer runs empty, so a starved stream never
// leaves the torch burning a hole in a standing blade.

#include <cstdint>

namespace kinevis::hal::weld_robot {

inline constexpr int kJointCount = 5;

// ---- Identity and limits (input registers) ----------------------------------------------------
inline constexpr int kIdentityAddress = 0;
inline constexpr int kIdentityRegisters = 40;  // 0..39, read in one request
inline constexpr int kRegMagic = 0;
inline constexpr int kRegMapVersion = 1;
inline constexpr int kRegJointCount = 2;
inline constexpr int kRegBufferCapacity = 3;
inline constexpr int kRegMaxSegmentDurationMs = 4;
inline constexpr int kRegMaxCurrent = 5;
inline constexpr int kRegMaxVoltage = 6;
inline constexpr int kRegMaxWireFeed = 7;
inline constexpr int kRegSerialNumber = 8;  // u32
inline constexpr int kRegJointLimits = 10;  // + 6 j
inline constexpr int kJointLimitRegisters = 6;
inline constexpr int kJointLimitMinOffset = 0;    // i32
inline constexpr int kJointLimitMaxOffset = 2;    // i32
inline constexpr int kJointLimitSpeedOffset = 4;  // u32

inline constexpr uint16_t kIdentityMagic = 0x4B57;  // "KW"
inline constexpr uint16_t kMapVersion = 1;

// ---- Status (input registers) -----------------------------------------------------------------
inline constexpr int kStatusAddress = 100;
inline constexpr int kStatusRegisters = 25;  // 100..124, read in one request
inline constexpr int kRegMotionState = 100;
inline constexpr int kRegAlarmCode = 101;
inline constexpr int kRegBufferLevel = 102;
inline constexpr int kRegBufferFree = 103;
inline constexpr int kRegArcEnabled = 104;
inline constexpr int kRegArcOn = 105;
inline constexpr int kRegLastSequence = 106;       // u32
inline constexpr int kRegCompletedSequence = 108;  // u32
inline constexpr int kRegAlarmSequence = 110;      // u32
inline constexpr int kRegActualJoints = 112;       // 5 x i32
inline constexpr int kRegActualCurrent = 122;
inline constexpr int kRegActualVoltage = 123;
inline constexpr int kRegActualWireFeed = 124;

inline constexpr int kInputRegisterCount = 128;  // size of the input register table

// ---- Commands and set-points (holding registers) ----------------------------------------------
inline constexpr int kRegCommand = 200;
inline constexpr int kRegSetCurrent = 210;
inline constexpr int kRegSetVoltage = 211;
inline constexpr int kRegSetWireFeed = 212;
inline constexpr int kSetPointRegisters = 3;

// ---- Trajectory segment (holding registers, one 0x10 write) -----------------------------------
inline constexpr int kSegmentAddress = 300;
inline constexpr int kSegmentRegisters = 14;
inline constexpr int kSegmentSequenceOffset = 0;  // u32
inline constexpr int kSegmentJointsOffset = 2;    // 5 x i32
inline constexpr int kSegmentDurationOffset = 12;
inline constexpr int kSegmentFlagsOffset = 13;
inline constexpr uint16_t kSegmentFlagArcOn = 1u << 0;
inline constexpr uint16_t kSegmentKnownFlags = kSegmentFlagArcOn;

inline constexpr int kHoldingRegisterCount = 320;  // size of the holding register table

// ---- Register units ---------------------------------------------------------------------------
// Register units per SI unit: µrad per rad, µm per m (joints, joint limits, and per second for
// speeds); ms per s; 0.1 A per A; 0.1 V per V; 0.1 mm/s per m/s.
inline constexpr double kJointUnitsPerSi = 1e6;
inline constexpr double kDurationUnitsPerSecond = 1e3;
inline constexpr double kCurrentUnitsPerAmpere = 10.0;
inline constexpr double kVoltageUnitsPerVolt = 10.0;
inline constexpr double kWireFeedUnitsPerMetrePerSecond = 1e4;
inline constexpr int kMinSegmentDurationMs = 1;

// Joint j is prismatic (pz3, metres) or rotary (radians).
constexpr bool IsPrismatic(int joint) { return joint == 2; }
// "θ1", "θ2", "pz3", "θ4", "θ5" (UTF-8).
constexpr const char* JointName(int joint) {
  constexpr const char* kNames[kJointCount] = {"θ1", "θ2", "pz3", "θ4", "θ5"};
  return joint >= 0 && joint < kJointCount ? kNames[joint] : "?";
}

// ---- Motion states ----------------------------------------------------------------------------
enum class MotionState : uint16_t {
  kIdle = 0,    // standing still, buffer empty
  kMoving = 1,  // executing a segment
  kAlarm = 2,   // an alarm is active: standing still, buffer cleared, until ALARM RESET
};

constexpr const char* MotionStateName(uint16_t state) {
  switch (state) {
    case static_cast<uint16_t>(MotionState::kIdle):
      return "IDLE";
    case static_cast<uint16_t>(MotionState::kMoving):
      return "MOVING";
    case static_cast<uint16_t>(MotionState::kAlarm):
      return "ALARM";
    default:
      return "UNKNOWN MOTION STATE";
  }
}

// ---- Commands (register 200) ------------------------------------------------------------------
enum class Command : uint16_t {
  kNone = 0,
  kStop = 1,        // motion stops where it is, buffer cleared, arc off and disabled; a new stream
                    // may start with any sequence number. Accepted in every state, alarm included
                    // (it does not clear the alarm).
  kAlarmReset = 2,  // clears the alarm -> IDLE; a new stream may start with any sequence number
  kArcOn = 3,       // arc enable; refused with exception 4 during an alarm, 3 while a weld
                    // set-point is zero
  kArcOff = 4,      // arc disable; accepted in every state
};

// ---- Alarms (register 101) --------------------------------------------------------------------
// Codes 1..6 are raised by the controller on bad input; 16.. by the cell (the simulator's
// fault injection raises any code). Any alarm: motion stops where it is, arc off and disabled,
// buffer cleared, segment writes and ARC ON refused, until ALARM RESET.
enum class Alarm : uint16_t {
  kNone = 0,
  kTargetOutOfRange = 1,  // a segment's target is outside a joint's limits
  kSequenceGap = 2,       // a segment's sequence number is not the last accepted + 1
  kBufferOverflow = 3,    // a segment arrived while the buffer was full
  kSpeedLimit = 4,        // a segment would move a joint faster than its speed limit
  kBadSegment = 5,        // duration out of 1..max, or unknown flag bits
  kEmergencyStop = 16,    // the cell's emergency stop circuit opened
  kArcFault = 17,         // the power source lost or could not strike the arc
  kWireStuck = 18,        // the wire feeder is blocked
  kCollision = 19,        // the torch collision sensor tripped
};

constexpr const char* AlarmName(uint16_t code) {
  switch (code) {
    case 0:
      return "NONE";
    case 1:
      return "TARGET OUT OF RANGE";
    case 2:
      return "SEQUENCE GAP";
    case 3:
      return "BUFFER OVERFLOW";
    case 4:
      return "SPEED LIMIT";
    case 5:
      return "BAD SEGMENT";
    case 16:
      return "EMERGENCY STOP";
    case 17:
      return "ARC FAULT";
    case 18:
      return "WIRE STUCK";
    case 19:
      return "COLLISION";
    default:
      return "UNKNOWN ALARM";
  }
}

// ---- 32-bit values in register pairs (high word first) ----------------------------------------
constexpr uint32_t GetU32(const uint16_t* regs) {
  return (static_cast<uint32_t>(regs[0]) << 16) | regs[1];
}
constexpr int32_t GetI32(const uint16_t* regs) { return static_cast<int32_t>(GetU32(regs)); }
constexpr void PutU32(uint16_t* regs, uint32_t value) {
  regs[0] = static_cast<uint16_t>(value >> 16);
  regs[1] = static_cast<uint16_t>(value & 0xFFFFu);
}
constexpr void PutI32(uint16_t* regs, int32_t value) { PutU32(regs, static_cast<uint32_t>(value)); }

}  // namespace kinevis::hal::weld_robot
