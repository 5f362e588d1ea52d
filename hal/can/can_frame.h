#pragma once

// Classical CAN 2.0 frames (CAN FD is out of scope: none of kinevis' devices use it), acceptance
// filters with SocketCAN semantics, and bus error events.

#include <array>
#include <chrono>
#include <cstdint>
#include <initializer_list>
#include <optional>
#include <string>
#include <string_view>

namespace kinevis::hal {

struct CanFrame {
  static constexpr uint32_t kMaxStandardId = 0x7FF;
  static constexpr uint32_t kMaxExtendedId = 0x1FFFFFFF;

  uint32_t id = 0;        // 11-bit (standard) or 29-bit (extended) identifier
  bool extended = false;  // 29-bit identifier
  bool rtr = false;       // remote transmission request (no data; dlc is the requested length)
  uint8_t dlc = 0;        // data length code, 0..8
  std::array<uint8_t, 8> data{};
  // Reception time since the epoch of the backend's clock: the SteadyClock for SocketCAN (the
  // kernel's stamp converted to it) and slcan (host time of arrival); the network's Clock for
  // the virtual bus (the SteadyClock unless a SimulatedClock was given). Zero for frames to send.
  std::chrono::nanoseconds timestamp{0};

  // Frames with the given payload; the helpers assert that id and payload fit.
  static CanFrame Standard(uint32_t id, std::initializer_list<uint8_t> payload = {});
  static CanFrame Extended(uint32_t id, std::initializer_list<uint8_t> payload = {});

  // Empty when the frame is valid; otherwise what is wrong ("id 0x800 exceeds 11 bits").
  std::string Validate() const;
};

// Equal identifiers, flags, dlc and the first dlc data bytes; timestamps are ignored.
bool operator==(const CanFrame& a, const CanFrame& b);
inline bool operator!=(const CanFrame& a, const CanFrame& b) { return !(a == b); }

// cansend syntax: "123#DEADBEEF", "12345678#00" (8 hex digits = extended), "123#R", "123#R4".
std::string FormatCanFrame(const CanFrame& frame);
// Parses cansend syntax; on failure returns nullopt and, when error is given, says what is wrong.
std::optional<CanFrame> ParseCanFrame(std::string_view text, std::string* error = nullptr);

// Number of bits the frame occupies on the wire, including stuff bits (computed exactly from
// the frame's bit pattern and CRC-15), the end of frame and the 3-bit interframe space.
int CanFrameWireBits(const CanFrame& frame);

// Acceptance filter, SocketCAN semantics: a frame passes when
// (frame.id & mask) == (id & mask), with the extended and rtr flags compared when the
// corresponding match_* flag is set; invert passes the frames that would not match.
struct CanFilter {
  uint32_t id = 0;
  uint32_t mask = 0;
  bool extended = false;
  bool match_extended = true;  // compare the frame's extended flag with `extended`
  bool rtr = false;
  bool match_rtr = false;  // compare the frame's rtr flag with `rtr`
  bool invert = false;

  bool Matches(const CanFrame& frame) const;
  // A filter that passes exactly one standard id.
  static CanFilter Exact(uint32_t id, bool extended = false);
};

// "123:7FF" (id:mask), "123~7FF" (inverted), as candump takes them; hex.
std::optional<CanFilter> ParseCanFilter(std::string_view text, std::string* error = nullptr);

enum class CanBusState { kErrorActive, kErrorWarning, kErrorPassive, kBusOff };
const char* ToString(CanBusState state);

enum class CanErrorKind {
  kErrorWarning,  // an error counter crossed 96
  kErrorPassive,  // an error counter crossed 127
  kBusOff,        // transmit error counter crossed 255; the controller left the bus
  kRestarted,     // back to error-active after bus-off recovery
  kRxOverflow,    // a receive queue (controller, kernel or host) overflowed; frames lost
  kTxTimeout,     // a frame could not be sent in time
  kProtocol,      // a protocol error on the bus (stuff, form, CRC, bit error)
  kNoAck,         // a transmitted frame got no acknowledgement
  kAdapter,       // a serial adapter reported an error or sent an undecodable line
};
const char* ToString(CanErrorKind kind);

struct CanErrorEvent {
  CanErrorKind kind = CanErrorKind::kProtocol;
  std::chrono::nanoseconds timestamp{0};
  std::string detail;  // human-readable specifics (error counters, the bad line, ...)
};

struct CanCounters {
  uint64_t tx_frames = 0;     // frames handed to the bus
  uint64_t rx_frames = 0;     // frames delivered to the caller
  uint64_t rx_filtered = 0;   // frames dropped by a software acceptance filter
  uint64_t rx_overflows = 0;  // frames lost because a receive queue was full
  uint64_t tx_errors = 0;     // sends that failed (bus-off, queue full, I/O, NAK)
  uint64_t error_events = 0;  // error events raised (all kinds)
  uint64_t bus_off_events = 0;
  uint64_t decode_errors = 0;  // undecodable input skipped (slcan garbage, short frames)
};

}  // namespace kinevis::hal
