#include "sim/hexapod_world.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include "hal/canopen/canopen_master.h"
#include "hal/drive/cia402_can_drive.h"

namespace kinevis::sim {
namespace {

using namespace std::chrono_literals;
using robots::kHexapodLegs;
using robots::Vector6d;
using ::testing::HasSubstr;

// The repository root, from this file's path (no compile definition needed).
std::string SourceDir() { return KINEVIS_SOURCE_DIR; }

std::string TestName() { return ::testing::UnitTest::GetInstance()->current_test_info()->name(); }

HexapodWorldConfig Config() {
  HexapodWorldConfig c;
  c.network = "hexapod-" + TestName();  // one bus per test in the process registry
  return c;
}

// The host side, as a controller would set it up: a CanopenMaster on the world's bus, on the
// world's clock (the master's waits are where simulated time passes).
class Host {
 public:
  explicit Host(HexapodWorld* world) : world_(world) {
    hal::canopen::CanopenMasterOptions o;
    o.clock = &world->clock();
    // Six drives, 4 PDOs each plus SYNC: ~2.7 ms of a 1 Mbit/s bus; a 4 ms cycle leaves room.
    o.cycle_period = 4ms;
    o.cycle_timeout = 3500us;
    master_ = std::make_unique<hal::canopen::CanopenMaster>(world->ConnectHost(), o);
    for (int j = 0; j < kHexapodLegs; ++j) {
      hal::Cia402CanDriveConfig c;
      c.node = static_cast<uint8_t>(world->config().nodes[j]);
      c.drive.name = "leg" + std::to_string(j);
      c.drive.scaling.position_counts_per_unit = world->config().counts_per_metre;
      c.drive.scaling.velocity_counts_per_unit = world->config().counts_per_metre;
      c.drive.command_timeout = 500ms;
      c.heartbeat_producer = 20ms;
      drives_.push_back(master_->AddDrive(c));
    }
  }

  void EnableAll() {
    master_->ConfigureAll();
    ASSERT_FALSE(master_->EnableAll(1000ms));
  }

  Vector6d Positions() const {
    Vector6d s;
    for (int j = 0; j < kHexapodLegs; ++j) s[j] = drives_[j]->status().position;
    return s;
  }

  // Moves every leg from where it is to s_target along a cosine ramp of `duration`, then holds
  // the target for `settle`.
  void MoveTo(const Vector6d& s_target, double duration_s, double settle_s) {
    const Vector6d s_start = Positions();
    const common::Duration start = world_->clock().Now();
    const auto elapsed = [&] {
      return std::chrono::duration<double>(world_->clock().Now() - start).count();
    };
    master_->RunCyclesUntil(start + std::chrono::duration_cast<common::Duration>(
                                        std::chrono::duration<double>(duration_s + settle_s)),
                            [&] {
                              const double t = std::min(1.0, elapsed() / duration_s);
                              const double a = 0.5 * (1 - std::cos(M_PI * t));
                              for (int j = 0; j < kHexapodLegs; ++j) {
                                EXPECT_FALSE(drives_[j]->SetTargetPosition(
                                    s_start[j] + a * (s_target[j] - s_start[j])));
                              }
                              return false;
                            });
  }

  std::vector<hal::Cia402CanDrive*> drives_;

 private:
  HexapodWorld* world_;
  std::unique_ptr<hal::canopen::CanopenMaster> master_;
};

double RotationError(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  return Eigen::AngleAxisd(a.linear().transpose() * b.linear()).angle();
}

TEST(HexapodWorldTest, TheTrueRobotIsTheNominalPerturbedBySeededErrorsOfTheConfiguredSize) {
  HexapodWorldConfig c = Config();
  const robots::HexapodModel truth = TrueHexapodModel(c);
  const robots::HexapodModel again = TrueHexapodModel(c);
  double sum_sq_mm = 0;
  double offset_sq_mm = 0;
  for (int j = 0; j < kHexapodLegs; ++j) {
    EXPECT_EQ(truth.p_B_A[j], again.p_B_A[j]);
    sum_sq_mm += (truth.p_B_A[j] - c.nominal.p_B_A[j]).squaredNorm() * 1e6;
    sum_sq_mm += (truth.p_P_B[j] - c.nominal.p_P_B[j]).squaredNorm() * 1e6;
    offset_sq_mm += std::pow((truth.q0[j] - c.nominal.q0[j]) * 1e3, 2);
  }
  // 36 coordinates with sigma 0.5 mm; 6 offsets with sigma 1 mm: RMS within a factor of 2.
  const double rms_points = std::sqrt(sum_sq_mm / 36);
  const double rms_offsets = std::sqrt(offset_sq_mm / 6);
  EXPECT_GT(rms_points, 0.25);
  EXPECT_LT(rms_points, 1.0);
  EXPECT_GT(rms_offsets, 0.4);
  EXPECT_LT(rms_offsets, 2.0);

  c.seed = 2;
  EXPECT_NE(TrueHexapodModel(c).p_B_A[0], truth.p_B_A[0]);
  c.base_point_sigma_mm = c.platform_point_sigma_mm = c.joint_offset_sigma_mm = 0;
  const robots::HexapodModel exact = TrueHexapodModel(c);
  for (int j = 0; j < kHexapodLegs; ++j) {
    EXPECT_EQ(exact.p_B_A[j], c.nominal.p_B_A[j]);
    EXPECT_EQ(exact.q0[j], c.nominal.q0[j]);
  }
}

TEST(HexapodWorldTest, BadConfigIsRefusedNamingEveryBadField) {
  HexapodWorldConfig c = Config();
  c.counts_per_metre = -1;
  c.nodes[3] = 2;
  c.can_bitrate = 300000;
  c.joint_offset_sigma_mm = std::nan("");
  const std::string message = c.Validate();
  EXPECT_THAT(message, HasSubstr("drives.counts_per_metre: must be > 0, got -1"));
  EXPECT_THAT(message, HasSubstr("drives.nodes[3]: 2 appears twice"));
  EXPECT_THAT(message, HasSubstr("can.bitrate: 300000"));
  EXPECT_THAT(message, HasSubstr("perturbation.joint_offset_sigma_mm: must be >= 0, got nan"));
  EXPECT_THROW(HexapodWorld world(c), std::invalid_argument);
}

TEST(HexapodWorldTest, ItStartsAtHomeAndTheDrivesReportTheTrueActuatorReadings) {
  HexapodWorld world(Config());
  const HexapodPlantState start = world.plant();
  EXPECT_TRUE(start.X_BP.isApprox(world.config().X_BP_home, 1e-12));
  Host host(&world);
  host.EnableAll();
  const HexapodPlantState s = world.plant();
  EXPECT_FALSE(s.held);
  EXPECT_LT((s.X_BP.translation() - world.config().X_BP_home.translation()).norm(), 2e-6);
  const Vector6d reported = host.Positions();
  for (int j = 0; j < kHexapodLegs; ++j) {
    // One count (1 µm) of rounding, and the true readings differ from what the nominal model
    // would say by the joint offset errors.
    EXPECT_NEAR(reported[j], s.q[j] - world.true_model().q0[j], 1.5e-6) << "leg " << j;
  }
}

TEST(HexapodWorldTest, LegsCommandedFromTheTrueInverseKinematicsBringThePlatformToTheTarget) {
  HexapodWorld world(Config());
  Host host(&world);
  host.EnableAll();
  Eigen::Isometry3d X_BP_target = world.config().X_BP_home;
  X_BP_target.translation() += Eigen::Vector3d(0.02, -0.015, 0.03);
  X_BP_target.linear() = (Eigen::AngleAxisd(0.05, Eigen::Vector3d::UnitX()) *
                          Eigen::AngleAxisd(-0.04, Eigen::Vector3d::UnitZ()))
                             .toRotationMatrix();
  robots::HexapodData data;
  ASSERT_TRUE(robots::InverseKinematics(world.true_model(), X_BP_target, &data).ok());
  const Vector6d s_target = robots::JointPositionsFromLegLengths(world.true_model(), data.q);

  host.MoveTo(s_target, 1.0, 0.3);

  const HexapodPlantState s = world.plant();
  EXPECT_FALSE(s.held);
  EXPECT_EQ(s.holds, 0u);
  // Targets are whole counts (1 µm): leg errors <= 0.5 µm give a pose error of a few µm.
  EXPECT_LT((s.X_BP.translation() - X_BP_target.translation()).norm(), 5e-6);
  EXPECT_LT(RotationError(s.X_BP, X_BP_target), 3e-5);
  for (int j = 0; j < kHexapodLegs; ++j) {
    EXPECT_NEAR(host.Positions()[j], s_target[j], 1.5e-6) << "leg " << j;
    EXPECT_EQ(host.drives_[j]->lifecycle(), common::DeviceLifecycle::kActive);
  }
}

TEST(HexapodWorldTest, LegsCommandedFromTheNominalModelMissTheTargetByWhatTheTruthPredicts) {
  HexapodWorld world(Config());
  Host host(&world);
  host.EnableAll();
  Eigen::Isometry3d X_BP_target = world.config().X_BP_home;
  X_BP_target.translation() += Eigen::Vector3d(-0.01, 0.02, 0.04);
  robots::HexapodData data;
  ASSERT_TRUE(robots::InverseKinematics(world.nominal_model(), X_BP_target, &data).ok());
  const Vector6d s_nominal = robots::JointPositionsFromLegLengths(world.nominal_model(), data.q);

  host.MoveTo(s_nominal, 1.0, 0.3);

  // What the true kinematics predict for those readings.
  const Vector6d q_true = robots::LegLengthsFromJointPositions(world.true_model(), s_nominal);
  const robots::ForwardKinematicsSummary predicted = robots::ForwardKinematics(
      world.true_model(), q_true, X_BP_target, robots::ForwardKinematicsOptions{}, &data);
  ASSERT_TRUE(predicted.converged());
  const HexapodPlantState s = world.plant();
  EXPECT_LT((s.X_BP.translation() - predicted.X_BP.translation()).norm(), 5e-6);
  EXPECT_LT(RotationError(s.X_BP, predicted.X_BP), 3e-5);
  // ... and that is not the target: the calibration has something to find.
  EXPECT_GT((s.X_BP.translation() - X_BP_target.translation()).norm(), 2e-4);
}

TEST(HexapodWorldTest, LoadsTheShippedConfig) {
  const HexapodWorldConfig c = LoadHexapodWorldConfig(SourceDir() + "/config/hexapod-sim.yaml");
  EXPECT_EQ(c.nominal.leg_length_max, robots::HexapodModel::Default().leg_length_max);
  EXPECT_EQ(c.nodes[5], 6);
  EXPECT_EQ(c.counts_per_metre, 1e6);
  EXPECT_EQ(c.cameras.size(), 2u);
  EXPECT_EQ(c.Validate(), "");
}

TEST(HexapodWorldTest, ConfigFileErrorsNameTheFileAndEveryBadKey) {
  const std::string path = ::testing::TempDir() + "/bad-hexapod-sim.yaml";
  std::ofstream(path) << "world: hexapod\nseed: 3\ndrives: {counts_per_metre: -5, nodez: 1}\n"
                         "perturbation: {base_point_sigma_mm: abc}\n";
  try {
    LoadHexapodWorldConfig(path);
    FAIL() << "no exception";
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr(path + ": "));
    EXPECT_THAT(e.what(), HasSubstr("drives.nodez: unknown key"));
    EXPECT_THAT(e.what(), HasSubstr("perturbation.base_point_sigma_mm: expected a finite number, "
                                    "got 'abc'"));
  }
}

}  // namespace
}  // namespace kinevis::sim
