#include "hal/can/can_frame.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <random>

namespace kinevis::hal {
namespace {

using ::testing::ContainsRegex;

TEST(CanFrameTest, FormatMatchesCansendSyntax) {
  EXPECT_EQ(FormatCanFrame(CanFrame::Standard(0x123, {0xDE, 0xAD, 0xBE, 0xEF})), "123#DEADBEEF");
  EXPECT_EQ(FormatCanFrame(CanFrame::Extended(0x1F334455, {0x11, 0x22})), "1F334455#1122");
  EXPECT_EQ(FormatCanFrame(CanFrame::Standard(0x5, {})), "005#");
  CanFrame rtr = CanFrame::Standard(0x701);
  rtr.rtr = true;
  rtr.dlc = 1;
  EXPECT_EQ(FormatCanFrame(rtr), "701#R1");
}

TEST(CanFrameTest, ParseRoundTrips) {
  for (const char* text : {"123#DEADBEEF", "1F334455#1122", "000#", "7FF#0011223344556677", "701#R",
                           "701#R8", "00000001#AB"}) {
    std::string error;
    auto f = ParseCanFrame(text, &error);
    ASSERT_TRUE(f.has_value()) << text << ": " << error;
    EXPECT_EQ(FormatCanFrame(*f), text);
  }
  auto dotted = ParseCanFrame("123#DE.AD.BE.EF");
  ASSERT_TRUE(dotted.has_value());
  EXPECT_EQ(*dotted, CanFrame::Standard(0x123, {0xDE, 0xAD, 0xBE, 0xEF}));
}

TEST(CanFrameTest, ParseErrorsSayWhatIsWrong) {
  std::string error;
  EXPECT_FALSE(ParseCanFrame("123DEAD", &error));
  EXPECT_THAT(error, ContainsRegex("no '#'"));
  EXPECT_FALSE(ParseCanFrame("12#00", &error));
  EXPECT_THAT(error, ContainsRegex("3 hex digits.*8 hex digits"));
  EXPECT_FALSE(ParseCanFrame("800#00", &error));
  EXPECT_THAT(error, ContainsRegex("exceeds 11 bits"));
  EXPECT_FALSE(ParseCanFrame("3FFFFFFF#00", &error));
  EXPECT_THAT(error, ContainsRegex("exceeds 29 bits"));
  EXPECT_FALSE(ParseCanFrame("123#001122334455667788", &error));
  EXPECT_THAT(error, ContainsRegex("0..8 bytes"));
  EXPECT_FALSE(ParseCanFrame("123#0G", &error));
  EXPECT_THAT(error, ContainsRegex("not hexadecimal"));
  EXPECT_FALSE(ParseCanFrame("123#R9", &error));
}

TEST(CanFrameTest, EqualityIgnoresBytesBeyondDlcAndTimestamp) {
  CanFrame a = CanFrame::Standard(0x10, {1, 2});
  CanFrame b = a;
  b.data[5] = 99;
  b.timestamp = std::chrono::seconds(3);
  EXPECT_EQ(a, b);
  b.data[1] = 3;
  EXPECT_NE(a, b);
}

TEST(CanFrameTest, WireBitsWithoutStuffingMatchTheFrameLayout) {
  // 0x555 with alternating data never has five equal bits in a row before the CRC; the count is
  // SOF..EOF (44 bits + 8 per data byte) + 3 interframe bits + the stuff bits the CRC causes.
  CanFrame f = CanFrame::Standard(0x555, {0x55, 0x55});
  int bits = CanFrameWireBits(f);
  EXPECT_GE(bits, 44 + 16 + 3);
  EXPECT_LE(bits, 44 + 16 + 3 + 4);  // at most a few stuff bits from the CRC
}

TEST(CanFrameTest, WireBitsOfAllZeroFrameCountStuffBits) {
  // Standard id 0, dlc 8, all-zero data: long dominant runs force a stuff bit every 4 bits after
  // the first five; the result must lie between the unstuffed length and the known worst case
  // 8n + 44 + floor((34 + 8n - 1) / 4) + 3 = 135 bits for n = 8.
  CanFrame f = CanFrame::Standard(0x000, {0, 0, 0, 0, 0, 0, 0, 0});
  int bits = CanFrameWireBits(f);
  EXPECT_GT(bits, 44 + 64 + 3 + 15);
  EXPECT_LE(bits, 135);
}

TEST(CanFrameTest, WireBitsStayWithinTheoreticalBounds) {
  std::mt19937 rng(7);
  for (int i = 0; i < 2000; ++i) {
    CanFrame f;
    f.extended = (rng() & 1) != 0;
    f.id = f.extended ? rng() & CanFrame::kMaxExtendedId : rng() & CanFrame::kMaxStandardId;
    f.dlc = static_cast<uint8_t>(rng() % 9);
    for (auto& b : f.data) b = static_cast<uint8_t>(rng());
    const int n = f.dlc;
    const int fixed = f.extended ? 64 : 44;      // SOF..EOF without data
    const int stuffable = f.extended ? 54 : 34;  // bits subject to stuffing without data
    int bits = CanFrameWireBits(f);
    EXPECT_GE(bits, fixed + 8 * n + 3) << FormatCanFrame(f);
    EXPECT_LE(bits, fixed + 8 * n + (stuffable + 8 * n - 1) / 4 + 3) << FormatCanFrame(f);
  }
}

TEST(CanFilterTest, MaskSemanticsLikeSocketCan) {
  CanFilter f;
  f.id = 0x180;
  f.mask = 0x780;  // all TPDO1 COB-IDs 0x180..0x1FF
  EXPECT_TRUE(f.Matches(CanFrame::Standard(0x181)));
  EXPECT_TRUE(f.Matches(CanFrame::Standard(0x1FF)));
  EXPECT_FALSE(f.Matches(CanFrame::Standard(0x281)));
  EXPECT_FALSE(f.Matches(CanFrame::Extended(0x181)));  // extended flag compared
  f.invert = true;
  EXPECT_FALSE(f.Matches(CanFrame::Standard(0x181)));
  EXPECT_TRUE(f.Matches(CanFrame::Standard(0x281)));
  CanFilter exact = CanFilter::Exact(0x701);
  EXPECT_TRUE(exact.Matches(CanFrame::Standard(0x701)));
  EXPECT_FALSE(exact.Matches(CanFrame::Standard(0x702)));
}

TEST(CanFilterTest, ParseCandumpFilterSyntax) {
  auto f = ParseCanFilter("123:7FF");
  ASSERT_TRUE(f.has_value());
  EXPECT_EQ(f->id, 0x123u);
  EXPECT_EQ(f->mask, 0x7FFu);
  EXPECT_FALSE(f->invert);
  auto inv = ParseCanFilter("100~700");
  ASSERT_TRUE(inv.has_value());
  EXPECT_TRUE(inv->invert);
  std::string error;
  EXPECT_FALSE(ParseCanFilter("123", &error));
  EXPECT_THAT(error, ContainsRegex("ID:MASK"));
  EXPECT_FALSE(ParseCanFilter("xyz:7FF", &error));
}

}  // namespace
}  // namespace kinevis::hal
