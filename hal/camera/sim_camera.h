#pragma once

// The simulated camera (source string "sim:NAME[,fps=F][,intrinsics=ID]", docs/cameras.md).
//
// hal/ knows nothing of scenes or robots: the pixels come from a render callback that sim/
// registers under a name in a process-wide registry ("hexapod-perspective"). SimCamera looks the
// name up, paces frames on a common::Clock at the nominal frame rate and asks the callback for each
// frame. On a SimulatedClock the camera runs as fast as the simulation advances time (in free-
// running mode every Grab() moves the clock to the next frame at once), so tests are exact and
// fast.
//
// Frame k is captured at start + k / fps, where start is the clock time of Start(); its frame id
// is k and its timestamp that capture time. A caller that comes late by a whole period or more
// gets the newest frame already captured; the ones it missed are counted as dropped (a real
// camera that keeps only the latest frame behaves the same).

#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

#include "common/clock.h"
#include "hal/camera/camera.h"

namespace kinevis::hal {

// Renders frame `frame_id`, captured at clock time `time`, into `image`. The image arrives sized
// to the registered format (width, height, pixel format, stride, data); the callback writes the
// pixels and must not resize it. Returns {} or an error code of its own, which Grab() passes on
// (counted as a decode error). Called from the thread that calls Grab(); renders of different
// cameras may run at the same time.
using RenderFn =
    std::function<std::error_code(uint64_t frame_id, common::Duration time, Image* image)>;

// Registers a render source under `name` for every SimCamera of this process. `format` is what
// the callback renders: width, height > 0, fps > 0 (the nominal rate; "fps=F" in a source
// string overrides it). `intrinsics_id` names the camera model the renderer projects with.
// Throws ConfigError when the name is empty or already registered, the format is invalid or
// `render` is empty. Thread-safe. A callback must not register or unregister sources itself.
void RegisterRenderSource(const std::string& name, const CameraFormat& format, RenderFn render,
                          const std::string& intrinsics_id = "");

// Removes a render source; false when none had that name. Blocks until renders in progress
// finish; after it returns the callback is never called again, and the SimCameras that used it
// report Errc::kClosed and go to fault. Thread-safe.
bool UnregisterRenderSource(std::string_view name);

// The registered names, sorted.
std::vector<std::string> RegisteredRenderSources();

struct SimCameraOptions {
  std::string source;         // the render source's registered name
  double fps = 0.0;           // frames/s; 0: the rate it was registered with
  std::string intrinsics_id;  // empty: the one it was registered with
};

class SimCamera final : public Camera {
 public:
  // `name` is the source string ("sim:hexapod-perspective"). `clock` paces the frames and must
  // outlive the camera. Nothing is looked up before Open().
  SimCamera(std::string name, SimCameraOptions options,
            common::Clock& clock = common::SteadyClock::Instance());

  const std::string& name() const override { return name_; }
  common::DeviceLifecycle lifecycle() const override;

  // Looks the render source up. Throws HalError naming the source and listing the registered
  // names when there is none of that name; ConfigError when options.fps is negative.
  void Open() override;
  // Frame 0 is captured at the clock time of Start().
  std::error_code Start() override;
  void Stop() override;

  // Sleeps on the clock until the next frame is due (at most `timeout`), then renders it into
  // *out. Errc::kTimeout when the frame is due later than now + timeout (the clock has then moved
  // to now + timeout); Errc::kClosed when the render source was unregistered (-> fault); the
  // callback's own error code when it fails, or Errc::kProtocol when it resized the image.
  std::error_code Grab(Image* out, std::chrono::milliseconds timeout) override;

  CameraFormat format() const override;
  const std::string& intrinsics_id() const override { return intrinsics_id_; }
  CameraCounters counters() const override { return counters_.Snapshot(); }

 private:
  // Capture time of frame k: start + k / fps, computed from k so that rounding never accumulates.
  common::Duration FrameTime(uint64_t k) const;

  const std::string name_;
  const SimCameraOptions options_;
  common::Clock& clock_;
  std::atomic<common::DeviceLifecycle> lifecycle_{common::DeviceLifecycle::kUnconfigured};
  mutable std::mutex format_mutex_;  // format_ is written by Open() and read from any thread
  CameraFormat format_;
  std::string intrinsics_id_;  // written by Open() only, before streaming
  AtomicCameraCounters counters_;
  common::Duration start_{0};
  uint64_t next_frame_ = 0;
};

}  // namespace kinevis::hal
