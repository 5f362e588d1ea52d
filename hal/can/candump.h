#pragma once

// The candump log format of can-utils (`candump -l` writes it to a file, `candump -L` to stdout;
// `canplayer` replays it, `log2long`/`log2asc` convert it). One frame per line:
//
//   (1436509052.249713) vcan0 044#2A366C2BBA       standard id: 3 hex digits, data as hex pairs
//   (1436509052.249713) vcan0 12345678#0102        extended id: 8 hex digits
//   (1436509052.249713) vcan0 123#R                remote frame; "123#R4" requests 4 bytes
//   (1436509052.249713) vcan0 20000080#0000000000000000   error frame: CAN_ERR_FLAG 0x20000000
//                                                          ORed into the error class, 8 digits
//
// The timestamp is seconds '.' microseconds. docs/can-log-format.md describes the format, what
// kinevis writes and reads, and how to replay a log with can-utils. CAN FD lines ("123##1...")
// are rejected: kinevis is classical CAN only (see can_frame.h).

#include <chrono>
#include <cstdint>
#include <fstream>
#include <optional>
#include <ostream>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

#include "hal/can/can_frame.h"

namespace kinevis::hal {

struct CandumpRecord {
  // Time of the line, since the Unix epoch when the log came from candump (any epoch is valid:
  // canplayer and the kinevis reader only use differences). Written with microsecond
  // resolution (truncated); must not be negative.
  std::chrono::nanoseconds timestamp{0};
  // Interface the frame was seen on ("can0", "vcan0"): non-empty, no whitespace. canplayer maps
  // interfaces by this name, and Linux interface names have at most 15 characters.
  std::string interface;
  // The frame. For a data or remote frame the id, flags, dlc and data are the frame's. For an
  // error frame (error_frame true) `frame.id` holds the error class bits (linux/can/error.h,
  // without CAN_ERR_FLAG), extended and rtr are false and dlc/data carry the error details
  // (normally dlc 8). The parser sets frame.timestamp to `timestamp`; the formatter ignores it.
  CanFrame frame;
  bool error_frame = false;
};

// One log line without the newline: "(1436509052.249713) vcan0 044#2A366C2BBA".
// Preconditions (checked by CandumpWriter::Write, not here): the interface is non-empty without
// whitespace and frame.Validate() is empty (error frames: id <= 0x1FFFFFFF, dlc <= 8).
// A negative timestamp is written as zero.
std::string FormatCandumpLine(const CandumpRecord& record);

// Parses one log line (surrounding whitespace and a trailing '\r' are allowed; so is the
// " R"/" T" direction field that `candump -x` appends, which is ignored). On failure returns
// nullopt and, when error is given, says what is wrong ("timestamp \"(12.3x)\" is not ...").
std::optional<CandumpRecord> ParseCandumpLine(std::string_view line, std::string* error = nullptr);

// Reads a whole log. Blank lines and lines whose first non-blank character is '#' are skipped.
// Throws ConfigError when the file cannot be read, or naming every bad line (up to 20) as
// "PATH:LINE: what is wrong", one per line of the message.
std::vector<CandumpRecord> ReadCandumpFile(const std::string& path);

// Writes records as candump log lines. Not thread-safe; give each thread its own writer or
// serialise the calls.
class CandumpWriter {
 public:
  // Writes to `out`, which must outlive the writer.
  explicit CandumpWriter(std::ostream& out);
  // Creates (truncates) the file at `path`; throws ConfigError when it cannot be created.
  explicit CandumpWriter(const std::string& path);
  CandumpWriter(const CandumpWriter&) = delete;
  CandumpWriter& operator=(const CandumpWriter&) = delete;

  // Appends one line. Returns Errc::kInvalidArgument (nothing written) for an empty interface,
  // an interface with whitespace, a negative timestamp or an invalid frame, and Errc::kIo when
  // the stream has failed (disk full, closed pipe). Does not flush.
  std::error_code Write(const CandumpRecord& record);
  // Flushes the stream; Errc::kIo when it has failed.
  std::error_code Flush();
  // Lines written so far.
  uint64_t lines_written() const { return lines_written_; }

 private:
  std::ofstream file_;  // used by the path constructor only
  std::ostream* out_;
  uint64_t lines_written_ = 0;
};

}  // namespace kinevis::hal
