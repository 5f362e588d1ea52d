#include "hal/camera/sim_camera.h"

#include <spdlog/spdlog.h>

#include <cmath>
#include <map>
#include <shared_mutex>

#include "hal/common/error.h"

namespace kinevis::hal {
namespace {

struct RenderSource {
  CameraFormat format;
  std::string intrinsics_id;
  RenderFn render;
};

// The process-wide registry. Renders hold the lock shared for the duration of the callback, so
// that UnregisterRenderSource() (exclusive) waits for them and never pulls a callback out from
// under a running render.
class Registry {
 public:
  static Registry& Instance() {
    static Registry registry;
    return registry;
  }

  std::shared_mutex mutex;
  std::map<std::string, RenderSource, std::less<>> sources;
};

std::string JoinedNames(const std::vector<std::string>& names) {
  if (names.empty()) return "none registered; sim/ registers them when a world is built";
  std::string all = "registered: ";
  for (size_t i = 0; i < names.size(); ++i) {
    if (i > 0) all += ", ";
    all += names[i];
  }
  return all;
}

}  // namespace

void RegisterRenderSource(const std::string& name, const CameraFormat& format, RenderFn render,
                          const std::string& intrinsics_id) {
  std::vector<std::string> problems;
  if (name.empty()) problems.push_back("the name is empty");
  if (format.width <= 0 || format.height <= 0) {
    problems.push_back("size " + std::to_string(format.width) + "x" +
                       std::to_string(format.height) + " is not positive");
  }
  if (!(format.fps > 0.0) || !std::isfinite(format.fps)) {
    problems.push_back("fps " + std::to_string(format.fps) + " is not a positive number");
  }
  if (!render) problems.push_back("the render callback is empty");
  std::unique_lock<std::shared_mutex> lock(Registry::Instance().mutex);
  auto& sources = Registry::Instance().sources;
  if (!name.empty() && sources.count(name) != 0) problems.push_back("the name is already taken");
  if (!problems.empty()) {
    std::string all = "render source \"" + name + "\": ";
    for (size_t i = 0; i < problems.size(); ++i) all += (i > 0 ? "; " : "") + problems[i];
    throw common::ConfigError(all);
  }
  sources.emplace(name, RenderSource{format, intrinsics_id, std::move(render)});
}

bool UnregisterRenderSource(std::string_view name) {
  std::unique_lock<std::shared_mutex> lock(Registry::Instance().mutex);
  auto& sources = Registry::Instance().sources;
  auto it = sources.find(name);
  if (it == sources.end()) return false;
  sources.erase(it);
  return true;
}

std::vector<std::string> RegisteredRenderSources() {
  std::shared_lock<std::shared_mutex> lock(Registry::Instance().mutex);
  std::vector<std::string> names;
  for (const auto& [name, source] : Registry::Instance().sources) names.push_back(name);
  return names;  // std::map keeps them sorted
}

SimCamera::SimCamera(std::string name, SimCameraOptions options, common::Clock& clock)
    : name_(std::move(name)), options_(std::move(options)), clock_(clock) {}

common::DeviceLifecycle SimCamera::lifecycle() const { return lifecycle_.load(); }

CameraFormat SimCamera::format() const {
  std::lock_guard<std::mutex> lock(format_mutex_);
  return format_;
}

void SimCamera::Open() {
  const common::DeviceLifecycle state = lifecycle_.load();
  if (state == common::DeviceLifecycle::kConfigured || state == common::DeviceLifecycle::kActive)
    return;
  if (options_.fps < 0.0 || !std::isfinite(options_.fps)) {
    throw common::ConfigError("camera source \"" + name_ + "\": fps " +
                              std::to_string(options_.fps) + " is not a positive number");
  }
  CameraFormat format;
  std::string intrinsics_id;
  {
    std::shared_lock<std::shared_mutex> lock(Registry::Instance().mutex);
    const auto& sources = Registry::Instance().sources;
    auto it = sources.find(options_.source);
    if (it == sources.end()) {
      lock.unlock();
      throw HalError(name_, "open",
                     "no render source \"" + options_.source + "\" (" +
                         JoinedNames(RegisteredRenderSources()) + ")");
    }
    format = it->second.format;
    intrinsics_id = it->second.intrinsics_id;
  }
  if (options_.fps > 0.0) format.fps = options_.fps;
  if (!options_.intrinsics_id.empty()) intrinsics_id = options_.intrinsics_id;
  {
    std::lock_guard<std::mutex> lock(format_mutex_);
    format_ = format;
  }
  intrinsics_id_ = intrinsics_id;
  lifecycle_ = common::DeviceLifecycle::kConfigured;
  spdlog::debug("{}: open, {}x{} {} at {} fps, intrinsics \"{}\"", name_, format.width,
                format.height, ToString(format.pixel_format), format.fps, intrinsics_id_);
}

std::error_code SimCamera::Start() {
  const common::DeviceLifecycle state = lifecycle_.load();
  if (state == common::DeviceLifecycle::kActive) return {};
  if (state != common::DeviceLifecycle::kConfigured) return Errc::kNotActive;
  start_ = clock_.Now();
  next_frame_ = 0;
  lifecycle_ = common::DeviceLifecycle::kActive;
  return {};
}

void SimCamera::Stop() {
  if (lifecycle_.load() == common::DeviceLifecycle::kActive)
    lifecycle_ = common::DeviceLifecycle::kConfigured;
}

common::Duration SimCamera::FrameTime(uint64_t k) const {
  const double fps = format_.fps;  // only the camera's own thread writes format_ (in Open)
  return start_ + common::Duration(std::llround(static_cast<double>(k) * 1e9 / fps));
}

std::error_code SimCamera::Grab(Image* out, std::chrono::milliseconds timeout) {
  const common::DeviceLifecycle state = lifecycle_.load();
  if (state == common::DeviceLifecycle::kFault) return Errc::kClosed;
  if (state != common::DeviceLifecycle::kActive) return Errc::kNotActive;

  common::Duration now = clock_.Now();
  // Late by a period or more: skip to the newest frame already captured.
  if (FrameTime(next_frame_ + 1) <= now) {
    uint64_t newest = static_cast<uint64_t>(
        std::floor(std::chrono::duration<double>(now - start_).count() * format_.fps));
    while (FrameTime(newest + 1) <= now) ++newest;
    while (newest > next_frame_ && FrameTime(newest) > now) --newest;
    counters_.dropped += newest - next_frame_;
    next_frame_ = newest;
  }
  const common::Duration due = FrameTime(next_frame_);
  if (due > now) {
    const common::Duration deadline = now + std::chrono::duration_cast<common::Duration>(timeout);
    if (due > deadline) {
      clock_.SleepUntil(deadline);
      ++counters_.timeouts;
      return Errc::kTimeout;
    }
    clock_.SleepUntil(due);
  }

  out->Resize(format_.width, format_.height, format_.pixel_format);
  out->timestamp = due;
  out->frame_id = next_frame_;
  out->intrinsics_id = intrinsics_id_;
  std::error_code ec;
  {
    std::shared_lock<std::shared_mutex> lock(Registry::Instance().mutex);
    const auto& sources = Registry::Instance().sources;
    auto it = sources.find(options_.source);
    if (it == sources.end()) {
      lock.unlock();
      lifecycle_ = common::DeviceLifecycle::kFault;
      spdlog::error("{}: render source \"{}\" was unregistered; camera in fault", name_,
                    options_.source);
      return Errc::kClosed;
    }
    ec = it->second.render(next_frame_, due, out);
  }
  ++next_frame_;
  if (!ec && (out->width != format_.width || out->height != format_.height ||
              out->format != format_.pixel_format ||
              out->stride < static_cast<size_t>(out->width) * BytesPerPixel(out->format) ||
              out->data.size() < out->stride * static_cast<size_t>(out->height))) {
    ec = Errc::kProtocol;
    spdlog::warn("{}: frame {}: the render callback resized the image to {}x{} {}", name_,
                 out->frame_id, out->width, out->height, ToString(out->format));
  }
  if (ec) {
    ++counters_.decode_errors;
    spdlog::warn("{}: frame {} not rendered: {}", name_, out->frame_id, ec.message());
    return ec;
  }
  out->timestamp = due;  // the callback may not move the capture time
  out->frame_id = next_frame_ - 1;
  ++counters_.frames;
  return {};
}

}  // namespace kinevis::hal
