// `kinevis calibrate camera` as a user runs it: synthetic chessboard images written as PNG files,
// the real program, and what it leaves behind (intrinsics YAML, overlay PNGs, exit codes and
// messages).

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <string>
#include <vector>

#include "tests/utilities/chessboard_images.h"
#include "tests/utilities/subprocess.h"
#include "vision/camera/camera_info_yaml.h"

namespace kinevis {
namespace {

using namespace std::chrono_literals;
using ::testing::ContainsRegex;
using ::testing::HasSubstr;
using testing::ProcessResult;

ProcessResult Kinevis(std::vector<std::string> args) {
  return testing::RunKinevis(std::move(args), 120s);
}

vision::PinholeBrownParameters TrueCamera() {
  vision::PinholeBrownParameters c;
  c.width = 640;
  c.height = 480;
  c.fx = 602.5;
  c.fy = 598.0;
  c.cx = 322.4;
  c.cy = 236.8;
  c.distortion = {-0.25, 0.08, 4e-4, -3e-4, 0, 0, 0, 0};
  return c;
}

void WritePng(const testing::GreyImage& image, const std::string& path) {
  const cv::Mat m(image.height, image.width, CV_8U, const_cast<std::uint8_t*>(image.pixels.data()));
  ASSERT_TRUE(cv::imwrite(path, m)) << path;
}

// A directory with `views` board images view_00.png... and, optionally, one without a board.
std::string MakeImageDir(const std::string& name, int views, bool with_empty) {
  const std::string dir = ::testing::TempDir() + "kinevis_calibrate_cli_" + name;
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  testing::RenderOptions render;
  render.blur_sigma_px = 0.8;
  const testing::ChessboardTarget target;
  const auto poses = testing::CalibrationPoses(TrueCamera(), target, views, 7);
  for (int k = 0; k < views; ++k) {
    char file[32];
    std::snprintf(file, sizeof file, "/view_%02d.png", k);
    WritePng(testing::RenderChessboard(TrueCamera(), poses[k], target, render), dir + file);
  }
  if (with_empty) WritePng(testing::RenderEmptyScene(640, 480, render), dir + "/view_99.png");
  return dir;
}

TEST(CalibrateCameraCliTest, WritesIntrinsicsAndOverlaysAndNamesTheRefusedImage) {
  const std::string dir = MakeImageDir("good", 15, true);
  const std::string yaml = dir + "/out/intrinsics.yaml";
  std::filesystem::create_directories(dir + "/out");
  const ProcessResult r =
      Kinevis({"calibrate", "camera", "--images", dir + "/*.png", "--board", "9x6", "--square",
               "0.025", "--out", yaml, "--overlay-dir", dir + "/overlays"});
  ASSERT_EQ(r.exit_code, 0) << r.out << r.err;
  // The table names every image; the refused one with its reason, on stdout and stderr.
  EXPECT_THAT(r.out, ContainsRegex("view_00\\.png +used +0\\.0[0-9]+"));
  EXPECT_THAT(r.out, ContainsRegex("view_99\\.png +board not found"));
  EXPECT_THAT(r.err, ContainsRegex("refused .*view_99\\.png: board not found"));
  EXPECT_THAT(r.out, HasSubstr("calibrated from 15 of 16 images"));
  EXPECT_THAT(r.out, ContainsRegex("fx = 60[0-9.]+ \\+- 0\\.[0-9]+ px"));

  const vision::PinholeBrownParameters p = vision::ReadPinholeIntrinsics(yaml);
  EXPECT_EQ(p.width, 640);
  EXPECT_EQ(p.height, 480);
  // 15 views: same renderer and margins as the library test (measured there within 0.4 px).
  EXPECT_NEAR(p.fx, TrueCamera().fx, 2.0);
  EXPECT_NEAR(p.fy, TrueCamera().fy, 2.0);
  EXPECT_NEAR(p.cx, TrueCamera().cx, 2.0);
  EXPECT_NEAR(p.cy, TrueCamera().cy, 2.0);
  EXPECT_NEAR(p.distortion[0], -0.25, 5e-3);
  // The per-image errors and the refused image are in the file too.
  std::ifstream in(yaml);
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_THAT(text, ContainsRegex("per_image_rms_px: \\[0\\.0"));
  EXPECT_THAT(text, ContainsRegex("refused_images: \\[\".*view_99\\.png: board not found"));
  EXPECT_THAT(text, HasSubstr("distortion_model: \"plumb_bob\""));

  for (const char* name : {"view_00_overlay.png", "view_14_overlay.png"}) {
    const cv::Mat overlay = cv::imread(dir + "/overlays/" + name, cv::IMREAD_UNCHANGED);
    ASSERT_FALSE(overlay.empty()) << name;
    EXPECT_EQ(overlay.cols, 640);
    EXPECT_EQ(overlay.rows, 480);
    EXPECT_EQ(overlay.channels(), 3);
  }
  EXPECT_FALSE(std::filesystem::exists(dir + "/overlays/view_99_overlay.png"));
}

TEST(CalibrateCameraCliTest, JsonOutputCarriesTheResult) {
  const std::string dir = MakeImageDir("json", 6, false);
  const ProcessResult r =
      Kinevis({"calibrate", "camera", "--images", dir + "/*.png", "--board", "9x6", "--square",
               "0.025", "--out", dir + "/i.yaml", "--json", "--rational"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("\"calibrated\": true"));
  EXPECT_THAT(r.out, HasSubstr("\"distortion_model\": \"rational_polynomial\""));
  EXPECT_THAT(r.out, HasSubstr("\"rms_px\""));
  EXPECT_EQ(r.out.find("image  "), std::string::npos);  // no table
  EXPECT_NO_THROW(vision::ReadPinholeIntrinsics(dir + "/i.yaml"));
}

TEST(CalibrateCameraCliTest, TooFewUsableImagesFailsNamingThem) {
  const std::string dir = MakeImageDir("few", 2, true);
  const ProcessResult r = Kinevis({"calibrate", "camera", "--images", dir + "/*.png", "--board",
                                   "9x6", "--square", "0.025", "--out", dir + "/x.yaml"});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_THAT(r.err, ContainsRegex("kinevis calibrate camera: only 2 of 3 images usable "
                                   "\\(minimum 3\\); refused: .*view_99\\.png \\(board not "
                                   "found"));
  EXPECT_FALSE(std::filesystem::exists(dir + "/x.yaml"));
}

TEST(CalibrateCameraCliTest, BadOptionsAreUsageErrors) {
  const std::string dir = MakeImageDir("bad", 1, false);
  const ProcessResult board = Kinevis(
      {"calibrate", "camera", "--images", dir + "/*.png", "--board", "9-6", "--square", "0.025"});
  EXPECT_EQ(board.exit_code, 2);
  EXPECT_THAT(board.err, HasSubstr("--board \"9-6\": expected COLSxROWS"));
  const ProcessResult corners = Kinevis(
      {"calibrate", "camera", "--images", dir + "/*.png", "--board", "1x6", "--square", "0.025"});
  EXPECT_EQ(corners.exit_code, 2);
  EXPECT_THAT(corners.err, HasSubstr("board_cols = 1"));
  const ProcessResult none = Kinevis(
      {"calibrate", "camera", "--images", dir + "/*.jpg", "--board", "9x6", "--square", "0.025"});
  EXPECT_EQ(none.exit_code, 2);
  EXPECT_THAT(none.err, ContainsRegex("--images: \".*\\*\\.jpg\" matches no file"));
  EXPECT_EQ(Kinevis({"calibrate", "camera", "--board", "9x6", "--square", "0.025"}).exit_code, 2);
  EXPECT_EQ(Kinevis({"calibrate", "camera", "--images", dir + "/*.png", "--board", "9x6",
                     "--square", "-1"})
                .exit_code,
            2);
}

TEST(CalibrateCameraCliTest, HelpSaysWhatItWrites) {
  const ProcessResult r = Kinevis({"calibrate", "camera", "--help"});
  EXPECT_EQ(r.exit_code, 0);
  EXPECT_THAT(r.out, HasSubstr("--overlay-dir"));
  EXPECT_THAT(r.out, HasSubstr("Writes the intrinsics YAML"));
  EXPECT_THAT(r.out, HasSubstr("ROS camera_info YAML"));
  EXPECT_THAT(r.out, HasSubstr("overlay PNG"));
}

}  // namespace
}  // namespace kinevis
