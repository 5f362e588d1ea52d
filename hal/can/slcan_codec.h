#pragma once

// The Lawicel ASCII CAN protocol ("slcan", CAN232/CANUSB), spoken by most USB-CAN adapters:
// pure encoders and decoders, no I/O. Every line ends in '\r'.
//
// Host to adapter (SlcanCommand):
//   tIIIL<data>\r        standard data frame: 3 hex id digits, dlc digit 0..8, 2*dlc hex digits
//   TIIIIIIIIL<data>\r   extended data frame: 8 hex id digits
//   rIIIL\r RIIIIIIIIL\r remote frames (L is the requested length; no data)
//   Sn\r                 CAN bit rate, n = 0..8 (10k 20k 50k 100k 125k 250k 500k 800k 1M)
//   O\r L\r C\r          open the channel, open listen-only, close
//   V\r N\r F\r          version, serial number, status flags
//   Z0\r Z1\r            millisecond timestamps off / on
// Adapter to host (SlcanEvent):
//   \r                   OK;  \a (BEL, 0x07) error
//   z\r Z\r              a t/r (z) or T/R (Z) line was accepted for transmission
//   t/T/r/R lines        received frames, with a 4-hex-digit ms timestamp 0000..EA5F appended when
//                        timestamps are on (Z1); the timestamp wraps from 59999 to 0 every 60 s
//   VHHSS\r NXXXX\r      version (hardware, software) and serial number, 4 characters each
//   FXX\r                status flags, 2 hex digits (see SlcanStatusFlag)
// Hex digits are written upper case and read in either case.

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <string_view>

#include "hal/can/can_frame.h"

namespace kinevis::hal {

// The longest line the protocol has: 'T', 8 id digits, dlc, 16 data digits, 4 timestamp digits,
// '\r'.
inline constexpr size_t kSlcanMaxLineSize = 31;
// Largest adapter timestamp: 59999 ms. The counter wraps to 0 every 60 s.
inline constexpr uint16_t kSlcanMaxTimestampMs = 0xEA5F;
inline constexpr char kSlcanBell = '\a';

// Bits of the Lawicel F (status flags) reply.
enum SlcanStatusFlag : uint8_t {
  kSlcanRxFifoFull = 1u << 0,       // the adapter's receive FIFO is full
  kSlcanTxFifoFull = 1u << 1,       // the adapter's transmit FIFO is full
  kSlcanErrorWarning = 1u << 2,     // an error counter of the controller is at or above 96
  kSlcanDataOverrun = 1u << 3,      // the controller lost received frames
  kSlcanErrorPassive = 1u << 5,     // an error counter of the controller is above 127
  kSlcanArbitrationLost = 1u << 6,  // a transmission lost arbitration
  kSlcanBusError = 1u << 7,         // a protocol error on the bus (stuff, form, CRC, bit)
};

// Milliseconds from adapter timestamp `earlier` to `later` (both 0..59999), across the wrap at
// 60 s: (later - earlier + 60000) % 60000. Right when the two frames are less than 60 s apart;
// the host arrival times tell whether they are.
inline uint16_t SlcanTimestampDeltaMs(uint16_t earlier, uint16_t later) {
  constexpr int kPeriod = kSlcanMaxTimestampMs + 1;
  return static_cast<uint16_t>((later - earlier + kPeriod) % kPeriod);
}

// Bit rate in bit/s of the Lawicel code S0..S8; -1 for a code out of range. The inverse is
// SlcanBitrateCode() in hal/common/backend_spec.h.
int SlcanBitrateFromCode(int code);

// Writes the line for `frame` (with the terminating '\r') into `buffer`, which must hold
// kSlcanMaxLineSize bytes. timestamp_ms (0..kSlcanMaxTimestampMs), when given, is appended as the
// adapter does with Z1. Returns the number of bytes written, or 0 when the frame is invalid
// (frame.Validate() is not empty) or the timestamp is out of range. Does not allocate.
size_t EncodeSlcanFrame(const CanFrame& frame, char* buffer,
                        std::optional<uint16_t> timestamp_ms = std::nullopt);
// The same as a string; empty when the frame or timestamp is invalid.
std::string SlcanFrameLine(const CanFrame& frame,
                           std::optional<uint16_t> timestamp_ms = std::nullopt);

// A line from the host to the adapter.
struct SlcanCommand {
  enum class Kind {
    kTransmit,      // t/T/r/R: send `frame`
    kSetBitrate,    // Sn: bitrate_code 0..8
    kOpen,          // O
    kListenOnly,    // L
    kClose,         // C
    kVersion,       // V
    kSerialNumber,  // N
    kStatus,        // F
    kTimestamps,    // Z0 / Z1: timestamps_on
  };
  Kind kind = Kind::kClose;
  int bitrate_code = 0;        // kSetBitrate: 0..8
  bool timestamps_on = false;  // kTimestamps
  CanFrame frame;              // kTransmit

  static SlcanCommand Simple(Kind kind);  // O, L, C, V, N, F
  static SlcanCommand SetBitrate(int bitrate_code);
  static SlcanCommand Timestamps(bool on);
  static SlcanCommand Transmit(const CanFrame& frame);
};

// "O\r", "S6\r", "Z1\r", "t1232AABB\r", ... Returns an empty string for a command that cannot be
// encoded (bitrate_code outside 0..8, an invalid frame).
std::string EncodeSlcanCommand(const SlcanCommand& command);
// "S6\r" for 500000 bit/s; empty when SlcanBitrateCode(bitrate) < 0.
std::string EncodeSlcanBitrate(int bitrate);

// Parses one host-to-adapter line without its '\r' ("S6", "t1232AABB"). Returns nullopt for an
// unknown or malformed line and, when error is given, says what is wrong.
std::optional<SlcanCommand> ParseSlcanCommand(std::string_view line, std::string* error = nullptr);

// Something the adapter said.
struct SlcanEvent {
  enum class Kind {
    kFrame,         // a received frame: frame, has_timestamp, timestamp_ms
    kOk,            // "\r": the last command succeeded
    kError,         // "\a": the last command or frame was refused
    kTxAck,         // "z\r" or "Z\r": a frame was queued for transmission (extended_ack for 'Z')
    kVersion,       // "Vxxxx\r": text = "xxxx"
    kSerialNumber,  // "Nxxxx\r": text = "xxxx"
    kStatus,        // "Fxx\r": status = the flags (SlcanStatusFlag)
    kInvalid,       // an undecodable line: text = the line, escaped and truncated (see below)
  };
  Kind kind = Kind::kOk;
  CanFrame frame;              // kFrame; frame.timestamp is left zero (the host stamps it)
  bool has_timestamp = false;  // kFrame: the adapter appended a ms timestamp
  uint16_t timestamp_ms = 0;   // kFrame: 0..59999 when has_timestamp
  bool extended_ack = false;   // kTxAck
  uint8_t status = 0;          // kStatus
  // kVersion, kSerialNumber: the 4 characters. kInvalid: the line as printable text (bytes
  // outside 0x20..0x7E and '\\' written as \xNN), its first kMaxLineBytes bytes only, with
  // "..." appended when it was longer.
  std::string text;
};

const char* ToString(SlcanEvent::Kind kind);

// Decodes the adapter-to-host byte stream into events. Bytes may arrive in pieces of any size.
//
// A line that does not decode (garbage, a lost byte, two lines run together because a '\r' was
// lost) becomes one kInvalid event; decoding starts afresh after the next '\r' or '\a', so a lost
// '\r' costs exactly the two lines it joined. A line is buffered up to kMaxLineBytes bytes: a
// longer one is reported as kInvalid as soon as it overflows and the rest of it, up to the next
// terminator, is skipped, so endless input without a terminator uses constant memory.
// A '\n' directly after a terminator is ignored (some adapters end lines with "\r\n").
// Not thread-safe; one decoder per stream.
class SlcanDecoder {
 public:
  // Longest line kept; longer than any valid line, so an overflowing line is certainly garbage.
  static constexpr size_t kMaxLineBytes = 64;
  using EventCallback = std::function<void(const SlcanEvent&)>;

  // Feeds bytes; on_event is called for every event they complete, in order. The event passed is
  // reused between calls: copy what you keep. Does not allocate once the decoder has decoded an
  // invalid line of maximum length.
  void Feed(const uint8_t* data, size_t size, const EventCallback& on_event);
  void Feed(std::string_view bytes, const EventCallback& on_event) {
    Feed(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size(), on_event);
  }
  // Forgets a partly received line (after flushing the port, for instance).
  void Reset();

  // Undecodable lines so far (kInvalid events).
  uint64_t decode_errors() const { return decode_errors_; }
  // Bytes of undecodable lines, including the skipped tails of overlong ones.
  uint64_t discarded_bytes() const { return discarded_bytes_; }
  // Bytes of the line being received (at most kMaxLineBytes).
  size_t pending_bytes() const { return size_; }
  // The text of the last kInvalid event (escaped, bounded), for diagnostics.
  const std::string& last_invalid_text() const { return last_invalid_; }

 private:
  void EndLine(const EventCallback& on_event);
  void EmitInvalid(const EventCallback& on_event, bool truncated);

  std::array<char, kMaxLineBytes> line_{};
  size_t size_ = 0;
  bool skipping_ = false;  // inside an overlong line, waiting for its terminator
  bool after_terminator_ = true;
  uint64_t decode_errors_ = 0;
  uint64_t discarded_bytes_ = 0;
  std::string last_invalid_;
  SlcanEvent event_;
};

}  // namespace kinevis::hal
