#include "hal/can/candump.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "hal/common/error.h"
#include "tests/utilities/subprocess.h"

namespace kinevis::hal {
namespace {

using std::chrono::nanoseconds;
using ::testing::ContainsRegex;
using ::testing::HasSubstr;

// The example line of the can-utils documentation: (1436509052.249713) vcan0 044#2A366C2BBA
constexpr nanoseconds kExampleTime{1436509052'249713000};

CandumpRecord Record(nanoseconds t, const std::string& iface, const CanFrame& frame,
                     bool error_frame = false) {
  CandumpRecord r;
  r.timestamp = t;
  r.interface = iface;
  r.frame = frame;
  r.error_frame = error_frame;
  return r;
}

CanFrame Remote(uint32_t id, bool extended, uint8_t dlc) {
  CanFrame f = extended ? CanFrame::Extended(id) : CanFrame::Standard(id);
  f.rtr = true;
  f.dlc = dlc;
  return f;
}

// An error frame as the kernel reports it: class bits in the id, 8 bytes of details.
CanFrame ErrorPayload(uint32_t error_class, std::initializer_list<uint8_t> data) {
  CanFrame f = CanFrame::Standard(0, data);
  f.id = error_class;
  return f;
}

std::string TempPath(const std::string& stem) {
  return ::testing::TempDir() + "/kinevis_candump_" + stem + "_" + std::to_string(::getpid()) +
         ".log";
}

void WriteText(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::trunc);
  out << text;
  ASSERT_TRUE(out.good()) << path;
}

struct FormatCase {
  CandumpRecord record;
  std::string line;
};

std::vector<FormatCase> CanUtilsVectors() {
  return {
      {Record(kExampleTime, "vcan0", CanFrame::Standard(0x044, {0x2A, 0x36, 0x6C, 0x2B, 0xBA})),
       "(1436509052.249713) vcan0 044#2A366C2BBA"},
      {Record(kExampleTime, "can1", CanFrame::Extended(0x12345678, {0x01, 0x02})),
       "(1436509052.249713) can1 12345678#0102"},
      {Record(kExampleTime, "can0", CanFrame::Extended(0x1, {})),
       "(1436509052.249713) can0 00000001#"},
      {Record(kExampleTime, "can0", CanFrame::Standard(0x7FF, {})),
       "(1436509052.249713) can0 7FF#"},
      {Record(kExampleTime, "can0",
              CanFrame::Standard(0x000, {0x00, 0x11, 0x22, 0x33, 0x44, 0x55, 0x66, 0xFF})),
       "(1436509052.249713) can0 000#00112233445566FF"},
      {Record(kExampleTime, "vcan0", Remote(0x123, false, 0)), "(1436509052.249713) vcan0 123#R"},
      {Record(kExampleTime, "vcan0", Remote(0x123, false, 4)), "(1436509052.249713) vcan0 123#R4"},
      {Record(kExampleTime, "vcan0", Remote(0x1FFFFFFF, true, 8)),
       "(1436509052.249713) vcan0 1FFFFFFF#R8"},
      // CAN_ERR_BUSERROR | CAN_ERR_PROT with a stuff error in the CRC sequence.
      {Record(kExampleTime, "can0", ErrorPayload(0x88, {0, 0, 0x04, 0x08, 0, 0, 0x10, 0x02}), true),
       "(1436509052.249713) can0 20000088#0000040800001002"},
      // CAN_ERR_BUSOFF
      {Record(kExampleTime, "can0", ErrorPayload(0x40, {0, 0, 0, 0, 0, 0, 0, 0}), true),
       "(1436509052.249713) can0 20000040#0000000000000000"},
      // Seconds are zero-padded to 10 digits, the fraction to 6.
      {Record(nanoseconds(1'500'000'000), "vcan0", CanFrame::Standard(0x1, {0xAB})),
       "(0000000001.500000) vcan0 001#AB"},
      {Record(nanoseconds(0), "vcan0", CanFrame::Standard(0x1, {})),
       "(0000000000.000000) vcan0 001#"},
  };
}

TEST(CandumpFormatTest, WritesTheCanUtilsLogSyntax) {
  for (const FormatCase& c : CanUtilsVectors()) {
    EXPECT_EQ(FormatCandumpLine(c.record), c.line);
  }
}

TEST(CandumpFormatTest, TruncatesTimestampsToMicroseconds) {
  CandumpRecord r = Record(nanoseconds(1'000'001'999), "vcan0", CanFrame::Standard(0x1));
  EXPECT_EQ(FormatCandumpLine(r), "(0000000001.000001) vcan0 001#");
}

TEST(CandumpFormatTest, WritesNegativeTimestampsAsZero) {
  CandumpRecord r = Record(nanoseconds(-5), "vcan0", CanFrame::Standard(0x1));
  EXPECT_EQ(FormatCandumpLine(r), "(0000000000.000000) vcan0 001#");
}

TEST(CandumpParseTest, ReadsTheCanUtilsLogSyntax) {
  for (const FormatCase& c : CanUtilsVectors()) {
    std::string error;
    std::optional<CandumpRecord> r = ParseCandumpLine(c.line, &error);
    ASSERT_TRUE(r.has_value()) << c.line << ": " << error;
    EXPECT_EQ(r->timestamp, c.record.timestamp) << c.line;
    EXPECT_EQ(r->interface, c.record.interface) << c.line;
    EXPECT_EQ(r->error_frame, c.record.error_frame) << c.line;
    EXPECT_EQ(r->frame, c.record.frame) << c.line;
    EXPECT_EQ(r->frame.timestamp, c.record.timestamp) << c.line;
  }
}

TEST(CandumpParseTest, ErrorFrameKeepsTheClassWithoutTheFlag) {
  std::optional<CandumpRecord> r =
      ParseCandumpLine("(1436509052.649847) vcan0 20000080#0000000000000000");
  ASSERT_TRUE(r.has_value());
  EXPECT_TRUE(r->error_frame);
  EXPECT_EQ(r->frame.id, 0x80u);
  EXPECT_FALSE(r->frame.extended);
  EXPECT_FALSE(r->frame.rtr);
  EXPECT_EQ(r->frame.dlc, 8);
}

TEST(CandumpParseTest, AcceptsWhatCandumpAndEditorsAddAroundTheLine) {
  // Lower-case hex, padding between the fields, a CRLF line end, the `candump -x` direction.
  for (const char* line :
       {"(1436509052.249713) vcan0 044#2a366c2bba",
        "  (1436509052.249713)   vcan0   044#2A366C2BBA  ",
        "(1436509052.249713) vcan0 044#2A366C2BBA\r", "(1436509052.249713) vcan0 044#2A366C2BBA R",
        "(1436509052.249713) vcan0 044#2A366C2BBA T"}) {
    std::string error;
    std::optional<CandumpRecord> r = ParseCandumpLine(line, &error);
    ASSERT_TRUE(r.has_value()) << line << ": " << error;
    EXPECT_EQ(r->frame, CanFrame::Standard(0x044, {0x2A, 0x36, 0x6C, 0x2B, 0xBA})) << line;
    EXPECT_EQ(r->interface, "vcan0") << line;
    EXPECT_EQ(r->timestamp, kExampleTime) << line;
  }
}

TEST(CandumpParseTest, ScalesShortAndLongFractions) {
  std::optional<CandumpRecord> r = ParseCandumpLine("(12.5) can0 001#");
  ASSERT_TRUE(r.has_value());
  EXPECT_EQ(r->timestamp, nanoseconds(12'500'000'000));
  r = ParseCandumpLine("(12.000000123) can0 001#");
  ASSERT_TRUE(r.has_value());
  EXPECT_EQ(r->timestamp, nanoseconds(12'000'000'123));
}

struct MalformedCase {
  const char* line;
  const char* message_regex;
};

TEST(CandumpParseTest, RejectsMalformedLinesSayingWhatIsWrong) {
  const MalformedCase cases[] = {
      {"", "empty line"},
      {"1436509052.249713 vcan0 123#00", "does not start with a timestamp"},
      {"(1436509052.249713 vcan0 123#00", "no closing '\\)'"},
      {"(14365x9052.249713) vcan0 123#00",
       "timestamp \"\\(14365x9052.249713\\)\" is not "
       "SECONDS.FRACTION"},
      {"(1436509052) vcan0 123#00", "timestamp \"\\(1436509052\\)\" is not SECONDS.FRACTION"},
      {"(1436509052.) vcan0 123#00", "is not SECONDS.FRACTION"},
      {"(1436509052.1234567890) vcan0 123#00", "is not SECONDS.FRACTION"},
      {"(1436509052.249713)vcan0 123#00", "expected a space after the timestamp"},
      {"(1436509052.249713)", "missing interface and frame"},
      {"(1436509052.249713) vcan0", "missing frame after \"vcan0\""},
      {"(1436509052.249713) vcan0 123#00 extra", "unexpected text \"extra\" after the frame"},
      {"(1436509052.249713) vcan0 123#00 R T", "unexpected text"},
      {"(1436509052.249713) vcan0 123", "has no '#'"},
      {"(1436509052.249713) vcan0 1234#00", "3 hex digits \\(standard\\) or 8 hex digits"},
      {"(1436509052.249713) vcan0 12G#00", "not hexadecimal"},
      {"(1436509052.249713) vcan0 800#00", "exceeds 11 bits"},
      {"(1436509052.249713) vcan0 123#0", "pairs of hex digits"},
      {"(1436509052.249713) vcan0 123#001122334455667788", "0\\.\\.8 bytes"},
      {"(1436509052.249713) vcan0 123#R9", "expected R or R0\\.\\.R8"},
      {"(1436509052.249713) vcan0 123##1001122", "CAN FD frame .* is not supported"},
      {"(1436509052.249713) vcan0 123#1122_9", "DLC extension"},
      {"(1436509052.249713) vcan0 A0000080#00", "error frame id \"A0000080\" has bits above"},
      {"(1436509052.249713) vcan0 20000080#R", "error frame .* cannot be a remote frame"},
      {"(1436509052.249713) vcan0 20000080#0", "error frame .*pairs of hex digits"},
  };
  for (const MalformedCase& c : cases) {
    std::string error;
    EXPECT_FALSE(ParseCandumpLine(c.line, &error).has_value()) << c.line;
    EXPECT_THAT(error, ContainsRegex(c.message_regex)) << "line: " << c.line;
    // Without an error string the parser still fails, and does not crash.
    EXPECT_FALSE(ParseCandumpLine(c.line).has_value()) << c.line;
  }
}

TEST(CandumpRoundTripTest, RandomRecordsSurviveFormatAndParse) {
  std::mt19937 rng(20240611);
  std::uniform_int_distribution<uint32_t> id11(0, CanFrame::kMaxStandardId);
  std::uniform_int_distribution<uint32_t> id29(0, CanFrame::kMaxExtendedId);
  std::uniform_int_distribution<int> dlc(0, 8);
  std::uniform_int_distribution<int> byte(0, 255);
  std::uniform_int_distribution<int> kind(0, 4);
  std::uniform_int_distribution<int64_t> micros(0, 4'102'444'800'000'000);  // up to year 2100
  const char* interfaces[] = {"can0", "vcan0", "can12", "slcan0", "any"};
  for (int i = 0; i < 2000; ++i) {
    CandumpRecord r;
    r.timestamp = std::chrono::microseconds(micros(rng));
    r.interface = interfaces[i % 5];
    const int k = kind(rng);
    r.frame.extended = k == 1 || k == 3;
    r.frame.rtr = k == 2 || k == 3;
    r.frame.id = r.frame.extended ? id29(rng) : id11(rng);
    r.frame.dlc = static_cast<uint8_t>(dlc(rng));
    if (!r.frame.rtr) {
      for (int b = 0; b < r.frame.dlc; ++b) r.frame.data[b] = static_cast<uint8_t>(byte(rng));
    }
    if (k == 4) {  // an error frame: any class bits, details in the payload
      r.error_frame = true;
      r.frame.extended = false;
      r.frame.id = id29(rng) & 0x3FF;
    }
    const std::string line = FormatCandumpLine(r);
    std::string error;
    std::optional<CandumpRecord> back = ParseCandumpLine(line, &error);
    ASSERT_TRUE(back.has_value()) << line << ": " << error;
    EXPECT_EQ(back->timestamp, r.timestamp) << line;
    EXPECT_EQ(back->interface, r.interface) << line;
    EXPECT_EQ(back->error_frame, r.error_frame) << line;
    EXPECT_EQ(back->frame, r.frame) << line;
    EXPECT_EQ(FormatCandumpLine(*back), line);
  }
}

TEST(CandumpFileTest, ReadsRecordsSkippingBlankLinesAndComments) {
  const std::string path = TempPath("read");
  WriteText(path,
            "# captured on the test bench\n"
            "(1436509052.249713) vcan0 044#2A366C2BBA\n"
            "\n"
            "   \n"
            "  # indented comment\n"
            "(1436509052.449847) vcan0 12345678#R\n"
            "(1436509052.649847) can1 20000004#0004000000000000\n");
  std::vector<CandumpRecord> records = ReadCandumpFile(path);
  ASSERT_EQ(records.size(), 3u);
  EXPECT_EQ(records[0].frame, CanFrame::Standard(0x044, {0x2A, 0x36, 0x6C, 0x2B, 0xBA}));
  EXPECT_EQ(records[1].frame, Remote(0x12345678, true, 0));
  EXPECT_EQ(records[1].timestamp, nanoseconds(1436509052'449847000));
  EXPECT_TRUE(records[2].error_frame);
  EXPECT_EQ(records[2].interface, "can1");
  EXPECT_EQ(records[2].frame.id, 0x4u);
  EXPECT_EQ(records[2].frame.data[1], 0x04);
  std::remove(path.c_str());
}

TEST(CandumpFileTest, NamesFileAndLineOfEveryBadLine) {
  const std::string path = TempPath("bad");
  WriteText(path,
            "(1436509052.249713) vcan0 044#2A366C2BBA\n"
            "# comment\n"
            "(1436509052.3) vcan0 800#00\n"
            "(1436509052.4) vcan0 123#00\n"
            "vcan0 123#00\n");
  try {
    ReadCandumpFile(path);
    FAIL() << "expected ConfigError";
  } catch (const common::ConfigError& e) {
    const std::string what = e.what();
    EXPECT_THAT(what, HasSubstr(path + ":3: "));
    EXPECT_THAT(what, ContainsRegex(":3: frame \"800#00\": id 0x800 exceeds 11 bits"));
    EXPECT_THAT(what, ContainsRegex(":5: line \"vcan0 123#00\" does not start with a timestamp"));
    EXPECT_THAT(what, ::testing::Not(HasSubstr(":4:")));
    EXPECT_THAT(what, ::testing::Not(HasSubstr(":1:")));
  }
  std::remove(path.c_str());
}

TEST(CandumpFileTest, CapsTheListOfBadLines) {
  const std::string path = TempPath("many_bad");
  std::string text;
  for (int i = 0; i < 25; ++i) text += "garbage\n";
  WriteText(path, text);
  try {
    ReadCandumpFile(path);
    FAIL() << "expected ConfigError";
  } catch (const common::ConfigError& e) {
    const std::string what = e.what();
    EXPECT_THAT(what, HasSubstr(path + ":20: "));
    EXPECT_THAT(what, ::testing::Not(HasSubstr(path + ":21: ")));
    EXPECT_THAT(what, ContainsRegex("\\.\\.\\. and 5 more bad lines"));
  }
  std::remove(path.c_str());
}

TEST(CandumpFileTest, MissingFileIsAConfigErrorNamingThePath) {
  const std::string path = TempPath("does_not_exist");
  std::remove(path.c_str());
  try {
    ReadCandumpFile(path);
    FAIL() << "expected ConfigError";
  } catch (const common::ConfigError& e) {
    EXPECT_THAT(e.what(), ContainsRegex("kinevis_candump_does_not_exist.*: cannot open candump "
                                        "log: No such file or directory"));
  }
}

TEST(CandumpWriterTest, WritesOneLinePerRecord) {
  std::ostringstream out;
  CandumpWriter writer(out);
  EXPECT_FALSE(writer.Write(
      Record(kExampleTime, "vcan0", CanFrame::Standard(0x044, {0x2A, 0x36, 0x6C, 0x2B, 0xBA}))));
  EXPECT_FALSE(
      writer.Write(Record(kExampleTime + nanoseconds(1000), "vcan0", Remote(0x123, false, 4))));
  EXPECT_FALSE(writer.Flush());
  EXPECT_EQ(writer.lines_written(), 2u);
  EXPECT_EQ(out.str(),
            "(1436509052.249713) vcan0 044#2A366C2BBA\n"
            "(1436509052.249714) vcan0 123#R4\n");
}

TEST(CandumpWriterTest, RefusesRecordsThatWouldNotReadBack) {
  std::ostringstream out;
  CandumpWriter writer(out);
  CanFrame bad_id = CanFrame::Standard(0x100);
  bad_id.id = 0x800;
  CanFrame bad_dlc = CanFrame::Standard(0x100);
  bad_dlc.dlc = 9;
  CanFrame bad_error = ErrorPayload(0x40, {});
  bad_error.id = 0x20000000;
  const CandumpRecord bad[] = {
      Record(kExampleTime, "", CanFrame::Standard(0x1)),
      Record(kExampleTime, "vcan 0", CanFrame::Standard(0x1)),
      Record(kExampleTime, "vcan0\t", CanFrame::Standard(0x1)),
      Record(nanoseconds(-1), "vcan0", CanFrame::Standard(0x1)),
      Record(kExampleTime, "vcan0", bad_id),
      Record(kExampleTime, "vcan0", bad_dlc),
      Record(kExampleTime, "vcan0", bad_error, true),
  };
  for (const CandumpRecord& r : bad) {
    EXPECT_EQ(writer.Write(r), Errc::kInvalidArgument) << "interface \"" << r.interface << "\"";
  }
  EXPECT_EQ(writer.lines_written(), 0u);
  EXPECT_EQ(out.str(), "");
}

TEST(CandumpWriterTest, ReportsAFailedStream) {
  std::ostringstream out;
  CandumpWriter writer(out);
  out.setstate(std::ios::badbit);
  EXPECT_EQ(writer.Write(Record(kExampleTime, "vcan0", CanFrame::Standard(0x1))), Errc::kIo);
  EXPECT_EQ(writer.Flush(), Errc::kIo);
  EXPECT_EQ(writer.lines_written(), 0u);
}

TEST(CandumpWriterTest, FileWriterOutputReadsBack) {
  const std::string path = TempPath("roundtrip");
  std::vector<CandumpRecord> written;
  for (const FormatCase& c : CanUtilsVectors()) written.push_back(c.record);
  {
    CandumpWriter writer(path);
    for (const CandumpRecord& r : written) ASSERT_FALSE(writer.Write(r));
    ASSERT_FALSE(writer.Flush());
  }
  std::vector<CandumpRecord> read = ReadCandumpFile(path);
  ASSERT_EQ(read.size(), written.size());
  for (size_t i = 0; i < read.size(); ++i) {
    EXPECT_EQ(read[i].frame, written[i].frame) << i;
    EXPECT_EQ(read[i].error_frame, written[i].error_frame) << i;
    EXPECT_EQ(read[i].timestamp, written[i].timestamp) << i;
    EXPECT_EQ(read[i].interface, written[i].interface) << i;
  }
  std::remove(path.c_str());
}

TEST(CandumpWriterTest, UncreatableFileIsAConfigError) {
  const std::string path = TempPath("no_such_dir") + "/capture.log";
  try {
    CandumpWriter writer(path);
    FAIL() << "expected ConfigError";
  } catch (const common::ConfigError& e) {
    EXPECT_THAT(e.what(), ContainsRegex("capture\\.log: cannot create candump log: "));
  }
}

// can-utils' own reader must understand what kinevis writes.
TEST(CandumpInteropTest, Log2longReadsWhatCandumpWriterWrites) {
  if (!testing::HaveProgram("log2long")) {
    GTEST_SKIP() << "log2long (can-utils) is not on PATH";
  }
  const std::string path = TempPath("log2long");
  {
    CandumpWriter writer(path);
    ASSERT_FALSE(writer.Write(
        Record(kExampleTime, "vcan0", CanFrame::Standard(0x123, {0xDE, 0xAD, 0xBE, 0xEF}))));
    ASSERT_FALSE(writer.Write(Record(kExampleTime + nanoseconds(200'134'000), "can1",
                                     CanFrame::Extended(0x12345678, {0x01, 0x02, 0x03}))));
    ASSERT_FALSE(writer.Write(
        Record(kExampleTime + nanoseconds(300'000'000), "vcan0", Remote(0x7FF, false, 4))));
    ASSERT_FALSE(writer.Write(Record(kExampleTime + nanoseconds(400'000'000), "vcan0",
                                     ErrorPayload(0x40, {0, 0, 0, 0, 0, 0, 0x7F, 0x00}), true)));
    ASSERT_FALSE(writer.Write(
        Record(kExampleTime + nanoseconds(500'000'000), "vcan0", CanFrame::Standard(0x000, {}))));
    ASSERT_FALSE(writer.Flush());
  }
  testing::ProcessResult result =
      testing::RunProcess({"sh", "-c", "log2long < '" + path + "'"}, std::chrono::seconds(20));
  ASSERT_FALSE(result.timed_out);
  ASSERT_EQ(result.exit_code, 0) << result.err;
  std::vector<std::string> lines;
  std::istringstream in(result.out);
  for (std::string line; std::getline(in, line);) lines.push_back(line);
  ASSERT_EQ(lines.size(), 5u) << result.out;
  EXPECT_THAT(lines[0], ContainsRegex("^\\(1436509052\\.249713\\) +vcan0 +123 +\\[4\\] +"
                                      "DE AD BE EF"));
  EXPECT_THAT(lines[1], ContainsRegex("^\\(1436509052\\.449847\\) +can1 +12345678 +\\[3\\] +"
                                      "01 02 03"));
  EXPECT_THAT(lines[2], ContainsRegex("vcan0 +7FF +\\[4\\] +remote request"));
  EXPECT_THAT(lines[3], ContainsRegex("vcan0 +20000040 +\\[8\\] +00 00 00 00 00 00 7F 00 +"
                                      "ERRORFRAME"));
  EXPECT_THAT(lines[4], ContainsRegex("vcan0 +000 +\\[0\\]"));
  std::remove(path.c_str());
}

}  // namespace
}  // namespace kinevis::hal
