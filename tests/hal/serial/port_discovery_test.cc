#include "hal/serial/port_discovery.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <algorithm>

#include "hal/serial/pty_pair.h"

namespace kinevis::hal {
namespace {

using ::testing::AnyOf;
using ::testing::Eq;
using ::testing::StartsWith;

// Whatever serial hardware the machine has (often none): listing works and every entry is well
// formed. Only invariants are checked, so the test holds on any machine.
TEST(PortDiscoveryTest, ListsWellFormedEntriesWithoutThrowing) {
  std::vector<SerialPortInfo> ports;
  ASSERT_NO_THROW(ports = ListSerialPorts());
  for (const SerialPortInfo& p : ports) {
    SCOPED_TRACE(p.path);
    EXPECT_THAT(p.path, StartsWith("/dev/"));
    struct stat st {};
    EXPECT_EQ(::stat(p.path.c_str(), &st), 0) << "listed port does not exist";
    EXPECT_THAT(p.transport, AnyOf(Eq("usb"), Eq("native"), Eq("bluetooth")));
    if (p.transport == "usb") {
      EXPECT_GE(p.usb_vid, -1);
      EXPECT_LE(p.usb_vid, 0xFFFF);
      EXPECT_GE(p.usb_pid, -1);
      EXPECT_LE(p.usb_pid, 0xFFFF);
    } else {
      EXPECT_EQ(p.usb_vid, -1);
      EXPECT_EQ(p.usb_pid, -1);
      EXPECT_EQ(p.serial_number, "");
    }
  }
  EXPECT_TRUE(std::is_sorted(
      ports.begin(), ports.end(),
      [](const SerialPortInfo& a, const SerialPortInfo& b) { return a.path < b.path; }));
}

// Pseudo-terminals have no /sys/class/tty device metadata: libserialport 0.1.1 does not list
// them, and kinevis does not require it to (simulators are reached by their path directly).
TEST(PortDiscoveryTest, ListingWorksWhileAPtyExists) {
  PtyPair pty;
  std::vector<SerialPortInfo> ports;
  ASSERT_NO_THROW(ports = ListSerialPorts());
  auto same_path = [](const SerialPortInfo& a, const SerialPortInfo& b) {
    return a.path == b.path;
  };
  EXPECT_EQ(std::adjacent_find(ports.begin(), ports.end(), same_path), ports.end())
      << "a port is listed twice";
}

}  // namespace
}  // namespace kinevis::hal
