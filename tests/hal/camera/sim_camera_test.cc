#include "hal/camera/sim_camera.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <thread>

#include "hal/common/error.h"

namespace kinevis::hal {
namespace {

using namespace std::chrono_literals;
using ::testing::ElementsAre;
using ::testing::HasSubstr;
using ::testing::MatchesRegex;

// A 4x3 mono8 source whose every pixel holds the low byte of the frame id.
CameraFormat SmallFormat(double fps = 50.0) { return CameraFormat{4, 3, PixelFormat::kMono8, fps}; }

std::error_code PaintFrameId(uint64_t frame_id, common::Duration, Image* image) {
  for (uint8_t& b : image->data) b = static_cast<uint8_t>(frame_id);
  return {};
}

// Registers a source for the duration of a test.
class ScopedSource {
 public:
  ScopedSource(std::string name, const CameraFormat& format, RenderFn render,
               const std::string& intrinsics = "")
      : name_(std::move(name)) {
    RegisterRenderSource(name_, format, std::move(render), intrinsics);
  }
  ~ScopedSource() { UnregisterRenderSource(name_); }

 private:
  std::string name_;
};

TEST(RenderSourceRegistryTest, ListsSortedNamesAndUnregisters) {
  ScopedSource b("test-b", SmallFormat(), PaintFrameId);
  {
    ScopedSource a("test-a", SmallFormat(), PaintFrameId);
    EXPECT_THAT(RegisteredRenderSources(), ElementsAre("test-a", "test-b"));
  }
  EXPECT_THAT(RegisteredRenderSources(), ElementsAre("test-b"));
  EXPECT_FALSE(UnregisterRenderSource("test-a"));
}

TEST(RenderSourceRegistryTest, RejectsDuplicatesAndBadFormatsNamingEveryProblem) {
  ScopedSource a("dup", SmallFormat(), PaintFrameId);
  EXPECT_THROW(RegisterRenderSource("dup", SmallFormat(), PaintFrameId), common::ConfigError);
  try {
    RegisterRenderSource("bad", CameraFormat{0, 3, PixelFormat::kMono8, -1.0}, RenderFn());
    FAIL() << "no ConfigError";
  } catch (const common::ConfigError& e) {
    EXPECT_THAT(e.what(), HasSubstr("\"bad\""));
    EXPECT_THAT(e.what(), HasSubstr("size 0x3"));
    EXPECT_THAT(e.what(), HasSubstr("fps"));
    EXPECT_THAT(e.what(), HasSubstr("render callback is empty"));
  }
  EXPECT_THAT(RegisteredRenderSources(), ElementsAre("dup"));
}

TEST(SimCameraTest, UnknownSourceErrorListsTheRegisteredNames) {
  ScopedSource a("hexapod-perspective", SmallFormat(), PaintFrameId);
  ScopedSource b("weld-torch", SmallFormat(), PaintFrameId);
  SimCamera camera("sim:nope", SimCameraOptions{"nope", 0.0, ""});
  try {
    camera.Open();
    FAIL() << "no HalError";
  } catch (const HalError& e) {
    EXPECT_THAT(e.what(), MatchesRegex(".*sim:nope: open failed: no render source \"nope\" "
                                       "\\(registered: hexapod-perspective, weld-torch\\).*"));
  }
  EXPECT_EQ(camera.lifecycle(), common::DeviceLifecycle::kUnconfigured);
}

TEST(SimCameraTest, FollowsTheLifecycle) {
  ScopedSource s("life", SmallFormat(), PaintFrameId, "cam-intrinsics-7");
  common::SimulatedClock clock;
  SimCamera camera("sim:life", SimCameraOptions{"life", 0.0, ""}, clock);
  Image image;
  EXPECT_EQ(camera.Grab(&image, 100ms), Errc::kNotActive);
  EXPECT_EQ(camera.Start(), Errc::kNotActive);
  camera.Open();
  EXPECT_EQ(camera.lifecycle(), common::DeviceLifecycle::kConfigured);
  EXPECT_EQ(camera.format().width, 4);
  EXPECT_EQ(camera.format().height, 3);
  EXPECT_EQ(camera.format().pixel_format, PixelFormat::kMono8);
  EXPECT_DOUBLE_EQ(camera.format().fps, 50.0);
  EXPECT_EQ(camera.intrinsics_id(), "cam-intrinsics-7");
  EXPECT_EQ(camera.Grab(&image, 100ms), Errc::kNotActive);
  ASSERT_FALSE(camera.Start());
  EXPECT_EQ(camera.lifecycle(), common::DeviceLifecycle::kActive);
  EXPECT_FALSE(camera.Grab(&image, 100ms));
  camera.Stop();
  EXPECT_EQ(camera.lifecycle(), common::DeviceLifecycle::kConfigured);
  EXPECT_EQ(camera.Grab(&image, 100ms), Errc::kNotActive);
}

TEST(SimCameraTest, PacesFramesOnASimulatedClockFasterThanRealTime) {
  ScopedSource s("pace", SmallFormat(50.0), PaintFrameId, "intr");
  common::SimulatedClock clock(common::SimulatedClock::Mode::kFreeRunning, common::Duration(1s));
  SimCamera camera("sim:pace", SimCameraOptions{"pace", 0.0, ""}, clock);
  camera.Open();
  ASSERT_FALSE(camera.Start());
  Image image;
  const auto wall_start = std::chrono::steady_clock::now();
  // 500 frames at 50 fps: 10 s of simulated time.
  for (uint64_t k = 0; k < 500; ++k) {
    ASSERT_FALSE(camera.Grab(&image, 1s)) << "frame " << k;
    ASSERT_EQ(image.frame_id, k);
    ASSERT_EQ(image.timestamp, common::Duration(1s) + common::Duration(20ms) * k);
    ASSERT_EQ(clock.Now(), image.timestamp);
    ASSERT_EQ(image.data[0], static_cast<uint8_t>(k));
  }
  EXPECT_EQ(image.width, 4);
  EXPECT_EQ(image.height, 3);
  EXPECT_EQ(image.stride, 4u);
  EXPECT_EQ(image.data.size(), 12u);
  EXPECT_EQ(image.intrinsics_id, "intr");
  EXPECT_LT(std::chrono::steady_clock::now() - wall_start, 5s);  // not paced in wall time
  EXPECT_EQ(camera.counters().frames, 500u);
  EXPECT_EQ(camera.counters().dropped, 0u);
  EXPECT_EQ(camera.counters().timeouts, 0u);
}

TEST(SimCameraTest, FpsOptionOverridesTheRegisteredRateAndIntrinsics) {
  ScopedSource s("rate", SmallFormat(50.0), PaintFrameId, "registered");
  common::SimulatedClock clock;
  SimCamera camera("sim:rate,fps=3", SimCameraOptions{"rate", 3.0, "override"}, clock);
  camera.Open();
  EXPECT_DOUBLE_EQ(camera.format().fps, 3.0);
  EXPECT_EQ(camera.intrinsics_id(), "override");
  ASSERT_FALSE(camera.Start());
  Image image;
  for (int k = 0; k < 4; ++k) ASSERT_FALSE(camera.Grab(&image, 1s));
  // Frame 3 at 3/3 s exactly: rounding of 1/3 s does not accumulate.
  EXPECT_EQ(image.timestamp, common::Duration(1s));
  EXPECT_EQ(image.intrinsics_id, "override");
}

TEST(SimCameraTest, TimeoutShorterThanThePeriodAdvancesTheClockAndIsCounted) {
  ScopedSource s("slow", SmallFormat(50.0), PaintFrameId);
  common::SimulatedClock clock;
  SimCamera camera("sim:slow", SimCameraOptions{"slow", 0.0, ""}, clock);
  camera.Open();
  ASSERT_FALSE(camera.Start());
  Image image;
  ASSERT_FALSE(camera.Grab(&image, 0ms));  // frame 0 is due at once
  EXPECT_EQ(camera.Grab(&image, 5ms), Errc::kTimeout);
  EXPECT_EQ(clock.Now(), common::Duration(5ms));
  EXPECT_EQ(camera.counters().timeouts, 1u);
  ASSERT_FALSE(camera.Grab(&image, 100ms));
  EXPECT_EQ(image.frame_id, 1u);
  EXPECT_EQ(image.timestamp, common::Duration(20ms));
}

TEST(SimCameraTest, ALateCallerGetsTheNewestFrameAndTheMissedOnesAreDropped) {
  ScopedSource s("late", SmallFormat(50.0), PaintFrameId);
  common::SimulatedClock clock;
  SimCamera camera("sim:late", SimCameraOptions{"late", 0.0, ""}, clock);
  camera.Open();
  ASSERT_FALSE(camera.Start());
  Image image;
  ASSERT_FALSE(camera.Grab(&image, 1s));
  ASSERT_FALSE(camera.Grab(&image, 1s));
  ASSERT_EQ(image.frame_id, 1u);
  clock.Advance(105ms);  // now 125 ms: frames 2..6 were captured meanwhile
  ASSERT_FALSE(camera.Grab(&image, 1s));
  EXPECT_EQ(image.frame_id, 6u);
  EXPECT_EQ(image.timestamp, common::Duration(120ms));
  EXPECT_EQ(camera.counters().dropped, 4u);
  ASSERT_FALSE(camera.Grab(&image, 1s));
  EXPECT_EQ(image.frame_id, 7u);
  EXPECT_EQ(image.timestamp, common::Duration(140ms));
}

TEST(SimCameraTest, RenderIsGivenTheFrameIdAndClockTimeAndTheBufferIsReused) {
  std::vector<std::pair<uint64_t, common::Duration>> calls;
  ScopedSource s("args", CameraFormat{8, 2, PixelFormat::kBgr8, 10.0},
                 [&](uint64_t id, common::Duration t, Image* image) {
                   calls.emplace_back(id, t);
                   EXPECT_EQ(image->format, PixelFormat::kBgr8);
                   EXPECT_EQ(image->stride, 24u);
                   EXPECT_EQ(image->data.size(), 48u);
                   image->row(1)[23] = 0xAB;
                   return std::error_code();
                 });
  common::SimulatedClock clock(common::SimulatedClock::Mode::kFreeRunning, common::Duration(7ms));
  SimCamera camera("sim:args", SimCameraOptions{"args", 0.0, ""}, clock);
  camera.Open();
  ASSERT_FALSE(camera.Start());
  Image image;
  ASSERT_FALSE(camera.Grab(&image, 1s));
  const uint8_t* buffer = image.data.data();
  ASSERT_FALSE(camera.Grab(&image, 1s));
  EXPECT_EQ(image.data.data(), buffer);
  EXPECT_EQ(image.data[47], 0xAB);
  ASSERT_EQ(calls.size(), 2u);
  EXPECT_EQ(calls[0], std::make_pair(uint64_t{0}, common::Duration(7ms)));
  EXPECT_EQ(calls[1], std::make_pair(uint64_t{1}, common::Duration(107ms)));
}

TEST(SimCameraTest, RenderErrorsAndResizingAreCountedAndTheStreamGoesOn) {
  ScopedSource s("flaky", SmallFormat(), [](uint64_t id, common::Duration, Image* image) {
    if (id == 1) return std::error_code(Errc::kIo);
    if (id == 2) image->Resize(2, 2, PixelFormat::kMono8);
    return std::error_code();
  });
  common::SimulatedClock clock;
  SimCamera camera("sim:flaky", SimCameraOptions{"flaky", 0.0, ""}, clock);
  camera.Open();
  ASSERT_FALSE(camera.Start());
  Image image;
  EXPECT_FALSE(camera.Grab(&image, 1s));
  EXPECT_EQ(camera.Grab(&image, 1s), Errc::kIo);
  EXPECT_EQ(camera.Grab(&image, 1s), Errc::kProtocol);
  ASSERT_FALSE(camera.Grab(&image, 1s));
  EXPECT_EQ(image.frame_id, 3u);
  EXPECT_EQ(image.width, 4);
  EXPECT_EQ(camera.counters().decode_errors, 2u);
  EXPECT_EQ(camera.counters().frames, 2u);
}

TEST(SimCameraTest, UnregisteringTheSourceFaultsTheCamera) {
  RegisterRenderSource("gone", SmallFormat(), PaintFrameId);
  common::SimulatedClock clock;
  SimCamera camera("sim:gone", SimCameraOptions{"gone", 0.0, ""}, clock);
  camera.Open();
  ASSERT_FALSE(camera.Start());
  Image image;
  ASSERT_FALSE(camera.Grab(&image, 1s));
  ASSERT_TRUE(UnregisterRenderSource("gone"));
  EXPECT_EQ(camera.Grab(&image, 1s), Errc::kClosed);
  EXPECT_EQ(camera.lifecycle(), common::DeviceLifecycle::kFault);
  EXPECT_EQ(camera.Start(), Errc::kNotActive);
  // Open() from fault looks the source up again.
  EXPECT_THROW(camera.Open(), HalError);
  RegisterRenderSource("gone", SmallFormat(), PaintFrameId);
  camera.Open();
  EXPECT_EQ(camera.lifecycle(), common::DeviceLifecycle::kConfigured);
  ASSERT_FALSE(camera.Start());
  EXPECT_FALSE(camera.Grab(&image, 1s));
  EXPECT_TRUE(UnregisterRenderSource("gone"));
}

TEST(SimCameraTest, UnregisterWaitsForARenderInProgress) {
  std::atomic<bool> rendering{false};
  std::atomic<bool> release{false};
  std::atomic<bool> finished{false};
  RegisterRenderSource("busy", SmallFormat(), [&](uint64_t, common::Duration, Image*) {
    rendering = true;
    while (!release) std::this_thread::yield();
    finished = true;
    return std::error_code();
  });
  common::SimulatedClock clock;
  SimCamera camera("sim:busy", SimCameraOptions{"busy", 0.0, ""}, clock);
  camera.Open();
  ASSERT_FALSE(camera.Start());
  std::thread grabber([&] {
    Image image;
    EXPECT_FALSE(camera.Grab(&image, 1s));
  });
  while (!rendering) std::this_thread::yield();
  std::atomic<bool> unregistered{false};
  std::thread remover([&] {
    EXPECT_TRUE(UnregisterRenderSource("busy"));
    unregistered = true;
    EXPECT_TRUE(finished.load());  // never returns while the callback runs
  });
  // Give the remover time to block on the render; it must still be waiting afterwards.
  std::this_thread::sleep_for(50ms);
  EXPECT_FALSE(unregistered.load());
  release = true;
  remover.join();
  grabber.join();
  EXPECT_TRUE(unregistered.load());
}

TEST(SimCameraTest, DrivenClockBlocksGrabUntilTimeIsAdvanced) {
  ScopedSource s("driven", SmallFormat(50.0), PaintFrameId);
  common::SimulatedClock clock(common::SimulatedClock::Mode::kDriven);
  SimCamera camera("sim:driven", SimCameraOptions{"driven", 0.0, ""}, clock);
  camera.Open();
  ASSERT_FALSE(camera.Start());
  Image image;
  ASSERT_FALSE(camera.Grab(&image, 1s));  // frame 0 is due at once, no wait
  std::atomic<bool> done{false};
  std::thread grabber([&] {
    EXPECT_FALSE(camera.Grab(&image, 1s));
    done = true;
  });
  clock.Advance(10ms);
  EXPECT_FALSE(done.load());
  clock.Advance(10ms);  // 20 ms: frame 1 is due
  grabber.join();
  EXPECT_TRUE(done.load());
  EXPECT_EQ(image.frame_id, 1u);
  EXPECT_EQ(image.timestamp, common::Duration(20ms));
}

}  // namespace
}  // namespace kinevis::hal
