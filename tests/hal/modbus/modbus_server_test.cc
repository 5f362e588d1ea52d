#include "hal/modbus/modbus_server.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <chrono>
#include <cstring>
#include <memory>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "hal/common/error.h"
#include "hal/modbus/modbus_client.h"
#include "hal/serial/pty_pair.h"

namespace kinevis::hal {
namespace {

using ::testing::ContainsRegex;
using ::testing::ElementsAre;
using ::testing::ElementsAreArray;
using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;
using Bytes = std::vector<uint8_t>;

constexpr char kPatient[] = ",timeout_ms=5000,retries=0";

// Waits until pred() holds or 20 s have passed; returns pred().
template <typename Pred>
bool Eventually(Pred pred) {
  const auto deadline = Clock::now() + std::chrono::seconds(20);
  while (!pred() && Clock::now() < deadline) std::this_thread::sleep_for(milliseconds(2));
  return pred();
}

// Reads from fd until `n` bytes have come or `timeout` has passed.
Bytes ReadBytes(int fd, size_t n, milliseconds timeout) {
  Bytes out;
  const auto deadline = Clock::now() + timeout;
  while (out.size() < n) {
    auto left = std::chrono::duration_cast<milliseconds>(deadline - Clock::now()).count();
    if (left <= 0) break;
    pollfd p{fd, POLLIN, 0};
    if (::poll(&p, 1, static_cast<int>(left)) <= 0) continue;
    uint8_t buffer[512];
    ssize_t got = ::read(fd, buffer, std::min(sizeof buffer, n - out.size()));
    if (got <= 0) break;
    out.insert(out.end(), buffer, buffer + got);
  }
  return out;
}

void WriteBytes(int fd, const Bytes& bytes) {
  ASSERT_EQ(::write(fd, bytes.data(), bytes.size()), static_cast<ssize_t>(bytes.size()));
}

Bytes WithCrc(Bytes frame) {
  const uint16_t crc = ModbusRtuCrc(frame.data(), frame.size());
  frame.push_back(static_cast<uint8_t>(crc & 0xFF));
  frame.push_back(static_cast<uint8_t>(crc >> 8));
  return frame;
}

// A raw TCP connection to the server, for frames the client would never send.
class RawTcp {
 public:
  explicit RawTcp(int port) {
    fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(static_cast<uint16_t>(port));
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    EXPECT_EQ(::connect(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a), 0);
  }
  ~RawTcp() { ::close(fd_); }
  int fd() const { return fd_; }

 private:
  int fd_ = -1;
};

// ---- CRC ---------------------------------------------------------------------------------------

TEST(ModbusRtuCrcTest, MatchesTheCheckValueAndTheSpecificationsExample) {
  const std::string check = "123456789";
  EXPECT_EQ(ModbusRtuCrc(reinterpret_cast<const uint8_t*>(check.data()), check.size()), 0x4B37);
  // "Modbus over serial line" V1.02, 6.2.2: 01 03 00 00 00 0A is sent with CRC bytes C5 CD.
  const Bytes request = {0x01, 0x03, 0x00, 0x00, 0x00, 0x0A};
  EXPECT_EQ(ModbusRtuCrc(request.data(), request.size()), 0xCDC5);
  EXPECT_EQ(ModbusRtuCrc(nullptr, 0), 0xFFFF);
}

// ---- Set-up ------------------------------------------------------------------------------------

TEST(ModbusServerSetupTest, TcpPortZeroBindsAnEphemeralPortNamedInTheBackend) {
  auto server = ModbusServer::ListenTcp("127.0.0.1", 0);
  ASSERT_GT(server->port(), 0);
  EXPECT_EQ(server->backend(), "modbus-tcp:127.0.0.1:" + std::to_string(server->port()));
  // The backend string is exactly what a host opens.
  auto client = ModbusClient::Open(server->backend() + kPatient);
  EXPECT_EQ(client->WriteRegister(1, 5), std::error_code());
}

TEST(ModbusServerSetupTest, BackendStringsCarryUnitAndLineSettings) {
  ModbusServer::Options o;
  o.unit = 7;
  auto tcp = ModbusServer::ListenTcp("0.0.0.0", 0, o);
  EXPECT_EQ(tcp->backend(), "modbus-tcp:127.0.0.1:" + std::to_string(tcp->port()) + ",unit=7");

  PtyPair pty;
  auto rtu = ModbusServer::ServeRtu(pty.master_fd(), pty.slave_path());
  EXPECT_EQ(rtu->backend(), "modbus-rtu:" + pty.slave_path() + "@115200,8E1");
  EXPECT_EQ(rtu->port(), 0);
  rtu.reset();

  o.unit = 3;
  o.baud = 9600;
  o.parity = 'N';
  o.stop_bits = 2;
  auto rtu2 = ModbusServer::ServeRtu(pty.master_fd(), pty.slave_path(), o);
  EXPECT_EQ(rtu2->backend(), "modbus-rtu:" + pty.slave_path() + "@9600,8N2,unit=3");
  auto client = ModbusClient::Open(rtu2->backend() + kPatient);
  EXPECT_EQ(client->WriteRegister(2, 6), std::error_code());
  EXPECT_EQ(rtu2->WithRegisters([](ModbusRegisterMap& m) { return m.holding_registers[2]; }), 6);
}

TEST(ModbusServerSetupTest, MapSizesComeFromTheOptions) {
  ModbusServer::Options o;
  o.coils = 3;
  o.discrete_inputs = 0;
  o.holding_registers = 65536;
  o.input_registers = 17;
  auto server = ModbusServer::ListenTcp("127.0.0.1", 0, o);
  server->WithRegisters([](ModbusRegisterMap& m) {
    EXPECT_EQ(m.coils.size(), 3U);
    EXPECT_EQ(m.discrete_inputs.size(), 0U);
    EXPECT_EQ(m.holding_registers.size(), 65536U);
    EXPECT_EQ(m.input_registers.size(), 17U);
  });
  auto client = ModbusClient::Open(server->backend() + kPatient);
  EXPECT_EQ(client->WriteRegister(65535, 1), std::error_code());
  uint8_t bit = 0;
  EXPECT_EQ(client->ReadDiscreteInputs(0, 1, &bit), ModbusErrc::kIllegalDataAddress);
  EXPECT_EQ(client->WriteCoil(3, true), ModbusErrc::kIllegalDataAddress);
  EXPECT_EQ(client->WriteCoil(2, true), std::error_code());
}

TEST(ModbusServerSetupTest, BadOptionsThrowConfigErrorNamingEveryField) {
  ModbusServer::Options o;
  o.coils = -1;
  o.input_registers = 70000;
  o.unit = 0;
  try {
    ModbusServer::ListenTcp("127.0.0.1", 0, o);
    FAIL() << "accepted bad options";
  } catch (const common::ConfigError& e) {
    EXPECT_THAT(e.what(), ContainsRegex("coils -1 is not in 0..65536.*input_registers 70000.*"
                                        "unit 0 is not in 1..247"));
  }
  ModbusServer::Options rtu;
  rtu.parity = 'X';
  rtu.data_bits = 9;
  EXPECT_THROW(ModbusServer::ServeRtu(-1, "/dev/null"), common::ConfigError);
  PtyPair pty;
  try {
    ModbusServer::ServeRtu(pty.master_fd(), pty.slave_path(), rtu);
    FAIL() << "accepted parity X";
  } catch (const common::ConfigError& e) {
    EXPECT_THAT(e.what(), ContainsRegex("parity 'X'.*data_bits 9"));
  }
}

TEST(ModbusServerSetupTest, PortInUseThrowsHalErrorNamingHostAndPort) {
  auto first = ModbusServer::ListenTcp("127.0.0.1", 0);
  const std::string where = "127.0.0.1:" + std::to_string(first->port());
  try {
    ModbusServer::ListenTcp("127.0.0.1", first->port());
    FAIL() << "two servers listen on " << where;
  } catch (const HalError& e) {
    EXPECT_THAT(e.what(), ContainsRegex("listen on " + where + " failed: Address already in use"));
  }
}

// ---- Serving -----------------------------------------------------------------------------------

TEST(ModbusServerTcpTest, ServesSeveralClientsAtOnce) {
  auto server = ModbusServer::ListenTcp("127.0.0.1", 0);
  constexpr int kClients = 4;
  constexpr int kRounds = 50;
  std::vector<std::unique_ptr<ModbusClient>> clients;
  clients.reserve(kClients);
  for (int i = 0; i < kClients; ++i) {
    clients.push_back(ModbusClient::Open(server->backend() + kPatient));
  }
  std::atomic<int> failures{0};
  std::vector<std::thread> threads;
  threads.reserve(kClients);
  for (int i = 0; i < kClients; ++i) {
    threads.emplace_back([&, i] {
      ModbusClient& client = *clients[static_cast<size_t>(i)];
      for (int round = 0; round < kRounds; ++round) {
        const std::array<uint16_t, 2> values = {static_cast<uint16_t>(i),
                                                static_cast<uint16_t>(round)};
        std::array<uint16_t, 2> read{};
        if (client.WriteRegisters(10 * i, 2, values.data()) ||
            client.ReadHoldingRegisters(10 * i, 2, read.data()) || read != values) {
          ++failures;
        }
      }
    });
  }
  // The simulator side works on the map meanwhile.
  for (int round = 0; round < kRounds; ++round) {
    server->WithRegisters(
        [round](ModbusRegisterMap& m) { m.input_registers[0] = static_cast<uint16_t>(round); });
  }
  for (std::thread& t : threads) t.join();
  EXPECT_EQ(failures.load(), 0);
  const ModbusServerStats s = server->stats();
  EXPECT_EQ(s.connections_accepted, static_cast<uint64_t>(kClients));
  EXPECT_EQ(s.connections_open, static_cast<uint64_t>(kClients));
  EXPECT_EQ(s.replies, static_cast<uint64_t>(2 * kClients * kRounds));
}

TEST(ModbusServerTcpTest, WriteHookSeesEveryWriteAndItsReactionIsVisibleToTheNextRequest) {
  auto server = ModbusServer::ListenTcp("127.0.0.1", 0);
  struct Seen {
    int function, address, count;
    std::vector<uint16_t> values;
  };
  std::vector<Seen> seen;  // written on the server thread under the register mutex
  constexpr int kAlarm = 100;
  server->SetWriteHook([&seen](const ModbusRequest& r, ModbusRegisterMap& m) {
    seen.push_back(
        {r.function, r.address, r.count, std::vector<uint16_t>(r.values, r.values + r.count)});
    // A simulator validating a target: anything above 500 raises an alarm.
    if (r.function == 0x06 && r.values[0] > 500) m.holding_registers[kAlarm] = 1;
  });
  auto client = ModbusClient::Open(server->backend() + kPatient);
  ASSERT_EQ(client->WriteRegister(10, 600), std::error_code());
  uint16_t alarm = 0;
  ASSERT_EQ(client->ReadHoldingRegisters(kAlarm, 1, &alarm), std::error_code());
  EXPECT_EQ(alarm, 1);

  const std::array<uint16_t, 3> regs = {7, 8, 9};
  ASSERT_EQ(client->WriteRegisters(20, 3, regs.data()), std::error_code());
  const std::array<uint8_t, 3> coils = {1, 0, 1};
  ASSERT_EQ(client->WriteCoils(5, 3, coils.data()), std::error_code());
  ASSERT_EQ(client->WriteCoil(9, true), std::error_code());
  ASSERT_EQ(client->MaskWriteRegister(20, 0x00FF, 0xAB00), std::error_code());
  std::array<uint16_t, 1> out{};
  ASSERT_EQ(client->WriteAndReadRegisters(30, 1, regs.data(), 30, 1, out.data()),
            std::error_code());
  // Reads and refused writes are not reported.
  EXPECT_EQ(client->WriteRegister(9999, 1), ModbusErrc::kIllegalDataAddress);
  ASSERT_EQ(client->ReadHoldingRegisters(0, 1, out.data()), std::error_code());

  server->WithRegisters([&](ModbusRegisterMap&) {
    ASSERT_EQ(seen.size(), 6U);
    EXPECT_EQ(seen[0].function, 0x06);
    EXPECT_EQ(seen[0].address, 10);
    EXPECT_THAT(seen[0].values, ElementsAre(600));
    EXPECT_EQ(seen[1].function, 0x10);
    EXPECT_EQ(seen[1].address, 20);
    EXPECT_EQ(seen[1].count, 3);
    EXPECT_THAT(seen[1].values, ElementsAre(7, 8, 9));
    EXPECT_EQ(seen[2].function, 0x0F);
    EXPECT_THAT(seen[2].values, ElementsAre(1, 0, 1));
    EXPECT_EQ(seen[3].function, 0x05);
    EXPECT_THAT(seen[3].values, ElementsAre(1));
    EXPECT_EQ(seen[4].function, 0x16);
    EXPECT_THAT(seen[4].values, ElementsAre(0xAB07));  // (7 & 0x00FF) | (0xAB00 & ~0x00FF)
    EXPECT_EQ(seen[5].function, 0x17);
    EXPECT_EQ(seen[5].address, 30);
    EXPECT_EQ(seen[5].count, 1);
  });
}

TEST(ModbusServerTcpTest, RequestHookSeesReadsAndWritesAndMayRefuseWithAnyException) {
  auto server = ModbusServer::ListenTcp("127.0.0.1", 0);
  std::vector<std::pair<int, bool>> seen;  // function, is_write
  server->SetRequestHook([&seen](const ModbusRequest& r, const ModbusRegisterMap&) {
    seen.emplace_back(r.function, r.is_write());
    if (r.function == 0x04) return ModbusErrc::kServerDeviceBusy;
    if (r.is_write() && r.function == 0x0F && r.count > 2) return ModbusErrc::kIllegalDataValue;
    return ModbusErrc::kNone;
  });
  auto client = ModbusClient::Open(server->backend() + kPatient);
  uint16_t reg = 0;
  std::error_code busy = client->ReadInputRegisters(0, 1, &reg);
  EXPECT_EQ(busy, ModbusErrc::kServerDeviceBusy);
  EXPECT_THAT(busy.message(), ContainsRegex("^SERVER DEVICE BUSY"));
  EXPECT_EQ(client->ReadHoldingRegisters(0, 1, &reg), std::error_code());
  const std::array<uint8_t, 3> coils = {1, 1, 1};
  EXPECT_EQ(client->WriteCoils(0, 3, coils.data()), ModbusErrc::kIllegalDataValue);
  EXPECT_EQ(client->WriteCoils(0, 2, coils.data()), std::error_code());
  // Requests the server refuses by itself never reach the hook.
  EXPECT_EQ(client->WriteRegister(5000, 1), ModbusErrc::kIllegalDataAddress);
  server->WithRegisters([&](ModbusRegisterMap& m) {
    EXPECT_THAT(seen, ElementsAre(std::make_pair(0x04, false), std::make_pair(0x03, false),
                                  std::make_pair(0x0F, true), std::make_pair(0x0F, true)));
    EXPECT_THAT(std::vector<uint8_t>(m.coils.begin(), m.coils.begin() + 3), ElementsAre(1, 1, 0));
  });
  EXPECT_EQ(server->stats().exceptions, 3U);
}

TEST(ModbusServerTcpTest, HookThatThrowsIsAnsweredWithServerDeviceFailure) {
  auto server = ModbusServer::ListenTcp("127.0.0.1", 0);
  server->SetRequestHook([](const ModbusRequest&, const ModbusRegisterMap&) -> ModbusErrc {
    throw std::runtime_error("simulator bug");
  });
  auto client = ModbusClient::Open(server->backend() + kPatient);
  uint16_t reg = 0;
  EXPECT_EQ(client->ReadHoldingRegisters(0, 1, &reg), ModbusErrc::kServerDeviceFailure);
  server->SetRequestHook(nullptr);
  EXPECT_EQ(client->ReadHoldingRegisters(0, 1, &reg), std::error_code());
}

TEST(ModbusServerTcpTest, HooksMayUseWithRegistersThemselves) {
  auto server = ModbusServer::ListenTcp("127.0.0.1", 0);
  ModbusServer* s = server.get();
  server->SetWriteHook([s](const ModbusRequest& r, ModbusRegisterMap&) {
    s->WithRegisters([&r](ModbusRegisterMap& m) { m.input_registers[0] = r.values[0]; });
  });
  auto client = ModbusClient::Open(server->backend() + kPatient);
  ASSERT_EQ(client->WriteRegister(0, 4321), std::error_code());
  uint16_t reg = 0;
  ASSERT_EQ(client->ReadInputRegisters(0, 1, &reg), std::error_code());
  EXPECT_EQ(reg, 4321);
}

TEST(ModbusServerTcpTest, DropConnectionsClosesEveryConnectionAndCountsThem) {
  auto server = ModbusServer::ListenTcp("127.0.0.1", 0);
  auto a = ModbusClient::Open(server->backend() + kPatient);
  auto b = ModbusClient::Open(server->backend() + kPatient);
  uint16_t reg = 0;
  ASSERT_EQ(a->ReadHoldingRegisters(0, 1, &reg), std::error_code());
  ASSERT_EQ(b->ReadHoldingRegisters(0, 1, &reg), std::error_code());
  EXPECT_EQ(server->DropConnections(), 2);
  ModbusServerStats s = server->stats();
  EXPECT_EQ(s.connections_dropped, 2U);
  EXPECT_EQ(s.connections_open, 0U);
  EXPECT_EQ(a->ReadHoldingRegisters(0, 1, &reg), Errc::kClosed);
  EXPECT_EQ(server->DropConnections(), 0);
}

TEST(ModbusServerTcpTest, StopAnsweringForAWhileThenAnswersAgain) {
  auto server = ModbusServer::ListenTcp("127.0.0.1", 0);
  auto client = ModbusClient::Open(server->backend() + ",timeout_ms=200,retries=0");
  const auto start = Clock::now();
  const milliseconds window(2000);
  server->StopAnswering(window);
  uint16_t reg = 0;
  EXPECT_EQ(client->ReadHoldingRegisters(0, 1, &reg), Errc::kTimeout);
  EXPECT_TRUE(Eventually([&] { return server->stats().swallowed == 1; }));
  std::this_thread::sleep_until(start + window + milliseconds(50));
  auto patient = ModbusClient::Open(server->backend() + kPatient);
  EXPECT_EQ(patient->ReadHoldingRegisters(0, 1, &reg), std::error_code());
  EXPECT_EQ(server->stats().swallowed, 1U);
}

TEST(ModbusServerTcpTest, ReplyDelayDelaysTheAnswer) {
  auto server = ModbusServer::ListenTcp("127.0.0.1", 0);
  auto client = ModbusClient::Open(server->backend() + kPatient);
  server->SetReplyDelay(milliseconds(300));
  uint16_t reg = 0;
  const auto start = Clock::now();
  ASSERT_EQ(client->ReadHoldingRegisters(0, 1, &reg), std::error_code());
  EXPECT_GE(Clock::now() - start, milliseconds(300));
}

TEST(ModbusServerTcpTest, StopReturnsPromptlyWhileAReplyIsDelayed) {
  auto server = ModbusServer::ListenTcp("127.0.0.1", 0);
  auto client = ModbusClient::Open(server->backend() + ",timeout_ms=60000,retries=0");
  server->SetReplyDelay(milliseconds(60'000));
  std::error_code result;
  std::thread request([&] {
    uint16_t reg = 0;
    result = client->ReadHoldingRegisters(0, 1, &reg);
  });
  ASSERT_TRUE(Eventually([&] { return server->stats().requests == 1; }));
  const auto start = Clock::now();
  server->Stop();
  EXPECT_LT(Clock::now() - start, milliseconds(30'000)) << "Stop() waited for the delay";
  request.join();
  EXPECT_EQ(result, Errc::kClosed);
  server->Stop();  // idempotent
}

TEST(ModbusServerTcpTest, UnitIdsServedOnTcp) {
  ModbusServer::Options o;
  o.unit = 5;
  auto server = ModbusServer::ListenTcp("127.0.0.1", 0, o);
  const std::string endpoint = "modbus-tcp:127.0.0.1:" + std::to_string(server->port());
  uint16_t reg = 0;
  for (int unit : {5, 0}) {
    auto client = ModbusClient::Open(endpoint + ",unit=" + std::to_string(unit) + kPatient);
    EXPECT_EQ(client->ReadHoldingRegisters(0, 1, &reg), std::error_code()) << "unit " << unit;
  }
  auto other = ModbusClient::Open(endpoint + ",unit=6" + kPatient);
  EXPECT_EQ(other->ReadHoldingRegisters(0, 1, &reg), ModbusErrc::kGatewayTargetFailedToRespond);
  // 0xFF, "not used" in Modbus TCP, cannot be given in a backend string: send it raw.
  RawTcp raw(server->port());
  WriteBytes(raw.fd(), {0x00, 0x07, 0x00, 0x00, 0x00, 0x06, 0xFF, 0x03, 0x00, 0x00, 0x00, 0x01});
  EXPECT_THAT(ReadBytes(raw.fd(), 11, milliseconds(5000)),
              ElementsAre(0x00, 0x07, 0x00, 0x00, 0x00, 0x05, 0xFF, 0x03, 0x02, 0x00, 0x00));
}

TEST(ModbusServerTcpTest, MalformedRequestsGetTheRightExceptionOnTheWire) {
  auto server = ModbusServer::ListenTcp("127.0.0.1", 0);
  RawTcp raw(server->port());
  // Function 0x2B (encapsulated interface) is not served: ILLEGAL FUNCTION, same transaction id.
  WriteBytes(raw.fd(), {0x12, 0x34, 0x00, 0x00, 0x00, 0x03, 0x01, 0x2B, 0x0E});
  EXPECT_THAT(ReadBytes(raw.fd(), 9, milliseconds(5000)),
              ElementsAre(0x12, 0x34, 0x00, 0x00, 0x00, 0x03, 0x01, 0xAB, 0x01));
  // Reading 0 registers: ILLEGAL DATA VALUE.
  WriteBytes(raw.fd(), {0x00, 0x02, 0x00, 0x00, 0x00, 0x06, 0x01, 0x03, 0x00, 0x00, 0x00, 0x00});
  EXPECT_THAT(ReadBytes(raw.fd(), 9, milliseconds(5000)),
              ElementsAre(0x00, 0x02, 0x00, 0x00, 0x00, 0x03, 0x01, 0x83, 0x03));
  // A byte count that disagrees with the quantity: ILLEGAL DATA VALUE, map untouched.
  WriteBytes(raw.fd(), {0x00, 0x03, 0x00, 0x00, 0x00, 0x09, 0x01, 0x10, 0x00, 0x00, 0x00, 0x02,
                        0x02, 0x12, 0x34});
  EXPECT_THAT(ReadBytes(raw.fd(), 9, milliseconds(5000)),
              ElementsAre(0x00, 0x03, 0x00, 0x00, 0x00, 0x03, 0x01, 0x90, 0x03));
  // Two requests in one segment are both answered, in order.
  WriteBytes(raw.fd(), {0x00, 0x04, 0x00, 0x00, 0x00, 0x06, 0x01, 0x06, 0x00, 0x01, 0x00, 0x2A,
                        0x00, 0x05, 0x00, 0x00, 0x00, 0x06, 0x01, 0x03, 0x00, 0x01, 0x00, 0x01});
  EXPECT_THAT(ReadBytes(raw.fd(), 12 + 11, milliseconds(5000)),
              ElementsAre(0x00, 0x04, 0x00, 0x00, 0x00, 0x06, 0x01, 0x06, 0x00, 0x01, 0x00, 0x2A,
                          0x00, 0x05, 0x00, 0x00, 0x00, 0x05, 0x01, 0x03, 0x02, 0x00, 0x2A));
  EXPECT_EQ(server->WithRegisters([](ModbusRegisterMap& m) { return m.holding_registers[0]; }), 0);
}

TEST(ModbusServerTcpTest, MalformedMbapHeaderClosesTheConnection) {
  auto server = ModbusServer::ListenTcp("127.0.0.1", 0);
  RawTcp raw(server->port());
  // Protocol id 1 is not Modbus.
  WriteBytes(raw.fd(), {0x00, 0x01, 0x00, 0x01, 0x00, 0x06, 0x01, 0x03, 0x00, 0x00, 0x00, 0x01});
  uint8_t byte = 0;
  pollfd p{raw.fd(), POLLIN, 0};
  ASSERT_EQ(::poll(&p, 1, 20'000), 1);
  EXPECT_EQ(::read(raw.fd(), &byte, 1), 0) << "expected the server to close the connection";
  EXPECT_EQ(server->stats().framing_errors, 1U);
  EXPECT_TRUE(Eventually([&] { return server->stats().connections_open == 0; }));
}

// ---- RTU on a pty ------------------------------------------------------------------------------

class ModbusServerRtuTest : public ::testing::Test {
 protected:
  void SetUp() override {
    server_ = ModbusServer::ServeRtu(pty_.master_fd(), pty_.slave_path());
    line_ = ::open(pty_.slave_path().c_str(), O_RDWR | O_NOCTTY | O_CLOEXEC | O_NONBLOCK);
    ASSERT_GE(line_, 0);
  }
  void TearDown() override { ::close(line_); }

  PtyPair pty_;
  std::unique_ptr<ModbusServer> server_;
  int line_ = -1;  // the host's end of the line, for raw frames
};

TEST_F(ModbusServerRtuTest, AnswersItsUnitOnly) {
  server_->WithRegisters([](ModbusRegisterMap& m) { m.holding_registers[1] = 0x0102; });
  // A request for unit 2 and right behind it one for unit 1: only the second is answered, so the
  // first bytes that come back must be unit 1's answer.
  Bytes frames = WithCrc({0x02, 0x03, 0x00, 0x01, 0x00, 0x01});
  const Bytes mine = WithCrc({0x01, 0x03, 0x00, 0x01, 0x00, 0x01});
  frames.insert(frames.end(), mine.begin(), mine.end());
  WriteBytes(line_, frames);
  EXPECT_THAT(ReadBytes(line_, 7, milliseconds(5000)),
              ElementsAreArray(WithCrc({0x01, 0x03, 0x02, 0x01, 0x02})));
  EXPECT_EQ(server_->stats().ignored, 1U);
  EXPECT_EQ(server_->stats().replies, 1U);
}

TEST_F(ModbusServerRtuTest, BroadcastWriteIsExecutedAndNeverAnswered) {
  Bytes frames = WithCrc({0x00, 0x06, 0x00, 0x05, 0x00, 0x4D});      // broadcast write
  const Bytes read = WithCrc({0x00, 0x03, 0x00, 0x05, 0x00, 0x01});  // broadcast read: ignored
  const Bytes mine = WithCrc({0x01, 0x03, 0x00, 0x05, 0x00, 0x01});
  frames.insert(frames.end(), read.begin(), read.end());
  frames.insert(frames.end(), mine.begin(), mine.end());
  WriteBytes(line_, frames);
  EXPECT_THAT(ReadBytes(line_, 7, milliseconds(5000)),
              ElementsAreArray(WithCrc({0x01, 0x03, 0x02, 0x00, 0x4D})));
  const ModbusServerStats s = server_->stats();
  EXPECT_EQ(s.broadcasts, 1U);
  EXPECT_EQ(s.ignored, 1U);
  EXPECT_EQ(s.replies, 1U);
}

TEST_F(ModbusServerRtuTest, LineNoiseIsCountedAndAGoodFrameBehindItIsServed) {
  server_->WithRegisters([](ModbusRegisterMap& m) { m.holding_registers[0] = 0x0A0B; });
  Bytes frames = {0x01, 0x03, 0x00, 0x00, 0x00, 0x01, 0xFF, 0xFF, 0x37};  // bad CRC + a stray byte
  const Bytes mine = WithCrc({0x01, 0x03, 0x00, 0x00, 0x00, 0x01});
  frames.insert(frames.end(), mine.begin(), mine.end());
  WriteBytes(line_, frames);
  EXPECT_THAT(ReadBytes(line_, 7, milliseconds(5000)),
              ElementsAreArray(WithCrc({0x01, 0x03, 0x02, 0x0A, 0x0B})));
  EXPECT_GE(server_->stats().framing_errors, 1U);
  EXPECT_EQ(server_->stats().replies, 1U);
}

TEST_F(ModbusServerRtuTest, UnknownFunctionIsAnsweredWithIllegalFunctionAfterTheSilence) {
  WriteBytes(line_, WithCrc({0x01, 0x2B, 0x0E, 0x01, 0x00}));
  EXPECT_THAT(ReadBytes(line_, 5, milliseconds(5000)),
              ElementsAreArray(WithCrc({0x01, 0xAB, 0x01})));
}

TEST_F(ModbusServerRtuTest, TruncatedFrameIsDroppedAtTheSilence) {
  WriteBytes(line_, {0x01, 0x03, 0x00});
  ASSERT_TRUE(Eventually([&] { return server_->stats().framing_errors >= 1; }));
  auto client = ModbusClient::Open(server_->backend() + kPatient);
  uint16_t reg = 1;
  EXPECT_EQ(client->ReadHoldingRegisters(0, 1, &reg), std::error_code());
  EXPECT_EQ(reg, 0);
}

TEST_F(ModbusServerRtuTest, StopAnsweringSwallowsRequestsOnTheLineToo) {
  server_->StopAnswering(milliseconds::max());
  auto client = ModbusClient::Open(server_->backend() + ",timeout_ms=100,retries=1");
  uint16_t reg = 0;
  EXPECT_EQ(client->ReadHoldingRegisters(0, 1, &reg), Errc::kTimeout);
  EXPECT_TRUE(Eventually([&] { return server_->stats().swallowed == 2; }));
  EXPECT_EQ(server_->DropConnections(), 0) << "a serial line has no connection to drop";
  server_->ResumeAnswering();
  client.reset();
  auto patient = ModbusClient::Open(server_->backend() + kPatient);
  EXPECT_EQ(patient->ReadHoldingRegisters(0, 1, &reg), std::error_code());
}

TEST_F(ModbusServerRtuTest, StopLeavesTheMasterDescriptorOpen) {
  server_->Stop();
  EXPECT_NE(::fcntl(pty_.master_fd(), F_GETFD), -1);
  // A new server can serve the same line.
  server_ = ModbusServer::ServeRtu(pty_.master_fd(), pty_.slave_path());
  auto client = ModbusClient::Open(server_->backend() + kPatient);
  EXPECT_EQ(client->WriteRegister(3, 3), std::error_code());
}

}  // namespace
}  // namespace kinevis::hal
