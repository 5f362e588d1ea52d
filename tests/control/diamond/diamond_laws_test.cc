#include "control/diamond/diamond_laws.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <deque>
#include <memory>
#include <vector>

#include "common/units.h"
#include "control/diamond/diamond_loop.h"
#include "vision/camera/camera_file.h"
#include "vision/camera/pinhole_camera.h"
#include "vision/render/scenes/diamond_marker_scene.h"

namespace kinevis::control {
namespace {

using robots::DiamondModel;
using ::testing::HasSubstr;

Eigen::Isometry3d CameraPose() { return vision::render::DiamondCameraPose(0.4462); }

std::unique_ptr<vision::CameraModel> SeedCamera() {
  vision::PinholeBrownParameters p;
  p.width = 1280;
  p.height = 640;
  p.fx = p.fy = 1000.0;
  p.cx = 639.5;
  p.cy = 319.5;
  return std::make_unique<vision::PinholeBrownCamera>(p);
}

Eigen::Vector2d JointsAt(const DiamondModel& model, double phi_deg, double gamma_deg) {
  Eigen::Vector2d q;
  EXPECT_TRUE(
      robots::InverseKinematics(model, {phi_deg * common::kDeg, gamma_deg * common::kDeg}, &q)
          .ok());
  return q;
}

TEST(DiamondLineTest, TaskLineRunsStraightInPhiGammaWithTheQuinticTimeLaw) {
  const DiamondLine line = DiamondLine::SeedVertical();
  Eigen::Vector2d x, r;
  ASSERT_TRUE(DiamondLineReference(line, 0.2, 0.0, &x, &r));
  EXPECT_TRUE(x.isApprox(line.from));
  EXPECT_LT(r.norm(), 1e-12);
  ASSERT_TRUE(DiamondLineReference(line, 0.2, line.duration_s, &x, &r));
  EXPECT_TRUE(x.isApprox(line.to));
  EXPECT_LT(r.norm(), 1e-12);
  ASSERT_TRUE(DiamondLineReference(line, 0.2, 0.5 * line.duration_s, &x, &r));
  EXPECT_NEAR(x[0], M_PI / 2, 1e-12);
  EXPECT_NEAR(x[1], 0.5 * (line.from[1] + line.to[1]), 1e-12);
  // The rate is the derivative of the reference (central differences).
  for (double t : {0.3, 1.1, 2.2}) {
    Eigen::Vector2d xp, xm, unused;
    DiamondLineReference(line, 0.2, t + 1e-6, &xp, &unused);
    DiamondLineReference(line, 0.2, t - 1e-6, &xm, &unused);
    DiamondLineReference(line, 0.2, t, &x, &r);
    EXPECT_LT((r - (xp - xm) / 2e-6).norm(), 1e-7);
  }
}

TEST(DiamondLineTest, TopViewLineIsStraightInTheBasePlaneAndItsRateIsTheDerivative) {
  const DiamondLine line = DiamondLine::SeedHorizontal(DiamondLineKind::kTopViewLine);
  // The chord's ends: sin γ = sin 45° / sin 60°.
  EXPECT_NEAR(line.from[1], std::asin(std::sqrt(2.0 / 3.0)), 1e-12);
  const double R = 0.2221;
  std::vector<Eigen::Vector2d> top;
  for (int k = 0; k <= 50; ++k) {
    const double t = line.duration_s * k / 50.0;
    Eigen::Vector2d x, r;
    ASSERT_TRUE(DiamondLineReference(line, R, t, &x, &r));
    top.emplace_back(R * std::sin(x[1]) * std::cos(x[0]), R * std::sin(x[1]) * std::sin(x[0]));
    EXPECT_NEAR(top.back().y(), R * std::sin(M_PI / 4), 1e-12);  // y_O const
    if (k > 0 && k < 50) {
      Eigen::Vector2d xp, xm, unused;
      DiamondLineReference(line, R, t + 1e-6, &xp, &unused);
      DiamondLineReference(line, R, t - 1e-6, &xm, &unused);
      EXPECT_LT((r - (xp - xm) / 2e-6).norm(), 1e-7);
    }
  }
  EXPECT_LT(Straightness(top), 1e-12);
  EXPECT_NEAR(top.front().x(), R * std::sin(M_PI / 4) / std::tan(M_PI / 3), 1e-12);
  // A top-view line through the base axis (φ undefined there) is refused where it crosses it.
  DiamondLine through = line;
  through.from = {0.0, 0.5};
  through.to = {M_PI, 0.5};
  Eigen::Vector2d x, r;
  EXPECT_TRUE(DiamondLineReference(through, R, 0.1, &x, &r));
  EXPECT_FALSE(DiamondLineReference(through, R, 0.5 * through.duration_s, &x, &r));
}

TEST(DiamondTaskPdLawTest, CommandsTheFeedForwardOnTheLineAndCorrectsAnError) {
  const DiamondModel model = DiamondModel::APriori();
  const DiamondLine line = DiamondLine::SeedHorizontal();
  DiamondPdOptions options;
  options.kp = 25.0;
  DiamondTaskPdLaw law(model, line, options);
  const double t = 1.2;
  Eigen::Vector2d x, r;
  ASSERT_TRUE(DiamondLineReference(line, model.radius, t, &x, &r));
  Eigen::Vector2d q;
  ASSERT_TRUE(robots::InverseKinematics(model, x, &q).ok());
  law.Start(q, common::Duration{0});
  DiamondCycleInput in;
  in.t = t;
  in.dt = 0.001;
  in.q = q;
  DiamondLawOutput out = law.Step(in);
  ASSERT_EQ(out.state, DiamondLawState::kRunning);
  robots::DiamondData data;
  robots::ForwardKinematics(model, q, &data);
  const Eigen::Matrix2d J = robots::TaskJacobian(data);
  EXPECT_LT((J * out.q_dot - r).norm(), 1e-9);  // on the line: the feed-forward only

  // Off the line by 0.01 rad in γ: J q̇ = ẋ* + kp e.
  Eigen::Vector2d q_off;
  ASSERT_TRUE(robots::InverseKinematics(model, x - Eigen::Vector2d(0, 0.01), &q_off).ok());
  law.Start(q_off, common::Duration{0});
  in.q = q_off;
  out = law.Step(in);
  robots::ForwardKinematics(model, q_off, &data);
  EXPECT_LT((robots::TaskJacobian(data) * out.q_dot - (r + Eigen::Vector2d(0, 0.25))).norm(), 1e-9);
  EXPECT_TRUE(out.task_reference.isApprox(x));
}

TEST(DiamondTaskPdLawTest, FinishesWhenSettledAndStopsWhenItCannotSettle) {
  const DiamondModel model = DiamondModel::APriori();
  DiamondLine line = DiamondLine::SeedVertical();
  line.duration_s = 0.5;
  DiamondTaskPdLaw law(model, line);
  Eigen::Vector2d q;
  ASSERT_TRUE(robots::InverseKinematics(model, line.to, &q).ok());
  law.Start(q, common::Duration{0});
  DiamondCycleInput in;
  in.dt = 0.001;
  in.q = q;
  DiamondLawState state = DiamondLawState::kRunning;
  for (in.t = 0.5; in.t < 0.6 && state == DiamondLawState::kRunning; in.t += in.dt) {
    state = law.Step(in).state;
  }
  EXPECT_EQ(state, DiamondLawState::kDone);
  // Readings stuck 0.05 rad away: not settled within settle_timeout_s.
  ASSERT_TRUE(robots::InverseKinematics(model, line.to - Eigen::Vector2d(0, 0.05), &q).ok());
  law.Start(q, common::Duration{0});
  in.q = q;
  in.t = 2.0;
  const DiamondLawOutput out = law.Step(in);
  EXPECT_EQ(out.state, DiamondLawState::kStop);
  EXPECT_THAT(out.reason, HasSubstr("did not settle"));
}

TEST(DiamondTaskPdLawTest, BadSetUpIsRefusedNamingEveryField) {
  DiamondPdOptions o;
  o.kp = -1;
  o.max_condition = 0.5;
  DiamondLine line;
  line.duration_s = 0;
  DiamondModel model = DiamondModel::APriori();
  model.radius = -0.1;
  try {
    DiamondTaskPdLaw law(model, line, o);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr("kp: must be > 0 (1/s), got -1"));
    EXPECT_THAT(e.what(), HasSubstr("max_condition: must be > 1, got 0.5"));
    EXPECT_THAT(e.what(), HasSubstr("line.duration_s: must be > 0, got 0"));
    EXPECT_THAT(e.what(), HasSubstr("model: "));
  }
}

// The camera-to-joint Jacobian of the marker, normalised and in pixels (with the Tsai camera's
// distortion), against central differences of the projection of the forward kinematics.
TEST(MarkerJacobianTest, MatchesFiniteDifferencesOfTheProjectedForwardKinematics) {
  const DiamondModel model = DiamondModel::SeedIdentified();
  const Eigen::Isometry3d X_CO = CameraPose();
  const auto tsai = vision::OpenCameraModel("builtin:tsai-seed004");
  const double h = 1e-6;
  double worst_n = 0, worst_p = 0;
  for (const auto& task : {Eigen::Vector2d(90, 45), Eigen::Vector2d(70, 35),
                           Eigen::Vector2d(115, 60), Eigen::Vector2d(100, 75)}) {
    const Eigen::Vector2d q = JointsAt(model, task[0], task[1]);
    robots::DiamondData data;
    robots::ForwardKinematics(model, q, &data);
    Eigen::Vector2d xy, px;
    Eigen::Matrix2d Jn, Jp;
    ASSERT_TRUE(MarkerNormalizedJacobian(X_CO, model, data, &xy, &Jn));
    ASSERT_TRUE(MarkerPixelJacobian(*tsai, X_CO, model, data, &px, &Jp));
    Eigen::Matrix2d Fn, Fp;
    for (int j = 0; j < 2; ++j) {
      Eigen::Vector2d xy_p, xy_m, px_p, px_m;
      Eigen::Matrix2d unused;
      for (const double sign : {1.0, -1.0}) {
        Eigen::Vector2d qs = q;
        qs[j] += sign * h;
        robots::DiamondData d;
        robots::ForwardKinematics(model, qs, &d);
        ASSERT_TRUE(MarkerNormalizedJacobian(X_CO, model, d, sign > 0 ? &xy_p : &xy_m, &unused));
        ASSERT_TRUE(MarkerPixelJacobian(*tsai, X_CO, model, d, sign > 0 ? &px_p : &px_m, &unused));
      }
      Fn.col(j) = (xy_p - xy_m) / (2 * h);
      Fp.col(j) = (px_p - px_m) / (2 * h);
    }
    worst_n = std::max(worst_n, (Jn - Fn).norm() / Fn.norm());
    worst_p = std::max(worst_p, (Jp - Fp).norm() / Fp.norm());
    // The normalised point is the projection of the tool point.
    const Eigen::Vector3d p_C = X_CO * data.p_O_T;
    EXPECT_LT((xy - p_C.head<2>() / p_C.z()).norm(), 1e-15);
  }
  EXPECT_LT(worst_n, 1e-7);
  EXPECT_LT(worst_p, 1e-6);
  // Not in front of the camera: refused.
  Eigen::Isometry3d behind = X_CO;
  behind.translation().z() -= 2.0;
  robots::DiamondData data;
  robots::ForwardKinematics(model, JointsAt(model, 90, 45), &data);
  Eigen::Vector2d xy;
  Eigen::Matrix2d J;
  EXPECT_FALSE(MarkerNormalizedJacobian(behind, model, data, &xy, &J));
}

// A source that replays scripted frames (for the law's state logic).
class ScriptedSource final : public MarkerFeatureSource {
 public:
  std::deque<MarkerFrame> frames;
  bool Poll(common::Duration now, MarkerFrame* frame) override {
    if (frames.empty()) return false;
    *frame = frames.front();
    frame->timestamp = now;
    frames.pop_front();
    return true;
  }
};

// ViSP's vpServo (EYETOHAND_L_cVf_fJe with cVf = twist(X_CO), fJe = [dp/dq; 0]) builds exactly
// our d s/dq, and its law is q̇ = −λ (d s/dq)⁻¹ (s − s*).
TEST(DiamondMarkerServoTest, VispTaskJacobianIsTheMarkerJacobianAndTheLawIsGaussNewton) {
  const DiamondModel model = DiamondModel::APriori();
  const auto camera = SeedCamera();
  ScriptedSource source;
  DiamondIbvsOptions options;
  options.gain = 3.0;
  DiamondMarkerServo servo(model, *camera, CameraPose(), &source, options);
  const Eigen::Vector2d q = JointsAt(model, 100, 50);
  robots::DiamondData data;
  robots::ForwardKinematics(model, q, &data);
  Eigen::Vector2d xy, px;
  Eigen::Matrix2d J, Jp;
  ASSERT_TRUE(MarkerNormalizedJacobian(CameraPose(), model, data, &xy, &J));
  ASSERT_TRUE(MarkerPixelJacobian(*camera, CameraPose(), model, data, &px, &Jp));
  const Eigen::Vector2d target = px + Eigen::Vector2d(-30, 12);
  servo.SetTarget(target);
  Eigen::Vector2d q_dot;
  Eigen::Matrix2d J_visp;
  ASSERT_TRUE(servo.Compute(q, px, &q_dot, &J_visp));
  EXPECT_LT((J_visp - J).norm() / J.norm(), 1e-12);
  const Eigen::Vector2d e = (px - target) / 1000.0;  // normalised error (f = 1000 px)
  EXPECT_LT((q_dot - (-3.0 * J.inverse() * e)).norm(), 1e-9 * q_dot.norm());
  // First order: the commanded motion moves the image point towards the target.
  EXPECT_LT(((px + Jp * q_dot * 0.01) - target).norm(), (px - target).norm());
}

TEST(DiamondMarkerServoTest, HoldsOnAMissedFrameStopsWhenTheMarkerIsLostOrTheCameraStale) {
  const DiamondModel model = DiamondModel::APriori();
  const auto camera = SeedCamera();
  ScriptedSource source;
  DiamondIbvsOptions options;
  options.max_lost_frames = 2;
  DiamondMarkerServo servo(model, *camera, CameraPose(), &source, options);
  const Eigen::Vector2d q = JointsAt(model, 95, 45);
  servo.SetTarget({600, 300});
  servo.Start(q, common::Duration{0});
  DiamondCycleInput in;
  in.q = q;
  in.dt = 0.001;
  // Waiting for the first frame: hold.
  EXPECT_EQ(servo.Step(in).state, DiamondLawState::kHold);
  MarkerFrame seen;
  seen.found = true;
  seen.pixel = {650, 320};
  MarkerFrame missed;
  source.frames = {seen, missed, missed};
  in.now = std::chrono::milliseconds(10);
  EXPECT_EQ(servo.Step(in).state, DiamondLawState::kRunning);
  in.now = std::chrono::milliseconds(20);
  const DiamondLawOutput hold = servo.Step(in);
  EXPECT_EQ(hold.state, DiamondLawState::kHold);
  EXPECT_TRUE(hold.q_dot.isZero());
  in.now = std::chrono::milliseconds(30);
  const DiamondLawOutput lost = servo.Step(in);
  EXPECT_EQ(lost.state, DiamondLawState::kStop);
  EXPECT_STREQ(lost.reason, "marker lost");

  servo.Start(q, common::Duration{0});
  source.frames = {seen};
  in.now = std::chrono::milliseconds(10);
  EXPECT_EQ(servo.Step(in).state, DiamondLawState::kRunning);
  in.now = std::chrono::milliseconds(400);  // no frame for 390 ms > 250 ms
  const DiamondLawOutput stale = servo.Step(in);
  EXPECT_EQ(stale.state, DiamondLawState::kStop);
  EXPECT_STREQ(stale.reason, "camera stale");

  EXPECT_THROW(servo.SetTarget({-10, 5}), std::invalid_argument);
  EXPECT_THROW(DiamondMarkerServo(model, *camera, CameraPose(), nullptr), std::invalid_argument);
}

TEST(StraightnessTest, IsTheRmsDistanceFromTheTotalLeastSquaresLine) {
  std::vector<Eigen::Vector2d> points;
  // Points on a tilted line at ±d alternately: the LS line is the middle one, RMS = d.
  const Eigen::Vector2d dir = Eigen::Vector2d(3, 1).normalized();
  const Eigen::Vector2d normal(-dir.y(), dir.x());
  for (int k = 0; k < 100; ++k)
    points.push_back(k * 0.01 * dir + (k % 2 ? 1 : -1) * 0.002 * normal);
  EXPECT_NEAR(Straightness(points), 0.002, 1e-6);
  points.resize(2);
  EXPECT_EQ(Straightness(points), 0.0);
}

TEST(PeriodStatisticsTest, SummarisesPeriodsLatenessAndIo) {
  std::vector<double> periods(100, 0.001);
  periods[10] = 0.003;
  const PeriodStatistics s =
      ComputePeriodStatistics(0.001, periods, {0.0, 0.0002, 0.00005}, {1e-4, 2e-4}, {1e-5}, 2);
  EXPECT_EQ(s.periods, 100u);
  EXPECT_NEAR(s.mean_s, 0.00102, 1e-12);
  EXPECT_DOUBLE_EQ(s.max_s, 0.003);
  EXPECT_DOUBLE_EQ(s.p99_s, 0.001);
  EXPECT_DOUBLE_EQ(s.p50_s, 0.001);
  EXPECT_DOUBLE_EQ(s.max_lateness_s, 0.0002);
  EXPECT_EQ(s.late_cycles, 1u);
  EXPECT_EQ(s.missed_deadlines, 2u);
  EXPECT_DOUBLE_EQ(s.io_max_s, 2e-4);
  EXPECT_GT(s.std_s, 0.0);
  EXPECT_THAT(s.Describe(), HasSubstr("p99 1000.0"));
}

}  // namespace
}  // namespace kinevis::control
