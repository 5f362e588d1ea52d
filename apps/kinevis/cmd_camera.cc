// kinevis camera grab|info: read frames from any camera source string (docs/cameras.md).

#include <spdlog/spdlog.h>

#include <chrono>
#include <cinttypes>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <system_error>

#include "apps/kinevis/cli_common.h"
#include "apps/kinevis/commands.h"
#include "common/clock.h"
#include "hal/camera/camera.h"
#include "hal/camera/camera_factory.h"
#include "hal/common/error.h"

namespace kinevis::cli {
namespace {

const char* const kSourceHelp =
    "Camera source: v4l2:/dev/video0[,width=W,height=H,fps=F,format=PIX,latest], "
    "file:PATH[,loop,fps=F], images:GLOB[,loop,fps=F], sim:NAME, "
    "net:HOST:PORT[,timeout_ms=N] (docs/cameras.md)";

struct GrabOptions {
  std::string source;
  int count = 10;  // 0 = until the end of the stream or Ctrl-C
  std::string out_dir;
  int timeout_ms = 2000;
};

int RunGrab(const GrabOptions& o) {
  if (!o.out_dir.empty()) {
    std::error_code fs_error;
    std::filesystem::create_directories(o.out_dir, fs_error);
    if (fs_error || !std::filesystem::is_directory(o.out_dir)) {
      throw common::ConfigError("--out: cannot create the directory \"" + o.out_dir + "\"" +
                                (fs_error ? ": " + fs_error.message() : ""));
    }
  }
  std::unique_ptr<hal::Camera> camera = hal::OpenCamera(o.source);
  const hal::CameraFormat f = camera->format();
  spdlog::info("{}: {}x{} {} at {} fps{}", camera->name(), f.width, f.height,
               hal::ToString(f.pixel_format), f.fps,
               o.count > 0 ? ", grabbing " + std::to_string(o.count) + " frames" : "");
  if (std::error_code ec = camera->Start()) {
    throw hal::HalError(camera->name(), "start", ec.message(), ec);
  }

  hal::Image image;
  int grabbed = 0;
  common::Duration first_stamp{0}, last_stamp{0};
  std::chrono::steady_clock::time_point first_wall, last_wall;
  std::printf("frame_id,timestamp_s%s\n", o.out_dir.empty() ? "" : ",file");
  while (!StopRequested() && (o.count == 0 || grabbed < o.count)) {
    const std::error_code ec = camera->Grab(&image, std::chrono::milliseconds(o.timeout_ms));
    if (ec == hal::Errc::kTimeout) {
      spdlog::warn("{}: no frame within {} ms", camera->name(), o.timeout_ms);
      continue;
    }
    if (ec == hal::Errc::kClosed && camera->lifecycle() != common::DeviceLifecycle::kFault) {
      spdlog::info("{}: end of the stream", camera->name());
      break;
    }
    if (ec) throw hal::HalError(camera->name(), "grab", ec.message(), ec);
    const auto wall = std::chrono::steady_clock::now();
    if (grabbed == 0) {
      first_stamp = image.timestamp;
      first_wall = wall;
    }
    last_stamp = image.timestamp;
    last_wall = wall;
    ++grabbed;
    if (o.out_dir.empty()) {
      std::printf("%" PRIu64 ",%.6f\n", image.frame_id, common::ToSeconds(image.timestamp));
    } else {
      char name[40];
      std::snprintf(name, sizeof name, "frame_%06" PRIu64 ".png", image.frame_id);
      const std::string path = (std::filesystem::path(o.out_dir) / name).string();
      hal::SaveImage(image, path);
      std::printf("%" PRIu64 ",%.6f,%s\n", image.frame_id, common::ToSeconds(image.timestamp),
                  path.c_str());
    }
    std::fflush(stdout);
  }

  // Rates over the frames delivered: by the camera's time stamps (the source's rate as the
  // program saw it) and by the wall clock (how fast this program got them).
  if (grabbed >= 2) {
    const double stamp_span = common::ToSeconds(last_stamp - first_stamp);
    const double wall_span = std::chrono::duration<double>(last_wall - first_wall).count();
    std::printf("# %d frames, %.3f fps by time stamps, %.3f fps by wall clock\n", grabbed,
                stamp_span > 0 ? (grabbed - 1) / stamp_span : 0.0,
                wall_span > 0 ? (grabbed - 1) / wall_span : 0.0);
  } else {
    std::printf("# %d frames\n", grabbed);
  }
  const hal::CameraCounters c = camera->counters();
  spdlog::info("{}: {} frames, {} timeouts, {} dropped, {} duplicates, {} decode errors",
               camera->name(), c.frames, c.timeouts, c.dropped, c.duplicates, c.decode_errors);
  camera->Stop();
  return grabbed > 0 ? kExitOk : kExitJobFailed;
}

int RunInfo(const std::string& source, bool json) {
  const hal::CameraSourceSpec spec = hal::ParseCameraSource(source);
  std::unique_ptr<hal::Camera> camera = hal::OpenCamera(source);
  const hal::CameraFormat f = camera->format();
  if (json) {
    const nlohmann::json out = {{"source", camera->name()},
                                {"kind", hal::ToString(spec.kind)},
                                {"target", spec.target},
                                {"width", f.width},
                                {"height", f.height},
                                {"pixel_format", hal::ToString(f.pixel_format)},
                                {"fps", f.fps},
                                {"intrinsics_id", camera->intrinsics_id()}};
    std::cout << out.dump(2) << "\n";
    return kExitOk;
  }
  std::printf("source:        %s\n", camera->name().c_str());
  std::printf("kind:          %s\n", hal::ToString(spec.kind));
  std::printf("target:        %s\n", spec.target.c_str());
  std::printf("size:          %dx%d\n", f.width, f.height);
  std::printf("pixel format:  %s\n", hal::ToString(f.pixel_format));
  std::printf("frame rate:    %.3f fps\n", f.fps);
  std::printf("intrinsics id: %s\n",
              camera->intrinsics_id().empty() ? "-" : camera->intrinsics_id().c_str());
  return kExitOk;
}

}  // namespace

void AddCameraCommands(const Parents& parents, CommandList* commands) {
  CLI::App& app = *parents.app;
  CLI::App* camera = app.add_subcommand("camera", "Camera tools: grab frames, show a source");
  camera->require_subcommand(1);

  auto grab_opts = std::make_shared<GrabOptions>();
  CLI::App* grab = camera->add_subcommand(
      "grab", "Grab frames; print 'frame_id,timestamp_s[,file]' per frame and the frame rate");
  grab->add_option("source", grab_opts->source, kSourceHelp)->required();
  grab->add_option("-n,--count", grab_opts->count,
                   "Stop after N frames (0: until the end of the stream or Ctrl-C)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  grab->add_option("-o,--out", grab_opts->out_dir,
                   "Save every frame as DIR/frame_<id>.png (the directory is created)");
  grab->add_option("--timeout-ms", grab_opts->timeout_ms, "Wait per frame, ms")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  grab->footer("Exit code 1 when no frame was grabbed.");
  commands->push_back({grab, [grab_opts] { return RunGrab(*grab_opts); }});

  auto info_source = std::make_shared<std::string>();
  auto info_json = std::make_shared<bool>(false);
  CLI::App* info = camera->add_subcommand(
      "info", "Open a source and print its size, pixel format, frame rate and intrinsics id");
  info->add_option("source", *info_source, kSourceHelp)->required();
  info->add_flag("--json", *info_json, "Print a JSON object");
  commands->push_back(
      {info, [info_source, info_json] { return RunInfo(*info_source, *info_json); }});
}

}  // namespace kinevis::cli
