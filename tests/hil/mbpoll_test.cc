// A third-party Modbus client, mbpoll (https://github.com/epsilonrt/mbpoll, Debian package
// "mbpoll"), against the project's ModbusServer on loopback TCP: proves that the server speaks
// Modbus TCP as other implementations understand it, not only as libmodbus' client does.

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <chrono>
#include <cinttypes>
#include <cstdint>
#include <cstdio>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "hal/modbus/modbus_server.h"
#include "tests/utilities/subprocess.h"

namespace kinevis::hal {
namespace {

using kinevis::testing::HaveProgram;
using kinevis::testing::ProcessResult;
using kinevis::testing::RunProcess;
using Value = std::pair<const int, int64_t>;  // reference, value
using ::testing::ElementsAre;

// mbpoll prints one line per value, "[REFERENCE]: \tVALUE", with the signed reading appended to
// registers above 32767 ("65535 (-1)"); returns reference -> unsigned value. (sscanf, not
// std::regex: GCC 12's <regex> trips -Wmaybe-uninitialized in the sanitizer build.)
std::map<int, int64_t> ParseValues(const std::string& out) {
  std::map<int, int64_t> values;
  std::istringstream lines(out);
  std::string line;
  while (std::getline(lines, line)) {
    int reference = 0;
    int64_t value = 0;
    if (std::sscanf(line.c_str(), "[%d]: %" SCNd64, &reference, &value) == 2) {
      values[reference] = value;
    }
  }
  return values;
}

class MbpollTest : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!HaveProgram("mbpoll")) GTEST_SKIP() << "mbpoll is not on PATH (apt install mbpoll)";
    server_ = ModbusServer::ListenTcp("127.0.0.1", 0);
  }

  // mbpoll over Modbus TCP to the server, unit 1, PDU (0-based) addressing, one poll only,
  // a 5 s timeout of its own; the whole run is bounded too.
  ProcessResult Mbpoll(const std::vector<std::string>& args) {
    std::vector<std::string> argv = {"mbpoll", "-m", "tcp", "-p", std::to_string(server_->port())};
    for (const char* option : {"-a", "1", "-0", "-1", "-o", "5"}) argv.emplace_back(option);
    argv.insert(argv.end(), args.begin(), args.end());
    return RunProcess(argv, std::chrono::seconds(30));
  }

  std::unique_ptr<ModbusServer> server_;
};

TEST_F(MbpollTest, ReadsHoldingRegistersFromTheServer) {
  server_->WithRegisters([](ModbusRegisterMap& m) {
    m.holding_registers[1] = 1234;
    m.holding_registers[2] = 0;
    m.holding_registers[3] = 65535;
    m.holding_registers[4] = 42;
  });
  ProcessResult r = Mbpoll({"-t", "4", "-r", "1", "-c", "4", "127.0.0.1"});
  ASSERT_FALSE(r.timed_out);
  ASSERT_EQ(r.exit_code, 0) << r.out << r.err;
  EXPECT_THAT(ParseValues(r.out),
              ElementsAre(Value(1, 1234), Value(2, 0), Value(3, 65535), Value(4, 42)))
      << r.out;
  EXPECT_EQ(server_->stats().replies, 1U);
}

TEST_F(MbpollTest, ReadsInputRegistersAndCoils) {
  server_->WithRegisters([](ModbusRegisterMap& m) {
    m.input_registers[10] = 7;
    m.input_registers[11] = 8;
    m.coils[5] = 1;
    m.coils[7] = 1;
  });
  ProcessResult regs = Mbpoll({"-t", "3", "-r", "10", "-c", "2", "127.0.0.1"});
  ASSERT_EQ(regs.exit_code, 0) << regs.out << regs.err;
  EXPECT_THAT(ParseValues(regs.out), ElementsAre(Value(10, 7), Value(11, 8)));
  ProcessResult coils = Mbpoll({"-t", "0", "-r", "5", "-c", "3", "127.0.0.1"});
  ASSERT_EQ(coils.exit_code, 0) << coils.out << coils.err;
  EXPECT_THAT(ParseValues(coils.out), ElementsAre(Value(5, 1), Value(6, 0), Value(7, 1)));
}

TEST_F(MbpollTest, WriteByMbpollIsSeenInTheServersMap) {
  std::vector<std::pair<int, int>> writes;  // (function, address), seen by the write hook
  server_->SetWriteHook([&writes](const ModbusRequest& r, ModbusRegisterMap&) {
    writes.emplace_back(r.function, r.address);
  });
  ProcessResult r = Mbpoll({"-t", "4", "-r", "20", "127.0.0.1", "111", "222", "333"});
  ASSERT_FALSE(r.timed_out);
  ASSERT_EQ(r.exit_code, 0) << r.out << r.err;
  server_->WithRegisters([&](ModbusRegisterMap& m) {
    EXPECT_THAT(
        std::vector<uint16_t>(m.holding_registers.begin() + 20, m.holding_registers.begin() + 23),
        ElementsAre(111, 222, 333));
    ASSERT_EQ(writes.size(), 1U);
    EXPECT_EQ(writes[0].first, 0x10);  // one Write Multiple Registers
    EXPECT_EQ(writes[0].second, 20);
  });
}

TEST_F(MbpollTest, ExceptionFromTheServerMakesMbpollFail) {
  // Registers 0..255 exist; 300 does not.
  ProcessResult r = Mbpoll({"-t", "4", "-r", "300", "-c", "1", "127.0.0.1"});
  ASSERT_FALSE(r.timed_out);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_THAT(r.out + r.err, ::testing::ContainsRegex("[Ii]llegal data address"));
  EXPECT_EQ(server_->stats().exceptions, 1U);
}

}  // namespace
}  // namespace kinevis::hal
