#include "sim/diamond_world.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include "hal/drive/rs485_drive.h"

namespace kinevis::sim {
namespace {

using namespace std::chrono_literals;
using ::testing::ContainsRegex;
using ::testing::HasSubstr;

std::string SourceDir() { return KINEVIS_SOURCE_DIR; }

// The host side as the DIAMOND controller sets it up: an Rs485DriveBus on the world's pty, on
// the world's clock (its waits step the world; the Modbus exchanges run in real time).
class Host {
 public:
  explicit Host(DiamondWorld* world) : world_(world) {
    hal::Rs485DriveBusOptions o;
    o.clock = &world->clock();
    o.cycle_period = 2500us;  // seed 001: 2.5 ms control sampling over RS485
    // Generous link timeouts: a loaded machine may not schedule the line's thread for a while.
    bus_ = std::make_unique<hal::Rs485DriveBus>(world->backend() + ",timeout_ms=500,retries=1", o);
    for (int i = 0; i < robots::kDiamondJoints; ++i) {
      hal::Rs485DriveConfig c;
      c.unit = world->config().units[i];
      c.drive.name = "arm" + std::to_string(i + 1);
      c.drive.scaling.position_counts_per_unit = world->config().counts_per_rad;
      c.drive.scaling.velocity_counts_per_unit = world->config().counts_per_rad;
      c.drive.command_timeout = 500ms;
      drives_.push_back(bus_->AddDrive(c));
    }
  }

  void EnableAll() {
    bus_->ConfigureAll();
    ASSERT_FALSE(bus_->EnableAll(1000ms));
  }

  Eigen::Vector2d Positions() const {
    return {drives_[0]->status().position, drives_[1]->status().position};
  }

  void MoveTo(const Eigen::Vector2d& q_target, double duration_s, double settle_s) {
    const Eigen::Vector2d q_start = Positions();
    const common::Duration start = world_->clock().Now();
    bus_->RunCyclesUntil(
        start + std::chrono::duration_cast<common::Duration>(
                    std::chrono::duration<double>(duration_s + settle_s)),
        [&] {
          const double t =
              std::min(1.0, std::chrono::duration<double>(world_->clock().Now() - start).count() /
                                duration_s);
          const double a = 0.5 * (1 - std::cos(M_PI * t));
          for (int i = 0; i < 2; ++i) {
            EXPECT_FALSE(
                drives_[i]->SetTargetPosition(q_start[i] + a * (q_target[i] - q_start[i])));
          }
          return false;
        });
  }

  std::vector<hal::Rs485Drive*> drives_;

 private:
  DiamondWorld* world_;
  std::unique_ptr<hal::Rs485DriveBus> bus_;
};

TEST(DiamondWorldTest, TheTruthIsTheSeedsIdentifiedSetWithTheJointOffsetErrors) {
  DiamondWorldConfig c;
  const robots::DiamondModel truth = TrueDiamondModel(c);
  EXPECT_DOUBLE_EQ(truth.radius, 0.2221);
  EXPECT_DOUBLE_EQ(truth.alpha, 0.7634);
  EXPECT_DOUBLE_EQ(truth.beta, 0.8037);
  EXPECT_DOUBLE_EQ(truth.joint_offsets[0], 0.6 * M_PI / 180);
  EXPECT_DOUBLE_EQ(truth.joint_offsets[1], -0.4 * M_PI / 180);
  EXPECT_DOUBLE_EQ(c.nominal.radius, 0.2);
  c.units = {3, 3};
  c.counts_per_rad = 0;
  EXPECT_THAT(c.Validate(), HasSubstr("drives.units[1]: 3 appears twice"));
  EXPECT_THAT(c.Validate(), HasSubstr("drives.counts_per_rad: must be > 0, got 0"));
  EXPECT_THROW(DiamondWorld world(c), std::invalid_argument);
}

TEST(DiamondWorldTest, DrivesAreOnAPtyAtThreeMegabaudAndReportTheTrueHomeReadings) {
  DiamondWorld world{DiamondWorldConfig{}};
  EXPECT_THAT(world.backend(), ContainsRegex("^modbus-rtu:/dev/pts/[0-9]+@3000000,8E1$"));
  Host host(&world);
  host.EnableAll();
  const DiamondPlantState s = world.plant();
  EXPECT_FALSE(s.held);
  EXPECT_NEAR(s.task[0], M_PI / 2, 1e-4);
  EXPECT_NEAR(s.task[1], M_PI / 4, 1e-4);
  EXPECT_NEAR(host.Positions()[0], s.q[0], 1.0 / world.config().counts_per_rad);
  EXPECT_NEAR(host.Positions()[1], s.q[1], 1.0 / world.config().counts_per_rad);
}

TEST(DiamondWorldTest, JointsCommandedFromTheTrueInverseKinematicsPutTheMarkerOnTheTarget) {
  DiamondWorld world{DiamondWorldConfig{}};
  Host host(&world);
  host.EnableAll();
  const Eigen::Vector2d task(110 * M_PI / 180, 55 * M_PI / 180);
  Eigen::Vector2d q;
  ASSERT_TRUE(robots::InverseKinematics(world.true_model(), task, &q).ok());

  host.MoveTo(q, 1.0, 0.3);

  const DiamondPlantState s = world.plant();
  EXPECT_FALSE(s.held);
  // Targets are whole counts (4.8e-5 rad): the task angles within a few counts.
  EXPECT_NEAR(s.task[0], task[0], 1e-4);
  EXPECT_NEAR(s.task[1], task[1], 1e-4);
  const Eigen::Vector3d p_target =
      robots::DiamondToolPoint(world.true_model().radius, task[0], task[1]);
  EXPECT_LT((s.p_O_T - p_target).norm(), 3e-5);
  EXPECT_EQ(host.drives_[0]->lifecycle(), common::DeviceLifecycle::kActive);
  EXPECT_EQ(host.drives_[1]->lifecycle(), common::DeviceLifecycle::kActive);

  // The a-priori model the host would use puts the same joints somewhere else by centimetres:
  // what seed 001's calibration removes.
  robots::DiamondData nominal;
  robots::ForwardKinematics(world.nominal_model(), s.q, &nominal);
  EXPECT_GT((nominal.p_O_T - s.p_O_T).norm(), 5e-3);
}

TEST(DiamondWorldTest, LoadsTheShippedConfig) {
  const DiamondWorldConfig c = LoadDiamondWorldConfig(SourceDir() + "/config/diamond-sim.yaml");
  EXPECT_DOUBLE_EQ(c.truth.radius, 0.2221);
  EXPECT_DOUBLE_EQ(c.nominal.radius, 0.2);
  EXPECT_EQ(c.baud, 3000000);
  EXPECT_EQ(c.cameras.size(), 1u);
  EXPECT_EQ(c.Validate(), "");
}

}  // namespace
}  // namespace kinevis::sim
