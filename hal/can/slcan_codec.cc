#include "hal/can/slcan_codec.h"

#include "hal/common/backend_spec.h"

namespace kinevis::hal {
namespace {

constexpr char kHexDigits[] = "0123456789ABCDEF";
constexpr int kBitrates[] = {10000, 20000, 50000, 100000, 125000, 250000, 500000, 800000, 1000000};

int HexValue(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  return -1;
}

bool ParseHex(std::string_view s, uint32_t* out) {
  uint32_t v = 0;
  for (char c : s) {
    int h = HexValue(c);
    if (h < 0) return false;
    v = (v << 4) | static_cast<uint32_t>(h);
  }
  *out = v;
  return true;
}

bool Fail(std::string* error, std::string message) {
  if (error != nullptr) *error = std::move(message);
  return false;
}

// A t/T/r/R line without its '\r'. The adapter appends a timestamp, the host never does.
bool ParseFrameLine(std::string_view line, bool allow_timestamp, CanFrame* frame,
                    bool* has_timestamp, uint16_t* timestamp_ms, std::string* error) {
  const char type = line[0];
  const bool extended = type == 'T' || type == 'R';
  const bool rtr = type == 'r' || type == 'R';
  const size_t id_digits = extended ? 8 : 3;
  if (line.size() < 1 + id_digits + 1) {
    return Fail(error, "frame line too short for the id and the length digit");
  }
  uint32_t id = 0;
  if (!ParseHex(line.substr(1, id_digits), &id)) return Fail(error, "frame id is not hexadecimal");
  if (id > (extended ? CanFrame::kMaxExtendedId : CanFrame::kMaxStandardId)) {
    return Fail(error, extended ? "frame id exceeds 29 bits" : "frame id exceeds 11 bits");
  }
  const char dlc_char = line[1 + id_digits];
  if (dlc_char < '0' || dlc_char > '8') return Fail(error, "length digit is not 0..8");
  const int dlc = dlc_char - '0';
  const size_t data_digits = rtr ? 0 : static_cast<size_t>(2 * dlc);
  const size_t base = 1 + id_digits + 1 + data_digits;
  bool with_timestamp = false;
  if (line.size() == base + 4 && allow_timestamp) {
    with_timestamp = true;
  } else if (line.size() != base) {
    return Fail(error,
                "frame line has " + std::to_string(line.size()) + " characters, expected " +
                    std::to_string(base) +
                    (allow_timestamp ? " (or " + std::to_string(base + 4) + " with a timestamp)"
                                     : std::string()));
  }
  CanFrame f;
  f.id = id;
  f.extended = extended;
  f.rtr = rtr;
  f.dlc = static_cast<uint8_t>(dlc);
  for (size_t i = 0; i < data_digits; i += 2) {
    int hi = HexValue(line[base - data_digits + i]);
    int lo = HexValue(line[base - data_digits + i + 1]);
    if (hi < 0 || lo < 0) return Fail(error, "frame data are not hexadecimal");
    f.data[i / 2] = static_cast<uint8_t>(hi << 4 | lo);
  }
  uint32_t ts = 0;
  if (with_timestamp) {
    if (!ParseHex(line.substr(base, 4), &ts)) return Fail(error, "timestamp is not hexadecimal");
    if (ts > kSlcanMaxTimestampMs) return Fail(error, "timestamp exceeds 59999 ms (EA5F)");
  }
  *frame = f;
  if (has_timestamp != nullptr) *has_timestamp = with_timestamp;
  if (timestamp_ms != nullptr) *timestamp_ms = static_cast<uint16_t>(ts);
  return true;
}

bool IsFrameType(char c) { return c == 't' || c == 'T' || c == 'r' || c == 'R'; }

// Version and serial-number characters: printable ASCII without the space.
bool PrintableField(std::string_view s) {
  for (char c : s) {
    if (c <= ' ' || c > '~') return false;
  }
  return true;
}

// An adapter-to-host line without its '\r'.
bool ParseAdapterLine(std::string_view line, SlcanEvent* event) {
  if (line.empty()) {
    event->kind = SlcanEvent::Kind::kOk;
    return true;
  }
  const char type = line[0];
  if (IsFrameType(type)) {
    event->kind = SlcanEvent::Kind::kFrame;
    return ParseFrameLine(line, /*allow_timestamp=*/true, &event->frame, &event->has_timestamp,
                          &event->timestamp_ms, nullptr);
  }
  if ((type == 'z' || type == 'Z') && line.size() == 1) {
    event->kind = SlcanEvent::Kind::kTxAck;
    event->extended_ack = type == 'Z';
    return true;
  }
  if ((type == 'V' || type == 'N') && line.size() == 5 && PrintableField(line.substr(1))) {
    event->kind = type == 'V' ? SlcanEvent::Kind::kVersion : SlcanEvent::Kind::kSerialNumber;
    event->text.assign(line.data() + 1, 4);
    return true;
  }
  uint32_t status = 0;
  if (type == 'F' && line.size() == 3 && ParseHex(line.substr(1), &status)) {
    event->kind = SlcanEvent::Kind::kStatus;
    event->status = static_cast<uint8_t>(status);
    return true;
  }
  return false;
}

}  // namespace

int SlcanBitrateFromCode(int code) {
  if (code < 0 || code > 8) return -1;
  return kBitrates[code];
}

size_t EncodeSlcanFrame(const CanFrame& frame, char* buffer, std::optional<uint16_t> timestamp_ms) {
  if (!frame.Validate().empty()) return 0;
  if (timestamp_ms && *timestamp_ms > kSlcanMaxTimestampMs) return 0;
  char* p = buffer;
  if (frame.extended) {
    *p++ = frame.rtr ? 'R' : 'T';
    for (int shift = 28; shift >= 0; shift -= 4) *p++ = kHexDigits[(frame.id >> shift) & 0xF];
  } else {
    *p++ = frame.rtr ? 'r' : 't';
    for (int shift = 8; shift >= 0; shift -= 4) *p++ = kHexDigits[(frame.id >> shift) & 0xF];
  }
  *p++ = static_cast<char>('0' + frame.dlc);
  if (!frame.rtr) {
    for (int i = 0; i < frame.dlc; ++i) {
      *p++ = kHexDigits[frame.data[i] >> 4];
      *p++ = kHexDigits[frame.data[i] & 0xF];
    }
  }
  if (timestamp_ms) {
    for (int shift = 12; shift >= 0; shift -= 4) *p++ = kHexDigits[(*timestamp_ms >> shift) & 0xF];
  }
  *p++ = '\r';
  return static_cast<size_t>(p - buffer);
}

std::string SlcanFrameLine(const CanFrame& frame, std::optional<uint16_t> timestamp_ms) {
  char buffer[kSlcanMaxLineSize];
  return std::string(buffer, EncodeSlcanFrame(frame, buffer, timestamp_ms));
}

SlcanCommand SlcanCommand::Simple(Kind kind) {
  SlcanCommand c;
  c.kind = kind;
  return c;
}

SlcanCommand SlcanCommand::SetBitrate(int bitrate_code) {
  SlcanCommand c;
  c.kind = Kind::kSetBitrate;
  c.bitrate_code = bitrate_code;
  return c;
}

SlcanCommand SlcanCommand::Timestamps(bool on) {
  SlcanCommand c;
  c.kind = Kind::kTimestamps;
  c.timestamps_on = on;
  return c;
}

SlcanCommand SlcanCommand::Transmit(const CanFrame& frame) {
  SlcanCommand c;
  c.kind = Kind::kTransmit;
  c.frame = frame;
  return c;
}

std::string EncodeSlcanCommand(const SlcanCommand& command) {
  using Kind = SlcanCommand::Kind;
  switch (command.kind) {
    case Kind::kTransmit:
      return SlcanFrameLine(command.frame);
    case Kind::kSetBitrate:
      if (command.bitrate_code < 0 || command.bitrate_code > 8) return {};
      return std::string{'S', static_cast<char>('0' + command.bitrate_code), '\r'};
    case Kind::kOpen:
      return "O\r";
    case Kind::kListenOnly:
      return "L\r";
    case Kind::kClose:
      return "C\r";
    case Kind::kVersion:
      return "V\r";
    case Kind::kSerialNumber:
      return "N\r";
    case Kind::kStatus:
      return "F\r";
    case Kind::kTimestamps:
      return command.timestamps_on ? "Z1\r" : "Z0\r";
  }
  return {};
}

std::string EncodeSlcanBitrate(int bitrate) {
  const int code = SlcanBitrateCode(bitrate);
  if (code < 0) return {};
  return EncodeSlcanCommand(SlcanCommand::SetBitrate(code));
}

std::optional<SlcanCommand> ParseSlcanCommand(std::string_view line, std::string* error) {
  using Kind = SlcanCommand::Kind;
  if (line.empty()) {
    Fail(error, "empty line");
    return std::nullopt;
  }
  const char type = line[0];
  if (IsFrameType(type)) {
    SlcanCommand c = SlcanCommand::Simple(Kind::kTransmit);
    if (!ParseFrameLine(line, /*allow_timestamp=*/false, &c.frame, nullptr, nullptr, error)) {
      return std::nullopt;
    }
    return c;
  }
  if (line.size() == 1) {
    switch (type) {
      case 'O':
        return SlcanCommand::Simple(Kind::kOpen);
      case 'L':
        return SlcanCommand::Simple(Kind::kListenOnly);
      case 'C':
        return SlcanCommand::Simple(Kind::kClose);
      case 'V':
        return SlcanCommand::Simple(Kind::kVersion);
      case 'N':
        return SlcanCommand::Simple(Kind::kSerialNumber);
      case 'F':
        return SlcanCommand::Simple(Kind::kStatus);
      default:
        break;
    }
  }
  if (type == 'S' && line.size() == 2 && line[1] >= '0' && line[1] <= '8') {
    return SlcanCommand::SetBitrate(line[1] - '0');
  }
  if (type == 'Z' && line.size() == 2 && (line[1] == '0' || line[1] == '1')) {
    return SlcanCommand::Timestamps(line[1] == '1');
  }
  Fail(error, "unknown or malformed command \"" + std::string(line.substr(0, 32)) + "\"");
  return std::nullopt;
}

const char* ToString(SlcanEvent::Kind kind) {
  switch (kind) {
    case SlcanEvent::Kind::kFrame:
      return "frame";
    case SlcanEvent::Kind::kOk:
      return "ok";
    case SlcanEvent::Kind::kError:
      return "error";
    case SlcanEvent::Kind::kTxAck:
      return "tx-ack";
    case SlcanEvent::Kind::kVersion:
      return "version";
    case SlcanEvent::Kind::kSerialNumber:
      return "serial-number";
    case SlcanEvent::Kind::kStatus:
      return "status";
    case SlcanEvent::Kind::kInvalid:
      return "invalid";
  }
  return "?";
}

void SlcanDecoder::Feed(const uint8_t* data, size_t size, const EventCallback& on_event) {
  for (size_t i = 0; i < size; ++i) {
    const char c = static_cast<char>(data[i]);
    if (c == '\r' || c == kSlcanBell) {
      if (skipping_) {
        skipping_ = false;
      } else if (c == '\r') {
        EndLine(on_event);
      } else if (size_ > 0) {
        // A BEL inside a line: the line lost its '\r' (or is garbage); the BEL itself is a reply.
        EmitInvalid(on_event, /*truncated=*/false);
      }
      if (c == kSlcanBell) {
        event_.kind = SlcanEvent::Kind::kError;
        on_event(event_);
      }
      size_ = 0;
      after_terminator_ = true;
      continue;
    }
    if (skipping_) {
      ++discarded_bytes_;
      continue;
    }
    if (c == '\n' && size_ == 0 && after_terminator_) {
      after_terminator_ = false;
      continue;
    }
    after_terminator_ = false;
    if (size_ == line_.size()) {
      ++discarded_bytes_;  // this byte; the buffered ones are counted by EmitInvalid
      EmitInvalid(on_event, /*truncated=*/true);
      size_ = 0;
      skipping_ = true;
      continue;
    }
    line_[size_++] = c;
  }
}

void SlcanDecoder::Reset() {
  size_ = 0;
  skipping_ = false;
  after_terminator_ = true;
}

void SlcanDecoder::EndLine(const EventCallback& on_event) {
  if (ParseAdapterLine(std::string_view(line_.data(), size_), &event_)) {
    on_event(event_);
  } else {
    EmitInvalid(on_event, /*truncated=*/false);
  }
}

void SlcanDecoder::EmitInvalid(const EventCallback& on_event, bool truncated) {
  ++decode_errors_;
  discarded_bytes_ += size_;
  // Escaped so that the text can go into a log line as it is: printable ASCII stays, every other
  // byte becomes \xNN.
  std::string& text = event_.text;
  text.clear();
  for (size_t i = 0; i < size_; ++i) {
    const auto b = static_cast<unsigned char>(line_[i]);
    if (b >= 0x20 && b < 0x7F && b != '\\') {
      text += static_cast<char>(b);
    } else {
      text += '\\';
      text += 'x';
      text += kHexDigits[b >> 4];
      text += kHexDigits[b & 0xF];
    }
  }
  if (truncated) text += "...";
  last_invalid_ = text;
  event_.kind = SlcanEvent::Kind::kInvalid;
  on_event(event_);
}

}  // namespace kinevis::hal
