#include "hal/canopen/sdo_client.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cstring>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "hal/can/slcan_bus.h"
#include "hal/can/virtual_can_bus.h"
#include "hal/common/backend_spec.h"
#include "hal/common/error.h"
#include "hal/mock/canopen_drive_sim.h"
#include "hal/mock/slcan_adapter_sim.h"
#include "hal/serial/pty_pair.h"

namespace kinevis::hal::canopen {
namespace {

using namespace std::chrono_literals;
using ::testing::ContainsRegex;
using ::testing::HasSubstr;
using ::testing::MatchesRegex;

std::string TestName() { return ::testing::UnitTest::GetInstance()->current_test_info()->name(); }

CanFrame Frame(uint32_t id, std::vector<uint8_t> bytes) {
  CanFrame f;
  f.id = id;
  f.dlc = static_cast<uint8_t>(bytes.size());
  std::memcpy(f.data.data(), bytes.data(), bytes.size());
  return f;
}

std::vector<uint8_t> Bytes(const CanFrame& f) { return {f.data.begin(), f.data.begin() + f.dlc}; }

// =============================================================================================
// SdoTransfer: the state machine against byte vectors of CiA 301, 7.2.4.3.

constexpr uint8_t kNode = 5;
constexpr uint32_t kRequestId = 0x605;
constexpr uint32_t kResponseId = 0x585;

TEST(SdoTransferTest, ExpeditedUploadOfTwoBytes) {
  SdoTransfer t;
  CanFrame request;
  t.StartUpload(kNode, 0x6041, 0x00, &request);
  EXPECT_EQ(request.id, kRequestId);
  EXPECT_EQ(Bytes(request), (std::vector<uint8_t>{0x40, 0x41, 0x60, 0x00, 0, 0, 0, 0}));
  // scs 2, n = 2 (2 bytes unused), e = 1, s = 1: 0x4B.
  auto action =
      t.OnResponse(Frame(kResponseId, {0x4B, 0x41, 0x60, 0x00, 0x37, 0x02, 0, 0}), &request);
  EXPECT_EQ(action, SdoTransfer::Action::kComplete);
  EXPECT_FALSE(t.active());
  EXPECT_FALSE(t.error());
  EXPECT_EQ(t.data(), (std::vector<uint8_t>{0x37, 0x02}));
  EXPECT_TRUE(t.expedited());
}

TEST(SdoTransferTest, ExpeditedDownloadOfFourBytes) {
  SdoTransfer t;
  CanFrame request;
  const uint8_t value[4] = {0x14, 0x00, 0x00, 0x00};
  t.StartDownload(kNode, 0x1017, 0x00, value, 2, &request);
  // ccs 1, n = 2, e = 1, s = 1: 0x2B.
  EXPECT_EQ(Bytes(request), (std::vector<uint8_t>{0x2B, 0x17, 0x10, 0x00, 0x14, 0x00, 0, 0}));
  EXPECT_EQ(t.OnResponse(Frame(kResponseId, {0x60, 0x17, 0x10, 0x00, 0, 0, 0, 0}), &request),
            SdoTransfer::Action::kComplete);
  EXPECT_FALSE(t.error());
}

TEST(SdoTransferTest, SegmentedDownloadTogglesAndEndsWithTheLastBit) {
  SdoTransfer t;
  CanFrame request;
  const std::vector<uint8_t> data = {1, 2, 3, 4, 5, 6, 7, 8, 9, 10};
  t.StartDownload(kNode, 0x2000, 0x01, data.data(), data.size(), &request);
  // ccs 1, s = 1, size 10.
  EXPECT_EQ(Bytes(request), (std::vector<uint8_t>{0x21, 0x00, 0x20, 0x01, 10, 0, 0, 0}));
  ASSERT_EQ(t.OnResponse(Frame(kResponseId, {0x60, 0x00, 0x20, 0x01, 0, 0, 0, 0}), &request),
            SdoTransfer::Action::kSend);
  // First segment: toggle 0, n = 0, c = 0.
  EXPECT_EQ(Bytes(request), (std::vector<uint8_t>{0x00, 1, 2, 3, 4, 5, 6, 7}));
  ASSERT_EQ(t.OnResponse(Frame(kResponseId, {0x20, 0, 0, 0, 0, 0, 0, 0}), &request),
            SdoTransfer::Action::kSend);
  // Second and last: toggle 1, n = 4 (3 bytes used), c = 1: 0x10 | 4 << 1 | 1 = 0x19.
  EXPECT_EQ(Bytes(request), (std::vector<uint8_t>{0x19, 8, 9, 10, 0, 0, 0, 0}));
  EXPECT_EQ(t.OnResponse(Frame(kResponseId, {0x30, 0, 0, 0, 0, 0, 0, 0}), &request),
            SdoTransfer::Action::kComplete);
  EXPECT_EQ(t.segments(), 2);
  EXPECT_FALSE(t.error());
}

TEST(SdoTransferTest, SegmentedUploadCollectsTheSegments) {
  SdoTransfer t;
  CanFrame request;
  t.StartUpload(kNode, 0x1008, 0x00, &request);
  ASSERT_EQ(t.OnResponse(Frame(kResponseId, {0x41, 0x08, 0x10, 0x00, 10, 0, 0, 0}), &request),
            SdoTransfer::Action::kSend);
  EXPECT_EQ(Bytes(request), (std::vector<uint8_t>{0x60, 0, 0, 0, 0, 0, 0, 0}));
  ASSERT_EQ(t.OnResponse(Frame(kResponseId, {0x00, 'k', 'i', 'n', 'e', 'v', 'i', 's'}), &request),
            SdoTransfer::Action::kSend);
  EXPECT_EQ(Bytes(request), (std::vector<uint8_t>{0x70, 0, 0, 0, 0, 0, 0, 0}));
  EXPECT_EQ(t.OnResponse(Frame(kResponseId, {0x19, ' ', 'd', 'r', 0, 0, 0, 0}), &request),
            SdoTransfer::Action::kComplete);
  EXPECT_EQ(std::string(t.data().begin(), t.data().end()), "kinevis dr");
  EXPECT_FALSE(t.expedited());
}

TEST(SdoTransferTest, ZeroLengthDownloadSendsOneEmptyLastSegment) {
  SdoTransfer t;
  CanFrame request;
  t.StartDownload(kNode, 0x2001, 0x00, nullptr, 0, &request);
  EXPECT_EQ(Bytes(request), (std::vector<uint8_t>{0x21, 0x01, 0x20, 0x00, 0, 0, 0, 0}));
  ASSERT_EQ(t.OnResponse(Frame(kResponseId, {0x60, 0x01, 0x20, 0x00, 0, 0, 0, 0}), &request),
            SdoTransfer::Action::kSend);
  EXPECT_EQ(request.data[0], 0x0F);  // toggle 0, n = 7, c = 1
  EXPECT_EQ(t.OnResponse(Frame(kResponseId, {0x20, 0, 0, 0, 0, 0, 0, 0}), &request),
            SdoTransfer::Action::kComplete);
}

TEST(SdoTransferTest, ServerAbortFailsWithTheCodeAndItsText) {
  SdoTransfer t;
  CanFrame request;
  t.StartUpload(kNode, 0x2100, 0x00, &request);
  auto action =
      t.OnResponse(Frame(kResponseId, {0x80, 0x00, 0x21, 0x00, 0x00, 0x00, 0x02, 0x06}), &request);
  EXPECT_EQ(action, SdoTransfer::Action::kFailed);
  EXPECT_EQ(t.error().category(), SdoAbortCategory());
  EXPECT_EQ(SdoAbortCode(t.error()), sdo_abort::kObjectDoesNotExist);
  EXPECT_TRUE(t.abort_from_server());
  EXPECT_THAT(t.error().message(),
              MatchesRegex("SDO abort 0x06020000: Object does not exist in the object "
                           "dictionary"));
  EXPECT_THAT(t.detail(), HasSubstr("abort 0x06020000 from the server"));
}

TEST(SdoTransferTest, WrongToggleBitIsAbortedWithItsCode) {
  SdoTransfer t;
  CanFrame request;
  t.StartUpload(kNode, 0x1008, 0x00, &request);
  ASSERT_EQ(t.OnResponse(Frame(kResponseId, {0x41, 0x08, 0x10, 0x00, 20, 0, 0, 0}), &request),
            SdoTransfer::Action::kSend);
  ASSERT_EQ(t.OnResponse(Frame(kResponseId, {0x00, 1, 2, 3, 4, 5, 6, 7}), &request),
            SdoTransfer::Action::kSend);
  // The second segment must carry toggle 1; this one repeats toggle 0.
  EXPECT_EQ(t.OnResponse(Frame(kResponseId, {0x00, 1, 2, 3, 4, 5, 6, 7}), &request),
            SdoTransfer::Action::kAbort);
  EXPECT_EQ(t.error(), make_error_code(Errc::kProtocol));
  EXPECT_EQ(t.abort_code(), sdo_abort::kToggleBitNotAlternated);
  EXPECT_FALSE(t.abort_from_server());
  EXPECT_EQ(request.id, kRequestId);
  EXPECT_EQ(Bytes(request), (std::vector<uint8_t>{0x80, 0x08, 0x10, 0x00, 0x00, 0x00, 0x03, 0x05}));
  EXPECT_THAT(t.detail(), HasSubstr("toggle bit not alternated in segment 2"));
}

TEST(SdoTransferTest, DownloadSegmentResponseWithWrongToggleIsAborted) {
  SdoTransfer t;
  CanFrame request;
  const std::vector<uint8_t> data(12, 0xAA);
  t.StartDownload(kNode, 0x2000, 0x00, data.data(), data.size(), &request);
  ASSERT_EQ(t.OnResponse(Frame(kResponseId, {0x60, 0x00, 0x20, 0x00, 0, 0, 0, 0}), &request),
            SdoTransfer::Action::kSend);
  EXPECT_EQ(t.OnResponse(Frame(kResponseId, {0x30, 0, 0, 0, 0, 0, 0, 0}), &request),
            SdoTransfer::Action::kAbort);
  EXPECT_EQ(t.abort_code(), sdo_abort::kToggleBitNotAlternated);
}

TEST(SdoTransferTest, MalformedResponseIsAProtocolErrorWithAnAbort) {
  SdoTransfer t;
  CanFrame request;
  t.StartUpload(kNode, 0x6041, 0x00, &request);
  EXPECT_EQ(t.OnResponse(Frame(kResponseId, {0x4B, 0x41, 0x60, 0x00, 0x37}), &request),
            SdoTransfer::Action::kAbort);
  EXPECT_EQ(t.error(), make_error_code(Errc::kProtocol));
  EXPECT_EQ(t.abort_code(), sdo_abort::kInvalidCommandSpecifier);
  EXPECT_THAT(t.detail(), ContainsRegex("malformed response.*8 bytes"));
}

TEST(SdoTransferTest, ResponseForAnotherObjectIsRejected) {
  SdoTransfer t;
  CanFrame request;
  t.StartUpload(kNode, 0x6041, 0x00, &request);
  EXPECT_EQ(t.OnResponse(Frame(kResponseId, {0x4B, 0x64, 0x60, 0x00, 1, 2, 0, 0}), &request),
            SdoTransfer::Action::kAbort);
  EXPECT_EQ(t.error(), make_error_code(Errc::kProtocol));
  EXPECT_THAT(t.detail(), HasSubstr("response is for 0x6064:00"));
}

TEST(SdoTransferTest, UnexpectedCommandSpecifierIsAborted) {
  SdoTransfer t;
  CanFrame request;
  t.StartUpload(kNode, 0x6041, 0x00, &request);
  // An initiate download response (scs 3) to an upload request.
  EXPECT_EQ(t.OnResponse(Frame(kResponseId, {0x60, 0x41, 0x60, 0x00, 0, 0, 0, 0}), &request),
            SdoTransfer::Action::kAbort);
  EXPECT_EQ(t.abort_code(), sdo_abort::kInvalidCommandSpecifier);
  EXPECT_THAT(t.detail(), HasSubstr("unexpected initiate download response"));
}

TEST(SdoTransferTest, SegmentsBeyondTheIndicatedSizeAreAborted) {
  SdoTransfer t;
  CanFrame request;
  t.StartUpload(kNode, 0x1008, 0x00, &request);
  ASSERT_EQ(t.OnResponse(Frame(kResponseId, {0x41, 0x08, 0x10, 0x00, 5, 0, 0, 0}), &request),
            SdoTransfer::Action::kSend);
  EXPECT_EQ(t.OnResponse(Frame(kResponseId, {0x00, 1, 2, 3, 4, 5, 6, 7}), &request),
            SdoTransfer::Action::kAbort);
  EXPECT_EQ(t.abort_code(), sdo_abort::kLengthTooHigh);
  EXPECT_EQ(t.error(), make_error_code(Errc::kProtocol));
}

TEST(SdoTransferTest, TotalShorterThanIndicatedFails) {
  SdoTransfer t;
  CanFrame request;
  t.StartUpload(kNode, 0x1008, 0x00, &request);
  ASSERT_EQ(t.OnResponse(Frame(kResponseId, {0x41, 0x08, 0x10, 0x00, 9, 0, 0, 0}), &request),
            SdoTransfer::Action::kSend);
  EXPECT_EQ(t.OnResponse(Frame(kResponseId, {0x01, 1, 2, 3, 4, 5, 6, 7}), &request),
            SdoTransfer::Action::kFailed);
  EXPECT_EQ(t.error(), make_error_code(Errc::kProtocol));
  EXPECT_THAT(t.detail(), HasSubstr("received 7 bytes, the server indicated 9"));
}

TEST(SdoTransferTest, UploadLargerThanTheLimitIsAbortedOutOfMemory) {
  SdoTransfer t(16);
  CanFrame request;
  t.StartUpload(kNode, 0x1008, 0x00, &request);
  EXPECT_EQ(t.OnResponse(Frame(kResponseId, {0x41, 0x08, 0x10, 0x00, 17, 0, 0, 0}), &request),
            SdoTransfer::Action::kAbort);
  EXPECT_EQ(t.error(), make_error_code(Errc::kOverflow));
  EXPECT_EQ(t.abort_code(), sdo_abort::kOutOfMemory);
}

TEST(SdoTransferTest, TimeoutAbortsWithProtocolTimedOut) {
  SdoTransfer t;
  CanFrame request;
  t.StartUpload(kNode, 0x6041, 0x00, &request);
  EXPECT_EQ(t.OnTimeout(&request), SdoTransfer::Action::kAbort);
  EXPECT_EQ(t.error(), make_error_code(Errc::kTimeout));
  EXPECT_EQ(Bytes(request), (std::vector<uint8_t>{0x80, 0x41, 0x60, 0x00, 0x00, 0x00, 0x04, 0x05}));
  EXPECT_FALSE(t.active());
}

TEST(SdoAbortCategoryTest, EveryAbortCodeOfTheTableHasItsText) {
  const std::vector<uint32_t> codes = {sdo_abort::kToggleBitNotAlternated,
                                       sdo_abort::kProtocolTimedOut,
                                       sdo_abort::kInvalidCommandSpecifier,
                                       sdo_abort::kOutOfMemory,
                                       sdo_abort::kUnsupportedAccess,
                                       sdo_abort::kWriteOnly,
                                       sdo_abort::kReadOnly,
                                       sdo_abort::kObjectDoesNotExist,
                                       sdo_abort::kCannotBeMapped,
                                       sdo_abort::kPdoLengthExceeded,
                                       sdo_abort::kParameterIncompatible,
                                       sdo_abort::kHardwareError,
                                       sdo_abort::kLengthMismatch,
                                       sdo_abort::kLengthTooHigh,
                                       sdo_abort::kLengthTooLow,
                                       sdo_abort::kSubindexDoesNotExist,
                                       sdo_abort::kInvalidValue,
                                       sdo_abort::kValueTooHigh,
                                       sdo_abort::kValueTooLow,
                                       sdo_abort::kGeneralError,
                                       sdo_abort::kCannotTransfer,
                                       sdo_abort::kCannotTransferLocalControl,
                                       sdo_abort::kCannotTransferDeviceState};
  for (uint32_t code : codes) {
    const std::error_code ec = MakeSdoAbortError(code);
    EXPECT_EQ(SdoAbortCode(ec), code);
    EXPECT_THAT(ec.message(), HasSubstr(SdoAbortText(code)));
    EXPECT_STRNE(SdoAbortText(code), "unknown abort code");
  }
  // Code 0 cannot be an error_code of the category (it would read as success).
  EXPECT_EQ(MakeSdoAbortError(0), make_error_code(Errc::kProtocol));
  EXPECT_EQ(SdoAbortCode(make_error_code(Errc::kTimeout)), 0u);
}

// =============================================================================================
// SdoClient over a virtual bus, against a small scripted SDO server.

// A clock whose time passes only when the code under test sleeps on it; while it passes, the
// simulated devices are serviced, in steps no longer than `step`.
class ServicedClock final : public common::Clock {
 public:
  explicit ServicedClock(common::Duration step = 50us) : step_(step) {}
  common::Duration Now() const override { return time_.Now(); }
  void SleepUntil(common::Duration deadline) override {
    while (time_.Now() < deadline) {
      time_.AdvanceTo(std::min(deadline, time_.Now() + step_));
      for (const auto& service : services_) service();
    }
  }
  void AddService(std::function<void()> service) { services_.push_back(std::move(service)); }

 private:
  common::SimulatedClock time_;
  common::Duration step_;
  std::vector<std::function<void()>> services_;
};

// An SDO server with an object dictionary of byte strings, written for these tests from
// CiA 301 (independently of the client), with fault injection.
class ScriptedSdoServer {
 public:
  ScriptedSdoServer(CanBus* bus, uint8_t node) : bus_(bus), node_(node) {}

  std::map<std::pair<uint16_t, uint8_t>, std::vector<uint8_t>> od;
  std::map<std::pair<uint16_t, uint8_t>, uint32_t> abort_on;  // object -> abort code
  int drop_next = 0;                                          // requests left unanswered
  int malformed_next = 0;                                     // responses sent with dlc 5
  bool wrong_toggle = false;  // upload segments carry the wrong toggle bit
  bool expedited_without_size = false;
  std::vector<uint32_t> aborts_received;
  int requests = 0;

  void Service() {
    CanFrame f;
    while (!bus_->Receive(&f, 0us)) Handle(f);
  }

 private:
  void Respond(const SdoMessage& m) {
    CanFrame f = EncodeSdoResponse(node_, m);
    if (malformed_next > 0) {
      --malformed_next;
      f.dlc = 5;
    }
    bus_->Send(f);
  }

  void Handle(const CanFrame& f) {
    if (f.id != kSdoRequestBase + node_) return;
    auto m = DecodeSdoRequest(f);
    if (!m) return;
    if (m->type == SdoType::kAbort) {
      aborts_received.push_back(m->abort_code);
      segmented_ = false;
      return;
    }
    ++requests;
    if (drop_next > 0) {
      --drop_next;
      return;
    }
    switch (m->type) {
      case SdoType::kInitiateUploadRequest: {
        key_ = {m->index, m->subindex};
        if (auto a = abort_on.find(key_); a != abort_on.end()) {
          Respond(SdoMessage::Abort(m->index, m->subindex, a->second));
          return;
        }
        auto it = od.find(key_);
        if (it == od.end()) {
          Respond(SdoMessage::Abort(m->index, m->subindex, sdo_abort::kObjectDoesNotExist));
          return;
        }
        const auto& v = it->second;
        if (v.size() >= 1 && v.size() <= 4) {
          SdoMessage r = SdoMessage::ExpeditedUploadResponse(m->index, m->subindex, v.data(),
                                                             static_cast<uint8_t>(v.size()));
          if (expedited_without_size) {
            r.size_indicated = false;
            CanFrame out = EncodeSdoResponse(node_, r);
            out.data[0] = 0x42;  // e = 1, s = 0
            bus_->Send(out);
            return;
          }
          Respond(r);
          return;
        }
        segmented_ = true;
        upload_ = v;
        offset_ = 0;
        toggle_ = false;
        Respond(SdoMessage::SegmentedUploadResponse(m->index, m->subindex,
                                                    static_cast<uint32_t>(v.size())));
        return;
      }
      case SdoType::kUploadSegmentRequest: {
        const size_t n = std::min<size_t>(7, upload_.size() - offset_);
        const bool last = offset_ + n == upload_.size();
        Respond(SdoMessage::UploadSegmentResponse(wrong_toggle ? !m->toggle : m->toggle,
                                                  upload_.data() + offset_, static_cast<uint8_t>(n),
                                                  last));
        offset_ += n;
        return;
      }
      case SdoType::kInitiateDownloadRequest: {
        key_ = {m->index, m->subindex};
        if (auto a = abort_on.find(key_); a != abort_on.end()) {
          Respond(SdoMessage::Abort(m->index, m->subindex, a->second));
          return;
        }
        if (m->expedited) {
          od[key_].assign(m->data.begin(), m->data.begin() + m->size);
        } else {
          download_.clear();
        }
        Respond(SdoMessage::InitiateDownloadResponse(m->index, m->subindex));
        return;
      }
      case SdoType::kDownloadSegmentRequest: {
        download_.insert(download_.end(), m->data.begin(), m->data.begin() + m->data_length);
        if (m->last) od[key_] = download_;
        Respond(SdoMessage::DownloadSegmentResponse(m->toggle));
        return;
      }
      default:
        return;
    }
  }

  CanBus* bus_;
  uint8_t node_;
  std::pair<uint16_t, uint8_t> key_;
  bool segmented_ = false;
  std::vector<uint8_t> upload_;
  size_t offset_ = 0;
  bool toggle_ = false;
  std::vector<uint8_t> download_;
};

class SdoClientTest : public ::testing::Test {
 protected:
  void SetUp() override {
    VirtualCanNetwork::Options options;
    options.clock = &clock_;
    network_ = std::make_shared<VirtualCanNetwork>("sdo-" + TestName(), options);
    host_ = network_->Connect("host");
    device_ = network_->Connect("device");
    server_ = std::make_unique<ScriptedSdoServer>(device_.get(), kNode);
    clock_.AddService([this] { server_->Service(); });
    client_ = std::make_unique<SdoClient>(host_.get(), kNode, &clock_, "axis (test node 5)");
  }

  ServicedClock clock_;
  std::shared_ptr<VirtualCanNetwork> network_;
  std::unique_ptr<VirtualCanBus> host_, device_;
  std::unique_ptr<ScriptedSdoServer> server_;
  std::unique_ptr<SdoClient> client_;
};

TEST_F(SdoClientTest, IntegersOfEverySizeAndSignRoundTrip) {
  EXPECT_FALSE(client_->DownloadValue<uint8_t>(0x2000, 1, 0xA5));
  EXPECT_FALSE(client_->DownloadValue<uint16_t>(0x2000, 2, 0xBEEF));
  EXPECT_FALSE(client_->DownloadValue<uint32_t>(0x2000, 3, 0xDEADBEEF));
  EXPECT_FALSE(client_->DownloadValue<int8_t>(0x2000, 4, -5));
  EXPECT_FALSE(client_->DownloadValue<int16_t>(0x2000, 5, -1234));
  EXPECT_FALSE(client_->DownloadValue<int32_t>(0x2000, 6, -123456789));
  EXPECT_EQ((server_->od[{0x2000, 5}]), (std::vector<uint8_t>{0x2E, 0xFB}));  // little-endian

  uint8_t u8 = 0;
  uint16_t u16 = 0;
  uint32_t u32 = 0;
  int8_t i8 = 0;
  int16_t i16 = 0;
  int32_t i32 = 0;
  ASSERT_FALSE(client_->UploadValue(0x2000, 1, &u8));
  ASSERT_FALSE(client_->UploadValue(0x2000, 2, &u16));
  ASSERT_FALSE(client_->UploadValue(0x2000, 3, &u32));
  ASSERT_FALSE(client_->UploadValue(0x2000, 4, &i8));
  ASSERT_FALSE(client_->UploadValue(0x2000, 5, &i16));
  ASSERT_FALSE(client_->UploadValue(0x2000, 6, &i32));
  EXPECT_EQ(u8, 0xA5);
  EXPECT_EQ(u16, 0xBEEF);
  EXPECT_EQ(u32, 0xDEADBEEFu);
  EXPECT_EQ(i8, -5);
  EXPECT_EQ(i16, -1234);
  EXPECT_EQ(i32, -123456789);
  EXPECT_EQ(client_->counters().transfers, 12u);
  EXPECT_EQ(client_->counters().failures, 0u);
}

TEST_F(SdoClientTest, SegmentedTransfersRoundTripAHundredBytes) {
  std::vector<uint8_t> data(100);
  for (size_t i = 0; i < data.size(); ++i) data[i] = static_cast<uint8_t>(i * 7 + 3);
  ASSERT_FALSE(client_->Download(0x2100, 0, data)) << client_->last_error_text();
  EXPECT_EQ((server_->od[{0x2100, 0}]), data);
  std::vector<uint8_t> back;
  ASSERT_FALSE(client_->Upload(0x2100, 0, &back)) << client_->last_error_text();
  EXPECT_EQ(back, data);
  // 100 bytes = 15 segments each way.
  EXPECT_EQ(client_->counters().segments, 30u);
}

TEST_F(SdoClientTest, VisibleStringLosesTrailingNuls) {
  const std::string name = "kinevis simulated drive";
  server_->od[{0x1008, 0}] = std::vector<uint8_t>(name.begin(), name.end());
  server_->od[{0x1008, 0}].push_back(0);
  std::string text;
  ASSERT_FALSE(client_->UploadString(0x1008, 0, &text));
  EXPECT_EQ(text, name);
}

TEST_F(SdoClientTest, ServerAbortIsReturnedWithCodeTextAndDeviceName) {
  server_->abort_on[{0x6060, 0}] = sdo_abort::kValueTooHigh;
  const std::error_code ec = client_->DownloadValue<int8_t>(0x6060, 0, 99);
  ASSERT_TRUE(ec);
  EXPECT_EQ(ec.category(), SdoAbortCategory());
  EXPECT_EQ(SdoAbortCode(ec), sdo_abort::kValueTooHigh);
  EXPECT_EQ(client_->last_abort_code(), sdo_abort::kValueTooHigh);
  EXPECT_THAT(client_->last_error_text(),
              MatchesRegex("axis \\(test node 5\\): SDO download 0x6060:00 failed: abort "
                           "0x06090031 from the server \\(Value of parameter written too high "
                           "\\(download only\\)\\)"));
  EXPECT_EQ(client_->counters().aborts_received, 1u);
  EXPECT_EQ(client_->counters().aborts_sent, 0u);

  uint32_t value = 0;
  EXPECT_EQ(SdoAbortCode(client_->UploadValue(0x2FFF, 0, &value)), sdo_abort::kObjectDoesNotExist);
  EXPECT_THAT(client_->last_error_text(), ContainsRegex("0x2FFF:00.*Object does not exist"));
}

TEST_F(SdoClientTest, NoAnswerTimesOutWithinTheBoundAndSendsAnAbort) {
  server_->drop_next = 1;
  SdoClientOptions options;
  options.timeout = 100ms;
  client_ = std::make_unique<SdoClient>(host_.get(), kNode, &clock_, "axis", options);
  const common::Duration start = clock_.Now();
  uint16_t value = 0;
  const std::error_code ec = client_->UploadValue<uint16_t>(0x6041, 0, &value);
  const common::Duration elapsed = clock_.Now() - start;
  EXPECT_EQ(ec, make_error_code(Errc::kTimeout));
  EXPECT_GE(elapsed, common::Duration(100ms));
  EXPECT_LE(elapsed, common::Duration(101ms));
  EXPECT_THAT(client_->last_error_text(),
              MatchesRegex("axis: SDO upload 0x6041:00 failed: timed out after 100 ms: no "
                           "response to the initiate request \\(abort 0x05040000 sent\\)"));
  clock_.SleepFor(1ms);
  EXPECT_EQ(server_->aborts_received, (std::vector<uint32_t>{sdo_abort::kProtocolTimedOut}));
  EXPECT_EQ(client_->counters().timeouts, 1u);
  EXPECT_EQ(client_->counters().aborts_sent, 1u);
  // The per-request timeout overrides the default.
  server_->drop_next = 1;
  const common::Duration start2 = clock_.Now();
  EXPECT_EQ(client_->UploadValue<uint16_t>(0x6041, 0, &value, 20ms), Errc::kTimeout);
  EXPECT_LE(clock_.Now() - start2, common::Duration(21ms));
  // And the server answers again.
  server_->od[{0x6041, 0}] = {0x37, 0x02};
  EXPECT_FALSE(client_->UploadValue<uint16_t>(0x6041, 0, &value));
  EXPECT_EQ(value, 0x0237);
}

TEST_F(SdoClientTest, MalformedResponseIsAProtocolError) {
  server_->od[{0x6041, 0}] = {0x37, 0x02};
  server_->malformed_next = 1;
  uint16_t value = 0;
  EXPECT_EQ(client_->UploadValue<uint16_t>(0x6041, 0, &value), Errc::kProtocol);
  EXPECT_THAT(client_->last_error_text(),
              ContainsRegex("^axis \\(test node 5\\): SDO upload 0x6041:00 failed: malformed "
                            "response .*\\(abort 0x05040001 sent\\)$"));
  clock_.SleepFor(1ms);
  EXPECT_EQ(server_->aborts_received, (std::vector<uint32_t>{sdo_abort::kInvalidCommandSpecifier}));
  EXPECT_EQ(client_->counters().protocol_errors, 1u);
}

TEST_F(SdoClientTest, WrongToggleFromTheServerIsAborted) {
  server_->od[{0x1008, 0}] = std::vector<uint8_t>(20, 'x');
  server_->wrong_toggle = true;
  std::vector<uint8_t> data;
  EXPECT_EQ(client_->Upload(0x1008, 0, &data), Errc::kProtocol);
  EXPECT_EQ(client_->last_abort_code(), sdo_abort::kToggleBitNotAlternated);
  EXPECT_THAT(client_->last_error_text(), HasSubstr("toggle bit not alternated in segment 1"));
  clock_.SleepFor(1ms);
  EXPECT_EQ(server_->aborts_received, (std::vector<uint32_t>{sdo_abort::kToggleBitNotAlternated}));
}

TEST_F(SdoClientTest, SizeOfAnIntegerMustMatch) {
  server_->od[{0x6064, 0}] = {1, 2, 3, 4};
  uint16_t value = 7;
  EXPECT_EQ(client_->UploadValue<uint16_t>(0x6064, 0, &value), Errc::kProtocol);
  EXPECT_EQ(value, 7);  // untouched
  EXPECT_THAT(client_->last_error_text(), HasSubstr("expected 2 bytes, the server sent 4"));
  // An expedited answer without size indication carries 4 bytes and fits any integer.
  server_->expedited_without_size = true;
  server_->od[{0x6041, 0}] = {0x37, 0x02, 0, 0};
  EXPECT_FALSE(client_->UploadValue<uint16_t>(0x6041, 0, &value));
  EXPECT_EQ(value, 0x0237);
}

TEST_F(SdoClientTest, RequestRefusedByTheBusIsALinkError) {
  host_->InjectBusOff();
  EXPECT_EQ(client_->DownloadValue<uint16_t>(0x1017, 0, 20), Errc::kBusOff);
  EXPECT_THAT(client_->last_error_text(),
              MatchesRegex("axis \\(test node 5\\): SDO download 0x1017:00 failed: could not "
                           "send the request: CAN bus-off"));
  EXPECT_EQ(client_->counters().link_errors, 1u);
  host_->Recover();
  EXPECT_FALSE(client_->DownloadValue<uint16_t>(0x1017, 0, 20));
}

// A frame source that owns the bus: it dispatches SDO responses to the client and keeps every
// other frame, as the CANopen master does.
class RecordingSource final : public CanFrameSource {
 public:
  RecordingSource(CanBus* bus, common::Clock* clock, SdoClient** client)
      : bus_(bus), clock_(clock), client_(client) {}
  void PumpUntil(common::Duration deadline, const std::function<bool()>& done) override {
    ++pumps;
    while (!done()) {
      CanFrame f;
      if (ReceiveFrameUntil(*bus_, *clock_, deadline, &f)) return;
      if (!(*client_)->HandleFrame(f)) others.push_back(f);
    }
  }
  int pumps = 0;
  std::vector<CanFrame> others;

 private:
  CanBus* bus_;
  common::Clock* clock_;
  SdoClient** client_;
};

TEST_F(SdoClientTest, WithAFrameSourceOtherTrafficReachesTheSource) {
  SdoClient* client = client_.get();
  RecordingSource source(host_.get(), &clock_, &client);
  client_->set_frame_source(&source);
  // The device's heartbeat is on the bus before its SDO answer.
  device_->Send(EncodeHeartbeat(kNode, NmtState::kOperational));
  server_->od[{0x1017, 0}] = {20, 0};
  uint16_t value = 0;
  ASSERT_FALSE(client_->UploadValue<uint16_t>(0x1017, 0, &value));
  EXPECT_EQ(value, 20);
  EXPECT_GE(source.pumps, 1);
  ASSERT_FALSE(source.others.empty());
  EXPECT_EQ(source.others.front().id, kHeartbeatBase + kNode);
  // A response nobody waits for is counted, not kept for the next transfer.
  device_->Send(EncodeSdoResponse(kNode, SdoMessage::InitiateDownloadResponse(0x1017, 0)));
  CanFrame stray;
  ASSERT_FALSE(host_->Receive(&stray, 0us));
  EXPECT_TRUE(client_->HandleFrame(stray));
  EXPECT_EQ(client_->counters().unexpected_responses, 1u);
  EXPECT_FALSE(client_->HandleFrame(EncodeHeartbeat(kNode, NmtState::kOperational)));
}

TEST(SdoClientConfigTest, BadNodeOrTimeoutIsAConfigError) {
  auto bus = VirtualCanNetwork::Get("sdo-config", {})->Connect();
  common::SimulatedClock clock;
  try {
    SdoClientOptions options;
    options.timeout = 0ms;
    SdoClient client(bus.get(), 0, &clock, "x", options);
    FAIL() << "no ConfigError";
  } catch (const common::ConfigError& e) {
    EXPECT_THAT(e.what(), MatchesRegex("SDO client x: node 0 is not in 1..127; timeout 0 ms "
                                       "must be > 0"));
  }
  EXPECT_THROW(SdoClient(bus.get(), 128, &clock, "x"), common::ConfigError);
}

// Real time: the client blocks in Receive() while a server thread answers.
TEST(SdoClientRealTimeTest, StandAloneClientReadsTheBusItself) {
  auto network = std::make_shared<VirtualCanNetwork>("sdo-rt", VirtualCanNetwork::Options{});
  auto host = network->Connect("host");
  auto device = network->Connect("device");
  ScriptedSdoServer server(device.get(), 9);
  server.od[{0x1018, 1}] = {0x53, 0x56, 0x4B, 0x00};
  std::atomic<bool> stop{false};
  std::thread serve([&] {
    while (!stop) {
      server.Service();
      std::this_thread::sleep_for(200us);
    }
  });
  SdoClient client(host.get(), 9, &common::SteadyClock::Instance(), "rt");
  uint32_t vendor = 0;
  const std::error_code ec = client.UploadValue<uint32_t>(0x1018, 1, &vendor, 5000ms);
  stop = true;
  serve.join();
  ASSERT_FALSE(ec) << client.last_error_text();
  EXPECT_EQ(vendor, 0x004B5653u);
}

// =============================================================================================
// SdoClient against the drive simulator: on a virtual bus (deterministic), and over slcan.

class SdoClientSimTest : public ::testing::Test {
 protected:
  void SetUp() override {
    VirtualCanNetwork::Options options;
    options.clock = &clock_;
    network_ = std::make_shared<VirtualCanNetwork>("sdo-sim-" + TestName(), options);
    host_ = network_->Connect("host");
    sim_node_ = network_->Connect("sim");
    CanopenDriveSim::Options o;
    o.node = 7;
    o.serial_number = 4242;
    sim_ = std::make_unique<CanopenDriveSim>(sim_node_.get(), &clock_, o);
    clock_.AddService([this] { sim_->Service(); });
    SdoClientOptions so;
    so.timeout = 100ms;
    client_ = std::make_unique<SdoClient>(host_.get(), 7, &clock_, "drive7", so);
  }

  ServicedClock clock_;
  std::shared_ptr<VirtualCanNetwork> network_;
  std::unique_ptr<VirtualCanBus> host_, sim_node_;
  std::unique_ptr<CanopenDriveSim> sim_;
  std::unique_ptr<SdoClient> client_;
};

TEST_F(SdoClientSimTest, ReadsIdentityAndTheSegmentedDeviceName) {
  uint32_t vendor = 0, serial = 0, type = 0;
  ASSERT_FALSE(client_->UploadValue(kIdentity, 1, &vendor)) << client_->last_error_text();
  ASSERT_FALSE(client_->UploadValue(kIdentity, 4, &serial));
  ASSERT_FALSE(client_->UploadValue(kDeviceType, 0, &type));
  EXPECT_EQ(vendor, 0x004B5653u);
  EXPECT_EQ(serial, 4242u);
  EXPECT_EQ(type, 0x00020192u);
  std::string name;
  ASSERT_FALSE(client_->UploadString(0x1008, 0, &name));
  EXPECT_EQ(name, "kinevis simulated drive");
  EXPECT_EQ(client_->counters().segments, 4u);  // 23 bytes in 7-byte segments
  ASSERT_FALSE(client_->DownloadValue<uint16_t>(kProducerHeartbeatTime, 0, 25));
  uint16_t heartbeat = 0;
  ASSERT_FALSE(client_->UploadValue(kProducerHeartbeatTime, 0, &heartbeat));
  EXPECT_EQ(heartbeat, 25);
}

TEST_F(SdoClientSimTest, SimulatorAbortsComeWithTheirCodes) {
  uint8_t u8 = 0;
  EXPECT_EQ(SdoAbortCode(client_->UploadValue<uint8_t>(0x5FFF, 0, &u8)),
            sdo_abort::kObjectDoesNotExist);
  EXPECT_EQ(SdoAbortCode(client_->DownloadValue<uint32_t>(kDeviceType, 0, 1)),
            sdo_abort::kReadOnly);
  EXPECT_EQ(SdoAbortCode(client_->DownloadValue<uint8_t>(kProducerHeartbeatTime, 0, 1)),
            sdo_abort::kLengthTooLow);
  EXPECT_THAT(client_->last_error_text(),
              MatchesRegex("drive7: SDO download 0x1017:00 failed: abort 0x06070013 from the "
                           "server \\(Data type does not match, length of service parameter too "
                           "low\\)"));
  EXPECT_EQ(client_->counters().aborts_received, 3u);
}

TEST_F(SdoClientSimTest, DroppedReplyTimesOutWithinTheBound) {
  sim_->Service();
  sim_->DropNextReplies(1);
  const common::Duration start = clock_.Now();
  uint32_t value = 0;
  EXPECT_EQ(client_->UploadValue(kIdentity, 1, &value), Errc::kTimeout);
  EXPECT_GE(clock_.Now() - start, common::Duration(100ms));
  EXPECT_LE(clock_.Now() - start, common::Duration(101ms));
  EXPECT_THAT(client_->last_error_text(), HasSubstr("timed out after 100 ms"));
  EXPECT_FALSE(client_->UploadValue(kIdentity, 1, &value));  // the server recovered
}

TEST_F(SdoClientSimTest, MalformedReplyIsAProtocolError) {
  sim_->Service();
  sim_->SendMalformedSdoReplies(1);
  std::string name;
  EXPECT_EQ(client_->UploadString(0x1008, 0, &name), Errc::kProtocol);
  EXPECT_THAT(client_->last_error_text(), ContainsRegex("^drive7: .*malformed response"));
  EXPECT_FALSE(client_->UploadString(0x1008, 0, &name));
  EXPECT_EQ(name, "kinevis simulated drive");
}

TEST(SdoClientSlcanTest, TransfersOverSlcanToTheSimulator) {
  PtyPair pty;
  auto network = VirtualCanNetwork::Get("sdo-slcan", {});
  auto adapter_node = network->Connect("adapter");
  auto sim_node = network->Connect("sim");
  SlcanAdapterSim adapter(pty.MasterPort(), adapter_node.get(), {});
  adapter.Start();
  CanopenDriveSim::Options o;
  o.node = 3;
  CanopenDriveSim sim(sim_node.get(), &common::SteadyClock::Instance(), o);
  sim.Start();
  auto bus =
      SlcanBus::Open(ParseCanBackend("slcan:" + pty.slave_path() + "@115200,bitrate=500000"));
  SdoClientOptions so;
  so.timeout = 2000ms;  // generous: real time on a loaded machine
  SdoClient client(bus.get(), 3, &common::SteadyClock::Instance(), "slcan-drive", so);
  std::string name;
  ASSERT_FALSE(client.UploadString(0x1008, 0, &name)) << client.last_error_text();
  EXPECT_EQ(name, "kinevis simulated drive");
  const std::string tag = "segmented over slcan";
  ASSERT_FALSE(client.Download(0x2000, 0, std::vector<uint8_t>(tag.begin(), tag.end())))
      << client.last_error_text();
  std::string back;
  ASSERT_FALSE(client.UploadString(0x2000, 0, &back));
  EXPECT_EQ(back, tag);
  uint32_t value = 0;
  EXPECT_EQ(SdoAbortCode(client.UploadValue<uint32_t>(0x2FFF, 0, &value)),
            sdo_abort::kObjectDoesNotExist);
  sim.Stop();
  adapter.Stop();
}

}  // namespace
}  // namespace kinevis::hal::canopen
