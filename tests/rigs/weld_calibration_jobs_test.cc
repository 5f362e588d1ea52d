// The weld cell's mount jobs in this process on the simulated cell (rigs/weld/weld_calibration_
// jobs.h): the report says what was written (checked against the dataset read back), the
// calibration's truth comparison is the world's own truth, and a stop request ends the recording.

#include "rigs/weld/weld_calibration_jobs.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>

#include "calibration/weld_mount/mount_dataset.h"
#include "common/units.h"
#include "sim/weld_cell_world.h"

namespace kinevis::rigs {
namespace {

namespace fs = std::filesystem;

std::string TempDir(const std::string& name) {
  const fs::path dir =
      fs::temp_directory_path() / ("kinevis_weld_jobs_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir.string();
}

// An exact arm with the block off the board's centre and turned (the truth the job must find).
std::string OffsetBlockConfig(const std::string& dir) {
  const std::string path = dir + "/offset_block.yaml";
  std::ofstream(path) << "world: weld-cell\n"
                         "truth: {dh_length_sigma_mm: 0, dh_angle_sigma_deg: 0}\n"
                         "workpiece:\n"
                         "  kind: board\n"
                         "  gauge_block: {present: true, centre_mm: [8, -6], heading_deg: 3, "
                         "size_mm: [100, 50, 10]}\n";
  return path;
}

TEST(WeldMountJobs, TheReportSaysWhatTheDatasetHoldsAndTheTruthIsTheWorlds) {
  const std::string dir = TempDir("record");
  const std::string config = OffsetBlockConfig(dir);
  const std::unique_ptr<WeldRig> rig = OpenGaugeBlockRig(config);
  ASSERT_TRUE(rig->simulated());
  MountRecordOptions o;
  o.out = dir + "/dataset";
  o.views = 3;
  const MountRecordReport r = RecordMountDataset(rig.get(), o);

  const calibration::MountDataset d = calibration::ReadMountDataset(o.out);
  EXPECT_EQ(r.touches, static_cast<int>(d.touches.size()));
  EXPECT_EQ(r.touches + static_cast<int>(r.unreachable.size()), 14);  // the plan's touches
  EXPECT_GE(r.touches, 10);
  EXPECT_EQ(r.scans, static_cast<int>(d.scans.size()));
  size_t points = 0;
  for (const calibration::MountDatasetScan& s : d.scans) {
    points += calibration::ReadMountScanPoints(d, s).size();
  }
  EXPECT_EQ(r.points, static_cast<int>(points));
  // Eq. (11) read at every image where the stripes cross, close to the commanded angle
  // (1e-3 of cot θ_y is ~1.6 mm of depth at 0.4 m).
  EXPECT_GE(r.eq11_deviation.size(), 7u);
  EXPECT_LE(r.eq11_deviation.size(), 9u);  // 3 views x 3 angles
  for (const double e : r.eq11_deviation) EXPECT_LT(std::abs(e), 5e-3);

  // The block's true pose: 8 mm, −6 mm on the board, turned by 3°, on top of its 5 mm half
  // height (the config above), in the base frame through the board's pose.
  const sim::WeldCellWorldConfig truth = sim::LoadWeldCellWorldConfig(config);
  const Eigen::Vector3d centre_0 = truth.X_0S * Eigen::Vector3d(0.008, -0.006, 0.005);
  EXPECT_LT((TrueGaugeBlockPose(*rig).translation() - centre_0).norm(), 1e-9);

  MountCalibrateOptions c;
  c.out = dir + "/mount.yaml";
  const MountCalibrationRun run = CalibrateScannerMountFromDataset(o.out, c, rig.get());
  ASSERT_TRUE(run.calibrated);
  EXPECT_TRUE(run.summary.ok()) << ToString(run.summary.status);
  EXPECT_EQ(run.fixed_left_out, 3u);  // one fixed-laser scan per view, left out by default
  ASSERT_TRUE(run.has_truth);
  const Eigen::Vector3d error = run.summary.X_5C.translation() - truth.X_5C.translation();
  EXPECT_LT((run.truth.position_error - error).norm(), 1e-12);
  EXPECT_NEAR(run.truth.cad_position_error,
              (truth.X_5C_nominal.translation() - truth.X_5C.translation()).norm(), 1e-12);
  EXPECT_GT(run.truth.cad_position_error, 1e-3);  // the CAD mount was off: it had to move
  EXPECT_LT(error.norm(), 0.3e-3);                // the CLI test measures ~0.04 mm with 4 views
  EXPECT_TRUE(fs::exists(c.out));
}

TEST(WeldMountJobs, AStopRequestEndsTheRecording) {
  const std::string dir = TempDir("stop");
  const std::unique_ptr<WeldRig> rig = OpenGaugeBlockRig("");
  MountRecordOptions o;
  o.out = dir + "/dataset";
  o.views = 1;
  int polls = 0;
  o.stop_requested = [&] { return ++polls > 2; };
  try {
    RecordMountDataset(rig.get(), o);
    ADD_FAILURE() << "recorded despite the stop request";
  } catch (const std::runtime_error& e) {
    EXPECT_THAT(e.what(), ::testing::HasSubstr("interrupted"));
  }
  EXPECT_EQ(polls, 3);
}

TEST(WeldMountJobs, ADeploymentFileIsRefusedBeforeAnythingConnects) {
  const std::string dir = TempDir("real");
  const std::string path = dir + "/cell.yaml";
  std::ofstream(path) << "rig: weld-cell\nrobot: {port: tcp:127.0.0.1:1}\n";
  try {
    OpenGaugeBlockRig(path);
    ADD_FAILURE() << "a real cell was opened";
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), ::testing::HasSubstr("no jog interface"));
  }
}

}  // namespace
}  // namespace kinevis::rigs
