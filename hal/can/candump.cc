#include "hal/can/candump.h"

#include <cerrno>
#include <cinttypes>
#include <cstdio>

#include "hal/common/error.h"

namespace kinevis::hal {
namespace {

// linux/can.h, repeated here so that the format code does not depend on kernel headers.
constexpr uint32_t kErrFlag = 0x20000000;
constexpr uint32_t kEffRtrFlags = 0xC0000000;
constexpr uint32_t kErrMask = 0x1FFFFFFF;
constexpr int kMaxReportedBadLines = 20;

bool IsBlank(char c) {
  return c == ' ' || c == '\t' || c == '\r' || c == '\n' || c == '\v' || c == '\f';
}
bool IsDigit(char c) { return c >= '0' && c <= '9'; }

std::string_view Trim(std::string_view s) {
  while (!s.empty() && IsBlank(s.front())) s.remove_prefix(1);
  while (!s.empty() && IsBlank(s.back())) s.remove_suffix(1);
  return s;
}

bool Fail(std::string* error, std::string message) {
  if (error != nullptr) *error = std::move(message);
  return false;
}

// "SECONDS.FRACTION" with 1..10 digits of seconds and 1..9 of fraction.
bool ParseTimestamp(std::string_view text, std::chrono::nanoseconds* out) {
  size_t dot = text.find('.');
  if (dot == std::string_view::npos) return false;
  std::string_view sec = text.substr(0, dot);
  std::string_view frac = text.substr(dot + 1);
  if (sec.empty() || sec.size() > 10 || frac.empty() || frac.size() > 9) return false;
  int64_t seconds = 0;
  for (char c : sec) {
    if (!IsDigit(c)) return false;
    seconds = seconds * 10 + (c - '0');
  }
  int64_t nanos = 0;
  for (char c : frac) {
    if (!IsDigit(c)) return false;
    nanos = nanos * 10 + (c - '0');
  }
  for (size_t i = frac.size(); i < 9; ++i) nanos *= 10;
  *out = std::chrono::nanoseconds(seconds * 1'000'000'000 + nanos);
  return true;
}

bool ParseHex32(std::string_view s, uint32_t* out) {
  if (s.empty() || s.size() > 8) return false;
  uint32_t v = 0;
  for (char c : s) {
    int h;
    if (c >= '0' && c <= '9') {
      h = c - '0';
    } else if (c >= 'a' && c <= 'f') {
      h = c - 'a' + 10;
    } else if (c >= 'A' && c <= 'F') {
      h = c - 'A' + 10;
    } else {
      return false;
    }
    v = (v << 4) | static_cast<uint32_t>(h);
  }
  *out = v;
  return true;
}

// The ID#DATA field; error frames are recognised by CAN_ERR_FLAG in an 8-digit id.
bool ParseFrameField(std::string_view text, CandumpRecord* record, std::string* error) {
  size_t hash = text.find('#');
  if (hash != std::string_view::npos && hash + 1 < text.size() && text[hash + 1] == '#') {
    return Fail(error, "CAN FD frame \"" + std::string(text) +
                           "\" is not supported (kinevis handles classical CAN only)");
  }
  if (text.find('_') != std::string_view::npos) {
    return Fail(error, "frame \"" + std::string(text) +
                           "\" has a DLC extension ('_'), which kinevis does not support");
  }
  uint32_t raw_id = 0;
  if (hash == 8 && ParseHex32(text.substr(0, 8), &raw_id) && (raw_id & kErrFlag) != 0) {
    if ((raw_id & kEffRtrFlags) != 0) {
      return Fail(error, "error frame id \"" + std::string(text.substr(0, 8)) +
                             "\" has bits above CAN_ERR_FLAG set");
    }
    std::string_view data = text.substr(hash + 1);
    if (!data.empty() && (data[0] == 'R' || data[0] == 'r')) {
      return Fail(error, "error frame \"" + std::string(text) + "\" cannot be a remote frame");
    }
    std::string why;
    std::optional<CanFrame> payload = ParseCanFrame("000#" + std::string(data), &why);
    if (!payload) return Fail(error, "error frame \"" + std::string(text) + "\": " + why);
    record->frame = *payload;
    record->frame.id = raw_id & kErrMask;
    record->error_frame = true;
    return true;
  }
  std::string why;
  std::optional<CanFrame> frame = ParseCanFrame(text, &why);
  if (!frame) return Fail(error, why);
  record->frame = *frame;
  record->error_frame = false;
  return true;
}

}  // namespace

std::string FormatCandumpLine(const CandumpRecord& record) {
  int64_t ns = record.timestamp.count();
  if (ns < 0) ns = 0;
  char stamp[48];
  std::snprintf(stamp, sizeof stamp, "(%010" PRId64 ".%06" PRId64 ") ", ns / 1'000'000'000,
                (ns % 1'000'000'000) / 1000);
  std::string line = stamp;
  line += record.interface;
  line += ' ';
  if (!record.error_frame) {
    line += FormatCanFrame(record.frame);
    return line;
  }
  char id[16];
  std::snprintf(id, sizeof id, "%08" PRIX32 "#", kErrFlag | (record.frame.id & kErrMask));
  line += id;
  static constexpr char kHex[] = "0123456789ABCDEF";
  for (int i = 0; i < record.frame.dlc && i < 8; ++i) {
    line += kHex[record.frame.data[i] >> 4];
    line += kHex[record.frame.data[i] & 0xF];
  }
  return line;
}

std::optional<CandumpRecord> ParseCandumpLine(std::string_view line, std::string* error) {
  std::string_view text = Trim(line);
  if (text.empty()) {
    Fail(error, "empty line; expected \"(SECONDS.MICROSECONDS) IFACE ID#DATA\"");
    return std::nullopt;
  }
  if (text[0] != '(') {
    Fail(error, "line \"" + std::string(text) +
                    "\" does not start with a timestamp \"(SECONDS.MICROSECONDS)\"");
    return std::nullopt;
  }
  size_t close = text.find(')');
  if (close == std::string_view::npos) {
    Fail(error, "timestamp in \"" + std::string(text) + "\" has no closing ')'");
    return std::nullopt;
  }
  CandumpRecord record;
  std::string_view stamp = text.substr(1, close - 1);
  if (!ParseTimestamp(stamp, &record.timestamp)) {
    Fail(error, "timestamp \"(" + std::string(stamp) +
                    ")\" is not SECONDS.FRACTION (decimal digits, e.g. (1436509052.249713))");
    return std::nullopt;
  }
  std::string_view rest = text.substr(close + 1);
  if (!rest.empty() && !IsBlank(rest[0])) {
    Fail(error, "expected a space after the timestamp \"(" + std::string(stamp) + ")\"");
    return std::nullopt;
  }
  std::vector<std::string_view> fields;
  while (true) {
    rest = Trim(rest);
    if (rest.empty()) break;
    size_t end = 0;
    while (end < rest.size() && !IsBlank(rest[end])) ++end;
    fields.push_back(rest.substr(0, end));
    rest.remove_prefix(end);
  }
  if (fields.empty()) {
    Fail(error, "missing interface and frame after the timestamp");
    return std::nullopt;
  }
  if (fields.size() == 1) {
    Fail(error, "missing frame after \"" + std::string(fields[0]) + "\"; expected IFACE ID#DATA");
    return std::nullopt;
  }
  if (fields.size() > 3 || (fields.size() == 3 && fields[2] != "R" && fields[2] != "T")) {
    Fail(error, "unexpected text \"" + std::string(fields[2]) + "\" after the frame \"" +
                    std::string(fields[1]) + "\"");
    return std::nullopt;
  }
  record.interface = std::string(fields[0]);
  if (!ParseFrameField(fields[1], &record, error)) return std::nullopt;
  record.frame.timestamp = record.timestamp;
  return record;
}

std::vector<CandumpRecord> ReadCandumpFile(const std::string& path) {
  errno = 0;
  std::ifstream in(path);
  if (!in.is_open()) {
    throw common::ConfigError(path + ": cannot open candump log: " +
                              (errno != 0 ? ErrnoText(errno) : std::string("unknown error")));
  }
  std::vector<CandumpRecord> records;
  std::string message;
  int bad_lines = 0;
  std::string line;
  for (int number = 1; std::getline(in, line); ++number) {
    std::string_view text = Trim(line);
    if (text.empty() || text[0] == '#') continue;
    std::string why;
    std::optional<CandumpRecord> record = ParseCandumpLine(text, &why);
    if (record) {
      records.push_back(std::move(*record));
      continue;
    }
    ++bad_lines;
    if (bad_lines <= kMaxReportedBadLines) {
      if (!message.empty()) message += '\n';
      message.append(path).append(":").append(std::to_string(number)).append(": ").append(why);
    }
  }
  if (in.bad()) throw common::ConfigError(path + ": read error in candump log");
  if (bad_lines > kMaxReportedBadLines) {
    message += "\n" + path + ": ... and " + std::to_string(bad_lines - kMaxReportedBadLines) +
               " more bad lines";
  }
  if (bad_lines > 0) throw common::ConfigError(message);
  return records;
}

CandumpWriter::CandumpWriter(std::ostream& out) : out_(&out) {}

CandumpWriter::CandumpWriter(const std::string& path) : out_(&file_) {
  errno = 0;
  file_.open(path, std::ios::out | std::ios::trunc);
  if (!file_.is_open()) {
    throw common::ConfigError(path + ": cannot create candump log: " +
                              (errno != 0 ? ErrnoText(errno) : std::string("unknown error")));
  }
}

std::error_code CandumpWriter::Write(const CandumpRecord& record) {
  if (record.interface.empty() || record.timestamp.count() < 0) return Errc::kInvalidArgument;
  for (char c : record.interface) {
    if (IsBlank(c) || c == '\0') return Errc::kInvalidArgument;
  }
  if (record.error_frame) {
    if (record.frame.id > kErrMask || record.frame.dlc > 8 || record.frame.rtr ||
        record.frame.extended) {
      return Errc::kInvalidArgument;
    }
  } else if (!record.frame.Validate().empty()) {
    return Errc::kInvalidArgument;
  }
  if (!*out_) return Errc::kIo;
  *out_ << FormatCandumpLine(record) << '\n';
  if (!*out_) return Errc::kIo;
  ++lines_written_;
  return {};
}

std::error_code CandumpWriter::Flush() {
  out_->flush();
  return *out_ ? std::error_code() : make_error_code(Errc::kIo);
}

}  // namespace kinevis::hal
