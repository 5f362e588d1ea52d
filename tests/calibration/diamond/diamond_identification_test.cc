#include "calibration/diamond/diamond_identification.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <memory>

#include "calibration/diamond/diamond_residuals_internal.h"
#include "common/units.h"
#include "vision/camera/pinhole_camera.h"
#include "vision/render/scenes/diamond_marker_scene.h"

namespace kinevis::calibration {
namespace {

using ::testing::HasSubstr;
using ::testing::MatchesRegex;

std::unique_ptr<vision::CameraModel> SeedCamera() {
  vision::PinholeBrownParameters p;
  p.width = 1280;
  p.height = 640;
  p.fx = p.fy = 1000.0;
  p.cx = 639.5;
  p.cy = 319.5;
  p.distortion = {-0.05, 0.01, 0, 0, 0, 0, 0, 0};
  return std::make_unique<vision::PinholeBrownCamera>(p);
}

// The true robot of the simulated world (sim/diamond_world.h): the seed's identified set plus
// encoder offsets of 0.6° and −0.4°.
robots::DiamondModel Truth() {
  robots::DiamondModel m = robots::DiamondModel::SeedIdentified();
  m.joint_offsets = {0.6 * common::kDeg, -0.4 * common::kDeg};
  return m;
}

// The camera as really placed: near the seed's 45° placement but not exactly (the set-up's pose
// is known to ~1°, ~1 cm; its distance, the scale gauge, is known).
Eigen::Isometry3d TrueCameraPose() {
  Eigen::Isometry3d X_OC = vision::render::DiamondCameraPose(0.4462).inverse();
  X_OC = Eigen::AngleAxisd(1.5 * common::kDeg, Eigen::Vector3d::UnitZ()) * X_OC;
  X_OC.linear() = X_OC.linear() *
                  Eigen::AngleAxisd(0.8 * common::kDeg, Eigen::Vector3d(1, -1, 0.5).normalized())
                      .toRotationMatrix();
  return X_OC;
}

// The set-up's idea of the pose: the seed's nominal placement, scaled to the true distance.
Eigen::Isometry3d NominalCameraPose() {
  return vision::render::DiamondCameraPose(TrueCameraPose().translation().norm()).inverse();
}

std::vector<DiamondSample> Samples(double noise, uint64_t seed = 3) {
  const auto camera = SeedCamera();
  const robots::DiamondModel nominal = robots::DiamondModel::APriori();
  const std::vector<Eigen::Vector2d> tasks =
      DiamondVisibleTaskGrid(nominal, *camera, TrueCameraPose(), 12, 10);
  DiamondSimulationOptions o;
  o.pixel_noise_sigma = noise;
  o.seed = seed;
  return SimulateDiamondSamples(nominal, Truth(), *camera, TrueCameraPose(), tasks, o);
}

// The camera pose up to the azimuth gauge: with mean_offset held at 0, O's x axis ends up turned
// by the true mean offset m about z_O, so the estimate is Rz(−m) X_OC.
Eigen::Isometry3d GaugedTruePose() {
  const robots::DiamondModel t = Truth();
  const double m = 0.5 * (t.joint_offsets[0] + t.joint_offsets[1]);
  return Eigen::AngleAxisd(-m, Eigen::Vector3d::UnitZ()) * TrueCameraPose();
}

TEST(DiamondIdentificationTest, ExactDataRecoverTheTruthFromTheAPrioriSet) {
  const auto camera = SeedCamera();
  const std::vector<DiamondSample> samples = Samples(0.0);
  ASSERT_GT(samples.size(), 60u);
  const DiamondIdentificationSummary s =
      IdentifyDiamond(samples, *camera, robots::DiamondModel::APriori(), NominalCameraPose());
  ASSERT_TRUE(s.ok()) << ToString(s.status) << ": " << s.solver_message;
  const robots::DiamondModel t = Truth();
  EXPECT_NEAR(s.model.radius, t.radius, 1e-9);
  EXPECT_NEAR(s.model.alpha, t.alpha, 1e-9);
  EXPECT_NEAR(s.model.beta, t.beta, 1e-9);
  EXPECT_NEAR(s.model.joint_offsets[0] - s.model.joint_offsets[1],
              t.joint_offsets[0] - t.joint_offsets[1], 1e-9);
  const Eigen::Isometry3d X = GaugedTruePose();
  EXPECT_LT((s.X_OC.translation() - X.translation()).norm(), 1e-9);
  EXPECT_LT((s.X_OC.linear() - X.linear()).norm(), 1e-9);
  EXPECT_LT(s.pixel_residuals.rms_norm, 1e-6);
  EXPECT_LT(s.task_residuals.sup.maxCoeff(), 1e-8);
  EXPECT_EQ(s.identifiability.rank, s.identifiability.parameters);
  EXPECT_EQ(s.identifiability.parameters, 9);
  EXPECT_TRUE(s.identifiability.unidentified.empty());
  EXPECT_EQ(s.identifiability.gauges.size(), 2u);
  EXPECT_GT(s.initial_cost, 1e3 * s.final_cost + 1.0);
  // The estimator contract carries the same, named and with units.
  const EstimationReport& e = s.estimation;
  EXPECT_EQ(e.Validate(), "");
  EXPECT_EQ(e.status, EstimationStatus::kConverged);
  ASSERT_EQ(e.parameters.size(), static_cast<size_t>(kDiamondParameterCount));
  ASSERT_NE(e.Find("radius"), nullptr);
  EXPECT_EQ(e.Find("radius")->unit, "m");
  EXPECT_DOUBLE_EQ(e.Find("radius")->value, s.model.radius);
  EXPECT_EQ(e.Find("alpha")->unit, "rad");
  EXPECT_EQ(e.identifiability.rank, 9);
  ASSERT_EQ(e.residuals.size(), 4u);  // pixel u, v; task phi, gamma
  EXPECT_EQ(e.residuals[0].unit, "px");
  EXPECT_EQ(e.residuals[0].count, static_cast<int>(samples.size()));
  EXPECT_LT(e.residuals[0].rms, 1e-6);
}

// With 0.3 px noise: the estimates sit within a few σ of the truth and σ itself is right (the
// spread over repeated draws matches it), the variance factor is ~1, residuals ~ the noise.
TEST(DiamondIdentificationTest, NoisyDataGiveConsistentUncertainties) {
  const auto camera = SeedCamera();
  const robots::DiamondModel t = Truth();
  std::vector<double> radius_errors;
  double sigma_radius = 0;
  for (uint64_t seed = 1; seed <= 8; ++seed) {
    const DiamondIdentificationSummary s = IdentifyDiamond(
        Samples(0.3, seed), *camera, robots::DiamondModel::APriori(), NominalCameraPose());
    ASSERT_TRUE(s.ok()) << s.solver_message;
    EXPECT_NEAR(s.variance_factor, 1.0, 0.3);
    EXPECT_NEAR(s.pixel_residuals.rms.x(), 0.3, 0.08);
    EXPECT_NEAR(s.pixel_residuals.rms.y(), 0.3, 0.08);
    for (int j : {kDiamondRadius, kDiamondAlpha, kDiamondBeta, kDiamondHalfOffsetDifference}) {
      const double truth = j == kDiamondRadius  ? t.radius
                           : j == kDiamondAlpha ? t.alpha
                           : j == kDiamondBeta  ? t.beta
                                                : 0.5 * (t.joint_offsets[0] - t.joint_offsets[1]);
      EXPECT_LT(std::abs(s.parameters[j].value - truth), 5 * s.parameters[j].sigma)
          << DiamondParameterName(j);
      EXPECT_TRUE(s.parameters[j].identified);
      EXPECT_GT(s.parameters[j].sigma, 0);
    }
    radius_errors.push_back(s.model.radius - t.radius);
    sigma_radius = s.parameters[kDiamondRadius].sigma;
    EXPECT_LT(std::abs(s.model.radius / t.radius - 1), 2e-3);
  }
  double spread = 0;
  for (double e : radius_errors) spread += e * e;
  spread = std::sqrt(spread / radius_errors.size());
  EXPECT_GT(spread, 0.3 * sigma_radius);
  EXPECT_LT(spread, 3.0 * sigma_radius);
}

TEST(DiamondIdentificationTest, SphericalResidualsAgreeWithPixelResiduals) {
  const auto camera = SeedCamera();
  const std::vector<DiamondSample> samples = Samples(0.3);
  DiamondIdentificationOptions o;
  o.residual = DiamondResidual::kSpherical;
  const DiamondIdentificationSummary sph =
      IdentifyDiamond(samples, *camera, robots::DiamondModel::APriori(), NominalCameraPose(), o);
  const DiamondIdentificationSummary pix =
      IdentifyDiamond(samples, *camera, robots::DiamondModel::APriori(), NominalCameraPose());
  ASSERT_TRUE(sph.ok()) << sph.solver_message;
  ASSERT_TRUE(pix.ok());
  for (int j : {kDiamondRadius, kDiamondAlpha, kDiamondBeta}) {
    EXPECT_NEAR(sph.parameters[j].value, pix.parameters[j].value, 2 * pix.parameters[j].sigma)
        << DiamondParameterName(j);
    EXPECT_NEAR(sph.parameters[j].sigma, pix.parameters[j].sigma, 0.3 * pix.parameters[j].sigma);
  }
  EXPECT_NEAR(sph.variance_factor, 1.0, 0.3);
}

// Freeing a gauge makes the Jacobian rank-deficient; the report names the combination.
TEST(DiamondIdentificationTest, ReportsTheScaleAndAzimuthGauges) {
  const auto camera = SeedCamera();
  const std::vector<DiamondSample> samples = Samples(0.0);
  {
    DiamondIdentificationOptions o;
    o.estimate_camera_distance = true;
    const DiamondIdentificationSummary s =
        IdentifyDiamond(samples, *camera, robots::DiamondModel::APriori(), NominalCameraPose(), o);
    EXPECT_EQ(s.identifiability.rank, s.identifiability.parameters - 1);
    ASSERT_EQ(s.identifiability.unidentified.size(), 1u);
    EXPECT_THAT(s.identifiability.unidentified[0], HasSubstr("radius"));
    EXPECT_THAT(s.identifiability.unidentified[0], HasSubstr("camera_distance"));
    EXPECT_FALSE(s.parameters[kDiamondRadius].identified);
    EXPECT_TRUE(std::isinf(s.parameters[kDiamondRadius].sigma));
    EXPECT_TRUE(s.parameters[kDiamondAlpha].identified);  // the angles do not scale
    EXPECT_THAT(s.warnings, testing::Contains(HasSubstr("rank-deficient")));
    EXPECT_EQ(s.estimation.status, EstimationStatus::kUnidentified);
    EXPECT_EQ(s.estimation.Validate(), "");
    EXPECT_TRUE(std::isinf(s.estimation.Find("radius")->sigma));
    EXPECT_THAT(s.estimation.BriefReport(),
                HasSubstr("unidentified, 8 of 10 estimated parameters identified (rank 9)"));
  }
  {
    DiamondIdentificationOptions o;
    o.estimate_mean_offset = true;
    const DiamondIdentificationSummary s =
        IdentifyDiamond(samples, *camera, robots::DiamondModel::APriori(), NominalCameraPose(), o);
    EXPECT_EQ(s.identifiability.rank, s.identifiability.parameters - 1);
    ASSERT_EQ(s.identifiability.unidentified.size(), 1u);
    EXPECT_THAT(s.identifiability.unidentified[0], HasSubstr("mean_offset"));
    EXPECT_THAT(s.identifiability.unidentified[0], HasSubstr("camera_direction"));
    EXPECT_TRUE(s.parameters[kDiamondRadius].identified);
    EXPECT_TRUE(std::isinf(s.offset_sigma[0]));
  }
  {
    // With the camera pose known and fixed, both offsets are identified.
    DiamondIdentificationOptions o;
    o.estimate_mean_offset = true;
    o.estimate_camera_rotation = o.estimate_camera_direction = false;
    const DiamondIdentificationSummary s =
        IdentifyDiamond(samples, *camera, robots::DiamondModel::APriori(), TrueCameraPose(), o);
    ASSERT_TRUE(s.ok());
    EXPECT_EQ(s.identifiability.rank, 5);
    EXPECT_NEAR(s.model.joint_offsets[0], Truth().joint_offsets[0], 1e-9);
    EXPECT_NEAR(s.model.joint_offsets[1], Truth().joint_offsets[1], 1e-9);
    ASSERT_EQ(s.identifiability.gauges.size(), 1u);  // R is still relative to the distance
    EXPECT_THAT(s.identifiability.gauges[0], HasSubstr("camera_distance fixed"));
  }
}

// Samples all at one limb separation (constant γ) cannot separate α, β and the offset
// difference: the report says so instead of returning confident numbers.
TEST(DiamondIdentificationTest, DetectsDegenerateExcitation) {
  const auto camera = SeedCamera();
  const robots::DiamondModel nominal = robots::DiamondModel::APriori();
  std::vector<Eigen::Vector2d> tasks;
  for (double phi = 60; phi <= 120; phi += 3)
    tasks.emplace_back(phi * common::kDeg, 45 * common::kDeg);
  const std::vector<DiamondSample> samples =
      SimulateDiamondSamples(nominal, Truth(), *camera, TrueCameraPose(), tasks);
  ASSERT_GT(samples.size(), 15u);
  const DiamondIdentificationSummary s =
      IdentifyDiamond(samples, *camera, nominal, NominalCameraPose());
  EXPECT_TRUE(s.identifiability.rank < s.identifiability.parameters ||
              s.identifiability.condition_number > 1e3)
      << s.identifiability.condition_number;
  EXPECT_FALSE(s.warnings.empty());
  const bool alpha_weak =
      !s.parameters[kDiamondAlpha].identified || s.parameters[kDiamondAlpha].sigma > 1e-3;
  EXPECT_TRUE(alpha_weak) << s.parameters[kDiamondAlpha].sigma;
}

TEST(DiamondIdentificationTest, TooFewSamplesAndRejectionsAreData) {
  const auto camera = SeedCamera();
  const std::vector<DiamondSample> all = Samples(0.0);
  std::vector<DiamondSample> samples(all.begin() + all.size() / 2,
                                     all.begin() + all.size() / 2 + 4);  // central ones
  DiamondSample missing = samples[0];
  missing.pixel = {0.0, 0.0};  // the image corner's ray passes beside the sphere
  samples.push_back(missing);
  DiamondIdentificationOptions o;
  o.residual = DiamondResidual::kSpherical;
  const DiamondIdentificationSummary s =
      IdentifyDiamond(samples, *camera, robots::DiamondModel::APriori(), NominalCameraPose(), o);
  EXPECT_EQ(s.status, DiamondIdentificationStatus::kTooFewSamples);
  EXPECT_EQ(s.samples_used, 4);
  ASSERT_EQ(s.rejected_samples.size(), 1u);
  EXPECT_EQ(s.rejected_samples[0], 4);
  EXPECT_THAT(s.rejected_reasons[0], HasSubstr("sample 4: its ray does not give a sphere fix"));
  EXPECT_THAT(s.rejected_reasons[0], HasSubstr("miss"));
  EXPECT_EQ(s.model.radius, 0.2);  // left at the initial value
  EXPECT_THAT(s.warnings, testing::Contains(HasSubstr("only 4 usable samples")));
}

TEST(DiamondIdentificationTest, RefusesBadInputNamingIt) {
  const auto camera = SeedCamera();
  std::vector<DiamondSample> samples = Samples(0.0);
  samples[7].pixel.x() = std::nan("");
  DiamondIdentificationOptions o;
  o.pixel_sigma = -1;
  o.max_iterations = 0;
  try {
    IdentifyDiamond(samples, *camera, robots::DiamondModel::APriori(), NominalCameraPose(), o);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr("pixel_sigma = -1 px"));
    EXPECT_THAT(e.what(), HasSubstr("max_iterations = 0"));
    EXPECT_THAT(e.what(), HasSubstr("sample 7"));
  }
  Eigen::Isometry3d at_rcm = NominalCameraPose();
  at_rcm.translation().setZero();
  EXPECT_THROW(
      {
        try {
          IdentifyDiamond(Samples(0.0), *camera, robots::DiamondModel::APriori(), at_rcm);
        } catch (const std::invalid_argument& e) {
          EXPECT_THAT(e.what(), MatchesRegex(".*camera centre is at the RCM.*"));
          throw;
        }
      },
      std::invalid_argument);
  robots::DiamondModel bad = robots::DiamondModel::APriori();
  bad.radius = -1;
  EXPECT_THROW(IdentifyDiamond(Samples(0.0), *camera, bad, NominalCameraPose()),
               std::invalid_argument);
  DiamondIdentificationOptions none;
  none.estimate_radius = none.estimate_alpha = none.estimate_beta = false;
  none.estimate_offset_difference = none.estimate_camera_rotation = false;
  none.estimate_camera_direction = false;
  EXPECT_EQ(IdentifyDiamond(Samples(0.0), *camera, robots::DiamondModel::APriori(),
                            NominalCameraPose(), none)
                .status,
            DiamondIdentificationStatus::kNothingToEstimate);
}

TEST(DiamondIdentificationTest, CameraPoseParametersAreTheIdentityAtZero) {
  const Eigen::Isometry3d X = TrueCameraPose();
  std::array<double, kDiamondParameterCount> x =
      DiamondInitialParameters(robots::DiamondModel::APriori(), X);
  EXPECT_LT((DiamondCameraPoseFromParameters(x, X).matrix() - X.matrix()).norm(), 1e-12);
  x[kDiamondCameraDistance] *= 2;
  EXPECT_NEAR(DiamondCameraPoseFromParameters(x, X).translation().norm(),
              2 * X.translation().norm(), 1e-12);
  // Moving on the sphere about O carries the orientation: the RCM stays at the same place in C.
  x[kDiamondCameraDistance] /= 2;
  x[kDiamondCameraDirection1] = 0.1;
  x[kDiamondCameraDirection2] = -0.05;
  const Eigen::Isometry3d moved = DiamondCameraPoseFromParameters(x, X);
  EXPECT_LT((moved.inverse().translation() - X.inverse().translation()).norm(), 1e-12);
  EXPECT_GT((moved.translation() - X.translation()).norm(), 0.04);
}

// --- the residual functors: autodiff/analytic Jacobians against central differences ----------

Eigen::MatrixXd NumericJacobian(const ceres::CostFunction& cost, const std::vector<double>& z,
                                int rows) {
  Eigen::MatrixXd J(rows, kDiamondParameterCount);
  const double h = 1e-6;
  for (int j = 0; j < kDiamondParameterCount; ++j) {
    std::vector<double> zp = z, zm = z;
    zp[j] += h;
    zm[j] -= h;
    std::vector<double> rp(rows), rm(rows);
    const double* pp[1] = {zp.data()};
    const double* pm[1] = {zm.data()};
    EXPECT_TRUE(cost.Evaluate(pp, rp.data(), nullptr));
    EXPECT_TRUE(cost.Evaluate(pm, rm.data(), nullptr));
    for (int r = 0; r < rows; ++r) J(r, j) = (rp[r] - rm[r]) / (2 * h);
  }
  return J;
}

Eigen::MatrixXd AnalyticJacobian(const ceres::CostFunction& cost, const std::vector<double>& z,
                                 int rows) {
  std::vector<double> r(rows), jac(rows * kDiamondParameterCount);
  double* jacs[1] = {jac.data()};
  const double* p[1] = {z.data()};
  EXPECT_TRUE(cost.Evaluate(p, r.data(), jacs));
  Eigen::MatrixXd J(rows, kDiamondParameterCount);
  for (int i = 0; i < rows; ++i) {
    for (int j = 0; j < kDiamondParameterCount; ++j) J(i, j) = jac[i * kDiamondParameterCount + j];
  }
  return J;
}

TEST(DiamondResidualsTest, JacobiansMatchCentralDifferences) {
  const auto camera = SeedCamera();
  const Eigen::Isometry3d X0 = NominalCameraPose();
  std::array<double, kDiamondParameterCount> x0 =
      DiamondInitialParameters(robots::DiamondModel::APriori(), X0);
  x0[kDiamondMeanOffset] = 0.01;
  x0[kDiamondHalfOffsetDifference] = -0.004;
  internal::ParameterFrame frame(x0, X0);
  const std::array<double, kDiamondParameterCount> scales = {0.5, 2,   3,   0.7, 1.3, 0.2,
                                                             0.3, 0.4, 0.6, 0.8, 0.9};
  frame.scale = scales;
  std::vector<double> z = {0.01, -0.02, 0.01, 0.02, -0.01, 0.03, -0.02, 0.01, 0.02, -0.03, 0.005};
  const std::vector<DiamondSample> samples = Samples(0.3);
  const int n = static_cast<int>(samples.size());
  for (int k : {n / 4, n / 2, 3 * n / 4}) {
    SCOPED_TRACE(k);
    const std::unique_ptr<ceres::CostFunction> pixel(
        internal::DiamondPixelCost::Create(&frame, camera.get(), samples[k], 0.3));
    const Eigen::MatrixXd Ja = AnalyticJacobian(*pixel, z, 2);
    const Eigen::MatrixXd Jn = NumericJacobian(*pixel, z, 2);
    EXPECT_LT((Ja - Jn).cwiseAbs().maxCoeff(), 1e-6 * Ja.cwiseAbs().maxCoeff())
        << "analytic\n"
        << Ja << "\nnumeric\n"
        << Jn;
    vision::Ray ray;
    ASSERT_EQ(camera->BackProject(samples[k].pixel, &ray), vision::ProjectionStatus::kOk);
    Eigen::Matrix2d W;
    W << 300, 20, 0, 250;
    const std::unique_ptr<ceres::CostFunction> sphere(
        internal::DiamondSphericalResidual::Create(&frame, samples[k].q, ray, &W, 0.05));
    const Eigen::MatrixXd Sa = AnalyticJacobian(*sphere, z, 2);
    const Eigen::MatrixXd Sn = NumericJacobian(*sphere, z, 2);
    EXPECT_LT((Sa - Sn).cwiseAbs().maxCoeff(), 1e-6 * Sa.cwiseAbs().maxCoeff())
        << "analytic\n"
        << Sa << "\nnumeric\n"
        << Sn;
  }
}

// The spherical residual's "measured" part equals vision::LocateOnSphere for the same pose.
TEST(DiamondResidualsTest, SphericalMeasurementIsLocateOnSphere) {
  const auto camera = SeedCamera();
  const Eigen::Isometry3d X0 = NominalCameraPose();
  std::array<double, kDiamondParameterCount> x =
      DiamondInitialParameters(robots::DiamondModel::SeedIdentified(), X0);
  x[kDiamondCameraRotationY] = 0.01;
  x[kDiamondCameraDirection1] = 0.02;
  const internal::ParameterFrame frame(x, X0);
  const Eigen::Isometry3d X = DiamondCameraPoseFromParameters(x, X0);
  const DiamondSample s = Samples(0.0)[5];
  vision::Ray ray;
  camera->BackProject(s.pixel, &ray);
  double o[3], d[3];
  frame.RayInO(x.data(), ray.p_C_O, ray.d_C, o, d);
  Eigen::Vector3d p;
  double incidence;
  ASSERT_EQ(
      vision::IntersectRaySphere<double>(Eigen::Vector3d(o[0], o[1], o[2]),
                                         Eigen::Vector3d(d[0], d[1], d[2]), x[0], &p, &incidence),
      vision::RaySphereHit::kOk);
  const vision::SphereFix fix = vision::LocateOnSphere(*camera, X, x[0], s.pixel);
  EXPECT_LT((fix.p_O - p).norm(), 1e-12);
  double p_C[3];
  const double pO[3] = {p.x(), p.y(), p.z()};
  frame.PointInCamera(x.data(), pO, p_C);
  EXPECT_LT((Eigen::Vector3d(p_C[0], p_C[1], p_C[2]) - X.inverse() * p).norm(), 1e-12);
}

}  // namespace
}  // namespace kinevis::calibration
