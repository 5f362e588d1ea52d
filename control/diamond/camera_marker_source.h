#pragma once

// The DIAMOND marker from a hal::Camera (issue 8; one source for every rig, issue 17): each
// frame through the MarkerDetector (DetectedMarkerSource, diamond_laws.h), in one of the two
// modes of a camera feature source (control/common/latest_frame.h):
//  - synchronous (simulated worlds in stepped time): Poll() grabs without waiting, in the loop's
//    thread; a frame is rendered and detected when one is due.
//  - asynchronous (real cameras, worlds on a real clock): a LatestFrameWorker grabs (waiting up to
//    grab_timeout_ms) and detects; Poll() takes the newest detection.
// A camera error (other than "no frame yet") is kept (error(), naming the camera). In the
// asynchronous mode the worker then idles: a failed camera stays failed, the law sees the frames
// go stale and stops the robot. Frames must be mono8 (else an error: the detector works on grey).
// The frame's timestamp is the capture time the camera reports.

#include <atomic>
#include <memory>
#include <mutex>
#include <string>

#include "control/common/latest_frame.h"
#include "control/diamond/diamond_laws.h"
#include "hal/camera/camera.h"

namespace kinevis::control {

struct CameraMarkerSourceOptions {
  vision::MarkerDetectorOptions detector;
  bool asynchronous = false;
  int grab_timeout_ms = 100;     // asynchronous: the longest wait for one frame, > 0
  std::string Validate() const;  // empty when usable, else every bad field and its value
};

class CameraMarkerSource final : public MarkerFeatureSource {
 public:
  // camera: active, on the loop's clock; must outlive the source. Throws std::invalid_argument
  // for a null camera or bad options (naming each).
  explicit CameraMarkerSource(hal::Camera* camera, CameraMarkerSourceOptions options = {});
  ~CameraMarkerSource() override;
  CameraMarkerSource(const CameraMarkerSource&) = delete;
  CameraMarkerSource& operator=(const CameraMarkerSource&) = delete;

  bool Poll(common::Duration now, MarkerFrame* frame) override;
  // The first camera error, "" when none: "camera <name>: <cause>".
  std::string error() const;
  // Frames detected (asynchronous: including those replaced before a Poll() took them).
  uint64_t frames() const;

 private:
  // Grabs one frame into a view; false (and the error kept) when there is none.
  bool Grab(std::chrono::milliseconds timeout, vision::ImageView8* view, common::Duration* stamp);
  void Fail(const std::string& text);

  hal::Camera* camera_;
  CameraMarkerSourceOptions options_;
  hal::Image image_;  // the frame being detected (the worker's in the asynchronous mode)
  mutable std::mutex mutex_;
  std::string error_;
  std::atomic<bool> failed_{false};
  DetectedMarkerSource detector_;
  std::unique_ptr<LatestFrameWorker<MarkerFrame>> worker_;  // last: uses everything above
};

}  // namespace kinevis::control
