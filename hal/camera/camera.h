#pragma once

// The one interface of every camera kinevis reads: a V4L2 device, a video file or a directory of
// images through OpenCV (hal/camera/opencv_camera.h), or a simulated camera whose pixels sim/
// renders (hal/camera/sim_camera.h). Cameras are opened from a source string by OpenCamera()
// (hal/camera/camera_factory.h); the strings are documented in docs/cameras.md.
//
// This header does not include OpenCV: an Image is plain bytes, so that control/ and tests can use
// cameras without OpenCV; vision/ wraps the bytes without copying.
//
// Lifecycle (STYLE.md, the DeviceLifecycle of hal/drive/motor_drive.h):
//   unconfigured -> Open() -> configured (format known) -> Start() -> active (streaming)
//   -> fault (the device vanished, the render source was unregistered).
// Grab() is refused with Errc::kNotActive unless active. Stop() goes back to configured.
//
// Threading: one thread drives a camera (Open, Start, Grab, Stop); counters(), format(),
// lifecycle() and name() may be read from any thread.

#include <atomic>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

#include "common/clock.h"
#include "hal/drive/motor_drive.h"

namespace kinevis::hal {

// Pixel layouts. Multi-byte samples (kMono16) are in host byte order.
enum class PixelFormat {
  kMono8,   // 1 byte per pixel
  kBgr8,    // 3 bytes per pixel, blue first (OpenCV's order)
  kRgb8,    // 3 bytes per pixel, red first
  kMono16,  // 2 bytes per pixel
};

// "mono8", "bgr8", "rgb8", "mono16".
const char* ToString(PixelFormat format);
// The inverse of ToString(); std::nullopt for any other text.
std::optional<PixelFormat> ParsePixelFormat(std::string_view text);
// 1, 3, 3 or 2.
int BytesPerPixel(PixelFormat format);

// One frame. Rows are `stride` bytes apart (stride >= width * BytesPerPixel(format)); pixel (x, y)
// starts at data[y * stride + x * BytesPerPixel(format)]. Camera::Grab() refills an Image in
// place: once `data` has the capacity of a frame, grabbing does not allocate.
struct Image {
  int width = 0;   // pixels
  int height = 0;  // pixels
  PixelFormat format = PixelFormat::kMono8;
  size_t stride = 0;          // bytes per row
  std::vector<uint8_t> data;  // height * stride bytes
  // When the frame was captured, on the camera's common::Clock (for a recorded file: its position
  // in the recording, see docs/cameras.md).
  common::Duration timestamp{0};
  // Number of the frame in the stream; strictly increasing, gaps where frames were lost.
  uint64_t frame_id = 0;
  // The calibration the pixels belong to (empty: none declared).
  std::string intrinsics_id;

  // Sets width, height and format with packed rows (stride = width * bytes per pixel) and sizes
  // `data`; reuses the existing capacity, so it allocates only when the frame grew. A negative
  // width or height is taken as 0.
  void Resize(int width, int height, PixelFormat format);
  uint8_t* row(int y) { return data.data() + static_cast<size_t>(y) * stride; }
  const uint8_t* row(int y) const { return data.data() + static_cast<size_t>(y) * stride; }
};

// Writes `image` to `path` in the format its extension names (".png": lossless for every pixel
// format, 16 bits for kMono16; ".jpg", ".bmp", ... as OpenCV's imwrite knows them). Set-up and
// tooling only, not for a loop: throws HalError naming the path when the file cannot be written,
// ConfigError when the image is empty or its data is shorter than height * stride.
void SaveImage(const Image& image, const std::string& path);

// What a camera delivers, known after Open().
struct CameraFormat {
  int width = 0;   // pixels
  int height = 0;  // pixels
  PixelFormat pixel_format = PixelFormat::kBgr8;
  double fps = 0.0;  // nominal frame rate, frames/s (> 0)
};

struct CameraCounters {
  uint64_t frames = 0;         // frames delivered by Grab()
  uint64_t timeouts = 0;       // Grab() calls that ended with Errc::kTimeout
  uint64_t dropped = 0;        // frames the source produced that were never delivered
  uint64_t duplicates = 0;     // frames skipped because they were not newer than the previous
  uint64_t decode_errors = 0;  // frames or files that could not be decoded or rendered
};

// The counters as a backend keeps them: bumped in the grab path (or a grabber thread) without a
// lock, read from any thread.
class AtomicCameraCounters {
 public:
  std::atomic<uint64_t> frames{0};
  std::atomic<uint64_t> timeouts{0};
  std::atomic<uint64_t> dropped{0};
  std::atomic<uint64_t> duplicates{0};
  std::atomic<uint64_t> decode_errors{0};
  CameraCounters Snapshot() const;
};

class Camera {
 public:
  virtual ~Camera() = default;

  // The source string the camera was opened with ("v4l2:/dev/video0"): in every log line and
  // error.
  virtual const std::string& name() const = 0;
  virtual common::DeviceLifecycle lifecycle() const = 0;

  // Set-up: opens the device, file or render source and learns the format -> configured.
  // Throws HalError naming the source, the operation and the cause (no such device or file, no
  // image matches the glob, the device refuses the asked size). Does nothing when configured or
  // active; from fault it releases the source and opens it again.
  virtual void Open() = 0;
  // configured -> active: frames are streamed from now on. Returns Errc::kNotActive when not
  // configured (unconfigured or fault); {} when already active.
  virtual std::error_code Start() = 0;
  // active -> configured: stops streaming (and the grabber thread, if any). Does nothing in the
  // other states.
  virtual void Stop() = 0;

  // Waits at most `timeout` (on the camera's clock) for the next frame and writes it to *out,
  // reusing out's buffer. Returns {} or
  //   Errc::kNotActive  the camera is not active;
  //   Errc::kTimeout    no frame within the timeout (counted);
  //   Errc::kClosed     end of a file or image sequence without `loop`, or the device vanished
  //                     (the camera goes to fault);
  //   another code      the source failed to deliver this frame (a render callback's error,
  //                     Errc::kProtocol for a malformed frame; counted as a decode error).
  // Never throws. See each backend for what it does with `timeout` and what it counts.
  virtual std::error_code Grab(Image* out, std::chrono::milliseconds timeout) = 0;

  // Valid once configured.
  virtual CameraFormat format() const = 0;
  // The calibration the frames belong to; copied into every Image. Empty: none declared.
  virtual const std::string& intrinsics_id() const = 0;
  virtual CameraCounters counters() const = 0;
};

}  // namespace kinevis::hal
