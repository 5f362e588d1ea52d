// The weld-repair chain's jobs in this process on the simulated cell (rigs/weld/weld_repair_
// jobs.h): scan → plan → weld, asserting on the reports against what was written and against the
// world's own truth; a stop request mid-weld ends with the robot stopped and the arc off.

#include "rigs/weld/weld_repair_jobs.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <string>

#include "sim/weld_cell_world.h"
#include "vision/cloud/cloud_sidecar.h"

namespace kinevis::rigs {
namespace {

namespace fs = std::filesystem;

std::string TempDir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() /
                       ("kinevis_weld_repair_jobs_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir.string();
}

TEST(WeldRepairJobs, ScanPlanAndWeldTheDefaultBladeReportWhatTheyDid) {
  const std::string dir = TempDir("chain");
  WeldRig rig(WeldRigOptions{});
  ASSERT_TRUE(rig.simulated());

  ScanJobOptions scan;
  scan.lines = 100;
  scan.out = dir + "/map.ply";
  const ScanJobReport s = ScanWorkpiece(&rig, scan);
  EXPECT_EQ(s.frames.frames, 100);
  ASSERT_FALSE(s.frames.lines.empty()) << s.frames.first_failure;
  vision::cloud::CloudSidecar sidecar;
  const vision::cloud::PointCloud cloud = vision::cloud::ReadCloud(s.sidecar_path, &sidecar);
  EXPECT_EQ(cloud.size(), s.points);
  EXPECT_EQ(sidecar.frame, "0");
  EXPECT_EQ(sidecar.scan_lines, s.frames.lines.size());
  EXPECT_EQ(s.sidecar_path, dir + "/map.yaml");
  EXPECT_TRUE(fs::exists(s.ply_path));
  EXPECT_LT(s.frames.max_angle_deviation, 1e-3);  // eq. 11 reads the stepper's angle back
  // The nominal mount's clamping error (~1 mm in the default cell) shows against the true blade.
  ASSERT_TRUE(s.has_truth);
  EXPECT_GT(s.truth_rms_error, 0.3e-3);
  EXPECT_LT(s.truth_rms_error, 3e-3);

  control::WeldPlanOptions plan_options;
  plan_options.grid_cell = 2e-3;
  const WeldPathRun p = PlanWeldPath(scan.out, plan_options, dir + "/path.yaml");
  // The default blade's pits (sim::DefaultBlade), each a region to repair.
  EXPECT_GE(p.plan.summary.regions, static_cast<int>(sim::DefaultBlade().pits.size()));
  EXPECT_EQ(p.plan.summary.unreachable_points, 0);
  EXPECT_TRUE(fs::exists(p.top));
  EXPECT_TRUE(fs::exists(p.section));
  ASSERT_FALSE(p.plan.trajectory.empty());

  const WeldRunReport w = RunWeldPlan(&rig, p.plan, WeldRunOptions{});
  ASSERT_EQ(w.outcome, WeldRunOutcome::kCompleted) << w.message;
  EXPECT_EQ(w.stream.executed, p.plan.trajectory.size());
  EXPECT_EQ(w.executed.size(), p.plan.trajectory.size());
  EXPECT_TRUE(w.arc_off_error.empty()) << w.arc_off_error;
  hal::WeldRobotState state;
  ASSERT_FALSE(rig.robot().ReadState(&state));
  EXPECT_FALSE(state.arc_on);  // the arc is off after the run
  EXPECT_FALSE(state.arc_enabled);
  ASSERT_TRUE(w.has_truth);
  // The executed torch (true robot) against the plan's surface: the robot's D–H error only.
  EXPECT_LT(w.planned_surface.mean_abs_error, 0.5e-3);
  EXPECT_GT(w.true_surface_points, 0);
  EXPECT_LT(w.true_surface_mean_abs, 5e-3);
}

TEST(WeldRepairJobs, AStopRequestMidWeldStopsTheRobotWithTheArcOff) {
  const std::string dir = TempDir("stop");
  WeldRig rig(WeldRigOptions{});
  ScanJobOptions scan;
  scan.lines = 60;
  scan.out = dir + "/map.ply";
  ScanWorkpiece(&rig, scan);
  control::WeldPlanOptions plan_options;
  plan_options.grid_cell = 2e-3;
  const WeldPathRun p = PlanWeldPath(scan.out, plan_options, dir + "/path.yaml");
  ASSERT_GT(p.plan.trajectory.size(), 10u);

  WeldRunOptions o;
  int polls = 0;
  o.stop_requested = [&] { return ++polls > 20; };
  const WeldRunReport w = RunWeldPlan(&rig, p.plan, o);
  EXPECT_EQ(w.outcome, WeldRunOutcome::kCancelled) << ToString(w.outcome) << ": " << w.message;
  EXPECT_LT(w.stream.executed, p.plan.trajectory.size());
  EXPECT_TRUE(w.stream.safe_state_confirmed);
  EXPECT_FALSE(w.has_truth);
  hal::WeldRobotState state;
  ASSERT_FALSE(rig.robot().ReadState(&state));
  EXPECT_FALSE(state.arc_on);
  EXPECT_FALSE(state.arc_enabled);
}

TEST(WeldRepairJobs, AnEmptyPlanMovesNothing) {
  WeldRig rig(WeldRigOptions{});
  const robots::Vector5d before = rig.Joints();
  const WeldRunReport w = RunWeldPlan(&rig, control::WeldPlan{}, WeldRunOptions{});
  EXPECT_EQ(w.outcome, WeldRunOutcome::kNoTrajectory);
  EXPECT_THAT(w.message, ::testing::HasSubstr("no trajectory"));
  EXPECT_LT((rig.Joints() - before).norm(), 1e-9);
}

}  // namespace
}  // namespace kinevis::rigs
