#include "hal/camera/camera_factory.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <string>

#include "hal/camera/sim_camera.h"
#include "hal/common/error.h"

namespace kinevis::hal {
namespace {

using Kind = CameraSourceSpec::Kind;
using ::testing::HasSubstr;
using ::testing::MatchesRegex;

std::string ParseError(const std::string& source) {
  try {
    ParseCameraSource(source);
  } catch (const common::ConfigError& e) {
    return e.what();
  }
  return "(no ConfigError)";
}

TEST(ParseCameraSourceTest, V4l2WithEveryOption) {
  const CameraSourceSpec s = ParseCameraSource(
      "v4l2:/dev/video2,width=1280,height=720,fps=59.94,format=mono8,latest,intrinsics=c270");
  EXPECT_EQ(s.kind, Kind::kV4l2);
  EXPECT_EQ(s.text,
            "v4l2:/dev/video2,width=1280,height=720,fps=59.94,format=mono8,latest,intrinsics=c270");
  EXPECT_EQ(s.target, "/dev/video2");
  EXPECT_EQ(s.width, 1280);
  EXPECT_EQ(s.height, 720);
  EXPECT_DOUBLE_EQ(s.fps, 59.94);
  EXPECT_EQ(s.format, PixelFormat::kMono8);
  EXPECT_TRUE(s.latest);
  EXPECT_FALSE(s.loop);
  EXPECT_EQ(s.intrinsics_id, "c270");
}

TEST(ParseCameraSourceTest, V4l2Defaults) {
  const CameraSourceSpec s = ParseCameraSource("v4l2:/dev/video0");
  EXPECT_EQ(s.kind, Kind::kV4l2);
  EXPECT_EQ(s.target, "/dev/video0");
  EXPECT_EQ(s.width, 0);
  EXPECT_EQ(s.height, 0);
  EXPECT_EQ(s.fps, 0.0);
  EXPECT_FALSE(s.format.has_value());
  EXPECT_FALSE(s.latest);
  EXPECT_TRUE(s.intrinsics_id.empty());
}

TEST(ParseCameraSourceTest, FileImagesAndSim) {
  CameraSourceSpec s = ParseCameraSource("file:runs/weld 3.mp4,loop,fps=25");
  EXPECT_EQ(s.kind, Kind::kFile);
  EXPECT_EQ(s.target, "runs/weld 3.mp4");
  EXPECT_TRUE(s.loop);
  EXPECT_DOUBLE_EQ(s.fps, 25.0);

  s = ParseCameraSource("images:shots/*.png,fps=2.5,loop,format=mono16,latest");
  EXPECT_EQ(s.kind, Kind::kImages);
  EXPECT_EQ(s.target, "shots/*.png");
  EXPECT_DOUBLE_EQ(s.fps, 2.5);
  EXPECT_TRUE(s.loop);
  EXPECT_EQ(s.format, PixelFormat::kMono16);
  EXPECT_TRUE(s.latest);

  s = ParseCameraSource("sim:hexapod-perspective,fps=200");
  EXPECT_EQ(s.kind, Kind::kSim);
  EXPECT_EQ(s.target, "hexapod-perspective");
  EXPECT_DOUBLE_EQ(s.fps, 200.0);

  // A scheme's colon is the first one: the rest belongs to the target.
  s = ParseCameraSource("file:C:/videos/a.avi");
  EXPECT_EQ(s.target, "C:/videos/a.avi");
}

TEST(ParseCameraSourceTest, PixelFormatNamesRoundTrip) {
  for (PixelFormat f :
       {PixelFormat::kMono8, PixelFormat::kBgr8, PixelFormat::kRgb8, PixelFormat::kMono16}) {
    EXPECT_EQ(ParseCameraSource(std::string("file:a.avi,format=") + ToString(f)).format, f);
  }
}

TEST(ParseCameraSourceTest, NoOrUnknownScheme) {
  EXPECT_THAT(ParseError("/dev/video0"),
              MatchesRegex("camera source \"/dev/video0\": no scheme; expected SCHEME:TARGET .*"
                           "v4l2, file, images, sim.*"));
  EXPECT_THAT(ParseError(":x"), HasSubstr("no scheme"));
  EXPECT_THAT(ParseError("rtsp://host/stream"),
              MatchesRegex(".*scheme \"rtsp\" is not a camera source \\(v4l2, file, images, "
                           "sim, net\\).*"));
}

TEST(ParseCameraSourceTest, EmptyTargetsNameWhatIsMissing) {
  EXPECT_THAT(ParseError("v4l2:"), HasSubstr("device path is empty"));
  EXPECT_THAT(ParseError("file:,loop"), HasSubstr("file path is empty"));
  EXPECT_THAT(ParseError("images:"), HasSubstr("glob pattern is empty"));
  EXPECT_THAT(ParseError("sim:"), HasSubstr("render source name is empty"));
}

TEST(ParseCameraSourceTest, EveryBadFieldIsReportedWithItsValueInOneMessage) {
  const std::string e =
      ParseError("v4l2:/dev/video0,width=0,height=12x,fps=-3,format=yuyv,speed=9");
  EXPECT_THAT(e, HasSubstr("camera source \"v4l2:/dev/video0,width=0,height=12x,fps=-3,"
                           "format=yuyv,speed=9\": "));
  EXPECT_THAT(e, HasSubstr("width \"0\" is not an integer in 1..16384"));
  EXPECT_THAT(e, HasSubstr("height \"12x\" is not an integer in 1..16384"));
  EXPECT_THAT(e, HasSubstr("fps \"-3\" is not a number in (0, 10000]"));
  EXPECT_THAT(e, HasSubstr("format \"yuyv\" is not a pixel format (mono8, bgr8, rgb8, mono16)"));
  EXPECT_THAT(e, HasSubstr("unknown option \"speed=9\" for v4l2 (allowed: width=W, height=H, "
                           "fps=F, format=PIX, latest, intrinsics=ID)"));
}

TEST(ParseCameraSourceTest, OptionsThatDoNotApplyToTheScheme) {
  EXPECT_THAT(ParseError("file:a.avi,width=2,height=2"),
              HasSubstr("unknown option \"width=2\" for file (allowed: loop, fps=F, format=PIX, "
                        "latest, intrinsics=ID)"));
  EXPECT_THAT(ParseError("images:*.png,width=640,height=480"),
              HasSubstr("unknown option \"width=640\" for images"));
  EXPECT_THAT(ParseError("v4l2:/dev/video0,loop"), HasSubstr("unknown option \"loop\" for v4l2"));
  EXPECT_THAT(ParseError("sim:world,format=mono8"),
              HasSubstr("unknown option \"format=mono8\" for sim (allowed: fps=F, "
                        "intrinsics=ID)"));
}

TEST(ParseCameraSourceTest, FlagsValuesAndRepeats) {
  EXPECT_THAT(ParseError("file:a.avi,loop=1"),
              HasSubstr("option \"loop\" takes no value (got \"loop=1\")"));
  EXPECT_THAT(ParseError("file:a.avi,fps"), HasSubstr("option \"fps\" needs a value"));
  EXPECT_THAT(ParseError("file:a.avi,fps=10,fps=20"), HasSubstr("option \"fps\" given twice"));
  EXPECT_THAT(ParseError("file:a.avi,,loop"), HasSubstr("empty option \"\""));
  EXPECT_THAT(ParseError("file:a.avi,intrinsics="), HasSubstr("intrinsics id is empty"));
  EXPECT_THAT(ParseError("file:a.avi,fps=30fps"), HasSubstr("fps \"30fps\""));
  EXPECT_THAT(ParseError("file:a.avi,fps=inf"), HasSubstr("fps \"inf\""));
}

TEST(ParseCameraSourceTest, WidthAndHeightGoTogether) {
  EXPECT_THAT(ParseError("v4l2:/dev/video0,width=640"),
              HasSubstr("width without height (give both or neither)"));
  EXPECT_THAT(ParseError("v4l2:/dev/video0,height=480"),
              HasSubstr("height without width (give both or neither)"));
}

TEST(OpenCameraTest, BadStringsThrowConfigErrorBeforeOpeningAnything) {
  EXPECT_THROW(OpenCamera("v4l2:/dev/video0,width=640"), common::ConfigError);
  EXPECT_THROW(OpenCamera("gige:cam1"), common::ConfigError);
}

TEST(OpenCameraTest, OpensASimCameraConfiguredOnTheGivenClock) {
  RegisterRenderSource(
      "factory-test", CameraFormat{2, 2, PixelFormat::kMono8, 10.0},
      [](uint64_t, common::Duration, Image*) { return std::error_code(); }, "intr-a");
  common::SimulatedClock clock(common::SimulatedClock::Mode::kFreeRunning,
                               common::Duration(std::chrono::seconds(3)));
  auto camera = OpenCamera("sim:factory-test,fps=20,intrinsics=intr-b", clock);
  EXPECT_EQ(camera->name(), "sim:factory-test,fps=20,intrinsics=intr-b");
  EXPECT_EQ(camera->lifecycle(), common::DeviceLifecycle::kConfigured);
  EXPECT_DOUBLE_EQ(camera->format().fps, 20.0);
  EXPECT_EQ(camera->intrinsics_id(), "intr-b");
  ASSERT_FALSE(camera->Start());
  Image image;
  ASSERT_FALSE(camera->Grab(&image, std::chrono::milliseconds(100)));
  ASSERT_FALSE(camera->Grab(&image, std::chrono::milliseconds(100)));
  EXPECT_EQ(image.timestamp, common::Duration(std::chrono::milliseconds(3050)));
  EXPECT_TRUE(UnregisterRenderSource("factory-test"));
}

TEST(OpenCameraTest, AbsentSourcesThrowHalErrorNamingThem) {
  try {
    OpenCamera("file:/nonexistent/kinevis/clip.avi");
    FAIL() << "no HalError";
  } catch (const HalError& e) {
    EXPECT_EQ(e.device(), "file:/nonexistent/kinevis/clip.avi");
    EXPECT_EQ(e.operation(), "open");
    EXPECT_THAT(e.cause(), HasSubstr("/nonexistent/kinevis/clip.avi"));
  }
  EXPECT_THROW(OpenCamera("sim:no-such-world"), HalError);
}

}  // namespace
}  // namespace kinevis::hal
