// Two processes, as on the bench: `kinevis sim world hexapod|diamond` is the machine, and the
// ordinary host command `kinevis drive BACKEND ...` in another process moves it through the
// transport real hardware uses (an slcan USB-CAN adapter on a pty; an RS485 line on a pty).

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <csignal>
#include <filesystem>
#include <regex>
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

// The "position X rad" of every line of `kinevis drive ... status`.
std::vector<double> Positions(const std::string& out) {
  std::vector<double> positions;
  const std::regex re("position (-?[0-9.]+) rad");
  for (auto it = std::sregex_iterator(out.begin(), out.end(), re); it != std::sregex_iterator();
       ++it) {
    positions.push_back(std::stod((*it)[1].str()));
  }
  return positions;
}

TEST(SimWorldCliTest, AHostProcessMovesTheSimulatedHexapodThroughTheSlcanAdapter) {
  BackgroundProcess world({KinevisCliPath(), "sim", "world", "hexapod"});
  std::string backend;
  ASSERT_TRUE(world.ReadLine(&backend, 20s));
  ASSERT_THAT(backend, ContainsRegex("^slcan:/dev/pts/[0-9]+@115200,bitrate=1000000$"));
  const std::vector<std::string> drive = {
      "drive", backend, "--nodes", "1,2,3,4,5,6", "--counts-per-rad", "1000000"};

  // Where the legs are: the true readings at the home pose (s_j = q_j - q_j0, about 0.07 m).
  std::vector<std::string> status = drive;
  status.push_back("status");
  ProcessResult before = RunKinevis(status);
  ASSERT_EQ(before.exit_code, 0) << before.err;
  const std::vector<double> s0 = Positions(before.out);
  ASSERT_EQ(s0.size(), 6u) << before.out;
  for (double s : s0) {
    EXPECT_GT(s, 0.02);
    EXPECT_LT(s, 0.15);
  }

  // Every leg to 0.10 m: the platform rises (a feasible, non-singular configuration).
  std::vector<std::string> move = drive;
  for (const char* a : {"move", "--position", "0.1", "--duration", "1.0", "--tolerance", "2e-5"}) {
    move.push_back(a);
  }
  ProcessResult moved = RunKinevis(move);
  EXPECT_EQ(moved.exit_code, 0) << moved.out << moved.err;

  ProcessResult after = RunKinevis(status);
  ASSERT_EQ(after.exit_code, 0) << after.err;
  const std::vector<double> s1 = Positions(after.out);
  ASSERT_EQ(s1.size(), 6u) << after.out;
  for (double s : s1) EXPECT_NEAR(s, 0.1, 2e-5);
  EXPECT_EQ(world.Stop(SIGTERM), 0);
}

TEST(SimWorldCliTest, AHostProcessMovesTheSimulatedDiamondOverRs485) {
  BackgroundProcess world({KinevisCliPath(), "sim", "world", "diamond"});
  std::string backend;
  ASSERT_TRUE(world.ReadLine(&backend, 20s));
  ASSERT_THAT(backend, ContainsRegex("^modbus-rtu:/dev/pts/[0-9]+@3000000,8E1$"));
  const std::vector<std::string> drive = {
      "drive", backend + ",timeout_ms=200", "--nodes",
      "1,2",   "--counts-per-rad",          "20860.756700940907"};
  // Joint 1 only, from its home reading (about 2.75 rad) to 2.0 rad: the limbs stay apart and
  // the mechanism closes (moving both to one angle would make the limbs collide and jam).
  const std::vector<std::string> move = {"drive",
                                         backend + ",timeout_ms=200",
                                         "--nodes",
                                         "1",
                                         "--counts-per-rad",
                                         "20860.756700940907",
                                         "move",
                                         "--position",
                                         "2.0",
                                         "--duration",
                                         "1.0",
                                         "--tolerance",
                                         "1e-3"};
  ProcessResult moved = RunKinevis(move);
  EXPECT_EQ(moved.exit_code, 0) << moved.out << moved.err;
  std::vector<std::string> status = drive;
  status.push_back("status");
  ProcessResult after = RunKinevis(status);
  ASSERT_EQ(after.exit_code, 0) << after.err;
  const std::vector<double> q = Positions(after.out);
  ASSERT_EQ(q.size(), 2u) << after.out;
  EXPECT_NEAR(q[0], 2.0, 1e-3);
  EXPECT_EQ(world.Stop(SIGTERM), 0);
}

TEST(SimWorldCliTest, ASecondProcessGrabsTheWorldsCameraFramesOverTheNetwork) {
  const std::string root = KINEVIS_SOURCE_DIR;
  BackgroundProcess world(
      {KinevisCliPath(), "sim", "world", "hexapod", "--config", root + "/config/hexapod-sim.yaml"});
  std::string backend, camera_line;
  ASSERT_TRUE(world.ReadLine(&backend, 20s));
  ASSERT_TRUE(world.ReadLine(&camera_line, 20s)) << "no camera line after " << backend;
  EXPECT_THAT(camera_line, ContainsRegex("^net:127\\.0\\.0\\.1:[0-9]+ hexapod-"));
  const std::string source = camera_line.substr(0, camera_line.find(' '));
  const std::string dir = "/tmp/kinevis_world_frames_" + std::to_string(::getpid());
  const ProcessResult grab = RunKinevis({"camera", "grab", source, "-n", "2", "-o", dir});
  ASSERT_EQ(grab.exit_code, 0) << grab.out << grab.err;
  EXPECT_THAT(grab.out, HasSubstr("# 2 frames"));
  const ProcessResult info = RunKinevis({"camera", "info", source});
  EXPECT_EQ(info.exit_code, 0) << info.err;
  EXPECT_EQ(world.Stop(SIGTERM), 0);
  std::filesystem::remove_all(dir);
}

TEST(SimWorldCliTest, ABadConfigIsAUsageError) {
  ProcessResult r = RunKinevis({"sim", "world", "hexapod", "--config", "/nonexistent.yaml"});
  EXPECT_EQ(r.exit_code, 2);
}

}  // namespace
}  // namespace kinevis
