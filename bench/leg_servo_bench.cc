// The leg-direction control law per camera frame (issue 6: extraction plus law within 2 ms).
// BM_LegServoCompute: LegServo::Compute (vpServo: interaction matrix, pseudo-inverse, D_inv) with
// six legs visible; BM_LegServoEigenReference: the same law with Eigen only (JacobiSVD), for
// comparison; BM_LegServoRebuild: a leg lost or found every frame (vpServo task rebuilt);
// BM_FrameToLegRates1024: the whole per-frame path of `kinevis servo hexapod` for a 1024×768
// perspective camera — grab (a pre-rendered frame copied by the simulated camera), nominal FK of
// the leg lengths, edge extraction of the six legs, eq. 11, then the law and D_inv: the issue's
// "edge extraction plus control law per frame" (target <= 2 ms on one core).
#include <benchmark/benchmark.h>

#include <Eigen/SVD>
#include <cstring>
#include <memory>
#include <vector>

#include "common/clock.h"
#include "control/hexapod/image_leg_features.h"
#include "control/hexapod/leg_servo.h"
#include "hal/camera/camera_factory.h"
#include "hal/camera/sim_camera.h"
#include "vision/camera/pinhole_camera.h"
#include "vision/render/renderer.h"
#include "vision/render/scenes/hexapod_scene.h"

namespace {

using namespace kinevis;

struct Fixture {
  robots::HexapodModel model = robots::HexapodModel::Default();
  Eigen::Isometry3d X_CB = Eigen::Isometry3d::Identity();
  control::LegDirections u, u_star;
  robots::Vector6d q;
  Fixture() {
    X_CB.translation() = Eigen::Vector3d(0, 0.2, 1.3);
    X_CB.linear() = Eigen::AngleAxisd(2.0, Eigen::Vector3d::UnitX()).matrix();
    Eigen::Isometry3d goal = robots::HexapodModel::NominalPose();
    goal.translation() += Eigen::Vector3d(0.01, -0.02, 0.02);
    control::DesiredLegDirections(model, goal, X_CB, &u_star);
    robots::HexapodData data;
    robots::InverseKinematics(model, robots::HexapodModel::NominalPose(), &data);
    for (int j = 0; j < 6; ++j) u[j] = X_CB.linear() * data.u_B[j];
    q = data.q;
  }
};

void BM_LegServoCompute(benchmark::State& state) {
  Fixture f;
  control::LegServo servo(control::AttachmentPointsInCamera(f.model, f.X_CB));
  servo.SetDesired(f.u_star);
  const control::LegMask all{true, true, true, true, true, true};
  for (auto _ : state) benchmark::DoNotOptimize(servo.Compute(f.u, all, f.q));
}
BENCHMARK(BM_LegServoCompute);

void BM_LegServoEigenReference(benchmark::State& state) {
  Fixture f;
  const control::LegPoints p = control::AttachmentPointsInCamera(f.model, f.X_CB);
  const control::LegMask all{true, true, true, true, true, true};
  for (auto _ : state) {
    Eigen::Matrix<double, 18, 6> L;
    Eigen::Matrix<double, 18, 1> e;
    control::StackLegServoTask(p, f.u, f.u_star, all, f.q, &L, &e);
    Eigen::JacobiSVD<Eigen::Matrix<double, 18, 6>> svd(L,
                                                       Eigen::ComputeFullU | Eigen::ComputeFullV);
    const robots::Vector6d tau = -svd.solve(e);
    benchmark::DoNotOptimize(control::InverseDifferentialAtCameraOrigin(p, f.u) * tau);
  }
}
BENCHMARK(BM_LegServoEigenReference);

void BM_LegServoRebuild(benchmark::State& state) {
  Fixture f;
  control::LegServo servo(control::AttachmentPointsInCamera(f.model, f.X_CB));
  servo.SetDesired(f.u_star);
  const control::LegMask all{true, true, true, true, true, true};
  const control::LegMask five{true, true, false, true, true, true};
  bool flip = false;
  for (auto _ : state) {
    benchmark::DoNotOptimize(servo.Compute(f.u, flip ? five : all, f.q));
    flip = !flip;
  }
}
BENCHMARK(BM_LegServoRebuild);

void BM_FrameToLegRates1024(benchmark::State& state) {
  // 1024×768, f = 1400 px, slight barrel distortion, 1.45 m out, 30° round (all legs seen).
  vision::PinholeBrownParameters p;
  p.width = 1024;
  p.height = 768;
  p.fx = p.fy = 1400.0;
  p.cx = 511.5;
  p.cy = 383.5;
  p.distortion[0] = -0.08;
  p.distortion[1] = 0.02;
  const vision::PinholeBrownCamera camera(p);
  const robots::HexapodModel model = robots::HexapodModel::Default();
  const Eigen::Isometry3d X_CB =
      vision::render::CameraLookingAt(Eigen::Vector3d(0.725, -1.2557, 0.9),
                                      Eigen::Vector3d(0.0, 0.0, 0.2), Eigen::Vector3d::UnitZ())
          .inverse();
  Eigen::Isometry3d X_BP = robots::HexapodModel::NominalPose();
  X_BP.translation() += Eigen::Vector3d(0.02, -0.015, 0.03);
  X_BP.linear() = Eigen::AngleAxisd(0.08, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  const vision::render::HexapodScene scene(model, X_BP, X_CB);
  vision::render::RenderOptions ro;
  ro.noise_sigma = 1.0;
  std::vector<uint8_t> frame(1024 * 768);
  vision::render::Renderer(camera, ro).Render(scene, 0, {frame.data(), 1024, 768, 1024});

  hal::CameraFormat format;
  format.width = 1024;
  format.height = 768;
  format.pixel_format = hal::PixelFormat::kMono8;
  format.fps = 100;
  hal::RegisterRenderSource("bench-frame", format, [&](uint64_t, common::Duration, hal::Image* im) {
    for (int y = 0; y < 768; ++y) std::memcpy(im->row(y), frame.data() + y * 1024, 1024);
    return std::error_code();
  });
  common::SimulatedClock clock;
  std::unique_ptr<hal::Camera> cam = hal::OpenCamera("sim:bench-frame", clock);
  cam->Open();
  cam->Start();
  robots::HexapodData ik;
  robots::InverseKinematics(model, X_BP, &ik);
  control::ImageLegFeatureSource source(cam.get(), &camera, model, X_CB, [&] { return ik.q; });
  control::LegServo law(control::AttachmentPointsInCamera(model, X_CB));
  control::LegDirections u_star;
  Eigen::Isometry3d goal = X_BP;
  goal.translation().z() += 0.01;
  control::DesiredLegDirections(model, goal, X_CB, &u_star);
  law.SetDesired(u_star);
  control::LegFeatureFrame features;
  int visible = 0;
  for (auto _ : state) {
    clock.Advance(std::chrono::milliseconds(10));  // the next frame is due
    if (!source.Poll(clock.Now(), &features)) {
      state.SkipWithError("no frame");
      break;
    }
    const control::LegServoResult r = law.Compute(features.u_C, features.visible, ik.q);
    benchmark::DoNotOptimize(r.q_dot);
    visible = r.visible_legs;
  }
  state.counters["visible_legs"] = visible;
  hal::UnregisterRenderSource("bench-frame");
}
BENCHMARK(BM_FrameToLegRates1024)->Unit(benchmark::kMicrosecond);

}  // namespace
