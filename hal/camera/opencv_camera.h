#pragma once

// Cameras read through OpenCV's videoio and imgcodecs (docs/cameras.md):
//
//   v4l2:/dev/video0[,width=W,height=H][,fps=F][,format=PIX][,latest]  a V4L2 device (CAP_V4L2)
//   file:PATH[,loop][,fps=F][,format=PIX][,latest]    a video file of any container OpenCV reads
//   images:GLOB[,loop][,fps=F][,format=PIX][,latest]  a sorted glob of image files (PNG, JPEG...)
//
// OpenCV stays inside opencv_camera.cc: this header only holds the options and a pointer to the
// implementation.
//
// Grab() runs in the caller's thread: it reads and converts one frame and returns. With `latest`
// a grabber thread reads the source continuously and keeps only the newest frame; Grab() then
// waits for a frame newer than the last one it returned, copies it out and returns at once, which
// is what a real-time servo loop needs (no queue of stale frames, bounded waits). For a file or
// image sequence `latest` replays the recording as a live camera: frames are published at their
// recorded spacing on the camera's clock (which should then be a SteadyClock), and a slow reader
// misses frames as it would on the real camera.
//
// Timestamps (on the camera's clock, see docs/cameras.md):
//  - v4l2: the driver's buffer time stamp (CLOCK_MONOTONIC, the steady clock) when it is
//    plausible on the camera's clock (not in the future, less than 1 s old), else the clock's
//    Now() when OpenCV handed over the frame;
//  - file: the frame's position in the recording, from frame index / fps when `fps=F` is given,
//    else from the container's presentation time (CAP_PROP_POS_MSEC) made strictly increasing;
//    looping adds the length of the recording at each pass, so time never goes back;
//  - images: frame_id / fps (default 30 fps).
//
// Counters:
//  - frames: frames Grab() delivered;
//  - dropped: v4l2 gaps in the driver's time stamps longer than 1.5 periods (the missing frames),
//    and frames the `latest` grabber replaced before anyone took them;
//  - duplicates: v4l2 frames whose time stamp is not newer than the previous frame's (skipped);
//  - decode_errors: image files that do not decode or whose size differs from the first image's,
//    video frames OpenCV cannot retrieve or whose size changed (all skipped, logged with the path
//    or frame number);
//  - timeouts: v4l2 reads that failed while the device node still exists, and `latest` waits that
//    ran out.

#include <memory>
#include <optional>
#include <string>

#include "common/clock.h"
#include "hal/camera/camera.h"

namespace kinevis::hal {

struct OpenCvCameraOptions {
  enum class Kind { kV4l2, kFile, kImages };
  Kind kind = Kind::kFile;
  std::string path;  // the device node, the video file, or the glob pattern of the images
  // v4l2: the capture size to ask the driver for, pixels; 0 (both): the driver's current size.
  int width = 0;
  int height = 0;
  // Nominal frame rate, frames/s; 0: the driver's (v4l2), the container's (file), 30 (images).
  // v4l2: asked of the driver. file, images: the rate the timestamps are computed with.
  double fps = 0.0;
  // Pixel format of the delivered images; nullopt: kBgr8 for v4l2 and files, for images the
  // first image's own (kMono8 or kMono16 for grey images, else kBgr8).
  std::optional<PixelFormat> format;
  bool loop = false;    // file, images: start again at the end instead of Errc::kClosed
  bool latest = false;  // grabber thread keeping only the newest frame (see the top of the file)
  std::string intrinsics_id;  // copied into every Image
};

class OpenCvCamera final : public Camera {
 public:
  // `name` is the source string ("v4l2:/dev/video0"); `clock` time-stamps frames and measures
  // timeouts and must outlive the camera. Nothing is opened before Open().
  OpenCvCamera(std::string name, OpenCvCameraOptions options,
               common::Clock& clock = common::SteadyClock::Instance());
  ~OpenCvCamera() override;
  OpenCvCamera(const OpenCvCamera&) = delete;
  OpenCvCamera& operator=(const OpenCvCamera&) = delete;

  const std::string& name() const override;
  common::DeviceLifecycle lifecycle() const override;

  // Opens the source and learns the format; reads the first frame of a file or the first image
  // that decodes (it is the first one Grab() delivers). Throws HalError naming the source and
  // the path when the device or file does not exist or cannot be opened, no file matches the
  // glob or none of them decodes, or the device refuses the asked width and height; ConfigError
  // when the options are inconsistent (only one of width and height, a size for a recording, a
  // frame rate out of (0, 10000]).
  void Open() override;
  // Starts the grabber thread with `latest`. Files and image sequences resume where Stop() left
  // them (they do not rewind).
  std::error_code Start() override;
  // Joins the grabber thread, which may take until OpenCV's read of the device returns.
  void Stop() override;

  // Caller's thread (no `latest`): reads until a frame is delivered, skipping frames that do not
  // decode and v4l2 duplicates. Files and images never wait, so `timeout` does not apply to them;
  // for v4l2 it bounds the retries, but a single read blocks inside OpenCV until the device
  // delivers or OpenCV's own select() timeout (OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT, 10 s by
  // default) passes. With `latest`: waits at most `timeout` (wall time) for a frame newer than
  // the last one returned and copies it out (Errc::kTimeout when none came).
  // End of a file or sequence without `loop`: Errc::kClosed (the camera stays active and keeps
  // answering kClosed). A device node that vanished: Errc::kClosed and fault.
  std::error_code Grab(Image* out, std::chrono::milliseconds timeout) override;

  CameraFormat format() const override;
  const std::string& intrinsics_id() const override;
  CameraCounters counters() const override;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace kinevis::hal
