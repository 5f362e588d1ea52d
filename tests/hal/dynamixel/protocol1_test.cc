#include "hal/dynamixel/protocol1.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cstdint>
#include <random>
#include <string>
#include <vector>

namespace kinevis::hal {
namespace {

using Bytes = std::vector<uint8_t>;
using ::testing::ElementsAre;
using ::testing::ElementsAreArray;

// Decodes `bytes` fed in pieces of `chunk` bytes and returns the packets, with their parameters
// copied out.
struct Decoded {
  uint8_t id;
  uint8_t instruction;
  uint8_t error;
  Bytes params;
};
std::vector<Decoded> DecodeAll(Dxl1Decoder* decoder, const Bytes& bytes, size_t chunk = 1000) {
  std::vector<Decoded> out;
  for (size_t i = 0; i < bytes.size(); i += chunk) {
    const size_t n = std::min(chunk, bytes.size() - i);
    decoder->FeedAll(bytes.data() + i, n, [&](const DxlPacket& p) {
      out.push_back({p.id, p.instruction, p.error, p.ParamVector()});
    });
  }
  return out;
}

// Examples of the Protocol 1.0 e-manual, byte for byte.
TEST(Dxl1EncodeTest, PingMatchesTheManual) {
  EXPECT_THAT(Dxl1InstructionPacket(1, DxlInstruction::kPing),
              ElementsAre(0xFF, 0xFF, 0x01, 0x02, 0x01, 0xFB));
  EXPECT_THAT(Dxl1StatusPacket(1, 0), ElementsAre(0xFF, 0xFF, 0x01, 0x02, 0x00, 0xFC));
}

TEST(Dxl1EncodeTest, ReadAndItsStatusMatchTheManual) {
  // Read 1 byte at 43 (present temperature) of ID 1; the answer is 32 degrees.
  EXPECT_THAT(Dxl1InstructionPacket(1, DxlInstruction::kRead, {0x2B, 0x01}),
              ElementsAre(0xFF, 0xFF, 0x01, 0x04, 0x02, 0x2B, 0x01, 0xCC));
  EXPECT_THAT(Dxl1StatusPacket(1, 0, {0x20}),
              ElementsAre(0xFF, 0xFF, 0x01, 0x03, 0x00, 0x20, 0xDB));
}

TEST(Dxl1EncodeTest, BroadcastWriteMatchesTheManual) {
  // Write ID = 1 to every servo on the bus.
  EXPECT_THAT(Dxl1InstructionPacket(kDxlBroadcastId, DxlInstruction::kWrite, {0x03, 0x01}),
              ElementsAre(0xFF, 0xFF, 0xFE, 0x04, 0x03, 0x03, 0x01, 0xF6));
}

TEST(Dxl1EncodeTest, SyncWriteMatchesTheManual) {
  // Goal position and moving speed (4 bytes from 30) of IDs 0..3.
  const Bytes params = {0x1E, 0x04, 0x00, 0x10, 0x00, 0x50, 0x01, 0x01, 0x20, 0x02, 0x60,
                        0x03, 0x02, 0x30, 0x00, 0x70, 0x01, 0x03, 0x20, 0x02, 0x80, 0x03};
  EXPECT_THAT(Dxl1InstructionPacket(kDxlBroadcastId, DxlInstruction::kSyncWrite, params),
              ElementsAreArray(Bytes{0xFF, 0xFF, 0xFE, 0x18, 0x83, 0x1E, 0x04, 0x00, 0x10, 0x00,
                                     0x50, 0x01, 0x01, 0x20, 0x02, 0x60, 0x03, 0x02, 0x30, 0x00,
                                     0x70, 0x01, 0x03, 0x20, 0x02, 0x80, 0x03, 0x12}));
}

TEST(Dxl1EncodeTest, BulkReadMatchesTheManual) {
  // 2 bytes at 30 of ID 1 and 2 bytes at 36 of ID 2.
  EXPECT_THAT(
      Dxl1InstructionPacket(kDxlBroadcastId, DxlInstruction::kBulkRead,
                            {0x00, 0x02, 0x01, 0x1E, 0x02, 0x02, 0x24}),
      ElementsAre(0xFF, 0xFF, 0xFE, 0x09, 0x92, 0x00, 0x02, 0x01, 0x1E, 0x02, 0x02, 0x24, 0x1D));
}

TEST(Dxl1EncodeTest, ChecksumIsTheInvertedLowByteOfTheSum) {
  const uint8_t bytes[] = {0x01, 0x04, 0x02, 0x2B, 0x01};
  EXPECT_EQ(Dxl1Checksum(bytes, sizeof bytes), 0xCC);
  // The sum overflows a byte: only its low byte counts.
  const uint8_t big[] = {0xFE, 0xFE, 0xFE};
  EXPECT_EQ(Dxl1Checksum(big, sizeof big), static_cast<uint8_t>(~(0xFE * 3) & 0xFF));
}

TEST(Dxl1EncodeTest, RefusesWhatTheFormatCannotCarry) {
  uint8_t out[kDxl1MaxPacketSize + 8];
  Bytes params(kDxl1MaxParams + 1, 0);
  EXPECT_EQ(EncodeDxl1Packet(1, 3, params.data(), params.size(), out, sizeof out), 0u);
  EXPECT_EQ(EncodeDxl1Packet(1, 3, params.data(), kDxl1MaxParams, out, sizeof out),
            kDxl1MaxPacketSize);
  EXPECT_EQ(EncodeDxl1Packet(0xFF, 1, nullptr, 0, out, sizeof out), 0u);
  EXPECT_EQ(EncodeDxl1Packet(1, 1, nullptr, 0, out, 5), 0u);  // needs 6
}

TEST(Dxl1DecoderTest, DecodesAStatusPacketSplitAnywhere) {
  const Bytes packet = {0xFF, 0xFF, 0x01, 0x03, 0x00, 0x20, 0xDB};
  for (size_t chunk = 1; chunk <= packet.size(); ++chunk) {
    Dxl1Decoder decoder(DxlPacketKind::kStatus);
    auto packets = DecodeAll(&decoder, packet, chunk);
    ASSERT_EQ(packets.size(), 1u) << "chunk " << chunk;
    EXPECT_EQ(packets[0].id, 1);
    EXPECT_EQ(packets[0].instruction, static_cast<uint8_t>(DxlInstruction::kStatus));
    EXPECT_EQ(packets[0].error, 0);
    EXPECT_THAT(packets[0].params, ElementsAre(0x20));
  }
}

TEST(Dxl1DecoderTest, InstructionDecoderReportsTheInstruction) {
  Dxl1Decoder decoder(DxlPacketKind::kInstruction);
  auto packets = DecodeAll(&decoder, Dxl1InstructionPacket(7, DxlInstruction::kRead, {36, 2}));
  ASSERT_EQ(packets.size(), 1u);
  EXPECT_EQ(packets[0].id, 7);
  EXPECT_EQ(packets[0].instruction, static_cast<uint8_t>(DxlInstruction::kRead));
  EXPECT_EQ(packets[0].error, 0);
  EXPECT_THAT(packets[0].params, ElementsAre(36, 2));
}

TEST(Dxl1DecoderTest, ResynchronisesAfterGarbageAndCountsWhatItSkipped) {
  Dxl1Decoder decoder(DxlPacketKind::kStatus);
  Bytes bytes = {0x00, 0x12, 0xFF, 0x34, 0xFF, 0xFF, 0xFF};  // noise, then FF FF FF
  const Bytes packet = Dxl1StatusPacket(3, kDxl1OverloadError, {0x10, 0x20});
  // The third FF above makes the header FF FF FF FF: the decoder must slide to the last two.
  bytes.insert(bytes.end(), packet.begin() + 2, packet.end());
  auto packets = DecodeAll(&decoder, bytes, 1);
  ASSERT_EQ(packets.size(), 1u);
  EXPECT_EQ(packets[0].id, 3);
  EXPECT_EQ(packets[0].error, kDxl1OverloadError);
  EXPECT_THAT(packets[0].params, ElementsAre(0x10, 0x20));
  EXPECT_EQ(decoder.stats().discarded_bytes, 5u);
  EXPECT_EQ(decoder.stats().packets, 1u);
}

TEST(Dxl1DecoderTest, BadChecksumIsCountedAndTheNextPacketStillDecodes) {
  Dxl1Decoder decoder(DxlPacketKind::kStatus);
  Bytes bad = Dxl1StatusPacket(1, 0, {0x01, 0x02});
  bad.back() ^= 0x5A;
  Bytes bytes = bad;
  const Bytes good = Dxl1StatusPacket(2, 0, {0x03});
  bytes.insert(bytes.end(), good.begin(), good.end());
  auto packets = DecodeAll(&decoder, bytes);
  ASSERT_EQ(packets.size(), 1u);
  EXPECT_EQ(packets[0].id, 2);
  EXPECT_EQ(decoder.stats().checksum_errors, 1u);
}

TEST(Dxl1DecoderTest, AFalseHeaderInsideAPacketDoesNotHideTheRealOne) {
  // A corrupted packet whose parameters hold FF FF and a large "length": the decoder waits for
  // that many bytes, finds the checksum wrong, and must then find the packets it swallowed.
  Dxl1Decoder decoder(DxlPacketKind::kStatus);
  Bytes bytes = {0xFF, 0xFF, 0x05, 0x30};  // header of a 52-byte-long packet that never comes
  std::vector<Bytes> goods;
  // 7 packets of 8 bytes: more than the 48 bytes the false header announces.
  for (uint8_t id = 1; id <= 7; ++id) goods.push_back(Dxl1StatusPacket(id, 0, {id, 0xFF}));
  for (const Bytes& g : goods) bytes.insert(bytes.end(), g.begin(), g.end());
  auto packets = DecodeAll(&decoder, bytes, 3);
  ASSERT_EQ(packets.size(), 7u);
  for (uint8_t i = 0; i < 7; ++i) EXPECT_EQ(packets[i].id, i + 1);
  EXPECT_EQ(decoder.stats().checksum_errors, 1u);
}

TEST(Dxl1DecoderTest, LengthBelowTwoIsMalformed) {
  Dxl1Decoder decoder(DxlPacketKind::kStatus);
  Bytes bytes = {0xFF, 0xFF, 0x01, 0x01, 0xFD};
  const Bytes good = Dxl1StatusPacket(1, 0);
  bytes.insert(bytes.end(), good.begin(), good.end());
  auto packets = DecodeAll(&decoder, bytes);
  ASSERT_EQ(packets.size(), 1u);
  EXPECT_EQ(decoder.stats().malformed, 1u);
}

TEST(Dxl1DecoderTest, ResetDropsAPartialPacket) {
  Dxl1Decoder decoder(DxlPacketKind::kStatus);
  const Bytes packet = Dxl1StatusPacket(1, 0, {1, 2, 3});
  decoder.FeedAll(packet.data(), 5, [](const DxlPacket&) { FAIL(); });
  decoder.Reset();
  auto packets = DecodeAll(&decoder, packet);
  ASSERT_EQ(packets.size(), 1u);
  EXPECT_THAT(packets[0].params, ElementsAre(1, 2, 3));
}

TEST(Dxl1ErrorTest, NamesEveryBit) {
  EXPECT_EQ(Dxl1ErrorText(0), "none");
  EXPECT_EQ(Dxl1ErrorText(kDxl1InputVoltageError), "input voltage");
  EXPECT_EQ(Dxl1ErrorText(kDxl1AngleLimitError), "angle limit");
  EXPECT_EQ(Dxl1ErrorText(kDxl1OverheatingError), "overheating");
  EXPECT_EQ(Dxl1ErrorText(kDxl1RangeError), "range");
  EXPECT_EQ(Dxl1ErrorText(kDxl1ChecksumError), "checksum");
  EXPECT_EQ(Dxl1ErrorText(kDxl1OverloadError), "overload");
  EXPECT_EQ(Dxl1ErrorText(kDxl1InstructionError), "instruction");
  EXPECT_EQ(Dxl1ErrorText(kDxl1OverheatingError | kDxl1OverloadError), "overheating, overload");
  EXPECT_EQ(Dxl1ErrorText(0x80), "bit 7");
  EXPECT_EQ(ToString(DxlInstruction::kBulkRead), "bulk read");
  EXPECT_EQ(ToString(static_cast<DxlInstruction>(0x42)), "0x42");
}

// Valid packets separated by random noise that holds no 0xFF byte: every packet must come out,
// intact and in order, whatever the split.
TEST(Dxl1DecoderTest, SeededRandomPacketsBetweenNoiseAllComeOut) {
  std::mt19937 rng(20240611);
  std::uniform_int_distribution<int> byte(0, 255);
  std::uniform_int_distribution<int> noise_byte(0, 254);
  for (int round = 0; round < 50; ++round) {
    Bytes stream;
    std::vector<Decoded> sent;
    for (int k = 0; k < 20; ++k) {
      const int noise = byte(rng) % 6;
      for (int i = 0; i < noise; ++i) stream.push_back(static_cast<uint8_t>(noise_byte(rng)));
      Decoded d{static_cast<uint8_t>(byte(rng) % 254), 0x55, static_cast<uint8_t>(byte(rng)), {}};
      const int n = byte(rng) % 40;
      for (int i = 0; i < n; ++i) d.params.push_back(static_cast<uint8_t>(byte(rng)));
      const Bytes packet = Dxl1StatusPacket(d.id, d.error, d.params);
      stream.insert(stream.end(), packet.begin(), packet.end());
      sent.push_back(d);
    }
    Dxl1Decoder decoder(DxlPacketKind::kStatus);
    auto got = DecodeAll(&decoder, stream, 1 + byte(rng) % 17);
    ASSERT_EQ(got.size(), sent.size()) << "round " << round;
    for (size_t i = 0; i < sent.size(); ++i) {
      EXPECT_EQ(got[i].id, sent[i].id);
      EXPECT_EQ(got[i].error, sent[i].error);
      EXPECT_EQ(got[i].params, sent[i].params);
    }
  }
}

// Pure random bytes, FF-rich: whatever comes out must be a packet whose checksum holds, and the
// decoder must keep decoding a good packet afterwards.
TEST(Dxl1DecoderTest, SeededRandomBytesNeverYieldAnInvalidPacket) {
  std::mt19937 rng(77);
  std::uniform_int_distribution<int> byte(0, 255);
  Dxl1Decoder decoder(DxlPacketKind::kStatus);
  for (int round = 0; round < 200; ++round) {
    Bytes stream(1 + byte(rng) * 4);
    for (auto& b : stream) b = byte(rng) < 64 ? 0xFF : static_cast<uint8_t>(byte(rng));
    decoder.FeedAll(stream.data(), stream.size(), [](const DxlPacket& p) {
      ASSERT_LE(p.param_count, kDxl1MaxParams);
      Bytes params(p.params, p.params + p.param_count);
      const Bytes again = Dxl1StatusPacket(p.id, p.error, params);
      const uint8_t* start = p.params - 5;
      EXPECT_TRUE(std::equal(again.begin(), again.end(), start))
          << "a decoded packet does not re-encode to its own bytes";
    });
  }
  // Flush whatever candidate the noise left open, then a good packet must come through.
  decoder.Reset();
  auto packets = DecodeAll(&decoder, Dxl1StatusPacket(9, 0, {1, 2}));
  ASSERT_EQ(packets.size(), 1u);
  EXPECT_EQ(packets[0].id, 9);
}

}  // namespace
}  // namespace kinevis::hal
