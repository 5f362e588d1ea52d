// Robot model hot paths named in issue 4: hexapod IK (target ≤ 0.5 µs), hexapod FK (≤ 10 µs),
// weld-robot IK (≤ 20 µs). Run: ./build/bench/robots_bench --benchmark_min_time=1

#include <benchmark/benchmark.h>

#include <random>
#include <vector>

#include "robots/hexapod/hexapod_model.h"
#include "robots/weld5/weld5_model.h"

namespace kinevis::robots {
namespace {

// Poses within ±3 cm / ±5° of the nominal one, all reachable.
std::vector<Eigen::Isometry3d> HexapodPoses(int n) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> t(-0.03, 0.03), r(-0.087, 0.087);
  std::vector<Eigen::Isometry3d> poses;
  for (int i = 0; i < n; ++i) {
    Eigen::Isometry3d X = HexapodModel::NominalPose();
    X.translation() += Eigen::Vector3d(t(rng), t(rng), t(rng));
    X.linear() = (Eigen::AngleAxisd(r(rng), Eigen::Vector3d::UnitZ()) *
                  Eigen::AngleAxisd(r(rng), Eigen::Vector3d::UnitY()) *
                  Eigen::AngleAxisd(r(rng), Eigen::Vector3d::UnitX()))
                     .toRotationMatrix();
    poses.push_back(X);
  }
  return poses;
}

void BM_HexapodInverseKinematics(benchmark::State& state) {
  const HexapodModel model = HexapodModel::Default();
  const auto poses = HexapodPoses(256);
  HexapodData data;
  size_t i = 0;
  for (auto _ : state) {
    Reachability reach = InverseKinematics(model, poses[i++ & 255], &data);
    benchmark::DoNotOptimize(reach);
    benchmark::DoNotOptimize(data.q);
  }
}
BENCHMARK(BM_HexapodInverseKinematics);

// FK from the nominal pose as the guess (the poses are up to 3 cm / 5° away: the cold-start case;
// a control loop warm-starts from the previous pose and needs fewer iterations).
void BM_HexapodForwardKinematics(benchmark::State& state) {
  const HexapodModel model = HexapodModel::Default();
  const auto poses = HexapodPoses(256);
  std::vector<Vector6d> legs;
  HexapodData data;
  for (const auto& X : poses) {
    InverseKinematics(model, X, &data);
    legs.push_back(data.q);
  }
  const ForwardKinematicsOptions options;
  size_t i = 0;
  int iterations = 0;
  for (auto _ : state) {
    const ForwardKinematicsSummary s =
        ForwardKinematics(model, legs[i++ & 255], HexapodModel::NominalPose(), options, &data);
    iterations += s.iterations;
    benchmark::DoNotOptimize(s);
  }
  state.counters["newton_steps"] =
      benchmark::Counter(iterations, benchmark::Counter::kAvgIterations);
}
BENCHMARK(BM_HexapodForwardKinematics);

// Weld-robot IK for targets from random in-limit configurations, guess = the true joints plus
// N(0, 0.05) noise (a path planner's previous point is closer than that).
void BM_Weld5InverseKinematics(benchmark::State& state) {
  const Weld5Model model = Weld5Model::Seed(Weld5TorchTransform(0.025, 0.25, 0.0));
  std::mt19937 rng(11);
  std::normal_distribution<double> noise(0.0, 0.05);
  struct Case {
    Eigen::Vector3d p, u;
    Vector5d guess;
  };
  std::vector<Case> cases;
  Weld5Data data;
  while (cases.size() < 256) {
    Vector5d q;
    for (int j = 0; j < kWeld5Joints; ++j) {
      const double span = model.q_max(j) - model.q_min(j);
      q(j) = std::uniform_real_distribution<double>(model.q_min(j) + 0.1 * span,
                                                    model.q_max(j) - 0.1 * span)(rng);
    }
    Weld5ForwardKinematics(model, q, &data);
    Vector5d guess = q;
    for (int j = 0; j < kWeld5Joints; ++j) guess(j) += noise(rng) * (j == 2 ? 0.2 : 1.0);
    cases.push_back({data.p_0T, data.u_0T, guess});
  }
  size_t i = 0;
  int converged = 0, n = 0;
  for (auto _ : state) {
    const Case& c = cases[i++ & 255];
    const Weld5IkResult r = Weld5InverseKinematics(model, c.p, c.u, c.guess);
    converged += r.converged();
    ++n;
    benchmark::DoNotOptimize(r);
  }
  state.counters["converged_fraction"] = n ? static_cast<double>(converged) / n : 0.0;
}
BENCHMARK(BM_Weld5InverseKinematics);

}  // namespace
}  // namespace kinevis::robots
