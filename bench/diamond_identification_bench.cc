// Issue 8: DIAMOND identification from 500 samples (target <= 50 ms): the seed's camera at its
// 45° placement, the seed-identified robot as truth, 0.3 px marker noise, started from the
// a-priori set; pixel residuals (the default) and the seed's spherical residuals.

#include <benchmark/benchmark.h>

#include <cmath>

#include "calibration/diamond/diamond_identification.h"
#include "vision/camera/pinhole_camera.h"
#include "vision/render/scenes/diamond_marker_scene.h"

namespace kc = kinevis::calibration;

namespace {

struct Setup {
  kinevis::vision::PinholeBrownCamera camera{[] {
    kinevis::vision::PinholeBrownParameters p;
    p.width = 1280;
    p.height = 640;
    p.fx = p.fy = 1000;
    p.cx = 639.5;
    p.cy = 319.5;
    return p;
  }()};
  Eigen::Isometry3d X_OC = kinevis::vision::render::DiamondCameraPose(0.4462).inverse();
  std::vector<kc::DiamondSample> samples;
  Setup() {
    kinevis::robots::DiamondModel truth = kinevis::robots::DiamondModel::SeedIdentified();
    truth.joint_offsets = {0.6 * M_PI / 180, -0.4 * M_PI / 180};
    const auto apriori = kinevis::robots::DiamondModel::APriori();
    auto tasks = kc::DiamondVisibleTaskGrid(apriori, camera, X_OC, 40, 30);
    kc::DiamondSimulationOptions o;
    o.pixel_noise_sigma = 0.3;
    samples = kc::SimulateDiamondSamples(apriori, truth, camera, X_OC, tasks, o);
    if (samples.size() > 500) samples.resize(500);
  }
};

void Identify(benchmark::State& state, kc::DiamondResidual residual) {
  static const Setup setup;
  kc::DiamondIdentificationOptions o;
  o.residual = residual;
  for (auto _ : state) {
    const kc::DiamondIdentificationSummary s = kc::IdentifyDiamond(
        setup.samples, setup.camera, kinevis::robots::DiamondModel::APriori(), setup.X_OC, o);
    benchmark::DoNotOptimize(s.model.radius);
    if (!s.ok()) state.SkipWithError("identification did not converge");
    state.counters["iterations"] = s.iterations;
  }
  state.counters["samples"] = static_cast<double>(setup.samples.size());
}

void BM_DiamondIdentification500Pixel(benchmark::State& state) {
  Identify(state, kc::DiamondResidual::kPixel);
}
void BM_DiamondIdentification500Spherical(benchmark::State& state) {
  Identify(state, kc::DiamondResidual::kSpherical);
}
BENCHMARK(BM_DiamondIdentification500Pixel)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_DiamondIdentification500Spherical)->Unit(benchmark::kMillisecond);

}  // namespace
