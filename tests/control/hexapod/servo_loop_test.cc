#include "control/hexapod/servo_loop.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include "common/units.h"
#include "hal/canopen/canopen_master.h"
#include "hal/drive/cia402_can_drive.h"
#include "hal/mock/canopen_drive_sim.h"
#include "sim/hexapod_world.h"

namespace kinevis::control {
namespace {

using namespace std::chrono_literals;
using ::testing::HasSubstr;

std::string TestName() { return ::testing::UnitTest::GetInstance()->current_test_info()->name(); }

// A camera in front of the robot (the features are ground truth: only its rotation matters).
Eigen::Isometry3d CameraPose_CB() {
  Eigen::Isometry3d X_BC = Eigen::Isometry3d::Identity();
  X_BC.linear() =
      Eigen::AngleAxisd(-113.0 * common::kPi / 180.0, Eigen::Vector3d::UnitX()).matrix();
  X_BC.translation() = Eigen::Vector3d(0.0, -1.2, 0.9);
  return X_BC.inverse();
}

double RotationError(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  return Eigen::AngleAxisd(a.linear().transpose() * b.linear()).angle();
}

// A simulated hexapod in stepped mode and the host side exactly as in
// tests/sim/hexapod_world_test.cc (CanopenMaster on the world's clock, 4 ms cycle, six
// Cia402CanDrives), plus the servo: ground-truth features of the true robot, the law with the
// true A_j in C (a perfect calibration), the loop with the nominal model's q0 and strokes.
class Rig {
 public:
  // drive_max_velocity (m/s, 0: the world's default): how fast the simulated legs can move.
  explicit Rig(GroundTruthFeatureOptions features = {}, double drive_max_velocity = 0) {
    sim::HexapodWorldConfig c;
    c.network = "servo-" + TestName();
    if (drive_max_velocity > 0) c.max_velocity = drive_max_velocity;
    world_ = std::make_unique<sim::HexapodWorld>(c);
    hal::canopen::CanopenMasterOptions o;
    o.clock = &world_->clock();
    o.cycle_period = 4ms;
    o.cycle_timeout = 3500us;
    master_ = std::make_unique<hal::canopen::CanopenMaster>(world_->ConnectHost(), o);
    for (int j = 0; j < kHexapodLegs; ++j) {
      hal::Cia402CanDriveConfig d;
      d.node = static_cast<uint8_t>(world_->config().nodes[j]);
      d.drive.name = "leg" + std::to_string(j);
      d.drive.scaling.position_counts_per_unit = world_->config().counts_per_metre;
      d.drive.scaling.velocity_counts_per_unit = world_->config().counts_per_metre;
      d.drive.command_timeout = 500ms;
      d.heartbeat_producer = 20ms;
      master_->AddDrive(d);
    }
    master_->ConfigureAll();
    EXPECT_FALSE(master_->EnableAll(1000ms));
    X_CB_ = CameraPose_CB();
    source_ = std::make_unique<GroundTruthLegFeatureSource>(
        world_->true_model(), X_CB_, [w = world_.get()] { return w->plant().X_BP; }, features);
    LegServoOptions law;
    law.gain = 3.0;
    servo_ = std::make_unique<LegServo>(AttachmentPointsInCamera(world_->true_model(), X_CB_), law);
  }

  // The desired features: the true robot at X_BP (what a camera would see there).
  void SetTarget(const Eigen::Isometry3d& X_BP) {
    LegDirections u_star;
    ASSERT_TRUE(DesiredLegDirections(world_->true_model(), X_BP, X_CB_, &u_star).ok());
    servo_->SetDesired(u_star);
  }

  ServoLoopReport Run(ServoLoopOptions options,
                      const std::function<void(const ServoLoopSample&)>& observer = {},
                      const robots::HexapodModel* model = nullptr) {
    ServoLoop loop(master_.get(), &world_->clock(), source_.get(),
                   model ? *model : world_->nominal_model(), servo_.get(), options);
    return loop.Run(observer);
  }

  sim::HexapodWorld& world() { return *world_; }
  GroundTruthLegFeatureSource& source() { return *source_; }
  hal::canopen::CanopenMaster& master() { return *master_; }

 private:
  std::unique_ptr<sim::HexapodWorld> world_;
  std::unique_ptr<hal::canopen::CanopenMaster> master_;
  Eigen::Isometry3d X_CB_;
  std::unique_ptr<GroundTruthLegFeatureSource> source_;
  std::unique_ptr<LegServo> servo_;
};

Eigen::Isometry3d Target(const sim::HexapodWorld& world) {
  Eigen::Isometry3d X = world.config().X_BP_home;
  X.translation() += Eigen::Vector3d(0.02, -0.015, 0.025);
  X.linear() = (Eigen::AngleAxisd(0.04, Eigen::Vector3d::UnitX()) *
                Eigen::AngleAxisd(-0.03, Eigen::Vector3d::UnitZ()))
                   .toRotationMatrix();
  return X;
}

TEST(ServoLoopTest, ConvergesToTheTargetPoseThroughTheCanopenDrivesInVelocityMode) {
  Rig rig;
  const Eigen::Isometry3d target = Target(rig.world());
  rig.SetTarget(target);
  ServoLoopOptions o;
  o.timeout_s = 6.0;
  const ServoLoopReport report = rig.Run(o);
  ASSERT_EQ(report.outcome, LoopOutcome::kCompleted) << report.message;
  EXPECT_LE(report.final_error_norm, 1e-4);
  EXPECT_GT(report.time_to_threshold_s, 0.5);    // it had a long way to go
  EXPECT_GT(report.velocity_scaled_cycles, 0u);  // the start was velocity-limited
  const sim::HexapodPlantState plant = rig.world().plant();
  const double dp = (plant.X_BP.translation() - target.translation()).norm();
  const double dr = RotationError(plant.X_BP, target);
  std::printf(
      "CSV: converged in %.3f s (|e| <= 1e-4 at %.3f s), final |e| %.2e, pose error "
      "%.2e m, %.2e rad (start 3.5 cm, 0.05 rad away)\n",
      report.duration_s, report.time_to_threshold_s, report.final_error_norm, dp, dr);
  EXPECT_LT(dp, 5e-5);
  EXPECT_LT(dr, 2e-4);
  EXPECT_FALSE(plant.held);
  // Never faster than the limit (counts of 1 µm/s of rounding aside).
  for (const ServoLoopSample& s : report.samples) {
    ASSERT_LE(s.q_dot.cwiseAbs().maxCoeff(), o.max_leg_velocity + 1e-12);
  }
  for (hal::MotorDrive* d : rig.master().drives()) {
    EXPECT_EQ(d->lifecycle(), common::DeviceLifecycle::kActive);
  }

  // The logs.
  const std::string csv = ::testing::TempDir() + "/servo.csv";
  const std::string png = ::testing::TempDir() + "/servo.png";
  WriteServoLogCsv(csv, report.samples);
  WriteConvergencePlot(png, report.samples, o.convergence_threshold, "test");
  std::ifstream in(csv);
  std::string header, line;
  std::getline(in, header);
  EXPECT_EQ(std::count(header.begin(), header.end(), ','), 36);  // 37 columns
  EXPECT_THAT(header, HasSubstr("remaining_mm,remaining_deg,visible"));
  EXPECT_THAT(header, HasSubstr("time_s,error_norm,u0_x,u0_y,u0_z"));
  size_t rows = 0;
  while (std::getline(in, line)) ++rows;
  EXPECT_EQ(rows, report.samples.size());
  EXPECT_TRUE(std::ifstream(png).good());
}

TEST(ServoLoopTest, ConvergesInPositionModeByIntegratingTheRates) {
  Rig rig;
  Eigen::Isometry3d target = rig.world().config().X_BP_home;
  target.translation() += Eigen::Vector3d(-0.01, 0.01, 0.015);
  rig.SetTarget(target);
  ServoLoopOptions o;
  o.command_mode = DriveCommandMode::kPosition;
  o.timeout_s = 5.0;
  const ServoLoopReport report = rig.Run(o);
  ASSERT_EQ(report.outcome, LoopOutcome::kCompleted) << report.message;
  const double dp = (rig.world().plant().X_BP.translation() - target.translation()).norm();
  std::printf("CSP: converged in %.3f s, pose error %.2e m\n", report.duration_s, dp);
  EXPECT_LT(dp, 5e-5);
}

// Legs that cannot follow (the drives' own velocity limit, 1 cm/s, below the loop's 5 cm/s): in
// CSP the set-points integrating the law's rates would run away from the legs (windup); held
// within max_command_lead of the readings, the loop stays a rate command on where the legs are.
TEST(ServoLoopTest, InPositionModeTheSetPointsNeverRunAwayFromLegsThatCannotFollow) {
  double worst_lead[2] = {0, 0};
  uint64_t limited[2] = {0, 0};
  const double lead[2] = {0.002, 1.0};  // bounded; in effect unbounded
  for (int k = 0; k < 2; ++k) {
    Rig rig({}, 0.01);
    Eigen::Isometry3d target = rig.world().config().X_BP_home;
    target.translation() += Eigen::Vector3d(-0.01, 0.01, 0.015);
    rig.SetTarget(target);
    ServoLoopOptions o;
    o.command_mode = DriveCommandMode::kPosition;
    o.max_command_lead = lead[k];
    o.timeout_s = 10.0;
    const ServoLoopReport report = rig.Run(o);
    for (const ServoLoopSample& s : report.samples) {
      worst_lead[k] = std::max(worst_lead[k], (s.q_command - s.q).cwiseAbs().maxCoeff());
    }
    limited[k] = report.lead_limited_cycles;
    if (k == 1) {
      // Without the bound the set-points run away until the drive's following-error window
      // (the simulator's CiA 402 0x6065) trips: a fault, 0x8611. This is what the bound prevents.
      EXPECT_EQ(report.outcome, LoopOutcome::kDriveFault) << report.message;
      EXPECT_THAT(report.message, HasSubstr("0x8611"));
    }
    std::printf(
        "CSP, legs at 1 cm/s, max_command_lead %.3f m: %s in %.2f s, largest lead %.2f mm, "
        "%llu lead-limited cycles\n",
        lead[k], ServoOutcomeName(report.outcome), report.duration_s, 1e3 * worst_lead[k],
        static_cast<unsigned long long>(limited[k]));
    if (k == 0) {
      ASSERT_EQ(report.outcome, LoopOutcome::kCompleted) << report.message;
      EXPECT_LT((rig.world().plant().X_BP.translation() - target.translation()).norm(), 5e-5);
    }
  }
  EXPECT_GT(limited[0], 0u);
  EXPECT_LE(worst_lead[0], lead[0] + 1e-12);
  EXPECT_EQ(limited[1], 0u);
  EXPECT_GT(worst_lead[1], 2 * lead[0]);
}

TEST(ServoLoopTest, AHiddenLegOrAStaleCameraHoldsThePlatformAndTheServoResumesAfterwards) {
  Rig rig;
  const Eigen::Isometry3d target = Target(rig.world());
  rig.SetTarget(target);
  ServoLoopOptions o;
  o.timeout_s = 6.0;
  Eigen::Isometry3d pose_hold_start, pose_hold_end, pose_stale_start, pose_stale_end;
  const auto observer = [&](const ServoLoopSample& s) {
    rig.source().SetLegHidden(2, s.time_s >= 0.3 && s.time_s < 0.7);
    rig.source().SetPaused(s.time_s >= 0.9 && s.time_s < 1.3);
    // The legs need ~50 ms to brake from 5 cm/s at 1 m/s^2; the stale hold starts 0.1 s after
    // the last frame.
    if (std::abs(s.time_s - 0.42) < 1e-9 + 0.002) pose_hold_start = rig.world().plant().X_BP;
    if (std::abs(s.time_s - 0.68) < 1e-9 + 0.002) pose_hold_end = rig.world().plant().X_BP;
    if (std::abs(s.time_s - 1.08) < 1e-9 + 0.002) pose_stale_start = rig.world().plant().X_BP;
    if (std::abs(s.time_s - 1.28) < 1e-9 + 0.002) pose_stale_end = rig.world().plant().X_BP;
  };
  const ServoLoopReport report = rig.Run(o, observer);
  ASSERT_EQ(report.outcome, LoopOutcome::kCompleted) << report.message;
  EXPECT_TRUE(report.legs_lost[2]);
  EXPECT_FALSE(report.legs_lost[0]);
  // 0.4 s of hidden leg at 4 ms: ~100 cycles (frames every 20 ms decide the state).
  EXPECT_NEAR(static_cast<double>(report.hold_cycles_leg_lost), 100.0, 6.0);
  EXPECT_GT(report.hold_cycles_stale_camera, 60u);
  // Held: the platform did not move while the leg was hidden or the camera silent.
  EXPECT_LT((pose_hold_end.translation() - pose_hold_start.translation()).norm(), 2e-6);
  EXPECT_LT((pose_stale_end.translation() - pose_stale_start.translation()).norm(), 2e-6);
  for (const ServoLoopSample& s : report.samples) {
    if (s.state == ServoLoopState::kHoldLegLost || s.state == ServoLoopState::kHoldStaleCamera) {
      ASSERT_EQ(s.q_dot, Vector6d::Zero()) << "t = " << s.time_s;
    }
  }
  // ... and far from the target then, at the target now.
  EXPECT_GT((pose_hold_start.translation() - target.translation()).norm(), 1e-3);
  EXPECT_LT((rig.world().plant().X_BP.translation() - target.translation()).norm(), 5e-5);
}

TEST(ServoLoopTest, ALegAboutToLeaveItsStrokeStopsTheLoopBeforeTheLimit) {
  Rig rig;
  const Eigen::Isometry3d target = Target(rig.world());
  rig.SetTarget(target);
  // The host believes the legs may grow only 8 mm beyond their longest start length.
  robots::HexapodModel model = rig.world().nominal_model();
  const Vector6d q_start = robots::LegLengthsFromJointPositions(model, [&] {
    Vector6d s;
    for (int j = 0; j < kHexapodLegs; ++j) s[j] = rig.master().drives()[j]->status().position;
    return s;
  }());
  model.leg_length_max = q_start.maxCoeff() + 0.008;
  ServoLoopOptions o;
  o.timeout_s = 3.0;
  const ServoLoopReport report = rig.Run(o, {}, &model);
  ASSERT_EQ(report.outcome, LoopOutcome::kLimit) << report.message;
  ASSERT_GE(report.stroke_leg, 0);
  EXPECT_THAT(report.message,
              HasSubstr("leg " + std::to_string(report.stroke_leg) + " would leave its stroke"));
  // Never beyond the limit: neither while running nor after stopping.
  for (const ServoLoopSample& s : report.samples) {
    ASSERT_LE(s.q.maxCoeff(), model.leg_length_max) << "t = " << s.time_s;
  }
  EXPECT_LE(report.final_q.maxCoeff(), model.leg_length_max);
  EXPECT_EQ(report.samples.back().q_dot, Vector6d::Zero());
  std::printf("stroke: stopped leg %d at %.5f m (limit %.5f m) after %.3f s\n", report.stroke_leg,
              report.final_q[report.stroke_leg], model.leg_length_max, report.duration_s);
  for (hal::MotorDrive* d : rig.master().drives()) {
    EXPECT_EQ(d->lifecycle(), common::DeviceLifecycle::kActive);  // stopped, not faulted
    EXPECT_LT(std::abs(d->status().velocity), 1e-6);
  }
}

TEST(ServoLoopTest, ADriveFaultStopsAllSixAndTheReportNamesTheDrive) {
  Rig rig;
  rig.SetTarget(Target(rig.world()));
  ServoLoopOptions o;
  o.timeout_s = 3.0;
  bool raised = false;
  const ServoLoopReport report = rig.Run(o, [&](const ServoLoopSample& s) {
    if (!raised && s.time_s >= 0.3) {
      rig.world().drive_device(3).RaiseFault(0x2310);
      raised = true;
    }
  });
  ASSERT_EQ(report.outcome, LoopOutcome::kDriveFault) << report.message;
  EXPECT_EQ(report.faulted_drive, 3);
  EXPECT_THAT(report.message, HasSubstr("leg 3 drive leg3"));
  EXPECT_THAT(report.message, HasSubstr("device fault, error code 0x2310"));
  EXPECT_LT(report.duration_s, 0.5);  // fault at 0.3 s, then braking
  for (hal::MotorDrive* d : rig.master().drives()) {
    EXPECT_NE(d->lifecycle(), common::DeviceLifecycle::kActive) << d->name();
  }
  // At rest: the platform no longer moves.
  rig.world().Step(100ms);
  const Eigen::Isometry3d a = rig.world().plant().X_BP;
  rig.world().Step(200ms);
  EXPECT_LT((rig.world().plant().X_BP.translation() - a.translation()).norm(), 1e-6);
}

TEST(ServoLoopTest, AHeartbeatLossStopsAllSixAndTheReportNamesTheDrive) {
  Rig rig;
  rig.SetTarget(Target(rig.world()));
  ServoLoopOptions o;
  o.timeout_s = 3.0;
  o.stop_action = StopAction::kDisable;
  bool stopped = false;
  const ServoLoopReport report = rig.Run(o, [&](const ServoLoopSample& s) {
    if (!stopped && s.time_s >= 0.2) {
      rig.world().drive(1).StopHeartbeat(true);
      stopped = true;
    }
  });
  ASSERT_EQ(report.outcome, LoopOutcome::kDriveFault) << report.message;
  EXPECT_EQ(report.faulted_drive, 1);
  EXPECT_THAT(report.message, HasSubstr("leg 1 drive leg1"));
  EXPECT_THAT(report.message, HasSubstr("link lost"));
  EXPECT_THAT(report.message, HasSubstr("heartbeat lost"));  // the drive's own cause
  // Consumer time 3 x 20 ms: noticed within ~60–90 ms.
  EXPECT_LT(report.duration_s, 0.45);
  for (hal::MotorDrive* d : rig.master().drives()) {
    EXPECT_NE(d->lifecycle(), common::DeviceLifecycle::kActive) << d->name();
  }
  rig.world().Step(100ms);
  const Eigen::Isometry3d a = rig.world().plant().X_BP;
  rig.world().Step(200ms);
  EXPECT_LT((rig.world().plant().X_BP.translation() - a.translation()).norm(), 1e-6);
}

TEST(ServoLoopTest, ALateAnswerIsToleratedButADriveThatStaysLateStopsAllSix) {
  {
    Rig rig;
    rig.SetTarget(Target(rig.world()));
    ServoLoopOptions o;
    o.timeout_s = 6.0;
    bool dropped = false;
    const ServoLoopReport report = rig.Run(o, [&](const ServoLoopSample& s) {
      if (!dropped && s.time_s >= 0.3) {
        rig.world().drive(2).DropNextReplies(2);  // one cycle without leg 2's TPDO1 and TPDO2
        dropped = true;
      }
    });
    EXPECT_EQ(report.outcome, LoopOutcome::kCompleted) << report.message;
    EXPECT_GE(report.cycle_timeouts, 1u);
  }
  {
    Rig rig;
    rig.SetTarget(Target(rig.world()));
    ServoLoopOptions o;
    o.timeout_s = 3.0;
    o.max_consecutive_cycle_timeouts = 3;
    bool delayed = false;
    const ServoLoopReport report = rig.Run(o, [&](const ServoLoopSample& s) {
      if (!delayed && s.time_s >= 0.3) {
        rig.world().drive(4).DropNextReplies(1000);  // silent on PDOs, heartbeat still on
        delayed = true;
      }
    });
    ASSERT_EQ(report.outcome, LoopOutcome::kDriveFault) << report.message;
    EXPECT_THAT(report.message, HasSubstr("4 cycles in a row without every drive's answer"));
    // Silent from 0.3 s: the fourth late cycle in a row is 4 cycles of 4 ms later.
    double fault_time = 0;
    ASSERT_EQ(std::sscanf(report.message.c_str(), "drive fault at t = %lf", &fault_time), 1);
    EXPECT_LT(fault_time, 0.33);
    for (hal::MotorDrive* d : rig.master().drives()) {
      EXPECT_NE(d->lifecycle(), common::DeviceLifecycle::kActive) << d->name();
    }
  }
}

// The law alone, no drives: ground-truth features of a platform that stays where it is.
TEST(LegDirectionLawTest, HoldsUntilAFrameRunsOnFramesHoldsOnLossAndIsDoneAfterTheDwell) {
  const robots::HexapodModel model = robots::HexapodModel::Default();
  const Eigen::Isometry3d X_CB = CameraPose_CB();
  Eigen::Isometry3d X_BP = robots::HexapodModel::NominalPose();
  GroundTruthLegFeatureSource source(model, X_CB, [&] { return X_BP; });  // 50 frames/s
  LegServo servo(AttachmentPointsInCamera(model, X_CB));
  Eigen::Isometry3d target = X_BP;
  target.translation() += Eigen::Vector3d(0.0, 0.0, 0.01);
  LegDirections u_star;
  ASSERT_TRUE(DesiredLegDirections(model, target, X_CB, &u_star).ok());
  servo.SetDesired(u_star);
  ServoLoopOptions o;
  o.convergence_dwell_s = 0.1;
  LegDirectionLaw law(&source, &servo, o);
  robots::HexapodData ik;
  ASSERT_TRUE(robots::InverseKinematics(model, X_BP, &ik).ok());
  const common::Duration start{0};
  law.Start(start);
  const auto at = [&](double t) { return start + common::FromSeconds(t); };

  // The first poll brings the first frame: 1 cm away, running, upwards.
  LegLawOutput out = law.Step(at(0.0), 0.0, ik.q);
  EXPECT_TRUE(out.new_frame);
  EXPECT_EQ(out.state, LawState::kRunning);
  EXPECT_GT(out.error_norm, o.convergence_threshold);
  EXPECT_GT(out.q_dot.norm(), 0.0);
  // Between frames the rates are held.
  const Vector6d held = out.q_dot;
  out = law.Step(at(0.004), 0.004, ik.q);
  EXPECT_FALSE(out.new_frame);
  EXPECT_EQ(out.state, LawState::kRunning);
  EXPECT_EQ(out.q_dot, held);
  // A leg hidden: the next frame holds, zero rates.
  source.SetLegHidden(4, true);
  out = law.Step(at(0.02), 0.02, ik.q);
  EXPECT_EQ(out.state, LawState::kHold);
  EXPECT_EQ(out.detail, ServoLoopState::kHoldLegLost);
  EXPECT_EQ(out.q_dot, Vector6d::Zero());
  EXPECT_TRUE(law.legs_lost()[4]);
  source.SetLegHidden(4, false);
  // The camera silent for longer than stale_camera_timeout_s: hold.
  source.SetPaused(true);
  out = law.Step(at(0.04 + 1.5 * o.stale_camera_timeout_s), 0.04 + 1.5 * o.stale_camera_timeout_s,
                 ik.q);
  EXPECT_EQ(out.detail, ServoLoopState::kHoldStaleCamera);
  EXPECT_EQ(out.state, LawState::kHold);
  source.SetPaused(false);
  // The platform at the target: the test holds, and after the dwell the law is done.
  X_BP = target;
  ASSERT_TRUE(robots::InverseKinematics(model, X_BP, &ik).ok());
  double done_at = -1;
  for (double t = 0.5; t < 1.5 && done_at < 0; t += 0.004) {
    out = law.Step(at(t), t, ik.q);
    if (out.state == LawState::kDone) done_at = t;
  }
  ASSERT_GE(done_at, 0.0);
  EXPECT_TRUE(out.converged_by_error);
  EXPECT_NEAR(done_at - law.time_to_threshold_s(), o.convergence_dwell_s, 0.021);
  EXPECT_GT(law.frames(), 3u);
}

TEST(ServoLoopTest, BadOptionsAreRefusedNamingEveryField) {
  ServoLoopOptions o;
  o.cycle_period_s = 0;
  o.max_leg_velocity = -1;
  o.min_visible_legs = 7;
  const std::string message = o.Validate();
  EXPECT_THAT(message, HasSubstr("cycle_period_s: must be > 0, got 0"));
  EXPECT_THAT(message, HasSubstr("max_leg_velocity: must be > 0, got -1"));
  EXPECT_THAT(message, HasSubstr("min_visible_legs: must be in 3..6, got 7"));
  EXPECT_EQ(ServoLoopOptions{}.Validate(), "");
  GroundTruthFeatureOptions f;
  f.fps = 0;
  EXPECT_THAT(f.Validate(), HasSubstr("fps: must be > 0, got 0"));
  EXPECT_THROW(GroundTruthLegFeatureSource(robots::HexapodModel::Default(),
                                           Eigen::Isometry3d::Identity(), {}, {}),
               std::invalid_argument);
}

}  // namespace
}  // namespace kinevis::control
