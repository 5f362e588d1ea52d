// `kinevis servo` and `kinevis sim dynamixel` as a user runs them: the CLI against a simulated
// chain of servos in this process (over a pty), and against the simulator run as its own process.

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <unistd.h>

#include <memory>
#include <string>
#include <vector>

#include "hal/dynamixel/control_table.h"
#include "hal/mock/dynamixel_sim.h"
#include "hal/serial/pty_pair.h"
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

class ServoCliTest : public ::testing::Test {
 protected:
  void StartSim(int protocol, const std::string& model, std::vector<uint8_t> ids) {
    hal::DynamixelSim::Options options;
    options.protocol = protocol;
    for (uint8_t id : ids) options.servos.push_back({id, hal::DxlControlTable::LoadModel(model)});
    sim_ = std::make_unique<hal::DynamixelSim>(pty_.MasterPort(), options);
    sim_->Start();
  }
  std::string Backend() const { return "tty:" + pty_.slave_path() + "@1000000"; }

  hal::PtyPair pty_;
  std::unique_ptr<hal::DynamixelSim> sim_;
};

TEST_F(ServoCliTest, PingPrintsModelAndFirmwareOfEachId) {
  StartSim(1, "mx-12w", {1, 2});
  ProcessResult r = RunKinevis({"servo", Backend(), "--protocol", "1", "--ids", "1,2", "ping"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("id 1: model number 360 (mx-12w), firmware 41"));
  EXPECT_THAT(r.out, HasSubstr("id 2: model number 360 (mx-12w), firmware 41"));
}

TEST_F(ServoCliTest, MissingServoIsAHardwareErrorNamingTheBus) {
  StartSim(2, "xm430-w350", {1});
  ProcessResult r = RunKinevis(
      {"servo", Backend(), "--protocol", "2", "--ids", "1,5", "--timeout-ms", "20", "ping"});
  EXPECT_EQ(r.exit_code, 3);
  EXPECT_THAT(r.out, HasSubstr("id 5: no answer"));
  EXPECT_THAT(r.err, HasSubstr("kinevis servo ping: " + Backend()));
  EXPECT_THAT(r.err, HasSubstr("1 of 2 servos did not answer"));
}

TEST_F(ServoCliTest, MoveReachesThePositionAndReadShowsIt) {
  StartSim(2, "xm430-w350", {3});
  ProcessResult m = RunKinevis({"servo", Backend(), "--ids", "3", "--model", "xm430-w350", "move",
                                "--position", "2.5", "--velocity", "3"});
  ASSERT_EQ(m.exit_code, 0) << m.err;
  EXPECT_THAT(m.out, ContainsRegex("id 3: position 2\\.50[0-9]* rad"));
  EXPECT_NEAR(sim_->Position(3), 2.5, 0.01);
  EXPECT_EQ(sim_->Register(3, "torque_enable"), 1);
  ProcessResult r = RunKinevis(
      {"servo", Backend(), "--ids", "3", "--protocol", "2", "read", "--register", "goal_position"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("torque on"));
  EXPECT_THAT(r.out, ContainsRegex("goal_position = 1630 \\(2\\.50[0-9]* rad\\)"));
  ProcessResult off =
      RunKinevis({"servo", Backend(), "--ids", "3", "--protocol", "2", "torque", "off"});
  ASSERT_EQ(off.exit_code, 0) << off.err;
  EXPECT_EQ(sim_->Register(3, "torque_enable"), 0);
}

TEST_F(ServoCliTest, RebootClearsAnOverload) {
  StartSim(2, "xm430-w350", {1});
  sim_->InjectOverload(1);
  ProcessResult r = RunKinevis({"servo", Backend(), "--protocol", "2", "read"});
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("alarm: overload"));
  ProcessResult b = RunKinevis({"servo", Backend(), "--protocol", "2", "reboot"});
  ASSERT_EQ(b.exit_code, 0) << b.err;
  EXPECT_FALSE(sim_->Overloaded(1));
  ProcessResult p1 = RunKinevis({"servo", Backend(), "--protocol", "1", "reboot"});
  EXPECT_EQ(p1.exit_code, 2);
  EXPECT_THAT(p1.err, HasSubstr("power-cycle"));
}

TEST_F(ServoCliTest, UsageErrorsExitTwo) {
  StartSim(1, "mx-12w", {1});
  EXPECT_EQ(RunKinevis({"servo", Backend(), "--protocol", "3", "ping"}).exit_code, 2);
  EXPECT_EQ(RunKinevis({"servo", Backend(), "ping", "--bogus"}).exit_code, 2);
  ProcessResult m =
      RunKinevis({"servo", Backend(), "--protocol", "2", "--model", "mx-12w", "ping"});
  EXPECT_EQ(m.exit_code, 2);
  EXPECT_THAT(m.err, HasSubstr("--protocol 2"));
  ProcessResult far = RunKinevis({"servo", Backend(), "move", "--position", "7"});
  EXPECT_EQ(far.exit_code, 2);
  EXPECT_THAT(far.err, HasSubstr("outside"));
  EXPECT_EQ(RunKinevis({"servo", Backend(), "--model", "ax-99", "ping"}).exit_code, 2);
}

TEST(ServoSimCliTest, SimulatorProcessServesTheCliUntilSigterm) {
  BackgroundProcess sim({KinevisCliPath(), "sim", "dynamixel", "--protocol", "2", "--ids", "1,2",
                         "--model", "xm430-w350"});
  std::string backend;
  ASSERT_TRUE(sim.ReadLine(&backend, 10s));
  EXPECT_THAT(backend, ContainsRegex("^tty:/dev/pts/[0-9]+@57600$"));
  ProcessResult r = RunKinevis({"servo", backend, "--protocol", "2", "--ids", "1,2", "ping"});
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("id 2: model number 1020 (xm430-w350), firmware 46"));
  EXPECT_EQ(sim.Stop(SIGTERM), 0);
}

TEST(ServoSimCliTest, SimulatorLinkAndBaudAreInTheBackend) {
  const std::string link = ::testing::TempDir() + "/kinevis_dxl_link_" + std::to_string(getpid());
  BackgroundProcess sim({KinevisCliPath(), "sim", "dynamixel", "--protocol", "1", "--link", link,
                         "--baud", "115200"});
  std::string backend;
  ASSERT_TRUE(sim.ReadLine(&backend, 10s));
  EXPECT_EQ(backend, "tty:" + link + "@115200");
  ProcessResult r = RunKinevis({"servo", backend, "--protocol", "1", "ping"});
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(sim.Stop(SIGINT), 0);
}

}  // namespace
}  // namespace kinevis
