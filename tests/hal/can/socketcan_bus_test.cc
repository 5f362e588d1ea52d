#include "hal/can/socketcan_bus.h"

#include <fcntl.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <linux/can.h>
#include <linux/can/error.h>
#include <net/if.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

#include "common/clock.h"
#include "hal/common/error.h"
#include "tests/utilities/subprocess.h"

namespace kinevis::hal {
namespace {

using std::chrono::microseconds;
using std::chrono::milliseconds;
using ::testing::ContainsRegex;

using Bytes = std::vector<uint8_t>;

common::Duration Now() { return common::SteadyClock::Instance().Now(); }

// A SocketCanBus on one end of a SOCK_SEQPACKET socketpair; the test plays the kernel on the
// other end, reading and writing struct can_frame records.
class SocketpairBusTest : public ::testing::Test {
 protected:
  void SetUp() override { Connect({}); }
  void TearDown() override {
    if (peer_ >= 0) ::close(peer_);
  }

  void Connect(const SocketCanOptions& options) {
    if (peer_ >= 0) ::close(peer_);
    bus_.reset();
    int fds[2];
    ASSERT_EQ(::socketpair(AF_UNIX, SOCK_SEQPACKET | SOCK_CLOEXEC, 0, fds), 0)
        << std::strerror(errno);
    bus_ = SocketCanBus::FromDescriptor(fds[0], "test:socketpair", options);
    peer_ = fds[1];
  }

  // Writes one record as the kernel would deliver it.
  void Inject(uint32_t can_id, uint8_t dlc, std::array<uint8_t, 8> data = {}) {
    can_frame record;
    std::memset(&record, 0, sizeof record);
    record.can_id = can_id;
    record.can_dlc = dlc;
    std::memcpy(record.data, data.data(), 8);
    ASSERT_EQ(::write(peer_, &record, sizeof record), static_cast<ssize_t>(sizeof record));
  }
  void InjectError(uint32_t error_class, std::array<uint8_t, 8> data = {}) {
    Inject(CAN_ERR_FLAG | error_class, CAN_ERR_DLC, data);
  }
  void InjectBytes(const Bytes& bytes) {
    ASSERT_EQ(::send(peer_, bytes.data(), bytes.size(), 0), static_cast<ssize_t>(bytes.size()));
  }

  // The next record the bus wrote, or an empty vector when none arrives within `timeout`.
  Bytes ReadPeer(milliseconds timeout = milliseconds(1000)) {
    pollfd p{peer_, POLLIN, 0};
    if (::poll(&p, 1, static_cast<int>(timeout.count())) <= 0) return {};
    Bytes buffer(64);
    ssize_t n = ::read(peer_, buffer.data(), buffer.size());
    buffer.resize(n > 0 ? static_cast<size_t>(n) : 0);
    return buffer;
  }

  // Receives expecting success.
  CanFrame MustReceive(milliseconds timeout = milliseconds(1000)) {
    CanFrame frame;
    std::error_code ec = bus_->Receive(&frame, timeout);
    EXPECT_FALSE(ec) << ec.message();
    return frame;
  }

  std::vector<CanErrorEvent> TakeEvents() {
    std::vector<CanErrorEvent> events;
    CanErrorEvent e;
    while (bus_->TakeErrorEvent(&e)) events.push_back(e);
    return events;
  }

  std::unique_ptr<SocketCanBus> bus_;
  int peer_ = -1;
};

bool LittleEndian() { return __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__; }

TEST_F(SocketpairBusTest, ToleratesSocketOptionsTheSocketpairRefuses) {
  SocketCanFeatures f = bus_->features();
  EXPECT_FALSE(f.kernel_filters);  // CAN_RAW_FILTER is not an AF_UNIX option
  EXPECT_FALSE(f.error_frames);    // nor CAN_RAW_ERR_FILTER
  EXPECT_TRUE(f.timestamps);       // SO_TIMESTAMPNS is generic
  EXPECT_EQ(bus_->name(), "test:socketpair");
  EXPECT_EQ(bus_->interface(), "");
  EXPECT_EQ(bus_->state(), CanBusState::kErrorActive);
  EXPECT_NE(::fcntl(bus_->fd(), F_GETFL) & O_NONBLOCK, 0);
  EXPECT_NE(::fcntl(bus_->fd(), F_GETFD) & FD_CLOEXEC, 0);
}

// struct can_frame as the kernel reads it (linux/can.h): can_id in host order with EFF (bit 31)
// and RTR (bit 30) flags, can_dlc, three zero bytes (__pad, __res0, len8_dlc), 8 data bytes.
TEST_F(SocketpairBusTest, SendWritesTheKernelFrameLayout) {
  if (!LittleEndian()) GTEST_SKIP() << "byte vectors are written for a little-endian host";
  CanFrame rtr_std = CanFrame::Standard(0x7FF);
  rtr_std.rtr = true;
  rtr_std.dlc = 4;
  CanFrame rtr_ext = CanFrame::Extended(0x1FFFFFFF);
  rtr_ext.rtr = true;
  struct Case {
    CanFrame frame;
    Bytes bytes;
  };
  const Case cases[] = {
      {CanFrame::Standard(0x123, {0xDE, 0xAD, 0xBE, 0xEF}),
       {0x23, 0x01, 0x00, 0x00, 4, 0, 0, 0, 0xDE, 0xAD, 0xBE, 0xEF, 0, 0, 0, 0}},
      {CanFrame::Extended(0x12345678, {1, 2, 3, 4, 5, 6, 7, 8}),
       {0x78, 0x56, 0x34, 0x92, 8, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8}},
      {CanFrame::Extended(0x0, {0xFF}),
       {0x00, 0x00, 0x00, 0x80, 1, 0, 0, 0, 0xFF, 0, 0, 0, 0, 0, 0, 0}},
      {rtr_std, {0xFF, 0x07, 0x00, 0x40, 4, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0}},
      {rtr_ext, {0xFF, 0xFF, 0xFF, 0xDF, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0}},
  };
  for (const Case& c : cases) {
    ASSERT_FALSE(bus_->Send(c.frame)) << FormatCanFrame(c.frame);
    EXPECT_EQ(ReadPeer(), c.bytes) << FormatCanFrame(c.frame);
  }
  EXPECT_EQ(bus_->counters().tx_frames, 5u);
  EXPECT_EQ(bus_->counters().tx_errors, 0u);
}

TEST_F(SocketpairBusTest, RemoteFrameDoesNotLeakItsDataBytes) {
  CanFrame f = CanFrame::Standard(0x100, {1, 2, 3});
  f.rtr = true;
  ASSERT_FALSE(bus_->Send(f));
  Bytes bytes = ReadPeer();
  ASSERT_EQ(bytes.size(), 16u);
  EXPECT_EQ(bytes[4], 3);
  EXPECT_EQ(Bytes(bytes.begin() + 8, bytes.end()), Bytes(8, 0));
}

TEST_F(SocketpairBusTest, SendRefusesInvalidFramesWithoutWriting) {
  CanFrame too_long_id = CanFrame::Standard(0x100);
  too_long_id.id = 0x800;
  CanFrame too_long_dlc = CanFrame::Standard(0x100);
  too_long_dlc.dlc = 9;
  CanFrame ext_too_long = CanFrame::Extended(0x100);
  ext_too_long.id = 0x20000000;
  for (const CanFrame& f : {too_long_id, too_long_dlc, ext_too_long}) {
    EXPECT_EQ(bus_->Send(f), Errc::kInvalidArgument);
  }
  EXPECT_TRUE(ReadPeer(milliseconds(20)).empty());
  EXPECT_EQ(bus_->counters().tx_frames, 0u);
}

TEST_F(SocketpairBusTest, ReceivesStandardExtendedAndRemoteFrames) {
  Inject(0x123, 3, {0xAA, 0xBB, 0xCC});
  Inject(CAN_EFF_FLAG | 0x1ABCDEF0, 8, {1, 2, 3, 4, 5, 6, 7, 8});
  Inject(CAN_RTR_FLAG | 0x456, 2);
  Inject(CAN_EFF_FLAG | CAN_RTR_FLAG | 0x00000001, 0);

  CanFrame rtr_std = CanFrame::Standard(0x456);
  rtr_std.rtr = true;
  rtr_std.dlc = 2;
  CanFrame rtr_ext = CanFrame::Extended(0x1);
  rtr_ext.rtr = true;
  EXPECT_EQ(MustReceive(), CanFrame::Standard(0x123, {0xAA, 0xBB, 0xCC}));
  EXPECT_EQ(MustReceive(), CanFrame::Extended(0x1ABCDEF0, {1, 2, 3, 4, 5, 6, 7, 8}));
  CanFrame got = MustReceive();
  EXPECT_EQ(got, rtr_std);
  EXPECT_TRUE(got.rtr);
  EXPECT_FALSE(got.extended);
  got = MustReceive();
  EXPECT_EQ(got, rtr_ext);
  EXPECT_TRUE(got.extended);
  EXPECT_EQ(bus_->counters().rx_frames, 4u);
}

TEST_F(SocketpairBusTest, TimestampsAreKernelReceptionTimesOnTheSteadyClock) {
  ASSERT_TRUE(bus_->features().timestamps);
  const common::Duration before = Now();
  Inject(0x001, 0);
  std::this_thread::sleep_for(milliseconds(30));
  Inject(0x002, 0);
  std::this_thread::sleep_for(milliseconds(30));
  const common::Duration read_start = Now();
  CanFrame first = MustReceive();
  CanFrame second = MustReceive();
  const common::Duration after = Now();
  // Stamped when the records were written, not when they were read.
  EXPECT_GE(first.timestamp, before - milliseconds(1));
  EXPECT_GE(second.timestamp - first.timestamp, milliseconds(29));
  EXPECT_LT(second.timestamp, read_start - milliseconds(15));
  EXPECT_LE(second.timestamp, after);
}

TEST_F(SocketpairBusTest, TimestampsNeverDecrease) {
  for (int i = 0; i < 200; ++i) Inject(static_cast<uint32_t>(i), 0);
  common::Duration last{0};
  for (int i = 0; i < 200; ++i) {
    CanFrame f = MustReceive();
    ASSERT_EQ(f.id, static_cast<uint32_t>(i));
    ASSERT_GT(f.timestamp.count(), 0);
    ASSERT_GE(f.timestamp, last) << "frame " << i;
    last = f.timestamp;
  }
}

TEST_F(SocketpairBusTest, WithoutKernelTimestampsFramesAreStampedWhenRead) {
  const int off = 0;
  ASSERT_EQ(::setsockopt(bus_->fd(), SOL_SOCKET, SO_TIMESTAMPNS, &off, sizeof off), 0);
  Inject(0x001, 0);
  std::this_thread::sleep_for(milliseconds(30));
  const common::Duration read_start = Now();
  CanFrame f = MustReceive();
  EXPECT_GE(f.timestamp, read_start);
  EXPECT_LE(f.timestamp, Now());
}

struct ErrorFrameCase {
  const char* what;
  uint32_t error_class;
  std::array<uint8_t, 8> data;
  std::vector<CanErrorKind> kinds;
  CanBusState state;
  const char* detail_regex;  // matched against the first event's detail
};

// Every error class of linux/can/error.h that kinevis reports, one row each.
TEST_F(SocketpairBusTest, DecodesEveryErrorFrameClass) {
  const ErrorFrameCase cases[] = {
      {"bus-off",
       CAN_ERR_BUSOFF,
       {0, 0, 0, 0, 0, 0, 0xFF, 0},
       {CanErrorKind::kBusOff},
       CanBusState::kBusOff,
       "bus-off.*tx errors 255, rx errors 0"},
      {"rx warning",
       CAN_ERR_CRTL,
       {0, CAN_ERR_CRTL_RX_WARNING, 0, 0, 0, 0, 0, 96},
       {CanErrorKind::kErrorWarning},
       CanBusState::kErrorWarning,
       "rx error counter reached error-warning.*tx errors 0, rx errors 96"},
      {"tx warning",
       CAN_ERR_CRTL,
       {0, CAN_ERR_CRTL_TX_WARNING, 0, 0, 0, 0, 100, 0},
       {CanErrorKind::kErrorWarning},
       CanBusState::kErrorWarning,
       "tx error counter reached error-warning.*tx errors 100"},
      {"rx passive",
       CAN_ERR_CRTL,
       {0, CAN_ERR_CRTL_RX_PASSIVE, 0, 0, 0, 0, 0, 128},
       {CanErrorKind::kErrorPassive},
       CanBusState::kErrorPassive,
       "rx error counter reached error-passive.*rx errors 128"},
      {"tx passive",
       CAN_ERR_CRTL,
       {0, CAN_ERR_CRTL_TX_PASSIVE, 0, 0, 0, 0, 130, 0},
       {CanErrorKind::kErrorPassive},
       CanBusState::kErrorPassive,
       "tx error counter reached error-passive.*tx errors 130"},
      {"rx overflow",
       CAN_ERR_CRTL,
       {0, CAN_ERR_CRTL_RX_OVERFLOW, 0, 0, 0, 0, 0, 0},
       {CanErrorKind::kRxOverflow},
       CanBusState::kErrorActive,
       "receive buffer overflow"},
      {"tx overflow",
       CAN_ERR_CRTL,
       {0, CAN_ERR_CRTL_TX_OVERFLOW, 0, 0, 0, 0, 0, 0},
       {CanErrorKind::kRxOverflow},
       CanBusState::kErrorActive,
       "transmit buffer overflow"},
      {"protocol",
       CAN_ERR_PROT | CAN_ERR_BUSERROR,
       {0, 0, CAN_ERR_PROT_STUFF | CAN_ERR_PROT_TX, CAN_ERR_PROT_LOC_CRC_SEQ, 0, 0, 8, 0},
       {CanErrorKind::kProtocol},
       CanBusState::kErrorActive,
       "stuff error, on transmission at CRC sequence \\(type 0x84, location 0x08\\).*tx errors 8"},
      {"bus error without details",
       CAN_ERR_BUSERROR,
       {},
       {CanErrorKind::kProtocol},
       CanBusState::kErrorActive,
       "bus error"},
      {"transceiver",
       CAN_ERR_TRX,
       {0, 0, 0, 0, CAN_ERR_TRX_CANH_SHORT_TO_GND, 0, 0, 0},
       {CanErrorKind::kProtocol},
       CanBusState::kErrorActive,
       "transceiver: CANH short to ground \\(status 0x07\\)"},
      {"no ack",
       CAN_ERR_ACK,
       {0, 0, 0, 0, 0, 0, 0x18, 0},
       {CanErrorKind::kNoAck},
       CanBusState::kErrorActive,
       "no acknowledgement.*tx errors 24"},
      {"tx timeout",
       CAN_ERR_TX_TIMEOUT,
       {},
       {CanErrorKind::kTxTimeout},
       CanBusState::kErrorActive,
       "timed out"},
      {"restarted",
       CAN_ERR_RESTARTED,
       {},
       {CanErrorKind::kRestarted},
       CanBusState::kErrorActive,
       "restarted"},
      {"passive and bus-off together",
       CAN_ERR_CRTL | CAN_ERR_BUSOFF,
       {0, CAN_ERR_CRTL_TX_PASSIVE, 0, 0, 0, 0, 0xF8, 0},
       {CanErrorKind::kErrorPassive, CanErrorKind::kBusOff},
       CanBusState::kBusOff,
       "error-passive.*tx errors 248"},
  };
  for (const ErrorFrameCase& c : cases) {
    SCOPED_TRACE(c.what);
    Connect({});
    const common::Duration before = Now();
    InjectError(c.error_class, c.data);
    Inject(0x321, 1, {0x5A});  // error frames do not end the receive: this frame comes back
    EXPECT_EQ(MustReceive(), CanFrame::Standard(0x321, {0x5A}));
    std::vector<CanErrorEvent> events = TakeEvents();
    ASSERT_EQ(events.size(), c.kinds.size());
    for (size_t i = 0; i < events.size(); ++i) {
      EXPECT_EQ(events[i].kind, c.kinds[i]) << ToString(events[i].kind);
      EXPECT_GE(events[i].timestamp, before - milliseconds(1));
      EXPECT_LE(events[i].timestamp, Now());
    }
    EXPECT_THAT(events[0].detail, ContainsRegex(c.detail_regex));
    EXPECT_EQ(bus_->state(), c.state) << ToString(bus_->state());
    const CanCounters counters = bus_->counters();
    EXPECT_EQ(counters.error_events, c.kinds.size());
    EXPECT_EQ(counters.rx_frames, 1u);
    const bool bus_off = (c.error_class & CAN_ERR_BUSOFF) != 0;
    EXPECT_EQ(counters.bus_off_events, bus_off ? 1u : 0u);
    const bool rx_overflow = c.error_class == CAN_ERR_CRTL && c.data[1] == CAN_ERR_CRTL_RX_OVERFLOW;
    EXPECT_EQ(counters.rx_overflows, rx_overflow ? 1u : 0u);
  }
}

TEST_F(SocketpairBusTest, ArbitrationLossAndCounterOnlyFramesRaiseNoEvent) {
  InjectError(CAN_ERR_LOSTARB, {5, 0, 0, 0, 0, 0, 0, 0});
  InjectError(CAN_ERR_CNT, {0, 0, 0, 0, 0, 0, 12, 3});
  Inject(0x001, 0);
  MustReceive();
  EXPECT_TRUE(TakeEvents().empty());
  EXPECT_EQ(bus_->state(), CanBusState::kErrorActive);
  EXPECT_EQ(bus_->counters().error_events, 0u);
}

TEST_F(SocketpairBusTest, StateFollowsTheControllerThroughBusOffAndBack) {
  auto feed = [this](uint32_t error_class, std::array<uint8_t, 8> data) {
    InjectError(error_class, data);
    CanFrame f;
    EXPECT_EQ(bus_->Receive(&f, milliseconds(0)), Errc::kTimeout);
  };
  feed(CAN_ERR_CRTL, {0, CAN_ERR_CRTL_TX_WARNING, 0, 0, 0, 0, 96, 0});
  EXPECT_EQ(bus_->state(), CanBusState::kErrorWarning);
  feed(CAN_ERR_CRTL, {0, CAN_ERR_CRTL_TX_PASSIVE, 0, 0, 0, 0, 128, 0});
  EXPECT_EQ(bus_->state(), CanBusState::kErrorPassive);
  feed(CAN_ERR_CRTL, {0, CAN_ERR_CRTL_ACTIVE, 0, 0, 0, 0, 0, 0});
  EXPECT_EQ(bus_->state(), CanBusState::kErrorActive);
  feed(CAN_ERR_BUSOFF, {});
  EXPECT_EQ(bus_->state(), CanBusState::kBusOff);

  // Bus-off: sends are refused and nothing reaches the socket.
  EXPECT_EQ(bus_->Send(CanFrame::Standard(0x100, {1})), Errc::kBusOff);
  EXPECT_TRUE(ReadPeer(milliseconds(20)).empty());
  EXPECT_EQ(bus_->counters().tx_errors, 1u);

  feed(CAN_ERR_RESTARTED, {});
  EXPECT_EQ(bus_->state(), CanBusState::kErrorActive);
  EXPECT_FALSE(bus_->Send(CanFrame::Standard(0x100, {1})));
  EXPECT_EQ(ReadPeer().size(), 16u);

  std::vector<CanErrorKind> kinds;
  for (const CanErrorEvent& e : TakeEvents()) kinds.push_back(e.kind);
  EXPECT_EQ(kinds,
            (std::vector<CanErrorKind>{CanErrorKind::kErrorWarning, CanErrorKind::kErrorPassive,
                                       CanErrorKind::kBusOff, CanErrorKind::kRestarted}));
}

TEST_F(SocketpairBusTest, ErrorFramesAloneDoNotEndTheWait) {
  InjectError(CAN_ERR_ACK);
  CanFrame f;
  const common::Duration start = Now();
  EXPECT_EQ(bus_->Receive(&f, milliseconds(50)), Errc::kTimeout);
  EXPECT_GE(Now() - start, milliseconds(50));
  ASSERT_EQ(TakeEvents().size(), 1u);

  // An error frame, then a data frame later within the same deadline.
  std::thread peer([this] {
    InjectError(CAN_ERR_ACK);
    std::this_thread::sleep_for(milliseconds(30));
    Inject(0x055, 1, {0x01});
  });
  const std::error_code ec = bus_->Receive(&f, milliseconds(2000));
  peer.join();
  EXPECT_FALSE(ec) << ec.message();
  EXPECT_EQ(f, CanFrame::Standard(0x055, {0x01}));
  EXPECT_EQ(TakeEvents().size(), 1u);
}

TEST_F(SocketpairBusTest, KeepsOnlyTheNewestErrorEventsWhenNobodyTakesThem) {
  SocketCanOptions options;
  options.max_pending_error_events = 3;
  Connect(options);
  for (uint8_t tec = 1; tec <= 5; ++tec) InjectError(CAN_ERR_ACK, {0, 0, 0, 0, 0, 0, tec, 0});
  CanFrame f;
  EXPECT_EQ(bus_->Receive(&f, milliseconds(0)), Errc::kTimeout);
  std::vector<CanErrorEvent> events = TakeEvents();
  ASSERT_EQ(events.size(), 3u);
  EXPECT_THAT(events[0].detail, ContainsRegex("tx errors 3,"));
  EXPECT_THAT(events[2].detail, ContainsRegex("tx errors 5,"));
  EXPECT_EQ(bus_->counters().error_events, 5u);
  EXPECT_EQ(bus_->counters().tx_errors, 5u);  // every missing ACK is a failed transmission
}

TEST_F(SocketpairBusTest, FiltersInSoftwareWhenTheKernelCannot) {
  ASSERT_FALSE(bus_->features().kernel_filters);
  ASSERT_FALSE(bus_->SetFilters({CanFilter::Exact(0x123)}));
  Inject(0x100, 0);
  Inject(CAN_EFF_FLAG | 0x123, 0);  // same number, extended: does not match
  Inject(0x123, 1, {0x42});
  EXPECT_EQ(MustReceive(), CanFrame::Standard(0x123, {0x42}));
  EXPECT_EQ(bus_->counters().rx_filtered, 2u);

  // Any of several filters; an inverted one; one on the rtr flag.
  CanFilter not_0x7xx;
  not_0x7xx.id = 0x700;
  not_0x7xx.mask = 0x700;
  not_0x7xx.invert = true;
  CanFilter remote_only;
  remote_only.id = 0;
  remote_only.mask = 0;
  remote_only.rtr = true;
  remote_only.match_rtr = true;
  remote_only.match_extended = false;
  ASSERT_FALSE(bus_->SetFilters({not_0x7xx, remote_only}));
  Inject(0x701, 0);                 // dropped: 0x7xx and not remote
  Inject(CAN_RTR_FLAG | 0x702, 0);  // passes remote_only
  Inject(0x201, 0);                 // passes not_0x7xx
  CanFrame got = MustReceive();
  EXPECT_EQ(got.id, 0x702u);
  EXPECT_TRUE(got.rtr);
  EXPECT_EQ(MustReceive().id, 0x201u);
  EXPECT_EQ(bus_->counters().rx_filtered, 3u);

  // No filter passes everything again.
  ASSERT_FALSE(bus_->SetFilters({}));
  Inject(0x701, 0);
  EXPECT_EQ(MustReceive().id, 0x701u);
}

TEST_F(SocketpairBusTest, RejectsFiltersTheKernelCouldNotTake) {
  ASSERT_FALSE(bus_->SetFilters({CanFilter::Exact(0x123)}));
  CanFilter wide;
  wide.id = 0x20000000;
  wide.mask = 0x1FFFFFFF;
  EXPECT_EQ(bus_->SetFilters({wide}), Errc::kInvalidArgument);
  EXPECT_EQ(bus_->SetFilters(std::vector<CanFilter>(513, CanFilter::Exact(1))),
            Errc::kInvalidArgument);
  // The earlier filter still holds.
  Inject(0x100, 0);
  Inject(0x123, 0);
  EXPECT_EQ(MustReceive().id, 0x123u);
}

TEST_F(SocketpairBusTest, ReceiveTimesOutWithinTheDeadline) {
  CanFrame f;
  common::Duration start = Now();
  EXPECT_EQ(bus_->Receive(&f, milliseconds(50)), Errc::kTimeout);
  common::Duration elapsed = Now() - start;
  EXPECT_GE(elapsed, milliseconds(50));
  EXPECT_LT(elapsed, std::chrono::seconds(2));

  start = Now();
  EXPECT_EQ(bus_->Receive(&f, microseconds(0)), Errc::kTimeout);
  EXPECT_LT(Now() - start, std::chrono::seconds(2));
  EXPECT_EQ(bus_->Receive(&f, microseconds(-5)), Errc::kTimeout);
}

TEST_F(SocketpairBusTest, ZeroTimeoutStillReturnsAQueuedFrame) {
  Inject(0x010, 0);
  CanFrame f;
  EXPECT_FALSE(bus_->Receive(&f, microseconds(0)));
  EXPECT_EQ(f.id, 0x010u);
}

TEST_F(SocketpairBusTest, PeerCloseIsClosedAfterTheQueuedFrames) {
  Inject(0x001, 0);
  ::close(peer_);
  peer_ = -1;
  EXPECT_EQ(MustReceive().id, 0x001u);
  CanFrame f;
  const common::Duration start = Now();
  EXPECT_EQ(bus_->Receive(&f, std::chrono::seconds(5)), Errc::kClosed);
  EXPECT_LT(Now() - start, std::chrono::seconds(2));
  EXPECT_EQ(bus_->Send(CanFrame::Standard(0x001)), Errc::kClosed);
  EXPECT_EQ(bus_->counters().tx_errors, 1u);
}

TEST_F(SocketpairBusTest, PeerCloseWakesAWaitingReceive) {
  std::thread closer([this] {
    std::this_thread::sleep_for(milliseconds(30));
    ::close(peer_);
  });
  CanFrame f;
  const common::Duration start = Now();
  const std::error_code ec = bus_->Receive(&f, std::chrono::seconds(5));
  closer.join();
  peer_ = -1;
  EXPECT_EQ(ec, Errc::kClosed);
  EXPECT_LT(Now() - start, std::chrono::seconds(2));
}

TEST_F(SocketpairBusTest, UndecodableRecordsAreCountedAndSkipped) {
  InjectBytes(Bytes{0x23, 0x01, 0x00, 0x00, 0x01});  // short
  InjectBytes(Bytes(72, 0));                         // a CAN FD sized record
  InjectBytes(Bytes{});                              // empty record, peer still there
  Inject(0x123, 9);                                  // dlc over 8
  Inject(0x000007FF + 1, 0);                         // standard id over 11 bits
  Inject(0x7AB, 2, {0x01, 0x02});
  EXPECT_EQ(MustReceive(), CanFrame::Standard(0x7AB, {0x01, 0x02}));
  const CanCounters c = bus_->counters();
  EXPECT_EQ(c.decode_errors, 5u);
  EXPECT_EQ(c.rx_frames, 1u);
}

TEST_F(SocketpairBusTest, FullQueueIsAnOverflowAfterTheTxTimeout) {
  SocketCanOptions options;
  options.tx_timeout = milliseconds(20);
  Connect(options);
  // Nobody reads the peer: the socket's send buffer fills up.
  std::error_code ec;
  uint64_t sent = 0;
  common::Duration failed_after{0};
  for (int i = 0; i < 100000 && !ec; ++i) {
    const common::Duration start = Now();
    ec = bus_->Send(CanFrame::Standard(0x100, {static_cast<uint8_t>(i)}));
    if (!ec) {
      ++sent;
    } else {
      failed_after = Now() - start;
    }
  }
  ASSERT_EQ(ec, Errc::kOverflow);
  EXPECT_GT(sent, 0u);
  EXPECT_GE(failed_after, milliseconds(20));
  EXPECT_LT(failed_after, std::chrono::seconds(2));
  EXPECT_EQ(bus_->counters().tx_frames, sent);
  EXPECT_EQ(bus_->counters().tx_errors, 1u);

  // Once the reader drains the queue, a waiting Send gets through.
  SocketCanOptions patient;
  patient.tx_timeout = milliseconds(1000);
  Connect(patient);
  can_frame filler;
  std::memset(&filler, 0, sizeof filler);
  while (::send(bus_->fd(), &filler, sizeof filler, MSG_DONTWAIT) > 0) {
  }
  ASSERT_TRUE(errno == EAGAIN || errno == EWOULDBLOCK) << std::strerror(errno);
  std::atomic<int> drained{0};
  std::thread reader([this, &drained] {
    std::this_thread::sleep_for(milliseconds(30));
    char buffer[16];
    while (::recv(peer_, buffer, sizeof buffer, MSG_DONTWAIT) > 0) ++drained;
  });
  const common::Duration start = Now();
  ec = bus_->Send(CanFrame::Standard(0x201));
  const common::Duration waited = Now() - start;
  reader.join();
  EXPECT_FALSE(ec) << ec.message();
  EXPECT_GT(drained.load(), 0);
  EXPECT_LT(waited, std::chrono::seconds(1));
}

TEST_F(SocketpairBusTest, SendAndReceiveRunOnTwoThreads) {
  // The peer echoes every record back, as a loopback would.
  constexpr int kFrames = 2000;
  std::thread echo([this] {
    char buffer[16];
    for (int i = 0; i < kFrames; ++i) {
      pollfd p{peer_, POLLIN, 0};
      if (::poll(&p, 1, 5000) <= 0) return;
      ssize_t n = ::read(peer_, buffer, sizeof buffer);
      if (n != 16 || ::write(peer_, buffer, 16) != 16) return;
    }
  });
  std::atomic<int> received{0};
  std::thread receiver([this, &received] {
    CanFrame f;
    for (int i = 0; i < kFrames; ++i) {
      if (bus_->Receive(&f, std::chrono::seconds(5))) return;
      if (f.id != static_cast<uint32_t>(i % 0x800)) return;
      ++received;
    }
  });
  for (int i = 0; i < kFrames; ++i) {
    std::error_code ec;
    do {
      ec = bus_->Send(CanFrame::Standard(static_cast<uint32_t>(i % 0x800)));
    } while (ec == Errc::kOverflow);
    ASSERT_FALSE(ec) << ec.message();
  }
  receiver.join();
  echo.join();
  EXPECT_EQ(received.load(), kFrames);
  EXPECT_EQ(bus_->counters().rx_frames, static_cast<uint64_t>(kFrames));
}

TEST(SocketCanBusSetupTest, AdoptingABadDescriptorIsAHalError) {
  try {
    SocketCanBus::FromDescriptor(-1, "test:bad");
    FAIL() << "expected HalError";
  } catch (const HalError& e) {
    EXPECT_EQ(e.device(), "test:bad");
    EXPECT_THAT(e.what(), ContainsRegex("fd -1 is not an open descriptor"));
  }
}

TEST(SocketCanBusSetupTest, BadOptionsAreAConfigErrorAndTheDescriptorIsClosed) {
  int fds[2];
  ASSERT_EQ(::socketpair(AF_UNIX, SOCK_SEQPACKET, 0, fds), 0);
  SocketCanOptions options;
  options.tx_timeout = std::chrono::seconds(5);
  try {
    SocketCanBus::FromDescriptor(fds[0], "test:options", options);
    FAIL() << "expected ConfigError";
  } catch (const common::ConfigError& e) {
    EXPECT_THAT(e.what(), ContainsRegex("test:options: .*tx_timeout 5000000 us must be"));
  }
  EXPECT_EQ(::fcntl(fds[0], F_GETFD), -1);  // owned, and closed
  ::close(fds[1]);
}

TEST(SocketCanBusSetupTest, OpenRejectsBadInterfaceNames) {
  for (const char* iface : {"", "a_name_longer_than15", "can 0", "can/0"}) {
    EXPECT_THROW(SocketCanBus::Open(iface, "socketcan:x"), common::ConfigError) << iface;
  }
}

bool HavePfCan(std::string* why) {
  const int fd = ::socket(PF_CAN, SOCK_RAW, CAN_RAW);
  if (fd < 0) {
    *why = std::strerror(errno);
    return false;
  }
  ::close(fd);
  return true;
}

TEST(SocketCanBusSetupTest, OpenExplainsWhyItCannot) {
  std::string why;
  const bool pf_can = HavePfCan(&why);
  try {
    SocketCanBus::Open("kvnoexist0", "socketcan:kvnoexist0");
    FAIL() << "expected HalError";
  } catch (const HalError& e) {
    EXPECT_EQ(e.device(), "socketcan:kvnoexist0");
    EXPECT_EQ(e.operation(), "open");
    if (pf_can) {
      EXPECT_THAT(e.what(), ContainsRegex("no network interface \"kvnoexist0\".*`ip link`.*"
                                          "`ip link add dev vcan0 type vcan && ip link set up "
                                          "vcan0`"));
    } else {
      EXPECT_THAT(e.what(), ContainsRegex("interface \"kvnoexist0\": the kernel has no SocketCAN "
                                          "\\(PF_CAN\\) support"));
      EXPECT_EQ(e.code().value(), EAFNOSUPPORT);
    }
  }
}

// Removes a vcan interface this test created.
class VcanInterface {
 public:
  ~VcanInterface() {
    if (!created_.empty()) testing::RunProcess({"ip", "link", "del", "dev", created_});
  }
  // The interface to use, or empty with the reason in *why.
  std::string Acquire(std::string* why) {
    if (::if_nametoindex("vcan0") != 0) return "vcan0";
    if (::geteuid() != 0) {
      *why = "no vcan0 interface, and not root to create one";
      return "";
    }
    if (::if_nametoindex("kvcan0") != 0) return "kvcan0";
    testing::ProcessResult r = testing::RunProcess(
        {"sh", "-c", "ip link add dev kvcan0 type vcan && ip link set up kvcan0"},
        std::chrono::seconds(10));
    if (r.exit_code != 0) {
      *why = "cannot create vcan interface kvcan0: " + r.err;
      return "";
    }
    created_ = "kvcan0";
    return created_;
  }

 private:
  std::string created_;
};

TEST(SocketCanVcanTest, ExchangesFramesThroughTheKernel) {
  std::string why;
  if (!HavePfCan(&why)) GTEST_SKIP() << "PF_CAN not available: " << why;
  VcanInterface vcan;
  const std::string iface = vcan.Acquire(&why);
  if (iface.empty()) GTEST_SKIP() << why;

  std::unique_ptr<SocketCanBus> a = SocketCanBus::Open(iface, "socketcan:" + iface + "#a");
  std::unique_ptr<SocketCanBus> b = SocketCanBus::Open(iface, "socketcan:" + iface + "#b");
  EXPECT_EQ(a->interface(), iface);
  const SocketCanFeatures f = b->features();
  EXPECT_TRUE(f.kernel_filters);
  EXPECT_TRUE(f.error_frames);
  EXPECT_TRUE(f.timestamps);
  EXPECT_TRUE(f.drop_counts);

  CanFrame rtr = CanFrame::Extended(0x1ABCDE);
  rtr.rtr = true;
  rtr.dlc = 2;
  const std::vector<CanFrame> frames = {CanFrame::Standard(0x123, {1, 2, 3}),
                                        CanFrame::Extended(0x12345678, {8, 7, 6, 5, 4, 3, 2, 1}),
                                        rtr};
  const common::Duration before = Now();
  for (const CanFrame& frame : frames) ASSERT_FALSE(a->Send(frame));
  for (const CanFrame& frame : frames) {
    CanFrame got;
    ASSERT_FALSE(b->Receive(&got, milliseconds(1000)));
    EXPECT_EQ(got, frame);
    EXPECT_GE(got.timestamp, before - milliseconds(1));
    EXPECT_LE(got.timestamp, Now());
  }
  // The sender does not receive its own frames (CAN_RAW_RECV_OWN_MSGS is off).
  CanFrame own;
  EXPECT_EQ(a->Receive(&own, milliseconds(20)), Errc::kTimeout);

  // A kernel filter: the unwanted frame never reaches the socket.
  ASSERT_FALSE(b->SetFilters({CanFilter::Exact(0x200)}));
  ASSERT_TRUE(b->features().kernel_filters);
  ASSERT_FALSE(a->Send(CanFrame::Standard(0x123)));
  ASSERT_FALSE(a->Send(CanFrame::Standard(0x200, {0xAA})));
  CanFrame got;
  ASSERT_FALSE(b->Receive(&got, milliseconds(1000)));
  EXPECT_EQ(got, CanFrame::Standard(0x200, {0xAA}));
  EXPECT_EQ(b->counters().rx_filtered, 0u);
  EXPECT_EQ(b->Receive(&got, milliseconds(20)), Errc::kTimeout);

  // A full receive queue: the kernel counts the drops and the bus reports them.
  ASSERT_FALSE(b->SetFilters({}));
  const int small = 1;  // the kernel rounds up to its minimum
  ASSERT_EQ(::setsockopt(b->fd(), SOL_SOCKET, SO_RCVBUF, &small, sizeof small), 0);
  for (int i = 0; i < 2000; ++i) {
    std::error_code ec;
    do {
      ec = a->Send(CanFrame::Standard(0x300, {static_cast<uint8_t>(i)}));
    } while (ec == Errc::kOverflow);
    ASSERT_FALSE(ec) << ec.message();
  }
  while (!b->Receive(&got, milliseconds(50))) {
  }
  // The kernel hands the drop count over with the next frame queued after the drops.
  ASSERT_FALSE(a->Send(CanFrame::Standard(0x301)));
  ASSERT_FALSE(b->Receive(&got, milliseconds(1000)));
  EXPECT_EQ(got.id, 0x301u);
  EXPECT_GT(b->counters().rx_overflows, 0u);
  bool overflow_event = false;
  CanErrorEvent e;
  while (b->TakeErrorEvent(&e)) overflow_event |= e.kind == CanErrorKind::kRxOverflow;
  EXPECT_TRUE(overflow_event);
}

}  // namespace
}  // namespace kinevis::hal
