#include "hal/camera/net_camera.h"

#include <arpa/inet.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstring>
#include <iostream>
#include <memory>
#include <random>
#include <thread>
#include <vector>

#include "hal/camera/camera_factory.h"
#include "hal/camera/frame_server.h"
#include "hal/common/error.h"
#include "tests/utilities/allocation_counter.h"

namespace kinevis::hal {
namespace {

using namespace std::chrono_literals;
using ::testing::HasSubstr;
using ::testing::MatchesRegex;

// The byte at offset i of frame k: every byte of every frame differs from its neighbours and
// from the same byte of the previous frame, so a shifted, truncated or stale frame shows.
uint8_t PatternByte(uint64_t frame_id, size_t i) {
  const uint64_t x = (i + 1) * 2654435761ULL + frame_id * 40503ULL + (i >> 7) * 97ULL;
  return static_cast<uint8_t>(x >> 11);
}

std::error_code PaintPattern(uint64_t frame_id, common::Duration, Image* image) {
  for (size_t i = 0; i < image->data.size(); ++i) image->data[i] = PatternByte(frame_id, i);
  return {};
}

void ExpectPattern(const Image& image, uint64_t frame_id) {
  size_t mismatches = 0;
  for (size_t i = 0; i < image.data.size(); ++i) {
    if (image.data[i] != PatternByte(frame_id, i)) ++mismatches;
  }
  EXPECT_EQ(mismatches, 0u) << "frame " << frame_id;
}

std::unique_ptr<FrameServer> PatternServer(const CameraFormat& format,
                                           const std::string& intrinsics = "test-intrinsics-v1") {
  FrameServerOptions options;
  options.fps = format.fps;
  return FrameServer::Listen(RenderFrameSource(format, PaintPattern, intrinsics), options);
}

std::unique_ptr<NetCamera> OpenNet(const std::string& source) {
  std::unique_ptr<Camera> camera = OpenCamera(source);
  auto* net = dynamic_cast<NetCamera*>(camera.get());
  EXPECT_NE(net, nullptr) << source << " did not open a NetCamera";
  camera.release();
  return std::unique_ptr<NetCamera>(net);
}

std::string ParseError(const std::string& source) {
  try {
    ParseNetCameraSource(source);
  } catch (const common::ConfigError& e) {
    return e.what();
  }
  return "no error";
}

// A raw TCP client, to talk to the server byte by byte without NetCamera or the codec.
class RawClient {
 public:
  explicit RawClient(int port) {
    fd_ = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(static_cast<uint16_t>(port));
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    connected_ = ::connect(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0;
    timeval tv{2, 0};  // a failing test must not hang
    ::setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  }
  ~RawClient() { ::close(fd_); }
  bool connected() const { return connected_; }
  bool Send(const std::vector<uint8_t>& bytes) {
    return ::send(fd_, bytes.data(), bytes.size(), MSG_NOSIGNAL) ==
           static_cast<ssize_t>(bytes.size());
  }
  // Reads exactly n bytes; fewer when the server closed or nothing came for 2 s.
  std::vector<uint8_t> Read(size_t n) {
    std::vector<uint8_t> out(n);
    size_t have = 0;
    while (have < n) {
      const ssize_t r = ::recv(fd_, out.data() + have, n - have, 0);
      if (r <= 0) break;
      have += static_cast<size_t>(r);
    }
    out.resize(have);
    return out;
  }

 private:
  int fd_ = -1;
  bool connected_ = false;
};

// ---- Wire codec ------------------------------------------------------------------------------

TEST(FrameProtocolTest, RequestBytesAreLittleEndianAsDocumented) {
  FrameRequest r;
  r.min_frame_id = 0x0102030405060708ULL;
  uint8_t bytes[kFrameRequestSize];
  EncodeFrameRequest(r, bytes);
  const std::vector<uint8_t> expected = {'K',  'V',  'F',  'Q',  0x01, 0x00, 0x00, 0x00,
                                         0x08, 0x07, 0x06, 0x05, 0x04, 0x03, 0x02, 0x01};
  EXPECT_EQ(std::vector<uint8_t>(bytes, bytes + sizeof bytes), expected);
  const FrameRequest back = DecodeFrameRequest(bytes);
  EXPECT_EQ(back.magic, kFrameRequestMagic);
  EXPECT_EQ(back.version, 1);
  EXPECT_EQ(back.min_frame_id, r.min_frame_id);
}

TEST(FrameProtocolTest, HeaderBytesAreLittleEndianAsDocumented) {
  FrameHeader h;
  h.width = 640;   // 0x0280
  h.height = 480;  // 0x01E0
  h.pixel_format = FramePixelFormatCode(PixelFormat::kMono16);
  h.stride = 1284;  // 0x0504
  h.frame_id = 0x1122334455667788ULL;
  h.timestamp_ns = -2;              // two's complement
  h.payload_bytes = 1284ULL * 480;  // 616320 = 0x096780
  h.fps = 1.0;                      // binary64 0x3FF0000000000000
  h.intrinsics_id_bytes = 0x0102;
  uint8_t b[kFrameHeaderSize];
  EncodeFrameHeader(h, b);
  const std::vector<uint8_t> expected = {
      'K',  'V',  'F',  'R',  0x01, 0x00, 0x00, 0x00,  // magic, version, status
      0x80, 0x02, 0x00, 0x00, 0xE0, 0x01, 0x00, 0x00,  // width, height
      0x03, 0x00, 0x00, 0x00, 0x04, 0x05, 0x00, 0x00,  // pixel format, stride
      0x88, 0x77, 0x66, 0x55, 0x44, 0x33, 0x22, 0x11,  // frame id
      0xFE, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF,  // timestamp ns
      0x80, 0x67, 0x09, 0x00, 0x00, 0x00, 0x00, 0x00,  // payload bytes
      0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0xF0, 0x3F,  // fps
      0x02, 0x01, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,  // intrinsics id bytes, reserved
  };
  EXPECT_EQ(std::vector<uint8_t>(b, b + sizeof b), expected);
  const FrameHeader back = DecodeFrameHeader(b);
  EXPECT_EQ(back.magic, kFrameMagic);
  EXPECT_EQ(back.width, 640u);
  EXPECT_EQ(back.height, 480u);
  EXPECT_EQ(back.stride, 1284u);
  EXPECT_EQ(back.frame_id, h.frame_id);
  EXPECT_EQ(back.timestamp_ns, -2);
  EXPECT_EQ(back.payload_bytes, h.payload_bytes);
  EXPECT_EQ(back.fps, 1.0);
  EXPECT_EQ(back.intrinsics_id_bytes, 0x0102);
}

TEST(FrameProtocolTest, CheckNamesWhatIsWrongWithAHeader) {
  FrameHeader good;
  good.width = 4;
  good.height = 3;
  good.pixel_format = FramePixelFormatCode(PixelFormat::kBgr8);
  good.stride = 12;
  good.payload_bytes = 36;
  good.fps = 30.0;
  EXPECT_EQ(CheckFrameHeader(good), nullptr);
  auto check = [&](auto change) {
    FrameHeader h = good;
    change(&h);
    const char* why = CheckFrameHeader(h);
    return std::string(why == nullptr ? "valid" : why);
  };
  EXPECT_EQ(check([](FrameHeader* h) { h->magic = 0; }), "bad magic");
  EXPECT_EQ(check([](FrameHeader* h) { h->version = 2; }), "unsupported protocol version");
  EXPECT_EQ(check([](FrameHeader* h) { h->width = 0; }), "width is not in 1..16384");
  EXPECT_EQ(check([](FrameHeader* h) { h->height = 16385; }), "height is not in 1..16384");
  EXPECT_EQ(check([](FrameHeader* h) { h->pixel_format = 4; }), "unknown pixel format code");
  EXPECT_EQ(check([](FrameHeader* h) { h->stride = 11; }), "stride is shorter than a row");
  EXPECT_EQ(check([](FrameHeader* h) { h->payload_bytes = 35; }),
            "payload size is not height * stride");
  EXPECT_EQ(check([](FrameHeader* h) { h->intrinsics_id_bytes = 256; }),
            "intrinsics id longer than 255 bytes");
  EXPECT_EQ(check([](FrameHeader* h) { h->fps = -1.0; }), "fps is negative or not finite");
  // An error response carries nothing; its frame fields are not judged.
  EXPECT_EQ(check([](FrameHeader* h) {
              *h = FrameHeader();
              h->status = static_cast<uint16_t>(Errc::kTimeout);
            }),
            "valid");
  EXPECT_EQ(check([](FrameHeader* h) { h->status = static_cast<uint16_t>(Errc::kTimeout); }),
            "an error response carries data");
}

TEST(FrameServerTest, AnswersARawRequestWithTheDocumentedBytes) {
  auto server = PatternServer(CameraFormat{5, 2, PixelFormat::kRgb8, 25.0}, "cam-A");
  RawClient client(server->port());
  ASSERT_TRUE(client.connected());
  // "KVFQ", version 1, flags 0, min_frame_id 0.
  ASSERT_TRUE(client.Send({'K', 'V', 'F', 'Q', 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0}));
  const std::vector<uint8_t> h = client.Read(kFrameHeaderSize);
  ASSERT_EQ(h.size(), kFrameHeaderSize);
  EXPECT_EQ(std::vector<uint8_t>(h.begin(), h.begin() + 24),
            (std::vector<uint8_t>{'K', 'V', 'F', 'R', 1,  0, 0, 0, 5, 0, 0, 0, 2, 0, 0, 0,  //
                                  2,   0,   0,   0,   15, 0, 0, 0}));
  EXPECT_EQ(std::vector<uint8_t>(h.begin() + 24, h.begin() + 32), std::vector<uint8_t>(8, 0));
  EXPECT_EQ(std::vector<uint8_t>(h.begin() + 40, h.begin() + 48),
            (std::vector<uint8_t>{30, 0, 0, 0, 0, 0, 0, 0}));
  double fps = 0.0;
  std::memcpy(&fps, h.data() + 48, 8);  // the test host is little-endian (x86-64, aarch64)
  EXPECT_EQ(fps, 25.0);
  EXPECT_EQ(h[56], 5);
  EXPECT_EQ(h[57], 0);
  const std::vector<uint8_t> id = client.Read(5);
  EXPECT_EQ(std::string(id.begin(), id.end()), "cam-A");
  const std::vector<uint8_t> pixels = client.Read(30);
  ASSERT_EQ(pixels.size(), 30u);
  for (size_t i = 0; i < pixels.size(); ++i) EXPECT_EQ(pixels[i], PatternByte(0, i)) << i;

  // A request of another version is answered "unsupported" in version 1, then closed.
  ASSERT_TRUE(client.Send({'K', 'V', 'F', 'Q', 2, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0}));
  const std::vector<uint8_t> refusal = client.Read(kFrameHeaderSize);
  ASSERT_EQ(refusal.size(), kFrameHeaderSize);
  const FrameHeader r = DecodeFrameHeader(refusal.data());
  EXPECT_EQ(r.version, 1);
  EXPECT_EQ(r.status, static_cast<uint16_t>(Errc::kUnsupported));
  EXPECT_EQ(r.payload_bytes, 0u);
  EXPECT_TRUE(client.Read(1).empty());  // closed
  EXPECT_EQ(server->stats().protocol_errors, 1u);
}

TEST(FrameServerTest, RejectsBadOptionsNamingEveryField) {
  FrameServerOptions options;
  options.port = 70000;
  options.fps = 0.0;
  options.max_clients = 0;
  try {
    FrameServer::Listen(FrameSource(), options);
    FAIL() << "no ConfigError";
  } catch (const common::ConfigError& e) {
    EXPECT_THAT(e.what(), HasSubstr("frame source is empty"));
    EXPECT_THAT(e.what(), HasSubstr("port 70000 is not in 0..65535"));
    EXPECT_THAT(e.what(), HasSubstr("fps 0.000000 is not in (0, 10000]"));
    EXPECT_THAT(e.what(), HasSubstr("max_clients 0 is not in 1..1024"));
  }
  EXPECT_THROW(RenderFrameSource(CameraFormat{0, 4, PixelFormat::kMono8, 30.0}, PaintPattern, ""),
               common::ConfigError);
}

// ---- Source strings --------------------------------------------------------------------------

TEST(NetCameraSourceTest, ParsesHostPortAndOptions) {
  NetCameraOptions o = ParseNetCameraSource("net:127.0.0.1:40123");
  EXPECT_EQ(o.host, "127.0.0.1");
  EXPECT_EQ(o.port, 40123);
  EXPECT_EQ(o.timeout_ms, 1000);
  EXPECT_EQ(o.intrinsics_id, "");
  o = ParseNetCameraSource("net:[::1]:5000,timeout_ms=250,intrinsics=cam-7");
  EXPECT_EQ(o.host, "::1");
  EXPECT_EQ(o.port, 5000);
  EXPECT_EQ(o.timeout_ms, 250);
  EXPECT_EQ(o.intrinsics_id, "cam-7");
  o = ParseNetCameraSource("net:robot-cell-3.local:7000");
  EXPECT_EQ(o.host, "robot-cell-3.local");
}

TEST(NetCameraSourceTest, BadStringsNameTheBadField) {
  EXPECT_THAT(ParseError("net:127.0.0.1"),
              MatchesRegex("camera source \"net:127.0.0.1\": address \"127.0.0.1\" has no port.*"));
  EXPECT_THAT(ParseError("net::5000"), HasSubstr("host is empty"));
  EXPECT_THAT(ParseError("net:localhost:0"), HasSubstr("port \"0\" is not an integer in 1..65535"));
  EXPECT_THAT(ParseError("net:localhost:http"),
              HasSubstr("port \"http\" is not an integer in 1..65535"));
  EXPECT_THAT(ParseError("net:[::1:5000"), HasSubstr("address \"[::1:5000\" is not [IPV6]:PORT"));
  EXPECT_THAT(ParseError("net:::1:5000"), HasSubstr("write IPv6 as [ADDR]:PORT"));
  EXPECT_THAT(ParseError("net:h:1,timeout_ms=0"),
              HasSubstr("timeout_ms \"0\" is not an integer in 1..600000 milliseconds"));
  EXPECT_THAT(ParseError("net:h:1,timeout_ms"), HasSubstr("option \"timeout_ms\" needs a value"));
  EXPECT_THAT(
      ParseError("net:h:1,fps=30"),
      HasSubstr("unknown option \"fps=30\" for net (allowed: timeout_ms=N, intrinsics=ID)"));
  EXPECT_THAT(ParseError("net:h:1,intrinsics=a,intrinsics=b"),
              HasSubstr("option \"intrinsics\" given twice"));
  EXPECT_THAT(ParseError("net:h:1,intrinsics="), HasSubstr("intrinsics id is empty"));
  // Every problem in one message.
  const std::string all = ParseError("net:h:99999,timeout_ms=-5,loop");
  EXPECT_THAT(all, HasSubstr("port \"99999\""));
  EXPECT_THAT(all, HasSubstr("timeout_ms \"-5\""));
  EXPECT_THAT(all, HasSubstr("unknown option \"loop\""));
  // Through the factory: ConfigError before any connection is tried.
  EXPECT_THROW(OpenCamera("net:127.0.0.1:0"), common::ConfigError);
  // The generic spec parser knows the kind and validates with the net parser.
  const CameraSourceSpec spec = ParseCameraSource("net:127.0.0.1:5000,intrinsics=cam0");
  EXPECT_EQ(spec.kind, CameraSourceSpec::Kind::kNet);
  EXPECT_EQ(spec.target, "127.0.0.1:5000");
  EXPECT_EQ(spec.intrinsics_id, "cam0");
  EXPECT_THROW(ParseCameraSource("net:127.0.0.1:99999"), common::ConfigError);
}

// ---- Streaming -------------------------------------------------------------------------------

TEST(NetCameraTest, FramesArriveBitIdenticalWithIncreasingIds) {
  const CameraFormat format{64, 48, PixelFormat::kBgr8, 60.0};
  auto server = PatternServer(format, "hexapod-perspective-v1");
  EXPECT_THAT(server->backend(), MatchesRegex("net:127\\.0\\.0\\.1:[0-9]+"));
  auto camera = OpenNet(server->backend());
  EXPECT_EQ(camera->lifecycle(), common::DeviceLifecycle::kConfigured);
  EXPECT_EQ(camera->format().width, 64);
  EXPECT_EQ(camera->format().height, 48);
  EXPECT_EQ(camera->format().pixel_format, PixelFormat::kBgr8);
  EXPECT_EQ(camera->format().fps, 60.0);
  EXPECT_EQ(camera->intrinsics_id(), "hexapod-perspective-v1");

  Image image;
  EXPECT_EQ(camera->Grab(&image, 100ms), make_error_code(Errc::kNotActive));
  ASSERT_FALSE(camera->Start());
  int64_t last_timestamp = -1;
  uint64_t last_id = 0;
  for (int i = 0; i < 30; ++i) {
    ASSERT_FALSE(camera->Grab(&image, 1000ms)) << camera->last_error();
    if (i > 0) {
      EXPECT_GT(image.frame_id, last_id);
    }
    EXPECT_GE(image.timestamp.count(), last_timestamp);
    last_id = image.frame_id;
    last_timestamp = image.timestamp.count();
    ASSERT_EQ(image.width, 64);
    ASSERT_EQ(image.height, 48);
    ASSERT_EQ(image.format, PixelFormat::kBgr8);
    ASSERT_EQ(image.stride, 64u * 3);
    ASSERT_EQ(image.data.size(), 64u * 3 * 48);
    EXPECT_EQ(image.intrinsics_id, "hexapod-perspective-v1");
    ExpectPattern(image, image.frame_id);
  }
  // The source renders on demand, so a single reader sees every frame: ids 1..30 after the
  // frame Open() read (id 0).
  EXPECT_EQ(last_id, 30u);
  const CameraCounters c = camera->counters();
  EXPECT_EQ(c.frames, 30u);
  EXPECT_EQ(c.dropped, 0u);
  EXPECT_EQ(c.timeouts, 0u);
  EXPECT_EQ(c.decode_errors, 0u);
}

TEST(NetCameraTest, PaddedRowsMono16AndTimeStampsCrossUnchanged) {
  // A source with padded rows (stride > row) and 16-bit samples, time stamps of its own.
  std::mt19937 rng(7);
  std::vector<uint8_t> sent;
  std::atomic<uint64_t> next{100};
  FrameSource source = [&](Image* image) -> std::error_code {
    image->Resize(7, 5, PixelFormat::kMono16);
    image->stride = 7 * 2 + 6;
    image->data.resize(image->stride * 5);
    for (uint8_t& b : image->data) b = static_cast<uint8_t>(rng());
    sent = image->data;
    image->frame_id = next;
    next += 3;  // a source that numbers with gaps
    image->timestamp = common::Duration(123'456'789'000LL + static_cast<int64_t>(image->frame_id));
    image->intrinsics_id = "";
    return {};
  };
  auto server = FrameServer::Listen(source);
  auto camera = OpenNet(server->backend() + ",intrinsics=override-id");
  EXPECT_EQ(camera->intrinsics_id(), "override-id");
  EXPECT_EQ(camera->format().pixel_format, PixelFormat::kMono16);
  ASSERT_FALSE(camera->Start());
  Image image;
  for (int i = 0; i < 3; ++i) {
    ASSERT_FALSE(camera->Grab(&image, 1000ms)) << camera->last_error();
    EXPECT_EQ(image.frame_id, 103u + 3u * i);
    EXPECT_EQ(image.timestamp.count(), 123'456'789'000LL + static_cast<int64_t>(image.frame_id));
    EXPECT_EQ(image.stride, 20u);
    EXPECT_EQ(image.data, sent);
    EXPECT_EQ(image.intrinsics_id, "override-id");
  }
  // Gaps in the server's numbering are frames this reader never got.
  EXPECT_EQ(camera->counters().dropped, 4u);
}

TEST(NetCameraTest, SeveralClientsEachGetCorrectFramesAndShareFreshOnes) {
  const CameraFormat format{32, 24, PixelFormat::kMono8, 30.0};
  auto server = PatternServer(format);
  constexpr int kClients = 4;
  constexpr int kFrames = 40;
  std::vector<std::unique_ptr<NetCamera>> cameras;
  for (int i = 0; i < kClients; ++i) cameras.push_back(OpenNet(server->backend()));
  EXPECT_EQ(server->stats().connections_open, static_cast<uint64_t>(kClients));
  std::vector<int> good(kClients, 0);
  std::vector<int> increasing(kClients, 0);
  std::vector<std::thread> threads;
  for (int c = 0; c < kClients; ++c) {
    threads.emplace_back([&, c] {
      NetCamera& camera = *cameras[c];
      if (camera.Start()) return;
      Image image;
      uint64_t last = 0;
      for (int i = 0; i < kFrames; ++i) {
        if (camera.Grab(&image, 2000ms)) return;
        bool same = image.data.size() == 32u * 24;
        for (size_t k = 0; same && k < image.data.size(); ++k) {
          same = image.data[k] == PatternByte(image.frame_id, k);
        }
        good[c] += same ? 1 : 0;
        increasing[c] += (i == 0 || image.frame_id > last) ? 1 : 0;
        last = image.frame_id;
      }
    });
  }
  for (std::thread& t : threads) t.join();
  for (int c = 0; c < kClients; ++c) {
    EXPECT_EQ(good[c], kFrames) << "client " << c << ": " << cameras[c]->last_error();
    EXPECT_EQ(increasing[c], kFrames) << "client " << c;
  }
  const FrameServerStats s = server->stats();
  EXPECT_EQ(s.frames_sent, static_cast<uint64_t>(kClients * (kFrames + 1)));
  // Every request asks for a frame newer than the client's last, which the source may already
  // have rendered for another client: never more fresh frames than requests.
  EXPECT_LE(s.source_frames, s.frames_sent);
  EXPECT_GE(s.source_frames, static_cast<uint64_t>(kFrames + 1));
}

TEST(NetCameraTest, ASourceErrorIsPassedOnAndTheCameraStaysActive) {
  std::atomic<int> calls{0};
  FrameSource source = [&](Image* image) -> std::error_code {
    const int k = calls++;
    if (k == 2) return Errc::kDeviceFault;
    image->Resize(4, 4, PixelFormat::kMono8);
    image->frame_id = static_cast<uint64_t>(k);
    return {};
  };
  auto server = FrameServer::Listen(source);
  auto camera = OpenNet(server->backend());  // call 0
  ASSERT_FALSE(camera->Start());
  Image image;
  EXPECT_FALSE(camera->Grab(&image, 1000ms));  // call 1
  EXPECT_EQ(camera->Grab(&image, 1000ms), make_error_code(Errc::kDeviceFault));
  EXPECT_EQ(camera->lifecycle(), common::DeviceLifecycle::kActive);
  EXPECT_FALSE(camera->Grab(&image, 1000ms));  // call 3
  EXPECT_EQ(image.frame_id, 3u);
  EXPECT_EQ(camera->counters().decode_errors, 1u);
  EXPECT_EQ(server->stats().errors_sent, 1u);
}

TEST(NetCameraTest, GrabDoesNotAllocateOnceBuffersHaveTheFrameSize) {
  auto server = PatternServer(CameraFormat{80, 60, PixelFormat::kBgr8, 30.0},
                              "an-intrinsics-id-longer-than-small-string-buffers");
  auto camera = OpenNet(server->backend());
  ASSERT_FALSE(camera->Start());
  Image image;
  ASSERT_FALSE(camera->Grab(&image, 1000ms));  // sizes the buffers
  const long before = testing::ThreadAllocations();
  for (int i = 0; i < 50; ++i) ASSERT_FALSE(camera->Grab(&image, 1000ms));
  EXPECT_EQ(testing::ThreadAllocations() - before, 0);
  ExpectPattern(image, image.frame_id);
  EXPECT_EQ(image.intrinsics_id, "an-intrinsics-id-longer-than-small-string-buffers");
}

// ---- Faults ----------------------------------------------------------------------------------

TEST(NetCameraTest, ServerStopsAnsweringGrabTimesOutThenFaultsWithoutHanging) {
  auto server = PatternServer(CameraFormat{16, 16, PixelFormat::kMono8, 30.0});
  auto camera = OpenNet(server->backend() + ",timeout_ms=300");
  ASSERT_FALSE(camera->Start());
  Image image;
  ASSERT_FALSE(camera->Grab(&image, 1000ms));
  server->StopAnswering(std::chrono::milliseconds::max());
  // A short grab timeout is a timeout, not a lost link: the camera stays active...
  EXPECT_EQ(camera->Grab(&image, 20ms), make_error_code(Errc::kTimeout));
  EXPECT_EQ(camera->lifecycle(), common::DeviceLifecycle::kActive);
  // ...until the request has gone unanswered for timeout_ms.
  std::error_code ec;
  int grabs = 1;
  while (camera->lifecycle() == common::DeviceLifecycle::kActive && grabs < 100) {
    ec = camera->Grab(&image, 50ms);
    EXPECT_EQ(ec, make_error_code(Errc::kTimeout));
    ++grabs;
  }
  EXPECT_EQ(camera->lifecycle(), common::DeviceLifecycle::kFault);
  EXPECT_LT(grabs, 100);
  EXPECT_GE(camera->counters().timeouts, 2u);
  EXPECT_THAT(camera->last_error(),
              MatchesRegex("net:127\\.0\\.0\\.1:[0-9]+,timeout_ms=300: grab failed: no answer to "
                           "a frame request for timeout_ms = 300 ms .*; camera in fault"));
  EXPECT_EQ(camera->Grab(&image, 10ms), make_error_code(Errc::kClosed));
  EXPECT_GE(server->stats().swallowed, 1u);

  // Open() from fault reconnects; a silent server fails it within the timeout.
  try {
    camera->Open();
    FAIL() << "no HalError";
  } catch (const HalError& e) {
    EXPECT_THAT(e.what(), HasSubstr("open failed: no frame within timeout_ms = 300 ms"));
  }
  server->ResumeAnswering();
  camera->Open();
  EXPECT_EQ(camera->lifecycle(), common::DeviceLifecycle::kConfigured);
  ASSERT_FALSE(camera->Start());
  ASSERT_FALSE(camera->Grab(&image, 1000ms)) << camera->last_error();
  ExpectPattern(image, image.frame_id);
}

TEST(NetCameraTest, DroppedConnectionFaultsAndOpenReconnects) {
  auto server = PatternServer(CameraFormat{16, 8, PixelFormat::kMono8, 30.0});
  auto camera = OpenNet(server->backend());
  ASSERT_FALSE(camera->Start());
  Image image;
  ASSERT_FALSE(camera->Grab(&image, 1000ms));
  EXPECT_EQ(server->DropConnections(), 1);
  const std::error_code ec = camera->Grab(&image, 1000ms);
  EXPECT_EQ(ec, make_error_code(Errc::kClosed));
  EXPECT_EQ(camera->lifecycle(), common::DeviceLifecycle::kFault);
  EXPECT_THAT(camera->last_error(),
              MatchesRegex("net:127\\.0\\.0\\.1:[0-9]+: grab failed: (the server closed the "
                           "connection|cannot send a request: .*|receive failed: .*); camera in "
                           "fault"));
  EXPECT_EQ(camera->Start(), make_error_code(Errc::kNotActive));
  camera->Open();
  ASSERT_FALSE(camera->Start());
  ASSERT_FALSE(camera->Grab(&image, 1000ms)) << camera->last_error();
  ExpectPattern(image, image.frame_id);
  EXPECT_EQ(server->stats().connections_dropped, 1u);
  EXPECT_EQ(server->stats().connections_accepted, 2u);
}

TEST(NetCameraTest, BadMagicFaultsWithAClearMessage) {
  auto server = PatternServer(CameraFormat{16, 8, PixelFormat::kMono8, 30.0});
  auto camera = OpenNet(server->backend());
  ASSERT_FALSE(camera->Start());
  Image image;
  ASSERT_FALSE(camera->Grab(&image, 1000ms));
  server->CorruptMagic(1);
  EXPECT_EQ(camera->Grab(&image, 1000ms), make_error_code(Errc::kProtocol));
  EXPECT_EQ(camera->lifecycle(), common::DeviceLifecycle::kFault);
  EXPECT_EQ(camera->counters().decode_errors, 1u);
  EXPECT_THAT(camera->last_error(),
              MatchesRegex("net:127\\.0\\.0\\.1:[0-9]+: grab failed: bad magic 0x00000000 in a "
                           "frame header \\(expected 0x5246564b, \"KVFR\"\\).*; camera in fault"));
  // At open, the same cause fails the open.
  server->CorruptMagic(1);
  try {
    camera->Open();
    FAIL() << "no HalError";
  } catch (const HalError& e) {
    EXPECT_THAT(e.what(), HasSubstr("open failed: bad magic 0x00000000"));
  }
  camera->Open();
  ASSERT_FALSE(camera->Start());
  EXPECT_FALSE(camera->Grab(&image, 1000ms));
  EXPECT_EQ(server->stats().corrupted, 2u);
}

TEST(NetCameraTest, OpenWithNoServerNamesTheSourceAndTheCause) {
  int port = 0;
  {
    auto server = PatternServer(CameraFormat{4, 4, PixelFormat::kMono8, 30.0});
    port = server->port();
  }  // stopped: nothing listens there now
  const std::string source = "net:127.0.0.1:" + std::to_string(port);
  try {
    OpenCamera(source);
    FAIL() << "no HalError";
  } catch (const HalError& e) {
    EXPECT_EQ(e.device(), source);
    EXPECT_THAT(e.what(), MatchesRegex(".*net:127\\.0\\.0\\.1:[0-9]+: open failed: cannot "
                                       "connect: .*ECONNREFUSED.*"));
  }
  NetCamera camera(source, ParseNetCameraSource(source));
  EXPECT_THROW(camera.Open(), HalError);
  EXPECT_EQ(camera.lifecycle(), common::DeviceLifecycle::kUnconfigured);
  EXPECT_THAT(camera.last_error(), HasSubstr("cannot connect"));
}

// ---- Throughput (printed, never asserted) -----------------------------------------------------

TEST(NetCameraThroughputTest, Vga640x480Mono8) {
  // A source that only stamps the frame id into the pixels, so the transport is what is timed.
  const CameraFormat format{640, 480, PixelFormat::kMono8, 30.0};
  RenderFn cheap = [](uint64_t frame_id, common::Duration, Image* image) {
    std::memset(image->data.data(), static_cast<int>(frame_id & 0xFF), image->data.size());
    return std::error_code();
  };
  FrameServerOptions options;
  auto server = FrameServer::Listen(RenderFrameSource(format, cheap, ""), options);
  auto camera = OpenNet(server->backend());
  ASSERT_FALSE(camera->Start());
  Image image;
  ASSERT_FALSE(camera->Grab(&image, 1000ms));
  constexpr int kFrames = 300;
  const auto start = std::chrono::steady_clock::now();
  int wrong = 0;
  for (int i = 0; i < kFrames; ++i) {
    ASSERT_FALSE(camera->Grab(&image, 2000ms)) << camera->last_error();
    wrong += image.data[640 * 480 - 1] == static_cast<uint8_t>(image.frame_id & 0xFF) ? 0 : 1;
  }
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  EXPECT_EQ(wrong, 0);
  const double fps = kFrames / seconds;
  std::cout << "[ throughput ] net: 640x480 mono8 over loopback, request/response: " << fps
            << " frames/s, " << fps * 640 * 480 / 1e6 << " MB/s (" << kFrames << " frames)\n";
  RecordProperty("frames_per_second", std::to_string(fps));
}

}  // namespace
}  // namespace kinevis::hal
