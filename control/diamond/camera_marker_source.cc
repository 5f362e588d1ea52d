#include "control/diamond/camera_marker_source.h"

#include <chrono>
#include <stdexcept>
#include <thread>

#include "common/config_error.h"
#include "hal/common/error.h"

namespace kinevis::control {

std::string CameraMarkerSourceOptions::Validate() const {
  common::Problems p;
  if (grab_timeout_ms <= 0) p.Add("grab_timeout_ms", grab_timeout_ms, "must be > 0 ms");
  return p.Message();
}

namespace {

hal::Camera* Checked(hal::Camera* camera, const CameraMarkerSourceOptions& options) {
  std::string message = options.Validate();
  if (camera == nullptr) message += std::string(message.empty() ? "" : "; ") + "camera: null";
  if (!message.empty()) throw std::invalid_argument("CameraMarkerSource: " + message);
  return camera;
}

}  // namespace

CameraMarkerSource::CameraMarkerSource(hal::Camera* camera, CameraMarkerSourceOptions options)
    : camera_(Checked(camera, options)),
      options_(std::move(options)),
      detector_(
          [this](common::Duration, vision::ImageView8* view, common::Duration* stamp) {
            return Grab(
                std::chrono::milliseconds(options_.asynchronous ? options_.grab_timeout_ms : 0),
                view, stamp);
          },
          options_.detector) {
  if (options_.asynchronous) {
    worker_ = std::make_unique<LatestFrameWorker<MarkerFrame>>(
        [this](MarkerFrame* frame, const std::atomic<bool>&) {
          if (failed_) {  // a failed camera stays failed: idle until the source is destroyed
            std::this_thread::sleep_for(std::chrono::milliseconds(20));
            return false;
          }
          // The grab sets the frame's time stamp: the time passed here is never used.
          return detector_.Poll(common::Duration(0), frame);
        });
  }
}

CameraMarkerSource::~CameraMarkerSource() {
  if (worker_) worker_->Stop();
}

bool CameraMarkerSource::Grab(std::chrono::milliseconds timeout, vision::ImageView8* view,
                              common::Duration* stamp) {
  const std::error_code ec = camera_->Grab(&image_, timeout);
  if (ec) {
    if (ec != hal::Errc::kTimeout) Fail("camera " + camera_->name() + ": " + ec.message());
    return false;
  }
  if (image_.format != hal::PixelFormat::kMono8) {
    Fail("camera " + camera_->name() + ": frames are not mono8");
    return false;
  }
  *view = vision::ImageView8{image_.data.data(), image_.width, image_.height, image_.stride};
  *stamp = image_.timestamp;
  return true;
}

void CameraMarkerSource::Fail(const std::string& text) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (error_.empty()) error_ = text;
  }
  // A failed camera stays failed: the law sees the frames go stale and stops.
  failed_ = true;
}

bool CameraMarkerSource::Poll(common::Duration now, MarkerFrame* frame) {
  if (worker_) return worker_->Take(frame);
  return detector_.Poll(now, frame);
}

std::string CameraMarkerSource::error() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return error_;
}

uint64_t CameraMarkerSource::frames() const {
  return worker_ ? worker_->published() : detector_.frames();
}

}  // namespace kinevis::control
