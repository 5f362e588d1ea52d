#include "hal/modbus/modbus_client.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <memory>
#include <mutex>
#include <new>
#include <string>
#include <thread>
#include <vector>

#include "hal/common/error.h"
#include "hal/modbus/modbus_server.h"
#include "hal/serial/pty_pair.h"
#include "tests/utilities/allocation_counter.h"

namespace kinevis::hal {
namespace {

using ::testing::ContainsRegex;
using ::testing::ElementsAre;
using ::testing::ElementsAreArray;
using ::testing::HasSubstr;
using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;

// Round trips that must succeed get a timeout far above any plausible scheduling delay.
constexpr char kPatient[] = ",timeout_ms=5000,retries=0";

// Waits until pred() holds or 20 s have passed; returns pred(). For counters the server thread
// updates on its own schedule.
template <typename Pred>
bool Eventually(Pred pred) {
  const auto deadline = Clock::now() + std::chrono::seconds(20);
  while (!pred() && Clock::now() < deadline) std::this_thread::sleep_for(milliseconds(2));
  return pred();
}

enum class Transport { kTcp, kRtu };

std::string TransportName(const ::testing::TestParamInfo<Transport>& info) {
  return info.param == Transport::kTcp ? "Tcp" : "Rtu";
}

ModbusServer::Options MapOptions() {
  ModbusServer::Options o;
  o.coils = 2000;
  o.discrete_inputs = 100;
  o.holding_registers = 300;
  o.input_registers = 50;
  return o;
}

// A ModbusServer on loopback TCP (ephemeral port) or on a real pty, and clients opened the way a
// host opens them: from a backend string.
class ModbusClientTest : public ::testing::TestWithParam<Transport> {
 protected:
  void SetUp() override {
    if (GetParam() == Transport::kTcp) {
      server_ = ModbusServer::ListenTcp("127.0.0.1", 0, MapOptions());
    } else {
      pty_ = std::make_unique<PtyPair>();
      server_ = ModbusServer::ServeRtu(pty_->master_fd(), pty_->slave_path(), MapOptions());
    }
  }

  // "modbus-tcp:127.0.0.1:PORT" or "modbus-rtu:/dev/pts/N@115200,8E1", then `unit_and_more`.
  std::string Backend(const std::string& unit_and_more) const {
    if (GetParam() == Transport::kTcp) {
      return "modbus-tcp:127.0.0.1:" + std::to_string(server_->port()) + unit_and_more;
    }
    return "modbus-rtu:" + pty_->slave_path() + "@115200,8E1" + unit_and_more;
  }

  std::unique_ptr<ModbusClient> Open(const std::string& options = kPatient,
                                     const std::string& unit = ",unit=1") {
    return ModbusClient::Open(Backend(unit + options));
  }

  std::unique_ptr<PtyPair> pty_;
  std::unique_ptr<ModbusServer> server_;
};

INSTANTIATE_TEST_SUITE_P(Transports, ModbusClientTest,
                         ::testing::Values(Transport::kTcp, Transport::kRtu), TransportName);

TEST_P(ModbusClientTest, WriteRegistersThenReadHoldingRegistersRoundTrip) {
  auto client = Open();
  const std::vector<uint16_t> values = {1, 2, 0x1234, 0x8000, 0xFFFF};
  ASSERT_EQ(client->WriteRegisters(10, 5, values.data()), std::error_code());
  std::vector<uint16_t> read(5);
  ASSERT_EQ(client->ReadHoldingRegisters(10, 5, read.data()), std::error_code());
  EXPECT_EQ(read, values);
  auto in_map = server_->WithRegisters([](ModbusRegisterMap& m) {
    return std::vector<uint16_t>(m.holding_registers.begin() + 10,
                                 m.holding_registers.begin() + 15);
  });
  EXPECT_EQ(in_map, values);
  EXPECT_EQ(client->counters().requests, 2U);
  EXPECT_EQ(client->counters().failures, 0U);
}

TEST_P(ModbusClientTest, WriteRegisterRoundTrip) {
  auto client = Open();
  ASSERT_EQ(client->WriteRegister(299, 0xBEEF), std::error_code());
  uint16_t read = 0;
  ASSERT_EQ(client->ReadHoldingRegisters(299, 1, &read), std::error_code());
  EXPECT_EQ(read, 0xBEEF);
}

TEST_P(ModbusClientTest, ReadInputRegistersSeesTheSimulatorsValues) {
  server_->WithRegisters([](ModbusRegisterMap& m) {
    for (size_t i = 0; i < m.input_registers.size(); ++i) {
      m.input_registers[i] = static_cast<uint16_t>(1000 + i);
    }
  });
  auto client = Open();
  std::array<uint16_t, 4> read{};
  ASSERT_EQ(client->ReadInputRegisters(46, 4, read.data()), std::error_code());
  EXPECT_THAT(read, ElementsAre(1046, 1047, 1048, 1049));
}

TEST_P(ModbusClientTest, WriteCoilsAndWriteCoilThenReadCoilsRoundTrip) {
  auto client = Open();
  const std::vector<uint8_t> pattern = {1, 0, 1, 1, 0, 0, 0, 1, 1, 0, 1};  // crosses a byte
  ASSERT_EQ(client->WriteCoils(3, static_cast<int>(pattern.size()), pattern.data()),
            std::error_code());
  ASSERT_EQ(client->WriteCoil(0, true), std::error_code());
  ASSERT_EQ(client->WriteCoil(3, false), std::error_code());
  std::vector<uint8_t> read(14, 0xAA);
  ASSERT_EQ(client->ReadCoils(0, 14, read.data()), std::error_code());
  EXPECT_THAT(read, ElementsAre(1, 0, 0, /*3 cleared*/ 0, 0, 1, 1, 0, 0, 0, 1, 1, 0, 1));
}

TEST_P(ModbusClientTest, WriteCoilsTreatsAnyNonZeroByteAsOn) {
  auto client = Open();
  const std::array<uint8_t, 3> values = {0x80, 0, 0x01};
  ASSERT_EQ(client->WriteCoils(20, 3, values.data()), std::error_code());
  auto coils = server_->WithRegisters([](ModbusRegisterMap& m) {
    return std::vector<uint8_t>(m.coils.begin() + 20, m.coils.begin() + 23);
  });
  EXPECT_THAT(coils, ElementsAre(1, 0, 1));
}

TEST_P(ModbusClientTest, ReadDiscreteInputsSeesTheSimulatorsValues) {
  server_->WithRegisters([](ModbusRegisterMap& m) {
    m.discrete_inputs[97] = 1;
    m.discrete_inputs[99] = 1;
  });
  auto client = Open();
  std::array<uint8_t, 4> read{};
  ASSERT_EQ(client->ReadDiscreteInputs(96, 4, read.data()), std::error_code());
  EXPECT_THAT(read, ElementsAre(0, 1, 0, 1));
}

TEST_P(ModbusClientTest, WriteAndReadRegistersWritesBeforeReading) {
  auto client = Open();
  server_->WithRegisters([](ModbusRegisterMap& m) {
    m.holding_registers[18] = 18;
    m.holding_registers[19] = 19;
  });
  const std::array<uint16_t, 3> written = {200, 201, 202};
  std::array<uint16_t, 5> read{};
  ASSERT_EQ(client->WriteAndReadRegisters(20, 3, written.data(), 18, 5, read.data()),
            std::error_code());
  EXPECT_THAT(read, ElementsAre(18, 19, 200, 201, 202));
}

TEST_P(ModbusClientTest, MaskWriteRegisterFollowsTheSpecificationsExample) {
  // Modbus Application Protocol V1.1b3, 6.16: current 0x12, AND 0xF2, OR 0x25 -> 0x17.
  server_->WithRegisters([](ModbusRegisterMap& m) { m.holding_registers[4] = 0x12; });
  auto client = Open();
  ASSERT_EQ(client->MaskWriteRegister(4, 0x00F2, 0x0025), std::error_code());
  EXPECT_EQ(server_->WithRegisters([](ModbusRegisterMap& m) { return m.holding_registers[4]; }),
            0x17);
}

TEST_P(ModbusClientTest, LargestRequestsTheProtocolAllows) {
  auto client = Open();
  std::vector<uint16_t> values(ModbusClient::kMaxWriteRegisters);
  for (size_t i = 0; i < values.size(); ++i) values[i] = static_cast<uint16_t>(i * 7 + 1);
  ASSERT_EQ(client->WriteRegisters(0, ModbusClient::kMaxWriteRegisters, values.data()),
            std::error_code());
  std::vector<uint16_t> read(ModbusClient::kMaxReadRegisters);
  ASSERT_EQ(client->ReadHoldingRegisters(0, ModbusClient::kMaxReadRegisters, read.data()),
            std::error_code());
  EXPECT_TRUE(std::equal(values.begin(), values.end(), read.begin()));

  std::vector<uint8_t> bits(ModbusClient::kMaxWriteBits);
  for (size_t i = 0; i < bits.size(); ++i) bits[i] = (i % 3 == 0) ? 1 : 0;
  ASSERT_EQ(client->WriteCoils(0, ModbusClient::kMaxWriteBits, bits.data()), std::error_code());
  std::vector<uint8_t> read_bits(ModbusClient::kMaxReadBits);
  ASSERT_EQ(client->ReadCoils(0, ModbusClient::kMaxReadBits, read_bits.data()), std::error_code());
  EXPECT_TRUE(std::equal(bits.begin(), bits.end(), read_bits.begin()));
}

TEST_P(ModbusClientTest, WriteOutsideTheMapIsIllegalDataAddressByName) {
  auto client = Open(",timeout_ms=5000,retries=3");
  std::error_code ec = client->WriteRegister(300, 1);  // the map has registers 0..299
  EXPECT_TRUE(IsModbusException(ec));
  EXPECT_EQ(ec, ModbusErrc::kIllegalDataAddress);
  EXPECT_THAT(ec.message(), ContainsRegex("^ILLEGAL DATA ADDRESS"));
  EXPECT_EQ(client->last_error(), ec);
  EXPECT_THAT(client->last_error_text(),
              ContainsRegex("unit 1: write register at 0x012c, count 1: ILLEGAL DATA ADDRESS.* "
                            "after 1 attempt$"));
  EXPECT_THAT(client->last_error_text(), HasSubstr(client->name()));
  const ModbusClientCounters c = client->counters();
  EXPECT_EQ(c.exceptions, 1U);
  EXPECT_EQ(c.retries, 0U) << "a Modbus exception must never be retried";
  EXPECT_EQ(c.failures, 1U);
  // Reads across the end of the map too, and the link stays usable afterwards.
  std::array<uint16_t, 2> read{};
  EXPECT_EQ(client->ReadHoldingRegisters(299, 2, read.data()), ModbusErrc::kIllegalDataAddress);
  EXPECT_EQ(client->ReadHoldingRegisters(298, 2, read.data()), std::error_code());
}

TEST_P(ModbusClientTest, RequestHookRefusingAValueGivesIllegalDataValue) {
  server_->SetRequestHook([](const ModbusRequest& r, const ModbusRegisterMap&) {
    if (r.is_write() && r.address <= 7 && r.address + r.count > 7 &&
        r.values[7 - r.address] > 1000) {
      return ModbusErrc::kIllegalDataValue;
    }
    return ModbusErrc::kNone;
  });
  auto client = Open();
  std::error_code ec = client->WriteRegister(7, 1001);
  EXPECT_EQ(ec, ModbusErrc::kIllegalDataValue);
  EXPECT_THAT(ec.message(), ContainsRegex("^ILLEGAL DATA VALUE"));
  const std::array<uint16_t, 3> block = {5, 5000, 5};
  EXPECT_EQ(client->WriteRegisters(6, 3, block.data()), ModbusErrc::kIllegalDataValue);
  EXPECT_EQ(server_->WithRegisters([](ModbusRegisterMap& m) { return m.holding_registers[7]; }), 0)
      << "a refused write must leave the map unchanged";
  EXPECT_EQ(client->WriteRegister(7, 1000), std::error_code());
  EXPECT_EQ(client->counters().exceptions, 2U);
}

TEST_P(ModbusClientTest, TimeoutWhenTheServerStopsAnsweringIsBoundedAndRetried) {
  auto client = Open(",timeout_ms=150,retries=2");
  uint16_t value = 0;
  ASSERT_EQ(client->ReadHoldingRegisters(0, 1, &value), std::error_code());
  server_->StopAnswering(milliseconds::max());
  const auto start = Clock::now();
  std::error_code ec = client->ReadHoldingRegisters(0, 1, &value);
  const auto elapsed = Clock::now() - start;
  EXPECT_EQ(ec, Errc::kTimeout);
  const ModbusClientCounters c = client->counters();
  EXPECT_EQ(c.timeouts, 3U);
  EXPECT_EQ(c.retries, 2U);
  EXPECT_EQ(c.exceptions, 0U);
  // Three attempts of 150 ms each cannot end sooner; the upper bound only proves it never hangs.
  EXPECT_GE(elapsed, milliseconds(3 * 150 - 20));
  EXPECT_LT(elapsed, milliseconds(3 * 2 * 150 + 10'000));
  EXPECT_THAT(client->last_error_text(), ContainsRegex("timed out after 3 attempts$"));
  EXPECT_TRUE(Eventually([&] { return server_->stats().swallowed >= 3; }));

  // The same client recovers once the server answers again (on a loaded machine a 150 ms
  // timeout may still expire now and then: what must not happen is that it never recovers).
  server_->ResumeAnswering();
  server_->WithRegisters([](ModbusRegisterMap& m) { m.holding_registers[0] = 42; });
  const auto deadline = Clock::now() + std::chrono::seconds(20);
  do {
    ec = client->ReadHoldingRegisters(0, 1, &value);
  } while (ec == Errc::kTimeout && Clock::now() < deadline);
  EXPECT_EQ(ec, std::error_code()) << client->last_error_text();
  EXPECT_EQ(value, 42);
}

TEST_P(ModbusClientTest, OperationsDoNotAllocate) {
  auto client = Open();
  std::array<uint16_t, 8> regs = {1, 2, 3, 4, 5, 6, 7, 8};
  std::array<uint8_t, 8> bits = {1, 0, 1, 0, 1, 0, 1, 0};
  auto all_operations = [&] {
    int failures = 0;
    failures += !!client->WriteRegisters(0, 8, regs.data());
    failures += !!client->ReadHoldingRegisters(0, 8, regs.data());
    failures += !!client->ReadInputRegisters(0, 8, regs.data());
    failures += !!client->WriteRegister(0, 9);
    failures += !!client->MaskWriteRegister(0, 0x00FF, 0);
    failures += !!client->WriteCoils(0, 8, bits.data());
    failures += !!client->WriteCoil(0, true);
    failures += !!client->ReadCoils(0, 8, bits.data());
    failures += !!client->ReadDiscreteInputs(0, 8, bits.data());
    failures += !!client->WriteAndReadRegisters(0, 2, regs.data(), 0, 8, regs.data());
    return failures;
  };
  ASSERT_EQ(all_operations(), 0);  // warm-up
  // A device refusing over and over is a fault of the steady state too (the first refusal is
  // logged, the repeats only counted).
  uint16_t reg = 0;
  EXPECT_EQ(client->ReadHoldingRegisters(1000, 1, &reg), ModbusErrc::kIllegalDataAddress);
  const long before = testing::ThreadAllocations();  // this thread only: not the server's
  int failures = 0;
  int refusals = 0;
  for (int i = 0; i < 20; ++i) {
    failures += all_operations();
    refusals += client->ReadHoldingRegisters(1000, 1, &reg) == ModbusErrc::kIllegalDataAddress;
  }
  const long allocations = testing::ThreadAllocations() - before;
  EXPECT_EQ(failures, 0);
  EXPECT_EQ(refusals, 20);
  EXPECT_EQ(allocations, 0);
}

TEST_P(ModbusClientTest, BadArgumentsAreRefusedWithoutSendingAnything) {
  auto client = Open();
  std::array<uint16_t, 126> regs{};
  std::array<uint8_t, 2001> bits{};
  EXPECT_EQ(client->ReadHoldingRegisters(0, 0, regs.data()), Errc::kInvalidArgument);
  EXPECT_EQ(client->ReadHoldingRegisters(0, 126, regs.data()), Errc::kInvalidArgument);
  EXPECT_EQ(client->ReadInputRegisters(65535, 2, regs.data()), Errc::kInvalidArgument);
  EXPECT_EQ(client->ReadHoldingRegisters(-1, 1, regs.data()), Errc::kInvalidArgument);
  EXPECT_EQ(client->ReadHoldingRegisters(0, 1, nullptr), Errc::kInvalidArgument);
  EXPECT_EQ(client->WriteRegisters(0, 124, regs.data()), Errc::kInvalidArgument);
  EXPECT_EQ(client->WriteRegister(65536, 1), Errc::kInvalidArgument);
  EXPECT_EQ(client->ReadCoils(0, 2001, bits.data()), Errc::kInvalidArgument);
  EXPECT_EQ(client->WriteCoils(0, 1969, bits.data()), Errc::kInvalidArgument);
  EXPECT_EQ(client->WriteAndReadRegisters(0, 122, regs.data(), 0, 1, regs.data()),
            Errc::kInvalidArgument);
  EXPECT_EQ(server_->stats().requests, 0U);
  EXPECT_EQ(client->counters().failures, 10U);
  // The largest valid request at the very top of the address space is accepted by the client
  // (and refused by this server, whose map is smaller).
  EXPECT_EQ(client->ReadHoldingRegisters(65535, 1, regs.data()), ModbusErrc::kIllegalDataAddress);
}

TEST_P(ModbusClientTest, WrongUnitIdIsNotServed) {
  auto client = Open(",timeout_ms=200,retries=0", ",unit=9");
  uint16_t value = 0;
  std::error_code ec = client->ReadHoldingRegisters(0, 1, &value);
  if (GetParam() == Transport::kTcp) {
    // A TCP server answers for units it does not have as a gateway would.
    EXPECT_EQ(ec, ModbusErrc::kGatewayTargetFailedToRespond);
    EXPECT_THAT(ec.message(), ContainsRegex("^GATEWAY TARGET DEVICE FAILED TO RESPOND"));
  } else {
    // On a serial line the other units keep quiet.
    EXPECT_EQ(ec, Errc::kTimeout);
    EXPECT_TRUE(Eventually([&] { return server_->stats().ignored >= 1; }));
  }
  client.reset();
  // The server still serves its own unit right after.
  auto right = Open();
  EXPECT_EQ(right->ReadHoldingRegisters(0, 1, &value), std::error_code());
}

// ---- TCP only ----------------------------------------------------------------------------------

class ModbusTcpClientTest : public ::testing::Test {
 protected:
  void SetUp() override { server_ = ModbusServer::ListenTcp("127.0.0.1", 0, MapOptions()); }
  std::unique_ptr<ModbusClient> Open(const std::string& options) {
    return ModbusClient::Open(server_->backend() + options);
  }
  std::unique_ptr<ModbusServer> server_;
};

TEST_F(ModbusTcpClientTest, DroppedLinkIsReconnectedAndTheRequestSucceeds) {
  auto client = Open(",timeout_ms=5000,retries=2");
  server_->WithRegisters([](ModbusRegisterMap& m) { m.holding_registers[5] = 55; });
  uint16_t value = 0;
  ASSERT_EQ(client->ReadHoldingRegisters(5, 1, &value), std::error_code());
  EXPECT_EQ(server_->DropConnections(), 1);
  value = 0;
  EXPECT_EQ(client->ReadHoldingRegisters(5, 1, &value), std::error_code())
      << client->last_error_text();
  EXPECT_EQ(value, 55);
  const ModbusClientCounters c = client->counters();
  EXPECT_EQ(c.reconnects, 1U);
  EXPECT_EQ(c.retries, 1U);
  EXPECT_EQ(c.failures, 0U);
  EXPECT_TRUE(client->connected());
  EXPECT_EQ(server_->stats().connections_accepted, 2U);
}

TEST_F(ModbusTcpClientTest, DroppedLinkWithoutRetriesFailsClosedThenReconnectsOnTheNextCall) {
  auto client = Open(",timeout_ms=5000,retries=0");
  uint16_t value = 0;
  ASSERT_EQ(client->ReadHoldingRegisters(0, 1, &value), std::error_code());
  ASSERT_EQ(server_->DropConnections(), 1);
  EXPECT_EQ(client->ReadHoldingRegisters(0, 1, &value), Errc::kClosed);
  EXPECT_FALSE(client->connected());
  EXPECT_THAT(client->last_error_text(), HasSubstr("channel closed"));
  EXPECT_EQ(client->WriteRegister(0, 9), std::error_code());
  EXPECT_EQ(client->counters().reconnects, 1U);
  EXPECT_TRUE(client->connected());
}

TEST_F(ModbusTcpClientTest, ServerGoneAndBackIsReconnected) {
  auto client = Open(",timeout_ms=2000,retries=1");
  const int port = server_->port();
  server_.reset();
  uint16_t value = 0;
  EXPECT_EQ(client->ReadHoldingRegisters(0, 1, &value), Errc::kClosed);
  EXPECT_THAT(client->last_error_text(), HasSubstr("after 2 attempts"));
  server_ = ModbusServer::ListenTcp("127.0.0.1", port, MapOptions());
  EXPECT_EQ(client->ReadHoldingRegisters(0, 1, &value), std::error_code())
      << client->last_error_text();
  EXPECT_EQ(client->counters().reconnects, 1U);
}

TEST_F(ModbusTcpClientTest, LateAnswerIsNeverTakenForTheNextOne) {
  server_->WithRegisters([](ModbusRegisterMap& m) {
    m.holding_registers[1] = 111;
    m.holding_registers[2] = 222;
  });
  auto client = Open(",timeout_ms=100,retries=0");
  server_->SetReplyDelay(milliseconds(400));
  uint16_t value = 0;
  EXPECT_EQ(client->ReadHoldingRegisters(1, 1, &value), Errc::kTimeout);
  server_->SetReplyDelay(milliseconds(0));
  // The answer to the first request (111) is sent while the client already waits for the next
  // one; the client's fresh connection after the timeout rules it out.
  std::error_code ec;
  const auto deadline = Clock::now() + std::chrono::seconds(20);
  do {
    value = 0;
    ec = client->ReadHoldingRegisters(2, 1, &value);
  } while (ec == Errc::kTimeout && Clock::now() < deadline);
  ASSERT_EQ(ec, std::error_code()) << client->last_error_text();
  EXPECT_EQ(value, 222);
  EXPECT_GE(client->counters().reconnects, 1U);
}

TEST_F(ModbusTcpClientTest, HostNamesAndEveryResolvedAddressAreTried) {
  // "localhost" may resolve to ::1 first, where nobody listens; 127.0.0.1 must still be reached.
  auto client =
      ModbusClient::Open("modbus-tcp:localhost:" + std::to_string(server_->port()) + kPatient);
  EXPECT_EQ(client->WriteRegister(3, 33), std::error_code());
}

TEST(ModbusClientIpv6Test, BracketedIpv6AddressRoundTrip) {
  std::unique_ptr<ModbusServer> server;
  try {
    server = ModbusServer::ListenTcp("::1", 0);
  } catch (const HalError& e) {
    GTEST_SKIP() << "no IPv6 loopback here: " << e.what();
  }
  EXPECT_EQ(server->backend(), "modbus-tcp:[::1]:" + std::to_string(server->port()));
  auto client = ModbusClient::Open(server->backend() + kPatient);
  uint16_t value = 0;
  EXPECT_EQ(client->WriteRegister(1, 11), std::error_code());
  EXPECT_EQ(client->ReadHoldingRegisters(1, 1, &value), std::error_code());
  EXPECT_EQ(value, 11);
}

// A port that refuses connections for the whole test: bound, never listening.
class RefusingPort {
 public:
  RefusingPort() {
    fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    EXPECT_EQ(::bind(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a), 0);
    socklen_t length = sizeof a;
    ::getsockname(fd_, reinterpret_cast<sockaddr*>(&a), &length);
    port_ = ntohs(a.sin_port);
  }
  ~RefusingPort() { ::close(fd_); }
  int port() const { return port_; }

 private:
  int fd_ = -1;
  int port_ = 0;
};

TEST(ModbusClientOpenTest, ConnectionRefusedThrowsHalErrorNamingHostAndPort) {
  RefusingPort refusing;
  const std::string where = "127.0.0.1:" + std::to_string(refusing.port());
  try {
    ModbusClient::Open("modbus-tcp:" + where + ",timeout_ms=2000");
    FAIL() << "Open() succeeded against a port nobody listens on";
  } catch (const HalError& e) {
    EXPECT_THAT(e.what(), ContainsRegex("connect to " + where + " failed: Connection refused"));
    EXPECT_EQ(e.device(), "modbus-tcp:" + where + ",timeout_ms=2000");
    EXPECT_EQ(e.code(), std::error_code(ECONNREFUSED, std::system_category()));
  }
}

TEST(ModbusClientOpenTest, MalformedBackendStringThrowsConfigError) {
  EXPECT_THROW(ModbusClient::Open("modbus-tcp:127.0.0.1"), common::ConfigError);
  EXPECT_THROW(ModbusClient::Open("tty:/dev/ttyUSB0"), common::ConfigError);
  ModbusBackendSpec spec;
  spec.host = "127.0.0.1";
  spec.port = 502;
  spec.timeout_ms = 0;
  spec.unit = 300;
  try {
    ModbusClient::Open(spec);
    FAIL() << "Open() accepted timeout_ms 0 and unit 300";
  } catch (const common::ConfigError& e) {
    EXPECT_THAT(e.what(), ContainsRegex("unit 300 is not in 0..247.*timeout_ms 0"));
  }
}

// ---- RTU only ----------------------------------------------------------------------------------

TEST(ModbusRtuClientOpenTest, Rs485OnAPtyThrowsHalErrorSayingSo) {
  PtyPair pty;
  try {
    ModbusClient::Open("modbus-rtu:" + pty.slave_path() + "@115200,8E1,rs485");
    FAIL() << "a pty accepted RS485 mode";
  } catch (const HalError& e) {
    EXPECT_THAT(e.what(), ContainsRegex("enable RS485 mode.*leave rs485 off"));
  }
}

TEST(ModbusRtuClientOpenTest, MissingDeviceThrowsHalError) {
  try {
    ModbusClient::Open("modbus-rtu:/dev/kinevis-no-such-tty@115200");
    FAIL() << "opened a device that does not exist";
  } catch (const HalError& e) {
    EXPECT_THAT(e.what(), ContainsRegex("open /dev/kinevis-no-such-tty failed: No such file"));
  }
}

TEST(ModbusRtuClientOpenTest, BaudRateLibmodbusCannotSetIsAConfigError) {
  PtyPair pty;
  try {
    ModbusClient::Open("modbus-rtu:" + pty.slave_path() + "@2000000");
    FAIL() << "accepted a baud rate libmodbus would silently replace by 9600";
  } catch (const common::ConfigError& e) {
    EXPECT_THAT(e.what(), ContainsRegex("baud rate 2000000 is not one libmodbus can set"));
  }
}

// A device on the master side of a pty that answers every request with `answer(request)`.
class FakeRtuDevice {
 public:
  using Answer = std::function<std::vector<uint8_t>(const std::vector<uint8_t>&)>;
  FakeRtuDevice(int fd, Answer answer) : fd_(fd), answer_(std::move(answer)) {
    thread_ = std::thread([this] { Run(); });
  }
  ~FakeRtuDevice() {
    stop_ = true;
    thread_.join();
  }

  static std::vector<uint8_t> WithCrc(std::vector<uint8_t> frame) {
    const uint16_t crc = ModbusRtuCrc(frame.data(), frame.size());
    frame.push_back(static_cast<uint8_t>(crc & 0xFF));
    frame.push_back(static_cast<uint8_t>(crc >> 8));
    return frame;
  }

 private:
  void Run() {
    std::vector<uint8_t> request;
    while (!stop_) {
      pollfd p{fd_, POLLIN, 0};
      if (::poll(&p, 1, 20) <= 0) continue;
      uint8_t buffer[256];
      ssize_t n = ::read(fd_, buffer, sizeof buffer);
      if (n <= 0) continue;
      request.insert(request.end(), buffer, buffer + n);
      if (request.size() < 8) continue;  // the tests send 8-byte read requests
      std::vector<uint8_t> answer = answer_(request);
      request.clear();
      ASSERT_EQ(::write(fd_, answer.data(), answer.size()), static_cast<ssize_t>(answer.size()));
    }
  }

  int fd_;
  Answer answer_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

TEST(ModbusRtuClientTest, AnswerWithABadCrcIsCountedAndNotRetried) {
  PtyPair pty;
  FakeRtuDevice device(pty.master_fd(), [](const std::vector<uint8_t>& request) {
    std::vector<uint8_t> answer = FakeRtuDevice::WithCrc({request[0], 0x03, 0x02, 0x00, 0x2A});
    answer.back() ^= 0x5A;
    return answer;
  });
  auto client = ModbusClient::Open("modbus-rtu:" + pty.slave_path() +
                                   "@115200,8E1,unit=1,timeout_ms=2000,retries=2");
  uint16_t value = 0;
  std::error_code ec = client->ReadHoldingRegisters(0, 1, &value);
  EXPECT_EQ(ec, ModbusErrc::kBadCrc);
  EXPECT_THAT(ec.message(), HasSubstr("CRC"));
  EXPECT_EQ(value, 0) << "nothing may be written to the output on failure";
  EXPECT_EQ(client->counters().crc_errors, 1U);
  EXPECT_EQ(client->counters().retries, 0U);
}

TEST(ModbusRtuClientTest, AnswerFromAnotherUnitIsBadSlave) {
  PtyPair pty;
  FakeRtuDevice device(pty.master_fd(), [](const std::vector<uint8_t>&) {
    return FakeRtuDevice::WithCrc({0x05, 0x03, 0x02, 0x00, 0x2A});
  });
  auto client = ModbusClient::Open("modbus-rtu:" + pty.slave_path() +
                                   "@115200,8E1,unit=1,timeout_ms=2000,retries=0");
  uint16_t value = 0;
  std::error_code ec = client->ReadHoldingRegisters(0, 1, &value);
  EXPECT_EQ(ec, ModbusErrc::kBadSlave);
  EXPECT_FALSE(IsModbusException(ec));
}

TEST(ModbusRtuClientTest, ExceptionCodesOutsideTheSpecificationAreNamedAsSuch) {
  PtyPair pty;
  std::atomic<uint8_t> code{6};
  FakeRtuDevice device(pty.master_fd(), [&code](const std::vector<uint8_t>&) {
    return FakeRtuDevice::WithCrc({0x01, 0x83, code.load()});
  });
  auto client = ModbusClient::Open("modbus-rtu:" + pty.slave_path() +
                                   "@115200,8E1,unit=1,timeout_ms=5000,retries=2");
  uint16_t value = 0;
  EXPECT_EQ(client->ReadHoldingRegisters(0, 1, &value), ModbusErrc::kServerDeviceBusy);
  code = 9;  // not assigned by the specification
  EXPECT_EQ(client->ReadHoldingRegisters(0, 1, &value), ModbusErrc::kUnknownException);
  code = 0x20;  // out of range altogether
  EXPECT_EQ(client->ReadHoldingRegisters(0, 1, &value), ModbusErrc::kBadException);
  EXPECT_EQ(client->counters().retries, 0U);
}

TEST(ModbusRtuClientTest, CorrectAnswerFromAFakeDeviceIsDecoded) {
  PtyPair pty;
  std::mutex mutex;
  std::vector<uint8_t> seen;
  FakeRtuDevice device(pty.master_fd(), [&](const std::vector<uint8_t>& request) {
    std::lock_guard<std::mutex> lock(mutex);
    seen = request;
    return FakeRtuDevice::WithCrc({0x01, 0x03, 0x04, 0x12, 0x34, 0xAB, 0xCD});
  });
  auto client = ModbusClient::Open("modbus-rtu:" + pty.slave_path() +
                                   "@115200,8E1,unit=1,timeout_ms=5000,retries=0");
  std::array<uint16_t, 2> values{};
  ASSERT_EQ(client->ReadHoldingRegisters(0x0102, 2, values.data()), std::error_code());
  EXPECT_THAT(values, ElementsAre(0x1234, 0xABCD));
  // The request on the wire: unit, function, address, count, CRC low byte first.
  std::lock_guard<std::mutex> lock(mutex);
  EXPECT_THAT(seen, ElementsAreArray(FakeRtuDevice::WithCrc({0x01, 0x03, 0x01, 0x02, 0x00, 0x02})));
}

TEST(ModbusRtuClientTest, BroadcastWritesAreExecutedWithoutWaitingForAnAnswer) {
  PtyPair pty;
  auto server = ModbusServer::ServeRtu(pty.master_fd(), pty.slave_path(), MapOptions());
  const std::string line = "modbus-rtu:" + pty.slave_path() + "@115200,8E1";
  {
    auto broadcaster = ModbusClient::Open(line + ",unit=0,timeout_ms=5000,retries=0");
    const auto start = Clock::now();
    EXPECT_EQ(broadcaster->WriteRegister(5, 77), std::error_code());
    const std::array<uint8_t, 2> coils = {1, 1};
    EXPECT_EQ(broadcaster->WriteCoils(8, 2, coils.data()), std::error_code());
    EXPECT_LT(Clock::now() - start, milliseconds(5000)) << "waited for an answer to a broadcast";
    uint16_t value = 0;
    EXPECT_EQ(broadcaster->ReadHoldingRegisters(5, 1, &value), Errc::kInvalidArgument)
        << "reads cannot be broadcast";
  }
  auto client = ModbusClient::Open(line + ",unit=1" + kPatient);
  uint16_t value = 0;
  ASSERT_EQ(client->ReadHoldingRegisters(5, 1, &value), std::error_code());
  EXPECT_EQ(value, 77);
  std::array<uint8_t, 2> coils{};
  ASSERT_EQ(client->ReadCoils(8, 2, coils.data()), std::error_code());
  EXPECT_THAT(coils, ElementsAre(1, 1));
  EXPECT_EQ(server->stats().broadcasts, 2U);
  EXPECT_EQ(server->stats().replies, 2U) << "a broadcast must not be answered";
}

TEST(ModbusRtuClientTest, LateAnswerThatArrivedBeforeTheNextRequestIsFlushed) {
  PtyPair pty;
  auto server = ModbusServer::ServeRtu(pty.master_fd(), pty.slave_path(), MapOptions());
  server->WithRegisters([](ModbusRegisterMap& m) {
    m.holding_registers[1] = 111;
    m.holding_registers[2] = 222;
  });
  auto client = ModbusClient::Open("modbus-rtu:" + pty.slave_path() +
                                   "@115200,8E1,unit=1,timeout_ms=1000,retries=0");
  server->SetReplyDelay(milliseconds(2500));
  uint16_t value = 0;
  EXPECT_EQ(client->ReadHoldingRegisters(1, 1, &value), Errc::kTimeout);
  server->SetReplyDelay(milliseconds(0));
  // Wait until the late answer (7 bytes) sits unread in the line's input queue, which every
  // descriptor of the pty's slave side shares.
  const int probe = ::open(pty.slave_path().c_str(), O_RDONLY | O_NOCTTY | O_CLOEXEC | O_NONBLOCK);
  ASSERT_GE(probe, 0);
  int queued = 0;
  EXPECT_TRUE(Eventually([&] { return ::ioctl(probe, FIONREAD, &queued) == 0 && queued >= 7; }));
  ::close(probe);
  // A read of the same shape would take the stale frame (serial Modbus has no transaction id);
  // the flush after the timeout discards it.
  ASSERT_EQ(client->ReadHoldingRegisters(2, 1, &value), std::error_code())
      << client->last_error_text();
  EXPECT_EQ(value, 222);
}

// ---- The error category ------------------------------------------------------------------------

TEST(ModbusCategoryTest, EveryExceptionCarriesItsStandardName) {
  const std::vector<std::pair<ModbusErrc, std::string>> names = {
      {ModbusErrc::kIllegalFunction, "ILLEGAL FUNCTION"},
      {ModbusErrc::kIllegalDataAddress, "ILLEGAL DATA ADDRESS"},
      {ModbusErrc::kIllegalDataValue, "ILLEGAL DATA VALUE"},
      {ModbusErrc::kServerDeviceFailure, "SERVER DEVICE FAILURE"},
      {ModbusErrc::kAcknowledge, "ACKNOWLEDGE"},
      {ModbusErrc::kServerDeviceBusy, "SERVER DEVICE BUSY"},
      {ModbusErrc::kMemoryParityError, "MEMORY PARITY ERROR"},
      {ModbusErrc::kGatewayPathUnavailable, "GATEWAY PATH UNAVAILABLE"},
      {ModbusErrc::kGatewayTargetFailedToRespond, "GATEWAY TARGET DEVICE FAILED TO RESPOND"},
  };
  for (const auto& [code, name] : names) {
    std::error_code ec = code;
    EXPECT_EQ(ec.category(), ModbusCategory());
    EXPECT_THAT(ec.message(), ContainsRegex("^" + name + " \\(Modbus exception " +
                                            std::to_string(static_cast<int>(code)) + "\\)$"));
    EXPECT_TRUE(IsModbusException(ec)) << name;
  }
}

TEST(ModbusCategoryTest, LibmodbusFailuresAreNamedButAreNoExceptions) {
  EXPECT_THAT(std::error_code(ModbusErrc::kBadCrc).message(), ContainsRegex("^CRC ERROR"));
  EXPECT_THAT(std::error_code(ModbusErrc::kBadData).message(), ContainsRegex("^BAD DATA"));
  EXPECT_THAT(std::error_code(ModbusErrc::kBadSlave).message(), ContainsRegex("^BAD SLAVE"));
  EXPECT_THAT(std::error_code(ModbusErrc::kTooManyData).message(), ContainsRegex("^TOO MANY DATA"));
  EXPECT_FALSE(IsModbusException(ModbusErrc::kBadCrc));
  EXPECT_FALSE(IsModbusException(Errc::kTimeout));
  EXPECT_FALSE(IsModbusException(std::error_code()));
  EXPECT_FALSE(std::error_code(ModbusErrc::kNone)) << "kNone must read as success";
  EXPECT_STREQ(ModbusCategory().name(), "kinevis.modbus");
}

}  // namespace
}  // namespace kinevis::hal
