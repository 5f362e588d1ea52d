#include "vision/cloud/cloud_sidecar.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <regex>

#include "vision/cloud/ply.h"

namespace kinevis::vision::cloud {
namespace {

using ::testing::HasSubstr;

std::string TempDir() {
  const std::filesystem::path dir = std::filesystem::temp_directory_path() / "kinevis_sidecar_test";
  std::filesystem::create_directories(dir);
  return dir.string();
}

CloudSidecar Example() {
  CloudSidecar s;
  s.ply = "map.ply";
  s.source = "test";
  s.robot_calibration = "robots/weld5/weld5.yaml";
  s.robot_dh = {{0.1, -1.5, 0.275, 0.002, false}, {0.0, 0.0, 0.0, 0.0, true}};
  s.X_5T =
      Eigen::Translation3d(0.025, 0.0, 0.25) * Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitY());
  s.X_5C = Eigen::Translation3d(-0.05, -0.06, 0.1) *
           Eigen::AngleAxisd(0.01, Eigen::Vector3d(1, 2, 3).normalized());
  s.mount_calibration = "mount.yaml";
  s.scanner_calibration = "scanner.yaml";
  s.scanner_parameters = {{"rotating_b_y_mm", 101.973}, {"fixed_cot_theta_x", -0.0922}};
  s.scan_lines = 2;
  return s;
}

PointCloud Cloud() {
  PointCloud c;
  c.points = {{0.1f, 0.2f, 0.3f}, {0.4f, 0.5f, 0.6f}, {0.7f, 0.8f, 0.9f}};
  c.normals = {{0, 0, 1}, {0, 0, 0}, {1, 0, 0}};
  return c;
}

TEST(CloudSidecar, RoundTripKeepsEverything) {
  const std::string path = TempDir() + "/map.yaml";
  WriteCloud(path, Cloud(), Example());
  CloudSidecar r;
  const PointCloud c = ReadCloud(path, &r);
  EXPECT_EQ(c.size(), 3u);
  EXPECT_EQ(r.points, 3u);
  EXPECT_EQ(r.normals_estimated, 2u);
  EXPECT_EQ(r.normals_missing, 1u);
  EXPECT_FALSE(r.has_confidence);
  EXPECT_EQ(r.units, "m");
  EXPECT_EQ(r.frame, "0");
  EXPECT_EQ(r.scan_lines, 2u);
  EXPECT_EQ(r.robot_calibration, "robots/weld5/weld5.yaml");
  ASSERT_EQ(r.robot_dh.size(), 2u);
  EXPECT_NEAR(r.robot_dh[0].alpha, -1.5, 1e-14);
  EXPECT_NEAR(r.robot_dh[0].d, 0.275, 1e-15);
  EXPECT_TRUE(r.robot_dh[1].prismatic);
  EXPECT_TRUE(r.X_5T.isApprox(Example().X_5T, 1e-12));
  EXPECT_TRUE(r.X_5C.isApprox(Example().X_5C, 1e-12));
  EXPECT_EQ(r.scanner_parameters.at("rotating_b_y_mm"), 101.973);
  EXPECT_TRUE(std::regex_match(r.created, std::regex(R"(\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ)")));
}

std::string Error(const std::string& path) {
  try {
    ReadCloud(path);
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "";
}

TEST(CloudSidecar, RefusesBadSidecarsNamingTheKey) {
  const std::string dir = TempDir();
  const std::string path = dir + "/bad.yaml";
  WriteCloud(path, Cloud(), Example());
  std::ifstream in(path);
  const std::string text((std::istreambuf_iterator<char>(in)), {});
  const auto with = [&](const std::string& from, const std::string& to) {
    std::string t = text;
    const std::size_t at = t.find(from);
    EXPECT_NE(at, std::string::npos) << from;
    t.replace(at, from.size(), to);
    std::ofstream(path) << t;
    return Error(path);
  };
  EXPECT_THAT(with("units: m", "units: mm"), HasSubstr("bad.yaml: units: is 'mm'; expected m"));
  EXPECT_THAT(with("kind: kinevis-point-cloud", "kind: other"), HasSubstr("kind: is 'other'"));
  EXPECT_THAT(with("points: 3", "points: 4"), HasSubstr("is neither 0 nor points = 4"));
  EXPECT_THAT(with("normals_missing: 1", "normals_missing: 0"), HasSubstr("counts:"));
  EXPECT_THAT(with("  scan_lines: 2\n", "\n"), HasSubstr("counts.scan_lines: missing"));
  EXPECT_THAT(with("a_mm: 100", "a_mm: .nan"), HasSubstr("robot.dh[0].a_mm: is not finite"));
  EXPECT_THAT(with("ply: map.ply", "ply: other.ply"), HasSubstr("other.ply: cannot open"));
  EXPECT_THAT(Error(dir + "/none.yaml"), HasSubstr("none.yaml: cannot open"));
  // A PLY that does not match its sidecar.
  std::ofstream(path) << text;
  PointCloud two = Cloud();
  two.points.pop_back();
  two.normals.pop_back();
  WritePly(dir + "/map.ply", two);
  EXPECT_THAT(Error(path), HasSubstr("the sidecar says 3 points, the PLY holds 2"));
}

}  // namespace
}  // namespace kinevis::vision::cloud
