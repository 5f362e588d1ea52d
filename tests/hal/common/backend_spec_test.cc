#include "hal/common/backend_spec.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "hal/common/error.h"

namespace kinevis::hal {
namespace {

using ::testing::ContainsRegex;

// Runs `fn`, expects a ConfigError and returns its message.
template <typename Fn>
std::string ConfigErrorOf(Fn fn) {
  try {
    fn();
  } catch (const common::ConfigError& e) {
    return e.what();
  }
  ADD_FAILURE() << "no ConfigError thrown";
  return {};
}

TEST(BackendSpecTest, SocketCan) {
  CanBackendSpec s = ParseCanBackend("socketcan:can0");
  EXPECT_EQ(s.kind, CanBackendSpec::Kind::kSocketCan);
  EXPECT_EQ(s.interface, "can0");
  EXPECT_EQ(s.text, "socketcan:can0");
}

TEST(BackendSpecTest, SlcanWithAllOptions) {
  CanBackendSpec s = ParseCanBackend("slcan:/dev/ttyACM0@1000000,bitrate=500000,listen,timestamps");
  EXPECT_EQ(s.kind, CanBackendSpec::Kind::kSlcan);
  EXPECT_EQ(s.serial.device, "/dev/ttyACM0");
  EXPECT_EQ(s.serial.baud, 1000000);
  EXPECT_EQ(s.bitrate, 500000);
  EXPECT_TRUE(s.listen_only);
  EXPECT_TRUE(s.timestamps);
}

TEST(BackendSpecTest, VirtualWithAndWithoutBitrate) {
  EXPECT_EQ(ParseCanBackend("virtual:hexapod").interface, "hexapod");
  EXPECT_EQ(ParseCanBackend("virtual:hexapod").bitrate, 0);
  EXPECT_EQ(ParseCanBackend("virtual:x,bitrate=1000000").bitrate, 1000000);
}

TEST(BackendSpecTest, TtyFrameFormatAndRs485) {
  SerialSettings s = ParseTtyBackend("tty:/dev/ttyUSB0@3000000,8N1,rs485");
  EXPECT_EQ(s.device, "/dev/ttyUSB0");
  EXPECT_EQ(s.baud, 3000000);
  EXPECT_EQ(s.data_bits, 8);
  EXPECT_EQ(s.parity, 'N');
  EXPECT_EQ(s.stop_bits, 1);
  EXPECT_TRUE(s.rs485);
  SerialSettings t = ParseTtyBackend("tty:/dev/ttyS1@9600,7O2");
  EXPECT_EQ(t.data_bits, 7);
  EXPECT_EQ(t.parity, 'O');
  EXPECT_EQ(t.stop_bits, 2);
  EXPECT_FALSE(t.rs485);
  EXPECT_EQ(ParseTtyBackend("tty:/dev/ttyS1").baud, 115200);
}

TEST(BackendSpecTest, ModbusTcp) {
  ModbusBackendSpec s = ParseModbusBackend("modbus-tcp:192.168.0.10:502,unit=3,timeout_ms=50");
  EXPECT_EQ(s.kind, ModbusBackendSpec::Kind::kTcp);
  EXPECT_EQ(s.host, "192.168.0.10");
  EXPECT_EQ(s.port, 502);
  EXPECT_EQ(s.unit, 3);
  EXPECT_EQ(s.timeout_ms, 50);
  ModbusBackendSpec v6 = ParseModbusBackend("modbus-tcp:[::1]:1502");
  EXPECT_EQ(v6.host, "::1");
  EXPECT_EQ(v6.port, 1502);
}

TEST(BackendSpecTest, ModbusRtuDefaultsTo8E1) {
  ModbusBackendSpec s = ParseModbusBackend("modbus-rtu:/dev/ttyUSB1@115200,unit=1");
  EXPECT_EQ(s.kind, ModbusBackendSpec::Kind::kRtu);
  EXPECT_EQ(s.serial.device, "/dev/ttyUSB1");
  EXPECT_EQ(s.serial.parity, 'E');
  ModbusBackendSpec n = ParseModbusBackend("modbus-rtu:/dev/ttyUSB1@115200,8N2,rs485,retries=0");
  EXPECT_EQ(n.serial.parity, 'N');
  EXPECT_EQ(n.serial.stop_bits, 2);
  EXPECT_TRUE(n.serial.rs485);
  EXPECT_EQ(n.retries, 0);
}

TEST(BackendSpecTest, MissingSchemeNamesTheChoices) {
  EXPECT_THAT(ConfigErrorOf([] { ParseCanBackend("can0"); }),
              ContainsRegex("backend \"can0\": no scheme.*socketcan, slcan, virtual"));
}

TEST(BackendSpecTest, WrongSchemeForTheDevice) {
  EXPECT_THAT(ConfigErrorOf([] { ParseCanBackend("tty:/dev/ttyUSB0"); }),
              ContainsRegex("scheme \"tty\" is not a CAN backend"));
  EXPECT_THAT(ConfigErrorOf([] { ParseModbusBackend("socketcan:can0"); }),
              ContainsRegex("not a Modbus backend"));
}

TEST(BackendSpecTest, EveryBadFieldIsNamedInOneMessage) {
  std::string m = ConfigErrorOf([] { ParseTtyBackend("tty:/dev/ttyUSB0@fast,9X1,bogus"); });
  EXPECT_THAT(m, ContainsRegex("baud rate \"fast\""));
  EXPECT_THAT(m, ContainsRegex("frame format \"9X1\""));
  EXPECT_THAT(m, ContainsRegex("unknown option \"bogus\""));
}

TEST(BackendSpecTest, SlcanBitrateMustHaveALawicelCode) {
  EXPECT_THAT(ConfigErrorOf([] { ParseCanBackend("slcan:/dev/ttyACM0,bitrate=333333"); }),
              ContainsRegex("bitrate 333333 has no Lawicel code"));
  EXPECT_EQ(SlcanBitrateCode(10000), 0);
  EXPECT_EQ(SlcanBitrateCode(500000), 6);
  EXPECT_EQ(SlcanBitrateCode(1000000), 8);
  EXPECT_EQ(SlcanBitrateCode(12345), -1);
}

TEST(BackendSpecTest, BadValues) {
  EXPECT_THAT(ConfigErrorOf([] { ParseModbusBackend("modbus-tcp:localhost"); }),
              ContainsRegex("has no port"));
  EXPECT_THAT(ConfigErrorOf([] { ParseModbusBackend("modbus-tcp:localhost:70000"); }),
              ContainsRegex("port \"70000\" is not an integer in 1..65535"));
  EXPECT_THAT(ConfigErrorOf([] { ParseModbusBackend("modbus-tcp:h:502,unit=300"); }),
              ContainsRegex("unit \"300\""));
  EXPECT_THAT(ConfigErrorOf([] { ParseModbusBackend("modbus-tcp:h:502,8E1"); }),
              ContainsRegex("unknown option \"8E1\""));
  EXPECT_THAT(ConfigErrorOf([] { ParseCanBackend("socketcan:this-name-is-too-long"); }),
              ContainsRegex("interface name"));
  EXPECT_THAT(ConfigErrorOf([] { ParseCanBackend("virtual:"); }), ContainsRegex("name is empty"));
  EXPECT_THAT(ConfigErrorOf([] { ParseCanBackend("virtual:x,bitrate=2000000"); }),
              ContainsRegex("bitrate \"2000000\""));
  EXPECT_THAT(ConfigErrorOf([] { ParseTtyBackend("tty:@9600"); }),
              ContainsRegex("device path is empty"));
}

TEST(BackendSpecTest, SchemeOf) {
  EXPECT_EQ(BackendScheme("modbus-rtu:/dev/x"), "modbus-rtu");
  EXPECT_THROW(BackendScheme(":x"), common::ConfigError);
}

}  // namespace
}  // namespace kinevis::hal
