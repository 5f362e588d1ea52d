#pragma once

// Camera frames across processes: kinevis' own frame transport over TCP (docs/cameras.md,
// "Network frames"), served by FrameServer and read by NetCamera (hal/camera/net_camera.h,
// source string "net:HOST:PORT"). A simulated world run as its own process (`kinevis sim ...`)
// serves its rendered frames this way so that a second process can be the controller; it also
// lets a robot's camera be watched from another machine. It is not GigE Vision.
//
// The protocol is one request and one response per frame, so the client sets the rate:
//   client -> server  FrameRequest (16 bytes): "give me a frame whose id is >= min_frame_id"
//   server -> client  FrameHeader (64 bytes), the intrinsics id, the pixel bytes
// Every integer is little-endian; the layout, byte by byte, is in docs/cameras.md. The server
// keeps the last frame its source delivered and answers from it when it is new enough for the
// request, else it takes a fresh frame from the source; several clients therefore share frames
// instead of each pulling its own from the source.
//
// This file holds the wire codec (pure functions, no I/O) and the server. Timing here is wall
// time (std::chrono::steady_clock): the peer is a real socket.

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <system_error>

#include "common/clock.h"
#include "hal/camera/camera.h"
#include "hal/camera/sim_camera.h"

namespace kinevis::hal {

// ---- Wire format (version 1) ---------------------------------------------------------------

inline constexpr uint32_t kFrameMagic = 0x5246564B;         // bytes "KVFR"
inline constexpr uint32_t kFrameRequestMagic = 0x5146564B;  // bytes "KVFQ"
inline constexpr uint16_t kFrameProtocolVersion = 1;
inline constexpr size_t kFrameHeaderSize = 64;   // bytes
inline constexpr size_t kFrameRequestSize = 16;  // bytes
inline constexpr size_t kMaxIntrinsicsIdBytes = 255;
inline constexpr uint64_t kMaxFramePayloadBytes = uint64_t{1} << 30;  // 1 GiB
inline constexpr uint32_t kMaxFrameSide = 16384;                      // pixels

// A request: the client wants a frame with frame_id >= min_frame_id (0: any, e.g. the first).
struct FrameRequest {
  uint32_t magic = kFrameRequestMagic;
  uint16_t version = kFrameProtocolVersion;
  uint16_t flags = 0;  // none defined in version 1; sent as 0, ignored
  uint64_t min_frame_id = 0;
};

// The fixed part of a response. status 0: a frame follows (intrinsics_id_bytes bytes of
// intrinsics id, then payload_bytes bytes of pixels, `height` rows `stride` bytes apart);
// otherwise the hal::Errc value the server's source failed with and nothing follows.
struct FrameHeader {
  uint32_t magic = kFrameMagic;
  uint16_t version = kFrameProtocolVersion;
  uint16_t status = 0;
  uint32_t width = 0;         // pixels, 1..16384 when status is 0
  uint32_t height = 0;        // pixels, 1..16384 when status is 0
  uint32_t pixel_format = 0;  // FramePixelFormatCode(): 0 mono8, 1 bgr8, 2 rgb8, 3 mono16
  uint32_t stride = 0;        // bytes per row, >= width * bytes per pixel
  uint64_t frame_id = 0;
  int64_t timestamp_ns = 0;          // capture time on the server's clock (Image::timestamp)
  uint64_t payload_bytes = 0;        // height * stride
  double fps = 0.0;                  // the server's nominal frame rate, frames/s
  uint16_t intrinsics_id_bytes = 0;  // 0..255
};

// Wire code of a pixel format, and back (std::nullopt for an unknown code).
uint32_t FramePixelFormatCode(PixelFormat format);
std::optional<PixelFormat> FramePixelFormatFromCode(uint32_t code);

// Little-endian encoders into exactly kFrameRequestSize / kFrameHeaderSize bytes, and decoders
// from them. Decoders do not judge the values; see CheckFrameHeader().
void EncodeFrameRequest(const FrameRequest& request, uint8_t* bytes);
FrameRequest DecodeFrameRequest(const uint8_t* bytes);
void EncodeFrameHeader(const FrameHeader& header, uint8_t* bytes);
FrameHeader DecodeFrameHeader(const uint8_t* bytes);

// nullptr when `header` is a valid version-1 header; else what is wrong with it, naming the
// field ("bad magic", "unsupported protocol version", "payload size is not height * stride",
// ...). Does not allocate.
const char* CheckFrameHeader(const FrameHeader& header);

// ---- The server ----------------------------------------------------------------------------

// Fills `image` with the next frame: size, format, stride, data, frame_id (strictly increasing
// from call to call), timestamp and intrinsics id. Returns {} or the error that made it fail
// (a hal::Errc is passed on to the client as is; any other code as Errc::kIo). Called on the
// server's connection threads, one call at a time; the image is the server's and keeps its
// buffer from call to call.
using FrameSource = std::function<std::error_code(Image* image)>;

// A source that grabs from `camera`, which must be active (Start()ed) and outlive the server:
// every fresh frame is camera.Grab(image, timeout).
FrameSource CameraFrameSource(Camera& camera, std::chrono::milliseconds timeout);

// A source that renders on demand with a RenderFn (hal/camera/sim_camera.h): fresh frame k
// (k = 0, 1, ...) is rendered at clock.Now() into an image of `format`, carrying
// `intrinsics_id`. `clock` must outlive the server. Throws ConfigError when the format's size is
// not positive or `render` is empty.
FrameSource RenderFrameSource(const CameraFormat& format, RenderFn render,
                              std::string intrinsics_id,
                              common::Clock& clock = common::SteadyClock::Instance());

struct FrameServerOptions {
  // Address to listen on: numeric or a name ("127.0.0.1", "::1", "localhost"; "0.0.0.0" for
  // every interface, to be watched from another machine).
  std::string host = "127.0.0.1";
  int port = 0;          // 0..65535; 0: any free port (see FrameServer::port())
  double fps = 30.0;     // the nominal frame rate announced to clients, frames/s, (0, 10000]
  int max_clients = 16;  // connections served at once, 1..1024; more are closed at once
};

struct FrameServerStats {
  uint64_t requests = 0;         // well-formed requests received
  uint64_t frames_sent = 0;      // responses with a frame
  uint64_t errors_sent = 0;      // responses with a non-zero status
  uint64_t source_frames = 0;    // fresh frames taken from the source
  uint64_t swallowed = 0;        // requests discarded unanswered by StopAnswering()
  uint64_t corrupted = 0;        // responses sent with a bad magic (CorruptMagic())
  uint64_t protocol_errors = 0;  // malformed requests (the connection is closed)
  uint64_t connections_accepted = 0;
  uint64_t connections_refused = 0;  // beyond max_clients
  uint64_t connections_dropped = 0;  // closed by DropConnections()
  uint64_t connections_open = 0;     // right now
};

// Serves the frames of one FrameSource over TCP to any number of clients (up to max_clients),
// one thread per connection plus one accepting. Requests of one connection are answered in
// order; different connections are answered concurrently, except that one source call runs at a
// time. A source that blocks (a camera waiting for its next frame) delays every client that
// needs a fresh frame.
class FrameServer {
 public:
  // Listens and starts serving. Throws ConfigError for bad options or an empty source (every bad
  // field and its value in one message), HalError naming host:port when it cannot listen.
  static std::unique_ptr<FrameServer> Listen(FrameSource source,
                                             const FrameServerOptions& options = {});

  // Stop()s.
  ~FrameServer();
  FrameServer(const FrameServer&) = delete;
  FrameServer& operator=(const FrameServer&) = delete;

  // Closes the listening socket and every connection and joins the threads. Waits for a source
  // call in progress to return. Idempotent; call it from one thread at a time.
  void Stop();

  // The source string a NetCamera opens to reach this server: "net:127.0.0.1:40123"
  // ("net:[::1]:40123" for IPv6). A server on 0.0.0.0 (::) names 127.0.0.1 (::1).
  const std::string& backend() const;
  int port() const;  // the port actually bound

  // Fault injection (tests, `kinevis sim`).
  // Closes every connection now (clients see the link drop) and returns how many were open.
  int DropConnections();
  // Reads and discards every request for `duration` from now (clients time out).
  // std::chrono::milliseconds::max(): until ResumeAnswering().
  void StopAnswering(std::chrono::milliseconds duration);
  void ResumeAnswering();
  // The next `responses` responses carry a wrong magic (0x00000000) instead of "KVFR".
  void CorruptMagic(int responses);

  FrameServerStats stats() const;

 private:
  struct Impl;
  FrameServer();
  std::unique_ptr<Impl> impl_;
};

}  // namespace kinevis::hal
