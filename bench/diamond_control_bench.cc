// DIAMOND control cycle costs (issue 8; target <= 50 µs of compute per cycle): the task-space PD
// law (forward kinematics, task Jacobian, its solve), the loop's safety checks on the commanded
// joints (two forward kinematics with limits), the ViSP visual-servo law for one frame, the marker
// detector in its search window and over the whole image, and — for the I/O side of the
// 1 kHz question — one bus Cycle() (two Modbus RTU round trips) over DiamondWorld's pty in real
// time.

#include <benchmark/benchmark.h>
#include <spdlog/spdlog.h>

#include <chrono>
#include <memory>
#include <thread>
#include <vector>

#include "common/units.h"
#include "control/diamond/diamond_drives.h"
#include "control/diamond/diamond_laws.h"
#include "control/diamond/diamond_loop.h"
#include "sim/diamond_world.h"
#include "vision/camera/pinhole_camera.h"
#include "vision/diamond/marker_detector.h"
#include "vision/render/renderer.h"
#include "vision/render/scenes/diamond_marker_scene.h"

namespace {

using namespace std::chrono_literals;
using namespace kinevis;

std::unique_ptr<vision::CameraModel> SeedCamera() {
  vision::PinholeBrownParameters p;
  p.width = 1280;
  p.height = 640;
  p.fx = p.fy = 1000.0;
  p.cx = 639.5;
  p.cy = 319.5;
  return std::make_unique<vision::PinholeBrownCamera>(p);
}

void BM_TaskPdLawStep(benchmark::State& state) {
  const robots::DiamondModel model = robots::DiamondModel::APriori();
  control::DiamondTaskPdLaw law(
      model, control::DiamondLine::SeedHorizontal(control::DiamondLineKind::kTopViewLine));
  Eigen::Vector2d q;
  robots::InverseKinematics(model, {M_PI / 2, 50 * common::kDeg}, &q);
  law.Start(q, common::Duration{0});
  control::DiamondCycleInput in;
  in.dt = 0.001;
  in.q = q;
  for (auto _ : state) {
    in.t += 1e-4;
    if (in.t > 2.9) in.t = 0.1;
    benchmark::DoNotOptimize(law.Step(in));
  }
}
BENCHMARK(BM_TaskPdLawStep);

// What the loop adds per cycle: FK with limits at the next and the stopping joints.
void BM_SafetyForwardKinematicsTwice(benchmark::State& state) {
  const robots::DiamondModel model = robots::DiamondModel::APriori();
  Eigen::Vector2d q;
  robots::InverseKinematics(model, {M_PI / 2, 50 * common::kDeg}, &q);
  robots::DiamondData a, b;
  for (auto _ : state) {
    q[0] += 1e-9;
    benchmark::DoNotOptimize(robots::ForwardKinematics(model, q, &a));
    benchmark::DoNotOptimize(robots::ForwardKinematics(model, q + Eigen::Vector2d(1e-4, 0), &b));
  }
}
BENCHMARK(BM_SafetyForwardKinematicsTwice);

class NoFrames final : public control::MarkerFeatureSource {
 public:
  bool Poll(common::Duration, control::MarkerFrame*) override { return false; }
};

// The IBVS law for one frame: FK, the marker Jacobian, back-projection, vpServo's law.
void BM_MarkerServoCompute(benchmark::State& state) {
  const robots::DiamondModel model = robots::DiamondModel::APriori();
  const auto camera = SeedCamera();
  NoFrames source;
  control::DiamondMarkerServo servo(model, *camera, vision::render::DiamondCameraPose(0.4462),
                                    &source);
  servo.SetTarget({600, 300});
  Eigen::Vector2d q;
  robots::InverseKinematics(model, {95 * common::kDeg, 48 * common::kDeg}, &q);
  Eigen::Vector2d q_dot;
  for (auto _ : state) benchmark::DoNotOptimize(servo.Compute(q, {650, 320}, &q_dot));
}
BENCHMARK(BM_MarkerServoCompute);

void DetectorBench(benchmark::State& state, bool windowed) {
  const auto camera = SeedCamera();
  vision::render::RenderOptions o;
  o.noise_sigma = 1.0;
  vision::render::Renderer renderer(*camera, o);
  vision::render::DiamondMarkerSceneParameters p;
  p.X_CO = vision::render::DiamondCameraPose(0.4462);
  p.p_O_T = robots::DiamondToolPoint(0.2221, 95 * common::kDeg, 48 * common::kDeg);
  std::vector<uint8_t> pixels(static_cast<size_t>(camera->width()) * camera->height());
  vision::ImageView8 view{pixels.data(), camera->width(), camera->height(),
                          static_cast<size_t>(camera->width())};
  vision::render::DiamondMarkerScene scene(p);
  renderer.Render(scene, 1, view);
  Eigen::Vector2d truth;
  camera->Project(scene.p_C_T(), &truth);
  const Eigen::Vector2d prediction = truth + Eigen::Vector2d(5, -3);
  vision::MarkerDetector detector;
  for (auto _ : state) {
    benchmark::DoNotOptimize(detector.Detect(view, windowed ? &prediction : nullptr));
  }
}
void BM_MarkerDetectWindow(benchmark::State& state) { DetectorBench(state, true); }
void BM_MarkerDetectFullImage(benchmark::State& state) { DetectorBench(state, false); }
BENCHMARK(BM_MarkerDetectWindow)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_MarkerDetectFullImage)->Unit(benchmark::kMillisecond);

// One bus cycle = two Modbus RTU write-and-read transactions (27 + 25 bytes each) over the pty to
// the drive simulators, in real time. On a real RS485 line at 3 Mbit/s the bytes alone take
// 2 × 52 × 11 bit / 3 Mbit/s = 0.38 ms, plus the drives' turnaround and the USB adapter's latency.
void BM_BusCycleOverPty(benchmark::State& state) {
  spdlog::set_level(spdlog::level::warn);
  sim::DiamondWorld world{sim::DiamondWorldConfig{}, sim::DiamondWorld::Timing::kRealTime};
  world.Start();
  std::this_thread::sleep_for(100ms);  // see experiments/diamond_straightness.cc
  control::DiamondDriveBusConfig c;
  c.backend = world.backend() + ",timeout_ms=100,retries=1";
  c.units = world.config().units;
  c.counts_per_rad = world.config().counts_per_rad;
  auto bus = control::MakeDiamondDriveBus(c, &world.clock());
  control::BringUpDiamondDrives(bus.get(), 2000ms);
  for (auto _ : state) benchmark::DoNotOptimize(bus->Cycle());
  bus->Close();
  world.Stop();
}
BENCHMARK(BM_BusCycleOverPty)->Unit(benchmark::kMicrosecond)->UseRealTime();

}  // namespace
