#pragma once

// Dynamixel Protocol 2.0 (X series such as the XM430-W350, MX(2.0), PRO): pure encoders and a
// streaming decoder, no I/O. Shared definitions (DxlInstruction, DxlPacket, DxlDecoderStats) are
// in protocol1.h.
//
// Packet (little-endian multi-byte fields):
//   instruction  FF FF FD 00 ID LEN_L LEN_H INST P1 .. Pn CRC_L CRC_H           LEN = n + 3
//   status       FF FF FD 00 ID LEN_L LEN_H 55 ERROR P1 .. Pn CRC_L CRC_H       LEN = n + 4
// CRC: CRC-16 with polynomial 0x8005, initial value 0, not reflected, no final XOR, over every
// byte from the first FF up to the byte before CRC_L, as transmitted (after stuffing).
// Byte stuffing: inside INST and the parameters (ERROR included), every FF FF FD is sent as
// FF FF FD FD, so that the header never appears in a packet's body; LEN counts the stuffed bytes.
// IDs 0..252; 254 (0xFE) is the broadcast id; 0xFD and 0xFF are not ids.
//
// Instructions of the subset kinevis uses (parameters after INST; ADDR and K are 2 bytes):
//   ping        -                                       status: MODEL_L MODEL_H FIRMWARE
//   read        ADDR K                                  status: K data bytes
//   write       ADDR D1 .. Dk                           status: no parameters
//   reg write   ADDR D1 .. Dk (executed at action)      status: no parameters
//   action      -                                       status: none when broadcast
//   reboot      -                                       status: no parameters, then the reboot
//   sync read   ADDR K ID1 ID2 ..        (broadcast)    one status per ID, in the order given
//   sync write  ADDR K [ID D1 .. DK]...  (broadcast)    no status
//
// Status error field: bit 7 is the alert bit (the servo has a hardware error: read its Hardware
// Error Status); bits 0..6 carry an error code, Dxl2ErrorCode, 0 when the instruction succeeded.

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "hal/dynamixel/protocol1.h"

namespace kinevis::hal {

// FF FF FD 00 ID LEN_L LEN_H.
inline constexpr size_t kDxl2HeaderSize = 7;
// Default bound of one packet in a decoder; a 2.0 packet may announce up to 7 + 65535 bytes,
// far more than any control table holds.
inline constexpr size_t kDxl2DefaultMaxPacketSize = 2048;

inline constexpr uint8_t kDxl2AlertBit = 0x80;

// The error code in bits 0..6 of the status error field.
enum class Dxl2ErrorCode : uint8_t {
  kNone = 0,
  kResultFail = 1,        // the instruction could not be processed
  kInstructionError = 2,  // undefined instruction, or action without reg write
  kCrcError = 3,          // the instruction packet's CRC was wrong
  kDataRangeError = 4,    // the value written is outside the register's range
  kDataLengthError = 5,   // fewer bytes written than the register holds
  kDataLimitError = 6,    // the value is outside a limit (e.g. goal position vs position limits)
  kAccessError = 7,       // read-only or undefined address written, or EEPROM with torque on
};

// Bits of the Hardware Error Status register (XM430-W350: address 70).
enum Dxl2HardwareErrorBit : uint8_t {
  kDxl2HwInputVoltage = 1u << 0,     // supply outside the voltage limits
  kDxl2HwOverheating = 1u << 2,      // internal temperature above the limit
  kDxl2HwMotorEncoder = 1u << 3,     // the encoder does not work
  kDxl2HwElectricalShock = 1u << 4,  // electrical shock on the circuit or insufficient power
  kDxl2HwOverload = 1u << 5,         // persistent load above the maximum
};

// "result fail", "instruction error", "CRC error", "data range error", "data length error",
// "data limit error", "access error"; "none" for 0; "error code N" for codes above 7.
std::string Dxl2ErrorCodeName(uint8_t code);
// The status error field in words: "none", "data range error", "alert",
// "alert, access error".
std::string Dxl2ErrorText(uint8_t error);
// The Hardware Error Status bits in words: "overload", "input voltage, overheating", "none";
// undefined bits as "bit N".
std::string Dxl2HardwareErrorText(uint8_t bits);

// CRC-16 (poly 0x8005, non-reflected) of `data`, continuing from `crc` (0 to start).
uint16_t Dxl2Crc16(const uint8_t* data, size_t size, uint16_t crc = 0);

// An upper bound of the encoded size of a packet with `param_count` parameters (status packets:
// the error field counts as a parameter), stuffing included.
inline constexpr size_t Dxl2MaxEncodedSize(size_t param_count) {
  return kDxl2HeaderSize + 1 + param_count + (param_count + 1) / 3 + 2;
}

// Writes an instruction packet into `out`, stuffing INST and the parameters, and returns its
// size; 0 when the id is 0xFD or 0xFF, the stuffed length does not fit LEN's 16 bits, or
// `capacity` is too small (Dxl2MaxEncodedSize(param_count) is always enough). Does not allocate.
size_t EncodeDxl2Instruction(uint8_t id, uint8_t instruction, const uint8_t* params,
                             size_t param_count, uint8_t* out, size_t capacity);
// Writes a status packet (instruction 0x55, the error field, then the parameters).
size_t EncodeDxl2Status(uint8_t id, uint8_t error, const uint8_t* params, size_t param_count,
                        uint8_t* out, size_t capacity);
// The same as vectors; empty on the conditions above.
std::vector<uint8_t> Dxl2InstructionPacket(uint8_t id, DxlInstruction instruction,
                                           const std::vector<uint8_t>& params = {});
std::vector<uint8_t> Dxl2StatusPacket(uint8_t id, uint8_t error,
                                      const std::vector<uint8_t>& params = {});

// Streaming decoder: bytes in (any split), packets out, parameters de-stuffed. It resynchronises
// on garbage by dropping one byte at a time and rescanning what it holds. A status decoder
// ignores (and counts) instruction packets, an instruction decoder status packets: on a shared
// half-duplex line each side sees the other direction too. Memory is allocated once, at
// construction: 3 x max_packet_size bytes. Not thread-safe.
class Dxl2Decoder {
 public:
  // max_packet_size: the longest packet accepted, header and CRC included (at least 11);
  // longer ones are counted as malformed and skipped.
  explicit Dxl2Decoder(DxlPacketKind kind, size_t max_packet_size = kDxl2DefaultMaxPacketSize);

  // As Dxl1Decoder::Feed(): consumes bytes until a packet is complete; has_packet() says whether
  // packet() holds a new one. Size 0 looks for a further packet among bytes already held.
  size_t Feed(const uint8_t* data, size_t size);
  bool has_packet() const { return has_packet_; }
  const DxlPacket& packet() const { return packet_; }

  template <typename OnPacket>
  void FeedAll(const uint8_t* data, size_t size, OnPacket&& on_packet) {
    while (true) {
      const size_t n = Feed(data, size);
      data += n;
      size -= n;
      if (has_packet()) {
        on_packet(packet());
      } else if (size == 0) {
        return;
      }
    }
  }

  void Reset();
  const DxlDecoderStats& stats() const { return stats_; }

 private:
  bool Parse();
  void Drop();

  const DxlPacketKind kind_;
  const size_t max_packet_size_;
  std::vector<uint8_t> buffer_;   // 2 x max_packet_size_
  std::vector<uint8_t> payload_;  // the de-stuffed INST + parameters of the last packet
  size_t begin_ = 0;
  size_t end_ = 0;
  DxlPacket packet_;
  bool has_packet_ = false;
  DxlDecoderStats stats_;
};

}  // namespace kinevis::hal
