#include "hal/serial/termios_serial_port.h"

// termios2 for checking the line settings the port applied (see termios_serial_port.cc for why
// not <termios.h>).
#include <asm/termbits.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sys/ioctl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <string>
#include <thread>
#include <vector>

#include "hal/common/error.h"
#include "hal/serial/pty_pair.h"

namespace kinevis::hal {
namespace {

using namespace std::chrono_literals;
using std::chrono::microseconds;
using ::testing::ContainsRegex;

constexpr microseconds kDeadline = 5s;  // bound for things that take microseconds

std::unique_ptr<SerialPort> OpenSlave(const PtyPair& pty, int baud = 115200) {
  SerialSettings settings;
  settings.device = pty.slave_path();
  settings.baud = baud;
  return OpenSerialPort(settings);
}

std::error_code Write(SerialPort* port, const std::string& bytes) {
  return port->WriteAll(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size(), kDeadline);
}

// Reads exactly n bytes, or fewer if the port fails or the deadline passes.
std::string ReadBytes(SerialPort* port, size_t n) {
  std::string out;
  const auto end = std::chrono::steady_clock::now() + kDeadline;
  while (out.size() < n && std::chrono::steady_clock::now() < end) {
    uint8_t buffer[4096];
    size_t got = 0;
    if (port->Read(buffer, std::min(sizeof buffer, n - out.size()), 100ms, &got)) {
      if (got == 0) continue;
    }
    out.append(reinterpret_cast<char*>(buffer), got);
  }
  return out;
}

termios2 SlaveSettings(const PtyPair& pty) {
  // On a pty master, TCGETS2 reports the slave's settings.
  termios2 tio{};
  EXPECT_EQ(::ioctl(pty.master_fd(), TCGETS2, &tio), 0) << ErrnoText(errno);
  return tio;
}

TEST(TermiosSerialPortTest, CarriesEveryByteValueBothWays) {
  PtyPair pty;
  auto host = OpenSlave(pty);
  auto device = pty.MasterPort();
  std::string all;
  for (int b = 0; b < 256; ++b) all += static_cast<char>(b);  // raw: \r, \n, ^C, ^S pass as is
  ASSERT_FALSE(Write(host.get(), all));
  EXPECT_EQ(ReadBytes(device.get(), all.size()), all);
  ASSERT_FALSE(Write(device.get(), all));
  EXPECT_EQ(ReadBytes(host.get(), all.size()), all);
  EXPECT_EQ(host->name(), "tty:" + pty.slave_path());
  EXPECT_EQ(host->settings().device, pty.slave_path());
}

TEST(TermiosSerialPortTest, ReadReturnsTimeoutAfterTheTimeout) {
  PtyPair pty;
  auto host = OpenSlave(pty);
  uint8_t b;
  size_t n = 99;
  const auto start = std::chrono::steady_clock::now();
  EXPECT_EQ(host->Read(&b, 1, 100ms, &n), Errc::kTimeout);
  const auto elapsed = std::chrono::steady_clock::now() - start;
  EXPECT_EQ(n, 0u);
  EXPECT_GE(elapsed, 95ms);
  EXPECT_LT(elapsed, 10s);  // a bound against hanging, not a speed requirement
  EXPECT_EQ(host->Read(&b, 1, 0us, &n), Errc::kTimeout);
}

TEST(TermiosSerialPortTest, ReadReturnsWhatHasArrivedWithoutWaitingForMore) {
  PtyPair pty;
  auto host = OpenSlave(pty);
  auto device = pty.MasterPort();
  ASSERT_FALSE(Write(device.get(), "abc"));
  uint8_t buffer[64];
  size_t n = 0;
  ASSERT_FALSE(host->Read(buffer, sizeof buffer, kDeadline, &n));
  EXPECT_GE(n, 1u);
  EXPECT_LE(n, 3u);
  EXPECT_EQ(buffer[0], 'a');
}

TEST(TermiosSerialPortTest, AcceptsANonStandardBaudRateThroughBother) {
  PtyPair pty;
  auto host = OpenSlave(pty, 123457);
  const termios2 tio = SlaveSettings(pty);
  EXPECT_EQ(tio.c_cflag & CBAUD, static_cast<tcflag_t>(BOTHER));
  EXPECT_EQ(tio.c_ospeed, 123457u);
  EXPECT_EQ(tio.c_ispeed, 123457u);
  EXPECT_EQ(host->settings().baud, 123457);
}

TEST(TermiosSerialPortTest, AppliesRawModeAndTheFrameFormat) {
  PtyPair pty;
  SerialSettings settings;
  settings.device = pty.slave_path();
  settings.baud = 1'000'000;
  settings.data_bits = 7;
  settings.parity = 'O';
  settings.stop_bits = 2;
  auto host = OpenSerialPort(settings);
  const termios2 tio = SlaveSettings(pty);
  // The pty driver forces CS8 and clears PARENB (it is not a real line), so only the odd-parity
  // and stop-bit flags show what was asked for.
  EXPECT_NE(tio.c_cflag & PARODD, 0u);
  EXPECT_NE(tio.c_cflag & CSTOPB, 0u);
  EXPECT_NE(tio.c_iflag & INPCK, 0u);
  EXPECT_EQ(tio.c_lflag & (ICANON | ECHO | ISIG), 0u);
  EXPECT_EQ(tio.c_iflag & (ICRNL | IXON), 0u);
  EXPECT_EQ(tio.c_oflag & OPOST, 0u);
  EXPECT_EQ(tio.c_ospeed, 1'000'000u);
}

TEST(TermiosSerialPortTest, MissingDeviceThrowsNamingThePathAndTheErrno) {
  SerialSettings settings;
  settings.device = "/dev/kinevis-no-such-tty";
  try {
    OpenSerialPort(settings);
    FAIL() << "no HalError";
  } catch (const HalError& e) {
    EXPECT_THAT(e.what(), ContainsRegex("^tty:/dev/kinevis-no-such-tty: open "
                                        "/dev/kinevis-no-such-tty failed: No such file or "
                                        "directory \\(ENOENT\\)"));
    EXPECT_EQ(e.code(), std::errc::no_such_file_or_directory);
    EXPECT_EQ(e.device(), "tty:/dev/kinevis-no-such-tty");
  }
}

TEST(TermiosSerialPortTest, NonTerminalThrowsSayingItIsNotASerialPort) {
  SerialSettings settings;
  settings.device = "/dev/null";
  try {
    OpenSerialPort(settings, "my-servo");
    FAIL() << "no HalError";
  } catch (const HalError& e) {
    EXPECT_THAT(e.what(), ContainsRegex("^my-servo: read line settings \\(TCGETS2\\) failed: .*"
                                        "\\(ENOTTY\\); is /dev/null a serial port\\?"));
  }
}

TEST(TermiosSerialPortTest, Rs485OnAPtyThrowsUnsupported) {
  PtyPair pty;
  SerialSettings settings;
  settings.device = pty.slave_path();
  settings.rs485 = true;
  try {
    OpenSerialPort(settings);
    FAIL() << "no HalError";
  } catch (const HalError& e) {
    EXPECT_THAT(e.what(), ContainsRegex("enable RS485 direction control \\(TIOCSRS485\\) failed: "
                                        ".*no kernel RS485 support"));
    EXPECT_EQ(e.code(), Errc::kUnsupported);
  }
  settings.rs485 = false;
  EXPECT_NO_THROW(OpenSerialPort(settings));  // the failed open left the tty free
}

TEST(TermiosSerialPortTest, PeerHangUpIsClosed) {
  auto pty = std::make_unique<PtyPair>();
  auto host = OpenSlave(*pty);
  pty.reset();  // the device side goes away (a USB adapter unplugged)
  uint8_t b;
  size_t n = 0;
  const auto start = std::chrono::steady_clock::now();
  EXPECT_EQ(host->Read(&b, 1, kDeadline, &n), Errc::kClosed);
  EXPECT_LT(std::chrono::steady_clock::now() - start, kDeadline);  // not a timeout
  EXPECT_EQ(Write(host.get(), "x"), Errc::kClosed);
}

TEST(TermiosSerialPortTest, SlaveCanBeOpenedAgainAfterClose) {
  PtyPair pty;
  auto device = pty.MasterPort();
  {
    auto host = OpenSlave(pty);
    ASSERT_FALSE(Write(host.get(), "1"));
    EXPECT_EQ(ReadBytes(device.get(), 1), "1");
  }
  // The pair keeps its own slave descriptor: the master sees no hang-up ...
  uint8_t b;
  size_t n = 0;
  EXPECT_EQ(device->Read(&b, 1, 50ms, &n), Errc::kTimeout);
  // ... and the exclusive claim of the first open was released (EBUSY otherwise, for non-root).
  auto host = OpenSlave(pty);
  ASSERT_FALSE(Write(host.get(), "2"));
  EXPECT_EQ(ReadBytes(device.get(), 1), "2");
}

TEST(TermiosSerialPortTest, WritesLargeBlocksWhileTheOtherSideReads) {
  PtyPair pty;
  auto host = OpenSlave(pty);
  auto device = pty.MasterPort();
  std::string block(256 * 1024, '\0');
  for (size_t i = 0; i < block.size(); ++i) block[i] = static_cast<char>(i * 7 + i / 251);
  std::string received;
  std::thread reader([&] { received = ReadBytes(device.get(), block.size()); });
  EXPECT_FALSE(host->WriteAll(reinterpret_cast<const uint8_t*>(block.data()), block.size(), 20s));
  reader.join();
  EXPECT_TRUE(received == block) << "received " << received.size() << " of " << block.size();
}

TEST(TermiosSerialPortTest, WriteTimesOutWhenNobodyReads) {
  PtyPair pty;
  auto host = OpenSlave(pty);
  const std::string block(1 << 20, 'x');  // far more than a pty buffers
  const auto start = std::chrono::steady_clock::now();
  EXPECT_EQ(host->WriteAll(reinterpret_cast<const uint8_t*>(block.data()), block.size(), 100ms),
            Errc::kTimeout);
  EXPECT_LT(std::chrono::steady_clock::now() - start, 10s);
}

TEST(TermiosSerialPortTest, FlushInputDiscardsUnreadBytes) {
  PtyPair pty;
  auto host = OpenSlave(pty);
  auto device = pty.MasterPort();
  ASSERT_FALSE(Write(device.get(), "abc"));
  ASSERT_EQ(ReadBytes(host.get(), 1), "a");  // "bc" have arrived and wait unread
  ASSERT_FALSE(host->FlushInput());
  uint8_t b;
  size_t n = 0;
  EXPECT_EQ(host->Read(&b, 1, 50ms, &n), Errc::kTimeout);
  ASSERT_FALSE(Write(device.get(), "d"));
  EXPECT_EQ(ReadBytes(host.get(), 1), "d");
}

TEST(PtyPairTest, CreateLinkMakesAndRemovesTheSymlink) {
  const std::string link = ::testing::TempDir() + "kinevis-pty-link-" + std::to_string(::getpid());
  ASSERT_EQ(::symlink("/nonexistent", link.c_str()), 0);  // a stale link is replaced
  {
    PtyPair pty;
    pty.CreateLink(link);
    char target[256] = {};
    ASSERT_GT(::readlink(link.c_str(), target, sizeof target - 1), 0);
    EXPECT_EQ(std::string(target), pty.slave_path());
    SerialSettings settings;
    settings.device = link;  // the host opens the link as it would /dev/ttyUSB0
    auto host = OpenSerialPort(settings);
    auto device = pty.MasterPort();
    ASSERT_FALSE(Write(host.get(), "via link"));
    EXPECT_EQ(ReadBytes(device.get(), 8), "via link");
  }
  struct stat st {};
  EXPECT_NE(::lstat(link.c_str(), &st), 0);
  EXPECT_EQ(errno, ENOENT);
}

TEST(PtyPairTest, CreateLinkInAMissingDirectoryThrows) {
  PtyPair pty;
  try {
    pty.CreateLink("/nonexistent-dir/kinevis-link");
    FAIL() << "no HalError";
  } catch (const HalError& e) {
    EXPECT_THAT(e.what(), ContainsRegex("create link /nonexistent-dir/kinevis-link failed: .*"
                                        "ENOENT"));
  }
}

}  // namespace
}  // namespace kinevis::hal
