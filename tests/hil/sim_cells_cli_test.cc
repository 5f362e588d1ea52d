// Two processes, as on the bench: `kinevis sim world weld-cell|soccer` is the cell, and the
// ordinary host commands `kinevis weld-robot BACKEND ...` and `kinevis camera grab net:...` in
// other processes drive the robot over Modbus TCP and read the cameras' frames over the network.

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <csignal>
#include <filesystem>
#include <string>
#include <vector>

#include "tests/utilities/subprocess.h"

namespace kinevis {
namespace {

using testing::RunKinevis;

using namespace std::chrono_literals;
using testing::BackgroundProcess;
using ::testing::ContainsRegex;
using ::testing::HasSubstr;
using testing::KinevisCliPath;
using testing::ProcessResult;

std::string ConfigPath(const std::string& name) {
  return std::string(KINEVIS_SOURCE_DIR) + "/config/" + name;
}

TEST(SimCellsCliTest, AHostProcessMovesTheWeldRobotAndAnotherGrabsTheScannerFrames) {
  BackgroundProcess world({KinevisCliPath(), "sim", "world", "weld-cell", "--config",
                           ConfigPath("weld-cell-sim.yaml")});
  std::string backend, camera_line;
  ASSERT_TRUE(world.ReadLine(&backend, 30s));
  ASSERT_THAT(backend, ContainsRegex("^modbus-tcp:127\\.0\\.0\\.1:[0-9]+$"));
  ASSERT_TRUE(world.ReadLine(&camera_line, 30s)) << "no camera line after " << backend;
  ASSERT_THAT(camera_line,
              ContainsRegex("^net:127\\.0\\.0\\.1:[0-9]+,timeout_ms=[0-9]+ weld-scanner$"));
  const std::string source = camera_line.substr(0, camera_line.find(' '));

  const ProcessResult before = RunKinevis({"weld-robot", backend, "status"});
  ASSERT_EQ(before.exit_code, 0) << before.err;
  EXPECT_THAT(before.out, HasSubstr("pz3 200.000 mm"));  // the config's initial joints

  const ProcessResult moved =
      RunKinevis({"weld-robot", backend, "move", "--joints", "3,0,220,-2,4", "--duration", "0.5"});
  ASSERT_EQ(moved.exit_code, 0) << moved.out << moved.err;
  const ProcessResult after = RunKinevis({"weld-robot", backend, "status"});
  ASSERT_EQ(after.exit_code, 0) << after.err;
  EXPECT_THAT(after.out,
              HasSubstr("joints: θ1 3.000°, θ2 0.000°, pz3 220.000 mm, θ4 -2.000°, θ5 4.000°"));

  const std::string dir = "/tmp/kinevis_cells_frames_" + std::to_string(::getpid());
  const ProcessResult grab =
      RunKinevis({"camera", "grab", source, "-n", "1", "--timeout-ms", "20000", "-o", dir});
  ASSERT_EQ(grab.exit_code, 0) << grab.out << grab.err;
  EXPECT_THAT(grab.out, HasSubstr("# 1 frames"));
  EXPECT_TRUE(std::filesystem::exists(dir + "/frame_000001.png")) << grab.out;
  const ProcessResult info = RunKinevis({"camera", "info", source});
  EXPECT_EQ(info.exit_code, 0) << info.err;
  EXPECT_THAT(info.out, HasSubstr("1616x1216"));
  EXPECT_EQ(world.Stop(SIGTERM), 0);
  std::filesystem::remove_all(dir);
}

TEST(SimCellsCliTest, ASecondProcessGrabsTheSoccerRobotsCameraFrames) {
  BackgroundProcess world(
      {KinevisCliPath(), "sim", "world", "soccer", "--config", ConfigPath("soccer-sim.yaml")});
  std::string camera_line;
  ASSERT_TRUE(world.ReadLine(&camera_line, 30s));
  ASSERT_THAT(camera_line,
              ContainsRegex("^net:127\\.0\\.0\\.1:[0-9]+,timeout_ms=[0-9]+ soccer-omni$"));
  const std::string source = camera_line.substr(0, camera_line.find(' '));
  const ProcessResult grab = RunKinevis({"camera", "grab", source, "-n", "3"});
  ASSERT_EQ(grab.exit_code, 0) << grab.out << grab.err;
  EXPECT_THAT(grab.out, HasSubstr("# 3 frames"));
  const ProcessResult info = RunKinevis({"camera", "info", source});
  EXPECT_EQ(info.exit_code, 0) << info.err;
  EXPECT_THAT(info.out, HasSubstr("640x480"));
  EXPECT_EQ(world.Stop(SIGTERM), 0);
}

TEST(SimCellsCliTest, ABadConfigIsAUsageErrorNamingTheKey) {
  const std::string path = "/tmp/kinevis_cells_bad_" + std::to_string(::getpid()) + ".yaml";
  {
    FILE* f = std::fopen(path.c_str(), "w");
    ASSERT_NE(f, nullptr);
    std::fputs("world: weld-cell\nmodbus: {unit: 0}\n", f);
    std::fclose(f);
  }
  const ProcessResult r = RunKinevis({"sim", "world", "weld-cell", "--config", path});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.err, HasSubstr("modbus.unit: must be in 1..247, got 0"));
  std::filesystem::remove(path);
  EXPECT_EQ(RunKinevis({"sim", "world", "soccer", "--config", "/nonexistent.yaml"}).exit_code, 2);
}

}  // namespace
}  // namespace kinevis
