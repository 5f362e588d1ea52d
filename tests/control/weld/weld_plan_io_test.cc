#include "control/weld/weld_plan_io.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <sstream>

#include "tests/control/weld/synthetic_blade.h"

namespace kinevis::control {
namespace {

using ::testing::HasSubstr;

const WeldPlan& Plan() {
  static const WeldPlan plan = [] {
    testing::SyntheticBlade blade = testing::DefaultTestBlade();
    blade.spacing = 0.4e-3;
    return PlanWeldRepair(blade.Make(),
                          robots::Weld5Model::Seed(robots::Weld5TorchTransform(0.025, 0.25, 0.0)));
  }();
  return plan;
}

std::string TempPath(const std::string& name) {
  return (std::filesystem::temp_directory_path() /
          ("weld_plan_io_test_" + std::to_string(::getpid()) + "_" + name))
      .string();
}

TEST(WeldPlanIo, RoundTrip) {
  const WeldPlan& plan = Plan();
  ASSERT_EQ(plan.summary.status, WeldPlanStatus::kPlanned);
  const std::string path = TempPath("plan.yaml");
  WriteWeldPlan(path, plan, {"2024-01-01T00:00:00Z", "synthetic", ""});
  const WeldPlanFile f = ReadWeldPlan(path);
  const WeldPlan& r = f.plan;
  EXPECT_EQ(f.metadata.source, "synthetic");
  EXPECT_EQ(r.summary.status, plan.summary.status);
  EXPECT_EQ(r.summary.beads, plan.summary.beads);
  EXPECT_NEAR(r.summary.coverage_executable, 1.0, 1e-12);
  EXPECT_NEAR(r.options.bead_width, plan.options.bead_width, 1e-12);
  EXPECT_NEAR(r.options.ik.max_tilt, plan.options.ik.max_tilt, 1e-12);
  ASSERT_EQ(r.trajectory.size(), plan.trajectory.size());
  for (size_t k = 0; k < plan.trajectory.size(); ++k) {
    for (int i = 0; i < 5; ++i) {
      EXPECT_NEAR(r.trajectory[k].joints[i], plan.trajectory[k].joints[i], 1e-9);
    }
    EXPECT_NEAR(r.trajectory[k].duration, plan.trajectory[k].duration, 1e-12);
    EXPECT_EQ(r.trajectory[k].arc_on, plan.trajectory[k].arc_on);
    EXPECT_EQ(r.trajectory_source[k].point, plan.trajectory_source[k].point);
  }
  ASSERT_EQ(r.regions.size(), plan.regions.size());
  const WeldPoint& a = plan.regions[0].layers[0].beads[0].points[3];
  const WeldPoint& b = r.regions[0].layers[0].beads[0].points[3];
  EXPECT_LT((a.p_0T - b.p_0T).norm(), 1e-9);
  EXPECT_LT((a.p_0S - b.p_0S).norm(), 1e-9);
  EXPECT_LT((a.u_0T - b.u_0T).norm(), 1e-9);
  EXPECT_EQ(a.kind, b.kind);
  EXPECT_NEAR(a.tilt, b.tilt, 1e-9);
  // The reference surface comes back: the same heights.
  for (double u : {-0.02, 0.0, 0.03}) {
    EXPECT_NEAR(r.reference.surface.Height(u, 0.01), plan.reference.surface.Height(u, 0.01), 1e-9);
  }
  // So the stand-off comparison works from the file alone.
  std::vector<ExecutedTorchPose> none;
  EXPECT_TRUE(CompareStandOff(r, none).samples.empty());
  std::filesystem::remove(path);
}

TEST(WeldPlanIo, BadFileNamesFileAndKeys) {
  const std::string path = TempPath("bad.yaml");
  WriteWeldPlan(path, Plan());
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  std::string text = ss.str();
  const auto at = text.find("bead_width_mm:");
  ASSERT_NE(at, std::string::npos);
  text.replace(at, text.find('\n', at) - at, "bead_width_mm: wide");
  const auto lh = text.find("  layer_height_mm:");
  text.erase(lh, text.find('\n', lh) - lh + 1);
  std::ofstream(path) << text;
  try {
    ReadWeldPlan(path);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr(path));
    EXPECT_THAT(e.what(), HasSubstr("options.bead_width_mm: bad value 'wide'"));
    EXPECT_THAT(e.what(), HasSubstr("options.layer_height_mm: missing"));
  }
  EXPECT_THROW(ReadWeldPlan(TempPath("does-not-exist.yaml")), std::runtime_error);
  std::filesystem::remove(path);
}

TEST(WeldPlanIo, ImagesAreWritten) {
  const WeldPlan& plan = Plan();
  const std::string top = TempPath("top.png"), section = TempPath("section.png");
  WriteWeldPlanTopView(top, plan);
  WriteWeldPlanSection(section, plan, 0);
  const cv::Mat t = cv::imread(top), s = cv::imread(section);
  ASSERT_FALSE(t.empty());
  ASSERT_FALSE(s.empty());
  const int scale = std::max(1, 1000 / std::max(plan.grid.nu, plan.grid.nv));
  EXPECT_EQ(t.cols, plan.grid.nu * scale);
  EXPECT_EQ(t.rows, plan.grid.nv * scale);
  EXPECT_THROW(WriteWeldPlanSection(section, plan, 99), std::invalid_argument);
  EXPECT_THROW(WriteWeldPlanTopView("/nonexistent-dir/top.png", plan), std::runtime_error);
  WeldPlan no_grid;
  EXPECT_THROW(WriteWeldPlanTopView(top, no_grid), std::invalid_argument);
  std::filesystem::remove(top);
  std::filesystem::remove(section);
}

}  // namespace
}  // namespace kinevis::control
