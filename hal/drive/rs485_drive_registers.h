#pragma once

// Register map of kinevis' RS485 motor drive (the DIAMOND's motor arms): Modbus RTU holding
// registers that carry the CiA 402 semantics, so that the same state machine and modes run over
// Modbus as over CANopen. docs/rs485-drive-registers.md is the human-readable form of this file;
// this header is the single source both the host driver and the simulator use.
//
// Conventions:
//  - All registers are holding registers (function 0x03 read, 0x10 write, 0x17 write-and-read),
//    so that one 0x17 transaction per cycle writes the outputs and reads the inputs.
//  - 32-bit values occupy two consecutive registers, HIGH word first (Modbus convention).
//  - Units are the drive's: counts, counts/s, counts/s^2, per mille of rated torque, ms.
//  - Output block (host -> drive) at 0x0000, read/write. Input block (drive -> host) at 0x0100,
//    read-only: a write there is answered with exception ILLEGAL DATA ADDRESS (2).
//  - A value out of range (unknown mode, limit min > max) is answered ILLEGAL DATA VALUE (3)
//    and not applied.
//  - Communication watchdog: when kRegWatchdogMs is non-zero and no valid request addressed to
//    the drive arrives for that long, the drive faults (error code 0x8130, like a lost CANopen
//    heartbeat) and stops with its quick stop ramp.

#include <cstdint>

namespace kinevis::hal::rs485_drive {

// ---- output block: written by the host (read back allowed)
inline constexpr uint16_t kRegControlword = 0x0000;           // u16, CiA 402 0x6040
inline constexpr uint16_t kRegModeOfOperation = 0x0001;       // i16, CiA 402 0x6060 (1,3,4,8,9,10)
inline constexpr uint16_t kRegTargetPosition = 0x0002;        // i32 (2 regs), counts, 0x607A
inline constexpr uint16_t kRegTargetVelocity = 0x0004;        // i32 (2 regs), counts/s, 0x60FF
inline constexpr uint16_t kRegTargetTorque = 0x0006;          // i16, per mille, 0x6071
inline constexpr uint16_t kCyclicOutputCount = 7;             // 0x0000..0x0006: one cycle's outputs
inline constexpr uint16_t kRegProfileVelocity = 0x0007;       // u32 (2 regs), counts/s, 0x6081
inline constexpr uint16_t kRegProfileAcceleration = 0x0009;   // u32 (2 regs), counts/s^2, 0x6083
inline constexpr uint16_t kRegFollowingErrorWindow = 0x000B;  // u32 (2 regs), counts, 0x6065
inline constexpr uint16_t kRegPositionLimitMin = 0x000D;      // i32 (2 regs), counts, 0x607D.1
inline constexpr uint16_t kRegPositionLimitMax = 0x000F;      // i32 (2 regs), counts, 0x607D.2
inline constexpr uint16_t kRegQuickStopOptionCode = 0x0011;   // i16, 0x605A (0..8)
inline constexpr uint16_t kRegWatchdogMs = 0x0012;            // u16, ms, 0 = off
inline constexpr uint16_t kOutputBlockSize = 0x0013;

// ---- input block: read-only
inline constexpr uint16_t kRegStatusword = 0x0100;            // u16, 0x6041
inline constexpr uint16_t kRegModeDisplay = 0x0101;           // i16, 0x6061
inline constexpr uint16_t kRegPositionActual = 0x0102;        // i32 (2 regs), counts, 0x6064
inline constexpr uint16_t kRegVelocityActual = 0x0104;        // i32 (2 regs), counts/s, 0x606C
inline constexpr uint16_t kRegTorqueActual = 0x0106;          // i16, per mille, 0x6077
inline constexpr uint16_t kRegErrorCode = 0x0107;             // u16, 0x603F (CiA 402 / EMCY codes)
inline constexpr uint16_t kRegFollowingErrorActual = 0x0108;  // i32 (2 regs), counts, 0x60F4
inline constexpr uint16_t kCyclicInputCount = 10;             // 0x0100..0x0109: one cycle's inputs
inline constexpr uint16_t kRegVendorId = 0x010A;              // u32 (2 regs), 0x1018.1
inline constexpr uint16_t kRegProductCode = 0x010C;           // u32 (2 regs), 0x1018.2
inline constexpr uint16_t kRegSerialNumber = 0x010E;          // u32 (2 regs), 0x1018.4
inline constexpr uint16_t kRegSupportedModes = 0x0110;        // u32 (2 regs), 0x6502
inline constexpr uint16_t kInputBlockStart = 0x0100;
inline constexpr uint16_t kInputBlockSize = 0x0012;

// kinevis' vendor id for its own simulated drives (a real drive reports its own).
inline constexpr uint32_t kSimulatorVendorId = 0x004B5653;  // "KVS"

inline uint32_t JoinHighFirst(uint16_t high, uint16_t low) { return uint32_t{high} << 16 | low; }
inline void SplitHighFirst(uint32_t value, uint16_t* out) {
  out[0] = static_cast<uint16_t>(value >> 16);
  out[1] = static_cast<uint16_t>(value);
}

}  // namespace kinevis::hal::rs485_drive
