#include "hal/mock/canopen_drive_sim.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <chrono>
#include <cstring>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "hal/can/virtual_can_bus.h"
#include "hal/canopen/canopen_codec.h"
#include "hal/common/error.h"

namespace kinevis::hal {
namespace {

using namespace std::chrono_literals;
using namespace canopen;
using S = Cia402State;

constexpr uint8_t kNode = 5;

// Raw CANopen frames from a host node of a VirtualCanNetwork to the simulator on another node,
// in deterministic mode: the test advances a SimulatedClock and calls Service().
class CanopenDriveSimTest : public ::testing::Test {
 protected:
  void SetUp() override { Make(DefaultOptions()); }

  static CanopenDriveSim::Options DefaultOptions() {
    CanopenDriveSim::Options o;
    o.node = kNode;
    o.vendor_id = 0x004B5653;
    o.product_code = 0x0402;
    o.revision = 7;
    o.serial_number = 0x1234;
    o.device.limits.max_velocity = 100000;
    o.device.limits.max_acceleration = 1000000;
    return o;
  }

  void Make(const CanopenDriveSim::Options& options) {
    sim_.reset();
    drive_bus_.reset();
    host_.reset();
    network_ = std::make_shared<VirtualCanNetwork>(
        "canopen-drive-sim-test", VirtualCanNetwork::Options{0, &clock_, 4096, 256});
    host_ = network_->Connect("host");
    drive_bus_ = network_->Connect("drive");
    sim_ = std::make_unique<CanopenDriveSim>(drive_bus_.get(), &clock_, options);
  }

  // Boots the simulator (first Service) and discards the boot-up message.
  void Boot() {
    sim_->Service();
    Frames();
  }

  std::vector<CanFrame> Frames() {
    std::vector<CanFrame> out;
    CanFrame f;
    while (!host_->Receive(&f, std::chrono::microseconds::zero())) out.push_back(f);
    return out;
  }

  void Send(const CanFrame& f) { ASSERT_FALSE(host_->Send(f)); }

  std::vector<CanFrame> Exchange(const CanFrame& f) {
    Send(f);
    sim_->Service();
    return Frames();
  }

  // Advances the clock by `total` in steps of `step`, serving after each; returns the frames.
  std::vector<CanFrame> Run(common::Duration total, common::Duration step = 1ms) {
    std::vector<CanFrame> out;
    for (common::Duration t{0}; t < total; t += step) {
      clock_.Advance(step);
      sim_->Service();
      for (const CanFrame& f : Frames()) out.push_back(f);
    }
    return out;
  }

  // One SDO request; exactly one response on 0x580 + node is expected, decoded.
  SdoMessage Sdo(const SdoMessage& request) {
    const std::vector<CanFrame> frames = Exchange(EncodeSdoRequest(kNode, request));
    EXPECT_EQ(frames.size(), 1u);
    if (frames.size() != 1) return SdoMessage::Abort(0, 0, 0xFFFFFFFF);
    EXPECT_EQ(frames[0].id, kSdoResponseBase + kNode);
    std::string error;
    auto response = DecodeSdoResponse(frames[0], &error);
    EXPECT_TRUE(response.has_value()) << error;
    return response.value_or(SdoMessage::Abort(0, 0, 0xFFFFFFFF));
  }

  // The abort code the drive answers `request` with (0 when it did not abort).
  uint32_t AbortCode(const SdoMessage& request) {
    const SdoMessage r = Sdo(request);
    return r.type == SdoType::kAbort ? r.abort_code : 0;
  }

  uint32_t Upload(uint16_t index, uint8_t sub, uint32_t* size = nullptr) {
    const SdoMessage r = Sdo(SdoMessage::InitiateUpload(index, sub));
    EXPECT_EQ(r.type, SdoType::kInitiateUploadResponse)
        << std::hex << index << " abort 0x" << r.abort_code;
    EXPECT_TRUE(r.expedited);
    EXPECT_EQ(r.index, index);
    EXPECT_EQ(r.subindex, sub);
    if (size != nullptr) *size = r.size;
    return GetLe(r.data.data(), static_cast<int>(r.size));
  }

  SdoMessage DownloadRequest(uint16_t index, uint8_t sub, uint32_t value, uint8_t size) {
    uint8_t bytes[4];
    PutLe(bytes, value, 4);
    return SdoMessage::ExpeditedDownload(index, sub, bytes, size);
  }

  void Download(uint16_t index, uint8_t sub, uint32_t value, uint8_t size) {
    const SdoMessage r = Sdo(DownloadRequest(index, sub, value, size));
    EXPECT_EQ(r.type, SdoType::kInitiateDownloadResponse)
        << "0x" << std::hex << index << "." << int{sub} << " abort 0x" << r.abort_code << " ("
        << SdoAbortText(r.abort_code) << ")";
    EXPECT_EQ(r.index, index);
    EXPECT_EQ(r.subindex, sub);
  }

  uint32_t DownloadAbort(uint16_t index, uint8_t sub, uint32_t value, uint8_t size) {
    return AbortCode(DownloadRequest(index, sub, value, size));
  }

  std::string UploadSegmented(uint16_t index, uint8_t sub) {
    const SdoMessage init = Sdo(SdoMessage::InitiateUpload(index, sub));
    EXPECT_EQ(init.type, SdoType::kInitiateUploadResponse);
    EXPECT_FALSE(init.expedited);
    EXPECT_TRUE(init.size_indicated);
    std::string out;
    bool toggle = false;
    for (int i = 0; i < 20; ++i) {
      const SdoMessage seg = Sdo(SdoMessage::UploadSegment(toggle));
      EXPECT_EQ(seg.type, SdoType::kUploadSegmentResponse);
      EXPECT_EQ(seg.toggle, toggle);
      out.append(reinterpret_cast<const char*>(seg.data.data()), seg.data_length);
      if (seg.last) break;
      toggle = !toggle;
    }
    EXPECT_EQ(out.size(), init.size);
    return out;
  }

  // Segmented download of `data` (initiate without size indication when indicated_size is
  // empty); returns the abort code (0 on success).
  uint32_t DownloadSegmented(uint16_t index, uint8_t sub, const std::string& data,
                             std::optional<uint32_t> indicated_size) {
    SdoMessage initiate = SdoMessage::SegmentedDownload(index, sub, indicated_size.value_or(0));
    initiate.size_indicated = indicated_size.has_value();
    SdoMessage r = Sdo(initiate);
    if (r.type == SdoType::kAbort) return r.abort_code;
    EXPECT_EQ(r.type, SdoType::kInitiateDownloadResponse);
    bool toggle = false;
    for (size_t offset = 0; offset < data.size() || offset == 0;) {
      const size_t n = std::min<size_t>(7, data.size() - offset);
      const bool last = offset + n == data.size();
      r = Sdo(SdoMessage::DownloadSegment(toggle,
                                          reinterpret_cast<const uint8_t*>(data.data()) + offset,
                                          static_cast<uint8_t>(n), last));
      if (r.type == SdoType::kAbort) return r.abort_code;
      EXPECT_EQ(r.type, SdoType::kDownloadSegmentResponse);
      EXPECT_EQ(r.toggle, toggle);
      toggle = !toggle;
      offset += n;
      if (last) break;
    }
    return 0;
  }

  void Nmt(NmtCommand command, uint8_t node = kNode) {
    Send(EncodeNmt(command, node));
    sim_->Service();
  }

  // SYNC after advancing the clock by one cycle; returns the frames answered.
  std::vector<CanFrame> Sync(common::Duration cycle = 1ms) {
    clock_.Advance(cycle);
    return Exchange(EncodeSync());
  }

  static std::vector<CanFrame> WithId(const std::vector<CanFrame>& frames, uint32_t id) {
    std::vector<CanFrame> out;
    for (const CanFrame& f : frames) {
      if (f.id == id) out.push_back(f);
    }
    return out;
  }

  common::SimulatedClock clock_;
  std::shared_ptr<VirtualCanNetwork> network_;
  std::unique_ptr<VirtualCanBus> host_;
  std::unique_ptr<VirtualCanBus> drive_bus_;
  std::unique_ptr<CanopenDriveSim> sim_;
};

// ------------------------------------------------------------------------------------ NMT

TEST_F(CanopenDriveSimTest, BootsIntoPreOperationalWithABootUpMessage) {
  EXPECT_EQ(Frames().size(), 0u);  // nothing before the first Service()
  sim_->Service();
  const std::vector<CanFrame> frames = Frames();
  ASSERT_EQ(frames.size(), 1u);
  EXPECT_EQ(frames[0], CanFrame::Standard(0x705, {0x00}));
  EXPECT_EQ(sim_->nmt_state(), NmtState::kPreOperational);
  EXPECT_EQ(sim_->device().state(), S::kSwitchOnDisabled);
  EXPECT_EQ(sim_->node(), kNode);
}

TEST_F(CanopenDriveSimTest, BootUpMessageCanBeSwitchedOff) {
  CanopenDriveSim::Options o = DefaultOptions();
  o.boot_up_message = false;
  Make(o);
  sim_->Service();
  EXPECT_TRUE(Frames().empty());
  EXPECT_EQ(sim_->nmt_state(), NmtState::kPreOperational);
}

TEST_F(CanopenDriveSimTest, NmtStateTransitions) {
  Boot();
  Nmt(NmtCommand::kStart);
  EXPECT_EQ(sim_->nmt_state(), NmtState::kOperational);
  Nmt(NmtCommand::kEnterPreOperational);
  EXPECT_EQ(sim_->nmt_state(), NmtState::kPreOperational);
  Nmt(NmtCommand::kStop);
  EXPECT_EQ(sim_->nmt_state(), NmtState::kStopped);
  // Stopped: SDO is not served.
  EXPECT_TRUE(Exchange(EncodeSdoRequest(kNode, SdoMessage::InitiateUpload(0x1000, 0))).empty());
  Nmt(NmtCommand::kStart, 0);  // broadcast
  EXPECT_EQ(sim_->nmt_state(), NmtState::kOperational);
  Nmt(NmtCommand::kStop, kNode + 1);  // another node's command
  EXPECT_EQ(sim_->nmt_state(), NmtState::kOperational);
  EXPECT_EQ(sim_->statistics().nmt_commands, 4u);
}

TEST_F(CanopenDriveSimTest, ResetCommunicationRestoresTheCommunicationObjects) {
  Boot();
  Download(kProducerHeartbeatTime, 0, 100, 2);
  Download(kTpdoCommunication, 1, kPdoCobIdInvalid | 0x185, 4);
  Download(cia402::kProfileVelocity, 0, 777, 4);
  Nmt(NmtCommand::kStart);
  const std::vector<CanFrame> frames = Exchange(EncodeNmt(NmtCommand::kResetCommunication, kNode));
  ASSERT_EQ(frames.size(), 1u);
  EXPECT_EQ(frames[0], CanFrame::Standard(0x705, {0x00}));
  EXPECT_EQ(sim_->nmt_state(), NmtState::kPreOperational);
  EXPECT_EQ(Upload(kProducerHeartbeatTime, 0), 0u);
  EXPECT_EQ(Upload(kTpdoCommunication, 1), 0x185u);
  EXPECT_EQ(Upload(cia402::kProfileVelocity, 0), 777u);  // application object: kept
}

TEST_F(CanopenDriveSimTest, ResetNodeResetsTheDriveToo) {
  Boot();
  Download(cia402::kModesOfOperation, 0, 9, 1);
  Download(cia402::kControlword, 0, 0x06, 2);
  ASSERT_EQ(sim_->device().state(), S::kReadyToSwitchOn);
  ASSERT_EQ(DownloadSegmented(0x2000, 0, "tag set", 7), 0u);
  const std::vector<CanFrame> frames = Exchange(EncodeNmt(NmtCommand::kResetNode, 0));
  ASSERT_EQ(frames.size(), 1u);
  EXPECT_EQ(frames[0], CanFrame::Standard(0x705, {0x00}));
  EXPECT_EQ(sim_->device().state(), S::kSwitchOnDisabled);
  EXPECT_EQ(Upload(cia402::kModesOfOperationDisplay, 0), 8u);
  EXPECT_EQ(UploadSegmented(0x2000, 0), "");
}

// ------------------------------------------------------------------------------------ SDO

TEST_F(CanopenDriveSimTest, ExpeditedUploadsWithTheRightSizes) {
  Boot();
  // 0x43: 4 bytes, 0x4B: 2 bytes, 0x4F: 1 byte.
  std::vector<CanFrame> f =
      Exchange(EncodeSdoRequest(kNode, SdoMessage::InitiateUpload(kDeviceType, 0)));
  ASSERT_EQ(f.size(), 1u);
  EXPECT_EQ(f[0], CanFrame::Standard(0x585, {0x43, 0x00, 0x10, 0x00, 0x92, 0x01, 0x02, 0x00}));
  f = Exchange(EncodeSdoRequest(kNode, SdoMessage::InitiateUpload(cia402::kStatusword, 0)));
  ASSERT_EQ(f.size(), 1u);
  EXPECT_EQ(f[0].data[0], 0x4B);
  EXPECT_EQ(GetLe(&f[0].data[4], 2) & 0x4F, 0x40u);  // Switch on disabled
  f = Exchange(EncodeSdoRequest(kNode, SdoMessage::InitiateUpload(cia402::kModesOfOperation, 0)));
  ASSERT_EQ(f.size(), 1u);
  EXPECT_EQ(f[0].data[0], 0x4F);
  EXPECT_EQ(f[0].data[4], 8);

  EXPECT_EQ(Upload(kIdentity, 0), 4u);
  EXPECT_EQ(Upload(kIdentity, 1), 0x004B5653u);
  EXPECT_EQ(Upload(kIdentity, 2), 0x0402u);
  EXPECT_EQ(Upload(kIdentity, 3), 7u);
  EXPECT_EQ(Upload(kIdentity, 4), 0x1234u);
  EXPECT_EQ(Upload(cia402::kSupportedDriveModes, 0), 0x38Du);
  EXPECT_EQ(Upload(kErrorRegister, 0), 0u);
  EXPECT_EQ(Upload(cia402::kSoftwarePositionLimit, 0), 2u);
  EXPECT_EQ(Upload(kTpdoMapping, 0), 2u);
  EXPECT_EQ(Upload(kTpdoMapping, 1), 0x60410010u);
  EXPECT_EQ(Upload(kTpdoMapping, 2), 0x60640020u);
  EXPECT_EQ(Upload(kRpdoMapping, 1), 0x60400010u);
  EXPECT_EQ(Upload(kRpdoMapping, 2), 0x607A0020u);
  EXPECT_EQ(Upload(kRpdoCommunication, 1), 0x205u);
  EXPECT_EQ(Upload(kRpdoCommunication + 1, 1), 0x80000305u);
  EXPECT_EQ(Upload(kTpdoCommunication, 2), 1u);
  EXPECT_EQ(sim_->statistics().sdo_requests, 19u);
}

TEST_F(CanopenDriveSimTest, ExpeditedDownloadsOfEverySize) {
  Boot();
  // 0x2F (1 byte), 0x2B (2 bytes), 0x23 (4 bytes), each answered 0x60.
  std::vector<CanFrame> f =
      Exchange(CanFrame::Standard(0x605, {0x2F, 0x60, 0x60, 0x00, 0x09, 0x00, 0x00, 0x00}));
  ASSERT_EQ(f.size(), 1u);
  EXPECT_EQ(f[0], CanFrame::Standard(0x585, {0x60, 0x60, 0x60, 0x00, 0, 0, 0, 0}));
  EXPECT_EQ(sim_->device().mode_display(), 9);
  f = Exchange(CanFrame::Standard(0x605, {0x2B, 0x40, 0x60, 0x00, 0x06, 0x00, 0x00, 0x00}));
  ASSERT_EQ(f.size(), 1u);
  EXPECT_EQ(f[0].data[0], 0x60);
  EXPECT_EQ(sim_->device().state(), S::kReadyToSwitchOn);
  f = Exchange(CanFrame::Standard(0x605, {0x23, 0xFF, 0x60, 0x00, 0x30, 0xF8, 0xFF, 0xFF}));
  ASSERT_EQ(f.size(), 1u);
  EXPECT_EQ(f[0].data[0], 0x60);
  EXPECT_EQ(sim_->device().snapshot().target_velocity, -2000);
  // Expedited without size indication (0x22): the object's own size.
  f = Exchange(CanFrame::Standard(0x605, {0x22, 0x7A, 0x60, 0x00, 0x10, 0x27, 0x00, 0x00}));
  ASSERT_EQ(f.size(), 1u);
  EXPECT_EQ(f[0].data[0], 0x60);
  EXPECT_EQ(sim_->device().snapshot().target_position, 10000);
  // Read back through the dictionary.
  EXPECT_EQ(static_cast<int32_t>(Upload(cia402::kTargetVelocity, 0)), -2000);
  EXPECT_EQ(Upload(cia402::kControlword, 0), 6u);
  Download(cia402::kSoftwarePositionLimit, 1, static_cast<uint32_t>(-5000), 4);
  Download(cia402::kSoftwarePositionLimit, 2, 5000, 4);
  EXPECT_EQ(sim_->device().snapshot().position_limit_min, -5000);
  EXPECT_EQ(sim_->device().snapshot().position_limit_max, 5000);
  Download(cia402::kQuickStopOptionCode, 0, 6, 2);
  Download(cia402::kFollowingErrorWindow, 0, 1234, 4);
  Download(cia402::kMaxProfileVelocity, 0, 50000, 4);
  Download(cia402::kProfileAcceleration, 0, 300000, 4);
  Download(cia402::kTargetTorque, 0, static_cast<uint16_t>(-150), 2);
  const Cia402Device::Snapshot s = sim_->device().snapshot();
  EXPECT_EQ(s.quick_stop_option_code, 6);
  EXPECT_EQ(s.following_error_window, 1234u);
  EXPECT_EQ(s.max_velocity, 50000u);
  EXPECT_EQ(s.profile_acceleration, 300000u);
  EXPECT_EQ(s.target_torque, -150);
}

TEST_F(CanopenDriveSimTest, SegmentedUploadOfTheDeviceName) {
  Boot();
  // Initiate: 0x41 (segmented, size indicated), size 23.
  std::vector<CanFrame> f =
      Exchange(EncodeSdoRequest(kNode, SdoMessage::InitiateUpload(0x1008, 0)));
  ASSERT_EQ(f.size(), 1u);
  EXPECT_EQ(f[0], CanFrame::Standard(0x585, {0x41, 0x08, 0x10, 0x00, 23, 0, 0, 0}));
  // Segments: toggle 0, 1, 0, 1; the last carries 2 bytes (n = 5) and c = 1.
  f = Exchange(CanFrame::Standard(0x605, {0x60, 0, 0, 0, 0, 0, 0, 0}));
  ASSERT_EQ(f.size(), 1u);
  EXPECT_EQ(f[0], CanFrame::Standard(0x585, {0x00, 'k', 'i', 'n', 'e', 'v', 'i', 's'}));
  f = Exchange(CanFrame::Standard(0x605, {0x70, 0, 0, 0, 0, 0, 0, 0}));
  ASSERT_EQ(f.size(), 1u);
  EXPECT_EQ(f[0], CanFrame::Standard(0x585, {0x10, ' ', 's', 'i', 'm', 'u', 'l', 'a'}));
  f = Exchange(CanFrame::Standard(0x605, {0x60, 0, 0, 0, 0, 0, 0, 0}));
  ASSERT_EQ(f.size(), 1u);
  EXPECT_EQ(f[0], CanFrame::Standard(0x585, {0x00, 't', 'e', 'd', ' ', 'd', 'r', 'i'}));
  f = Exchange(CanFrame::Standard(0x605, {0x70, 0, 0, 0, 0, 0, 0, 0}));
  ASSERT_EQ(f.size(), 1u);
  EXPECT_EQ(f[0].data[0], 0x10 | (5 << 1) | 1);
  EXPECT_EQ(f[0].data[1], 'v');
  EXPECT_EQ(f[0].data[2], 'e');
  EXPECT_EQ(UploadSegmented(0x1008, 0), "kinevis simulated drive");
}

TEST_F(CanopenDriveSimTest, SegmentedDownloads) {
  Boot();
  const std::string tag = "hexapod leg 3, left front";
  EXPECT_EQ(DownloadSegmented(0x2000, 0, tag, static_cast<uint32_t>(tag.size())), 0u);
  EXPECT_EQ(UploadSegmented(0x2000, 0), tag);
  // A short value segmented is answered expedited on upload.
  EXPECT_EQ(DownloadSegmented(0x2000, 0, "abc", 3), 0u);
  uint32_t size = 0;
  EXPECT_EQ(Upload(0x2000, 0, &size), 0x636261u);
  EXPECT_EQ(size, 3u);
  // A numeric object may be downloaded in segments as well.
  const uint8_t value[4] = {0x40, 0xE2, 0x01, 0x00};  // 123456
  EXPECT_EQ(DownloadSegmented(cia402::kTargetPosition, 0,
                              std::string(reinterpret_cast<const char*>(value), 4), 4),
            0u);
  EXPECT_EQ(sim_->device().snapshot().target_position, 123456);
}

TEST_F(CanopenDriveSimTest, EveryAbortPathWithItsCode) {
  Boot();
  using namespace sdo_abort;
  EXPECT_EQ(AbortCode(SdoMessage::InitiateUpload(0x5000, 0)), kObjectDoesNotExist);
  EXPECT_EQ(DownloadAbort(0x1005, 0, 0x80, 4), kObjectDoesNotExist);
  EXPECT_EQ(AbortCode(SdoMessage::InitiateUpload(kIdentity, 7)), kSubindexDoesNotExist);
  EXPECT_EQ(AbortCode(SdoMessage::InitiateUpload(kTpdoCommunication, 4)), kSubindexDoesNotExist);
  EXPECT_EQ(DownloadAbort(cia402::kControlword, 1, 6, 2), kSubindexDoesNotExist);
  EXPECT_EQ(DownloadAbort(cia402::kStatusword, 0, 0, 2), kReadOnly);
  EXPECT_EQ(DownloadAbort(kDeviceType, 0, 0, 4), kReadOnly);
  EXPECT_EQ(DownloadAbort(kIdentity, 1, 0, 4), kReadOnly);
  EXPECT_EQ(AbortCode(SdoMessage::SegmentedDownload(0x1008, 0, 4)), kReadOnly);
  EXPECT_EQ(DownloadAbort(cia402::kControlword, 0, 6, 4), kLengthTooHigh);
  EXPECT_EQ(DownloadAbort(cia402::kTargetPosition, 0, 6, 1), kLengthTooLow);
  EXPECT_EQ(AbortCode(SdoMessage::SegmentedDownload(0x2000, 0, 100)), kLengthTooHigh);
  EXPECT_EQ(AbortCode(SdoMessage::SegmentedDownload(cia402::kTargetPosition, 0, 2)), kLengthTooLow);
  EXPECT_EQ(DownloadSegmented(0x2000, 0, "123456789", 10), kLengthMismatch);
  EXPECT_EQ(DownloadSegmented(0x2000, 0, std::string(70, 'x'), std::nullopt), kLengthTooHigh);
  EXPECT_EQ(DownloadAbort(cia402::kQuickStopOptionCode, 0, 9, 2), kValueTooHigh);
  EXPECT_EQ(DownloadAbort(cia402::kQuickStopOptionCode, 0, 0xFFFF, 2), kValueTooLow);
  EXPECT_EQ(DownloadAbort(cia402::kMaxProfileVelocity, 0, 0, 4), kValueTooLow);
  EXPECT_EQ(DownloadAbort(cia402::kSoftwarePositionLimit, 1, 2000000000, 4), kValueTooHigh);
  EXPECT_EQ(DownloadAbort(cia402::kSoftwarePositionLimit, 2, static_cast<uint32_t>(-2000000000), 4),
            kValueTooLow);
  EXPECT_EQ(DownloadAbort(cia402::kModesOfOperation, 0, 6, 1), kInvalidValue);  // homing
  EXPECT_EQ(DownloadAbort(kTpdoCommunication, 2, 250, 1), kInvalidValue);
  EXPECT_EQ(DownloadAbort(kRpdoCommunication + 1, 1, 0x005, 4), kInvalidValue);  // restricted
  EXPECT_EQ(DownloadAbort(kTpdoCommunication, 1, 0x186, 4), kInvalidValue);      // valid: no change
  EXPECT_EQ(DownloadAbort(kTpdoCommunication + 1, 1, 0x20000285, 4), kInvalidValue);  // 29-bit
  // Toggle bit: the first upload segment must have toggle 0.
  ASSERT_EQ(Sdo(SdoMessage::InitiateUpload(0x1008, 0)).type, SdoType::kInitiateUploadResponse);
  EXPECT_EQ(AbortCode(SdoMessage::UploadSegment(true)), kToggleBitNotAlternated);
  ASSERT_EQ(Sdo(SdoMessage::SegmentedDownload(0x2000, 0, 10)).type,
            SdoType::kInitiateDownloadResponse);
  const uint8_t bytes[7] = {1, 2, 3, 4, 5, 6, 7};
  EXPECT_EQ(AbortCode(SdoMessage::DownloadSegment(true, bytes, 7, false)), kToggleBitNotAlternated);
  // Segments without an initiate, block transfer: invalid command specifier.
  EXPECT_EQ(AbortCode(SdoMessage::UploadSegment(false)), kInvalidCommandSpecifier);
  EXPECT_EQ(AbortCode(SdoMessage::DownloadSegment(false, bytes, 7, true)),
            kInvalidCommandSpecifier);
  const std::vector<CanFrame> block =
      Exchange(CanFrame::Standard(0x605, {0xC0, 0x08, 0x10, 0x00, 0, 0, 0, 0}));
  ASSERT_EQ(block.size(), 1u);
  EXPECT_EQ(block[0], CanFrame::Standard(0x585, {0x80, 0x08, 0x10, 0x00, 0x01, 0x00, 0x04, 0x05}));
  // Mapping: a valid PDO, an object that cannot be mapped, too long a PDO.
  EXPECT_EQ(DownloadAbort(kTpdoMapping, 0, 0, 1), kUnsupportedAccess);
  EXPECT_EQ(DownloadAbort(kTpdoMapping, 1, 0x60410010, 4), kUnsupportedAccess);
  Download(kTpdoCommunication, 1, kPdoCobIdInvalid | 0x185, 4);
  EXPECT_EQ(DownloadAbort(kTpdoMapping, 1, 0x60410010, 4), kUnsupportedAccess) << "sub 0 != 0";
  Download(kTpdoMapping, 0, 0, 1);
  EXPECT_EQ(DownloadAbort(kTpdoMapping, 1, 0x10000020, 4), kCannotBeMapped);      // 0x1000
  EXPECT_EQ(DownloadAbort(kTpdoMapping, 1, 0x60410020, 4), kCannotBeMapped);      // wrong length
  EXPECT_EQ(DownloadAbort(kRpdoMapping + 1, 1, 0x60410010, 4), kCannotBeMapped);  // read-only
  Download(kTpdoMapping, 1, 0x60640020, 4);
  Download(kTpdoMapping, 2, 0x606C0020, 4);
  Download(kTpdoMapping, 3, 0x60F40020, 4);
  EXPECT_EQ(DownloadAbort(kTpdoMapping, 0, 3, 1), kPdoLengthExceeded);  // 96 bits
  EXPECT_EQ(DownloadAbort(kTpdoMapping, 0, 9, 1), kPdoLengthExceeded);
  EXPECT_EQ(sim_->statistics().sdo_aborts_sent, 38u);
}

TEST_F(CanopenDriveSimTest, IdleSegmentedTransferTimesOut) {
  Boot();
  ASSERT_EQ(Sdo(SdoMessage::InitiateUpload(0x1008, 0)).type, SdoType::kInitiateUploadResponse);
  EXPECT_TRUE(WithId(Run(900ms, 100ms), 0x585).empty());
  const std::vector<CanFrame> f = WithId(Run(200ms, 100ms), 0x585);
  ASSERT_EQ(f.size(), 1u);
  const auto abort = DecodeSdoResponse(f[0]);
  ASSERT_TRUE(abort.has_value());
  EXPECT_EQ(abort->type, SdoType::kAbort);
  EXPECT_EQ(abort->index, 0x1008);
  EXPECT_EQ(abort->abort_code, sdo_abort::kProtocolTimedOut);
  // The transfer is gone.
  EXPECT_EQ(AbortCode(SdoMessage::UploadSegment(false)), sdo_abort::kInvalidCommandSpecifier);
}

TEST_F(CanopenDriveSimTest, ClientAbortEndsTheTransferSilently) {
  Boot();
  ASSERT_EQ(Sdo(SdoMessage::InitiateUpload(0x1008, 0)).type, SdoType::kInitiateUploadResponse);
  EXPECT_TRUE(
      Exchange(EncodeSdoRequest(kNode, SdoMessage::Abort(0x1008, 0, sdo_abort::kGeneralError)))
          .empty());
  EXPECT_EQ(AbortCode(SdoMessage::UploadSegment(false)), sdo_abort::kInvalidCommandSpecifier);
}

// ------------------------------------------------------------------------------------ PDO

TEST_F(CanopenDriveSimTest, SyncTriggersTheDefaultTpdoInOperationalOnly) {
  Boot();
  EXPECT_TRUE(Sync().empty()) << "no PDOs in pre-operational";
  Nmt(NmtCommand::kStart);
  std::vector<CanFrame> f = Sync();
  ASSERT_EQ(f.size(), 1u);
  EXPECT_EQ(f[0].id, 0x185u);
  EXPECT_EQ(f[0].dlc, 6);
  EXPECT_EQ(GetLe(&f[0].data[0], 2) & 0x4F, 0x40u);  // statusword: switch on disabled
  EXPECT_EQ(GetLe(&f[0].data[2], 4), 0u);            // position actual
  EXPECT_EQ(Sync().size(), 1u);
  const CanopenDriveSim::Statistics s = sim_->statistics();
  EXPECT_EQ(s.syncs, 3u);
  EXPECT_EQ(s.tpdos, 2u);
}

TEST_F(CanopenDriveSimTest, TransmissionTypesEveryNthSyncAndOnChange) {
  Boot();
  Download(kTpdoCommunication, 2, 3, 1);  // every 3rd SYNC
  Nmt(NmtCommand::kStart);
  int sent = 0;
  for (int i = 0; i < 9; ++i) sent += static_cast<int>(Sync().size());
  EXPECT_EQ(sent, 3);
  // Type 0: on a SYNC after a change only.
  Download(kTpdoCommunication, 2, 0, 1);
  EXPECT_EQ(Sync().size(), 1u);  // first time
  EXPECT_EQ(Sync().size(), 0u);
  Download(cia402::kControlword, 0, 0x06, 2);  // statusword changes
  EXPECT_EQ(Sync().size(), 1u);
  EXPECT_EQ(Sync().size(), 0u);
}

TEST_F(CanopenDriveSimTest, RpdoTargetsAreAppliedAtTheNextSync) {
  Boot();
  Nmt(NmtCommand::kStart);
  // RPDO1 = controlword + target position (synchronous): buffered until SYNC.
  auto rpdo = [](uint16_t cw, int32_t target) {
    CanFrame f = CanFrame::Standard(0x205, {0, 0, 0, 0, 0, 0});
    PutLe(&f.data[0], cw, 2);
    PutLe(&f.data[2], static_cast<uint32_t>(target), 4);
    return f;
  };
  EXPECT_TRUE(Exchange(rpdo(0x06, 0)).empty());
  EXPECT_EQ(sim_->device().state(), S::kSwitchOnDisabled);
  std::vector<CanFrame> f = Sync();
  EXPECT_EQ(sim_->device().state(), S::kReadyToSwitchOn);
  ASSERT_EQ(f.size(), 1u);
  EXPECT_EQ(GetLe(&f[0].data[0], 2) & 0x6F, 0x21u);  // the TPDO after the SYNC shows it
  Exchange(rpdo(0x07, 0));
  Sync();
  Exchange(rpdo(0x0F, 0));
  f = Sync();
  ASSERT_EQ(sim_->device().state(), S::kOperationEnabled);
  EXPECT_EQ(GetLe(&f[0].data[0], 2) & 0x6F, 0x27u);
  // CSP: one set-point per SYNC, followed exactly (feed-forward from the set-points).
  int32_t target = 0;
  for (int i = 1; i <= 40; ++i) {
    target += i;  // accelerating at 250000 counts/s^2 with 2 ms cycles: within the limits
    Exchange(rpdo(0x0F, target));
    f = Sync(2ms);
    ASSERT_EQ(f.size(), 1u);
    EXPECT_EQ(static_cast<int32_t>(GetLe(&f[0].data[2], 4)), target) << "cycle " << i;
  }
  EXPECT_EQ(sim_->device().snapshot().target_position, target);
  EXPECT_EQ(sim_->statistics().rpdos, 43u);
  // A short RPDO is not processed.
  Exchange(CanFrame::Standard(0x205, {0x06, 0x00}));
  Sync();
  EXPECT_EQ(sim_->device().state(), S::kOperationEnabled);
  EXPECT_EQ(sim_->statistics().rpdos, 43u);
}

TEST_F(CanopenDriveSimTest, CyclicModeMovesOnSyncOnly) {
  Boot();
  Download(cia402::kModesOfOperation, 0, 9, 1);  // CSV
  Download(cia402::kTargetVelocity, 0, 10000, 4);
  for (uint16_t cw : {0x06, 0x07, 0x0F}) Download(cia402::kControlword, 0, cw, 2);
  Nmt(NmtCommand::kStart);
  for (int i = 0; i < 20; ++i) Sync();
  const int32_t at_sync = sim_->device().position();
  EXPECT_GT(at_sync, 0);
  Run(20ms);  // no SYNC, but within the SYNC loss timeout: no motion
  EXPECT_EQ(sim_->device().position(), at_sync);
  Run(100ms);  // SYNC lost: stepped on the clock again
  EXPECT_GT(sim_->device().position(), at_sync + 500);
}

TEST_F(CanopenDriveSimTest, ProfileModeMovesOnTheClock) {
  Boot();
  Download(cia402::kModesOfOperation, 0, 1, 1);  // PP
  Download(cia402::kProfileVelocity, 0, 20000, 4);
  Download(cia402::kProfileAcceleration, 0, 200000, 4);
  Download(cia402::kTargetPosition, 0, 3000, 4);
  for (uint16_t cw : {0x06, 0x07, 0x0F, 0x1F}) Download(cia402::kControlword, 0, cw, 2);
  Run(500ms, 5ms);
  EXPECT_EQ(static_cast<int32_t>(Upload(cia402::kPositionActualValue, 0)), 3000);
  EXPECT_NE(Upload(cia402::kStatusword, 0) & cia402::kSwTargetReached, 0u);
}

TEST_F(CanopenDriveSimTest, PdoRemappingBySdo) {
  Boot();
  // TPDO1: statusword, velocity actual, mode display (7 bytes).
  Download(kTpdoCommunication, 1, kPdoCobIdInvalid | 0x185, 4);
  Download(kTpdoMapping, 0, 0, 1);
  Download(kTpdoMapping, 1, PdoMappingEntry{cia402::kStatusword, 0, 16}.Encode(), 4);
  Download(kTpdoMapping, 2, PdoMappingEntry{cia402::kVelocityActualValue, 0, 32}.Encode(), 4);
  Download(kTpdoMapping, 3, PdoMappingEntry{cia402::kModesOfOperationDisplay, 0, 8}.Encode(), 4);
  Download(kTpdoMapping, 0, 3, 1);
  Download(kTpdoCommunication, 1, 0x185, 4);
  // RPDO2 on 0x305: controlword, target velocity, modes of operation, event-driven.
  const uint16_t rpdo2 = kRpdoCommunication + 1, map2 = kRpdoMapping + 1;
  Download(map2, 1, PdoMappingEntry{cia402::kControlword, 0, 16}.Encode(), 4);
  Download(map2, 2, PdoMappingEntry{cia402::kTargetVelocity, 0, 32}.Encode(), 4);
  Download(map2, 3, PdoMappingEntry{cia402::kModesOfOperation, 0, 8}.Encode(), 4);
  Download(map2, 0, 3, 1);
  Download(rpdo2, 2, kTransmissionEventDriven, 1);
  Download(rpdo2, 1, 0x305, 4);
  EXPECT_EQ(Upload(map2, 0), 3u);
  Nmt(NmtCommand::kStart);
  // Event-driven RPDO: applied at once, the controlword after the mode.
  auto rpdo = [](uint16_t cw, int32_t velocity, int8_t mode) {
    CanFrame f = CanFrame::Standard(0x305, {0, 0, 0, 0, 0, 0, 0});
    PutLe(&f.data[0], cw, 2);
    PutLe(&f.data[2], static_cast<uint32_t>(velocity), 4);
    f.data[6] = static_cast<uint8_t>(mode);
    return f;
  };
  for (uint16_t cw : {0x06, 0x07, 0x0F}) Exchange(rpdo(cw, 20000, 9));
  EXPECT_EQ(sim_->device().state(), S::kOperationEnabled);
  EXPECT_EQ(sim_->device().mode_display(), 9);
  for (int i = 0; i < 50; ++i) Sync();
  const std::vector<CanFrame> f = Sync();
  ASSERT_EQ(f.size(), 1u);
  EXPECT_EQ(f[0].id, 0x185u);
  EXPECT_EQ(f[0].dlc, 7);
  EXPECT_EQ(GetLe(&f[0].data[0], 2) & 0x6F, 0x27u);
  EXPECT_EQ(static_cast<int32_t>(GetLe(&f[0].data[2], 4)), 20000);
  EXPECT_EQ(f[0].data[6], 9);
  // Disable voltage through RPDO2: applied at once, without a SYNC.
  EXPECT_TRUE(Exchange(rpdo(0x00, 0, 9)).empty());
  EXPECT_EQ(sim_->device().state(), S::kSwitchOnDisabled);
}

TEST_F(CanopenDriveSimTest, EventDrivenTpdoOnChangeAndOnTheEventTimer) {
  Boot();
  Download(kTpdoCommunication + 1, 2, kTransmissionEventDriven, 1);
  Download(kTpdoMapping + 1, 1, PdoMappingEntry{cia402::kStatusword, 0, 16}.Encode(), 4);
  Download(kTpdoMapping + 1, 0, 1, 1);
  Download(kTpdoCommunication + 1, 5, 100, 2);  // event timer 100 ms
  Download(kTpdoCommunication + 1, 1, 0x285, 4);
  Download(kTpdoCommunication, 1, kPdoCobIdInvalid | 0x185, 4);  // TPDO1 off
  Nmt(NmtCommand::kStart);
  std::vector<CanFrame> f = WithId(Run(10ms), 0x285);
  EXPECT_EQ(f.size(), 1u);  // first transmission
  f = WithId(Run(250ms, 10ms), 0x285);
  EXPECT_EQ(f.size(), 2u);              // unchanged: the event timer only (at 100 and 200 ms)
  sim_->device().SetControlword(0x06);  // the statusword changes
  f = WithId(Run(1ms), 0x285);
  ASSERT_EQ(f.size(), 1u);  // changed
  EXPECT_EQ(GetLe(&f[0].data[0], 2) & 0x6F, 0x21u);
}

// ------------------------------------------------------------------------------------ heartbeat

TEST_F(CanopenDriveSimTest, HeartbeatAtTheConfiguredPeriodWithTheNmtState) {
  Boot();
  EXPECT_TRUE(WithId(Run(500ms, 10ms), 0x705).empty()) << "off by default";
  Download(kProducerHeartbeatTime, 0, 100, 2);
  std::vector<common::Duration> times;
  std::vector<uint8_t> states;
  for (int i = 0; i < 50; ++i) {
    if (i == 25) Nmt(NmtCommand::kStart);
    for (const CanFrame& f : WithId(Run(10ms), 0x705)) {
      times.push_back(clock_.Now());
      states.push_back(f.data[0]);
    }
  }
  ASSERT_EQ(times.size(), 5u);
  for (size_t i = 1; i < times.size(); ++i) EXPECT_EQ(times[i] - times[i - 1], 100ms);
  EXPECT_EQ(states.front(), 0x7F);
  EXPECT_EQ(states.back(), 0x05);
  EXPECT_EQ(sim_->statistics().heartbeats, 5u);
}

// ------------------------------------------------------------------------------------ EMCY

TEST_F(CanopenDriveSimTest, EmcyWhenAFaultIsReachedAndAfterTheReset) {
  Boot();
  sim_->RaiseFault(0x2310);
  EXPECT_TRUE(WithId(Run(5ms), 0x085).empty()) << "still in fault reaction";
  std::vector<CanFrame> f = WithId(Run(10ms), 0x085);
  ASSERT_EQ(f.size(), 1u);
  EXPECT_EQ(f[0], CanFrame::Standard(0x085, {0x10, 0x23, 0x03, 0, 0, 0, 0, 0}));
  EXPECT_EQ(sim_->device().state(), S::kFault);
  EXPECT_EQ(Upload(cia402::kErrorCode, 0), 0x2310u);
  EXPECT_EQ(Upload(kErrorRegister, 0), 0x03u);
  EXPECT_TRUE(WithId(Run(100ms, 10ms), 0x085).empty()) << "one EMCY per fault";
  // Fault reset (rising edge of bit 7) by SDO.
  Send(EncodeSdoRequest(kNode, DownloadRequest(cia402::kControlword, 0, 0x80, 2)));
  sim_->Service();
  f = WithId(Frames(), 0x085);
  ASSERT_EQ(f.size(), 1u);
  EXPECT_EQ(f[0], CanFrame::Standard(0x085, {0, 0, 0, 0, 0, 0, 0, 0}));
  EXPECT_EQ(sim_->device().state(), S::kSwitchOnDisabled);
  EXPECT_EQ(Upload(kErrorRegister, 0), 0u);
  EXPECT_EQ(sim_->statistics().emcys, 2u);
}

TEST_F(CanopenDriveSimTest, FollowingErrorFaultSendsItsEmcy) {
  Boot();
  for (uint16_t cw : {0x06, 0x07, 0x0F}) Download(cia402::kControlword, 0, cw, 2);
  Nmt(NmtCommand::kStart);
  Download(cia402::kTargetPosition, 0, 50000, 4);  // beyond the 10000-count window
  std::vector<CanFrame> emcy;
  for (int i = 0; i < 30; ++i) {
    for (const CanFrame& f : WithId(Sync(), 0x085)) emcy.push_back(f);
  }
  ASSERT_EQ(emcy.size(), 1u);
  const auto m = DecodeEmcy(emcy[0]);
  ASSERT_TRUE(m.has_value());
  EXPECT_EQ(m->error_code, 0x8611);
  EXPECT_EQ(m->error_register, 0x21);  // generic + device profile
}

TEST_F(CanopenDriveSimTest, NoEmcyInStopped) {
  Boot();
  Nmt(NmtCommand::kStop);
  sim_->RaiseFault(0x5000);
  EXPECT_TRUE(WithId(Run(50ms), 0x085).empty());
  EXPECT_EQ(sim_->device().state(), S::kFault);
}

// ------------------------------------------------------------------------------------ faults

TEST_F(CanopenDriveSimTest, DropNextRepliesLosesSdoResponsesAndTpdos) {
  Boot();
  sim_->DropNextReplies(2);
  EXPECT_TRUE(Exchange(EncodeSdoRequest(kNode, SdoMessage::InitiateUpload(0x1000, 0))).empty());
  Nmt(NmtCommand::kStart);
  EXPECT_TRUE(Sync().empty());  // the TPDO is the second reply dropped
  EXPECT_EQ(Sync().size(), 1u);
  EXPECT_EQ(Upload(kDeviceType, 0), 0x00020192u);
  EXPECT_EQ(sim_->statistics().tpdos, 1u);
}

TEST_F(CanopenDriveSimTest, ReplyDelay) {
  Boot();
  sim_->SetReplyDelay(5ms);
  EXPECT_TRUE(Exchange(EncodeSdoRequest(kNode, SdoMessage::InitiateUpload(0x1000, 0))).empty());
  EXPECT_TRUE(WithId(Run(4ms), 0x585).empty());
  EXPECT_EQ(WithId(Run(1ms), 0x585).size(), 1u);
  sim_->SetReplyDelay(0us);
  EXPECT_EQ(Upload(kDeviceType, 0), 0x00020192u);
}

TEST_F(CanopenDriveSimTest, MalformedSdoReplies) {
  Boot();
  sim_->SendMalformedSdoReplies(1);
  const std::vector<CanFrame> f =
      Exchange(EncodeSdoRequest(kNode, SdoMessage::InitiateUpload(0x1000, 0)));
  ASSERT_EQ(f.size(), 1u);
  EXPECT_EQ(f[0].dlc, 5);
  std::string error;
  EXPECT_FALSE(DecodeSdoResponse(f[0], &error).has_value());
  EXPECT_THAT(error, ::testing::ContainsRegex("8 bytes"));
  EXPECT_EQ(Upload(kDeviceType, 0), 0x00020192u);  // the next one is fine
}

TEST_F(CanopenDriveSimTest, StopHeartbeatSilencesTheProducer) {
  Boot();
  Download(kProducerHeartbeatTime, 0, 50, 2);
  EXPECT_EQ(WithId(Run(200ms, 10ms), 0x705).size(), 4u);
  sim_->StopHeartbeat(true);
  EXPECT_TRUE(WithId(Run(500ms, 10ms), 0x705).empty());
  EXPECT_EQ(Upload(kDeviceType, 0), 0x00020192u) << "SDO still served";
  sim_->StopHeartbeat(false);
  EXPECT_EQ(WithId(Run(200ms, 10ms), 0x705).size(), 4u);
}

TEST_F(CanopenDriveSimTest, DisconnectIsDeafAndMute) {
  Boot();
  Download(kProducerHeartbeatTime, 0, 50, 2);
  sim_->Disconnect(true);
  EXPECT_TRUE(Exchange(EncodeSdoRequest(kNode, SdoMessage::InitiateUpload(0x1000, 0))).empty());
  Send(EncodeNmt(NmtCommand::kStart, kNode));
  sim_->RaiseFault(0x3210);
  EXPECT_TRUE(Run(300ms, 10ms).empty());  // no heartbeat, no EMCY, no answer
  EXPECT_EQ(sim_->device().state(), S::kFault) << "the drive itself runs on";
  sim_->Disconnect(false);
  sim_->Service();
  EXPECT_EQ(sim_->nmt_state(), NmtState::kPreOperational) << "frames sent meanwhile are lost";
  EXPECT_EQ(WithId(Run(100ms, 10ms), 0x705).size(), 2u);
  EXPECT_EQ(Upload(kDeviceType, 0), 0x00020192u);
}

TEST_F(CanopenDriveSimTest, BadOptionsThrow) {
  CanopenDriveSim::Options o = DefaultOptions();
  o.node = 0;
  o.device.limits.max_acceleration = 0;
  try {
    CanopenDriveSim sim(drive_bus_.get(), &clock_, o);
    FAIL() << "no exception";
  } catch (const common::ConfigError& e) {
    EXPECT_THAT(std::string(e.what()), ::testing::ContainsRegex("node 0 is outside 1\\.\\.127"));
    EXPECT_THAT(std::string(e.what()), ::testing::ContainsRegex("max_acceleration 0"));
  }
}

TEST(CanopenDriveSimThreadTest, StartServesInRealTime) {
  auto network =
      std::make_shared<VirtualCanNetwork>("canopen-drive-sim-thread", VirtualCanNetwork::Options{});
  auto host = network->Connect("host");
  auto drive = network->Connect("drive");
  CanopenDriveSim::Options o;
  o.node = 9;
  CanopenDriveSim sim(drive.get(), &common::SteadyClock::Instance(), o);
  sim.Start();
  CanFrame f;
  ASSERT_FALSE(host->Receive(&f, 5s));
  EXPECT_EQ(f, CanFrame::Standard(0x709, {0x00}));
  ASSERT_FALSE(host->Send(EncodeSdoRequest(9, SdoMessage::InitiateUpload(kIdentity, 1))));
  ASSERT_FALSE(host->Receive(&f, 5s));
  EXPECT_EQ(f, CanFrame::Standard(0x589, {0x43, 0x18, 0x10, 0x01, 0x53, 0x56, 0x4B, 0x00}));
  sim.Stop();
  sim.Stop();  // idempotent
}

}  // namespace
}  // namespace kinevis::hal
