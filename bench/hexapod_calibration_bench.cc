// Hexapod calibration from leg edges (issue 6; target: CalibrateHexapod with 60 configurations
// <= 1 ms). BM_CalibrateHexapod/<loss>: eq. 14 for six legs (least-median start + IRLS for the
// robust losses), eq. 15 and 16, on 60 planned poses seen by a perspective camera 1.3 m away, the
// normals perturbed by ~0.3 mrad and 10 % of them replaced by another leg's (outliers).
// BM_PlanCalibrationPoses: the planner with its defaults (2000 candidates, 60 poses).
#include <benchmark/benchmark.h>

#include <random>

#include "calibration/hexapod/leg_calibration.h"
#include "calibration/hexapod/pose_planner.h"
#include "vision/render/scenes/hexapod_scene.h"

namespace {

using namespace kinevis;
using namespace kinevis::calibration;

const HexapodCalibrationData& Data() {
  static const HexapodCalibrationData data = [] {
    const robots::HexapodModel model = robots::HexapodModel::Default();
    const Eigen::Isometry3d X_CB =
        vision::render::CameraLookingAt(Eigen::Vector3d(0.2, -1.25, 0.45),
                                        Eigen::Vector3d(0.0, 0.0, 0.25), Eigen::Vector3d::UnitZ())
            .inverse();
    HexapodCalibrationData d =
        PredictCalibrationData(model, X_CB, PlanCalibrationPoses(model).X_BP);
    std::mt19937 rng(1);
    std::normal_distribution<double> g(0.0, 3e-4);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    for (auto& c : d.configurations) {
      for (int j = 0; j < robots::kHexapodLegs; ++j) {
        if (!c[j]) continue;
        c[j]->n1_C = (c[j]->n1_C + Eigen::Vector3d(g(rng), g(rng), g(rng))).normalized();
        c[j]->n2_C = (c[j]->n2_C + Eigen::Vector3d(g(rng), g(rng), g(rng))).normalized();
        if (u(rng) < 0.1 && c[(j + 1) % 6]) c[j]->n1_C = c[(j + 1) % 6]->n1_C;
      }
    }
    return d;
  }();
  return data;
}

void BM_CalibrateHexapod(benchmark::State& state) {
  HexapodCalibrationOptions options;
  options.loss = static_cast<RobustLoss>(state.range(0));
  const robots::HexapodModel cad = robots::HexapodModel::Default();
  const HexapodCalibrationData& data = Data();
  for (auto _ : state) {
    HexapodCalibrationResult r = CalibrateHexapod(data, cad, options);
    benchmark::DoNotOptimize(r);
  }
  state.SetLabel(ToString(options.loss));
}
BENCHMARK(BM_CalibrateHexapod)->Arg(0)->Arg(1)->Arg(2)->Unit(benchmark::kMicrosecond);

void BM_PlanCalibrationPoses(benchmark::State& state) {
  const robots::HexapodModel model = robots::HexapodModel::Default();
  for (auto _ : state) {
    PosePlan plan = PlanCalibrationPoses(model);
    benchmark::DoNotOptimize(plan);
  }
}
BENCHMARK(BM_PlanCalibrationPoses)->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
