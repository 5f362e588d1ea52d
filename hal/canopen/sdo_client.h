#pragma once

// CANopen SDO client (CiA 301, 7.2.4.3) for one node: expedited and segmented upload and
// download, a per-request timeout, server aborts returned as std::error_code values carrying the
// abort code and the specification's text, toggle-bit checking, counters.
//
// Two layers:
//  - SdoTransfer: one transfer as a state machine, frames in and frames out; no I/O, no clock.
//    It checks every response (command specifier, multiplexer, toggle bit, sizes) and, when a
//    response is wrong, says which abort to send (what fuzz/sdo_fuzz.cc drives).
//  - SdoClient: runs transfers over a CanBus, with a timeout on a Clock for every response.
//
// Who reads the bus: exactly one thread calls CanBus::Receive(). An SdoClient either reads the
// bus itself (stand-alone, e.g. a set-up tool with nothing else on the bus; frames that are not
// its responses are dropped), or, with a CanFrameSource attached (the CanopenMaster), asks the
// source to read and dispatch the bus until its response came: the source hands every frame
// with COB-ID 0x580 + node to HandleFrame(). Either way everything runs on the caller's thread.
//
// SDO transfers are set-up operations: they allocate and log, and are not for the control cycle.

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <system_error>
#include <type_traits>
#include <vector>

#include "common/clock.h"
#include "hal/can/can_bus.h"
#include "hal/can/can_frame.h"
#include "hal/canopen/canopen_codec.h"

namespace kinevis::hal::canopen {

// Errors of this category are aborts sent by the SDO server: the value is the abort code
// (CiA 301 table 22, as a 32-bit pattern), message() is "SDO abort 0x06020000: Object does not
// exist in the object dictionary". An abort with code 0 (which no server should send) is
// reported as hal::Errc::kProtocol instead, so that the error_code is never "no error".
const std::error_category& SdoAbortCategory();
std::error_code MakeSdoAbortError(uint32_t abort_code);
// The abort code carried by `ec`, or 0 when `ec` is not an SDO abort.
uint32_t SdoAbortCode(std::error_code ec);

// Waits for the next received frame until `clock` reaches `deadline`. On a SteadyClock this
// blocks in bus.Receive(); on any other clock (a SimulatedClock, or a test clock that services
// simulators while time passes) it polls bus.Receive() without waiting and sleeps on the clock in
// steps of `poll_period`, so that simulated time moves. Returns {} with *frame filled,
// Errc::kTimeout at the deadline, or the bus's link error (kClosed, kIo).
std::error_code ReceiveFrameUntil(CanBus& bus, common::Clock& clock, common::Duration deadline,
                                  CanFrame* frame,
                                  common::Duration poll_period = std::chrono::microseconds(50));

// One SDO transfer as a state machine. Usage: Start*() gives the first request; feed every
// response (a frame with COB-ID 0x580 + node) to OnResponse() and, when no response came in time,
// call OnTimeout(); act on the returned Action until the transfer is no longer active().
class SdoTransfer {
 public:
  enum class Action {
    kSend,      // send *request, then wait for the next response
    kComplete,  // the transfer succeeded (uploaded bytes in data())
    kFailed,    // the transfer failed (error()); nothing to send
    kAbort,     // the transfer failed (error()); send *request, the client's abort, to the server
  };

  // max_upload_size: the largest upload accepted, bytes (> 0); a server announcing more is
  // aborted with 0x05040005 (out of memory) and the transfer fails with Errc::kOverflow.
  explicit SdoTransfer(size_t max_upload_size = 65536);

  // Starts an upload (read) of index:subindex from `node` (1..127).
  void StartUpload(uint8_t node, uint16_t index, uint8_t subindex, CanFrame* request);
  // Starts a download (write): 1..4 bytes go expedited, other sizes (0 included) segmented.
  void StartDownload(uint8_t node, uint16_t index, uint8_t subindex, const uint8_t* data,
                     size_t size, CanFrame* request);

  // A response arrived. Checks, in order: a decodable 8-byte frame (else abort 0x05040001), a
  // server abort (the transfer fails with the server's code), the command specifier expected
  // in this phase (else abort 0x05040001), the multiplexer of an initiate response (else abort
  // 0x08000000), the toggle bit of a segment (else abort 0x05030000), and the sizes (segments
  // beyond the indicated size: abort 0x06070012; a total that differs from it: failure).
  Action OnResponse(const CanFrame& response, CanFrame* request);
  // No response within the timeout: the transfer fails with Errc::kTimeout and the client
  // sends abort 0x05040000 (SDO protocol timed out).
  Action OnTimeout(CanFrame* request);

  bool active() const { return phase_ != Phase::kIdle; }
  bool upload() const { return upload_; }
  uint16_t index() const { return index_; }
  uint8_t subindex() const { return subindex_; }
  // {} after success; hal::Errc::kTimeout, kProtocol or kOverflow, or an SdoAbortCategory code.
  std::error_code error() const { return error_; }
  // The abort code received from the server or sent to it; 0 when none.
  uint32_t abort_code() const { return abort_code_; }
  bool abort_from_server() const { return abort_from_server_; }
  // What went wrong, for messages ("toggle bit not alternated in segment 3"); empty on success.
  const std::string& detail() const { return detail_; }
  // Uploaded bytes (upload) once complete.
  const std::vector<uint8_t>& data() const { return data_; }
  bool expedited() const { return expedited_; }
  bool size_indicated() const { return size_indicated_; }
  int segments() const { return segments_; }
  // Ends the transfer without a response (the request could not be sent): error() = `error`.
  void Cancel(std::error_code error, std::string detail) { Fail(error, std::move(detail)); }

 private:
  enum class Phase { kIdle, kInitiate, kSegments };
  Action Fail(std::error_code error, std::string detail);
  Action FailWithAbort(std::error_code error, uint32_t abort_code, std::string detail,
                       CanFrame* request);
  Action OnUploadResponse(const SdoMessage& m, CanFrame* request);
  Action OnDownloadResponse(const SdoMessage& m, CanFrame* request);
  void EncodeNextDownloadSegment(CanFrame* request);

  size_t max_upload_size_;
  Phase phase_ = Phase::kIdle;
  bool upload_ = true;
  uint8_t node_ = 1;
  uint16_t index_ = 0;
  uint8_t subindex_ = 0;
  bool toggle_ = false;  // toggle bit of the segment requested / sent last
  bool expedited_ = false;
  bool size_indicated_ = false;
  uint32_t size_ = 0;       // indicated upload size, or the download size
  size_t offset_ = 0;       // download: bytes sent so far
  bool last_sent_ = false;  // download: the segment with the c bit went out
  int segments_ = 0;
  std::vector<uint8_t> data_;  // upload: received; download: to send
  std::error_code error_;
  uint32_t abort_code_ = 0;
  bool abort_from_server_ = false;
  std::string detail_;
};

// Reads and dispatches received frames on behalf of SDO clients that do not own the bus.
class CanFrameSource {
 public:
  virtual ~CanFrameSource() = default;
  // Reads received frames and hands each to its consumer (SDO responses to the SdoClient of that
  // node, through HandleFrame()) until `done()` returns true or the source's clock reaches
  // `deadline`. Returns at once when `done()` is already true.
  virtual void PumpUntil(common::Duration deadline, const std::function<bool()>& done) = 0;
};

struct SdoClientOptions {
  // How long the server has to answer each request of a transfer (the initiate request and every
  // segment request), > 0. A transfer of n segments therefore takes at most (n + 1) x timeout.
  std::chrono::milliseconds timeout{500};
  size_t max_upload_size = 65536;                                // bytes, > 0; see SdoTransfer
  common::Duration poll_period = std::chrono::microseconds(50);  // see ReceiveFrameUntil, > 0
};

struct SdoCounters {
  uint64_t transfers = 0;             // Upload*/Download* calls
  uint64_t failures = 0;              // transfers that returned an error
  uint64_t timeouts = 0;              // responses that did not come in time
  uint64_t aborts_received = 0;       // transfers the server aborted
  uint64_t aborts_sent = 0;           // aborts the client sent (timeout, protocol error)
  uint64_t protocol_errors = 0;       // malformed or unexpected responses, bad toggle, sizes
  uint64_t link_errors = 0;           // requests the bus refused (bus-off, closed, overflow)
  uint64_t segments = 0;              // segments exchanged
  uint64_t unexpected_responses = 0;  // responses that came while no request was waiting
};

class SdoClient {
 public:
  // bus and clock must outlive the client; node 1..127. `name` names the device in every log
  // line and error text ("leg3 (virtual:hexapod node 3)"). Throws ConfigError for a bad node or
  // options.
  SdoClient(CanBus* bus, uint8_t node, common::Clock* clock, std::string name,
            SdoClientOptions options = {});

  // With a source, the client never calls bus->Receive(); nullptr: it reads the bus itself.
  void set_frame_source(CanFrameSource* source) { source_ = source; }

  // Every transfer below returns {} on success, or: hal::Errc::kTimeout (the server did not
  // answer within the timeout; abort 0x05040000 sent), hal::Errc::kProtocol (a malformed or
  // unexpected response; an abort sent where the protocol says so), hal::Errc::kOverflow (upload
  // larger than max_upload_size), an SdoAbortCategory error (the server aborted), or the bus's
  // error when a request could not be sent (kBusOff, kClosed, kIo, kOverflow). last_error_text()
  // then says which device, object and cause. `timeout` overrides SdoClientOptions::timeout for
  // this transfer. Output arguments are written only on success.

  std::error_code Upload(uint16_t index, uint8_t subindex, std::vector<uint8_t>* data,
                         std::optional<std::chrono::milliseconds> timeout = std::nullopt);
  std::error_code Download(uint16_t index, uint8_t subindex, const uint8_t* data, size_t size,
                           std::optional<std::chrono::milliseconds> timeout = std::nullopt);
  std::error_code Download(uint16_t index, uint8_t subindex, const std::vector<uint8_t>& data,
                           std::optional<std::chrono::milliseconds> timeout = std::nullopt) {
    return Download(index, subindex, data.data(), data.size(), timeout);
  }
  // A VISIBLE_STRING (e.g. 0x1008 manufacturer device name); trailing NULs removed.
  std::error_code UploadString(uint16_t index, uint8_t subindex, std::string* text,
                               std::optional<std::chrono::milliseconds> timeout = std::nullopt);

  // Integer objects: T is uint8_t, uint16_t, uint32_t, int8_t, int16_t or int32_t, little-endian
  // on the wire. An upload whose size is not sizeof(T) fails with Errc::kProtocol (an expedited
  // response without size indication carries 4 bytes and is accepted for any T).
  template <typename T>
  std::error_code UploadValue(uint16_t index, uint8_t subindex, T* value,
                              std::optional<std::chrono::milliseconds> timeout = std::nullopt) {
    static_assert(std::is_integral_v<T> && sizeof(T) <= 4, "SDO integers are 8, 16 or 32 bit");
    uint32_t raw = 0;
    std::error_code ec = UploadInteger(index, subindex, sizeof(T), &raw, timeout);
    if (!ec) *value = static_cast<T>(raw);
    return ec;
  }
  template <typename T>
  std::error_code DownloadValue(uint16_t index, uint8_t subindex, T value,
                                std::optional<std::chrono::milliseconds> timeout = std::nullopt) {
    static_assert(std::is_integral_v<T> && sizeof(T) <= 4, "SDO integers are 8, 16 or 32 bit");
    uint8_t bytes[4];
    PutLe(bytes, static_cast<uint32_t>(value), sizeof(T));
    return Download(index, subindex, bytes, sizeof(T), timeout);
  }

  // Feeds a received frame; returns true when it was an SDO response of this node (COB-ID
  // 0x580 + node, standard id), which the client then keeps for the waiting transfer (or counts
  // as unexpected when none is waiting). Called by the CanFrameSource on the client's thread.
  bool HandleFrame(const CanFrame& frame);

  uint8_t node() const { return node_; }
  const std::string& name() const { return name_; }
  const SdoClientOptions& options() const { return options_; }
  SdoCounters counters() const { return counters_; }
  // The error of the last transfer that failed ({} when none has).
  std::error_code last_error() const { return last_error_; }
  // The abort code of the last failed transfer (received or sent), 0 when it had none.
  uint32_t last_abort_code() const { return last_abort_code_; }
  // "leg3 (virtual:hexapod node 3): SDO upload 0x6502:00 failed: abort 0x06020000 from the
  // server (Object does not exist in the object dictionary)".
  const std::string& last_error_text() const { return last_error_text_; }
  // The same without the device name: "SDO upload 0x6502:00 failed: abort ...".
  const std::string& last_error_cause() const { return last_error_cause_; }

 private:
  std::error_code UploadInteger(uint16_t index, uint8_t subindex, size_t size, uint32_t* raw,
                                std::optional<std::chrono::milliseconds> timeout);
  // Sends `request` and runs transfer_ to its end.
  std::error_code Run(CanFrame request, std::optional<std::chrono::milliseconds> timeout);
  // Waits for a response until deadline; true when one is in mailbox_.
  bool WaitForResponse(common::Duration deadline);
  std::error_code RecordFailure(std::error_code ec, uint32_t abort_code, const std::string& cause);

  CanBus* bus_;
  uint8_t node_;
  common::Clock* clock_;
  std::string name_;
  SdoClientOptions options_;
  CanFrameSource* source_ = nullptr;
  SdoTransfer transfer_;
  bool waiting_ = false;
  bool has_response_ = false;
  CanFrame mailbox_;
  SdoCounters counters_;
  std::error_code last_error_;
  uint32_t last_abort_code_ = 0;
  std::string last_error_text_;
  std::string last_error_cause_;
};

}  // namespace kinevis::hal::canopen
