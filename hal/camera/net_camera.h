#pragma once

// The network camera client (source string "net:HOST:PORT[,timeout_ms=N][,intrinsics=ID]",
// docs/cameras.md): a hal::Camera whose frames come from a FrameServer (hal/camera/
// frame_server.h) in another process or on another machine, over kinevis' own frame protocol.
//
// Grab() sends one request and reads one response per frame, so the reader sets the rate and
// always gets the server's newest frame (never a queue of stale ones). Frame ids and time
// stamps are the server's: the time stamps are on the server's clock, which is the same steady
// clock (CLOCK_MONOTONIC) as this process's only when both run on one machine.
//
// Faults: a dropped link, a response that does not follow the protocol (bad magic, another
// version, impossible sizes) and a request left unanswered for timeout_ms put the camera in
// fault; last_error() then says why, naming the source string and the cause, and the same line
// is logged. Open() again reconnects.
//
// Timing is wall time (std::chrono::steady_clock), as for every socket peer.

#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <mutex>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

#include "hal/camera/camera.h"
#include "hal/camera/frame_server.h"

namespace kinevis::hal {

struct NetCameraOptions {
  std::string host;  // numeric address or name; IPv6 without brackets ("::1")
  int port = 0;      // 1..65535
  // Connecting and the first frame at Open() must succeed within this time; in Grab(), a request
  // left unanswered this long means the link is lost (-> fault). 1..600000 ms.
  int timeout_ms = 1000;
  std::string intrinsics_id;  // non-empty: overrides the id the server sends
};

// Parses "net:HOST:PORT[,timeout_ms=N][,intrinsics=ID]" (IPv6 as "net:[::1]:PORT"). Throws
// ConfigError naming the source string and every bad field with its value: no or wrong scheme,
// no port, empty host, a port outside 1..65535, unknown option, bad or repeated value.
NetCameraOptions ParseNetCameraSource(std::string_view source);

class NetCamera final : public Camera {
 public:
  // `name` is the source string ("net:127.0.0.1:40123"). Nothing is connected before Open().
  // Throws ConfigError when the options are invalid (every bad field and its value).
  NetCamera(std::string name, NetCameraOptions options);
  ~NetCamera() override;
  NetCamera(const NetCamera&) = delete;
  NetCamera& operator=(const NetCamera&) = delete;

  const std::string& name() const override { return name_; }
  common::DeviceLifecycle lifecycle() const override { return lifecycle_.load(); }

  // Connects and reads one frame, whose header gives the format -> configured. Throws HalError
  // naming the source, "open" and the cause (cannot resolve, connection refused, no answer
  // within timeout_ms, a response that breaks the protocol, the server's source failing for the
  // whole timeout). From fault it closes the old connection and connects again.
  void Open() override;
  std::error_code Start() override;
  // The connection stays open; a request in flight is answered and its frame discarded.
  void Stop() override;

  // Requests the next frame (id newer than the last delivered) and waits at most `timeout` (wall
  // time) for it. Returns {} or
  //   kNotActive  not active (kClosed in fault);
  //   kTimeout    no answer within `timeout` (counted). The request stays in flight and the next
  //               Grab() goes on waiting for its answer; once it has been unanswered for
  //               timeout_ms the camera goes to fault;
  //   kClosed     the server closed the link (-> fault);
  //   kProtocol   a response that breaks the protocol (-> fault; counted as a decode error);
  //   another     the code the server's source failed with (the camera stays active; counted as
  //               a decode error, or as a timeout for kTimeout).
  // Gaps in the server's frame ids are counted as dropped. Does not allocate once *out and the
  // camera's receive buffer have the size of a frame.
  std::error_code Grab(Image* out, std::chrono::milliseconds timeout) override;

  CameraFormat format() const override;
  const std::string& intrinsics_id() const override { return intrinsics_id_; }
  CameraCounters counters() const override { return counters_.Snapshot(); }

  // Why the camera last went to fault or failed to open ("" if never): the source string, the
  // operation and the cause. Thread-safe.
  std::string last_error() const;

 private:
  // Connects within the deadline; throws HalError.
  void Connect(std::chrono::steady_clock::time_point deadline);
  void CloseSocket();
  bool SendRequest(uint64_t min_frame_id);
  // Reads the rest of the response in flight into header_ / intrinsics_ / rx_ until `deadline`.
  // Returns {}, kTimeout, or kClosed / kProtocol / kIo with *cause saying why.
  std::error_code ReceiveResponse(std::chrono::steady_clock::time_point deadline,
                                  std::string* cause);
  // -> fault with "<name>: <operation>: <cause>" logged and kept for last_error().
  void Fault(const std::string& cause);

  const std::string name_;
  const NetCameraOptions options_;
  std::atomic<common::DeviceLifecycle> lifecycle_{common::DeviceLifecycle::kUnconfigured};
  mutable std::mutex mutex_;  // format_ and last_error_, read from any thread
  CameraFormat format_;
  std::string last_error_;
  std::string intrinsics_id_;
  AtomicCameraCounters counters_;

  int fd_ = -1;
  // The request in flight and how much of its response has arrived.
  bool in_flight_ = false;
  bool discard_in_flight_ = false;  // its answer was asked for before Stop(): drop it
  std::chrono::steady_clock::time_point sent_at_{};
  size_t received_ = 0;  // bytes of the current response received so far
  std::array<uint8_t, kFrameHeaderSize> header_bytes_{};
  FrameHeader header_;
  std::array<char, kMaxIntrinsicsIdBytes> intrinsics_{};
  std::vector<uint8_t> rx_;  // the pixels of the response
  uint64_t next_min_frame_id_ = 0;
  bool delivered_any_ = false;
  uint64_t last_frame_id_ = 0;
};

}  // namespace kinevis::hal
