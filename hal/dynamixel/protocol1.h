#pragma once

// Dynamixel Protocol 1.0 (AX, RX, EX, MX servos such as the MX-12W): pure encoders and a streaming
// decoder, no I/O. Also the definitions both protocol versions share (instruction codes, the
// decoded-packet view, decoder statistics); protocol2.h includes this header.
//
// Packet (every field one byte, half-duplex, little-endian multi-byte parameters):
//   instruction  FF FF ID LEN INST  P1 .. Pn CHK      LEN = n + 2
//   status       FF FF ID LEN ERROR P1 .. Pn CHK      LEN = n + 2
//   CHK = ~(ID + LEN + INST/ERROR + P1 + .. + Pn) & 0xFF
// IDs 0..253; 254 (0xFE) is the broadcast id; 0xFF never occurs as an id.
//
// Instructions of the subset kinevis uses (parameters after INST):
//   ping        -                                        status: no parameters
//   read        ADDR LEN                                 status: LEN data bytes
//   write       ADDR D1 .. Dk                            status: no parameters
//   reg write   ADDR D1 .. Dk (executed at action)       status: no parameters
//   action      -                                        status: none when broadcast
//   sync write  ADDR K  [ID D1 .. DK]...  (broadcast)    no status
//   bulk read   00 [K ID ADDR]...         (broadcast)    one status per ID, in the order given

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace kinevis::hal {

// ---------------------------------------------------------------------------------------------
// Shared by protocol 1.0 and 2.0.

// Instruction codes. Both versions use the same values; reboot, clear, sync read and bulk write
// exist in protocol 2.0 only.
enum class DxlInstruction : uint8_t {
  kPing = 0x01,
  kRead = 0x02,
  kWrite = 0x03,
  kRegWrite = 0x04,
  kAction = 0x05,
  kFactoryReset = 0x06,
  kReboot = 0x08,
  kClear = 0x10,
  kStatus = 0x55,  // protocol 2.0: the instruction field of a status packet
  kSyncRead = 0x82,
  kSyncWrite = 0x83,
  kBulkRead = 0x92,
  kBulkWrite = 0x93,
};
// "ping", "read", ..., or "0xNN" for a code that is not in the enum.
std::string ToString(DxlInstruction instruction);

inline constexpr uint8_t kDxlBroadcastId = 0xFE;

// Which packets a decoder hands out: a host decodes status packets, a servo (the simulator)
// instruction packets.
enum class DxlPacketKind { kInstruction, kStatus };

// A decoded packet. `params` points into the decoder and stays valid until the decoder's next
// Feed() or Reset(); copy what must outlive that.
struct DxlPacket {
  uint8_t id = 0;
  // Instruction packets: the instruction code. Status packets: DxlInstruction::kStatus (0x55),
  // also for protocol 1.0, whose status packets carry no instruction field.
  uint8_t instruction = 0;
  uint8_t error = 0;  // status packets: the error field; 0 for instruction packets
  const uint8_t* params = nullptr;
  size_t param_count = 0;

  std::vector<uint8_t> ParamVector() const { return {params, params + param_count}; }
};

struct DxlDecoderStats {
  uint64_t packets = 0;          // valid packets handed out
  uint64_t checksum_errors = 0;  // framed packets whose checksum (1.0) or CRC (2.0) was wrong
  uint64_t discarded_bytes = 0;  // bytes skipped while looking for a header
  uint64_t malformed = 0;        // headers with an impossible or too large length, bad stuffing
  uint64_t ignored = 0;          // valid packets of the other kind (an echo of the host's own
                                 // instruction seen by a status decoder, or another servo's
                                 // status seen by an instruction decoder); protocol 2.0 only
};

// ---------------------------------------------------------------------------------------------
// Protocol 1.0.

// FF FF ID LEN + at most 255 bytes.
inline constexpr size_t kDxl1MaxPacketSize = 4 + 255;
// LEN is one byte and counts INST/ERROR and CHK.
inline constexpr size_t kDxl1MaxParams = 253;

// Bits of the status packet's error field.
enum Dxl1ErrorBit : uint8_t {
  kDxl1InputVoltageError = 1u << 0,  // supply outside the voltage limits
  kDxl1AngleLimitError = 1u << 1,    // goal position outside the CW/CCW angle limits
  kDxl1OverheatingError = 1u << 2,   // internal temperature above the limit
  kDxl1RangeError = 1u << 3,         // a parameter out of range (or a read-only address written)
  kDxl1ChecksumError = 1u << 4,      // the instruction packet's checksum was wrong
  kDxl1OverloadError = 1u << 5,      // the load exceeded the torque limit; torque is off
  kDxl1InstructionError = 1u << 6,   // undefined instruction, or action without reg write
};

// "input voltage", "angle limit", "overheating", "range", "checksum", "overload", "instruction"
// for one bit of Dxl1ErrorBit; nullptr for any other value.
const char* Dxl1ErrorBitName(uint8_t bit);
// The names of every bit set, joined by ", " ("overheating, overload"); "none" for 0;
// "bit 7" for the undefined bit 7.
std::string Dxl1ErrorText(uint8_t error);

// ~(sum of bytes) & 0xFF over `data` (ID through the last parameter).
uint8_t Dxl1Checksum(const uint8_t* data, size_t size);

// Writes FF FF ID LEN CODE P.. CHK into `out` and returns its size, or 0 when param_count >
// kDxl1MaxParams, id is 0xFF, or `capacity` is smaller than param_count + 6. `code` is the
// instruction (instruction packet) or the error field (status packet). Does not allocate.
size_t EncodeDxl1Packet(uint8_t id, uint8_t code, const uint8_t* params, size_t param_count,
                        uint8_t* out, size_t capacity);
// The same as a vector; empty on the conditions above.
std::vector<uint8_t> Dxl1InstructionPacket(uint8_t id, DxlInstruction instruction,
                                           const std::vector<uint8_t>& params = {});
std::vector<uint8_t> Dxl1StatusPacket(uint8_t id, uint8_t error,
                                      const std::vector<uint8_t>& params = {});

// Streaming decoder: bytes in (any split), packets out. It resynchronises on garbage by dropping
// one byte at a time and rescanning what it holds, so a packet that follows garbage or a
// corrupted packet is still found. Memory is fixed at construction (2 x kDxl1MaxPacketSize).
// Not thread-safe; one decoder per byte stream.
class Dxl1Decoder {
 public:
  explicit Dxl1Decoder(DxlPacketKind kind);

  // Consumes bytes from `data` until a packet is complete or the bytes run out; returns how many
  // were consumed. has_packet() then says whether packet() holds a new packet. Call again with the
  // rest (or with size 0, which looks for a further packet among bytes already held).
  size_t Feed(const uint8_t* data, size_t size);
  bool has_packet() const { return has_packet_; }
  const DxlPacket& packet() const { return packet_; }

  // Feeds all of `data`, calling on_packet(const DxlPacket&) for every packet completed.
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

  // Drops the bytes of an incomplete packet (statistics are kept).
  void Reset();
  const DxlDecoderStats& stats() const { return stats_; }

 private:
  bool Parse();
  void Drop();

  const DxlPacketKind kind_;
  std::array<uint8_t, 2 * kDxl1MaxPacketSize> buffer_{};
  size_t begin_ = 0;
  size_t end_ = 0;
  DxlPacket packet_;
  bool has_packet_ = false;
  DxlDecoderStats stats_;
};

}  // namespace kinevis::hal
