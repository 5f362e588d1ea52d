#include "control/hexapod/image_leg_features.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <memory>
#include <string>
#include <thread>

#include "control/hexapod/leg_servo.h"
#include "control/hexapod/servo_loop.h"
#include "hal/camera/camera_factory.h"
#include "hal/camera/sim_camera.h"
#include "hal/canopen/canopen_master.h"
#include "hal/common/error.h"
#include "hal/drive/cia402_can_drive.h"
#include "sim/hexapod_world.h"
#include "vision/camera/camera_file.h"
#include "vision/render/renderer.h"
#include "vision/render/scenes/hexapod_scene.h"

namespace kinevis::control {
namespace {

using namespace std::chrono_literals;
using ::testing::HasSubstr;

std::string TestName() { return ::testing::UnitTest::GetInstance()->current_test_info()->name(); }

// A stepped simulated hexapod with the cameras of config/hexapod-sim.yaml rendering its legs, the
// host's six CiA 402 drives on its CAN bus, and one camera opened as the host would ("sim:NAME").
class World {
 public:
  explicit World(const std::string& camera_name, double noise_sigma = 1.0) {
    sim::HexapodWorldConfig c;
    c.network = "features-" + TestName();
    c.cameras = sim::DefaultHexapodCameras();
    for (sim::WorldCameraConfig& cam : c.cameras) {
      cam.name += "-" + TestName();
      cam.render.noise_sigma = noise_sigma;
    }
    world_ = std::make_unique<sim::HexapodWorld>(c);
    world_->RegisterCameras([](const robots::HexapodModel& model,
                               const sim::HexapodPlantState& state, const Eigen::Isometry3d& X_BC) {
      return std::make_unique<vision::render::HexapodScene>(model, state.X_BP, X_BC.inverse());
    });
    for (const sim::WorldCameraConfig& cam : c.cameras) {
      if (cam.name == camera_name + "-" + TestName()) {
        X_CB_ = cam.X_WC.inverse();
        camera_model_ = vision::OpenCameraModel(cam.model);
        camera_ = hal::OpenCamera("sim:" + cam.name, world_->clock());
      }
    }
    EXPECT_NE(camera_, nullptr) << camera_name;
    camera_->Open();
    EXPECT_FALSE(camera_->Start());

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
    // Configured and enabled, so that the readings (and the predictions made from them) are live.
    master_->ConfigureAll();
    EXPECT_FALSE(master_->EnableAll(1000ms));
  }

  // q the host knows: nominal q0 + the drive readings.
  Vector6d HostLegLengths() const {
    Vector6d s;
    for (int j = 0; j < kHexapodLegs; ++j) s[j] = master_->can_drives()[j]->status().position;
    return robots::LegLengthsFromJointPositions(world_->nominal_model(), s);
  }

  std::unique_ptr<ImageLegFeatureSource> MakeSource(ImageLegFeatureOptions options = {}) {
    return std::make_unique<ImageLegFeatureSource>(
        camera_.get(), camera_model_.get(), world_->nominal_model(), X_CB_,
        [this] { return HostLegLengths(); }, options);
  }

  // The true leg directions in C at the plant's pose.
  LegDirections TrueDirections() const {
    robots::HexapodData data;
    robots::InverseKinematics(world_->true_model(), world_->plant().X_BP, &data);
    LegDirections u;
    for (int j = 0; j < kHexapodLegs; ++j) u[j] = X_CB_.linear() * data.u_B[j];
    return u;
  }

  sim::HexapodWorld& world() { return *world_; }
  hal::canopen::CanopenMaster& master() { return *master_; }
  hal::Camera& camera() { return *camera_; }
  const vision::CameraModel& camera_model() const { return *camera_model_; }
  const Eigen::Isometry3d& X_CB() const { return X_CB_; }

 private:
  std::unique_ptr<sim::HexapodWorld> world_;
  Eigen::Isometry3d X_CB_ = Eigen::Isometry3d::Identity();
  std::unique_ptr<vision::CameraModel> camera_model_;
  std::unique_ptr<hal::Camera> camera_;
  std::unique_ptr<hal::canopen::CanopenMaster> master_;
};

TEST(ImageLegFeatureSourceTest, ConstructorNamesEveryBadArgument) {
  const std::unique_ptr<vision::CameraModel> mirror =
      vision::OpenCameraModel("builtin:hyperbolic-mirror-4mm");
  ImageLegFeatureOptions options;
  options.edges.sample_step_px = -1;
  try {
    ImageLegFeatureSource source(nullptr, mirror.get(), robots::HexapodModel::Default(),
                                 Eigen::Isometry3d::Identity(), {}, options);
    FAIL() << "accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr("camera: null"));
    EXPECT_THAT(e.what(), HasSubstr("not central"));
    EXPECT_THAT(e.what(), HasSubstr("leg lengths: empty provider"));
    EXPECT_THAT(e.what(), HasSubstr("sample_step_px"));
  }
}

// Leg directions measured in rendered frames of the simulated world, predicted from the drive
// readings through the nominal model, against the true directions.
void ExpectDirectionsMatchTheTruth(const std::string& camera, double tolerance_rad,
                                   int min_visible) {
  World w(camera);
  auto source = w.MakeSource();
  LegFeatureFrame frame;
  ASSERT_TRUE(source->Poll(w.world().clock().Now(), &frame)) << source->last_error();
  const LegDirections truth = w.TrueDirections();
  int visible = 0;
  double worst = 0;
  for (int j = 0; j < kHexapodLegs; ++j) {
    if (!frame.visible[j]) {
      std::printf("  %s\n", source->last_observations()[j].reason.c_str());
      continue;
    }
    ++visible;
    worst = std::max(worst, std::acos(std::min(1.0, frame.u_C[j].dot(truth[j]))));
  }
  std::printf("%s: %d legs visible, worst direction error %.4f rad\n", camera.c_str(), visible,
              worst);
  EXPECT_GE(visible, min_visible);
  EXPECT_LE(worst, tolerance_rad);
  EXPECT_EQ(source->counters().frames, 1u);
  EXPECT_EQ(frame.sequence, 1u);
}

TEST(ImageLegFeatureSourceTest, PerspectiveCameraDirectionsMatchTheTruth) {
  // The direction of a leg seen from 1.9 m is the sensitive part (vision/hexapod/README.md):
  // eq. (11) divides the limb normals' error by sin 2θ ≈ 2R/d ≈ 0.02; measured 0.0096 rad worst
  // (0.064 with the first, parabola-only edge locator).
  ExpectDirectionsMatchTheTruth("hexapod-perspective", 0.03, 6);
}

TEST(ImageLegFeatureSourceTest, OmniCameraDirectionsMatchTheTruth) {
  ExpectDirectionsMatchTheTruth("hexapod-omni", 0.01, 6);  // measured 0.0032 rad
}

// The gate against gross extraction errors: a direction further from the prediction than
// max_prediction_deviation is not used (here a gate far below the extraction's accuracy rejects
// every leg; off, every leg is used).
TEST(ImageLegFeatureSourceTest, DirectionsFarFromThePredictionAreGatedOutAndNamed) {
  World w("hexapod-omni");
  ImageLegFeatureOptions options;
  options.max_prediction_deviation = 1e-6;
  auto gated = w.MakeSource(options);
  LegFeatureFrame frame;
  ASSERT_TRUE(gated->Poll(w.world().clock().Now(), &frame));
  for (int j = 0; j < kHexapodLegs; ++j) EXPECT_FALSE(frame.visible[j]) << j;
  EXPECT_EQ(gated->counters().legs_rejected, 6u);
  EXPECT_THAT(gated->last_observations()[2].reason,
              ::testing::ContainsRegex("leg 2: measured direction [0-9.e-]+ rad from the "
                                       "predicted one \\(gate"));
  w.world().Step(150ms);
  options.max_prediction_deviation = 0;
  auto open = w.MakeSource(options);
  ASSERT_TRUE(open->Poll(w.world().clock().Now(), &frame));
  for (int j = 0; j < kHexapodLegs; ++j) EXPECT_TRUE(frame.visible[j]) << j;
}

TEST(ImageLegFeatureSourceTest, PollsAFrameOnlyWhenTheCameraHasOneDue) {
  World w("hexapod-omni");
  auto source = w.MakeSource();
  LegFeatureFrame frame;
  const common::Duration t0 = w.world().clock().Now();
  ASSERT_TRUE(source->Poll(t0, &frame));
  EXPECT_FALSE(source->Poll(t0, &frame));  // same instant: nothing new
  w.world().Step(50ms);                    // half a period at 10 fps
  EXPECT_FALSE(source->Poll(w.world().clock().Now(), &frame));
  w.world().Step(60ms);
  EXPECT_TRUE(source->Poll(w.world().clock().Now(), &frame));
  EXPECT_EQ(source->counters().frames, 2u);
  EXPECT_EQ(frame.sequence, 2u);
  EXPECT_EQ(source->counters().camera_errors, 0u);
}

TEST(ImageLegFeatureSourceTest, CameraErrorIsCountedAndNamedAndGivesNoFrame) {
  World w("hexapod-omni");
  auto source = w.MakeSource();
  w.camera().Stop();  // grabs are refused: not active
  LegFeatureFrame frame;
  EXPECT_FALSE(source->Poll(w.world().clock().Now(), &frame));
  EXPECT_EQ(source->counters().camera_errors, 1u);
  EXPECT_THAT(source->last_error(), HasSubstr("sim:hexapod-omni"));
}

// Asynchronous mode on a free-running camera (SteadyClock), as with a real camera: Poll() only
// hands over frames the worker has finished; it never waits for the camera.
TEST(ImageLegFeatureSourceTest, AsynchronousModeHandsOverFramesWithoutWaiting) {
  const robots::HexapodModel model = robots::HexapodModel::Default();
  const sim::WorldCameraConfig config = sim::DefaultHexapodCameras()[1];  // the omni camera
  const std::unique_ptr<vision::CameraModel> camera_model = vision::OpenCameraModel(config.model);
  const Eigen::Isometry3d X_CB = config.X_WC.inverse();
  const Eigen::Isometry3d X_BP = robots::HexapodModel::NominalPose();
  const vision::render::HexapodScene scene(model, X_BP, X_CB);
  vision::render::Renderer renderer(*camera_model, config.render);
  hal::CameraFormat format;
  format.width = camera_model->width();
  format.height = camera_model->height();
  format.pixel_format = hal::PixelFormat::kMono8;
  format.fps = 20;
  const std::string name = "async-" + TestName();
  // A slow camera: every frame takes at least 150 ms to come.
  hal::RegisterRenderSource(name, format, [&](uint64_t id, common::Duration, hal::Image* image) {
    std::this_thread::sleep_for(150ms);
    renderer.Render(scene, id, {image->data.data(), image->width, image->height, image->stride});
    return std::error_code();
  });
  {
    std::unique_ptr<hal::Camera> camera = hal::OpenCamera("sim:" + name);
    camera->Open();
    ASSERT_FALSE(camera->Start());
    robots::HexapodData ik;
    robots::InverseKinematics(model, X_BP, &ik);
    ImageLegFeatureOptions options;
    options.asynchronous = true;
    ImageLegFeatureSource source(
        camera.get(), camera_model.get(), model, X_CB, [&] { return ik.q; }, options);
    LegFeatureFrame frame;
    int frames = 0;
    double slowest_poll_ms = 0;
    const auto end = std::chrono::steady_clock::now() + 3s;
    while (frames < 3 && std::chrono::steady_clock::now() < end) {
      const auto t0 = std::chrono::steady_clock::now();
      const bool got = source.Poll(common::SteadyClock::Instance().Now(), &frame);
      slowest_poll_ms = std::max(
          slowest_poll_ms,
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
      if (got) {
        ++frames;
        EXPECT_EQ(frame.sequence, static_cast<uint64_t>(frames));
        for (int j = 0; j < kHexapodLegs; ++j) {
          ASSERT_TRUE(frame.visible[j]) << j;
          EXPECT_LT(std::acos(std::min(1.0, frame.u_C[j].dot(X_CB.linear() * ik.u_B[j]))), 0.03);
        }
      }
      std::this_thread::sleep_for(4ms);  // a drive cycle
    }
    EXPECT_EQ(frames, 3);
    // A frame takes >= 150 ms to come and ~10 ms to process; none of it happens in Poll() (the
    // margin is for a loaded machine, not for the work).
    EXPECT_LT(slowest_poll_ms, 75.0);
    EXPECT_EQ(source.counters().camera_errors, 0u);
  }
  hal::UnregisterRenderSource(name);
}

// The whole chain of "servo the hexapod from leg edges": rendered frames -> leg edges -> leg
// directions -> the law -> six CiA 402 drives over CANopen on the virtual bus. The law uses the
// true A_j (a perfect calibration); the desired features are those measured at the target
// (teach by showing), so the extraction's own bias cancels at the goal.
TEST(ImageLegFeatureSourceTest, ServoLoopConvergesOnFeaturesFromRenderedImages) {
  World w("hexapod-omni");
  const Eigen::Isometry3d home = w.world().plant().X_BP;

  // Desired features: move to the target by IK of the true robot, look, come back.
  Eigen::Isometry3d target = home;
  target.translation() += Eigen::Vector3d(0.015, -0.01, 0.02);
  target.linear() = (Eigen::AngleAxisd(0.03, Eigen::Vector3d::UnitX()) *
                     Eigen::AngleAxisd(-0.02, Eigen::Vector3d::UnitZ()))
                        .toRotationMatrix();
  const auto move_to = [&](const Eigen::Isometry3d& X_BP) {
    robots::HexapodData ik;
    ASSERT_TRUE(robots::InverseKinematics(w.world().true_model(), X_BP, &ik).ok());
    const Vector6d s = robots::JointPositionsFromLegLengths(w.world().true_model(), ik.q);
    Vector6d s0;
    for (int j = 0; j < kHexapodLegs; ++j) s0[j] = w.master().can_drives()[j]->status().position;
    // A cosine ramp over 1 s (a step would trip the drives' following-error supervision).
    const common::Duration start = w.world().clock().Now();
    w.master().RunCyclesUntil(start + 1500ms, [&] {
      const double t =
          std::min(1.0, std::chrono::duration<double>(w.world().clock().Now() - start).count());
      const double a = 0.5 * (1 - std::cos(M_PI * t));
      for (int j = 0; j < kHexapodLegs; ++j) {
        w.master().can_drives()[j]->SetTargetPosition(s0[j] + a * (s[j] - s0[j]));
      }
      return false;
    });
  };
  for (const auto& d : w.master().can_drives()) {
    ASSERT_FALSE(d->SetMode(hal::DriveMode::kCyclicSynchronousPosition));
  }
  move_to(target);
  auto source = w.MakeSource();
  LegFeatureFrame desired;
  w.master().RunCyclesUntil(w.world().clock().Now() + 200ms,
                            [&] { return source->Poll(w.world().clock().Now(), &desired); });
  ASSERT_EQ(desired.sequence, 1u);
  for (int j = 0; j < kHexapodLegs; ++j) ASSERT_TRUE(desired.visible[j]) << j;
  move_to(home);

  LegServoOptions law_options;
  law_options.gain = 2.0;
  LegServo law(AttachmentPointsInCamera(w.world().true_model(), w.X_CB()), law_options);
  law.SetDesired(desired.u_C);
  // |e| itself stops at the features' noise floor (about 1e-3 with 1 grey level of image noise):
  // the loop is judged by the low-passed displacement the law still asks for.
  ServoLoopOptions o;
  o.convergence_threshold = 1e-4;
  o.convergence_translation = 2e-4;
  o.convergence_rotation = 0.03 * M_PI / 180;
  o.stale_camera_timeout_s = 0.3;
  o.convergence_dwell_s = 0.3;
  o.timeout_s = 10.0;
  ServoLoop loop(&w.master(), &w.world().clock(), source.get(), w.world().nominal_model(), &law, o);
  const ServoLoopReport report = loop.Run();
  std::printf("image-feature servo: %s, |e| = %.3g, %.2f s, %llu frames\n",
              ToString(report.outcome), report.final_error_norm, report.duration_s,
              static_cast<unsigned long long>(report.frames));
  ASSERT_EQ(report.outcome, LoopOutcome::kCompleted) << report.message;
  const sim::HexapodPlantState state = w.world().plant();
  const double position_error = (state.X_BP.translation() - target.translation()).norm();
  std::printf("platform %.3f mm from the target\n", 1e3 * position_error);
  EXPECT_LE(position_error, 1e-3);
  EXPECT_EQ(source->counters().camera_errors, 0u);
}

}  // namespace
}  // namespace kinevis::control
