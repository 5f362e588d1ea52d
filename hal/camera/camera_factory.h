#pragma once

// Camera source strings (docs/cameras.md): one line of a deployment file or one command-line
// argument says where the frames come from.
//
//   v4l2:DEVICE[,width=W,height=H][,fps=F][,format=PIX][,latest][,intrinsics=ID]
//   file:PATH[,loop][,fps=F][,format=PIX][,latest][,intrinsics=ID]
//   images:GLOB[,loop][,fps=F][,format=PIX][,latest][,intrinsics=ID]
//   sim:NAME[,fps=F][,intrinsics=ID]
//   net:HOST:PORT[,timeout_ms=N][,intrinsics=ID]   (frames from a kinevis FrameServer over TCP;
//                                                  parsed by ParseNetCameraSource, net_camera.h)
//
// PIX is mono8, bgr8, rgb8 or mono16. Paths and globs cannot contain ','.
// The parser throws common::ConfigError naming the source string, every bad field and its value.

#include <memory>
#include <optional>
#include <string>
#include <string_view>

#include "common/clock.h"
#include "hal/camera/camera.h"

namespace kinevis::hal {

struct CameraSourceSpec {
  enum class Kind { kV4l2, kFile, kImages, kSim, kNet };
  Kind kind = Kind::kFile;
  std::string text;    // the source string as given
  std::string target;  // device node, video file, glob pattern, or render source name
  int width = 0;       // v4l2: capture size to ask for, pixels, 1..16384; 0: the driver's
  int height = 0;
  double fps = 0.0;  // frames/s in (0, 10000]; 0: the source's own (see OpenCvCameraOptions)
  std::optional<PixelFormat> format;  // nullopt: the source's own
  bool loop = false;                  // file, images
  bool latest = false;                // grabber thread keeping the newest frame
  std::string intrinsics_id;          // intrinsics=ID; empty: none (sim: the registered one)
};

// "v4l2", "file", "images", "sim".
const char* ToString(CameraSourceSpec::Kind kind);

// Parses a source string. Throws ConfigError listing every problem: no or unknown scheme, empty
// target, unknown option or one that does not apply to the scheme, a bad value (with the value),
// width without height, an option given twice, a value given to a flag.
CameraSourceSpec ParseCameraSource(std::string_view source);

// Parses `source`, builds the camera (OpenCvCamera or SimCamera) on `clock` and opens it: the
// camera returned is configured; call Start() to stream. `clock` must outlive the camera.
// Throws ConfigError for a bad string (exit code 2 in the CLI) and HalError when the source
// cannot be opened (exit code 3).
std::unique_ptr<Camera> OpenCamera(std::string_view source,
                                   common::Clock& clock = common::SteadyClock::Instance());

}  // namespace kinevis::hal
