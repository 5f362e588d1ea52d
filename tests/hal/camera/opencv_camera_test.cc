#include "hal/camera/opencv_camera.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <opencv2/core.hpp>
#include <opencv2/videoio.hpp>
#include <string>
#include <thread>
#include <vector>

#include "hal/camera/camera_factory.h"
#include "hal/common/error.h"

namespace kinevis::hal {
namespace {

using namespace std::chrono_literals;
using ::testing::HasSubstr;
using ::testing::MatchesRegex;

constexpr int kVideoFrames = 20;
constexpr double kVideoFps = 10.0;
constexpr int kWidth = 64;
constexpr int kHeight = 48;
// Frame k of the video is grey k * kGreyStep with a white square moving to the right; the grey
// level survives JPEG compression to well within half a step.
constexpr int kGreyStep = 12;

std::string TestDir() {
  static const std::string dir = [] {
    std::string d =
        ::testing::TempDir() + "kinevis_opencv_camera_test_" + std::to_string(::getpid());
    std::filesystem::create_directories(d);
    return d;
  }();
  return dir;
}

std::string MakeDir(const std::string& name) {
  const std::string d = TestDir() + "/" + name;
  std::filesystem::create_directories(d);
  return d;
}

// Removes the files the tests wrote.
class RemoveTestDir : public ::testing::Environment {
 public:
  void TearDown() override {
    std::error_code ignored;
    std::filesystem::remove_all(TestDir(), ignored);
  }
};
const ::testing::Environment* const kRemoveTestDir =
    ::testing::AddGlobalTestEnvironment(new RemoveTestDir);

// An MJPG AVI of kVideoFrames frames at kVideoFps, written once per test program.
const std::string& VideoPath() {
  static const std::string path = [] {
    const std::string p = TestDir() + "/moving_square.avi";
    cv::VideoWriter writer(p, cv::VideoWriter::fourcc('M', 'J', 'P', 'G'), kVideoFps,
                           cv::Size(kWidth, kHeight), true);
    EXPECT_TRUE(writer.isOpened()) << "cannot write " << p;
    for (int k = 0; k < kVideoFrames; ++k) {
      cv::Mat frame(kHeight, kWidth, CV_8UC3, cv::Scalar::all(k * kGreyStep));
      frame(cv::Rect(2 * k, 32, 8, 8)).setTo(cv::Scalar::all(255));
      writer.write(frame);
    }
    writer.release();
    return p;
  }();
  return path;
}

// The frame number a video frame encodes: the mean grey of its top rows, over the step.
int EncodedFrameNumber(const Image& image) {
  const int channels = BytesPerPixel(image.format);
  double sum = 0;
  int n = 0;
  for (int y = 0; y < 16; ++y) {
    for (int x = 0; x < image.width * channels; ++x) {
      sum += image.row(y)[x];
      ++n;
    }
  }
  return static_cast<int>(std::lround(sum / n / kGreyStep));
}

Image MonoImage(int width, int height, uint8_t value) {
  Image image;
  image.Resize(width, height, PixelFormat::kMono8);
  std::fill(image.data.begin(), image.data.end(), value);
  return image;
}

void WriteFile(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary);
  out << bytes;
}

std::unique_ptr<Camera> Started(const std::string& source) {
  auto camera = OpenCamera(source);
  EXPECT_FALSE(camera->Start());
  return camera;
}

TEST(OpenCvCameraFileTest, ReadsEveryFrameInOrderWithContainerTimestamps) {
  auto camera = OpenCamera("file:" + VideoPath());
  EXPECT_EQ(camera->lifecycle(), common::DeviceLifecycle::kConfigured);
  const CameraFormat f = camera->format();
  EXPECT_EQ(f.width, kWidth);
  EXPECT_EQ(f.height, kHeight);
  EXPECT_EQ(f.pixel_format, PixelFormat::kBgr8);
  EXPECT_NEAR(f.fps, kVideoFps, 1e-6);
  ASSERT_FALSE(camera->Start());

  Image image;
  std::vector<common::Duration> stamps;
  std::error_code ec;
  while (!(ec = camera->Grab(&image, 100ms))) {
    ASSERT_EQ(image.frame_id, stamps.size());
    ASSERT_EQ(EncodedFrameNumber(image), static_cast<int>(image.frame_id));
    ASSERT_EQ(image.width, kWidth);
    ASSERT_EQ(image.format, PixelFormat::kBgr8);
    ASSERT_EQ(image.stride, static_cast<size_t>(kWidth * 3));
    stamps.push_back(image.timestamp);
  }
  EXPECT_EQ(ec, Errc::kClosed);
  ASSERT_EQ(stamps.size(), static_cast<size_t>(kVideoFrames));
  for (size_t k = 0; k < stamps.size(); ++k) {
    // The container's presentation times: k / fps, to the millisecond OpenCV reports.
    EXPECT_NEAR(std::chrono::duration<double>(stamps[k]).count(), k / kVideoFps, 1e-3) << k;
    if (k > 0) {
      EXPECT_GT(stamps[k], stamps[k - 1]);
    }
  }
  EXPECT_EQ(camera->Grab(&image, 100ms), Errc::kClosed);  // and stays closed
  EXPECT_EQ(camera->lifecycle(), common::DeviceLifecycle::kActive);
  EXPECT_EQ(camera->counters().frames, static_cast<uint64_t>(kVideoFrames));
  EXPECT_EQ(camera->counters().decode_errors, 0u);
}

TEST(OpenCvCameraFileTest, FpsOptionSetsTheTimestampsFromTheFrameIndex) {
  auto camera = Started("file:" + VideoPath() + ",fps=25");
  EXPECT_DOUBLE_EQ(camera->format().fps, 25.0);
  Image image;
  for (int k = 0; k < 5; ++k) {
    ASSERT_FALSE(camera->Grab(&image, 100ms));
    EXPECT_EQ(image.timestamp, common::Duration(40ms) * k);
  }
}

TEST(OpenCvCameraFileTest, LoopKeepsIdsAndTimestampsIncreasing) {
  auto camera = Started("file:" + VideoPath() + ",loop,fps=10");
  Image image;
  for (int k = 0; k < 2 * kVideoFrames + 5; ++k) {
    ASSERT_FALSE(camera->Grab(&image, 100ms)) << k;
    ASSERT_EQ(image.frame_id, static_cast<uint64_t>(k));
    ASSERT_EQ(EncodedFrameNumber(image), k % kVideoFrames);
    ASSERT_EQ(image.timestamp, common::Duration(100ms) * k);
  }
}

TEST(OpenCvCameraFileTest, ConvertsToTheAskedFormatAndReusesTheBuffer) {
  auto camera = Started("file:" + VideoPath() + ",format=mono8,intrinsics=bench-cam");
  EXPECT_EQ(camera->format().pixel_format, PixelFormat::kMono8);
  EXPECT_EQ(camera->intrinsics_id(), "bench-cam");
  Image image;
  ASSERT_FALSE(camera->Grab(&image, 100ms));
  const uint8_t* buffer = image.data.data();
  for (int k = 1; k < 10; ++k) {
    ASSERT_FALSE(camera->Grab(&image, 100ms));
    ASSERT_EQ(image.data.data(), buffer);
  }
  EXPECT_EQ(image.format, PixelFormat::kMono8);
  EXPECT_EQ(image.stride, static_cast<size_t>(kWidth));
  EXPECT_EQ(image.data.size(), static_cast<size_t>(kWidth * kHeight));
  EXPECT_EQ(EncodedFrameNumber(image), 9);
  EXPECT_EQ(image.intrinsics_id, "bench-cam");
  // The square of frame 9 starts at x = 18, y = 32.
  EXPECT_GT(image.row(36)[20], 240);
}

TEST(OpenCvCameraFileTest, AbsentFileThrowsHalErrorWithThePath) {
  const std::string path = TestDir() + "/no_such_clip.avi";
  try {
    OpenCamera("file:" + path);
    FAIL() << "no HalError";
  } catch (const HalError& e) {
    EXPECT_THAT(e.what(), MatchesRegex(".*open failed: no such file \".*/no_such_clip\\.avi\": "
                                       "No such file or directory.*"));
  }
}

TEST(OpenCvCameraFileTest, FileThatIsNotAVideoThrowsHalError) {
  const std::string path = TestDir() + "/not_a_video.avi";
  WriteFile(path, "this is text, not a RIFF container");
  try {
    OpenCamera("file:" + path);
    FAIL() << "no HalError";
  } catch (const HalError& e) {
    EXPECT_THAT(e.what(), HasSubstr("not_a_video.avi"));
  }
}

TEST(OpenCvCameraFileTest, NotActiveBeforeStartAndAfterStop) {
  auto camera = OpenCamera("file:" + VideoPath());
  Image image;
  EXPECT_EQ(camera->Grab(&image, 100ms), Errc::kNotActive);
  ASSERT_FALSE(camera->Start());
  ASSERT_FALSE(camera->Grab(&image, 100ms));
  camera->Stop();
  EXPECT_EQ(camera->Grab(&image, 100ms), Errc::kNotActive);
  // Start again resumes where the stream was.
  ASSERT_FALSE(camera->Start());
  ASSERT_FALSE(camera->Grab(&image, 100ms));
  EXPECT_EQ(image.frame_id, 1u);
}

TEST(OpenCvCameraLatestTest, ReplaysARecordingAsALiveCameraDroppingWhatASlowReaderMisses) {
  // 20 frames 5 ms apart, read by a loop that takes 30 ms per frame.
  auto camera = Started("file:" + VideoPath() + ",fps=200,latest");
  Image image;
  std::vector<uint64_t> ids;
  std::error_code ec;
  while (!(ec = camera->Grab(&image, 5s))) {
    EXPECT_EQ(EncodedFrameNumber(image), static_cast<int>(image.frame_id));
    EXPECT_EQ(image.timestamp, common::Duration(5ms) * image.frame_id);
    if (!ids.empty()) {
      EXPECT_GT(image.frame_id, ids.back());
    }
    ids.push_back(image.frame_id);
    std::this_thread::sleep_for(30ms);
  }
  EXPECT_EQ(ec, Errc::kClosed);
  EXPECT_EQ(camera->lifecycle(), common::DeviceLifecycle::kActive);
  const CameraCounters c = camera->counters();
  EXPECT_EQ(c.frames, ids.size());
  // Every frame of the recording was either delivered or replaced unseen; the last one is always
  // delivered before the end is reported.
  EXPECT_EQ(c.frames + c.dropped, static_cast<uint64_t>(kVideoFrames));
  EXPECT_GT(c.dropped, 0u);
  EXPECT_EQ(ids.back(), static_cast<uint64_t>(kVideoFrames - 1));
}

TEST(OpenCvCameraLatestTest, WaitsAtMostTheTimeoutAndStopsPromptly) {
  // One frame every 5 s: after the first, nothing comes within a short timeout.
  auto camera = Started("file:" + VideoPath() + ",fps=0.2,latest");
  Image image;
  ASSERT_FALSE(camera->Grab(&image, 5s));
  EXPECT_EQ(image.frame_id, 0u);
  EXPECT_EQ(camera->Grab(&image, 50ms), Errc::kTimeout);
  EXPECT_EQ(camera->counters().timeouts, 1u);
  const auto before_stop = std::chrono::steady_clock::now();
  camera->Stop();  // the grabber is pacing towards frame 1, 5 s away
  EXPECT_LT(std::chrono::steady_clock::now() - before_stop, 2s);
  EXPECT_EQ(camera->lifecycle(), common::DeviceLifecycle::kConfigured);
  EXPECT_EQ(camera->Grab(&image, 50ms), Errc::kNotActive);
}

// A sequence of 6 grey PNGs of 8x4 pixels, value 40 * index; the one at index 3 is corrupt.
std::string ImageSequence() {
  static const std::string dir = [] {
    const std::string d = MakeDir("sequence");
    for (int k = 0; k < 6; ++k) {
      char name[32];
      std::snprintf(name, sizeof(name), "/frame_%03d.png", k);
      if (k == 3) {
        WriteFile(d + name, "\x89PNG\r\n\x1a\n but the rest is garbage");
      } else {
        SaveImage(MonoImage(8, 4, static_cast<uint8_t>(40 * k)), d + name);
      }
    }
    return d;
  }();
  return dir;
}

TEST(OpenCvCameraImagesTest, SortedGlobWithACorruptFileCountedAndSkipped) {
  auto camera = Started("images:" + ImageSequence() + "/frame_*.png,fps=5");
  const CameraFormat f = camera->format();
  EXPECT_EQ(f.width, 8);
  EXPECT_EQ(f.height, 4);
  EXPECT_EQ(f.pixel_format, PixelFormat::kMono8);  // the images' own
  Image image;
  std::vector<uint64_t> ids;
  std::error_code ec;
  while (!(ec = camera->Grab(&image, 100ms))) {
    ids.push_back(image.frame_id);
    EXPECT_EQ(image.data[0], 40 * image.frame_id);
    EXPECT_EQ(image.timestamp, common::Duration(200ms) * image.frame_id);
  }
  EXPECT_EQ(ec, Errc::kClosed);
  EXPECT_EQ(ids, (std::vector<uint64_t>{0, 1, 2, 4, 5}));
  EXPECT_EQ(camera->counters().decode_errors, 1u);
  EXPECT_EQ(camera->counters().frames, 5u);
}

TEST(OpenCvCameraImagesTest, LoopContinuesIdsAcrossPasses) {
  auto camera = Started("images:" + ImageSequence() + "/*.png,loop");
  EXPECT_DOUBLE_EQ(camera->format().fps, 30.0);
  Image image;
  std::vector<uint64_t> ids;
  for (int k = 0; k < 10; ++k) {
    ASSERT_FALSE(camera->Grab(&image, 100ms));
    ids.push_back(image.frame_id);
    EXPECT_EQ(image.data[0], 40 * (image.frame_id % 6));
  }
  EXPECT_EQ(ids, (std::vector<uint64_t>{0, 1, 2, 4, 5, 6, 7, 8, 10, 11}));
  EXPECT_EQ(camera->counters().decode_errors, 2u);
  EXPECT_NEAR(std::chrono::duration<double>(image.timestamp).count(), 11 / 30.0, 1e-9);
}

TEST(OpenCvCameraImagesTest, ColourAndDepthConversions) {
  const std::string dir = MakeDir("colour");
  Image bgr;
  bgr.Resize(3, 2, PixelFormat::kBgr8);
  for (int y = 0; y < 2; ++y) {
    for (int x = 0; x < 3; ++x) {
      bgr.row(y)[3 * x + 0] = 10;  // blue
      bgr.row(y)[3 * x + 1] = 20;  // green
      bgr.row(y)[3 * x + 2] = 30;  // red
    }
  }
  SaveImage(bgr, dir + "/a.png");

  Image image;
  auto rgb = Started("images:" + dir + "/a.png,format=rgb8");
  ASSERT_FALSE(rgb->Grab(&image, 100ms));
  EXPECT_EQ(image.format, PixelFormat::kRgb8);
  EXPECT_EQ(std::vector<uint8_t>(image.data.begin(), image.data.begin() + 3),
            (std::vector<uint8_t>{30, 20, 10}));

  auto native = Started("images:" + dir + "/a.png");
  ASSERT_FALSE(native->Grab(&image, 100ms));
  EXPECT_EQ(image.format, PixelFormat::kBgr8);
  EXPECT_EQ(image.data, bgr.data);

  const std::string grey_dir = MakeDir("grey");
  SaveImage(MonoImage(5, 5, 200), grey_dir + "/g.png");
  auto wide = Started("images:" + grey_dir + "/g.png,format=mono16");
  ASSERT_FALSE(wide->Grab(&image, 100ms));
  EXPECT_EQ(image.format, PixelFormat::kMono16);
  EXPECT_EQ(image.stride, 10u);
  uint16_t sample = 0;
  std::memcpy(&sample, image.data.data(), 2);
  EXPECT_EQ(sample, 200 * 257);

  // A 16-bit PNG written by SaveImage comes back as mono16, bit for bit.
  Image deep;
  deep.Resize(4, 1, PixelFormat::kMono16);
  const uint16_t values[4] = {0, 1, 4095, 65535};
  std::memcpy(deep.data.data(), values, sizeof(values));
  const std::string deep_dir = MakeDir("deep");
  SaveImage(deep, deep_dir + "/d.png");
  auto sixteen = Started("images:" + deep_dir + "/d.png");
  EXPECT_EQ(sixteen->format().pixel_format, PixelFormat::kMono16);
  ASSERT_FALSE(sixteen->Grab(&image, 100ms));
  EXPECT_EQ(image.data, deep.data);
}

TEST(OpenCvCameraImagesTest, ImagesOfAnotherSizeAreDecodeErrors) {
  const std::string dir = MakeDir("sizes");
  SaveImage(MonoImage(4, 4, 1), dir + "/0.png");
  SaveImage(MonoImage(6, 4, 2), dir + "/1.png");
  SaveImage(MonoImage(4, 4, 3), dir + "/2.png");
  auto camera = Started("images:" + dir + "/*.png");
  Image image;
  ASSERT_FALSE(camera->Grab(&image, 100ms));
  ASSERT_FALSE(camera->Grab(&image, 100ms));
  EXPECT_EQ(image.frame_id, 2u);
  EXPECT_EQ(image.data[0], 3);
  EXPECT_EQ(camera->counters().decode_errors, 1u);
}

TEST(OpenCvCameraImagesTest, EmptyGlobAndUndecodableSequenceThrowHalError) {
  const std::string pattern = TestDir() + "/nothing_here_*.png";
  try {
    OpenCamera("images:" + pattern);
    FAIL() << "no HalError";
  } catch (const HalError& e) {
    EXPECT_THAT(e.what(), MatchesRegex(".*open failed: no file matches \".*/nothing_here_\\*\\.png"
                                       "\".*"));
  }
  const std::string dir = MakeDir("all_corrupt");
  WriteFile(dir + "/x.png", "garbage");
  WriteFile(dir + "/y.png", "more garbage");
  try {
    OpenCamera("images:" + dir + "/*.png");
    FAIL() << "no HalError";
  } catch (const HalError& e) {
    EXPECT_THAT(e.what(), MatchesRegex(".*none of the 2 files matching .* decodes as an image "
                                       "\\(first: \".*/x\\.png\"\\).*"));
  }
}

TEST(OpenCvCameraV4l2Test, MissingDeviceThrowsHalErrorQuickly) {
  const auto start = std::chrono::steady_clock::now();
  try {
    OpenCamera("v4l2:/dev/video99");
    FAIL() << "no HalError";
  } catch (const HalError& e) {
    EXPECT_THAT(e.what(), MatchesRegex("v4l2:/dev/video99: open failed: no such device "
                                       "\"/dev/video99\": No such file or directory.*"));
  }
  EXPECT_LT(std::chrono::steady_clock::now() - start, 5s);
}

TEST(OpenCvCameraV4l2Test, NodeThatIsNotADeviceIsRefused) {
  const std::string path = TestDir() + "/fake_video0";
  WriteFile(path, "");
  EXPECT_THROW(OpenCamera("v4l2:" + path), HalError);
}

TEST(OpenCvCameraTest, InconsistentOptionsThrowConfigErrorNamingEach) {
  OpenCvCameraOptions options;
  options.kind = OpenCvCameraOptions::Kind::kFile;
  options.path = VideoPath();
  options.width = 640;
  options.fps = -2;
  OpenCvCamera camera("file:x", options);
  try {
    camera.Open();
    FAIL() << "no ConfigError";
  } catch (const common::ConfigError& e) {
    EXPECT_THAT(e.what(), HasSubstr("fps -2"));
    EXPECT_THAT(e.what(), HasSubstr("width and height go together"));
    EXPECT_THAT(e.what(), HasSubstr("width and height apply to v4l2 only"));
  }
  EXPECT_EQ(camera.lifecycle(), common::DeviceLifecycle::kUnconfigured);
}

TEST(SaveImageTest, RefusesEmptyImagesAndUnwritablePaths) {
  EXPECT_THROW(SaveImage(Image(), TestDir() + "/empty.png"), common::ConfigError);
  try {
    SaveImage(MonoImage(2, 2, 0), TestDir() + "/no/such/dir/x.png");
    FAIL() << "no HalError";
  } catch (const HalError& e) {
    EXPECT_THAT(e.what(), HasSubstr("no/such/dir/x.png: write image failed"));
  }
}

}  // namespace
}  // namespace kinevis::hal
