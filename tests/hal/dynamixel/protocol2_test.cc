#include "hal/dynamixel/protocol2.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <random>
#include <string>
#include <vector>

namespace kinevis::hal {
namespace {

using Bytes = std::vector<uint8_t>;
using ::testing::ElementsAre;
using ::testing::ElementsAreArray;

struct Decoded {
  uint8_t id;
  uint8_t instruction;
  uint8_t error;
  Bytes params;
};

std::vector<Decoded> DecodeAll(Dxl2Decoder* decoder, const Bytes& bytes, size_t chunk = 1000) {
  std::vector<Decoded> out;
  for (size_t i = 0; i < bytes.size(); i += chunk) {
    const size_t n = std::min(chunk, bytes.size() - i);
    decoder->FeedAll(bytes.data() + i, n, [&](const DxlPacket& p) {
      out.push_back({p.id, p.instruction, p.error, p.ParamVector()});
    });
  }
  return out;
}

// The two official vectors of the issue: ping of ID 1 and its answer.
TEST(Dxl2EncodeTest, PingOfId1IsByteExact) {
  EXPECT_THAT(Dxl2InstructionPacket(1, DxlInstruction::kPing),
              ElementsAre(0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x03, 0x00, 0x01, 0x19, 0x4E));
}

TEST(Dxl2EncodeTest, PingStatusIsByteExact) {
  // Model number 0x0406, firmware 0x26.
  EXPECT_THAT(Dxl2StatusPacket(1, 0, {0x06, 0x04, 0x26}),
              ElementsAre(0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x07, 0x00, 0x55, 0x00, 0x06, 0x04, 0x26,
                          0x65, 0x5D));
}

// Further examples of the Protocol 2.0 e-manual.
TEST(Dxl2EncodeTest, ReadWriteRebootSyncReadAndSyncWriteMatchTheManual) {
  // Read 4 bytes at 132 (present position) of ID 1, and the answer 166.
  EXPECT_THAT(Dxl2InstructionPacket(1, DxlInstruction::kRead, {0x84, 0x00, 0x04, 0x00}),
              ElementsAre(0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x07, 0x00, 0x02, 0x84, 0x00, 0x04, 0x00,
                          0x1D, 0x15));
  EXPECT_THAT(Dxl2StatusPacket(1, 0, {0xA6, 0x00, 0x00, 0x00}),
              ElementsAre(0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x08, 0x00, 0x55, 0x00, 0xA6, 0x00, 0x00,
                          0x00, 0x8C, 0xC0));
  // Write 512 to 116 (goal position) of ID 1, and the empty answer.
  EXPECT_THAT(
      Dxl2InstructionPacket(1, DxlInstruction::kWrite, {0x74, 0x00, 0x00, 0x02, 0x00, 0x00}),
      ElementsAre(0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x09, 0x00, 0x03, 0x74, 0x00, 0x00, 0x02, 0x00,
                  0x00, 0xCA, 0x89));
  EXPECT_THAT(Dxl2StatusPacket(1, 0),
              ElementsAre(0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x04, 0x00, 0x55, 0x00, 0xA1, 0x0C));
  EXPECT_THAT(Dxl2InstructionPacket(1, DxlInstruction::kReboot),
              ElementsAre(0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x03, 0x00, 0x08, 0x2F, 0x4E));
  // Sync read of 4 bytes at 132 from IDs 1 and 2.
  EXPECT_THAT(Dxl2InstructionPacket(kDxlBroadcastId, DxlInstruction::kSyncRead,
                                    {0x84, 0x00, 0x04, 0x00, 0x01, 0x02}),
              ElementsAre(0xFF, 0xFF, 0xFD, 0x00, 0xFE, 0x09, 0x00, 0x82, 0x84, 0x00, 0x04, 0x00,
                          0x01, 0x02, 0xCE, 0xFA));
  // Sync write of 4 bytes at 116: 150 to ID 1, 170 to ID 2.
  EXPECT_THAT(Dxl2InstructionPacket(kDxlBroadcastId, DxlInstruction::kSyncWrite,
                                    {0x74, 0x00, 0x04, 0x00, 0x01, 0x96, 0x00, 0x00, 0x00, 0x02,
                                     0xAA, 0x00, 0x00, 0x00}),
              ElementsAreArray(Bytes{0xFF, 0xFF, 0xFD, 0x00, 0xFE, 0x11, 0x00, 0x83,
                                     0x74, 0x00, 0x04, 0x00, 0x01, 0x96, 0x00, 0x00,
                                     0x00, 0x02, 0xAA, 0x00, 0x00, 0x00, 0x82, 0x87}));
}

TEST(Dxl2CrcTest, MatchesTheOfficialVectorsAndChains) {
  const Bytes ping = {0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x03, 0x00, 0x01};
  EXPECT_EQ(Dxl2Crc16(ping.data(), ping.size()), 0x4E19);
  // Computing in two parts gives the same CRC.
  const uint16_t half = Dxl2Crc16(ping.data(), 3);
  EXPECT_EQ(Dxl2Crc16(ping.data() + 3, ping.size() - 3, half), 0x4E19);
  const Bytes status = {0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x07, 0x00, 0x55, 0x00, 0x06, 0x04, 0x26};
  EXPECT_EQ(Dxl2Crc16(status.data(), status.size()), 0x5D65);
  // The CRC-16/BUYPASS check value ("123456789"), the same polynomial and settings.
  const std::string check = "123456789";
  EXPECT_EQ(Dxl2Crc16(reinterpret_cast<const uint8_t*>(check.data()), check.size()), 0xFEE8);
}

TEST(Dxl2StuffingTest, HeaderPatternInTheParametersIsStuffedAndLenCountsIt) {
  // Write FF FF FD 01 at address 0x0200: the body is 03 00 02 FF FF FD 01.
  const Bytes packet =
      Dxl2InstructionPacket(1, DxlInstruction::kWrite, {0x00, 0x02, 0xFF, 0xFF, 0xFD, 0x01});
  ASSERT_EQ(packet.size(), 7u + 1 + 6 + 1 + 2);
  EXPECT_EQ(packet[5], 3 + 6 + 1);  // LEN: params + 3 + one stuffed byte
  EXPECT_EQ(packet[6], 0);
  EXPECT_THAT(Bytes(packet.begin() + 7, packet.end() - 2),
              ElementsAre(0x03, 0x00, 0x02, 0xFF, 0xFF, 0xFD, 0xFD, 0x01));
  // The CRC covers the stuffed bytes.
  const uint16_t crc = Dxl2Crc16(packet.data(), packet.size() - 2);
  EXPECT_EQ(packet[packet.size() - 2], crc & 0xFF);
  EXPECT_EQ(packet[packet.size() - 1], crc >> 8);

  Dxl2Decoder decoder(DxlPacketKind::kInstruction);
  auto packets = DecodeAll(&decoder, packet);
  ASSERT_EQ(packets.size(), 1u);
  EXPECT_THAT(packets[0].params, ElementsAre(0x00, 0x02, 0xFF, 0xFF, 0xFD, 0x01));
}

TEST(Dxl2StuffingTest, RepeatedAndTrailingPatternsRoundTrip) {
  const Bytes params = {0xFF, 0xFF, 0xFD, 0xFF, 0xFF, 0xFD, 0xFD, 0xFF, 0xFF, 0xFF, 0xFD};
  const Bytes packet = Dxl2StatusPacket(4, 0, params);
  // Three occurrences of FF FF FD, each followed by an added FD.
  EXPECT_EQ(packet.size(), 7u + 2 + params.size() + 3 + 2);
  EXPECT_LE(packet.size(), Dxl2MaxEncodedSize(params.size() + 1));
  Dxl2Decoder decoder(DxlPacketKind::kStatus);
  auto packets = DecodeAll(&decoder, packet, 2);
  ASSERT_EQ(packets.size(), 1u);
  EXPECT_EQ(packets[0].params, params);
}

TEST(Dxl2DecoderTest, UnstuffedHeaderInsideABodyIsMalformed) {
  // A body with FF FF FD not followed by FD, with a correct CRC: a broken sender.
  Bytes packet = {0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x08, 0x00, 0x55, 0x00, 0xFF, 0xFF, 0xFD, 0x01};
  const uint16_t crc = Dxl2Crc16(packet.data(), packet.size());
  packet.push_back(crc & 0xFF);
  packet.push_back(crc >> 8);
  Dxl2Decoder decoder(DxlPacketKind::kStatus);
  EXPECT_TRUE(DecodeAll(&decoder, packet).empty());
  EXPECT_EQ(decoder.stats().malformed, 1u);
}

TEST(Dxl2DecoderTest, DecodesTheOfficialStatusSplitAnywhere) {
  const Bytes packet = {0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x07, 0x00,
                        0x55, 0x00, 0x06, 0x04, 0x26, 0x65, 0x5D};
  for (size_t chunk = 1; chunk <= packet.size(); ++chunk) {
    Dxl2Decoder decoder(DxlPacketKind::kStatus);
    auto packets = DecodeAll(&decoder, packet, chunk);
    ASSERT_EQ(packets.size(), 1u) << "chunk " << chunk;
    EXPECT_EQ(packets[0].id, 1);
    EXPECT_EQ(packets[0].instruction, 0x55);
    EXPECT_EQ(packets[0].error, 0);
    EXPECT_THAT(packets[0].params, ElementsAre(0x06, 0x04, 0x26));
  }
}

TEST(Dxl2DecoderTest, BadCrcIsCountedAndTheNextPacketStillDecodes) {
  Bytes bytes = Dxl2StatusPacket(1, 0, {0x10, 0x20});
  bytes[bytes.size() - 2] ^= 0x01;
  const Bytes good = Dxl2StatusPacket(2, 0x80 | 4);
  bytes.insert(bytes.end(), good.begin(), good.end());
  Dxl2Decoder decoder(DxlPacketKind::kStatus);
  auto packets = DecodeAll(&decoder, bytes);
  ASSERT_EQ(packets.size(), 1u);
  EXPECT_EQ(packets[0].id, 2);
  EXPECT_EQ(packets[0].error, 0x84);
  EXPECT_EQ(decoder.stats().checksum_errors, 1u);
}

TEST(Dxl2DecoderTest, ResynchronisesAfterGarbage) {
  Bytes bytes = {0x00, 0xFF, 0xFF, 0xFF, 0xFD, 0x01, 0xFF, 0xFF, 0xFD};  // partial headers
  const Bytes good = Dxl2StatusPacket(3, 0, {0x01});
  bytes.insert(bytes.end(), good.begin(), good.end());
  Dxl2Decoder decoder(DxlPacketKind::kStatus);
  auto packets = DecodeAll(&decoder, bytes, 1);
  ASSERT_EQ(packets.size(), 1u);
  EXPECT_EQ(packets[0].id, 3);
  EXPECT_EQ(decoder.stats().discarded_bytes, 9u);
}

TEST(Dxl2DecoderTest, EachDirectionIgnoresTheOther) {
  Bytes bytes = Dxl2InstructionPacket(1, DxlInstruction::kRead, {0x84, 0x00, 0x04, 0x00});
  const Bytes status = Dxl2StatusPacket(1, 0, {1, 2, 3, 4});
  bytes.insert(bytes.end(), status.begin(), status.end());

  Dxl2Decoder host(DxlPacketKind::kStatus);
  auto at_host = DecodeAll(&host, bytes);
  ASSERT_EQ(at_host.size(), 1u);
  EXPECT_THAT(at_host[0].params, ElementsAre(1, 2, 3, 4));
  EXPECT_EQ(host.stats().ignored, 1u);

  Dxl2Decoder servo(DxlPacketKind::kInstruction);
  auto at_servo = DecodeAll(&servo, bytes);
  ASSERT_EQ(at_servo.size(), 1u);
  EXPECT_EQ(at_servo[0].instruction, static_cast<uint8_t>(DxlInstruction::kRead));
  EXPECT_EQ(servo.stats().ignored, 1u);
}

TEST(Dxl2DecoderTest, TooLongAPacketIsSkippedWithoutWaitingForIt) {
  Dxl2Decoder decoder(DxlPacketKind::kStatus, 64);
  Bytes bytes = Dxl2StatusPacket(1, 0, Bytes(100, 0x11));
  const Bytes good = Dxl2StatusPacket(2, 0, Bytes(10, 0x22));
  bytes.insert(bytes.end(), good.begin(), good.end());
  auto packets = DecodeAll(&decoder, bytes, 7);
  ASSERT_EQ(packets.size(), 1u);
  EXPECT_EQ(packets[0].id, 2);
  EXPECT_EQ(decoder.stats().malformed, 1u);
}

TEST(Dxl2DecoderTest, InvalidIdsAndShortLengthsAreNotPackets) {
  Dxl2Decoder decoder(DxlPacketKind::kStatus);
  // ID 0xFD, and a status with LEN 3 (no room for the error field).
  Bytes bytes = {0xFF, 0xFF, 0xFD, 0x00, 0xFD, 0x04, 0x00, 0x55, 0x00, 0x00, 0x00,
                 0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x03, 0x00, 0x55, 0x00, 0x00};
  const Bytes good = Dxl2StatusPacket(1, 0);
  bytes.insert(bytes.end(), good.begin(), good.end());
  auto packets = DecodeAll(&decoder, bytes);
  ASSERT_EQ(packets.size(), 1u);
  EXPECT_EQ(decoder.stats().malformed, 1u);
  uint8_t out[32];
  EXPECT_EQ(EncodeDxl2Instruction(0xFD, 1, nullptr, 0, out, sizeof out), 0u);
  EXPECT_EQ(EncodeDxl2Instruction(0xFF, 1, nullptr, 0, out, sizeof out), 0u);
  EXPECT_EQ(EncodeDxl2Instruction(1, 1, nullptr, 0, out, 9), 0u);  // needs 10
  EXPECT_EQ(EncodeDxl2Instruction(1, 1, nullptr, 0, out, 10), 10u);
}

TEST(Dxl2ErrorTest, NamesTheAlertBitTheCodesAndTheHardwareBits) {
  EXPECT_EQ(Dxl2ErrorText(0), "none");
  EXPECT_EQ(Dxl2ErrorText(1), "result fail");
  EXPECT_EQ(Dxl2ErrorText(2), "instruction error");
  EXPECT_EQ(Dxl2ErrorText(3), "CRC error");
  EXPECT_EQ(Dxl2ErrorText(4), "data range error");
  EXPECT_EQ(Dxl2ErrorText(5), "data length error");
  EXPECT_EQ(Dxl2ErrorText(6), "data limit error");
  EXPECT_EQ(Dxl2ErrorText(7), "access error");
  EXPECT_EQ(Dxl2ErrorText(0x80), "alert");
  EXPECT_EQ(Dxl2ErrorText(0x87), "alert, access error");
  EXPECT_EQ(Dxl2ErrorText(0x09), "error code 9");
  EXPECT_EQ(Dxl2HardwareErrorText(0), "none");
  EXPECT_EQ(Dxl2HardwareErrorText(kDxl2HwOverload), "overload");
  EXPECT_EQ(Dxl2HardwareErrorText(kDxl2HwInputVoltage | kDxl2HwOverheating | kDxl2HwMotorEncoder |
                                  kDxl2HwElectricalShock),
            "input voltage, overheating, motor encoder, electrical shock");
  EXPECT_EQ(Dxl2HardwareErrorText(0x02), "bit 1");
}

// Valid packets (random ids, errors and parameters, FF FF FD patterns likely) separated by noise
// that holds no 0xFF: every packet comes out intact, whatever the split.
TEST(Dxl2DecoderTest, SeededRandomPacketsBetweenNoiseAllComeOut) {
  std::mt19937 rng(424242);
  std::uniform_int_distribution<int> byte(0, 255);
  const uint8_t pattern_bytes[] = {0xFF, 0xFD, 0x00, 0x42};
  for (int round = 0; round < 50; ++round) {
    Bytes stream;
    std::vector<Decoded> sent;
    for (int k = 0; k < 20; ++k) {
      const int noise = byte(rng) % 6;
      for (int i = 0; i < noise; ++i) stream.push_back(static_cast<uint8_t>(byte(rng) % 255));
      Decoded d{static_cast<uint8_t>(byte(rng) % 253), 0x55, static_cast<uint8_t>(byte(rng)), {}};
      const int n = byte(rng) % 40;
      for (int i = 0; i < n; ++i) d.params.push_back(pattern_bytes[byte(rng) % 4]);
      const Bytes packet = Dxl2StatusPacket(d.id, d.error, d.params);
      ASSERT_FALSE(packet.empty());
      stream.insert(stream.end(), packet.begin(), packet.end());
      sent.push_back(d);
    }
    Dxl2Decoder decoder(DxlPacketKind::kStatus);
    auto got = DecodeAll(&decoder, stream, 1 + byte(rng) % 17);
    ASSERT_EQ(got.size(), sent.size()) << "round " << round;
    for (size_t i = 0; i < sent.size(); ++i) {
      EXPECT_EQ(got[i].id, sent[i].id);
      EXPECT_EQ(got[i].error, sent[i].error);
      EXPECT_EQ(got[i].params, sent[i].params);
    }
    EXPECT_EQ(decoder.stats().checksum_errors, 0u);
  }
}

// Random header-rich bytes: whatever comes out re-encodes to a packet with a valid CRC, and a good
// packet decodes afterwards.
TEST(Dxl2DecoderTest, SeededRandomBytesNeverYieldAnInvalidPacket) {
  std::mt19937 rng(99);
  std::uniform_int_distribution<int> byte(0, 255);
  const uint8_t likely[] = {0xFF, 0xFF, 0xFD, 0x00, 0x55, 0x01, 0x02};
  Dxl2Decoder decoder(DxlPacketKind::kStatus, 256);
  for (int round = 0; round < 200; ++round) {
    Bytes stream(1 + byte(rng) * 4);
    for (auto& b : stream) b = byte(rng) < 128 ? likely[byte(rng) % 7] : byte(rng);
    decoder.FeedAll(stream.data(), stream.size(), [](const DxlPacket& p) {
      const Bytes again = Dxl2StatusPacket(p.id, p.error, p.ParamVector());
      ASSERT_FALSE(again.empty());
      Dxl2Decoder check(DxlPacketKind::kStatus);
      int n = 0;
      check.FeedAll(again.data(), again.size(), [&](const DxlPacket&) { ++n; });
      EXPECT_EQ(n, 1);
    });
  }
  decoder.Reset();
  auto packets = DecodeAll(&decoder, Dxl2StatusPacket(9, 0, {1, 2}));
  ASSERT_EQ(packets.size(), 1u);
  EXPECT_EQ(packets[0].id, 9);
}

}  // namespace
}  // namespace kinevis::hal
