#include "hal/mock/rs485_drive_sim.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <array>
#include <chrono>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "hal/common/error.h"
#include "hal/drive/rs485_drive_registers.h"
#include "hal/modbus/modbus_client.h"
#include "hal/modbus/modbus_server.h"
#include "hal/serial/pty_pair.h"
#include "hal/serial/termios_serial_port.h"

namespace kinevis::hal {
namespace {

using namespace std::chrono_literals;
using namespace rs485_drive;
using S = Cia402State;

// Generous: a correct simulator answers in microseconds; a loaded machine may take long.
constexpr char kPatient[] = ",timeout_ms=3000,retries=0";
// For requests that are meant to time out.
constexpr char kImpatient[] = ",timeout_ms=100,retries=0";

template <typename Condition>
bool Eventually(Condition condition, std::chrono::milliseconds deadline = 5s) {
  const auto end = std::chrono::steady_clock::now() + deadline;
  while (!condition()) {
    if (std::chrono::steady_clock::now() > end) return false;
    std::this_thread::sleep_for(1ms);
  }
  return true;
}

Rs485DriveSim::DriveOptions Drive(int unit, uint32_t serial) {
  Rs485DriveSim::DriveOptions d;
  d.unit = unit;
  d.serial_number = serial;
  d.device.limits.max_velocity = 100000;
  d.device.limits.max_acceleration = 1000000;
  return d;
}

// A hal::ModbusClient on the pty slave, the simulator on the master, deterministic stepping on a
// SimulatedClock.
class Rs485DriveSimTest : public ::testing::Test {
 protected:
  void SetUp() override {
    Rs485DriveSim::Options o;
    o.drives = {Drive(1, 11), Drive(2, 22)};
    sim_ = std::make_unique<Rs485DriveSim>(pty_.master_fd(), pty_.slave_path(), &clock_, o);
  }

  std::unique_ptr<ModbusClient> Client(int unit, const char* options = kPatient) {
    return ModbusClient::Open(sim_->backend() + ",unit=" + std::to_string(unit) + options);
  }

  void Advance(common::Duration d) {
    clock_.Advance(d);
    sim_->Step();
  }

  // One cycle: the seven cyclic outputs written, the ten cyclic inputs read, in one 0x17.
  std::error_code Cycle(ModbusClient& client, uint16_t cw, int16_t mode, int32_t position,
                        int32_t velocity, std::array<uint16_t, kCyclicInputCount>* in) {
    uint16_t out[kCyclicOutputCount] = {};
    out[kRegControlword] = cw;
    out[kRegModeOfOperation] = static_cast<uint16_t>(mode);
    SplitHighFirst(static_cast<uint32_t>(position), &out[kRegTargetPosition]);
    SplitHighFirst(static_cast<uint32_t>(velocity), &out[kRegTargetVelocity]);
    return client.WriteAndReadRegisters(kRegControlword, kCyclicOutputCount, out, kRegStatusword,
                                        kCyclicInputCount, in->data());
  }

  static int32_t I32(const uint16_t* regs) {
    return static_cast<int32_t>(JoinHighFirst(regs[0], regs[1]));
  }

  PtyPair pty_;
  common::SimulatedClock clock_;
  std::unique_ptr<Rs485DriveSim> sim_;
};

TEST_F(Rs485DriveSimTest, BackendNamesTheLine) {
  EXPECT_EQ(sim_->backend(), "modbus-rtu:" + pty_.slave_path() + "@3000000,8E1");
}

TEST_F(Rs485DriveSimTest, ReadsTheRegisterMap) {
  auto client = Client(2);
  uint16_t in[kInputBlockSize] = {};
  ASSERT_EQ(client->ReadHoldingRegisters(kInputBlockStart, kInputBlockSize, in), std::error_code())
      << client->last_error_text();
  auto at = [&in](uint16_t reg) { return &in[reg - kInputBlockStart]; };
  EXPECT_EQ(*at(kRegStatusword) & 0x4F, 0x40);  // Switch on disabled
  EXPECT_NE(*at(kRegStatusword) & cia402::kSwRemote, 0);
  EXPECT_EQ(*at(kRegModeDisplay), 8);
  EXPECT_EQ(I32(at(kRegPositionActual)), 0);
  EXPECT_EQ(*at(kRegErrorCode), 0);
  EXPECT_EQ(JoinHighFirst(at(kRegVendorId)[0], at(kRegVendorId)[1]), kSimulatorVendorId);
  EXPECT_EQ(JoinHighFirst(at(kRegProductCode)[0], at(kRegProductCode)[1]), 0x0485u);
  EXPECT_EQ(JoinHighFirst(at(kRegSerialNumber)[0], at(kRegSerialNumber)[1]), 22u);
  EXPECT_EQ(JoinHighFirst(at(kRegSupportedModes)[0], at(kRegSupportedModes)[1]), 0x38Du);

  uint16_t out[kOutputBlockSize] = {};
  ASSERT_EQ(client->ReadHoldingRegisters(0, kOutputBlockSize, out), std::error_code());
  EXPECT_EQ(out[kRegModeOfOperation], 8);
  EXPECT_EQ(JoinHighFirst(out[kRegProfileVelocity], out[kRegProfileVelocity + 1]), 100000u);
  EXPECT_EQ(JoinHighFirst(out[kRegFollowingErrorWindow], out[kRegFollowingErrorWindow + 1]),
            10000u);
  EXPECT_EQ(I32(&out[kRegPositionLimitMin]), -1000000000);
  EXPECT_EQ(I32(&out[kRegPositionLimitMax]), 1000000000);
  EXPECT_EQ(out[kRegQuickStopOptionCode], 2);
  EXPECT_EQ(out[kRegWatchdogMs], 0);
}

TEST_F(Rs485DriveSimTest, WritesReachTheDriveAndReadBack) {
  auto client = Client(1);
  uint16_t limits[4];
  SplitHighFirst(static_cast<uint32_t>(-5000), &limits[0]);
  SplitHighFirst(7000, &limits[2]);
  ASSERT_EQ(client->WriteRegisters(kRegPositionLimitMin, 4, limits), std::error_code());
  ASSERT_EQ(client->WriteRegister(kRegQuickStopOptionCode, 6), std::error_code());
  ASSERT_EQ(client->WriteRegister(kRegModeOfOperation, 9), std::error_code());
  uint16_t profile[4];
  SplitHighFirst(1234, &profile[0]);
  SplitHighFirst(56789, &profile[2]);
  ASSERT_EQ(client->WriteRegisters(kRegProfileVelocity, 4, profile), std::error_code());
  const Cia402Device::Snapshot s = sim_->device(1).snapshot();
  EXPECT_EQ(s.position_limit_min, -5000);
  EXPECT_EQ(s.position_limit_max, 7000);
  EXPECT_EQ(s.quick_stop_option_code, 6);
  EXPECT_EQ(s.mode, 9);
  EXPECT_EQ(s.profile_velocity, 1234u);
  EXPECT_EQ(s.profile_acceleration, 56789u);
  uint16_t back[2];
  ASSERT_EQ(client->ReadHoldingRegisters(kRegPositionLimitMin, 2, back), std::error_code());
  EXPECT_EQ(I32(back), -5000);
  EXPECT_EQ(sim_->device(2).snapshot().mode, 8) << "unit 2 untouched";
}

TEST_F(Rs485DriveSimTest, OneWriteAndReadTransactionPerCycle) {
  auto client = Client(1);
  std::array<uint16_t, kCyclicInputCount> in{};
  const Cia402State expected[] = {S::kReadyToSwitchOn, S::kSwitchedOn, S::kOperationEnabled};
  const uint16_t commands[] = {0x06, 0x07, 0x0F};
  for (int i = 0; i < 3; ++i) {
    ASSERT_EQ(Cycle(*client, commands[i], 9, 0, 20000, &in), std::error_code())
        << client->last_error_text();
    EXPECT_EQ(DecodeCia402Statusword(in[0]), expected[i]);
    Advance(1ms);
  }
  EXPECT_EQ(in[kRegModeDisplay - kInputBlockStart], 9);
  for (int i = 0; i < 40; ++i) {
    ASSERT_EQ(Cycle(*client, 0x0F, 9, 0, 20000, &in), std::error_code());
    Advance(1ms);
  }
  ASSERT_EQ(Cycle(*client, 0x0F, 9, 0, 20000, &in), std::error_code());
  EXPECT_EQ(I32(&in[kRegVelocityActual - kInputBlockStart]), 20000);
  // 41 steps of 1 ms: 20 accelerating by 1000 counts/s each (210 counts), 21 at 20000 counts/s.
  EXPECT_NEAR(I32(&in[kRegPositionActual - kInputBlockStart]), 210 + 420, 2);
  EXPECT_EQ(in[kRegErrorCode - kInputBlockStart], 0);
  EXPECT_EQ(client->counters().failures, 0u);
}

TEST_F(Rs485DriveSimTest, ReadOnlyBlockAndHolesAreIllegalAddresses) {
  auto client = Client(1);
  EXPECT_EQ(client->WriteRegister(kRegStatusword, 0), ModbusErrc::kIllegalDataAddress);
  const uint16_t two[2] = {0, 0};
  EXPECT_EQ(client->WriteRegisters(kRegWatchdogMs, 2, two), ModbusErrc::kIllegalDataAddress);
  uint16_t regs[32];
  EXPECT_EQ(client->ReadHoldingRegisters(kOutputBlockSize, 1, regs),
            ModbusErrc::kIllegalDataAddress);
  EXPECT_EQ(client->ReadHoldingRegisters(kInputBlockStart, kInputBlockSize + 1, regs),
            ModbusErrc::kIllegalDataAddress);
  EXPECT_EQ(client->ReadHoldingRegisters(0x00F0, 0x20, regs), ModbusErrc::kIllegalDataAddress);
  EXPECT_EQ(client->WriteAndReadRegisters(kRegStatusword, 1, two, kRegStatusword, 1, regs),
            ModbusErrc::kIllegalDataAddress);
  EXPECT_EQ(client->WriteAndReadRegisters(0, 1, two, 0x0200, 1, regs),
            ModbusErrc::kIllegalDataAddress);
  EXPECT_EQ(client->counters().exceptions, 7u);
  EXPECT_EQ(sim_->statistics().exceptions, 7u);
}

TEST_F(Rs485DriveSimTest, OutOfRangeValuesAreIllegalAndNotApplied) {
  auto client = Client(1);
  EXPECT_EQ(client->WriteRegister(kRegModeOfOperation, 6), ModbusErrc::kIllegalDataValue);
  EXPECT_EQ(client->WriteRegister(kRegModeOfOperation, 0), ModbusErrc::kIllegalDataValue);
  EXPECT_EQ(client->WriteRegister(kRegQuickStopOptionCode, 9), ModbusErrc::kIllegalDataValue);
  uint16_t limits[4];
  SplitHighFirst(100, &limits[0]);
  SplitHighFirst(static_cast<uint32_t>(-100), &limits[2]);
  EXPECT_EQ(client->WriteRegisters(kRegPositionLimitMin, 4, limits), ModbusErrc::kIllegalDataValue);
  // The whole request is refused: the controlword written with a bad mode is not applied.
  const uint16_t cw_and_mode[2] = {0x06, 42};
  EXPECT_EQ(client->WriteRegisters(kRegControlword, 2, cw_and_mode), ModbusErrc::kIllegalDataValue);
  EXPECT_EQ(sim_->device(1).state(), S::kSwitchOnDisabled);
  uint16_t back[2];
  ASSERT_EQ(client->ReadHoldingRegisters(kRegControlword, 2, back), std::error_code());
  EXPECT_EQ(back[0], 0);
  EXPECT_EQ(back[1], 8);
  // A mode the drive does not list in its supported modes.
  Rs485DriveSim::Options o;
  o.drives = {Drive(1, 1)};
  o.drives[0].device.supported_modes = 0x80;  // CSP only
  sim_.reset();
  client.reset();
  PtyPair other;
  Rs485DriveSim csp_only(other.master_fd(), other.slave_path(), &clock_, o);
  auto c = ModbusClient::Open(csp_only.backend() + kPatient);
  EXPECT_EQ(c->WriteRegister(kRegModeOfOperation, 9), ModbusErrc::kIllegalDataValue);
  EXPECT_EQ(c->WriteRegister(kRegModeOfOperation, 8), std::error_code());
}

TEST_F(Rs485DriveSimTest, OtherFunctionCodesAreIllegal) {
  auto client = Client(1);
  uint16_t regs[2];
  EXPECT_EQ(client->ReadInputRegisters(0, 1, regs), ModbusErrc::kIllegalFunction);
  EXPECT_EQ(client->MaskWriteRegister(0, 0xFF, 0), ModbusErrc::kIllegalFunction);
  uint8_t bits[2];
  EXPECT_EQ(client->ReadCoils(0, 1, bits), ModbusErrc::kIllegalFunction);
  EXPECT_EQ(client->ReadHoldingRegisters(0, 1, regs), std::error_code()) << "still in step";
}

// The host side opens the line once at a time (a second ModbusClient on the same tty is
// refused), so the units are addressed one after the other, as a host polls a multi-drop line.
TEST_F(Rs485DriveSimTest, TwoDrivesOnOneLine) {
  uint16_t serial[2];
  {
    auto one = Client(1);
    ASSERT_EQ(one->ReadHoldingRegisters(kRegSerialNumber, 2, serial), std::error_code());
    EXPECT_EQ(JoinHighFirst(serial[0], serial[1]), 11u);
  }
  {
    auto two = Client(2);
    ASSERT_EQ(two->ReadHoldingRegisters(kRegSerialNumber, 2, serial), std::error_code());
    EXPECT_EQ(JoinHighFirst(serial[0], serial[1]), 22u);
    ASSERT_EQ(two->WriteRegister(kRegControlword, 0x06), std::error_code());
  }
  EXPECT_EQ(sim_->device(2).state(), S::kReadyToSwitchOn);
  EXPECT_EQ(sim_->device(1).state(), S::kSwitchOnDisabled);
  {
    // A broadcast write reaches both drives and is not answered.
    auto all = Client(0);
    ASSERT_EQ(all->WriteRegister(kRegQuickStopOptionCode, 5), std::error_code());
  }
  EXPECT_TRUE(Eventually([&] {
    return sim_->device(1).snapshot().quick_stop_option_code == 5 &&
           sim_->device(2).snapshot().quick_stop_option_code == 5;
  }));
  {
    // No drive 3 on the line: nobody answers.
    auto three = Client(3, kImpatient);
    uint16_t reg = 0;
    EXPECT_EQ(three->ReadHoldingRegisters(0, 1, &reg), Errc::kTimeout);
  }
  EXPECT_TRUE(Eventually([&] { return sim_->statistics().ignored == 1; }));
  auto one = Client(1);
  uint16_t qs = 0;
  ASSERT_EQ(one->ReadHoldingRegisters(kRegQuickStopOptionCode, 1, &qs), std::error_code());
  EXPECT_EQ(qs, 5);
}

TEST_F(Rs485DriveSimTest, WatchdogFaultsADriveThatHearsNothing) {
  auto client = Client(1);
  ASSERT_EQ(client->WriteRegister(kRegWatchdogMs, 100), std::error_code());
  for (uint16_t cw : {0x06, 0x07, 0x0F}) {
    ASSERT_EQ(client->WriteRegister(kRegControlword, cw), std::error_code());
  }
  Advance(60ms);
  uint16_t status = 0;
  ASSERT_EQ(client->ReadHoldingRegisters(kRegStatusword, 1, &status), std::error_code());
  Advance(100ms);  // exactly the watchdog time since the last request: still fine
  EXPECT_EQ(sim_->device(1).state(), S::kOperationEnabled);
  Advance(1ms);
  EXPECT_EQ(sim_->device(1).state(), S::kFaultReactionActive);
  Advance(20ms);
  EXPECT_EQ(sim_->device(1).state(), S::kFault);
  uint16_t code = 0;
  ASSERT_EQ(client->ReadHoldingRegisters(kRegErrorCode, 1, &code), std::error_code());
  EXPECT_EQ(code, 0x8130);
  EXPECT_EQ(sim_->statistics().watchdog_trips, 1u);
  EXPECT_EQ(sim_->device(2).state(), S::kSwitchOnDisabled) << "unit 2 has no watchdog set";
  // Fault reset (rising edge of bit 7) and the drive is usable again.
  ASSERT_EQ(client->WriteRegister(kRegControlword, 0x80), std::error_code());
  EXPECT_EQ(sim_->device(1).state(), S::kSwitchOnDisabled);
}

TEST_F(Rs485DriveSimTest, StopAnsweringMakesTheClientTimeOut) {
  sim_->StopAnswering(1, true);
  uint16_t reg = 0;
  {
    auto one = Client(1, kImpatient);
    EXPECT_EQ(one->ReadHoldingRegisters(kRegStatusword, 1, &reg), Errc::kTimeout);
    EXPECT_EQ(one->counters().timeouts, 1u);
    EXPECT_EQ(one->WriteRegister(kRegControlword, 0x06), Errc::kTimeout);
  }
  EXPECT_EQ(sim_->device(1).state(), S::kSwitchOnDisabled) << "a silent drive executes nothing";
  {
    auto two = Client(2);
    EXPECT_EQ(two->ReadHoldingRegisters(kRegStatusword, 1, &reg), std::error_code());
  }
  sim_->StopAnswering(1, false);
  auto one = Client(1);
  EXPECT_EQ(one->ReadHoldingRegisters(kRegStatusword, 1, &reg), std::error_code());
}

TEST_F(Rs485DriveSimTest, CorruptRepliesAreCrcErrorsForTheClient) {
  auto client = Client(2);
  sim_->CorruptNextReplies(2, 1);
  uint16_t reg = 0;
  EXPECT_EQ(client->ReadHoldingRegisters(kRegStatusword, 1, &reg), ModbusErrc::kBadCrc);
  EXPECT_EQ(client->counters().crc_errors, 1u);
  EXPECT_EQ(client->ReadHoldingRegisters(kRegStatusword, 1, &reg), std::error_code());
  EXPECT_EQ(reg & 0x4F, 0x40);
}

TEST_F(Rs485DriveSimTest, RaisedFaultShowsInTheInputs) {
  auto client = Client(2);
  sim_->RaiseFault(2, 0x4310);
  Advance(20ms);
  uint16_t in[8];
  ASSERT_EQ(client->ReadHoldingRegisters(kRegStatusword, 8, in), std::error_code());
  EXPECT_EQ(DecodeCia402Statusword(in[0]), S::kFault);
  EXPECT_EQ(in[kRegErrorCode - kInputBlockStart], 0x4310);
}

TEST_F(Rs485DriveSimTest, RawFramesQuantityErrorsNoiseAndTruncation) {
  sim_.reset();
  Rs485DriveSim::Options o;
  o.drives = {Drive(4, 4)};
  Rs485DriveSim sim(pty_.master_fd(), pty_.slave_path(), &clock_, o);
  SerialSettings settings;
  settings.device = pty_.slave_path();
  auto line = OpenSerialPort(settings);
  auto with_crc = [](std::vector<uint8_t> frame) {
    const uint16_t crc = ModbusRtuCrc(frame.data(), frame.size());
    frame.push_back(static_cast<uint8_t>(crc));
    frame.push_back(static_cast<uint8_t>(crc >> 8));
    return frame;
  };
  auto exchange = [&](const std::vector<uint8_t>& bytes, size_t answer_size) {
    EXPECT_FALSE(line->WriteAll(bytes.data(), bytes.size(), std::chrono::microseconds(1s)));
    std::vector<uint8_t> out;
    const auto end = std::chrono::steady_clock::now() + 5s;
    while (out.size() < answer_size && std::chrono::steady_clock::now() < end) {
      uint8_t buffer[64];
      size_t n = 0;
      if (!line->Read(buffer, std::min(sizeof buffer, answer_size - out.size()), 100ms, &n)) {
        out.insert(out.end(), buffer, buffer + n);
      }
    }
    return out;
  };
  // Quantity 0 and 126: ILLEGAL DATA VALUE.
  EXPECT_EQ(exchange(with_crc({4, 0x03, 0x00, 0x00, 0x00, 0x00}), 5), with_crc({4, 0x83, 3}));
  EXPECT_EQ(exchange(with_crc({4, 0x03, 0x00, 0x00, 0x00, 126}), 5), with_crc({4, 0x83, 3}));
  // 0x10 whose byte count does not match the quantity.
  EXPECT_EQ(exchange(with_crc({4, 0x10, 0x00, 0x00, 0x00, 0x02, 0x02, 0x00, 0x06}), 5),
            with_crc({4, 0x90, 3}));
  // Noise in front of a good request: skipped, counted, the request is served.
  std::vector<uint8_t> noisy = {0x04, 0x03, 0x00, 0x00, 0x00, 0x01, 0xFF, 0xFF, 0x37};
  const std::vector<uint8_t> good = with_crc({4, 0x03, 0x00, 0x01, 0x00, 0x01});
  noisy.insert(noisy.end(), good.begin(), good.end());
  EXPECT_EQ(exchange(noisy, 7), with_crc({4, 0x03, 0x02, 0x00, 0x08}));
  EXPECT_GE(sim.statistics().framing_errors, 1u);
  // A truncated request is dropped at the silence; the line works on.
  const uint64_t errors = sim.statistics().framing_errors;
  EXPECT_TRUE(exchange({0x04, 0x03, 0x00}, 0).empty());
  EXPECT_TRUE(Eventually([&] { return sim.statistics().framing_errors > errors; }));
  EXPECT_EQ(exchange(good, 7), with_crc({4, 0x03, 0x02, 0x00, 0x08}));
  // Unknown function code, delimited by silence: ILLEGAL FUNCTION.
  EXPECT_EQ(exchange(with_crc({4, 0x2B, 0x0E, 0x01, 0x00}), 5), with_crc({4, 0xAB, 1}));
}

TEST(Rs485DriveSimThreadTest, StartStepsTheDrivesInRealTime) {
  PtyPair pty;
  Rs485DriveSim::Options o;
  o.drives = {Drive(7, 7)};
  Rs485DriveSim sim(pty.master_fd(), pty.slave_path(), &common::SteadyClock::Instance(), o);
  sim.Start();
  sim.Start();  // does nothing when running
  auto client = ModbusClient::Open(sim.backend() + ",unit=7" + kPatient);
  ASSERT_EQ(client->WriteRegister(kRegModeOfOperation, 9), std::error_code());
  uint16_t velocity[2];
  SplitHighFirst(5000, velocity);
  ASSERT_EQ(client->WriteRegisters(kRegTargetVelocity, 2, velocity), std::error_code());
  for (uint16_t cw : {0x06, 0x07, 0x0F}) {
    ASSERT_EQ(client->WriteRegister(kRegControlword, cw), std::error_code());
  }
  EXPECT_TRUE(Eventually([&] {
    uint16_t v[2] = {};
    return !client->ReadHoldingRegisters(kRegVelocityActual, 2, v) &&
           static_cast<int32_t>(JoinHighFirst(v[0], v[1])) == 5000;
  }));
  sim.Stop();
  sim.Stop();
}

TEST(Rs485DriveSimConfigTest, BadOptionsThrowNamingEachProblem) {
  PtyPair pty;
  common::SimulatedClock clock;
  Rs485DriveSim::Options o;
  o.drives = {Drive(0, 1), Drive(5, 1), Drive(5, 2), Drive(300, 3)};
  try {
    Rs485DriveSim sim(pty.master_fd(), pty.slave_path(), &clock, o);
    FAIL() << "no exception";
  } catch (const common::ConfigError& e) {
    EXPECT_THAT(std::string(e.what()), ::testing::ContainsRegex("unit 0 is outside 1\\.\\.247"));
    EXPECT_THAT(std::string(e.what()), ::testing::ContainsRegex("unit 5 appears twice"));
    EXPECT_THAT(std::string(e.what()), ::testing::ContainsRegex("unit 300 is outside"));
  }
  o.drives = {Drive(1, 1)};
  Rs485DriveSim sim(pty.master_fd(), pty.slave_path(), &clock, o);
  EXPECT_THROW(sim.device(2), common::ConfigError);
  EXPECT_THROW(sim.StopAnswering(9, true), common::ConfigError);
}

}  // namespace
}  // namespace kinevis::hal
