#include "hal/can/can_frame.h"

#include <algorithm>
#include <cstdio>

#include "common/check.h"

namespace kinevis::hal {
namespace {

int HexValue(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}

bool Fail(std::string* error, std::string message) {
  if (error != nullptr) *error = std::move(message);
  return false;
}

bool ParseHexU32(std::string_view s, uint32_t* out) {
  if (s.empty() || s.size() > 8) return false;
  uint32_t v = 0;
  for (char c : s) {
    int h = HexValue(c);
    if (h < 0) return false;
    v = (v << 4) | static_cast<uint32_t>(h);
  }
  *out = v;
  return true;
}

}  // namespace

CanFrame CanFrame::Standard(uint32_t id, std::initializer_list<uint8_t> payload) {
  KINEVIS_DEMAND(id <= kMaxStandardId && payload.size() <= 8);
  CanFrame f;
  f.id = id;
  f.dlc = static_cast<uint8_t>(payload.size());
  std::copy(payload.begin(), payload.end(), f.data.begin());
  return f;
}

CanFrame CanFrame::Extended(uint32_t id, std::initializer_list<uint8_t> payload) {
  KINEVIS_DEMAND(id <= kMaxExtendedId && payload.size() <= 8);
  CanFrame f = Standard(0, payload);
  f.id = id;
  f.extended = true;
  return f;
}

std::string CanFrame::Validate() const {
  char buf[96];
  if (extended && id > kMaxExtendedId) {
    std::snprintf(buf, sizeof buf, "id 0x%X exceeds 29 bits", id);
    return buf;
  }
  if (!extended && id > kMaxStandardId) {
    std::snprintf(buf, sizeof buf, "id 0x%X exceeds 11 bits (set extended for a 29-bit id)", id);
    return buf;
  }
  if (dlc > 8) {
    std::snprintf(buf, sizeof buf, "dlc %u exceeds 8", static_cast<unsigned>(dlc));
    return buf;
  }
  return {};
}

bool operator==(const CanFrame& a, const CanFrame& b) {
  if (a.id != b.id || a.extended != b.extended || a.rtr != b.rtr || a.dlc != b.dlc) return false;
  if (a.rtr) return true;
  for (int i = 0; i < a.dlc && i < 8; ++i) {
    if (a.data[i] != b.data[i]) return false;
  }
  return true;
}

std::string FormatCanFrame(const CanFrame& frame) {
  char buf[40];
  int n = std::snprintf(buf, sizeof buf, frame.extended ? "%08X#" : "%03X#", frame.id);
  std::string out(buf, n);
  if (frame.rtr) {
    out += 'R';
    if (frame.dlc > 0) out += static_cast<char>('0' + frame.dlc);
    return out;
  }
  static constexpr char kHex[] = "0123456789ABCDEF";
  for (int i = 0; i < frame.dlc && i < 8; ++i) {
    out += kHex[frame.data[i] >> 4];
    out += kHex[frame.data[i] & 0xF];
  }
  return out;
}

std::optional<CanFrame> ParseCanFrame(std::string_view text, std::string* error) {
  size_t hash = text.find('#');
  if (hash == std::string_view::npos) {
    Fail(error,
         "frame \"" + std::string(text) + "\" has no '#'; expected ID#DATA like 123#DEADBEEF");
    return std::nullopt;
  }
  std::string_view id_text = text.substr(0, hash);
  std::string_view data_text = text.substr(hash + 1);
  CanFrame f;
  if (id_text.size() != 3 && id_text.size() != 8) {
    Fail(error, "frame id \"" + std::string(id_text) +
                    "\" must be 3 hex digits (standard) or 8 hex digits (extended)");
    return std::nullopt;
  }
  if (!ParseHexU32(id_text, &f.id)) {
    Fail(error, "frame id \"" + std::string(id_text) + "\" is not hexadecimal");
    return std::nullopt;
  }
  f.extended = id_text.size() == 8;
  if (!data_text.empty() && (data_text[0] == 'R' || data_text[0] == 'r')) {
    f.rtr = true;
    if (data_text.size() == 2 && data_text[1] >= '0' && data_text[1] <= '8') {
      f.dlc = static_cast<uint8_t>(data_text[1] - '0');
    } else if (data_text.size() != 1) {
      Fail(error, "remote frame \"" + std::string(text) + "\": expected R or R0..R8 after '#'");
      return std::nullopt;
    }
  } else {
    std::string hex;
    for (char c : data_text) {
      if (c != '.') hex += c;  // cansend allows '.' as a byte separator
    }
    if (hex.size() % 2 != 0 || hex.size() > 16) {
      Fail(error, "frame data \"" + std::string(data_text) +
                      "\" must be 0..8 bytes as pairs of hex digits");
      return std::nullopt;
    }
    for (size_t i = 0; i < hex.size(); i += 2) {
      int hi = HexValue(hex[i]), lo = HexValue(hex[i + 1]);
      if (hi < 0 || lo < 0) {
        Fail(error, "frame data \"" + std::string(data_text) + "\" is not hexadecimal");
        return std::nullopt;
      }
      f.data[i / 2] = static_cast<uint8_t>(hi << 4 | lo);
    }
    f.dlc = static_cast<uint8_t>(hex.size() / 2);
  }
  std::string why = f.Validate();
  if (!why.empty()) {
    Fail(error, "frame \"" + std::string(text) + "\": " + why);
    return std::nullopt;
  }
  return f;
}

int CanFrameWireBits(const CanFrame& frame) {
  // The bits from start of frame to the end of the data field, as transmitted before stuffing
  // (ISO 11898-1): 0 is dominant.
  // At most 1 + 32 + 6 + 4 + 64 + 15 = 122 bits before stuffing; no allocation.
  std::array<bool, 128> bits{};
  size_t n_bits = 0;
  auto put = [&bits, &n_bits](uint32_t value, int count) {
    for (int i = count - 1; i >= 0; --i) bits[n_bits++] = ((value >> i) & 1u) != 0;
  };
  put(0, 1);  // SOF
  if (frame.extended) {
    put(frame.id >> 18, 11);      // base id
    put(1, 1);                    // SRR (recessive)
    put(1, 1);                    // IDE (recessive: extended)
    put(frame.id & 0x3FFFF, 18);  // id extension
    put(frame.rtr ? 1 : 0, 1);    // RTR
    put(0, 2);                    // r1, r0
  } else {
    put(frame.id, 11);
    put(frame.rtr ? 1 : 0, 1);  // RTR
    put(0, 1);                  // IDE (dominant: standard)
    put(0, 1);                  // r0
  }
  put(frame.dlc, 4);
  int data_bytes = frame.rtr ? 0 : std::min<int>(frame.dlc, 8);
  for (int i = 0; i < data_bytes; ++i) put(frame.data[i], 8);
  // CRC-15, polynomial 0x4599, over SOF..data.
  uint32_t crc = 0;
  for (size_t i = 0; i < n_bits; ++i) {
    const bool b = bits[i];
    bool crc_next = b ^ (((crc >> 14) & 1u) != 0);
    crc = (crc << 1) & 0x7FFF;
    if (crc_next) crc ^= 0x4599;
  }
  put(crc, 15);
  // Stuffing applies from SOF to the end of the CRC sequence: after five equal bits a
  // complementary bit is inserted, and the stuff bit itself starts the next run.
  int stuff = 0;
  int run = 0;
  bool last = false;
  for (size_t i = 0; i < n_bits; ++i) {
    if (i > 0 && bits[i] == last) {
      ++run;
    } else {
      run = 1;
      last = bits[i];
    }
    if (run == 5) {
      ++stuff;
      last = !last;
      run = 1;
    }
  }
  // CRC delimiter, ACK slot, ACK delimiter, 7-bit end of frame, 3-bit interframe space.
  return static_cast<int>(n_bits) + stuff + 1 + 1 + 1 + 7 + 3;
}

bool CanFilter::Matches(const CanFrame& frame) const {
  bool match = (frame.id & mask) == (id & mask);
  if (match_extended && frame.extended != extended) match = false;
  if (match_rtr && frame.rtr != rtr) match = false;
  return invert ? !match : match;
}

CanFilter CanFilter::Exact(uint32_t id, bool extended) {
  CanFilter f;
  f.id = id;
  f.extended = extended;
  f.mask = extended ? CanFrame::kMaxExtendedId : CanFrame::kMaxStandardId;
  return f;
}

std::optional<CanFilter> ParseCanFilter(std::string_view text, std::string* error) {
  size_t sep = text.find_first_of(":~");
  if (sep == std::string_view::npos) {
    Fail(error, "filter \"" + std::string(text) + "\" is not ID:MASK or ID~MASK (hex)");
    return std::nullopt;
  }
  CanFilter f;
  std::string_view id_text = text.substr(0, sep);
  if (!ParseHexU32(id_text, &f.id) || !ParseHexU32(text.substr(sep + 1), &f.mask)) {
    Fail(error, "filter \"" + std::string(text) + "\": id and mask must be hexadecimal");
    return std::nullopt;
  }
  f.invert = text[sep] == '~';
  f.extended = id_text.size() == 8 || f.id > CanFrame::kMaxStandardId;
  f.match_extended = true;
  return f;
}

const char* ToString(CanBusState state) {
  switch (state) {
    case CanBusState::kErrorActive:
      return "error-active";
    case CanBusState::kErrorWarning:
      return "error-warning";
    case CanBusState::kErrorPassive:
      return "error-passive";
    case CanBusState::kBusOff:
      return "bus-off";
  }
  return "?";
}

const char* ToString(CanErrorKind kind) {
  switch (kind) {
    case CanErrorKind::kErrorWarning:
      return "error-warning";
    case CanErrorKind::kErrorPassive:
      return "error-passive";
    case CanErrorKind::kBusOff:
      return "bus-off";
    case CanErrorKind::kRestarted:
      return "restarted";
    case CanErrorKind::kRxOverflow:
      return "rx-overflow";
    case CanErrorKind::kTxTimeout:
      return "tx-timeout";
    case CanErrorKind::kProtocol:
      return "protocol-error";
    case CanErrorKind::kNoAck:
      return "no-ack";
    case CanErrorKind::kAdapter:
      return "adapter-error";
  }
  return "?";
}

}  // namespace kinevis::hal
