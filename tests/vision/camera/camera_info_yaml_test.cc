// Intrinsics files in ROS's camera_info YAML layout: exact round trip, ROS files written by hand,
// the same file read the way ROS's camera_calibration_parsers reads it (yaml-cpp), and errors
// that name the file and the key.

#include "vision/camera/camera_info_yaml.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>

#include <cstdio>
#include <fstream>
#include <opencv2/core.hpp>
#include <stdexcept>
#include <string>

namespace kinevis::vision {
namespace {

using ::testing::ContainsRegex;
using ::testing::HasSubstr;

std::string TempPath(const std::string& name) {
  return ::testing::TempDir() + "kinevis_camera_info_yaml_" + name;
}

std::string WriteText(const std::string& name, const std::string& text) {
  const std::string path = TempPath(name);
  std::ofstream(path) << text;
  return path;
}

PinholeBrownParameters Sample(bool rational) {
  PinholeBrownParameters p;
  p.width = 640;
  p.height = 480;
  p.fx = 601.2345678901234;
  p.fy = 599.87654321;
  p.cx = 319.5 + 1.0 / 3.0;
  p.cy = 241.123456789;
  p.distortion = {-0.25, 0.08, 1.5e-4, -2.5e-4, -0.0123, 0, 0, 0};
  if (rational) {
    p.distortion[5] = 0.11;
    p.distortion[6] = -0.02;
    p.distortion[7] = 1e-3;
  }
  return p;
}

void ExpectSame(const PinholeBrownParameters& a, const PinholeBrownParameters& b) {
  EXPECT_EQ(a.width, b.width);
  EXPECT_EQ(a.height, b.height);
  // Bit-exact: the writer uses the shortest representation that reads back to the same double.
  EXPECT_EQ(a.fx, b.fx);
  EXPECT_EQ(a.fy, b.fy);
  EXPECT_EQ(a.cx, b.cx);
  EXPECT_EQ(a.cy, b.cy);
  for (int i = 0; i < 8; ++i) EXPECT_EQ(a.distortion[i], b.distortion[i]) << "coefficient " << i;
}

std::string Expect(const std::function<void()>& f, bool runtime_error = false) {
  try {
    f();
  } catch (const std::invalid_argument& e) {
    EXPECT_FALSE(runtime_error) << e.what();
    return e.what();
  } catch (const std::runtime_error& e) {
    EXPECT_TRUE(runtime_error) << e.what();
    return e.what();
  }
  ADD_FAILURE() << "no exception";
  return "";
}

TEST(CameraInfoYamlTest, PlumbBobRoundTripIsExact) {
  const std::string path = TempPath("plumb_bob.yaml");
  IntrinsicsFileExtras extras;
  extras.camera_name = "left \"wide\" 01";
  WritePinholeIntrinsics(path, Sample(false), extras);
  std::string name;
  ExpectSame(ReadPinholeIntrinsics(path, &name), Sample(false));
  EXPECT_EQ(name, extras.camera_name);
  YAML::Node doc = YAML::LoadFile(path);
  EXPECT_EQ(doc["distortion_model"].as<std::string>(), "plumb_bob");
  EXPECT_EQ(doc["distortion_coefficients"]["cols"].as<int>(), 5);
}

TEST(CameraInfoYamlTest, RationalRoundTripIsExact) {
  const std::string path = TempPath("rational.yaml");
  WritePinholeIntrinsics(path, Sample(true));
  ExpectSame(ReadPinholeIntrinsics(path), Sample(true));
  YAML::Node doc = YAML::LoadFile(path);
  EXPECT_EQ(doc["distortion_model"].as<std::string>(), "rational_polynomial");
  EXPECT_EQ(doc["distortion_coefficients"]["cols"].as<int>(), 8);
  EXPECT_EQ(doc["distortion_coefficients"]["data"].size(), 8u);
}

// The reads of camera_calibration_parsers' readCalibrationYml (yaml-cpp): image size, K, R and
// P as {rows, cols, data} maps of the fixed sizes, distortion_model, D of rows*cols values.
TEST(CameraInfoYamlTest, FileReadsTheWayRosParsesIt) {
  const std::string path = TempPath("ros_read.yaml");
  const PinholeBrownParameters p = Sample(false);
  IntrinsicsFileExtras extras;
  extras.camera_name = "cam0";
  extras.numbers = {{"rms_px", 0.0421}};
  extras.number_lists = {{"per_image_rms_px", {0.04, 0.05}}};
  extras.string_lists = {{"images", {"a.png", "b c.png"}}};
  WritePinholeIntrinsics(path, p, extras);
  YAML::Node doc = YAML::LoadFile(path);
  EXPECT_EQ(doc["camera_name"].as<std::string>(), "cam0");
  EXPECT_EQ(doc["image_width"].as<int>(), 640);
  EXPECT_EQ(doc["image_height"].as<int>(), 480);
  const double K[9] = {p.fx, 0, p.cx, 0, p.fy, p.cy, 0, 0, 1};
  const double R[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  const double P[12] = {p.fx, 0, p.cx, 0, 0, p.fy, p.cy, 0, 0, 0, 1, 0};
  struct {
    const char* key;
    int rows, cols;
    const double* expected;
  } matrices[] = {{"camera_matrix", 3, 3, K},
                  {"rectification_matrix", 3, 3, R},
                  {"projection_matrix", 3, 4, P}};
  for (const auto& m : matrices) {
    SCOPED_TRACE(m.key);
    ASSERT_TRUE(doc[m.key].IsMap());
    EXPECT_EQ(doc[m.key]["rows"].as<int>(), m.rows);
    EXPECT_EQ(doc[m.key]["cols"].as<int>(), m.cols);
    ASSERT_EQ(doc[m.key]["data"].size(), static_cast<size_t>(m.rows * m.cols));
    for (int i = 0; i < m.rows * m.cols; ++i) {
      EXPECT_EQ(doc[m.key]["data"][i].as<double>(), m.expected[i]) << i;
    }
  }
  EXPECT_EQ(doc["distortion_coefficients"]["rows"].as<int>(), 1);
  for (int i = 0; i < 5; ++i) {
    EXPECT_EQ(doc["distortion_coefficients"]["data"][i].as<double>(), p.distortion[i]);
  }
  EXPECT_EQ(doc["rms_px"].as<double>(), 0.0421);
  EXPECT_EQ(doc["images"][1].as<std::string>(), "b c.png");
  // OpenCV's FileStorage opens the file as written, extra keys included.
  cv::FileStorage fs(path, cv::FileStorage::READ);
  ASSERT_TRUE(fs.isOpened());
  EXPECT_EQ(static_cast<double>(fs["per_image_rms_px"][1]), 0.05);
  EXPECT_EQ(static_cast<double>(fs["camera_matrix"]["data"][0]), p.fx);
}

// As written by ROS's Python calibrator: no %YAML header, an unquoted serial number as the
// camera name, multi-line flow lists, numbers such as "0.".
TEST(CameraInfoYamlTest, HandWrittenRosFileLoads) {
  const std::string path = WriteText("ros_by_hand.yaml", R"(image_width: 640
image_height: 480
camera_name: 00b09d0100990bb6
camera_matrix:
  rows: 3
  cols: 3
  data: [ 580.46715,    0.     ,  315.27153,
            0.     ,  576.62721,  247.47257,
            0.     ,    0.     ,    1.     ]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [0.134462, -0.311908, 0.002304, 0.003083, 0.000000]
rectification_matrix:
  rows: 3
  cols: 3
  data: [ 1.,  0.,  0.,
          0.,  1.,  0.,
          0.,  0.,  1.]
projection_matrix:
  rows: 3
  cols: 4
  data: [ 587.73773,    0.     ,  316.77307,    0.     ,
            0.     ,  585.66626,  248.29638,    0.     ,
            0.     ,    0.     ,    1.     ,    0.     ]
)");
  std::string name;
  const PinholeBrownParameters p = ReadPinholeIntrinsics(path, &name);
  EXPECT_EQ(name, "00b09d0100990bb6");
  EXPECT_EQ(p.width, 640);
  EXPECT_EQ(p.height, 480);
  EXPECT_DOUBLE_EQ(p.fx, 580.46715);
  EXPECT_DOUBLE_EQ(p.fy, 576.62721);
  EXPECT_DOUBLE_EQ(p.cx, 315.27153);
  EXPECT_DOUBLE_EQ(p.cy, 247.47257);
  const double expected[8] = {0.134462, -0.311908, 0.002304, 0.003083, 0, 0, 0, 0};
  for (int i = 0; i < 8; ++i) EXPECT_DOUBLE_EQ(p.distortion[i], expected[i]) << i;
}

// ROS's C++ writer (yaml-cpp emitter): no distortion_model in old files, integers for zeros.
TEST(CameraInfoYamlTest, OldRosFileWithoutDistortionModelIsPlumbBob) {
  const std::string path = WriteText("ros_old.yaml", R"(image_width: 800
image_height: 600
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [538.63, 0, 457.698, 0, 539.723, 297.003, 0, 0, 1]
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.30678, 0.0825017, 0.0028784, -0.00015829, 0]
)");
  const PinholeBrownParameters p = ReadPinholeIntrinsics(path);
  EXPECT_EQ(p.width, 800);
  EXPECT_DOUBLE_EQ(p.cx, 457.698);
  EXPECT_DOUBLE_EQ(p.distortion[0], -0.30678);
  EXPECT_DOUBLE_EQ(p.distortion[3], -0.00015829);
}

const char* const kGoodHead = R"(image_width: 640
image_height: 480
)";
const char* const kGoodK = R"(camera_matrix:
  rows: 3
  cols: 3
  data: [600, 0, 320, 0, 600, 240, 0, 0, 1]
)";
const char* const kGoodD = R"(distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.25, 0.08, 0, 0, 0]
)";

TEST(CameraInfoYamlTest, MissingKeyNamesFileAndKey) {
  const std::string path = WriteText("missing_k.yaml", std::string(kGoodHead) + kGoodD);
  const std::string message = Expect([&] { ReadPinholeIntrinsics(path); });
  EXPECT_THAT(message, ContainsRegex("missing_k\\.yaml.*camera_matrix: missing"));
  const std::string path2 =
      WriteText("missing_w.yaml", std::string("image_height: 480\n") + kGoodK + kGoodD);
  EXPECT_THAT(Expect([&] { ReadPinholeIntrinsics(path2); }),
              ContainsRegex("missing_w\\.yaml.*image_width: missing"));
}

TEST(CameraInfoYamlTest, WrongMatrixSizeIsNamed) {
  const std::string path = WriteText("k_2x3.yaml", std::string(kGoodHead) + R"(camera_matrix:
  rows: 2
  cols: 3
  data: [600, 0, 320, 0, 600, 240]
)" + kGoodD + R"(projection_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
)");
  const std::string message = Expect([&] { ReadPinholeIntrinsics(path); });
  EXPECT_THAT(message, HasSubstr("camera_matrix: size 2x3, expected 3x3"));
  EXPECT_THAT(message, HasSubstr("projection_matrix: size 3x3, expected 3x4"));

  const std::string path2 = WriteText("d_count.yaml", std::string(kGoodHead) + kGoodK + R"(
distortion_model: rational_polynomial
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.25, 0.08, 0, 0, 0]
)");
  EXPECT_THAT(Expect([&] { ReadPinholeIntrinsics(path2); }),
              HasSubstr("distortion_coefficients: size 1x5 does not fit rational_polynomial"));

  const std::string path3 = WriteText("d_short.yaml", std::string(kGoodHead) + kGoodK + R"(
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.25, 0.08, 0, 0]
)");
  EXPECT_THAT(Expect([&] { ReadPinholeIntrinsics(path3); }),
              HasSubstr("distortion_coefficients: data has 4 values for 1x5"));
}

TEST(CameraInfoYamlTest, EveryBadValueIsNamedInOneMessage) {
  const std::string path = WriteText("bad_values.yaml", R"(image_width: 0
image_height: 480
camera_matrix:
  rows: 3
  cols: 3
  data: [-600, 0.5, 320, 0, 0, 240, 0, 0, 1]
distortion_model: equidistant
distortion_coefficients:
  rows: 1
  cols: 4
  data: [0, 0, 0, 0]
)");
  const std::string message = Expect([&] { ReadPinholeIntrinsics(path); });
  EXPECT_THAT(message, HasSubstr("bad_values.yaml"));
  EXPECT_THAT(message, HasSubstr("image_width: must be a positive integer"));
  EXPECT_THAT(message, HasSubstr("fx = data[0] = -600 must be > 0"));
  EXPECT_THAT(message, HasSubstr("fy = data[4] = 0 must be > 0"));
  EXPECT_THAT(message, HasSubstr("skew data[1] = 0.5"));
  EXPECT_THAT(message, HasSubstr("distortion_model: \"equidistant\" is not supported"));
}

TEST(CameraInfoYamlTest, UnreadableOrUnparsableFileIsARuntimeError) {
  const std::string missing = TempPath("does_not_exist.yaml");
  std::remove(missing.c_str());
  EXPECT_THAT(Expect([&] { ReadPinholeIntrinsics(missing); }, true),
              ContainsRegex("does_not_exist\\.yaml.*cannot open"));
  const std::string garbage = WriteText("garbage.yaml", "image_width: [1, 2\n  : {\n");
  EXPECT_THAT(Expect([&] { ReadPinholeIntrinsics(garbage); }, true),
              ContainsRegex("garbage\\.yaml.*not parsable as YAML"));
}

TEST(CameraInfoYamlTest, WritingBadParametersOrKeysThrowsNamingThem) {
  PinholeBrownParameters p = Sample(false);
  p.fy = -1;
  p.width = 0;
  p.distortion[2] = std::nan("");
  const std::string message = Expect([&] { WritePinholeIntrinsics(TempPath("never.yaml"), p); });
  EXPECT_THAT(message, HasSubstr("width = 0"));
  EXPECT_THAT(message, HasSubstr("fy = -1"));
  EXPECT_THAT(message, HasSubstr("distortion[2] = nan"));

  IntrinsicsFileExtras extras;
  extras.numbers = {{"camera_matrix", 1.0}, {"bad key", 2.0}};
  const std::string keys =
      Expect([&] { WritePinholeIntrinsics(TempPath("never.yaml"), Sample(false), extras); });
  EXPECT_THAT(keys, HasSubstr("\"camera_matrix\" is used twice or is a ROS key"));
  EXPECT_THAT(keys, HasSubstr("\"bad key\" is not an identifier"));

  EXPECT_THAT(
      Expect([&] { WritePinholeIntrinsics("/nonexistent-dir/x.yaml", Sample(false)); }, true),
      HasSubstr("/nonexistent-dir/x.yaml"));
}

}  // namespace
}  // namespace kinevis::vision
