#include "hal/can/slcan_codec.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <random>
#include <string>
#include <vector>

#include "hal/common/backend_spec.h"

namespace kinevis::hal {
namespace {

using Kind = SlcanEvent::Kind;
using ::testing::ElementsAre;
using ::testing::HasSubstr;

std::vector<SlcanEvent> Decode(SlcanDecoder* decoder, std::string_view bytes) {
  std::vector<SlcanEvent> events;
  decoder->Feed(bytes, [&](const SlcanEvent& e) { events.push_back(e); });
  return events;
}

std::vector<SlcanEvent> Decode(std::string_view bytes) {
  SlcanDecoder decoder;
  return Decode(&decoder, bytes);
}

std::vector<Kind> Kinds(const std::vector<SlcanEvent>& events) {
  std::vector<Kind> kinds;
  for (const auto& e : events) kinds.push_back(e.kind);
  return kinds;
}

// --- encoding frames ---------------------------------------------------------------------------

TEST(SlcanEncodeTest, FrameFormsMatchTheLawicelSpecification) {
  EXPECT_EQ(SlcanFrameLine(CanFrame::Standard(0x123, {0xAA, 0xBB})), "t1232AABB\r");
  EXPECT_EQ(SlcanFrameLine(CanFrame::Extended(0x12345678, {0x11, 0x22})), "T1234567821122\r");
  CanFrame remote = CanFrame::Standard(0x123);
  remote.rtr = true;
  EXPECT_EQ(SlcanFrameLine(remote), "r1230\r");
  remote.dlc = 4;
  EXPECT_EQ(SlcanFrameLine(remote), "r1234\r");
  CanFrame remote_ext = CanFrame::Extended(0x12345678);
  remote_ext.rtr = true;
  EXPECT_EQ(SlcanFrameLine(remote_ext), "R123456780\r");
  EXPECT_EQ(SlcanFrameLine(CanFrame::Standard(0x000)), "t0000\r");
  EXPECT_EQ(SlcanFrameLine(CanFrame::Standard(0x7FF, {0, 1, 2, 3, 0xFC, 0xFD, 0xFE, 0xFF})),
            "t7FF800010203FCFDFEFF\r");
  EXPECT_EQ(SlcanFrameLine(CanFrame::Extended(0x1FFFFFFF, {0xDE, 0xAD, 0xBE, 0xEF, 1, 2, 3, 4})),
            "T1FFFFFFF8DEADBEEF01020304\r");
  // An extended frame with a small id keeps its 8 digits.
  EXPECT_EQ(SlcanFrameLine(CanFrame::Extended(0x5)), "T000000050\r");
}

TEST(SlcanEncodeTest, TimestampIsFourHexDigitsUpToEA5F) {
  const CanFrame f = CanFrame::Standard(0x123, {0xAA, 0xBB});
  EXPECT_EQ(SlcanFrameLine(f, 0), "t1232AABB0000\r");
  EXPECT_EQ(SlcanFrameLine(f, 0x1234), "t1232AABB1234\r");
  EXPECT_EQ(SlcanFrameLine(f, kSlcanMaxTimestampMs), "t1232AABBEA5F\r");
  EXPECT_EQ(SlcanFrameLine(f, 60000), "");  // out of range: 60 s wraps to 0
  CanFrame remote = CanFrame::Extended(0x1ABCDEF0);
  remote.rtr = true;
  remote.dlc = 8;
  EXPECT_EQ(SlcanFrameLine(remote, 59999), "R1ABCDEF08EA5F\r");
}

TEST(SlcanEncodeTest, TimestampDifferenceWrapsAt60Seconds) {
  EXPECT_EQ(SlcanTimestampDeltaMs(1000, 1500), 500);
  EXPECT_EQ(SlcanTimestampDeltaMs(59990, 10), 20);
  EXPECT_EQ(SlcanTimestampDeltaMs(59999, 0), 1);
  EXPECT_EQ(SlcanTimestampDeltaMs(0, 59999), 59999);
  EXPECT_EQ(SlcanTimestampDeltaMs(1234, 1234), 0);
}

TEST(SlcanEncodeTest, LongestLineFitsTheBufferSize) {
  char buffer[kSlcanMaxLineSize];
  const CanFrame f = CanFrame::Extended(0x1FFFFFFF, {1, 2, 3, 4, 5, 6, 7, 8});
  EXPECT_EQ(EncodeSlcanFrame(f, buffer, kSlcanMaxTimestampMs), kSlcanMaxLineSize);
  EXPECT_EQ(std::string(buffer, kSlcanMaxLineSize), "T1FFFFFFF80102030405060708EA5F\r");
}

TEST(SlcanEncodeTest, InvalidFramesEncodeToNothing) {
  char buffer[kSlcanMaxLineSize];
  CanFrame too_big_id = CanFrame::Standard(0);
  too_big_id.id = 0x800;
  EXPECT_EQ(EncodeSlcanFrame(too_big_id, buffer), 0u);
  CanFrame too_big_ext = CanFrame::Extended(0);
  too_big_ext.id = 0x20000000;
  EXPECT_EQ(EncodeSlcanFrame(too_big_ext, buffer), 0u);
  CanFrame too_long = CanFrame::Standard(0x1);
  too_long.dlc = 9;
  EXPECT_EQ(SlcanFrameLine(too_long), "");
}

// --- encoding and parsing commands -------------------------------------------------------------

TEST(SlcanCommandTest, BitrateCodesS0ToS8) {
  const int rates[] = {10000, 20000, 50000, 100000, 125000, 250000, 500000, 800000, 1000000};
  for (int code = 0; code <= 8; ++code) {
    EXPECT_EQ(EncodeSlcanBitrate(rates[code]), "S" + std::to_string(code) + "\r");
    EXPECT_EQ(SlcanBitrateFromCode(code), rates[code]);
    EXPECT_EQ(SlcanBitrateCode(SlcanBitrateFromCode(code)), code);
  }
  EXPECT_EQ(EncodeSlcanBitrate(33333), "");
  EXPECT_EQ(SlcanBitrateFromCode(9), -1);
  EXPECT_EQ(SlcanBitrateFromCode(-1), -1);
  EXPECT_EQ(EncodeSlcanCommand(SlcanCommand::SetBitrate(9)), "");
}

TEST(SlcanCommandTest, SimpleCommands) {
  using K = SlcanCommand::Kind;
  EXPECT_EQ(EncodeSlcanCommand(SlcanCommand::Simple(K::kOpen)), "O\r");
  EXPECT_EQ(EncodeSlcanCommand(SlcanCommand::Simple(K::kListenOnly)), "L\r");
  EXPECT_EQ(EncodeSlcanCommand(SlcanCommand::Simple(K::kClose)), "C\r");
  EXPECT_EQ(EncodeSlcanCommand(SlcanCommand::Simple(K::kVersion)), "V\r");
  EXPECT_EQ(EncodeSlcanCommand(SlcanCommand::Simple(K::kSerialNumber)), "N\r");
  EXPECT_EQ(EncodeSlcanCommand(SlcanCommand::Simple(K::kStatus)), "F\r");
  EXPECT_EQ(EncodeSlcanCommand(SlcanCommand::Timestamps(false)), "Z0\r");
  EXPECT_EQ(EncodeSlcanCommand(SlcanCommand::Timestamps(true)), "Z1\r");
  EXPECT_EQ(EncodeSlcanCommand(SlcanCommand::Transmit(CanFrame::Standard(0x123, {0xAA}))),
            "t1231AA\r");
}

TEST(SlcanCommandTest, EveryEncodedCommandParsesBack) {
  using K = SlcanCommand::Kind;
  std::vector<SlcanCommand> commands = {
      SlcanCommand::Simple(K::kOpen),
      SlcanCommand::Simple(K::kListenOnly),
      SlcanCommand::Simple(K::kClose),
      SlcanCommand::Simple(K::kVersion),
      SlcanCommand::Simple(K::kSerialNumber),
      SlcanCommand::Simple(K::kStatus),
      SlcanCommand::Timestamps(false),
      SlcanCommand::Timestamps(true),
      SlcanCommand::Transmit(CanFrame::Extended(0x1FFFFFFF, {1, 2, 3, 4, 5, 6, 7, 8}))};
  for (int code = 0; code <= 8; ++code) commands.push_back(SlcanCommand::SetBitrate(code));
  for (const SlcanCommand& c : commands) {
    std::string line = EncodeSlcanCommand(c);
    ASSERT_FALSE(line.empty());
    ASSERT_EQ(line.back(), '\r');
    line.pop_back();
    std::string error;
    auto parsed = ParseSlcanCommand(line, &error);
    ASSERT_TRUE(parsed.has_value()) << line << ": " << error;
    EXPECT_EQ(parsed->kind, c.kind) << line;
    EXPECT_EQ(parsed->bitrate_code, c.bitrate_code) << line;
    EXPECT_EQ(parsed->timestamps_on, c.timestamps_on) << line;
    EXPECT_EQ(parsed->frame, c.frame) << line;
  }
}

TEST(SlcanCommandTest, ParsesHostFrameLinesInEitherCase) {
  auto c = ParseSlcanCommand("t1232aabb");
  ASSERT_TRUE(c.has_value());
  EXPECT_EQ(c->kind, SlcanCommand::Kind::kTransmit);
  EXPECT_EQ(c->frame, CanFrame::Standard(0x123, {0xAA, 0xBB}));
  c = ParseSlcanCommand("R1ABCDEF03");
  ASSERT_TRUE(c.has_value());
  EXPECT_TRUE(c->frame.rtr);
  EXPECT_TRUE(c->frame.extended);
  EXPECT_EQ(c->frame.id, 0x1ABCDEF0u);
  EXPECT_EQ(c->frame.dlc, 3);
}

TEST(SlcanCommandTest, RejectsMalformedCommandsWithAReason) {
  std::string error;
  EXPECT_FALSE(ParseSlcanCommand("", &error));
  EXPECT_THAT(error, HasSubstr("empty"));
  EXPECT_FALSE(ParseSlcanCommand("S9", &error));
  EXPECT_THAT(error, HasSubstr("S9"));
  EXPECT_FALSE(ParseSlcanCommand("Z2", &error));
  EXPECT_FALSE(ParseSlcanCommand("OO", &error));
  EXPECT_FALSE(ParseSlcanCommand("X", &error));
  EXPECT_FALSE(ParseSlcanCommand("t800", &error));
  EXPECT_FALSE(ParseSlcanCommand("t8000", &error));
  EXPECT_THAT(error, HasSubstr("11 bits"));
  EXPECT_FALSE(ParseSlcanCommand("T200000000", &error));
  EXPECT_THAT(error, HasSubstr("29 bits"));
  EXPECT_FALSE(ParseSlcanCommand("t1239", &error));
  EXPECT_THAT(error, HasSubstr("0..8"));
  EXPECT_FALSE(ParseSlcanCommand("t1232AAB", &error));
  EXPECT_THAT(error, HasSubstr("expected 9"));
  EXPECT_FALSE(ParseSlcanCommand("t1231GG", &error));
  EXPECT_THAT(error, HasSubstr("not hexadecimal"));
  // The host does not send timestamps: a frame with 4 extra digits is malformed.
  EXPECT_FALSE(ParseSlcanCommand("t1230ABCD", &error));
}

// --- decoding the adapter stream ---------------------------------------------------------------

TEST(SlcanDecoderTest, DecodesEveryFrameForm) {
  auto events = Decode("t1232AABB\rT1234567821122\rr1230\rR123456780\rr1238\r");
  ASSERT_EQ(events.size(), 5u);
  for (const auto& e : events) {
    EXPECT_EQ(e.kind, Kind::kFrame);
    EXPECT_FALSE(e.has_timestamp);
  }
  EXPECT_EQ(events[0].frame, CanFrame::Standard(0x123, {0xAA, 0xBB}));
  EXPECT_EQ(events[1].frame, CanFrame::Extended(0x12345678, {0x11, 0x22}));
  EXPECT_TRUE(events[2].frame.rtr);
  EXPECT_FALSE(events[2].frame.extended);
  EXPECT_EQ(events[2].frame.id, 0x123u);
  EXPECT_EQ(events[2].frame.dlc, 0);
  EXPECT_TRUE(events[3].frame.rtr);
  EXPECT_TRUE(events[3].frame.extended);
  EXPECT_EQ(events[3].frame.id, 0x12345678u);
  EXPECT_EQ(events[4].frame.dlc, 8);
  EXPECT_EQ(events[4].frame.timestamp.count(), 0);
}

TEST(SlcanDecoderTest, DecodesTimestamps) {
  auto events = Decode("t1232AABB0000\rt1232AABBEA5F\rT1234567800001\rr1231ABCD\r");
  ASSERT_EQ(events.size(), 4u);
  EXPECT_TRUE(events[0].has_timestamp);
  EXPECT_EQ(events[0].timestamp_ms, 0);
  EXPECT_EQ(events[0].frame, CanFrame::Standard(0x123, {0xAA, 0xBB}));
  EXPECT_EQ(events[1].timestamp_ms, 59999);
  EXPECT_EQ(events[2].frame, CanFrame::Extended(0x12345678));
  EXPECT_EQ(events[2].timestamp_ms, 1);
  EXPECT_TRUE(events[3].frame.rtr);
  EXPECT_EQ(events[3].frame.dlc, 1);
  EXPECT_EQ(events[3].timestamp_ms, 0xABCD);
}

TEST(SlcanDecoderTest, TimestampBeyond59999IsInvalid) {
  SlcanDecoder decoder;
  auto events = Decode(&decoder, "t1232AABBEA60\r");
  ASSERT_EQ(events.size(), 1u);
  EXPECT_EQ(events[0].kind, Kind::kInvalid);
  EXPECT_EQ(events[0].text, "t1232AABBEA60");
  EXPECT_EQ(decoder.decode_errors(), 1u);
}

TEST(SlcanDecoderTest, DecodesRepliesAcksVersionSerialAndStatus) {
  auto events = Decode("\r\az\rZ\rV1013\rNA1B2\rF00\rFA4\r");
  EXPECT_THAT(Kinds(events),
              ElementsAre(Kind::kOk, Kind::kError, Kind::kTxAck, Kind::kTxAck, Kind::kVersion,
                          Kind::kSerialNumber, Kind::kStatus, Kind::kStatus));
  EXPECT_FALSE(events[2].extended_ack);
  EXPECT_TRUE(events[3].extended_ack);
  EXPECT_EQ(events[4].text, "1013");
  EXPECT_EQ(events[5].text, "A1B2");
  EXPECT_EQ(events[6].status, 0);
  EXPECT_EQ(events[7].status, kSlcanErrorWarning | kSlcanErrorPassive | kSlcanBusError);
}

TEST(SlcanDecoderTest, AcceptsLowerCaseHex) {
  auto events = Decode("t1ab2cdef\rfa4\r");
  ASSERT_EQ(events.size(), 2u);
  EXPECT_EQ(events[0].frame, CanFrame::Standard(0x1AB, {0xCD, 0xEF}));
  // 'f' is not the status reply: only upper-case F is.
  EXPECT_EQ(events[1].kind, Kind::kInvalid);
}

TEST(SlcanDecoderTest, SameEventsWhetherFedWholeOrByteByByte) {
  const std::string stream = "V1013\r\rt1232AABB\rgarbage\rT1234567821122ABCD\r\aF08\rz\r";
  SlcanDecoder whole_decoder;
  auto whole = Decode(&whole_decoder, stream);
  SlcanDecoder split_decoder;
  std::vector<SlcanEvent> split;
  for (char c : stream) {
    auto part = Decode(&split_decoder, std::string_view(&c, 1));
    split.insert(split.end(), part.begin(), part.end());
  }
  ASSERT_EQ(Kinds(whole), Kinds(split));
  EXPECT_THAT(Kinds(whole), ElementsAre(Kind::kVersion, Kind::kOk, Kind::kFrame, Kind::kInvalid,
                                        Kind::kFrame, Kind::kError, Kind::kStatus, Kind::kTxAck));
  for (size_t i = 0; i < whole.size(); ++i) {
    EXPECT_EQ(whole[i].frame, split[i].frame);
    EXPECT_EQ(whole[i].text, split[i].text);
  }
  EXPECT_EQ(whole_decoder.decode_errors(), 1u);
  EXPECT_EQ(split_decoder.decode_errors(), 1u);
}

TEST(SlcanDecoderTest, ToleratesCrLf) {
  SlcanDecoder decoder;
  auto events = Decode(&decoder, "t1230\r\nt1240\r\n\r\n");
  EXPECT_THAT(Kinds(events), ElementsAre(Kind::kFrame, Kind::kFrame, Kind::kOk));
  EXPECT_EQ(decoder.decode_errors(), 0u);
}

TEST(SlcanDecoderTest, GarbageCostsItsLineAndIsKeptEscapedForDiagnostics) {
  SlcanDecoder decoder;
  auto events = Decode(&decoder, "t1230\rhello\x01\\ world\rt1240\r");
  EXPECT_THAT(Kinds(events), ElementsAre(Kind::kFrame, Kind::kInvalid, Kind::kFrame));
  EXPECT_EQ(events[1].text, "hello\\x01\\x5C world");
  EXPECT_EQ(decoder.last_invalid_text(), "hello\\x01\\x5C world");
  EXPECT_EQ(decoder.decode_errors(), 1u);
  EXPECT_EQ(decoder.discarded_bytes(), 13u);
  EXPECT_EQ(events[2].frame.id, 0x124u);
}

TEST(SlcanDecoderTest, LostDataByteCostsOneLine) {
  SlcanDecoder decoder;
  // "t1232AABB" lost one 'B'; "t1232AABB0001" lost a timestamp digit.
  auto events = Decode(&decoder, "t1232AAB\rt1232AABB001\rt3210\r");
  EXPECT_THAT(Kinds(events), ElementsAre(Kind::kInvalid, Kind::kInvalid, Kind::kFrame));
  EXPECT_EQ(events[2].frame.id, 0x321u);
  EXPECT_EQ(decoder.decode_errors(), 2u);
}

TEST(SlcanDecoderTest, LostCarriageReturnCostsExactlyTheTwoLinesItJoined) {
  // Every kind of line an adapter sends (the empty OK line excepted: losing its '\r' loses the
  // line without joining two). Whichever '\r' is lost, the two lines it separated become one
  // counted error and every other line still decodes.
  const std::vector<std::string> lines = {
      "t1232AABB",     "T1234567821122", "r1230", "R123456780",
      "t1232AABBEA5F", "T123456780ABCD", "z",     "Z",
      "V1013",         "NA1B2",          "F00",   "t7FF8FFFFFFFFFFFFFFFF",
      "r1238"};
  for (size_t lost = 0; lost + 1 < lines.size(); ++lost) {
    std::string stream;
    for (size_t i = 0; i < lines.size(); ++i) {
      stream += lines[i];
      if (i != lost) stream += '\r';
    }
    SlcanDecoder decoder;
    auto events = Decode(&decoder, stream);
    ASSERT_EQ(events.size(), lines.size() - 1) << "lost the \\r of line " << lost;
    EXPECT_EQ(decoder.decode_errors(), 1u) << "lost the \\r of line " << lost;
    EXPECT_EQ(events[lost].kind, Kind::kInvalid);
    EXPECT_EQ(events[lost].text, lines[lost] + lines[lost + 1]);
    for (size_t i = 0; i < events.size(); ++i) {
      if (i != lost) {
        EXPECT_NE(events[i].kind, Kind::kInvalid) << "event " << i;
      }
    }
  }
}

TEST(SlcanDecoderTest, BellInsideALineEndsItAsAnErrorAndIsStillReported) {
  SlcanDecoder decoder;
  auto events = Decode(&decoder, "t12\at1230\r");
  EXPECT_THAT(Kinds(events), ElementsAre(Kind::kInvalid, Kind::kError, Kind::kFrame));
  EXPECT_EQ(events[0].text, "t12");
  EXPECT_EQ(decoder.decode_errors(), 1u);
}

TEST(SlcanDecoderTest, OverlongLineIsReportedOnceAndSkippedToTheTerminator) {
  SlcanDecoder decoder;
  std::vector<SlcanEvent> events;
  auto sink = [&](const SlcanEvent& e) { events.push_back(e); };
  const std::string chunk(1000, 'A');
  decoder.Feed(chunk, sink);
  EXPECT_LE(decoder.pending_bytes(), SlcanDecoder::kMaxLineBytes);
  ASSERT_EQ(events.size(), 1u);  // reported as soon as it overflowed, not at the '\r'
  EXPECT_EQ(events[0].kind, Kind::kInvalid);
  EXPECT_EQ(events[0].text, std::string(SlcanDecoder::kMaxLineBytes, 'A') + "...");
  decoder.Feed("\rt1230\r", sink);
  ASSERT_EQ(events.size(), 2u);
  EXPECT_EQ(events[1].kind, Kind::kFrame);
  EXPECT_EQ(decoder.decode_errors(), 1u);
  EXPECT_EQ(decoder.discarded_bytes(), 1000u);
}

TEST(SlcanDecoderTest, EndlessInputWithoutTerminatorUsesConstantMemory) {
  SlcanDecoder decoder;
  size_t events = 0;
  std::string chunk(4096, '\0');
  for (size_t i = 0; i < chunk.size(); ++i) chunk[i] = static_cast<char>('0' + i % 40);
  for (int i = 0; i < 256; ++i) {  // 1 MiB
    decoder.Feed(chunk, [&](const SlcanEvent&) { ++events; });
    ASSERT_LE(decoder.pending_bytes(), SlcanDecoder::kMaxLineBytes);
  }
  EXPECT_EQ(events, 1u);
  EXPECT_EQ(decoder.decode_errors(), 1u);
  EXPECT_EQ(decoder.discarded_bytes(), 256u * 4096u);
  EXPECT_LE(decoder.last_invalid_text().size(), 4 * SlcanDecoder::kMaxLineBytes + 3);
}

TEST(SlcanDecoderTest, ResetForgetsAPartialLine) {
  SlcanDecoder decoder;
  auto events = Decode(&decoder, "t12");
  EXPECT_TRUE(events.empty());
  EXPECT_EQ(decoder.pending_bytes(), 3u);
  decoder.Reset();
  events = Decode(&decoder, "t1230\r");
  ASSERT_EQ(events.size(), 1u);
  EXPECT_EQ(events[0].kind, Kind::kFrame);
  EXPECT_EQ(decoder.decode_errors(), 0u);
}

CanFrame RandomFrame(std::mt19937* rng) {
  std::uniform_int_distribution<int> coin(0, 1);
  std::uniform_int_distribution<int> dlc(0, 8);
  std::uniform_int_distribution<int> byte(0, 255);
  CanFrame f;
  f.extended = coin(*rng) == 1;
  f.id = std::uniform_int_distribution<uint32_t>(
      0, f.extended ? CanFrame::kMaxExtendedId : CanFrame::kMaxStandardId)(*rng);
  f.rtr = std::uniform_int_distribution<int>(0, 9)(*rng) == 0;
  f.dlc = static_cast<uint8_t>(dlc(*rng));
  if (!f.rtr) {
    for (int i = 0; i < f.dlc; ++i) f.data[i] = static_cast<uint8_t>(byte(*rng));
  }
  return f;
}

// A megabyte of random bytes with valid lines mixed in: no crash, bounded memory, and every
// valid line that starts right after a terminator comes out, in order (garbage may by chance
// form extra valid lines, so the expected frames must be a subsequence of the decoded ones).
TEST(SlcanDecoderTest, RandomGarbageMixedWithValidLines) {
  std::mt19937 rng(20240611);
  std::uniform_int_distribution<int> byte(0, 255);
  std::uniform_int_distribution<int> garbage_length(0, 120);
  std::uniform_int_distribution<int> percent(0, 99);
  std::uniform_int_distribution<int> timestamp(0, kSlcanMaxTimestampMs);

  struct Expected {
    CanFrame frame;
    std::optional<uint16_t> timestamp_ms;
  };
  std::string stream;
  std::vector<Expected> expected;
  while (stream.size() < (1u << 20)) {
    const int p = percent(rng);
    if (p < 40) {
      const int n = garbage_length(rng);
      for (int i = 0; i < n; ++i) stream += static_cast<char>(byte(rng));
    } else if (p < 45) {
      stream.append(static_cast<size_t>(garbage_length(rng)) * 20, 'x');  // overlong line
    } else {
      const CanFrame f = RandomFrame(&rng);
      std::optional<uint16_t> ts;
      if (percent(rng) < 50) ts = static_cast<uint16_t>(timestamp(rng));
      const bool at_boundary =
          stream.empty() || stream.back() == '\r' || stream.back() == kSlcanBell;
      stream += SlcanFrameLine(f, ts);
      if (at_boundary) expected.push_back({f, ts});
    }
  }
  ASSERT_GT(expected.size(), 1000u);

  SlcanDecoder decoder;
  std::vector<Expected> decoded;
  std::uniform_int_distribution<size_t> chunk(1, 4096);
  size_t pos = 0;
  while (pos < stream.size()) {
    const size_t n = std::min(chunk(rng), stream.size() - pos);
    decoder.Feed(
        reinterpret_cast<const uint8_t*>(stream.data() + pos), n, [&](const SlcanEvent& e) {
          if (e.kind != Kind::kFrame) return;
          decoded.push_back(
              {e.frame, e.has_timestamp ? std::optional<uint16_t>(e.timestamp_ms) : std::nullopt});
        });
    pos += n;
    ASSERT_LE(decoder.pending_bytes(), SlcanDecoder::kMaxLineBytes);
    ASSERT_LE(decoder.last_invalid_text().size(), 4 * SlcanDecoder::kMaxLineBytes + 3);
  }
  size_t next = 0;
  for (const Expected& d : decoded) {
    if (next < expected.size() && d.frame == expected[next].frame &&
        d.timestamp_ms == expected[next].timestamp_ms) {
      ++next;
    }
  }
  EXPECT_EQ(next, expected.size()) << "a valid line after a terminator was not decoded";
  EXPECT_GT(decoder.decode_errors(), 0u);
  EXPECT_GT(decoder.discarded_bytes(), 0u);
}

}  // namespace
}  // namespace kinevis::hal
