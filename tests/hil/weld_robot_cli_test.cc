// `kinevis weld-robot ...` against `kinevis sim weld-robot` running as its own process: the
// program a technician runs for bring-up, over loopback Modbus TCP and over RTU on a pty, with
// the exit codes and messages of docs/cli.md.

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <csignal>
#include <cstdio>
#include <fstream>
#include <iterator>
#include <memory>
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

// The simulator as a process; backend() is its first line of output.
class SimProcess {
 public:
  explicit SimProcess(std::vector<std::string> args) {
    args.insert(args.begin(), {KinevisCliPath(), "sim", "weld-robot"});
    process_ = std::make_unique<BackgroundProcess>(args);
    EXPECT_TRUE(process_->ReadLine(&backend_, 20s)) << "the simulator printed no backend";
  }
  const std::string& backend() const { return backend_; }
  int Stop() { return process_->Stop(SIGTERM); }

 private:
  std::unique_ptr<BackgroundProcess> process_;
  std::string backend_;
};

std::string WriteFile(const std::string& name, const std::string& text) {
  const std::string path = "/tmp/kinevis_weld_cli_" + std::to_string(::getpid()) + "_" + name;
  std::ofstream(path) << text;
  return path;
}

TEST(WeldRobotCliTest, SimPrintsItsBackendAndExitsZeroOnSigterm) {
  SimProcess sim({"--listen", "127.0.0.1:0", "--buffer", "8"});
  EXPECT_THAT(sim.backend(), ContainsRegex("^modbus-tcp:127\\.0\\.0\\.1:[0-9]+$"));
  ProcessResult status = RunKinevis({"weld-robot", sim.backend(), "status"});
  ASSERT_EQ(status.exit_code, 0) << status.err;
  EXPECT_THAT(status.out, HasSubstr("motion: IDLE"));
  EXPECT_THAT(status.out, HasSubstr("alarm: NONE (0)"));
  EXPECT_THAT(status.out, HasSubstr("buffer: 0/8 segments"));
  EXPECT_THAT(status.out, HasSubstr("joints: θ1 0.000°, θ2 0.000°, pz3 50.000 mm"));
  EXPECT_EQ(sim.Stop(), 0);
}

TEST(WeldRobotCliTest, SimEnforcesTheLimitsOfARobotDescription) {
  // The shipped description with θ1 limited to ±30°.
  std::ifstream in(std::string(KINEVIS_SOURCE_DIR) + "/robots/weld5/weld5.yaml");
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const std::string from = "limits: {min_deg: -170, max_deg: 170, speed_deg_s: 90}";
  ASSERT_NE(text.find(from), std::string::npos);
  text.replace(text.find(from), from.size(),
               "limits: {min_deg: -30, max_deg: 30, speed_deg_s: 90}");
  const std::string robot = WriteFile("narrow.yaml", text);
  SimProcess sim({"--robot", robot});
  ProcessResult inside = RunKinevis(
      {"weld-robot", sim.backend(), "move", "--joints", "20,0,50,0,0", "--duration", "0.5"});
  EXPECT_EQ(inside.exit_code, 0) << inside.err;
  ProcessResult outside = RunKinevis(
      {"weld-robot", sim.backend(), "move", "--joints", "40,0,50,0,0", "--duration", "1"});
  EXPECT_NE(outside.exit_code, 0);
  EXPECT_THAT(outside.out + outside.err, HasSubstr("θ1"));
  EXPECT_EQ(sim.Stop(), 0);
  std::remove(robot.c_str());
}

TEST(WeldRobotCliTest, MoveStreamArcStopAndReset) {
  SimProcess sim({});
  const std::string& b = sim.backend();

  ProcessResult move =
      RunKinevis({"weld-robot", b, "move", "--joints", "10,5,60,0,-5", "--duration", "0.3"});
  ASSERT_EQ(move.exit_code, 0) << move.err;
  EXPECT_THAT(move.out, HasSubstr("done: 1 segments executed"));
  EXPECT_THAT(move.out, HasSubstr("θ1 10.000°, θ2 5.000°, pz3 60.000 mm, θ4 0.000°, θ5 -5.000°"));

  ProcessResult arc = RunKinevis(
      {"weld-robot", b, "arc", "on", "--current", "150", "--voltage", "22.5", "--wire-feed", "9"});
  ASSERT_EQ(arc.exit_code, 0) << arc.err;
  ProcessResult status = RunKinevis({"weld-robot", b, "status"});
  EXPECT_THAT(status.out, HasSubstr("arc: enabled, off"));
  EXPECT_THAT(status.out, HasSubstr("weld: 150.0 A, 22.5 V, wire feed 9.00 m/min"));

  // 40 segments of 20 ms from where the robot stands; the CSV mixes units by column name.
  std::string csv =
      "# test bead\nduration_ms,theta1_deg,theta2_rad,pz3_mm,theta4_deg,theta5_deg,arc\n";
  for (int i = 1; i <= 40; ++i) {
    csv += "20," + std::to_string(10 + 0.05 * i) + ",0.0872664626," + std::to_string(60 + 0.1 * i) +
           ",0,-5," + (i > 5 ? "1" : "0") + "\n";
  }
  const std::string path = WriteFile("bead.csv", csv);
  ProcessResult stream = RunKinevis({"weld-robot", b, "stream", path});
  ASSERT_EQ(stream.exit_code, 0) << stream.err;
  EXPECT_THAT(stream.out, HasSubstr("progress: 40/40 executed"));
  EXPECT_THAT(stream.out, HasSubstr("done: 40 segments executed"));
  EXPECT_THAT(stream.out, HasSubstr("θ1 12.000°, θ2 5.000°, pz3 64.000 mm"));

  ProcessResult stop = RunKinevis({"weld-robot", b, "stop"});
  ASSERT_EQ(stop.exit_code, 0) << stop.err;
  status = RunKinevis({"weld-robot", b, "status"});
  EXPECT_THAT(status.out, HasSubstr("arc: disabled, off"));
  EXPECT_THAT(status.out, HasSubstr("sequence: last accepted 41, last completed 41"));

  // Unchecked, the robot judges the target itself: an alarm, exit 3, named with the device.
  ProcessResult bad = RunKinevis(
      {"weld-robot", b, "move", "--joints", "10,5,60,0,-130", "--duration", "60", "--no-check"});
  EXPECT_EQ(bad.exit_code, 3);
  EXPECT_THAT(bad.err, HasSubstr("kinevis weld-robot move: weld-robot (" + b + ")"));
  EXPECT_THAT(bad.err, HasSubstr("alarm TARGET OUT OF RANGE (code 1)"));
  status = RunKinevis({"weld-robot", b, "status"});
  EXPECT_THAT(status.out, HasSubstr("motion: ALARM"));
  EXPECT_THAT(status.out, HasSubstr("alarm: TARGET OUT OF RANGE (1)"));
  ProcessResult refused = RunKinevis({"weld-robot", b, "arc", "on"});
  EXPECT_EQ(refused.exit_code, 3);
  EXPECT_THAT(refused.err, HasSubstr("reset`"));
  ProcessResult reset = RunKinevis({"weld-robot", b, "reset"});
  ASSERT_EQ(reset.exit_code, 0) << reset.err;
  status = RunKinevis({"weld-robot", b, "status"});
  EXPECT_THAT(status.out, HasSubstr("motion: IDLE"));
  EXPECT_EQ(sim.Stop(), 0);
}

TEST(WeldRobotCliTest, BadInputExitsTwoNamingWhatIsWrong) {
  SimProcess sim({});
  const std::string& b = sim.backend();
  ProcessResult range =
      RunKinevis({"weld-robot", b, "move", "--joints", "175,0,50,0,0", "--duration", "10"});
  EXPECT_EQ(range.exit_code, 2);
  EXPECT_THAT(range.err, HasSubstr("joint θ1 target 175.000° is outside its limits"));
  ProcessResult count =
      RunKinevis({"weld-robot", b, "move", "--joints", "1,2,3", "--duration", "1"});
  EXPECT_EQ(count.exit_code, 2);
  const std::string path = WriteFile("bad.csv",
                                     "duration_s,theta1_deg,theta2_deg,pz3_mm,"
                                     "theta4_deg,theta5_deg,arc\n1,0,0,50,0,0,0\n"
                                     "1,0,zero,50,0,0,0\n");
  ProcessResult csv = RunKinevis({"weld-robot", b, "stream", path});
  EXPECT_EQ(csv.exit_code, 2);
  EXPECT_THAT(csv.err, HasSubstr("\"" + path + "\" line 3: field 3 \"zero\" is not a number"));
  const std::string columns = WriteFile("columns.csv", "duration_s,theta1_deg\n1,0\n");
  ProcessResult header = RunKinevis({"weld-robot", b, "stream", columns});
  EXPECT_EQ(header.exit_code, 2);
  EXPECT_THAT(header.err, HasSubstr("the header needs"));
  EXPECT_EQ(RunKinevis({"sim", "weld-robot", "--listen", "nowhere"}).exit_code, 2);
  std::remove(path.c_str());
  std::remove(columns.c_str());
}

TEST(WeldRobotCliTest, AbsentRobotIsAHardwareError) {
  // A port nothing listens on: connection refused, exit 3, within the client's timeout.
  ProcessResult r = RunKinevis({"weld-robot", "modbus-tcp:127.0.0.1:1,timeout_ms=200", "status"});
  EXPECT_FALSE(r.timed_out);
  EXPECT_EQ(r.exit_code, 3);
  EXPECT_THAT(r.err, HasSubstr("127.0.0.1:1"));
}

TEST(WeldRobotCliTest, RtuSimulatorOnAPtyWithALink) {
  const std::string link = "/tmp/kinevis_weld_cli_" + std::to_string(::getpid()) + "_tty";
  SimProcess sim({"--rtu", "--link", link});
  EXPECT_EQ(sim.backend(), "modbus-rtu:" + link + "@115200,8E1");
  ProcessResult move = RunKinevis(
      {"weld-robot", sim.backend(), "move", "--joints", "0,-3,55,2,0", "--duration", "0.2"});
  ASSERT_EQ(move.exit_code, 0) << move.err;
  EXPECT_THAT(move.out, HasSubstr("θ1 0.000°, θ2 -3.000°, pz3 55.000 mm, θ4 2.000°"));
  EXPECT_EQ(sim.Stop(), 0);
  EXPECT_NE(::access(link.c_str(), F_OK), 0);  // the link is removed with the simulator
}

}  // namespace
}  // namespace kinevis
