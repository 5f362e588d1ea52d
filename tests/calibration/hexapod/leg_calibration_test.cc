#include "calibration/hexapod/leg_calibration.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <memory>
#include <random>
#include <vector>

#include "calibration/hexapod/pose_planner.h"
#include "common/units.h"
#include "vision/camera/pinhole_camera.h"
#include "vision/camera/unified_camera.h"
#include "vision/render/scenes/hexapod_scene.h"

namespace kinevis::calibration {
namespace {

using ::testing::ContainsRegex;
using ::testing::HasSubstr;
using ::testing::IsEmpty;

constexpr double kTarget = 0.004;  // the accuracy target on A_j (m)

// The "true" robot: the CAD model with its base points moved by a few millimetres, so that the
// CAD and the truth differ as on a real robot.
robots::HexapodModel TrueModel() {
  robots::HexapodModel model = robots::HexapodModel::Default();
  std::mt19937 rng(7);
  std::normal_distribution<double> mm(0.0, 0.002);
  for (auto& a : model.p_B_A) a += Eigen::Vector3d(mm(rng), mm(rng), mm(rng));
  return model;
}

// A camera and where it looks from.
struct Geometry {
  std::unique_ptr<vision::CameraModel> camera;
  Eigen::Isometry3d X_CB;
};

// Seed 002 §V's perspective case: a 1024×768 camera (f = 1000 px, 54° horizontal field) placed
// horizontally-ish about 1.3 m in front of the robot, looking at the middle of the legs.
Geometry Perspective() {
  vision::PinholeBrownParameters p;
  p.width = 1024;
  p.height = 768;
  p.fx = p.fy = 1000.0;
  p.cx = 511.5;
  p.cy = 383.5;
  const Eigen::Isometry3d X_BC = vision::render::CameraLookingAt(
      Eigen::Vector3d(0.2, -1.25, 0.45), Eigen::Vector3d(0.0, 0.0, 0.25), Eigen::Vector3d::UnitZ());
  return {std::make_unique<vision::PinholeBrownCamera>(p), X_BC.inverse()};
}

// Seed 002 §V's omnidirectional case: the unified-model 640×480 camera (unified-default) between
// the legs, 0.15 m above the base, its axis vertical (looking down at the base joints).
Geometry Omni() {
  Eigen::Isometry3d X_BC = Eigen::Isometry3d::Identity();
  X_BC.linear() = Eigen::AngleAxisd(common::kPi, Eigen::Vector3d::UnitX()).toRotationMatrix();
  X_BC.translation() = Eigen::Vector3d(0.0, 0.0, 0.15);
  return {std::make_unique<vision::UnifiedCamera>(vision::UnifiedParameters::Default()),
          X_BC.inverse()};
}

const std::vector<Eigen::Isometry3d>& PlannedPoses() {
  static const std::vector<Eigen::Isometry3d> poses = [] {
    PosePlannerOptions o;
    o.poses = 60;
    return PlanCalibrationPoses(robots::HexapodModel::Default(), o).X_BP;
  }();
  return poses;
}

struct NoiseOptions {
  double edge_sigma_px = 0.5;     // Gaussian, per edge point, per image axis
  int points_per_limb = 20;       // edge points along the leg (those in the image are used)
  int min_points = 8;             // fewer in the image: limb not seen
  double outlier_fraction = 0.0;  // of the limb normals
};

// Synthetic edge measurement of one limb, the way the image side produces it: points of the limb
// generator (axis + R n, seed eq. 3's tangent line) projected through the camera, 0.5 px Gaussian
// noise added to each, back-projected, and the plane through the viewpoint fitted to the rays
// (least squares: the eigenvector of Σ d dᵀ with the smallest eigenvalue). 20 points per limb is
// pessimistic: a real edge of a few hundred pixels gives hundreds of points.
bool MeasureLimb(const vision::CameraModel& camera, const Eigen::Vector3d& a,
                 const Eigen::Vector3d& b, double radius, const Eigen::Vector3d& n_true,
                 const NoiseOptions& noise, std::mt19937* rng, Eigen::Vector3d* n) {
  std::normal_distribution<double> px(0.0, noise.edge_sigma_px);
  Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
  int used = 0;
  for (int i = 0; i < noise.points_per_limb; ++i) {
    const double t = (i + 0.5) / noise.points_per_limb;
    const Eigen::Vector3d p = a + t * (b - a) + radius * n_true;
    Eigen::Vector2d pixel;
    if (camera.Project(p, &pixel) != vision::ProjectionStatus::kOk || !camera.InImage(pixel)) {
      continue;
    }
    pixel += Eigen::Vector2d(px(*rng), px(*rng));
    vision::Ray ray;
    if (camera.BackProject(pixel, &ray) != vision::ProjectionStatus::kOk) continue;
    scatter += ray.d_C * ray.d_C.transpose();
    ++used;
  }
  if (used < noise.min_points) return false;
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(scatter);
  *n = es.eigenvectors().col(0);
  if (n->dot(n_true) < 0.0) *n = -*n;  // the labelling fixes the sign, not the image
  return true;
}

// Calibration data for `truth` at `poses` seen through `geometry`, with edge noise and outliers.
// Outliers replace a limb normal by a wrong one: half tilted by 0.5°–5° about a random axis in the
// plane (an edge fitted partly to a neighbouring contour), half the normal of another leg (the
// edge of the wrong leg). Returns the indices (configuration, leg, limb) of the outliers.
struct Outlier {
  int configuration, leg, limb;
};
HexapodCalibrationData MakeData(const robots::HexapodModel& truth, const Geometry& geometry,
                                const std::vector<Eigen::Isometry3d>& poses,
                                const NoiseOptions& noise, uint32_t seed,
                                std::vector<Outlier>* outliers = nullptr) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  HexapodCalibrationData data;
  data.leg_radius = truth.leg_radius;
  robots::HexapodData ik;
  for (size_t k = 0; k < poses.size(); ++k) {
    robots::InverseKinematics(truth, poses[k], &ik);
    std::array<std::optional<LegLimbs>, robots::kHexapodLegs> configuration;
    for (int j = 0; j < robots::kHexapodLegs; ++j) {
      const Eigen::Vector3d a = geometry.X_CB * truth.p_B_A[j];
      const Eigen::Vector3d b = geometry.X_CB * ik.p_B_B[j];
      Eigen::Vector3d n1, n2;
      if (!vision::render::PredictCylinderLimbs(a, b, truth.leg_radius, &n1, &n2)) continue;
      LegLimbs limbs;
      if (!MeasureLimb(*geometry.camera, a, b, truth.leg_radius, n1, noise, &rng, &limbs.n1_C) ||
          !MeasureLimb(*geometry.camera, a, b, truth.leg_radius, n2, noise, &rng, &limbs.n2_C)) {
        continue;
      }
      configuration[j] = limbs;
    }
    for (int j = 0; j < robots::kHexapodLegs; ++j) {
      if (!configuration[j]) continue;
      for (int limb = 1; limb <= 2; ++limb) {
        if (unit(rng) >= noise.outlier_fraction) continue;
        Eigen::Vector3d& n = limb == 1 ? configuration[j]->n1_C : configuration[j]->n2_C;
        const int other = (j + 1 + static_cast<int>(unit(rng) * 5)) % robots::kHexapodLegs;
        if (unit(rng) < 0.5 && configuration[other]) {
          n = limb == 1 ? configuration[other]->n1_C : configuration[other]->n2_C;
        } else {
          const Eigen::Vector3d axis = n.unitOrthogonal();
          const Eigen::Vector3d tilt_axis =
              Eigen::AngleAxisd(2.0 * common::kPi * unit(rng), n).toRotationMatrix() * axis;
          const double angle = (0.5 + 4.5 * unit(rng)) * common::kPi / 180.0;
          n = Eigen::AngleAxisd(angle, tilt_axis).toRotationMatrix() * n;
        }
        if (outliers) outliers->push_back({static_cast<int>(k), j, limb});
      }
    }
    data.configurations.push_back(configuration);
  }
  return data;
}

struct Errors {
  double rms = 0.0;
  double max = 0.0;
};
Errors ErrorsAgainst(const HexapodCalibrationResult& r, const robots::HexapodModel& truth,
                     const Eigen::Isometry3d& X_CB) {
  Errors e;
  for (int j = 0; j < robots::kHexapodLegs; ++j) {
    const double d = (r.p_C_A[j] - X_CB * truth.p_B_A[j]).norm();
    e.rms += d * d / robots::kHexapodLegs;
    e.max = std::max(e.max, d);
  }
  e.rms = std::sqrt(e.rms);
  return e;
}

TEST(LegCalibrationTest, ExactNormalsRecoverTheBasePointsTheRigidFitAndUnitScale) {
  const robots::HexapodModel truth = TrueModel();
  const robots::HexapodModel cad = robots::HexapodModel::Default();
  for (const Geometry& geometry : {Perspective(), Omni()}) {
    const HexapodCalibrationData data =
        PredictCalibrationData(truth, geometry.X_CB, PlannedPoses());
    for (RobustLoss loss : {RobustLoss::kLeastSquares, RobustLoss::kHuber, RobustLoss::kTukey}) {
      HexapodCalibrationOptions options;
      options.loss = loss;
      const HexapodCalibrationResult r = CalibrateHexapod(data, cad, options);
      ASSERT_TRUE(r.ok()) << ::testing::PrintToString(r.errors);
      for (int j = 0; j < robots::kHexapodLegs; ++j) {
        EXPECT_LT((r.p_C_A[j] - geometry.X_CB * truth.p_B_A[j]).norm(), 1e-9)
            << "leg " << j << " loss " << ToString(loss);
        EXPECT_EQ(r.legs[j].status, LegStatus::kEstimated);
        EXPECT_EQ(r.legs[j].configurations, 60);
        EXPECT_LT(r.legs[j].residual_max, 1e-12);
        EXPECT_LT(r.legs[j].condition_number, options.warn_condition_number);
      }
      EXPECT_THAT(r.down_weighted, IsEmpty());
      // The CAD differs from the truth by ~2 mm per point: the rigid fit lands within that.
      ASSERT_TRUE(r.rigid_fit);
      EXPECT_LT(r.rigid_fit_max, 0.008);
      EXPECT_LT((r.X_CB.translation() - geometry.X_CB.translation()).norm(), 0.005);
      EXPECT_NEAR(r.scale, 1.0, 0.01);
    }
  }
}

// Measured (seed 11, 60 planned poses, 0.5 px, 10 % outliers), max error on A_j: perspective
// least squares 1427 mm, Huber 1134 mm, Tukey 1.8 mm; omni 308 / 213 / 2.1 mm (README).
void ExpectRobustBeatsLeastSquares(const Geometry& geometry, const char* name) {
  const robots::HexapodModel truth = TrueModel();
  NoiseOptions noise;
  noise.outlier_fraction = 0.10;
  std::vector<Outlier> outliers;
  const HexapodCalibrationData data =
      MakeData(truth, geometry, PlannedPoses(), noise, 11, &outliers);
  for (int j = 0; j < robots::kHexapodLegs; ++j) {
    int seen = 0;
    for (const auto& c : data.configurations) seen += c[j].has_value();
    EXPECT_GE(seen, 25) << name << " leg " << j;
  }
  HexapodCalibrationOptions ls_options;
  ls_options.loss = RobustLoss::kLeastSquares;
  const HexapodCalibrationResult ls =
      CalibrateHexapod(data, robots::HexapodModel::Default(), ls_options);
  HexapodCalibrationOptions huber_options;
  huber_options.loss = RobustLoss::kHuber;
  const HexapodCalibrationResult huber =
      CalibrateHexapod(data, robots::HexapodModel::Default(), huber_options);
  const HexapodCalibrationResult tukey = CalibrateHexapod(data, robots::HexapodModel::Default());
  ASSERT_TRUE(ls.ok() && huber.ok() && tukey.ok());
  const Errors e_ls = ErrorsAgainst(ls, truth, geometry.X_CB);
  const Errors e_huber = ErrorsAgainst(huber, truth, geometry.X_CB);
  const Errors e_tukey = ErrorsAgainst(tukey, truth, geometry.X_CB);
  std::printf(
      "[%s] error on A_j (mm): least squares rms %.3f max %.3f | huber rms %.3f max %.3f | "
      "tukey rms %.3f max %.3f | outliers injected %zu, down-weighted %zu\n",
      name, e_ls.rms * 1e3, e_ls.max * 1e3, e_huber.rms * 1e3, e_huber.max * 1e3, e_tukey.rms * 1e3,
      e_tukey.max * 1e3, outliers.size(), tukey.down_weighted.size());
  // Tukey (the default) lands well below the target; Huber's monotone ψ leaves the outliers a
  // pull along eq. 14's weak direction (README), so it only beats plain least squares.
  EXPECT_LT(e_tukey.max, 0.75 * kTarget) << name;
  EXPECT_LT(e_tukey.rms, 0.01 * e_ls.rms) << name;
  EXPECT_LT(e_huber.rms, e_ls.rms) << name;
  EXPECT_GT(e_ls.max, kTarget) << name << ": the outliers should hurt plain least squares";
  // Most injected outliers are among the down-weighted equations (the smallest tilts may hide in
  // the noise, hence not all).
  int found = 0;
  for (const Outlier& o : outliers) {
    for (const DownWeightedEquation& d : tukey.down_weighted) {
      if (d.configuration == o.configuration && d.leg == o.leg && d.limb == o.limb) {
        ++found;
        break;
      }
    }
  }
  EXPECT_GE(found, 0.8 * static_cast<double>(outliers.size())) << name;
  EXPECT_LE(tukey.down_weighted.size(), outliers.size() + 0.05 * 720) << name;
  // Reported per-leg statistics are consistent.
  for (int j = 0; j < robots::kHexapodLegs; ++j) {
    const LegCalibration& leg = tukey.legs[j];
    EXPECT_GT(leg.sigma, 0.0);
    EXPECT_LT(leg.residual_rms_inliers, leg.residual_rms);
    EXPECT_GE(leg.residual_max, leg.residual_rms);
    EXPECT_TRUE(leg.covariance.allFinite());
    EXPECT_GT(leg.covariance.determinant(), 0.0);
  }
}

TEST(LegCalibrationTest, NoisyEdgesWithOutliersPerspectiveRobustBeatsLeastSquaresBelowTarget) {
  ExpectRobustBeatsLeastSquares(Perspective(), "perspective");
}

TEST(LegCalibrationTest, NoisyEdgesWithOutliersOmniRobustBeatsLeastSquaresBelowTarget) {
  ExpectRobustBeatsLeastSquares(Omni(), "omni");
}

// The reported covariance describes the actual error: over repeated noisy runs (no outliers) the
// mean squared Mahalanobis distance of the error is near 3 (three parameters).
TEST(LegCalibrationTest, CovarianceMatchesTheScatterOfRepeatedRuns) {
  const robots::HexapodModel truth = TrueModel();
  const Geometry geometry = Perspective();
  NoiseOptions noise;
  double sum = 0.0;
  int n = 0;
  for (uint32_t seed = 100; seed < 120; ++seed) {
    const HexapodCalibrationResult r = CalibrateHexapod(
        MakeData(truth, geometry, PlannedPoses(), noise, seed), robots::HexapodModel::Default());
    for (int j = 0; j < robots::kHexapodLegs; ++j) {
      const Eigen::Vector3d e = r.p_C_A[j] - geometry.X_CB * truth.p_B_A[j];
      sum += e.dot(r.legs[j].covariance.ldlt().solve(e));
      ++n;
      // The estimator contract's covariance (one identifiability analysis of the weighted
      // system, by SVD) is each leg's own σ²(JᵀWJ)⁻¹ (by LU).
      const Eigen::Matrix3d c = r.estimation.covariance.block<3, 3>(3 * j, 3 * j);
      EXPECT_LT((c - r.legs[j].covariance).norm(), 1e-6 * r.legs[j].covariance.norm()) << j;
    }
    EXPECT_EQ(r.estimation.Validate(), "");
    EXPECT_EQ(r.estimation.status, EstimationStatus::kConverged);
    EXPECT_EQ(r.estimation.identifiability.rank, 18);
  }
  const double mean = sum / n;
  std::printf("mean squared Mahalanobis error over %d leg estimates: %.2f (3 expected)\n", n, mean);
  EXPECT_GT(mean, 1.5);
  EXPECT_LT(mean, 6.0);
}

TEST(LegCalibrationTest, IdenticalConfigurationsAreRefusedAsTooAlike) {
  const robots::HexapodModel truth = TrueModel();
  const Geometry geometry = Perspective();
  const std::vector<Eigen::Isometry3d> same(20, robots::HexapodModel::NominalPose());
  // Exact normals: eq. 14 is singular along each leg.
  const HexapodCalibrationResult exact =
      CalibrateHexapod(PredictCalibrationData(truth, geometry.X_CB, same), truth);
  EXPECT_FALSE(exact.ok());
  ASSERT_EQ(exact.errors.size(), 6u);
  for (int j = 0; j < robots::kHexapodLegs; ++j) {
    EXPECT_EQ(exact.legs[j].status, LegStatus::kConfigurationsTooAlike);
    EXPECT_GT(exact.legs[j].condition_number, 1e4);
    EXPECT_THAT(exact.errors[j],
                ContainsRegex("^leg " + std::to_string(j) + ": configurations too alike.*> 10000"));
    EXPECT_TRUE(std::isnan(exact.p_C_A[j].x()));
  }
  EXPECT_FALSE(exact.rigid_fit);
  EXPECT_EQ(exact.estimation.status, EstimationStatus::kInsufficientData);
  // With edge noise the system is merely ill-conditioned: every leg is at least warned about.
  NoiseOptions noise;
  const HexapodCalibrationResult noisy =
      CalibrateHexapod(MakeData(truth, geometry, same, noise, 5), truth);
  for (int j = 0; j < robots::kHexapodLegs; ++j) {
    EXPECT_GT(noisy.legs[j].condition_number, HexapodCalibrationOptions{}.warn_condition_number);
    bool reported = false;
    for (const auto& m : noisy.errors)
      reported |= m.rfind("leg " + std::to_string(j) + ":", 0) == 0;
    for (const auto& m : noisy.warnings)
      reported |= m.rfind("leg " + std::to_string(j) + ":", 0) == 0;
    EXPECT_TRUE(reported) << "leg " << j;
  }
}

TEST(LegCalibrationTest, ALegSeenInTooFewConfigurationsIsAnErrorNamingIt) {
  const robots::HexapodModel truth = TrueModel();
  const Geometry geometry = Omni();
  HexapodCalibrationData data = PredictCalibrationData(truth, geometry.X_CB, PlannedPoses());
  for (size_t k = 1; k < data.configurations.size(); ++k) data.configurations[k][4].reset();
  const HexapodCalibrationResult r = CalibrateHexapod(data, truth);
  EXPECT_FALSE(r.ok());
  ASSERT_EQ(r.errors.size(), 1u);
  EXPECT_THAT(r.errors[0], ContainsRegex("^leg 4: seen with both limbs in 1 configuration"));
  EXPECT_EQ(r.legs[4].status, LegStatus::kTooFewConfigurations);
  // The other five are estimated and the rigid fit uses them.
  for (int j : {0, 1, 2, 3, 5}) {
    EXPECT_LT((r.p_C_A[j] - geometry.X_CB * truth.p_B_A[j]).norm(), 1e-9);
  }
  ASSERT_TRUE(r.rigid_fit);
  EXPECT_TRUE(std::isnan(r.legs[4].rigid_fit_residual));
  EXPECT_LT(r.rigid_fit_max, 1e-9);
  EXPECT_TRUE(r.X_CB.isApprox(geometry.X_CB, 1e-9));
  // In the contract: leg 4 unidentified, the others identified, the error as the message.
  EXPECT_EQ(r.estimation.status, EstimationStatus::kUnidentified);
  EXPECT_EQ(r.estimation.Validate(), "");
  EXPECT_FALSE(r.estimation.Find("leg4.p_C_A.y")->identified);
  EXPECT_TRUE(std::isinf(r.estimation.Find("leg4.p_C_A.y")->sigma));
  EXPECT_TRUE(r.estimation.Find("leg5.p_C_A.z")->identified);
  EXPECT_THAT(r.estimation.message, ContainsRegex("^leg 4: seen with both limbs"));
  EXPECT_EQ(r.estimation.identifiability.rank, 15);
}

TEST(LegCalibrationTest, RigidFitRecoversAKnownTransformExactly) {
  std::mt19937 rng(3);
  std::normal_distribution<double> g(0.0, 1.0);
  for (int trial = 0; trial < 20; ++trial) {
    Eigen::Isometry3d X_CB = Eigen::Isometry3d::Identity();
    X_CB.linear() =
        Eigen::Quaterniond(g(rng), g(rng), g(rng), g(rng)).normalized().toRotationMatrix();
    X_CB.translation() = Eigen::Vector3d(g(rng), g(rng), g(rng));
    std::vector<Eigen::Vector3d> p_B, p_C;
    for (const auto& a : robots::HexapodModel::Default().p_B_A) {
      p_B.push_back(a);
      p_C.push_back(X_CB * a);
    }
    Eigen::Isometry3d fit;
    ASSERT_TRUE(FitRigidTransform(p_C, p_B, &fit));
    EXPECT_LT((fit.matrix() - X_CB.matrix()).cwiseAbs().maxCoeff(), 1e-12);
    EXPECT_NEAR(fit.linear().determinant(), 1.0, 1e-12);  // proper, also for planar points
  }
  // Degenerate input is refused.
  Eigen::Isometry3d fit;
  const std::vector<Eigen::Vector3d> line = {Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(1, 0, 0),
                                             Eigen::Vector3d(2, 0, 0)};
  EXPECT_FALSE(FitRigidTransform(line, line, &fit));
  EXPECT_FALSE(FitRigidTransform({line[0], line[1]}, {line[0], line[1]}, &fit));
}

// A wrong leg radius scales every A_j (eq. 14 is linear in R); eq. 16 finds the factor and
// correct_scale removes it.
TEST(LegCalibrationTest, ScaleRecoversAWrongLegRadius) {
  const robots::HexapodModel truth = TrueModel();
  const Geometry geometry = Perspective();
  HexapodCalibrationData data = PredictCalibrationData(truth, geometry.X_CB, PlannedPoses());
  data.leg_radius = 1.03 * truth.leg_radius;  // e.g. the paint or a tolerance made it look bigger
  const HexapodCalibrationResult raw = CalibrateHexapod(data, truth);
  EXPECT_NEAR(raw.scale, 1.03, 1e-9);
  EXPECT_NEAR(raw.scale_least_squares, 1.03, 1e-9);
  EXPECT_NEAR(raw.scale_median_ratio, 1.03, 1e-9);
  EXPECT_NEAR(raw.scale_max_ratio, 1.03, 1e-9);
  EXPECT_NEAR((raw.p_C_A[2] - geometry.X_CB * truth.p_B_A[2]).norm(),
              0.03 * (geometry.X_CB * truth.p_B_A[2]).norm(), 1e-9);
  bool warned = false;
  for (const auto& w : raw.warnings) warned |= w.find("scale (eq. 16") != std::string::npos;
  EXPECT_TRUE(warned) << ::testing::PrintToString(raw.warnings);
  HexapodCalibrationOptions options;
  options.correct_scale = true;
  const HexapodCalibrationResult corrected = CalibrateHexapod(data, truth, options);
  EXPECT_TRUE(corrected.scale_corrected);
  for (int j = 0; j < robots::kHexapodLegs; ++j) {
    EXPECT_LT((corrected.p_C_A[j] - geometry.X_CB * truth.p_B_A[j]).norm(), 1e-9);
  }
  EXPECT_LT(corrected.rigid_fit_max, 1e-9);
  // Known scale on random geometry as well, for each estimator.
  std::vector<Eigen::Vector3d> cad(truth.p_B_A.begin(), truth.p_B_A.end()), est;
  for (const auto& p : cad)
    est.push_back(geometry.X_CB.linear() * (0.97 * p) + Eigen::Vector3d(1, 2, 3));
  ScaleEstimates s;
  ASSERT_TRUE(EstimateScale(est, cad, &s));
  EXPECT_NEAR(s.least_squares, 0.97, 1e-12);
  EXPECT_NEAR(s.median_ratio, 0.97, 1e-12);
  EXPECT_NEAR(s.max_ratio, 0.97, 1e-12);
}

// The seed prints eq. 16 as a max over the 15 pairwise ratios though its text says "mean ratio".
// With noisy estimates the max picks the pair whose noise stretched it most: biased upwards. The
// least-squares similarity scale and the median are not (to well within their scatter).
TEST(LegCalibrationTest, MaxRatioScaleIsBiasedUpwardsLeastSquaresAndMedianAreNot) {
  const robots::HexapodModel model = robots::HexapodModel::Default();
  const std::vector<Eigen::Vector3d> cad(model.p_B_A.begin(), model.p_B_A.end());
  std::mt19937 rng(17);
  std::normal_distribution<double> noise(0.0, 0.003);  // 3 mm per axis: the seed's error level
  double sum_ls = 0, sum_med = 0, sum_max = 0, sum2_ls = 0;
  const int trials = 2000;
  for (int t = 0; t < trials; ++t) {
    std::vector<Eigen::Vector3d> est;
    for (const auto& p : cad)
      est.push_back(p + Eigen::Vector3d(noise(rng), noise(rng), noise(rng)));
    ScaleEstimates s;
    ASSERT_TRUE(EstimateScale(est, cad, &s));
    sum_ls += s.least_squares;
    sum2_ls += s.least_squares * s.least_squares;
    sum_med += s.median_ratio;
    sum_max += s.max_ratio;
  }
  const double mean_ls = sum_ls / trials, mean_med = sum_med / trials, mean_max = sum_max / trials;
  const double sd_ls = std::sqrt(sum2_ls / trials - mean_ls * mean_ls);
  std::printf(
      "scale with 3 mm noise, true 1: least squares %.5f (sd %.5f), median %.5f, max %.5f\n",
      mean_ls, sd_ls, mean_med, mean_max);
  EXPECT_NEAR(mean_ls, 1.0, 0.002);
  EXPECT_NEAR(mean_med, 1.0, 0.004);
  EXPECT_GT(mean_max - 1.0, 0.02);         // several per cent too large on average
  EXPECT_GT(mean_max - 1.0, 5.0 * sd_ls);  // far outside the least-squares estimate's scatter
}

TEST(LegCalibrationTest, BadDataAndOptionsAreRefusedWithEveryFieldNamed) {
  HexapodCalibrationData data;
  data.leg_radius = -0.02;
  EXPECT_THAT(data.Validate(), HasSubstr("leg_radius = -0.02"));
  EXPECT_THAT(data.Validate(), HasSubstr("configurations is empty"));
  data.leg_radius = 0.02;
  data.configurations.resize(2);
  data.configurations[1][3] = LegLimbs{Eigen::Vector3d(0, 0, 2), Eigen::Vector3d(1, 0, 0)};
  data.configurations[0][0] = LegLimbs{Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(NAN, 0, 0)};
  const std::string message = data.Validate();
  EXPECT_THAT(message,
              ContainsRegex("configurations\\[1\\] leg 3 n1_C = \\(0 0 2\\).*\\|n\\| = 2"));
  EXPECT_THAT(message, HasSubstr("configurations[0] leg 0 n2_C"));
  EXPECT_THROW(CalibrateHexapod(data, robots::HexapodModel::Default()), std::invalid_argument);

  HexapodCalibrationOptions o;
  o.huber_k = 0;
  o.tukey_c = -1;
  o.max_iterations = 0;
  o.min_scale = 0;
  o.report_weight_below = 2;
  o.warn_condition_number = 10;
  o.max_condition_number = 5;
  o.min_configurations = 1;
  const std::string bad = o.Validate();
  for (const char* field :
       {"huber_k = 0", "tukey_c = -1", "max_iterations = 0", "min_scale = 0",
        "report_weight_below = 2", "max_condition_number = 5", "min_configurations = 1"}) {
    EXPECT_THAT(bad, HasSubstr(field));
  }
  EXPECT_THAT(HexapodCalibrationOptions{}.Validate(), IsEmpty());
  try {
    CalibrateHexapod(PredictCalibrationData(TrueModel(), Perspective().X_CB, PlannedPoses()),
                     robots::HexapodModel::Default(), o);
    ADD_FAILURE() << "bad options accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr("tukey_c = -1"));
  }
}

}  // namespace
}  // namespace kinevis::calibration
