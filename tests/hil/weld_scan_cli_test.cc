// The weld-repair chain as a user runs it (issue 7): `kinevis scan`, `kinevis weld-path`,
// `kinevis weld-run` on the simulated cell in the same process (the default): the robot reached
// over Modbus TCP, the scanner through its camera source, as on the real cell.

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <regex>
#include <string>

#include "calibration/weld_mount/scan_dataset.h"
#include "control/weld/weld_plan_io.h"
#include "tests/utilities/subprocess.h"
#include "vision/cloud/cloud_sidecar.h"

namespace kinevis {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using ::testing::HasSubstr;
using testing::ProcessResult;
using testing::RunKinevis;

std::string TempDir(const std::string& name) {
  const fs::path dir =
      fs::temp_directory_path() / ("kinevis_weld_scan_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir.string();
}

// The number after `label` in `text` (NaN when absent).
double Figure(const std::string& text, const std::string& label) {
  const std::regex re(label + " ([-0-9.]+)");
  std::smatch m;
  if (!std::regex_search(text, m, re)) return std::nan("");
  return std::strtod(m[1].str().c_str(), nullptr);
}

// Scan -> plan -> execute on the simulated cell with the nominal scanner and mount (the cell's
// true mount is off by a clamping error of about 1 mm: that is what the true stand-off shows).
TEST(WeldScanCliTest, ScanPlanAndWeldTheSimulatedBlade) {
  const std::string dir = TempDir("chain");
  const std::string map = dir + "/map.ply";
  const ProcessResult scan = RunKinevis({"scan", "--lines", "120", "--out", map}, 240s);
  ASSERT_EQ(scan.exit_code, 0) << scan.out << scan.err;
  vision::cloud::CloudSidecar sidecar;
  const vision::cloud::PointCloud cloud = vision::cloud::ReadCloud(dir + "/map.yaml", &sidecar);
  EXPECT_GT(cloud.size(), 50000u);
  EXPECT_TRUE(cloud.has_normals());
  EXPECT_EQ(sidecar.frame, "0");
  EXPECT_GT(sidecar.scan_lines, 60u);
  // Eq. 11 reads the stepper's angle back from every image.
  EXPECT_LT(Figure(scan.out, "max \\|d cot theta_y\\|"), 1e-3) << scan.out;
  // Against the true blade: the nominal mount's clamping error (~1 mm), not noise.
  const double map_rms = Figure(scan.out, "rms");
  EXPECT_GT(map_rms, 0.3) << scan.out;
  EXPECT_LT(map_rms, 3.0) << scan.out;

  const std::string path = dir + "/path.yaml";
  const ProcessResult plan =
      RunKinevis({"weld-path", "--map", map, "--grid-cell-mm", "2", "--out", path}, 120s);
  ASSERT_EQ(plan.exit_code, 0) << plan.out << plan.err;
  EXPECT_THAT(plan.out, HasSubstr("coverage 100.0 %")) << plan.out;
  EXPECT_TRUE(fs::exists(dir + "/path_top.png"));
  EXPECT_TRUE(fs::exists(dir + "/path_section.png"));
  const control::WeldPlanFile file = control::ReadWeldPlan(path);
  // The three pits of the default blade (sim/weld_cell_world.cc DefaultBlade), 0.6-1.2 mm deep.
  EXPECT_GE(file.plan.summary.regions, 3) << plan.out;
  EXPECT_GT(file.plan.summary.executable_beads, 3);
  EXPECT_EQ(file.plan.summary.unreachable_points, 0);

  const std::string log = dir + "/standoff.csv";
  const ProcessResult run = RunKinevis({"weld-run", path, "--log", log}, 240s);
  ASSERT_EQ(run.exit_code, 0) << run.out << run.err;
  const std::string all = std::to_string(file.plan.trajectory.size());
  EXPECT_THAT(run.out, HasSubstr(all + " of " + all + " segments executed")) << run.out;
  // The executed torch (true robot) against the plan's surface: the robot's D-H error only.
  EXPECT_LT(Figure(run.out, "planned surface \\(true robot\\): mean \\|e\\|"), 0.5) << run.out;
  EXPECT_TRUE(fs::exists(log));
}

TEST(WeldScanCliTest, RecordedScanRebuildsTheSameMap) {
  const std::string dir = TempDir("dataset");
  const ProcessResult record =
      RunKinevis({"record", "scan", "--lines", "12", "--out", dir + "/ds"}, 120s);
  ASSERT_EQ(record.exit_code, 0) << record.out << record.err;
  EXPECT_THAT(record.out, HasSubstr("recorded 12 frames"));
  const calibration::ScanDataset d = calibration::ReadScanDataset(dir + "/ds");
  EXPECT_EQ(d.frames.size(), 12u);
  const ProcessResult scan =
      RunKinevis({"scan", "--dataset", dir + "/ds", "--out", dir + "/map.ply"}, 120s);
  ASSERT_EQ(scan.exit_code, 0) << scan.out << scan.err;
  EXPECT_THAT(scan.out, HasSubstr("scan: 12 frames"));
}

TEST(WeldScanCliTest, BadInputIsNamed) {
  const std::string dir = TempDir("bad");
  ProcessResult r = RunKinevis({"scan", "--at", "0,0,200", "--out", dir + "/m.ply"}, 60s);
  EXPECT_EQ(r.exit_code, 2) << r.out << r.err;
  EXPECT_THAT(r.out + r.err, HasSubstr("need 5 values"));
  // A dataset directory without a dataset.
  r = RunKinevis({"scan", "--dataset", dir, "--out", dir + "/m.ply"}, 60s);
  EXPECT_EQ(r.exit_code, 2) << r.out << r.err;
  EXPECT_THAT(r.out + r.err, HasSubstr("no scan.yaml"));
  // A plan file that is not one.
  const std::string bad_plan = dir + "/plan.yaml";
  std::ofstream(bad_plan) << "kind: something-else\n";
  r = RunKinevis({"weld-run", bad_plan}, 60s);
  EXPECT_EQ(r.exit_code, 2) << r.out << r.err;
  EXPECT_THAT(r.out + r.err, HasSubstr(bad_plan));
  // A map that does not exist.
  r = RunKinevis({"weld-path", "--map", dir + "/none.ply"}, 60s);
  EXPECT_EQ(r.exit_code, 2) << r.out << r.err;
}

}  // namespace
}  // namespace kinevis
