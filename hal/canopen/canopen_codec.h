#pragma once

// CANopen (CiA 301) frame codec: COB-IDs, NMT, SYNC, heartbeat, EMCY, SDO (expedited and
// segmented transfer) and PDO mapping entries. Pure functions, bytes in and structs out, no I/O;
// shared by the host stack (hal/canopen, hal/drive) and the drive simulator (hal/mock).
//
// SDO command specifiers (CiA 301, 7.2.4.3): the first data byte's bits 7..5 are the client
// command specifier (ccs) in requests and the server command specifier (scs) in responses; the
// same value means different things in each direction, so requests and responses have their own
// decoders.

#include <array>
#include <cstdint>
#include <optional>
#include <string>

#include "hal/can/can_frame.h"

namespace kinevis::hal::canopen {

// Predefined connection set (CiA 301, 7.3.5), node ids 1..127.
inline constexpr uint32_t kNmtCobId = 0x000;
inline constexpr uint32_t kSyncCobId = 0x080;
inline constexpr uint32_t kEmcyBase = 0x080;                            // + node id
inline constexpr uint32_t kTpdoBase[4] = {0x180, 0x280, 0x380, 0x480};  // + node id
inline constexpr uint32_t kRpdoBase[4] = {0x200, 0x300, 0x400, 0x500};  // + node id
inline constexpr uint32_t kSdoResponseBase = 0x580;  // server -> client, + node id
inline constexpr uint32_t kSdoRequestBase = 0x600;   // client -> server, + node id
inline constexpr uint32_t kHeartbeatBase = 0x700;    // + node id
inline constexpr int kMaxNodeId = 127;

// Communication objects of the object dictionary that the host configures over SDO.
inline constexpr uint16_t kDeviceType = 0x1000;
inline constexpr uint16_t kErrorRegister = 0x1001;
inline constexpr uint16_t kProducerHeartbeatTime = 0x1017;  // u16, ms
inline constexpr uint16_t kConsumerHeartbeatTime = 0x1016;
inline constexpr uint16_t kIdentity = 0x1018;           // sub 1 vendor, 2 product, 3 rev, 4 serial
inline constexpr uint16_t kRpdoCommunication = 0x1400;  // + pdo number 0..3
inline constexpr uint16_t kRpdoMapping = 0x1600;
inline constexpr uint16_t kTpdoCommunication = 0x1800;
inline constexpr uint16_t kTpdoMapping = 0x1A00;
inline constexpr uint32_t kPdoCobIdInvalid = 0x80000000u;  // bit 31 of sub 1: PDO disabled
inline constexpr uint8_t kTransmissionSynchronous = 1;     // sub 2: on every SYNC
inline constexpr uint8_t kTransmissionEventDriven = 0xFF;

// ----------------------------------------------------------------------------------- NMT
enum class NmtCommand : uint8_t {
  kStart = 0x01,
  kStop = 0x02,
  kEnterPreOperational = 0x80,
  kResetNode = 0x81,
  kResetCommunication = 0x82,
};
enum class NmtState : uint8_t {
  kBootUp = 0x00,
  kStopped = 0x04,
  kOperational = 0x05,
  kPreOperational = 0x7F,
};
const char* ToString(NmtCommand command);
const char* ToString(NmtState state);

// NMT command to `node` (0 = all nodes).
CanFrame EncodeNmt(NmtCommand command, uint8_t node);
struct NmtMessage {
  NmtCommand command;
  uint8_t node;  // 0 = all
};
std::optional<NmtMessage> DecodeNmt(const CanFrame& frame);

// Heartbeat (or boot-up, state kBootUp) of `node`.
CanFrame EncodeHeartbeat(uint8_t node, NmtState state);
struct HeartbeatMessage {
  uint8_t node;
  NmtState state;
};
std::optional<HeartbeatMessage> DecodeHeartbeat(const CanFrame& frame);

// SYNC, optionally with the counter byte (1..240).
CanFrame EncodeSync(std::optional<uint8_t> counter = std::nullopt);
bool IsSync(const CanFrame& frame);

// ----------------------------------------------------------------------------------- EMCY
struct EmcyMessage {
  uint8_t node = 0;
  uint16_t error_code = 0;     // 0x0000 = error reset / no error
  uint8_t error_register = 0;  // object 0x1001
  std::array<uint8_t, 5> manufacturer{};
};
CanFrame EncodeEmcy(const EmcyMessage& emcy);
// nullopt for a frame that is not an EMCY (SYNC has the same base id but node 0 and dlc 0..1).
std::optional<EmcyMessage> DecodeEmcy(const CanFrame& frame);
// "generic error", "current", "voltage", "temperature", "device hardware", "device software",
// "monitoring", "following error", ... by the error code's class (CiA 301 table 21 and CiA 402).
std::string EmcyErrorText(uint16_t error_code);

// ----------------------------------------------------------------------------------- SDO
enum class SdoType : uint8_t {
  // client -> server
  kInitiateDownloadRequest,
  kDownloadSegmentRequest,
  kInitiateUploadRequest,
  kUploadSegmentRequest,
  // server -> client
  kInitiateDownloadResponse,
  kDownloadSegmentResponse,
  kInitiateUploadResponse,
  kUploadSegmentResponse,
  // both directions
  kAbort,
};

struct SdoMessage {
  SdoType type = SdoType::kAbort;
  uint16_t index = 0;  // initiate and abort messages
  uint8_t subindex = 0;
  // Initiate download request / initiate upload response:
  bool expedited = false;  // data in this frame (1..4 bytes)
  bool size_indicated = false;
  uint32_t size = 0;  // expedited: data bytes (1..4); segmented: total bytes to transfer
  // Segments:
  bool toggle = false;
  bool last = false;  // c bit: no more segments
  // Data of an expedited transfer (size bytes) or of a segment (data_length bytes, 0..7).
  std::array<uint8_t, 7> data{};
  uint8_t data_length = 0;
  uint32_t abort_code = 0;

  static SdoMessage ExpeditedDownload(uint16_t index, uint8_t subindex, const uint8_t* bytes,
                                      uint8_t size);
  static SdoMessage SegmentedDownload(uint16_t index, uint8_t subindex, uint32_t total_size);
  static SdoMessage DownloadSegment(bool toggle, const uint8_t* bytes, uint8_t size, bool last);
  static SdoMessage InitiateUpload(uint16_t index, uint8_t subindex);
  static SdoMessage UploadSegment(bool toggle);
  static SdoMessage InitiateDownloadResponse(uint16_t index, uint8_t subindex);
  static SdoMessage DownloadSegmentResponse(bool toggle);
  static SdoMessage ExpeditedUploadResponse(uint16_t index, uint8_t subindex, const uint8_t* bytes,
                                            uint8_t size);
  static SdoMessage SegmentedUploadResponse(uint16_t index, uint8_t subindex, uint32_t total_size);
  static SdoMessage UploadSegmentResponse(bool toggle, const uint8_t* bytes, uint8_t size,
                                          bool last);
  static SdoMessage Abort(uint16_t index, uint8_t subindex, uint32_t code);
};

// Requests go to 0x600 + node, responses to 0x580 + node. Asserts that the message type fits the
// direction and that sizes are in range.
CanFrame EncodeSdoRequest(uint8_t node, const SdoMessage& message);
CanFrame EncodeSdoResponse(uint8_t node, const SdoMessage& message);
// Decode the 8 data bytes (the COB-ID is the caller's business). nullopt, with the reason in
// *error, for a dlc other than 8, an unknown or unsupported command specifier (block transfers)
// or inconsistent size bits.
std::optional<SdoMessage> DecodeSdoRequest(const CanFrame& frame, std::string* error = nullptr);
std::optional<SdoMessage> DecodeSdoResponse(const CanFrame& frame, std::string* error = nullptr);

// SDO abort codes (CiA 301, table 22).
namespace sdo_abort {
inline constexpr uint32_t kToggleBitNotAlternated = 0x05030000;
inline constexpr uint32_t kProtocolTimedOut = 0x05040000;
inline constexpr uint32_t kInvalidCommandSpecifier = 0x05040001;
inline constexpr uint32_t kOutOfMemory = 0x05040005;
inline constexpr uint32_t kUnsupportedAccess = 0x06010000;
inline constexpr uint32_t kWriteOnly = 0x06010001;
inline constexpr uint32_t kReadOnly = 0x06010002;
inline constexpr uint32_t kObjectDoesNotExist = 0x06020000;
inline constexpr uint32_t kCannotBeMapped = 0x06040041;
inline constexpr uint32_t kPdoLengthExceeded = 0x06040042;
inline constexpr uint32_t kParameterIncompatible = 0x06040043;
inline constexpr uint32_t kHardwareError = 0x06060000;
inline constexpr uint32_t kLengthMismatch = 0x06070010;
inline constexpr uint32_t kLengthTooHigh = 0x06070012;
inline constexpr uint32_t kLengthTooLow = 0x06070013;
inline constexpr uint32_t kSubindexDoesNotExist = 0x06090011;
inline constexpr uint32_t kInvalidValue = 0x06090030;
inline constexpr uint32_t kValueTooHigh = 0x06090031;
inline constexpr uint32_t kValueTooLow = 0x06090032;
inline constexpr uint32_t kGeneralError = 0x08000000;
inline constexpr uint32_t kCannotTransfer = 0x08000020;
inline constexpr uint32_t kCannotTransferLocalControl = 0x08000021;
inline constexpr uint32_t kCannotTransferDeviceState = 0x08000022;
}  // namespace sdo_abort
// The specification's text for an abort code ("Object does not exist in the object
// dictionary"); "unknown abort code" for others.
const char* SdoAbortText(uint32_t code);

// ----------------------------------------------------------------------------------- PDO
// One entry of a PDO mapping object (0x1600.., 0x1A00..): index << 16 | subindex << 8 | bits.
struct PdoMappingEntry {
  uint16_t index = 0;
  uint8_t subindex = 0;
  uint8_t bits = 0;  // 8, 16 or 32 in kinevis' mappings
  uint32_t Encode() const { return uint32_t{index} << 16 | uint32_t{subindex} << 8 | bits; }
  static PdoMappingEntry Decode(uint32_t value) {
    return {static_cast<uint16_t>(value >> 16), static_cast<uint8_t>(value >> 8),
            static_cast<uint8_t>(value)};
  }
};

// Little-endian helpers for PDO and SDO payloads.
inline void PutLe(uint8_t* out, uint32_t value, int bytes) {
  for (int i = 0; i < bytes; ++i) out[i] = static_cast<uint8_t>(value >> (8 * i));
}
inline uint32_t GetLe(const uint8_t* in, int bytes) {
  uint32_t v = 0;
  for (int i = 0; i < bytes; ++i) v |= uint32_t{in[i]} << (8 * i);
  return v;
}

}  // namespace kinevis::hal::canopen
