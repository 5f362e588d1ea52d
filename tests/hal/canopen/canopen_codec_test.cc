#include "hal/canopen/canopen_codec.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <random>

namespace kinevis::hal::canopen {
namespace {

// The 8 data bytes of a frame as a vector, for comparisons with specification byte vectors.
std::vector<uint8_t> Bytes(const CanFrame& f) { return {f.data.begin(), f.data.begin() + f.dlc}; }

TEST(CanopenCodecTest, NmtFrames) {
  CanFrame f = EncodeNmt(NmtCommand::kStart, 5);
  EXPECT_EQ(f.id, 0x000u);
  EXPECT_EQ(Bytes(f), (std::vector<uint8_t>{0x01, 0x05}));
  EXPECT_EQ(Bytes(EncodeNmt(NmtCommand::kResetCommunication, 0)),
            (std::vector<uint8_t>{0x82, 0x00}));
  auto m = DecodeNmt(EncodeNmt(NmtCommand::kEnterPreOperational, 127));
  ASSERT_TRUE(m);
  EXPECT_EQ(m->command, NmtCommand::kEnterPreOperational);
  EXPECT_EQ(m->node, 127);
  EXPECT_FALSE(DecodeNmt(CanFrame::Standard(0x000, {0x03, 0x01})));  // unknown command
  EXPECT_FALSE(DecodeNmt(CanFrame::Standard(0x000, {0x01, 0x80})));  // node 128
}

TEST(CanopenCodecTest, HeartbeatAndBootUp) {
  CanFrame f = EncodeHeartbeat(3, NmtState::kOperational);
  EXPECT_EQ(f.id, 0x703u);
  EXPECT_EQ(Bytes(f), (std::vector<uint8_t>{0x05}));
  EXPECT_EQ(Bytes(EncodeHeartbeat(3, NmtState::kBootUp)), (std::vector<uint8_t>{0x00}));
  auto hb = DecodeHeartbeat(CanFrame::Standard(0x77F, {0x7F}));
  ASSERT_TRUE(hb);
  EXPECT_EQ(hb->node, 127);
  EXPECT_EQ(hb->state, NmtState::kPreOperational);
  // Node guarding toggle bit is ignored.
  EXPECT_EQ(DecodeHeartbeat(CanFrame::Standard(0x701, {0x85}))->state, NmtState::kOperational);
  EXPECT_FALSE(DecodeHeartbeat(CanFrame::Standard(0x700, {0x05})));  // node 0
  EXPECT_FALSE(DecodeHeartbeat(CanFrame::Standard(0x701, {0x06})));  // no such state
}

TEST(CanopenCodecTest, SyncAndEmcyShareABaseButDiffer) {
  EXPECT_TRUE(IsSync(EncodeSync()));
  EXPECT_TRUE(IsSync(EncodeSync(uint8_t{7})));
  EXPECT_FALSE(DecodeEmcy(EncodeSync()).has_value());
  EmcyMessage e;
  e.node = 4;
  e.error_code = 0x8611;
  e.error_register = 0x20;
  e.manufacturer = {1, 2, 3, 4, 5};
  CanFrame f = EncodeEmcy(e);
  EXPECT_EQ(f.id, 0x084u);
  EXPECT_EQ(Bytes(f), (std::vector<uint8_t>{0x11, 0x86, 0x20, 1, 2, 3, 4, 5}));
  auto d = DecodeEmcy(f);
  ASSERT_TRUE(d);
  EXPECT_EQ(d->node, 4);
  EXPECT_EQ(d->error_code, 0x8611);
  EXPECT_EQ(EmcyErrorText(0x8611), "following error");
  EXPECT_EQ(EmcyErrorText(0x4210), "temperature");
  EXPECT_EQ(EmcyErrorText(0x0000), "error reset or no error");
}

// Byte vectors from the command specifier table of CiA 301 (and the summary).
TEST(CanopenCodecTest, ExpeditedDownloadCommandBytes) {
  const uint8_t v[4] = {0x0F, 0x00, 0x00, 0x00};
  struct {
    uint8_t size;
    uint8_t command;
  } cases[] = {{4, 0x23}, {3, 0x27}, {2, 0x2B}, {1, 0x2F}};
  for (auto c : cases) {
    CanFrame f = EncodeSdoRequest(2, SdoMessage::ExpeditedDownload(0x6040, 0x00, v, c.size));
    EXPECT_EQ(f.id, 0x602u);
    EXPECT_EQ(f.dlc, 8);
    EXPECT_EQ(f.data[0], c.command) << int(c.size);
    EXPECT_EQ(f.data[1], 0x40);
    EXPECT_EQ(f.data[2], 0x60);
    EXPECT_EQ(f.data[3], 0x00);
    EXPECT_EQ(f.data[4], 0x0F);
  }
  CanFrame ok = EncodeSdoResponse(2, SdoMessage::InitiateDownloadResponse(0x6040, 0));
  EXPECT_EQ(ok.id, 0x582u);
  EXPECT_EQ(Bytes(ok), (std::vector<uint8_t>{0x60, 0x40, 0x60, 0x00, 0, 0, 0, 0}));
}

TEST(CanopenCodecTest, ExpeditedUploadCommandBytes) {
  CanFrame req = EncodeSdoRequest(1, SdoMessage::InitiateUpload(0x6041, 0));
  EXPECT_EQ(Bytes(req), (std::vector<uint8_t>{0x40, 0x41, 0x60, 0x00, 0, 0, 0, 0}));
  const uint8_t sw[2] = {0x37, 0x02};
  CanFrame resp = EncodeSdoResponse(1, SdoMessage::ExpeditedUploadResponse(0x6041, 0, sw, 2));
  EXPECT_EQ(Bytes(resp), (std::vector<uint8_t>{0x4B, 0x41, 0x60, 0x00, 0x37, 0x02, 0, 0}));
  for (auto [size, cmd] :
       std::vector<std::pair<uint8_t, uint8_t>>{{4, 0x43}, {3, 0x47}, {2, 0x4B}, {1, 0x4F}}) {
    const uint8_t d[4] = {1, 2, 3, 4};
    auto m = DecodeSdoResponse(
        EncodeSdoResponse(1, SdoMessage::ExpeditedUploadResponse(0x1000, 0, d, size)));
    ASSERT_TRUE(m);
    EXPECT_EQ(EncodeSdoResponse(1, *m).data[0], cmd);
    EXPECT_EQ(m->type, SdoType::kInitiateUploadResponse);
    EXPECT_TRUE(m->expedited);
    EXPECT_EQ(m->size, size);
  }
}

TEST(CanopenCodecTest, SegmentedTransferBytes) {
  // Initiate segmented download of 11 bytes: 0x21, size in bytes 4..7.
  CanFrame init = EncodeSdoRequest(1, SdoMessage::SegmentedDownload(0x1008, 0, 11));
  EXPECT_EQ(Bytes(init), (std::vector<uint8_t>{0x21, 0x08, 0x10, 0x00, 11, 0, 0, 0}));
  const uint8_t seg[7] = {'k', 'i', 'n', 'e', 'v', 'i', 's'};
  // First segment: toggle 0, 7 bytes, not last -> 0x00.
  EXPECT_EQ(EncodeSdoRequest(1, SdoMessage::DownloadSegment(false, seg, 7, false)).data[0], 0x00);
  // Second: toggle 1, 4 bytes (n = 3), last -> 0x10 | 3 << 1 | 1 = 0x17.
  EXPECT_EQ(EncodeSdoRequest(1, SdoMessage::DownloadSegment(true, seg, 4, true)).data[0], 0x17);
  EXPECT_EQ(EncodeSdoResponse(1, SdoMessage::DownloadSegmentResponse(true)).data[0], 0x30);
  EXPECT_EQ(EncodeSdoRequest(1, SdoMessage::UploadSegment(true)).data[0], 0x70);
  EXPECT_EQ(EncodeSdoResponse(1, SdoMessage::SegmentedUploadResponse(0x1008, 0, 23)).data[0], 0x41);
  auto last = DecodeSdoResponse(
      EncodeSdoResponse(1, SdoMessage::UploadSegmentResponse(false, seg, 2, true)));
  ASSERT_TRUE(last);
  EXPECT_EQ(last->type, SdoType::kUploadSegmentResponse);
  EXPECT_EQ(last->data_length, 2);
  EXPECT_TRUE(last->last);
  EXPECT_FALSE(last->toggle);
}

TEST(CanopenCodecTest, AbortCarriesCodeAndText) {
  CanFrame f = EncodeSdoResponse(9, SdoMessage::Abort(0x2000, 1, sdo_abort::kObjectDoesNotExist));
  EXPECT_EQ(Bytes(f), (std::vector<uint8_t>{0x80, 0x00, 0x20, 0x01, 0x00, 0x00, 0x02, 0x06}));
  auto m = DecodeSdoResponse(f);
  ASSERT_TRUE(m);
  EXPECT_EQ(m->type, SdoType::kAbort);
  EXPECT_EQ(m->abort_code, 0x06020000u);
  EXPECT_STREQ(SdoAbortText(m->abort_code), "Object does not exist in the object dictionary");
  EXPECT_STREQ(SdoAbortText(0x12345678), "unknown abort code");
}

TEST(CanopenCodecTest, RequestsAndResponsesRoundTrip) {
  std::mt19937 rng(11);
  for (int i = 0; i < 500; ++i) {
    uint8_t d[7];
    for (auto& b : d) b = static_cast<uint8_t>(rng());
    const uint16_t index = static_cast<uint16_t>(rng());
    const uint8_t sub = static_cast<uint8_t>(rng());
    const uint8_t n4 = static_cast<uint8_t>(1 + rng() % 4), n7 = static_cast<uint8_t>(rng() % 8);
    const bool t = rng() & 1, c = rng() & 1;
    for (const SdoMessage& m :
         {SdoMessage::ExpeditedDownload(index, sub, d, n4),
          SdoMessage::SegmentedDownload(index, sub, rng()),
          SdoMessage::DownloadSegment(t, d, n7, c), SdoMessage::InitiateUpload(index, sub),
          SdoMessage::UploadSegment(t), SdoMessage::Abort(index, sub, rng())}) {
      auto back = DecodeSdoRequest(EncodeSdoRequest(1, m));
      ASSERT_TRUE(back);
      EXPECT_EQ(Bytes(EncodeSdoRequest(1, *back)), Bytes(EncodeSdoRequest(1, m)));
    }
    for (const SdoMessage& m :
         {SdoMessage::InitiateDownloadResponse(index, sub), SdoMessage::DownloadSegmentResponse(t),
          SdoMessage::ExpeditedUploadResponse(index, sub, d, n4),
          SdoMessage::SegmentedUploadResponse(index, sub, rng()),
          SdoMessage::UploadSegmentResponse(t, d, n7, c), SdoMessage::Abort(index, sub, rng())}) {
      auto back = DecodeSdoResponse(EncodeSdoResponse(1, m));
      ASSERT_TRUE(back);
      EXPECT_EQ(Bytes(EncodeSdoResponse(1, *back)), Bytes(EncodeSdoResponse(1, m)));
    }
  }
}

TEST(CanopenCodecTest, MalformedSdoFramesAreRejectedWithAReason) {
  std::string error;
  EXPECT_FALSE(DecodeSdoResponse(CanFrame::Standard(0x581, {0x43, 0, 0x10, 0, 1}), &error));
  EXPECT_THAT(error, ::testing::HasSubstr("8 bytes"));
  CanFrame block = CanFrame::Standard(0x601, {0xC0, 0, 0, 0, 0, 0, 0, 0});  // block download
  EXPECT_FALSE(DecodeSdoRequest(block, &error));
  EXPECT_THAT(error, ::testing::HasSubstr("block"));
}

TEST(CanopenCodecTest, PdoMappingEntries) {
  PdoMappingEntry e{0x6040, 0x00, 16};
  EXPECT_EQ(e.Encode(), 0x60400010u);
  PdoMappingEntry d = PdoMappingEntry::Decode(0x607A0020);
  EXPECT_EQ(d.index, 0x607A);
  EXPECT_EQ(d.subindex, 0);
  EXPECT_EQ(d.bits, 32);
  uint8_t buf[4];
  PutLe(buf, 0x12345678, 4);
  EXPECT_EQ(buf[0], 0x78);
  EXPECT_EQ(GetLe(buf, 4), 0x12345678u);
}

}  // namespace
}  // namespace kinevis::hal::canopen
