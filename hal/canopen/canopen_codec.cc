#include "hal/canopen/canopen_codec.h"

#include <cstring>

#include "common/check.h"

namespace kinevis::hal::canopen {
namespace {

bool Fail(std::string* error, const char* message) {
  if (error != nullptr) *error = message;
  return false;
}

void PutMultiplexer(CanFrame* f, uint16_t index, uint8_t subindex) {
  f->data[1] = static_cast<uint8_t>(index);
  f->data[2] = static_cast<uint8_t>(index >> 8);
  f->data[3] = subindex;
}

void GetMultiplexer(const CanFrame& f, SdoMessage* m) {
  m->index = static_cast<uint16_t>(f.data[1] | f.data[2] << 8);
  m->subindex = f.data[3];
}

CanFrame SdoFrame(uint32_t cob_id) {
  CanFrame f;
  f.id = cob_id;
  f.dlc = 8;
  return f;
}

// Segment layout shared by download segment requests and upload segment responses:
// bit 4 toggle, bits 3..1 n (bytes unused of 7), bit 0 c (last).
void EncodeSegment(const SdoMessage& m, uint8_t ccs, CanFrame* f) {
  KINEVIS_DEMAND(m.data_length <= 7);
  f->data[0] = static_cast<uint8_t>(ccs << 5 | (m.toggle ? 0x10 : 0) | (7 - m.data_length) << 1 |
                                    (m.last ? 1 : 0));
  std::memcpy(&f->data[1], m.data.data(), m.data_length);
}

void DecodeSegment(const CanFrame& f, SdoMessage* m) {
  m->toggle = (f.data[0] & 0x10) != 0;
  m->data_length = static_cast<uint8_t>(7 - ((f.data[0] >> 1) & 0x07));
  m->last = (f.data[0] & 0x01) != 0;
  std::memcpy(m->data.data(), &f.data[1], 7);
}

// Initiate layout shared by initiate download requests and initiate upload responses:
// bits 3..2 n (bytes unused of 4, valid when e and s), bit 1 e (expedited), bit 0 s (size).
void EncodeInitiate(const SdoMessage& m, uint8_t cs, CanFrame* f) {
  PutMultiplexer(f, m.index, m.subindex);
  if (m.expedited) {
    KINEVIS_DEMAND(m.size >= 1 && m.size <= 4);
    f->data[0] = static_cast<uint8_t>(cs << 5 | (4 - m.size) << 2 | 0x02 | 0x01);
    std::memcpy(&f->data[4], m.data.data(), m.size);
  } else {
    f->data[0] = static_cast<uint8_t>(cs << 5 | (m.size_indicated ? 0x01 : 0));
    PutLe(&f->data[4], m.size_indicated ? m.size : 0, 4);
  }
}

void DecodeInitiate(const CanFrame& f, SdoMessage* m) {
  GetMultiplexer(f, m);
  m->expedited = (f.data[0] & 0x02) != 0;
  m->size_indicated = (f.data[0] & 0x01) != 0;
  if (m->expedited) {
    // Expedited without size indication: 4 bytes, of which the meaningful ones are unknown.
    m->size = m->size_indicated ? 4u - ((f.data[0] >> 2) & 0x03) : 4u;
    std::memcpy(m->data.data(), &f.data[4], 4);
  } else {
    m->size = m->size_indicated ? GetLe(&f.data[4], 4) : 0;
  }
}

void EncodeAbort(const SdoMessage& m, CanFrame* f) {
  f->data[0] = 0x80;
  PutMultiplexer(f, m.index, m.subindex);
  PutLe(&f->data[4], m.abort_code, 4);
}

void DecodeAbort(const CanFrame& f, SdoMessage* m) {
  m->type = SdoType::kAbort;
  GetMultiplexer(f, m);
  m->abort_code = GetLe(&f.data[4], 4);
}

}  // namespace

const char* ToString(NmtCommand command) {
  switch (command) {
    case NmtCommand::kStart:
      return "start";
    case NmtCommand::kStop:
      return "stop";
    case NmtCommand::kEnterPreOperational:
      return "enter pre-operational";
    case NmtCommand::kResetNode:
      return "reset node";
    case NmtCommand::kResetCommunication:
      return "reset communication";
  }
  return "?";
}

const char* ToString(NmtState state) {
  switch (state) {
    case NmtState::kBootUp:
      return "boot-up";
    case NmtState::kStopped:
      return "stopped";
    case NmtState::kOperational:
      return "operational";
    case NmtState::kPreOperational:
      return "pre-operational";
  }
  return "?";
}

CanFrame EncodeNmt(NmtCommand command, uint8_t node) {
  return CanFrame::Standard(kNmtCobId, {static_cast<uint8_t>(command), node});
}

std::optional<NmtMessage> DecodeNmt(const CanFrame& frame) {
  if (frame.extended || frame.rtr || frame.id != kNmtCobId || frame.dlc != 2) return std::nullopt;
  switch (frame.data[0]) {
    case 0x01:
    case 0x02:
    case 0x80:
    case 0x81:
    case 0x82:
      break;
    default:
      return std::nullopt;
  }
  if (frame.data[1] > kMaxNodeId) return std::nullopt;
  return NmtMessage{static_cast<NmtCommand>(frame.data[0]), frame.data[1]};
}

CanFrame EncodeHeartbeat(uint8_t node, NmtState state) {
  KINEVIS_DEMAND(node >= 1 && node <= kMaxNodeId);
  return CanFrame::Standard(kHeartbeatBase + node, {static_cast<uint8_t>(state)});
}

std::optional<HeartbeatMessage> DecodeHeartbeat(const CanFrame& frame) {
  if (frame.extended || frame.rtr || frame.dlc != 1) return std::nullopt;
  if (frame.id <= kHeartbeatBase || frame.id > kHeartbeatBase + kMaxNodeId) return std::nullopt;
  const uint8_t s = frame.data[0] & 0x7F;  // bit 7 is the toggle bit of node guarding
  if (s != 0x00 && s != 0x04 && s != 0x05 && s != 0x7F) return std::nullopt;
  return HeartbeatMessage{static_cast<uint8_t>(frame.id - kHeartbeatBase),
                          static_cast<NmtState>(s)};
}

CanFrame EncodeSync(std::optional<uint8_t> counter) {
  if (counter) return CanFrame::Standard(kSyncCobId, {*counter});
  return CanFrame::Standard(kSyncCobId);
}

bool IsSync(const CanFrame& frame) {
  return !frame.extended && !frame.rtr && frame.id == kSyncCobId && frame.dlc <= 1;
}

CanFrame EncodeEmcy(const EmcyMessage& emcy) {
  KINEVIS_DEMAND(emcy.node >= 1 && emcy.node <= kMaxNodeId);
  CanFrame f;
  f.id = kEmcyBase + emcy.node;
  f.dlc = 8;
  PutLe(&f.data[0], emcy.error_code, 2);
  f.data[2] = emcy.error_register;
  std::memcpy(&f.data[3], emcy.manufacturer.data(), 5);
  return f;
}

std::optional<EmcyMessage> DecodeEmcy(const CanFrame& frame) {
  if (frame.extended || frame.rtr || frame.dlc != 8) return std::nullopt;
  if (frame.id <= kEmcyBase || frame.id > kEmcyBase + kMaxNodeId) return std::nullopt;
  EmcyMessage m;
  m.node = static_cast<uint8_t>(frame.id - kEmcyBase);
  m.error_code = static_cast<uint16_t>(GetLe(&frame.data[0], 2));
  m.error_register = frame.data[2];
  std::memcpy(m.manufacturer.data(), &frame.data[3], 5);
  return m;
}

std::string EmcyErrorText(uint16_t code) {
  if (code == 0x0000) return "error reset or no error";
  // CiA 402 codes kinevis' drives use, then the CiA 301 classes by the high byte.
  switch (code) {
    case 0x8611:
      return "following error";
    case 0x8612:
      return "reference limit";
    case 0x7121:
      return "motor blocked";
    case 0x2310:
      return "continuous over-current";
    case 0x3210:
      return "DC link over-voltage";
    case 0x3220:
      return "DC link under-voltage";
    case 0x4310:
      return "drive over-temperature";
    case 0x8130:
      return "life guard or heartbeat error";
    case 0x8110:
      return "CAN overrun (objects lost)";
    case 0x8120:
      return "CAN in error-passive mode";
    case 0x8140:
      return "recovered from bus-off";
    case 0xFF00:
      return "manufacturer specific";
    default:
      break;
  }
  switch (code >> 12) {
    case 0x1:
      return "generic error";
    case 0x2:
      return "current";
    case 0x3:
      return "voltage";
    case 0x4:
      return "temperature";
    case 0x5:
      return "device hardware";
    case 0x6:
      return "device software";
    case 0x7:
      return "additional modules";
    case 0x8:
      return "monitoring";
    case 0x9:
      return "external error";
    case 0xF:
      return "additional functions";
    default:
      return "unknown error class";
  }
}

SdoMessage SdoMessage::ExpeditedDownload(uint16_t index, uint8_t subindex, const uint8_t* bytes,
                                         uint8_t size) {
  KINEVIS_DEMAND(size >= 1 && size <= 4);
  SdoMessage m;
  m.type = SdoType::kInitiateDownloadRequest;
  m.index = index;
  m.subindex = subindex;
  m.expedited = true;
  m.size_indicated = true;
  m.size = size;
  std::memcpy(m.data.data(), bytes, size);
  return m;
}

SdoMessage SdoMessage::SegmentedDownload(uint16_t index, uint8_t subindex, uint32_t total_size) {
  SdoMessage m;
  m.type = SdoType::kInitiateDownloadRequest;
  m.index = index;
  m.subindex = subindex;
  m.size_indicated = true;
  m.size = total_size;
  return m;
}

SdoMessage SdoMessage::DownloadSegment(bool toggle, const uint8_t* bytes, uint8_t size, bool last) {
  KINEVIS_DEMAND(size <= 7);
  SdoMessage m;
  m.type = SdoType::kDownloadSegmentRequest;
  m.toggle = toggle;
  m.last = last;
  m.data_length = size;
  if (size > 0) std::memcpy(m.data.data(), bytes, size);
  return m;
}

SdoMessage SdoMessage::InitiateUpload(uint16_t index, uint8_t subindex) {
  SdoMessage m;
  m.type = SdoType::kInitiateUploadRequest;
  m.index = index;
  m.subindex = subindex;
  return m;
}

SdoMessage SdoMessage::UploadSegment(bool toggle) {
  SdoMessage m;
  m.type = SdoType::kUploadSegmentRequest;
  m.toggle = toggle;
  return m;
}

SdoMessage SdoMessage::InitiateDownloadResponse(uint16_t index, uint8_t subindex) {
  SdoMessage m;
  m.type = SdoType::kInitiateDownloadResponse;
  m.index = index;
  m.subindex = subindex;
  return m;
}

SdoMessage SdoMessage::DownloadSegmentResponse(bool toggle) {
  SdoMessage m;
  m.type = SdoType::kDownloadSegmentResponse;
  m.toggle = toggle;
  return m;
}

SdoMessage SdoMessage::ExpeditedUploadResponse(uint16_t index, uint8_t subindex,
                                               const uint8_t* bytes, uint8_t size) {
  SdoMessage m = ExpeditedDownload(index, subindex, bytes, size);
  m.type = SdoType::kInitiateUploadResponse;
  return m;
}

SdoMessage SdoMessage::SegmentedUploadResponse(uint16_t index, uint8_t subindex,
                                               uint32_t total_size) {
  SdoMessage m = SegmentedDownload(index, subindex, total_size);
  m.type = SdoType::kInitiateUploadResponse;
  return m;
}

SdoMessage SdoMessage::UploadSegmentResponse(bool toggle, const uint8_t* bytes, uint8_t size,
                                             bool last) {
  SdoMessage m = DownloadSegment(toggle, bytes, size, last);
  m.type = SdoType::kUploadSegmentResponse;
  return m;
}

SdoMessage SdoMessage::Abort(uint16_t index, uint8_t subindex, uint32_t code) {
  SdoMessage m;
  m.type = SdoType::kAbort;
  m.index = index;
  m.subindex = subindex;
  m.abort_code = code;
  return m;
}

CanFrame EncodeSdoRequest(uint8_t node, const SdoMessage& m) {
  CanFrame f = SdoFrame(kSdoRequestBase + node);
  switch (m.type) {
    case SdoType::kInitiateDownloadRequest:
      EncodeInitiate(m, 1, &f);
      break;
    case SdoType::kDownloadSegmentRequest:
      EncodeSegment(m, 0, &f);
      break;
    case SdoType::kInitiateUploadRequest:
      f.data[0] = 2 << 5;
      PutMultiplexer(&f, m.index, m.subindex);
      break;
    case SdoType::kUploadSegmentRequest:
      f.data[0] = static_cast<uint8_t>(3 << 5 | (m.toggle ? 0x10 : 0));
      break;
    case SdoType::kAbort:
      EncodeAbort(m, &f);
      break;
    default:
      KINEVIS_UNREACHABLE();  // not an SDO request
  }
  return f;
}

CanFrame EncodeSdoResponse(uint8_t node, const SdoMessage& m) {
  CanFrame f = SdoFrame(kSdoResponseBase + node);
  switch (m.type) {
    case SdoType::kInitiateDownloadResponse:
      f.data[0] = 3 << 5;
      PutMultiplexer(&f, m.index, m.subindex);
      break;
    case SdoType::kDownloadSegmentResponse:
      f.data[0] = static_cast<uint8_t>(1 << 5 | (m.toggle ? 0x10 : 0));
      break;
    case SdoType::kInitiateUploadResponse:
      EncodeInitiate(m, 2, &f);
      break;
    case SdoType::kUploadSegmentResponse:
      EncodeSegment(m, 0, &f);
      break;
    case SdoType::kAbort:
      EncodeAbort(m, &f);
      break;
    default:
      KINEVIS_UNREACHABLE();  // not an SDO response
  }
  return f;
}

std::optional<SdoMessage> DecodeSdoRequest(const CanFrame& frame, std::string* error) {
  if (frame.rtr || frame.dlc != 8) {
    Fail(error, "SDO request must be a data frame with 8 bytes");
    return std::nullopt;
  }
  SdoMessage m;
  switch (frame.data[0] >> 5) {
    case 0:
      m.type = SdoType::kDownloadSegmentRequest;
      DecodeSegment(frame, &m);
      return m;
    case 1:
      m.type = SdoType::kInitiateDownloadRequest;
      DecodeInitiate(frame, &m);
      return m;
    case 2:
      m.type = SdoType::kInitiateUploadRequest;
      GetMultiplexer(frame, &m);
      return m;
    case 3:
      m.type = SdoType::kUploadSegmentRequest;
      m.toggle = (frame.data[0] & 0x10) != 0;
      return m;
    case 4:
      DecodeAbort(frame, &m);
      return m;
    default:
      Fail(error, "SDO block transfer (ccs 5, 6) is not supported");
      return std::nullopt;
  }
}

std::optional<SdoMessage> DecodeSdoResponse(const CanFrame& frame, std::string* error) {
  if (frame.rtr || frame.dlc != 8) {
    Fail(error, "SDO response must be a data frame with 8 bytes");
    return std::nullopt;
  }
  SdoMessage m;
  switch (frame.data[0] >> 5) {
    case 0:
      m.type = SdoType::kUploadSegmentResponse;
      DecodeSegment(frame, &m);
      return m;
    case 1:
      m.type = SdoType::kDownloadSegmentResponse;
      m.toggle = (frame.data[0] & 0x10) != 0;
      return m;
    case 2:
      m.type = SdoType::kInitiateUploadResponse;
      DecodeInitiate(frame, &m);
      return m;
    case 3:
      m.type = SdoType::kInitiateDownloadResponse;
      GetMultiplexer(frame, &m);
      return m;
    case 4:
      DecodeAbort(frame, &m);
      return m;
    default:
      Fail(error, "SDO block transfer (scs 5, 6) is not supported");
      return std::nullopt;
  }
}

const char* SdoAbortText(uint32_t code) {
  using namespace sdo_abort;
  switch (code) {
    case kToggleBitNotAlternated:
      return "Toggle bit not alternated";
    case kProtocolTimedOut:
      return "SDO protocol timed out";
    case kInvalidCommandSpecifier:
      return "Client/server command specifier not valid or unknown";
    case kOutOfMemory:
      return "Out of memory";
    case kUnsupportedAccess:
      return "Unsupported access to an object";
    case kWriteOnly:
      return "Attempt to read a write only object";
    case kReadOnly:
      return "Attempt to write a read only object";
    case kObjectDoesNotExist:
      return "Object does not exist in the object dictionary";
    case kCannotBeMapped:
      return "Object cannot be mapped to the PDO";
    case kPdoLengthExceeded:
      return "The number and length of the objects to be mapped would exceed PDO length";
    case kParameterIncompatible:
      return "General parameter incompatibility reason";
    case kHardwareError:
      return "Access failed due to a hardware error";
    case kLengthMismatch:
      return "Data type does not match, length of service parameter does not match";
    case kLengthTooHigh:
      return "Data type does not match, length of service parameter too high";
    case kLengthTooLow:
      return "Data type does not match, length of service parameter too low";
    case kSubindexDoesNotExist:
      return "Sub-index does not exist";
    case kInvalidValue:
      return "Invalid value for parameter (download only)";
    case kValueTooHigh:
      return "Value of parameter written too high (download only)";
    case kValueTooLow:
      return "Value of parameter written too low (download only)";
    case kGeneralError:
      return "General error";
    case kCannotTransfer:
      return "Data cannot be transferred or stored to the application";
    case kCannotTransferLocalControl:
      return "Data cannot be transferred or stored to the application because of local control";
    case kCannotTransferDeviceState:
      return "Data cannot be transferred or stored to the application because of the present "
             "device state";
    default:
      return "unknown abort code";
  }
}

}  // namespace kinevis::hal::canopen
