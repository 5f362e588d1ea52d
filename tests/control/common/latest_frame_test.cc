// The asynchronous (latest-frame) mode of the camera feature sources
// (control/common/latest_frame.h): newest frame only, older ones counted dropped, a stop that
// ends a producer waiting on something else.

#include "control/common/latest_frame.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <thread>

namespace kinevis::control {
namespace {

using namespace std::chrono_literals;

struct Numbered {
  uint64_t n = 0;
};

// Waits (up to 5 s) until pred() holds; false when it never did.
template <typename Pred>
bool WaitFor(Pred pred) {
  const auto end = std::chrono::steady_clock::now() + 5s;
  while (!pred()) {
    if (std::chrono::steady_clock::now() > end) return false;
    std::this_thread::sleep_for(1ms);
  }
  return true;
}

TEST(LatestFrameWorkerTest, TakeHandsOverTheNewestFrameOnceAndCountsTheOlderDropped) {
  std::atomic<uint64_t> produced{0};
  LatestFrameWorker<Numbered> worker([&](Numbered* f, const std::atomic<bool>&) {
    std::this_thread::sleep_for(1ms);  // a camera at ~1 kHz
    f->n = ++produced;
    return true;
  });
  ASSERT_TRUE(WaitFor([&] { return worker.published() >= 20; }));
  Numbered frame;
  ASSERT_TRUE(worker.Take(&frame));
  // The newest at the moment of the Take: nothing older than what had been published before it.
  EXPECT_GE(frame.n, 20u);
  worker.Stop();
  const uint64_t published = worker.published();
  EXPECT_EQ(published, produced.load());
  // After the stop nothing new: the one frame published after the Take (if any) is handed over
  // once, then nothing.
  Numbered last;
  if (worker.Take(&last)) {
    EXPECT_EQ(last.n, published);
  }
  EXPECT_FALSE(worker.Take(&last));
  // Every frame was either taken (at most two) or replaced before anybody took it.
  EXPECT_GE(worker.dropped() + 2, published);
  EXPECT_LE(worker.dropped(), published - 1);
}

TEST(LatestFrameWorkerTest, AProducerThatReturnsNothingPublishesNothing) {
  std::atomic<int> calls{0};
  LatestFrameWorker<Numbered> worker([&](Numbered*, const std::atomic<bool>&) {
    ++calls;
    std::this_thread::sleep_for(1ms);
    return false;
  });
  ASSERT_TRUE(WaitFor([&] { return calls >= 5; }));
  Numbered frame;
  EXPECT_FALSE(worker.Take(&frame));
  EXPECT_EQ(worker.published(), 0u);
}

TEST(LatestFrameWorkerTest, StopEndsAProducerWaitingOnSomethingElse) {
  std::mutex mutex;
  std::condition_variable never;
  std::atomic<bool> waiting{false};
  auto worker = std::make_unique<LatestFrameWorker<Numbered>>(
      [&](Numbered*, const std::atomic<bool>& stopping) {
        std::unique_lock<std::mutex> lock(mutex);
        waiting = true;
        never.wait_for(lock, 5ms, [&] { return stopping.load(); });
        return false;
      });
  ASSERT_TRUE(WaitFor([&] { return waiting.load(); }));
  worker->Stop();  // returns: the producer saw `stopping` (a hang here is the failure)
  EXPECT_TRUE(worker->stopping());
  EXPECT_EQ(worker->published(), 0u);
  worker.reset();
}

TEST(LatestFrameWorkerTest, AnEmptyProducerIsRefused) {
  EXPECT_THROW(LatestFrameWorker<Numbered>(LatestFrameWorker<Numbered>::Producer()),
               std::invalid_argument);
}

}  // namespace
}  // namespace kinevis::control
