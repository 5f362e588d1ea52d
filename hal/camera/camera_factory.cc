#include "hal/camera/camera_factory.h"

#include <charconv>
#include <cmath>
#include <set>
#include <vector>

#include "hal/camera/net_camera.h"
#include "hal/camera/opencv_camera.h"
#include "hal/camera/sim_camera.h"
#include "hal/common/error.h"

namespace kinevis::hal {
namespace {

using Kind = CameraSourceSpec::Kind;

constexpr int kMaxSide = 16384;
constexpr double kMaxFps = 10'000.0;

// Collects every problem with one source string, then throws them together.
class Problems : public common::Problems {
 public:
  explicit Problems(std::string_view text)
      : common::Problems("camera source \"" + std::string(text) + "\"") {}
};

bool ParseInt(std::string_view s, int min, int max, int* out) {
  if (s.empty()) return false;
  int value = 0;
  auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), value);
  if (ec != std::errc() || ptr != s.data() + s.size() || value < min || value > max) return false;
  *out = value;
  return true;
}

bool ParseFps(std::string_view s, double* out) {
  if (s.empty()) return false;
  double value = 0.0;
  auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), value);
  if (ec != std::errc() || ptr != s.data() + s.size() || !std::isfinite(value) || value <= 0.0 ||
      value > kMaxFps) {
    return false;
  }
  *out = value;
  return true;
}

std::vector<std::string_view> Split(std::string_view s, char sep) {
  std::vector<std::string_view> parts;
  size_t start = 0;
  while (true) {
    size_t pos = s.find(sep, start);
    parts.push_back(s.substr(start, pos == std::string_view::npos ? pos : pos - start));
    if (pos == std::string_view::npos) break;
    start = pos + 1;
  }
  return parts;
}

// The options each scheme takes, as listed in the error for an unknown one.
const char* AllowedOptions(Kind kind) {
  switch (kind) {
    case Kind::kV4l2:
      return "width=W, height=H, fps=F, format=PIX, latest, intrinsics=ID";
    case Kind::kFile:
    case Kind::kImages:
      return "loop, fps=F, format=PIX, latest, intrinsics=ID";
    case Kind::kSim:
      return "fps=F, intrinsics=ID";
    case Kind::kNet:
      return "timeout_ms=N, intrinsics=ID";
  }
  return "";
}

bool Allows(Kind kind, std::string_view key) {
  if (key == "fps" || key == "intrinsics") return true;
  switch (kind) {
    case Kind::kV4l2:
      return key == "width" || key == "height" || key == "format" || key == "latest";
    case Kind::kFile:
    case Kind::kImages:
      return key == "loop" || key == "format" || key == "latest";
    case Kind::kSim:
      return false;
    case Kind::kNet:
      return key == "timeout_ms";
  }
  return false;
}

const char* TargetName(Kind kind) {
  switch (kind) {
    case Kind::kV4l2:
      return "device path";
    case Kind::kFile:
      return "file path";
    case Kind::kImages:
      return "glob pattern";
    case Kind::kSim:
      return "render source name";
    case Kind::kNet:
      return "HOST:PORT";
  }
  return "target";
}

}  // namespace

const char* ToString(CameraSourceSpec::Kind kind) {
  switch (kind) {
    case Kind::kV4l2:
      return "v4l2";
    case Kind::kFile:
      return "file";
    case Kind::kImages:
      return "images";
    case Kind::kSim:
      return "sim";
    case Kind::kNet:
      return "net";
  }
  return "?";
}

CameraSourceSpec ParseCameraSource(std::string_view source) {
  Problems problems(source);
  CameraSourceSpec spec;
  spec.text = std::string(source);
  const size_t colon = source.find(':');
  if (colon == std::string_view::npos || colon == 0) {
    problems.Add(
        "no scheme; expected SCHEME:TARGET with SCHEME one of v4l2, file, images, sim, net "
        "(see docs/cameras.md)");
    problems.ThrowIfAny();
  }
  const std::string_view scheme = source.substr(0, colon);
  if (scheme == "v4l2") {
    spec.kind = Kind::kV4l2;
  } else if (scheme == "file") {
    spec.kind = Kind::kFile;
  } else if (scheme == "images") {
    spec.kind = Kind::kImages;
  } else if (scheme == "sim") {
    spec.kind = Kind::kSim;
  } else if (scheme == "net") {
    // Fully validated by ParseNetCameraSource (host, port, options); the spec carries the kind and
    // the HOST:PORT target for tools that describe a source.
    const NetCameraOptions net = ParseNetCameraSource(source);
    spec.kind = Kind::kNet;
    spec.target = net.host + ":" + std::to_string(net.port);
    spec.intrinsics_id = net.intrinsics_id;
    return spec;
  } else {
    problems.Add("scheme \"" + std::string(scheme) +
                 "\" is not a camera source (v4l2, file, images, sim, net)");
    problems.ThrowIfAny();
  }
  const std::vector<std::string_view> fields = Split(source.substr(colon + 1), ',');
  spec.target = std::string(fields.front());
  if (spec.target.empty()) problems.Add(std::string(TargetName(spec.kind)) + " is empty");

  std::set<std::string_view> seen;
  for (size_t i = 1; i < fields.size(); ++i) {
    const std::string_view item = fields[i];
    const size_t eq = item.find('=');
    const std::string_view key = item.substr(0, eq);
    const bool has_value = eq != std::string_view::npos;
    const std::string_view value = has_value ? item.substr(eq + 1) : std::string_view();
    if (key.empty()) {
      problems.Add("empty option \"" + std::string(item) + "\"");
      continue;
    }
    if (!Allows(spec.kind, key)) {
      problems.Add("unknown option \"" + std::string(item) + "\" for " + ToString(spec.kind) +
                   " (allowed: " + AllowedOptions(spec.kind) + ")");
      continue;
    }
    if (!seen.insert(key).second) {
      problems.Add("option \"" + std::string(key) + "\" given twice");
      continue;
    }
    const bool flag = key == "loop" || key == "latest";
    if (flag) {
      if (has_value) {
        problems.Add("option \"" + std::string(key) + "\" takes no value (got \"" +
                     std::string(item) + "\")");
      } else if (key == "loop") {
        spec.loop = true;
      } else {
        spec.latest = true;
      }
      continue;
    }
    if (!has_value) {
      problems.Add("option \"" + std::string(key) + "\" needs a value (" + std::string(key) +
                   "=...)");
      continue;
    }
    if (key == "width" || key == "height") {
      int* out = key == "width" ? &spec.width : &spec.height;
      if (!ParseInt(value, 1, kMaxSide, out)) {
        problems.Add(std::string(key) + " \"" + std::string(value) +
                     "\" is not an integer in 1..16384 pixels");
      }
    } else if (key == "fps") {
      if (!ParseFps(value, &spec.fps)) {
        problems.Add("fps \"" + std::string(value) + "\" is not a number in (0, 10000] frames/s");
      }
    } else if (key == "format") {
      spec.format = ParsePixelFormat(value);
      if (!spec.format) {
        problems.Add("format \"" + std::string(value) +
                     "\" is not a pixel format (mono8, bgr8, rgb8, mono16)");
      }
    } else if (key == "intrinsics") {
      if (value.empty()) problems.Add("intrinsics id is empty");
      spec.intrinsics_id = std::string(value);
    }
  }
  const bool has_width = seen.count("width") != 0;
  const bool has_height = seen.count("height") != 0;
  if (has_width != has_height) {
    problems.Add(has_width ? "width without height (give both or neither)"
                           : "height without width (give both or neither)");
  }
  problems.ThrowIfAny();
  return spec;
}

std::unique_ptr<Camera> OpenCamera(std::string_view source, common::Clock& clock) {
  if (source.substr(0, 4) == "net:") {
    // Frames, ids and time stamps come from the server; timeouts on a socket are wall time, so
    // `clock` has no part in a network camera.
    auto camera = std::make_unique<NetCamera>(std::string(source), ParseNetCameraSource(source));
    camera->Open();
    return camera;
  }
  const CameraSourceSpec spec = ParseCameraSource(source);
  std::unique_ptr<Camera> camera;
  if (spec.kind == Kind::kSim) {
    SimCameraOptions options;
    options.source = spec.target;
    options.fps = spec.fps;
    options.intrinsics_id = spec.intrinsics_id;
    camera = std::make_unique<SimCamera>(spec.text, std::move(options), clock);
  } else {
    OpenCvCameraOptions options;
    options.kind = spec.kind == Kind::kV4l2   ? OpenCvCameraOptions::Kind::kV4l2
                   : spec.kind == Kind::kFile ? OpenCvCameraOptions::Kind::kFile
                                              : OpenCvCameraOptions::Kind::kImages;
    options.path = spec.target;
    options.width = spec.width;
    options.height = spec.height;
    options.fps = spec.fps;
    options.format = spec.format;
    options.loop = spec.loop;
    options.latest = spec.latest;
    options.intrinsics_id = spec.intrinsics_id;
    camera = std::make_unique<OpenCvCamera>(spec.text, std::move(options), clock);
  }
  camera->Open();
  return camera;
}

}  // namespace kinevis::hal
