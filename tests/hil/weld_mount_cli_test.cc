// The scanner-mount commands as a user runs them (issue 7, seed 004 §4): `kinevis record
// scanner-mount` and `kinevis calibrate scanner-mount` on the simulated weld cell in the same
// process (the robot over Modbus TCP, the scanner through its camera source), checked against the
// world's true mount.

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "calibration/weld_mount/mount_calibration_io.h"
#include "calibration/weld_mount/mount_dataset.h"
#include "common/units.h"
#include "sim/weld_cell_world.h"
#include "tests/utilities/subprocess.h"

namespace kinevis {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using ::testing::HasSubstr;
using testing::ProcessResult;
using testing::RunKinevis;

std::string TempDir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() /
                       ("kinevis_weld_mount_cli_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir.string();
}

void WriteText(const std::string& path, const std::string& text) {
  std::ofstream out(path);
  out << text;
}

double MountDistance(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  return (a.translation() - b.translation()).norm();
}
double MountAngle(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  return Eigen::AngleAxisd(a.linear().transpose() * b.linear()).angle();
}

// An exact arm (no D–H errors) with the gauge block placed off the board's centre and turned: the
// layout guess (board centre, heading 0) is 10 mm / 3° off, the CAD mount 1.2 mm / 0.9°.
std::string OffsetBlockConfig(const std::string& dir) {
  const std::string path = dir + "/offset_block.yaml";
  WriteText(path,
            "world: weld-cell\n"
            "truth: {dh_length_sigma_mm: 0, dh_angle_sigma_deg: 0}\n"
            "workpiece:\n"
            "  kind: board\n"
            "  gauge_block: {present: true, centre_mm: [8, -6], heading_deg: 3, size_mm: [100, "
            "50, 10]}\n");
  return path;
}

// Record on the cell, then calibrate from the recording; the result file against the truth.
TEST(WeldMountCliTest, RecordsAndCalibratesTheMountOfTheSimulatedScanner) {
  const std::string dir = TempDir("record");
  const std::string config = OffsetBlockConfig(dir);
  const std::string dataset = dir + "/dataset";
  const ProcessResult record = RunKinevis(
      {"record", "scanner-mount", "--config", config, "--views", "4", "--out", dataset}, 120s);
  ASSERT_EQ(record.exit_code, 0) << record.out << record.err;
  EXPECT_THAT(record.out, HasSubstr("from 4 views into " + dataset));
  EXPECT_THAT(record.out, HasSubstr("the world config's scanner geometry"));
  const calibration::MountDataset d = calibration::ReadMountDataset(dataset);
  EXPECT_GE(d.touches.size(), 10u);
  int fixed = 0, rotating = 0;
  for (const calibration::MountDatasetScan& s : d.scans) {
    (s.laser == "fixed" ? fixed : rotating)++;
    if (s.laser == "rotating") {
      EXPECT_FALSE(s.image.empty());
    }
  }
  EXPECT_EQ(fixed, 4);      // one per view
  EXPECT_GE(rotating, 10);  // 3 angles per view, a few may miss

  const std::string out = dir + "/mount_calib.yaml";
  const ProcessResult calibrate =
      RunKinevis({"calibrate", "scanner-mount", "--dataset", dataset, "--out", out}, 60s);
  ASSERT_EQ(calibrate.exit_code, 0) << calibrate.out << calibrate.err;
  EXPECT_THAT(calibrate.out, HasSubstr("status: ok"));
  EXPECT_THAT(calibrate.out, HasSubstr("correction from the CAD mount"));
  EXPECT_THAT(calibrate.out, HasSubstr("fixed-laser scans left out: 4"));
  const calibration::ScannerMountCalibrationFile f = calibration::ReadScannerMountCalibration(out);
  ASSERT_TRUE(f.summary.ok());
  const sim::WeldCellWorldConfig truth = sim::LoadWeldCellWorldConfig(config);
  // Measured: 0.037 mm, 0.058° from a CAD mount 1.15 mm / 0.86° off; bounds ~5-7x.
  EXPECT_LT(MountDistance(f.summary.X_5C, truth.X_5C), 0.25e-3) << calibrate.out;
  EXPECT_LT(MountAngle(f.summary.X_5C, truth.X_5C), 0.35 * common::kDeg) << calibrate.out;
  EXPECT_GT(MountDistance(f.metadata.X_5C_guess, truth.X_5C), 1e-3);  // it had to move
  // What `kinevis scan` reads.
  EXPECT_LT(MountDistance(calibration::ReadScannerMount(out), f.summary.X_5C), 1e-12);

  // Degenerate data are reported, not fitted: the scans of the first view only.
  const std::string one_view = dir + "/one_view";
  fs::copy(dataset, one_view, fs::copy_options::recursive);
  {
    std::ifstream in(dataset + "/scans.csv");
    std::string header, line;
    std::getline(in, header);
    std::string kept = header + "\n";
    int rows = 0;
    while (std::getline(in, line) && rows < 4) {
      kept += line + "\n";
      ++rows;
    }
    WriteText(one_view + "/scans.csv", kept);
  }
  const std::string one_out = dir + "/one_view.yaml";
  const ProcessResult degenerate =
      RunKinevis({"calibrate", "scanner-mount", "--dataset", one_view, "--out", one_out}, 60s);
  EXPECT_EQ(degenerate.exit_code, 1) << degenerate.out << degenerate.err;
  EXPECT_THAT(degenerate.out, HasSubstr("status: unidentified"));
  EXPECT_THAT(degenerate.out, HasSubstr("unidentified: "));
  EXPECT_THROW(calibration::ReadScannerMount(one_out), std::invalid_argument);
}

// Live on the default cell, whose arm has D–H errors: the mount alone absorbs them; with --dh the
// identifiable D–H errors are estimated and the mount comes out right.
TEST(WeldMountCliTest, DhErrorsOfTheArmAreEstimatedWithDh) {
  const std::string dir = TempDir("dh");
  const std::string dataset = dir + "/dataset";
  const std::string out_dh = dir + "/mount_dh.yaml";
  const ProcessResult dh = RunKinevis(
      {"calibrate", "scanner-mount", "--record", dataset, "--dh", "--out", out_dh}, 120s);
  ASSERT_EQ(dh.exit_code, 0) << dh.out << dh.err;
  EXPECT_THAT(dh.out, HasSubstr("D-H errors estimated"));
  EXPECT_THAT(dh.out, HasSubstr("D-H errors held at nominal: "));
  EXPECT_THAT(dh.out, HasSubstr("simulation truth: mount error"));
  const calibration::ScannerMountCalibrationFile with =
      calibration::ReadScannerMountCalibration(out_dh);
  ASSERT_TRUE(with.dh_estimated);
  EXPECT_FALSE(with.summary.fixed_dh.empty());
  EXPECT_GT(with.dh_errors.cwiseAbs().maxCoeff(), 0.0);

  const std::string out = dir + "/mount.yaml";
  const ProcessResult mount_only =
      RunKinevis({"calibrate", "scanner-mount", "--dataset", dataset, "--out", out}, 60s);
  ASSERT_EQ(mount_only.exit_code, 0) << mount_only.out << mount_only.err;
  const calibration::ScannerMountCalibrationFile without =
      calibration::ReadScannerMountCalibration(out);
  EXPECT_FALSE(without.dh_estimated);

  const sim::WeldCellWorldConfig truth;  // the defaults: 0.2 mm / 0.05° D–H errors
  const double e_dh = MountDistance(with.summary.X_5C, truth.X_5C);
  const double e = MountDistance(without.summary.X_5C, truth.X_5C);
  // Measured (7 views, docs/scanner-mount-calibration.md): with --dh 0.059 mm / 0.037°, the
  // mount alone 0.99 mm / 0.28°; bounds ~5x.
  EXPECT_LT(e_dh, 0.3e-3) << dh.out;
  EXPECT_LT(MountAngle(with.summary.X_5C, truth.X_5C), 0.2 * common::kDeg) << dh.out;
  EXPECT_LT(e, 5e-3) << mount_only.out;
  EXPECT_LT(MountAngle(without.summary.X_5C, truth.X_5C), 1.5 * common::kDeg) << mount_only.out;
  EXPECT_LT(e_dh, e) << dh.out << mount_only.out;
  // The mount-only fit shows the misfit in its touch residuals.
  EXPECT_GT(without.summary.touch.rms, 3.0 * with.summary.touch.rms);
}

TEST(WeldMountCliTest, AMissingDatasetIsAUsageError) {
  const ProcessResult r =
      RunKinevis({"calibrate", "scanner-mount", "--dataset", "/nonexistent/kinevis-mount"}, 30s);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.out + r.err, HasSubstr("/nonexistent/kinevis-mount"));

  const std::string empty = TempDir("empty");  // a directory without dataset.yaml
  const ProcessResult e = RunKinevis({"calibrate", "scanner-mount", "--dataset", empty}, 30s);
  EXPECT_EQ(e.exit_code, 2);
  EXPECT_THAT(e.out + e.err, HasSubstr(empty));
  EXPECT_THAT(e.out + e.err, HasSubstr("dataset.yaml"));
}

TEST(WeldMountCliTest, ABadScannerFileIsAUsageErrorNamingIt) {
  const std::string dir = TempDir("scanner");
  const std::string bad = dir + "/scanner_calib.yaml";
  WriteText(bad, "kind: kinevis-laser-scanner-calibration\nversion: 1\ncamera: ''\n");
  const ProcessResult r = RunKinevis(
      {"record", "scanner-mount", "--scanner", bad, "--views", "1", "--out", dir + "/ds"}, 60s);
  EXPECT_EQ(r.exit_code, 2) << r.out << r.err;
  EXPECT_THAT(r.err, HasSubstr(bad));
  EXPECT_THAT(r.err, HasSubstr("rotating_laser: missing"));
  EXPECT_FALSE(fs::exists(dir + "/ds/dataset.yaml"));  // nothing half-written

  const ProcessResult missing = RunKinevis(
      {"calibrate", "scanner-mount", "--scanner", dir + "/nope.yaml", "--views", "1"}, 30s);
  EXPECT_EQ(missing.exit_code, 2);
  EXPECT_THAT(missing.out + missing.err, HasSubstr(dir + "/nope.yaml"));
}

// A real cell has no host-side jog interface for the touches: refused before anything moves.
TEST(WeldMountCliTest, ARealCellIsRefusedWithThePointerToTheDatasetFormat) {
  const std::string dir = TempDir("real");
  const std::string deployment = dir + "/cell.yaml";
  WriteText(deployment,
            "rig: weld-cell\nrobot: robot.yaml\nwelder: {backend: "
            "modbus-tcp:127.0.0.1:1}\nscanner: {source: v4l2:/dev/video0, camera: "
            "builtin:tsai-seed004}\n");
  for (const std::vector<std::string>& args :
       {std::vector<std::string>{"record", "scanner-mount", "--config", deployment, "--out",
                                 dir + "/ds"},
        std::vector<std::string>{"calibrate", "scanner-mount", "--config", deployment}}) {
    const ProcessResult r = RunKinevis(args, 30s);
    EXPECT_EQ(r.exit_code, 2) << r.out << r.err;
    EXPECT_THAT(r.err, HasSubstr("no jog interface"));
    EXPECT_THAT(r.err, HasSubstr("docs/scanner-mount-calibration.md"));
  }
  EXPECT_FALSE(fs::exists(dir + "/ds"));
}

}  // namespace
}  // namespace kinevis
