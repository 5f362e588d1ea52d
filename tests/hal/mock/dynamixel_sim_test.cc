#include "hal/mock/dynamixel_sim.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "common/clock.h"
#include "hal/common/error.h"
#include "hal/dynamixel/control_table.h"
#include "hal/dynamixel/protocol1.h"
#include "hal/dynamixel/protocol2.h"
#include "hal/serial/pty_pair.h"
#include "hal/serial/termios_serial_port.h"

namespace kinevis::hal {
namespace {

using namespace std::chrono_literals;
using Bytes = std::vector<uint8_t>;
using ::testing::ElementsAre;
using ::testing::ElementsAreArray;

// Generous bound for an answer on a loaded machine; the simulator answers in microseconds.
constexpr auto kAnswerDeadline = 5s;

Bytes Le(uint32_t v, int size) {
  Bytes out;
  for (int i = 0; i < size; ++i) out.push_back(static_cast<uint8_t>(v >> (8 * i)));
  return out;
}

Bytes Cat(std::initializer_list<Bytes> parts) {
  Bytes out;
  for (const Bytes& p : parts) out.insert(out.end(), p.begin(), p.end());
  return out;
}

// The host side: raw bytes written to and read from the pty slave, as a terminal program would.
class DynamixelSimTest : public ::testing::Test {
 protected:
  void StartSim(int protocol, const std::vector<uint8_t>& ids, const std::string& model,
                common::Clock* clock = &common::SteadyClock::Instance(),
                std::chrono::milliseconds reboot_time = 30ms) {
    DynamixelSim::Options options;
    options.protocol = protocol;
    options.reboot_time = reboot_time;
    for (uint8_t id : ids) options.servos.push_back({id, DxlControlTable::LoadModel(model)});
    sim_ = std::make_unique<DynamixelSim>(pty_.MasterPort(), options, clock);
    sim_->Start();
    SerialSettings settings;
    settings.device = pty_.slave_path();
    host_ = OpenSerialPort(settings);
  }

  void Send(const Bytes& bytes) {
    ASSERT_FALSE(host_->WriteAll(bytes.data(), bytes.size(), std::chrono::microseconds(1s)));
  }

  // Reads exactly n bytes, or what came before the deadline.
  Bytes Receive(size_t n) {
    Bytes out;
    const auto end = std::chrono::steady_clock::now() + kAnswerDeadline;
    while (out.size() < n) {
      const auto left = std::chrono::duration_cast<std::chrono::microseconds>(
          end - std::chrono::steady_clock::now());
      if (left <= 0us) break;
      uint8_t buffer[256];
      size_t got = 0;
      if (host_->Read(buffer, std::min(sizeof buffer, n - out.size()), left, &got)) break;
      out.insert(out.end(), buffer, buffer + got);
    }
    return out;
  }

  // True when nothing arrives for `window` (after a request that must not be answered).
  bool Quiet(std::chrono::milliseconds window = 100ms) {
    uint8_t b;
    size_t n = 0;
    return host_->Read(&b, 1, window, &n) == Errc::kTimeout;
  }

  // Sends a request and returns an answer of the size `expected` has.
  Bytes Exchange(const Bytes& request, size_t answer_size) {
    Send(request);
    return Receive(answer_size);
  }

  // Returns once the simulator has handled everything sent before: it handles packets in order,
  // so the answer to a ping comes after every earlier (unanswered) instruction took effect.
  void Barrier(int protocol, uint8_t id) {
    const Bytes ping = protocol == 1 ? Dxl1InstructionPacket(id, DxlInstruction::kPing)
                                     : Dxl2InstructionPacket(id, DxlInstruction::kPing);
    ASSERT_EQ(Exchange(ping, protocol == 1 ? 6 : 14).size(), protocol == 1 ? 6u : 14u);
  }

  // Protocol 2.0 helpers.
  Bytes Read2(uint8_t id, uint16_t address, uint16_t length) {
    const Bytes request =
        Dxl2InstructionPacket(id, DxlInstruction::kRead, Cat({Le(address, 2), Le(length, 2)}));
    Send(request);
    const Bytes header = Receive(kDxl2HeaderSize);
    if (header.size() != kDxl2HeaderSize) return header;
    const Bytes rest = Receive(static_cast<size_t>(header[5] | header[6] << 8));
    return Cat({header, rest});
  }
  // The data of a 2.0 read, decoded (empty when the answer is not a clean status packet).
  Bytes ReadData2(uint8_t id, uint16_t address, uint16_t length, uint8_t* error = nullptr) {
    Dxl2Decoder decoder(DxlPacketKind::kStatus);
    Bytes data;
    const Bytes answer = Read2(id, address, length);
    decoder.FeedAll(answer.data(), answer.size(), [&](const DxlPacket& p) {
      data = p.ParamVector();
      if (error != nullptr) *error = p.error;
    });
    return data;
  }
  // Writes and returns the error field of the status packet (or -1 without a clean answer).
  int Write2(uint8_t id, uint16_t address, const Bytes& data) {
    const Bytes answer = Exchange(
        Dxl2InstructionPacket(id, DxlInstruction::kWrite, Cat({Le(address, 2), data})), 11);
    Dxl2Decoder decoder(DxlPacketKind::kStatus);
    int error = -1;
    decoder.FeedAll(answer.data(), answer.size(), [&](const DxlPacket& p) { error = p.error; });
    return error;
  }
  int Write1(uint8_t id, uint8_t address, const Bytes& data) {
    const Bytes answer =
        Exchange(Dxl1InstructionPacket(id, DxlInstruction::kWrite, Cat({{address}, data})), 6);
    Dxl1Decoder decoder(DxlPacketKind::kStatus);
    int error = -1;
    decoder.FeedAll(answer.data(), answer.size(), [&](const DxlPacket& p) { error = p.error; });
    return error;
  }

  PtyPair pty_;
  std::unique_ptr<DynamixelSim> sim_;
  std::unique_ptr<SerialPort> host_;
};

// ------------------------------------------------------------------------------ protocol 2.0

TEST_F(DynamixelSimTest, Protocol2PingIsAnsweredWithModelAndFirmwareByteForByte) {
  StartSim(2, {1}, "xm430-w350");
  // Model number 1020 = 0x03FC, firmware 46 = 0x2E; CRC computed independently.
  EXPECT_THAT(Exchange(Dxl2InstructionPacket(1, DxlInstruction::kPing), 14),
              ElementsAre(0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x07, 0x00, 0x55, 0x00, 0xFC, 0x03, 0x2E,
                          0x1D, 0x43));
  EXPECT_TRUE(Quiet());
  EXPECT_EQ(sim_->statistics().replies, 1u);
}

TEST_F(DynamixelSimTest, Protocol2ReadOfPresentPositionByteForByte) {
  StartSim(2, {1}, "xm430-w350");
  // 4 bytes at 132: 2048, the power-on position of the table.
  EXPECT_THAT(Read2(1, 132, 4), ElementsAre(0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x08, 0x00, 0x55, 0x00,
                                            0x00, 0x08, 0x00, 0x00, 0x1C, 0x38));
}

TEST_F(DynamixelSimTest, Protocol2ReadSpansGapsAndRefusesBeyondTheTable) {
  StartSim(2, {1}, "xm430-w350");
  // 64..70: torque, LED, two unused bytes, status return level 2, registered, hardware error.
  EXPECT_THAT(ReadData2(1, 64, 7), ElementsAre(0, 0, 0, 0, 2, 0, 0));
  uint8_t error = 0;
  EXPECT_TRUE(ReadData2(1, 140, 20, &error).empty());
  EXPECT_EQ(error, static_cast<uint8_t>(Dxl2ErrorCode::kAccessError));
}

TEST_F(DynamixelSimTest, Protocol2WriteErrorsFollowTheControlTable) {
  StartSim(2, {1}, "xm430-w350");
  // Goal position 5000: beyond the register's range 0..4095.
  EXPECT_EQ(Write2(1, 116, Le(5000, 4)), static_cast<int>(Dxl2ErrorCode::kDataRangeError));
  // Only 2 of the 4 bytes of the goal position.
  EXPECT_EQ(Write2(1, 116, Le(100, 2)), static_cast<int>(Dxl2ErrorCode::kDataLengthError));
  // The model number is read-only; address 66 is no register.
  EXPECT_EQ(Write2(1, 0, Le(1, 2)), static_cast<int>(Dxl2ErrorCode::kAccessError));
  EXPECT_EQ(Write2(1, 66, Le(1, 1)), static_cast<int>(Dxl2ErrorCode::kAccessError));
  // Narrow the position limits (EEPROM, torque off), then a goal outside them.
  EXPECT_EQ(Write2(1, 48, Le(3000, 4)), 0);
  EXPECT_EQ(Write2(1, 52, Le(1000, 4)), 0);
  EXPECT_EQ(Write2(1, 116, Le(3500, 4)), static_cast<int>(Dxl2ErrorCode::kDataLimitError));
  // Torque on: EEPROM is locked.
  EXPECT_EQ(Write2(1, 64, {1}), 0);
  EXPECT_EQ(Write2(1, 48, Le(4095, 4)), static_cast<int>(Dxl2ErrorCode::kAccessError));
  EXPECT_EQ(sim_->Register(1, "max_position_limit"), 3000);
  // A refused write changes nothing; an accepted one does.
  EXPECT_EQ(sim_->Register(1, "goal_position"), 2048);
  EXPECT_EQ(Write2(1, 116, Le(2500, 4)), 0);
  EXPECT_EQ(sim_->Register(1, "goal_position"), 2500);
  EXPECT_GE(sim_->statistics().refused, 6u);
}

TEST_F(DynamixelSimTest, Protocol2StatusErrorPacketByteForByte) {
  StartSim(2, {1}, "xm430-w350");
  EXPECT_EQ(Write2(1, 52, Le(2000, 4)), 0);
  const Bytes answer =
      Exchange(Dxl2InstructionPacket(1, DxlInstruction::kWrite, Cat({Le(116, 2), Le(10, 4)})), 11);
  EXPECT_THAT(answer,
              ElementsAre(0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x04, 0x00, 0x55, 0x06, 0xB5, 0x0C));
}

TEST_F(DynamixelSimTest, Protocol2RegWriteWaitsForAction) {
  StartSim(2, {1, 2}, "xm430-w350");
  for (uint8_t id : {1, 2}) {
    const Bytes answer = Exchange(
        Dxl2InstructionPacket(id, DxlInstruction::kRegWrite, Cat({Le(116, 2), Le(3000, 4)})), 11);
    EXPECT_THAT(answer, ElementsAreArray(Dxl2StatusPacket(id, 0)));
  }
  EXPECT_EQ(sim_->Register(1, "goal_position"), 2048);
  EXPECT_EQ(sim_->Register(2, "registered_instruction"), 1);
  // A broadcast action is not answered; both servos execute it.
  Send(Dxl2InstructionPacket(kDxlBroadcastId, DxlInstruction::kAction));
  EXPECT_TRUE(Quiet());
  Barrier(2, 1);
  EXPECT_EQ(sim_->Register(1, "goal_position"), 3000);
  EXPECT_EQ(sim_->Register(2, "goal_position"), 3000);
  EXPECT_EQ(sim_->Register(2, "registered_instruction"), 0);
  // Action without a registered write: instruction error.
  EXPECT_THAT(Exchange(Dxl2InstructionPacket(1, DxlInstruction::kAction), 11),
              ElementsAreArray(
                  Dxl2StatusPacket(1, static_cast<uint8_t>(Dxl2ErrorCode::kInstructionError))));
}

TEST_F(DynamixelSimTest, Protocol2SyncReadAnswersInTheOrderAsked) {
  StartSim(2, {1, 2, 3}, "xm430-w350");
  sim_->SetRegister(2, "present_position", 1000);
  sim_->SetRegister(3, "present_position", 3000);
  Send(Dxl2InstructionPacket(kDxlBroadcastId, DxlInstruction::kSyncRead,
                             {0x84, 0x00, 0x04, 0x00, 3, 2}));
  const Bytes expected =
      Cat({Dxl2StatusPacket(3, 0, Le(3000, 4)), Dxl2StatusPacket(2, 0, Le(1000, 4))});
  EXPECT_THAT(Receive(expected.size()), ElementsAreArray(expected));
  EXPECT_TRUE(Quiet());
}

TEST_F(DynamixelSimTest, Protocol2SyncWriteIsNotAnswered) {
  StartSim(2, {1, 2}, "xm430-w350");
  Send(Dxl2InstructionPacket(kDxlBroadcastId, DxlInstruction::kSyncWrite,
                             Cat({Le(116, 2), Le(4, 2), {1}, Le(150, 4), {2}, Le(170, 4)})));
  EXPECT_TRUE(Quiet());
  Barrier(2, 1);
  EXPECT_EQ(sim_->Register(1, "goal_position"), 150);
  EXPECT_EQ(sim_->Register(2, "goal_position"), 170);
}

TEST_F(DynamixelSimTest, Protocol2BroadcastPingIsAnsweredByEveryServoInIdOrder) {
  StartSim(2, {7, 3}, "xm430-w350");
  Send(Dxl2InstructionPacket(kDxlBroadcastId, DxlInstruction::kPing));
  const Bytes expected =
      Cat({Dxl2StatusPacket(3, 0, {0xFC, 0x03, 0x2E}), Dxl2StatusPacket(7, 0, {0xFC, 0x03, 0x2E})});
  EXPECT_THAT(Receive(expected.size()), ElementsAreArray(expected));
}

TEST_F(DynamixelSimTest, Protocol2UnknownInstructionIsAnInstructionError) {
  StartSim(2, {1}, "xm430-w350");
  EXPECT_THAT(Exchange(Dxl2InstructionPacket(1, DxlInstruction::kClear, {0x01}), 11),
              ElementsAreArray(
                  Dxl2StatusPacket(1, static_cast<uint8_t>(Dxl2ErrorCode::kInstructionError))));
}

TEST_F(DynamixelSimTest, Protocol2RebootAnswersThenResetsRamAndIsSilentMeanwhile) {
  StartSim(2, {1}, "xm430-w350", &common::SteadyClock::Instance(), 2s);
  EXPECT_EQ(Write2(1, 65, {1}), 0);  // LED on
  EXPECT_EQ(Write2(1, 64, {1}), 0);  // torque on
  EXPECT_THAT(Exchange(Dxl2InstructionPacket(1, DxlInstruction::kReboot), 11),
              ElementsAreArray(Dxl2StatusPacket(1, 0)));
  // Within the reboot time a ping goes unanswered.
  Send(Dxl2InstructionPacket(1, DxlInstruction::kPing));
  EXPECT_TRUE(Quiet(100ms));
  std::this_thread::sleep_for(2100ms);
  EXPECT_EQ(Exchange(Dxl2InstructionPacket(1, DxlInstruction::kPing), 14).size(), 14u);
  EXPECT_EQ(sim_->Register(1, "torque_enable"), 0);
  EXPECT_EQ(sim_->Register(1, "led"), 0);
}

TEST_F(DynamixelSimTest, Protocol2CorruptedRepliesFailTheirCrcThenRecover) {
  StartSim(2, {1}, "xm430-w350");
  sim_->CorruptNextReplies(1);
  const Bytes bad = Exchange(Dxl2InstructionPacket(1, DxlInstruction::kPing), 14);
  ASSERT_EQ(bad.size(), 14u);
  EXPECT_NE(Dxl2Crc16(bad.data(), 12), static_cast<uint16_t>(bad[12] | bad[13] << 8));
  const Bytes good = Exchange(Dxl2InstructionPacket(1, DxlInstruction::kPing), 14);
  EXPECT_THAT(good, ElementsAreArray(Dxl2StatusPacket(1, 0, {0xFC, 0x03, 0x2E})));
  EXPECT_EQ(sim_->statistics().corrupted_replies, 1u);
}

TEST_F(DynamixelSimTest, Protocol2NoReplyServoIsSilentWhileTheOtherAnswers) {
  StartSim(2, {1, 2}, "xm430-w350");
  sim_->SetNoReply(2, true);
  Send(Dxl2InstructionPacket(2, DxlInstruction::kPing));
  EXPECT_TRUE(Quiet());
  EXPECT_EQ(Exchange(Dxl2InstructionPacket(1, DxlInstruction::kPing), 14).size(), 14u);
  sim_->SetNoReply(2, false);
  EXPECT_EQ(Exchange(Dxl2InstructionPacket(2, DxlInstruction::kPing), 14).size(), 14u);
}

TEST_F(DynamixelSimTest, Protocol2OverloadNeedsARebootAndCarriesTheAlert) {
  StartSim(2, {1, 2}, "xm430-w350");
  EXPECT_EQ(Write2(2, 64, {1}), 0);
  sim_->InjectOverload(2);
  EXPECT_EQ(sim_->Register(2, "torque_enable"), 0);
  // Every answer carries the alert bit; the hardware error status says overload.
  EXPECT_THAT(Exchange(Dxl2InstructionPacket(2, DxlInstruction::kWrite, {65, 0, 1}), 11),
              ElementsAre(0xFF, 0xFF, 0xFD, 0x00, 0x02, 0x04, 0x00, 0x55, 0x80, 0x2A, 0x8F));
  uint8_t error = 0;
  EXPECT_THAT(ReadData2(2, 70, 1, &error), ElementsAre(kDxl2HwOverload));
  EXPECT_EQ(error, kDxl2AlertBit);
  // Torque cannot come back on.
  EXPECT_EQ(Write2(2, 64, {1}), kDxl2AlertBit | static_cast<int>(Dxl2ErrorCode::kResultFail));
  EXPECT_EQ(sim_->Register(2, "torque_enable"), 0);
  // The other servo is not affected.
  EXPECT_EQ(Write2(1, 65, {1}), 0);
  // Reboot clears it.
  EXPECT_EQ(Exchange(Dxl2InstructionPacket(2, DxlInstruction::kReboot), 11).size(), 11u);
  std::this_thread::sleep_for(50ms);
  EXPECT_FALSE(sim_->Overloaded(2));
  EXPECT_EQ(Write2(2, 64, {1}), 0);
  EXPECT_EQ(sim_->Register(2, "hardware_error_status"), 0);
}

TEST_F(DynamixelSimTest, InstructionWithABadCrcIsDroppedAndCounted) {
  StartSim(2, {1}, "xm430-w350");
  Bytes bad = Dxl2InstructionPacket(1, DxlInstruction::kPing);
  bad.back() ^= 0xFF;
  Send(bad);
  EXPECT_TRUE(Quiet());
  Barrier(2, 1);
  EXPECT_EQ(sim_->statistics().checksum_errors, 1u);
  EXPECT_EQ(sim_->statistics().instructions, 1u);  // the barrier's ping only
}

TEST_F(DynamixelSimTest, MotionMovesAtTheProfileVelocityOnTheSimulatedClock) {
  common::SimulatedClock clock;
  StartSim(2, {1}, "xm430-w350", &clock);
  EXPECT_EQ(Write2(1, 112, Le(100, 4)), 0);  // 100 x 0.229 rev/min = 2.398 rad/s
  EXPECT_EQ(Write2(1, 64, {1}), 0);
  EXPECT_EQ(Write2(1, 116, Le(3072, 4)), 0);  // +1024 ticks = +pi/2 rad
  const double speed = 100 * 0.229 * 2 * M_PI / 60;
  const double tick = 2 * M_PI / 4096;
  clock.Advance(std::chrono::milliseconds(250));
  EXPECT_NEAR(sim_->Position(1), 2048 * tick + speed * 0.25, 1e-9);
  EXPECT_EQ(sim_->Register(1, "moving"), 1);
  EXPECT_EQ(sim_->Register(1, "present_velocity"), 100);
  EXPECT_NEAR(static_cast<double>(sim_->Register(1, "present_position")),
              2048 + speed * 0.25 / tick, 0.5);
  EXPECT_GT(sim_->Register(1, "present_current"), 0);
  // pi/2 at 2.398 rad/s takes 0.655 s: long arrived after 2 s.
  clock.Advance(std::chrono::seconds(2));
  EXPECT_EQ(sim_->Register(1, "present_position"), 3072);
  EXPECT_EQ(sim_->Register(1, "moving"), 0);
  EXPECT_EQ(sim_->Register(1, "present_velocity"), 0);
  // The same through the wire.
  EXPECT_THAT(ReadData2(1, 132, 4), ElementsAreArray(Le(3072, 4)));
}

TEST_F(DynamixelSimTest, MotionStopsOnOverload) {
  common::SimulatedClock clock;
  StartSim(2, {1}, "xm430-w350", &clock);
  EXPECT_EQ(Write2(1, 64, {1}), 0);
  EXPECT_EQ(Write2(1, 116, Le(0, 4)), 0);  // profile velocity 0: the no-load speed
  clock.Advance(std::chrono::milliseconds(100));
  const double at_overload = sim_->Position(1);
  EXPECT_NEAR(at_overload, 2048 * 2 * M_PI / 4096 - 4.817108735504349 * 0.1, 1e-9);
  sim_->InjectOverload(1);
  clock.Advance(std::chrono::seconds(5));
  EXPECT_DOUBLE_EQ(sim_->Position(1), at_overload);
  EXPECT_EQ(sim_->Register(1, "moving"), 0);
}

// ------------------------------------------------------------------------------ protocol 1.0

TEST_F(DynamixelSimTest, Protocol1PingAndReadByteForByte) {
  StartSim(1, {1}, "mx-12w");
  EXPECT_THAT(Exchange(Dxl1InstructionPacket(1, DxlInstruction::kPing), 6),
              ElementsAre(0xFF, 0xFF, 0x01, 0x02, 0x00, 0xFC));
  // Present position (36, 2 bytes): 2048; checksum ~(1 + 4 + 0 + 0x00 + 0x08) = 0xF2.
  EXPECT_THAT(Exchange(Dxl1InstructionPacket(1, DxlInstruction::kRead, {36, 2}), 8),
              ElementsAre(0xFF, 0xFF, 0x01, 0x04, 0x00, 0x00, 0x08, 0xF2));
  // Model number 360 = 0x0168 and firmware.
  EXPECT_THAT(Exchange(Dxl1InstructionPacket(1, DxlInstruction::kRead, {0, 3}), 9),
              ElementsAreArray(Dxl1StatusPacket(1, 0, {0x68, 0x01, 41})));
  // A broadcast ping is not answered in 1.0.
  Send(Dxl1InstructionPacket(kDxlBroadcastId, DxlInstruction::kPing));
  EXPECT_TRUE(Quiet());
}

TEST_F(DynamixelSimTest, Protocol1ErrorBits) {
  StartSim(1, {1}, "mx-12w");
  EXPECT_EQ(Write1(1, 8, Le(3000, 2)), 0);  // CCW angle limit
  EXPECT_EQ(Write1(1, 30, Le(3500, 2)), kDxl1AngleLimitError);
  EXPECT_EQ(Write1(1, 24, {2}), kDxl1RangeError);       // torque enable 0..1
  EXPECT_EQ(Write1(1, 36, Le(5, 2)), kDxl1RangeError);  // read-only
  // Reboot is a 2.0 instruction.
  EXPECT_THAT(Exchange(Dxl1InstructionPacket(1, DxlInstruction::kReboot), 6),
              ElementsAreArray(Dxl1StatusPacket(1, kDxl1InstructionError)));
}

TEST_F(DynamixelSimTest, Protocol1BulkReadAnswersEachServoItsOwnSpan) {
  StartSim(1, {1, 2}, "mx-12w");
  sim_->SetRegister(2, "present_position", 0x0123);
  // The e-manual's example: 2 bytes at 30 of ID 1, 2 bytes at 36 of ID 2.
  Send(Dxl1InstructionPacket(kDxlBroadcastId, DxlInstruction::kBulkRead,
                             {0x00, 0x02, 0x01, 0x1E, 0x02, 0x02, 0x24}));
  const Bytes expected =
      Cat({Dxl1StatusPacket(1, 0, Le(2048, 2)), Dxl1StatusPacket(2, 0, {0x23, 0x01})});
  EXPECT_THAT(Receive(expected.size()), ElementsAreArray(expected));
  EXPECT_TRUE(Quiet());
}

TEST_F(DynamixelSimTest, Protocol1SyncWriteSetsEveryServo) {
  StartSim(1, {1, 2}, "mx-12w");
  Send(Dxl1InstructionPacket(kDxlBroadcastId, DxlInstruction::kSyncWrite,
                             {30, 4, 1, 0x10, 0x00, 0x50, 0x01, 2, 0x20, 0x02, 0x60, 0x03}));
  EXPECT_TRUE(Quiet());
  Barrier(1, 1);
  EXPECT_EQ(sim_->Register(1, "goal_position"), 0x010);
  EXPECT_EQ(sim_->Register(1, "moving_speed"), 0x150);
  EXPECT_EQ(sim_->Register(2, "goal_position"), 0x220);
  EXPECT_EQ(sim_->Register(2, "moving_speed"), 0x360);
}

TEST_F(DynamixelSimTest, Protocol1OverloadIsClearedOnlyByAPowerCycle) {
  StartSim(1, {1}, "mx-12w");
  EXPECT_EQ(Write1(1, 24, {1}), 0);
  sim_->InjectOverload(1);
  // Every status packet carries the overload bit: ~(1 + 2 + 0x20) = 0xDC.
  EXPECT_THAT(Exchange(Dxl1InstructionPacket(1, DxlInstruction::kPing), 6),
              ElementsAre(0xFF, 0xFF, 0x01, 0x02, 0x20, 0xDC));
  // Torque enable is refused: the answer has the overload bit, the register stays 0.
  EXPECT_EQ(Write1(1, 24, {1}), kDxl1OverloadError);
  EXPECT_EQ(sim_->Register(1, "torque_enable"), 0);
  sim_->PowerCycle(1);
  EXPECT_EQ(Write1(1, 24, {1}), 0);
  EXPECT_EQ(sim_->Register(1, "torque_enable"), 1);
}

TEST_F(DynamixelSimTest, Protocol1CorruptedReplyHasAWrongChecksum) {
  StartSim(1, {1}, "mx-12w");
  sim_->CorruptNextReplies(1);
  const Bytes bad = Exchange(Dxl1InstructionPacket(1, DxlInstruction::kPing), 6);
  ASSERT_EQ(bad.size(), 6u);
  EXPECT_NE(Dxl1Checksum(bad.data() + 2, 3), bad[5]);
  EXPECT_THAT(Exchange(Dxl1InstructionPacket(1, DxlInstruction::kPing), 6),
              ElementsAre(0xFF, 0xFF, 0x01, 0x02, 0x00, 0xFC));
}

TEST_F(DynamixelSimTest, Protocol1MotionUsesTheMovingSpeedUnit) {
  common::SimulatedClock clock;
  StartSim(1, {1}, "mx-12w", &clock);
  EXPECT_EQ(Write1(1, 32, Le(10, 2)), 0);  // 10 x 0.916 rev/min = 0.959 rad/s
  EXPECT_EQ(Write1(1, 24, {1}), 0);
  EXPECT_EQ(Write1(1, 30, Le(1024, 2)), 0);  // towards pi/2: CW, negative
  clock.Advance(std::chrono::milliseconds(500));
  const double speed = 10 * 0.916 * 2 * M_PI / 60;
  EXPECT_NEAR(sim_->Position(1), M_PI - speed * 0.5, 1e-9);
  EXPECT_EQ(sim_->Register(1, "present_speed"), -10);  // bit 10 set on the wire
  EXPECT_LT(sim_->Register(1, "present_load"), 0);
  EXPECT_THAT(Exchange(Dxl1InstructionPacket(1, DxlInstruction::kRead, {38, 2}), 8),
              ElementsAreArray(Dxl1StatusPacket(1, 0, Le(1024 + 10, 2))));
}

TEST_F(DynamixelSimTest, MotionStopsAtAnAngleLimitSetAfterTheGoal) {
  common::SimulatedClock clock;
  StartSim(1, {1}, "mx-12w", &clock);
  EXPECT_EQ(Write1(1, 24, {1}), 0);
  EXPECT_EQ(Write1(1, 30, Le(4000, 2)), 0);
  EXPECT_EQ(Write1(1, 8, Le(3000, 2)), 0);  // MX-12W EEPROM is writable with torque on
  clock.Advance(std::chrono::seconds(2));
  EXPECT_EQ(sim_->Register(1, "present_position"), 3000);
  EXPECT_EQ(sim_->Register(1, "moving"), 0);
}

TEST(DynamixelSimConfigTest, RefusesABadChain) {
  PtyPair pty;
  DynamixelSim::Options options;
  options.protocol = 2;
  EXPECT_THROW(DynamixelSim(pty.MasterPort(), options), common::ConfigError);  // no servos
  options.servos.push_back({1, DxlControlTable::LoadModel("mx-12w")});         // a 1.0 table
  EXPECT_THROW(DynamixelSim(pty.MasterPort(), options), common::ConfigError);
  options.servos[0].table = DxlControlTable::LoadModel("xm430-w350");
  options.servos.push_back({1, DxlControlTable::LoadModel("xm430-w350")});
  EXPECT_THROW(DynamixelSim(pty.MasterPort(), options), common::ConfigError);  // id 1 twice
  options.servos[1].id = 253;
  EXPECT_THROW(DynamixelSim(pty.MasterPort(), options), common::ConfigError);  // not a 2.0 id
  options.servos[1].id = 2;
  DynamixelSim sim(pty.MasterPort(), options);
  EXPECT_THROW(sim.Register(3, "led"), common::ConfigError);
  EXPECT_THROW(sim.Register(1, "no_such_register"), common::ConfigError);
}

}  // namespace
}  // namespace kinevis::hal
