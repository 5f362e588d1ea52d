// The leg-direction control law per camera frame (issue 6: extraction plus law within 2 ms).
// BM_LegServoCompute: LegServo::Compute (vpServo: interaction matrix, pseudo-inverse, D_inv) with
// six legs visible; BM_LegServoEigenReference: the same law with Eigen only (JacobiSVD), for
// comparison; BM_LegServoRebuild: a leg lost or found every frame (vpServo task rebuilt).
#include <benchmark/benchmark.h>

#include <Eigen/SVD>

#include "control/hexapod/leg_servo.h"

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

}  // namespace
