#include "calibration/weld_mount/mount_dataset.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

namespace kinevis::calibration {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

std::string FreshDir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / ("kinevis_mount_dataset_" + name);
  fs::remove_all(dir);
  return dir.string();
}

MountDataset Record(const std::string& dir) {
  MountDataset d;
  d.directory = dir;
  d.robot_description = "robots/weld5/weld5.yaml";
  d.scanner = "scanner.yaml";
  d.X_0B_guess =
      Eigen::Translation3d(0.7, 0.04, 0.3) * Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitY());
  d.X_5C_guess = Eigen::Translation3d(-0.05, -0.06, 0.1) * Eigen::Isometry3d::Identity();
  d.source = "test";
  CreateMountDataset(&d);
  MountTouch t;
  t.q << 0.1, -0.2, 0.25, 0.3, -0.4;
  t.feature = BlockFeature::Parse("+x-y+z");
  AppendMountTouch(&d, t);
  t.feature = BlockFeature::Parse("top");
  AppendMountTouch(&d, t);
  MountDatasetScan s;
  s.q << 0.01, 0.02, 0.2, 0.03, 0.04;
  s.cot_theta_y = 0.25;
  const std::vector<Eigen::Vector3d> p = {{0.001, 0.002, 0.4}, {0.0015, 0.0021, 0.4001}};
  AppendMountScan(&d, s, &p, {0.5f, 1.0f});
  const std::vector<uint8_t> pixels(16 * 8, 200);
  s.laser = "fixed";
  AppendMountScan(&d, s, nullptr, {}, pixels.data(), 16, 8, 16);
  return d;
}

TEST(MountDataset, RoundTrip) {
  const std::string dir = FreshDir("round_trip");
  const MountDataset written = Record(dir);
  const MountDataset d = ReadMountDataset(dir);
  EXPECT_EQ(d.robot_description, "robots/weld5/weld5.yaml");
  EXPECT_TRUE(d.X_0B_guess.isApprox(written.X_0B_guess, 1e-12));
  EXPECT_TRUE(d.X_5C_guess.isApprox(written.X_5C_guess, 1e-12));
  EXPECT_TRUE(d.block.size.isApprox(GaugeBlock().size, 1e-15));
  ASSERT_EQ(d.touches.size(), 2u);
  EXPECT_EQ(d.touches[0].feature.Name(), "+x-y+z");
  EXPECT_EQ(d.touches[1].feature.Name(), "top");
  EXPECT_LT((d.touches[0].q - written.touches[0].q).norm(), 1e-15);
  ASSERT_EQ(d.scans.size(), 2u);
  EXPECT_EQ(d.scans[0].points, "points/scan_0000.csv");
  EXPECT_EQ(d.scans[1].image, "images/scan_0001.png");
  EXPECT_EQ(d.scans[1].laser, "fixed");
  std::vector<float> confidence;
  const std::vector<Eigen::Vector3d> p = ReadMountScanPoints(d, d.scans[0], &confidence);
  ASSERT_EQ(p.size(), 2u);
  EXPECT_LT((p[1] - Eigen::Vector3d(0.0015, 0.0021, 0.4001)).norm(), 1e-15);
  EXPECT_EQ(confidence, (std::vector<float>{0.5f, 1.0f}));
  try {
    MountCalibrationDataFromDataset(d, robots::Weld5Model::Seed(Eigen::Isometry3d::Identity()));
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr("scan 1 has only an image (images/scan_0001.png)"));
  }
  EXPECT_THROW(Record(dir), std::invalid_argument);  // already a dataset
}

std::string Error(const std::string& dir) {
  try {
    ReadMountDataset(dir);
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "";
}

void Replace(const fs::path& file, const std::string& from, const std::string& to) {
  std::ifstream in(file);
  std::string text((std::istreambuf_iterator<char>(in)), {});
  const std::size_t at = text.find(from);
  ASSERT_NE(at, std::string::npos) << from;
  text.replace(at, from.size(), to);
  std::ofstream(file) << text;
}

TEST(MountDataset, RefusesBadDatasetsNamingFileLineAndProblem) {
  struct Case {
    std::string file, from, to, message;
  };
  const std::vector<Case> cases = {
      {"dataset.yaml", "kind: kinevis-scanner-mount-dataset", "kind: x", "dataset.yaml: kind: 'x'"},
      {"dataset.yaml", "size_mm: [100, 50, 10]", "size_mm: [100, -50, 10]", "block.size_mm"},
      {"dataset.yaml", "mount_guess:", "mount_gues:", "mount_guess: missing"},
      {"touches.csv", "+x-y+z", "+q", "touches.csv line 2: block feature '+q'"},
      {"touches.csv", "touch,feature", "touch,face", "touches.csv: header is"},
      {"scans.csv", ",rotating,", ",blue,", "scans.csv line 2: laser 'blue'"},
      {"scans.csv", "points/scan_0000.csv", "points/none.csv", "points/none.csv does not exist"},
      {"points/scan_0000.csv", "0.5", "x", ""},
  };
  for (const Case& c : cases) {
    const std::string dir = FreshDir("bad");
    Record(dir);
    Replace(fs::path(dir) / c.file, c.from, c.to);
    if (c.message.empty()) {
      const MountDataset d = ReadMountDataset(dir);
      try {
        ReadMountScanPoints(d, d.scans[0]);
        FAIL();
      } catch (const std::invalid_argument& e) {
        EXPECT_THAT(e.what(), HasSubstr("scan_0000.csv line 2: field 4 'x' is not a number"));
      }
    } else {
      EXPECT_THAT(Error(dir), HasSubstr(c.message)) << c.file << ": " << c.to;
    }
  }
  EXPECT_THAT(Error(FreshDir("none")), HasSubstr("no dataset.yaml"));
}

}  // namespace
}  // namespace kinevis::calibration
