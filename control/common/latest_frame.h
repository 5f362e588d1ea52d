#pragma once

// The asynchronous (latest-frame) mode of a camera feature source, shared by the hexapod's leg
// features (control/hexapod/image_leg_features.h) and the DIAMOND's marker
// (control/diamond/camera_marker_source.h) (issue 17).
//
// A feature source runs in one of two modes:
//  - synchronous: the control loop's thread grabs (never waiting) and extracts the features in
//    its Poll() when a frame is due. Deterministic: for simulated worlds in stepped time, whose
//    clock must only be advanced by the loop's thread.
//  - asynchronous: a worker thread grabs (waiting for the camera) and extracts, over and over;
//    Poll() only takes the newest finished frame. A camera slow to deliver or an extraction slower
//    than the cycle never delays a control cycle, and a loop that polls slower than the camera
//    delivers gets the newest frame, never a queue of old ones (the older are counted dropped).
//    For real cameras and worlds on a real-time clock.
//
// LatestFrameWorker is the asynchronous mode's machinery: the thread, the one-frame mailbox, the
// stop. The worker thread runs at a lower priority than the loop's (nice +10 by default; failing
// to renice is harmless): on a loaded machine the camera waits, not the cycle.

#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <atomic>
#include <cstdint>
#include <functional>
#include <mutex>
#include <stdexcept>
#include <thread>
#include <utility>

namespace kinevis::control {

template <typename Frame>
class LatestFrameWorker {
 public:
  // Grabs and processes one frame, waiting for the camera at most its own timeout; true when
  // *frame holds a new one. Runs on the worker thread only; `stopping` turns true when the
  // worker is asked to stop (a producer that waits for something else must watch it). A producer
  // whose camera fails at once must pause before returning false: the worker calls it again
  // straight away.
  using Producer = std::function<bool(Frame* frame, const std::atomic<bool>& stopping)>;

  // Starts the thread. Throws std::invalid_argument for an empty producer.
  explicit LatestFrameWorker(Producer produce, int nice_increment = 10)
      : produce_(std::move(produce)) {
    if (!produce_) throw std::invalid_argument("LatestFrameWorker: the producer is empty");
    thread_ = std::thread([this, nice_increment] {
      if (nice_increment != 0) {
        (void)::setpriority(PRIO_PROCESS, static_cast<id_t>(::syscall(SYS_gettid)), nice_increment);
      }
      Frame frame{};
      while (!stopping_) {
        if (!produce_(&frame, stopping_)) continue;
        std::lock_guard<std::mutex> lock(mutex_);
        if (published_ > taken_) ++dropped_;  // the previous one was never taken
        latest_ = frame;
        ++published_;
      }
    });
  }
  ~LatestFrameWorker() { Stop(); }
  LatestFrameWorker(const LatestFrameWorker&) = delete;
  LatestFrameWorker& operator=(const LatestFrameWorker&) = delete;

  // The newest frame not taken before: true and *frame filled, or false. Never blocks for longer
  // than the worker's copy of one frame.
  bool Take(Frame* frame) {
    std::lock_guard<std::mutex> lock(mutex_);
    if (published_ == taken_) return false;
    *frame = latest_;
    taken_ = published_;
    return true;
  }

  // Asks the worker to stop after its current frame; safe from the producer itself.
  void RequestStop() { stopping_ = true; }
  // Asks it to stop and waits for it (not from the producer). Idempotent.
  void Stop() {
    stopping_ = true;
    if (thread_.joinable() && thread_.get_id() != std::this_thread::get_id()) thread_.join();
  }
  bool stopping() const { return stopping_; }

  uint64_t published() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return published_;
  }
  // Frames replaced by a newer one before anybody took them.
  uint64_t dropped() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return dropped_;
  }

 private:
  Producer produce_;
  std::atomic<bool> stopping_{false};
  mutable std::mutex mutex_;  // guards what follows
  Frame latest_{};
  uint64_t published_ = 0, taken_ = 0, dropped_ = 0;
  std::thread thread_;  // last: started once everything above exists
};

}  // namespace kinevis::control
