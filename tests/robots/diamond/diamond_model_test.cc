#include "robots/diamond/diamond_model.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <random>
#include <stdexcept>
#include <vector>

#include "ceres/jet.h"  // header-only: the scalar type calibration/diamond will use
#include "common/units.h"
#include "tests/utilities/allocation_counter.h"

namespace kinevis::robots {
namespace {

using ::testing::AllOf;
using ::testing::ContainsRegex;
using ::testing::HasSubstr;
using ::testing::IsEmpty;

// Seed 001 eq. (35) exactly as printed, with the sign chosen by `sign` (+1 or −1).
double SeedEquation35(double alpha, double beta, double theta1, double theta2, double sign) {
  const double A = 0.5 * (theta1 - theta2);
  const double sa = std::sin(alpha);
  const double disc = std::pow(std::sin(beta), 2) - std::pow(sa * std::sin(A), 2);
  return 2.0 * std::atan((sa * std::cos(A) + sign * std::sqrt(disc)) /
                         (std::cos(alpha) + std::cos(beta)));
}

std::vector<DiamondModel> SeedModels() {
  return {DiamondModel::APriori(), DiamondModel::SeedIdentified()};
}

// A model with α > β, so that some separations have no assembly and the "−" root is positive.
DiamondModel LongProximalModel() {
  DiamondModel model = DiamondModel::APriori();
  model.alpha = 1.0;
  model.beta = 0.5;
  model.gamma_min = 0.1;
  return model;
}

// Seeded random joint configurations inside the θ and separation limits, with an assembly and
// away from singularities (task condition < 1e2), so accuracy margins hold.
std::vector<Eigen::Vector2d> RandomConfigurations(const DiamondModel& model, int count,
                                                  std::mt19937* rng) {
  std::uniform_real_distribution<double> phi(model.phi_min, model.phi_max);
  std::uniform_real_distribution<double> separation(model.separation_min, model.separation_max);
  std::vector<Eigen::Vector2d> out;
  DiamondData data;
  for (int attempt = 0; attempt < 100 * count && static_cast<int>(out.size()) < count; ++attempt) {
    const double p = phi(*rng);
    const double s = separation(*rng);
    const Eigen::Vector2d q(p + s / 2 - model.joint_offsets[0], p - s / 2 - model.joint_offsets[1]);
    ForwardKinematics(model, q, &data);
    if (!data.valid) continue;
    if (AnalyzeSingularity(model, data).task_condition > 1e2) continue;
    out.push_back(q);
  }
  return out;
}

TEST(DiamondModelTest, SeedParameterSetsAreTableI) {
  const DiamondModel a_priori = DiamondModel::APriori();
  EXPECT_THAT(a_priori.Validate(), IsEmpty());
  EXPECT_DOUBLE_EQ(a_priori.radius, 0.2000);
  EXPECT_NEAR(a_priori.alpha, 0.7854, 5e-5);
  EXPECT_NEAR(a_priori.beta, 0.7854, 5e-5);
  const DiamondModel identified = DiamondModel::SeedIdentified();
  EXPECT_THAT(identified.Validate(), IsEmpty());
  EXPECT_DOUBLE_EQ(identified.radius, 0.2221);
  EXPECT_DOUBLE_EQ(identified.alpha, 0.7634);
  EXPECT_DOUBLE_EQ(identified.beta, 0.8037);
  for (const DiamondModel& model : SeedModels()) {
    EXPECT_EQ(model.joint_offsets[0], 0.0);
    EXPECT_EQ(model.joint_offsets[1], 0.0);
    EXPECT_NO_THROW(DiamondModel::Checked(model));
    // The seed's quarter sphere (φ ∈ [0, π]) and its validation lines (seed §V-C) lie inside.
    EXPECT_EQ(model.phi_min, 0.0);
    EXPECT_NEAR(model.phi_max, common::kPi, 1e-15);
  }
}

TEST(DiamondModelTest, InvalidModelNamesEveryBadField) {
  DiamondModel model = DiamondModel::APriori();
  model.radius = -0.1;
  model.alpha = 0.0;
  model.beta = 3.5;
  model.joint_offsets[1] = std::numeric_limits<double>::quiet_NaN();
  const std::string message = model.Validate();
  EXPECT_THAT(message, AllOf(HasSubstr("radius = -0.1"), HasSubstr("alpha = 0 "),
                             HasSubstr("beta = 3.5"), HasSubstr("joint_offsets[1] = nan")));
  try {
    DiamondModel::Checked(model);
    ADD_FAILURE() << "Checked() did not throw";
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), ContainsRegex("radius = -0\\.1 must be .*alpha = 0 .*beta = 3\\.5"));
  }

  DiamondModel wide = DiamondModel::APriori();
  wide.alpha = 2.0;
  wide.beta = 1.5;
  EXPECT_THAT(wide.Validate(), HasSubstr("alpha + beta = 3.5"));

  DiamondModel limits = DiamondModel::APriori();
  limits.theta_min[0] = 1.0;
  limits.theta_max[0] = 0.5;
  limits.separation_min = 0.0;
  limits.gamma_max = 4.0;
  limits.phi_max = -1.0;
  EXPECT_THAT(limits.Validate(), AllOf(HasSubstr("theta_min[0] = 1, theta_max[0] = 0.5"),
                                       HasSubstr("separation_min = 0,"), HasSubstr("gamma_max = 4"),
                                       HasSubstr("phi_max = -1")));
  EXPECT_THROW(DiamondModel::Checked(limits), std::invalid_argument);
}

// Hand computation for α = β = π/4: eq. (35) with the "+" sign reduces to tan(γ/2) = cos A.
// θ_1 = π/2 + π/3, θ_2 = π/2 − π/3: φ = π/2, A = π/3, tan(γ/2) = 1/2, so sin γ = 4/5,
// cos γ = 3/5, u = (0, 4/5, 3/5), p = 0.2 u = (0, 0.16, 0.12) m; γ_A = −2 sA/(1 + c²A) = −2√3/2.5.
TEST(DiamondModelTest, HandComputedPoseMatches) {
  const DiamondModel model = DiamondModel::APriori();
  DiamondData data;
  const DiamondReachability reach = ForwardKinematics(
      model, Eigen::Vector2d(common::kPi / 2 + common::kPi / 3, common::kPi / 2 - common::kPi / 3),
      &data);
  EXPECT_TRUE(reach.ok()) << reach.Describe();
  ASSERT_TRUE(data.valid);
  EXPECT_NEAR(data.task[0], common::kPi / 2, 1e-15);
  EXPECT_NEAR(data.task[1], 2 * std::atan(0.5), 1e-15);
  EXPECT_NEAR((data.u_O - Eigen::Vector3d(0.0, 0.8, 0.6)).norm(), 0.0, 1e-15);
  EXPECT_NEAR((data.p_O_T - Eigen::Vector3d(0.0, 0.16, 0.12)).norm(), 0.0, 1e-15);
  EXPECT_NEAR(data.dgamma_dA, -2.0 * std::sqrt(3.0) / 2.0 / 1.25, 1e-14);

  // The centre of the seed's camera view, (φ, γ) = (π/2, π/4): tan(π/8) = cos A, limbs symmetric
  // about φ (θ_1 + θ_2 = π, the seed's "vertical" validation line, §V-C).
  Eigen::Vector2d q;
  const DiamondReachability centre =
      InverseKinematics(model, Eigen::Vector2d(common::kPi / 2, common::kPi / 4), &q);
  EXPECT_TRUE(centre.ok()) << centre.Describe();
  const double A = std::acos(std::tan(common::kPi / 8));
  EXPECT_NEAR(q[0], common::kPi / 2 + A, 1e-14);
  EXPECT_NEAR(q[1], common::kPi / 2 - A, 1e-14);
}

TEST(DiamondModelTest, ForwardKinematicsIsSeedEquation35WithThePlusSign) {
  std::mt19937 rng(1);
  for (const DiamondModel& model : SeedModels()) {
    for (const Eigen::Vector2d& q : RandomConfigurations(model, 200, &rng)) {
      DiamondData data;
      ForwardKinematics(model, q, &data);
      ASSERT_TRUE(data.valid);
      EXPECT_NEAR(data.task[0], 0.5 * (q[0] + q[1]), 1e-14);  // eq. (34)
      const double plus = SeedEquation35(model.alpha, model.beta, q[0], q[1], +1.0);
      const double minus = SeedEquation35(model.alpha, model.beta, q[0], q[1], -1.0);
      EXPECT_NEAR(data.task[1], plus, 1e-12);
      EXPECT_GT(std::abs(data.task[1] - minus), 1e-3);
    }
  }
}

// The closure w_i · u = cos β holds on both roots; the "+" root is the convex rhombus (u and z_O
// on opposite sides of the plane of w_1, w_2), the "−" root is folded (same side); for α = β the
// "−" root is γ = 0: both distal links lie back on the proximal ones.
TEST(DiamondModelTest, PlusBranchIsTheConvexNonFoldedRhombus) {
  std::mt19937 rng(2);
  for (const DiamondModel& model : SeedModels()) {
    for (const Eigen::Vector2d& q : RandomConfigurations(model, 200, &rng)) {
      DiamondData data;
      ForwardKinematics(model, q, &data);
      ASSERT_TRUE(data.valid);
      EXPECT_NEAR(data.u_O.norm(), 1.0, 1e-15);
      EXPECT_NEAR(data.p_O_T.norm(), model.radius, 1e-15);
      const Eigen::Vector3d n = data.w_O[0].cross(data.w_O[1]);
      for (int i = 0; i < 2; ++i)
        EXPECT_NEAR(data.w_O[i].dot(data.u_O), std::cos(model.beta), 1e-14);
      EXPECT_LT(n.dot(Eigen::Vector3d::UnitZ()) * n.dot(data.u_O), 0.0);
      const double minus = SeedEquation35(model.alpha, model.beta, q[0], q[1], -1.0);
      const Eigen::Vector3d u_minus = DiamondToolAxis(data.task[0], minus);
      for (int i = 0; i < 2; ++i)
        EXPECT_NEAR(data.w_O[i].dot(u_minus), std::cos(model.beta), 1e-14);
      EXPECT_GE(n.dot(Eigen::Vector3d::UnitZ()) * n.dot(u_minus), -1e-15);
      if (model.alpha == model.beta) {
        EXPECT_NEAR(minus, 0.0, 1e-14);
      }
    }
  }
}

TEST(DiamondModelTest, InverseThenForwardRoundTripsOverTheWorkspace) {
  std::mt19937 rng(3);
  for (const DiamondModel& model : SeedModels()) {
    std::uniform_real_distribution<double> phi(model.phi_min, model.phi_max);
    std::uniform_real_distribution<double> gamma(model.gamma_min, model.gamma_max);
    int tested = 0;
    double worst_task = 0.0;
    double worst_point = 0.0;
    for (int k = 0; k < 500; ++k) {
      const Eigen::Vector2d task(phi(rng), gamma(rng));
      Eigen::Vector2d q;
      const DiamondReachability reach = InverseKinematics(model, task, &q);
      // Every point of the box is in the workspace for both seed sets (the limits were chosen so).
      ASSERT_TRUE(reach.ok()) << reach.Describe();
      EXPECT_TRUE(CheckWorkspace(model, task).ok());
      DiamondData data;
      ASSERT_TRUE(ForwardKinematics(model, q, &data).ok());
      worst_task = std::max(worst_task, (data.task - task).cwiseAbs().maxCoeff());
      const Eigen::Vector3d p = DiamondToolPoint(model.radius, task[0], task[1]);
      worst_point = std::max(worst_point, (data.p_O_T - p).norm());
      Eigen::Vector2d q_from_direction;
      ASSERT_TRUE(InverseKinematicsFromDirection(model, 3.0 * data.u_O, &q_from_direction).ok());
      EXPECT_NEAR((q_from_direction - q).cwiseAbs().maxCoeff(), 0.0, 1e-12);
      ++tested;
    }
    EXPECT_EQ(tested, 500);
    std::printf(
        "R = %.4f m: IK->FK worst |d(phi, gamma)| = %.2e rad, |dp| = %.2e m over %d points\n",
        model.radius, worst_task, worst_point, tested);
    EXPECT_LT(worst_task, 1e-12);
    EXPECT_LT(worst_point, 1e-13);
  }
}

TEST(DiamondModelTest, ForwardThenInverseRoundTripsWithJointOffsets) {
  std::mt19937 rng(4);
  for (DiamondModel model : SeedModels()) {
    model.joint_offsets = {0.013, -0.021};
    double worst = 0.0;
    const std::vector<Eigen::Vector2d> sample = RandomConfigurations(model, 300, &rng);
    ASSERT_EQ(sample.size(), 300u);
    for (const Eigen::Vector2d& q : sample) {
      DiamondData data;
      ForwardKinematics(model, q, &data);
      ASSERT_TRUE(data.valid);
      EXPECT_NEAR((data.theta - q - Eigen::Vector2d(0.013, -0.021)).norm(), 0.0, 1e-15);
      Eigen::Vector2d q_back;
      const DiamondReachability reach = InverseKinematics(model, data.task, &q_back);
      ASSERT_FALSE(reach.Has(DiamondReach::kUnreachable));
      ASSERT_FALSE(reach.Has(DiamondReach::kFoldedBranchOnly));
      worst = std::max(worst, (q_back - q).cwiseAbs().maxCoeff());
    }
    std::printf("R = %.4f m: FK->IK worst |dq| = %.2e rad over %zu configurations\n", model.radius,
                worst, sample.size());
    EXPECT_LT(worst, 1e-10);
  }
}

// Central differences, step h = 1e-6 rad: truncation O(h²) ~ 1e-12, rounding ~ 1e-10.
TEST(DiamondModelTest, JacobiansMatchCentralDifferences) {
  constexpr double kStep = 1e-6;
  std::mt19937 rng(5);
  for (DiamondModel model : SeedModels()) {
    model.joint_offsets = {0.01, 0.02};
    double worst = 0.0;
    const std::vector<Eigen::Vector2d> sample = RandomConfigurations(model, 100, &rng);
    ASSERT_EQ(sample.size(), 100u);
    for (const Eigen::Vector2d& q : sample) {
      DiamondData data;
      ForwardKinematics(model, q, &data);
      const Eigen::Matrix2d J_task = TaskJacobian(data);
      const Matrix32d J_point = ToolPointJacobian(model, data);
      for (int j = 0; j < 2; ++j) {
        DiamondData plus;
        DiamondData minus;
        ForwardKinematics(model, q + kStep * Eigen::Vector2d::Unit(j), &plus);
        ForwardKinematics(model, q - kStep * Eigen::Vector2d::Unit(j), &minus);
        ASSERT_TRUE(plus.valid && minus.valid);
        const Eigen::Vector2d fd_task = (plus.task - minus.task) / (2 * kStep);
        const Eigen::Vector3d fd_point = (plus.p_O_T - minus.p_O_T) / (2 * kStep);
        EXPECT_NEAR((J_task.col(j) - fd_task).norm(), 0.0, 1e-7 * (1.0 + fd_task.norm()))
            << "column " << j;
        EXPECT_NEAR((J_point.col(j) - fd_point).norm(), 0.0, 1e-7 * (1.0 + fd_point.norm()))
            << "column " << j;
        worst = std::max({worst, (J_task.col(j) - fd_task).norm() / (1.0 + fd_task.norm()),
                          (J_point.col(j) - fd_point).norm() / (1.0 + fd_point.norm())});
      }
    }
    std::printf("R = %.4f m: worst Jacobian vs central difference (relative) = %.2e\n",
                model.radius, worst);
  }
}

// The templates carry derivatives with respect to the parameters (what Ceres Jets will do in
// calibration/diamond): ceres::Jet against central differences in R, α, β and the offsets.
TEST(DiamondModelTest, TemplatesDifferentiateWithRespectToParameters) {
  using Derivatives = Eigen::Matrix<double, 5, 1>;
  using AD = ceres::Jet<double, 5>;
  constexpr double kStep = 1e-6;
  std::mt19937 rng(6);
  for (const DiamondModel& model : SeedModels()) {
    for (const Eigen::Vector2d& q : RandomConfigurations(model, 30, &rng)) {
      const Derivatives x0(model.radius, model.alpha, model.beta, 0.0, 0.0);
      auto evaluate = [&](const Derivatives& x, double* phi, double* gamma, Eigen::Vector3d* p) {
        Eigen::Vector3d point = Eigen::Vector3d::Zero();
        const DiamondSolve solve = DiamondToolPointFromJoints<double>(
            x[0], x[1], x[2], x[3], x[4], q[0], q[1], phi, gamma, &point);
        ASSERT_EQ(solve, DiamondSolve::kOk);
        *p = point;
      };
      AD params[5];
      for (int k = 0; k < 5; ++k) params[k] = AD(x0[k], k);
      AD phi;
      AD gamma;
      Eigen::Matrix<AD, 3, 1> p;
      ASSERT_EQ(DiamondToolPointFromJoints<AD>(params[0], params[1], params[2], params[3],
                                               params[4], AD(q[0]), AD(q[1]), &phi, &gamma, &p),
                DiamondSolve::kOk);
      for (int k = 0; k < 5; ++k) {
        double phi_p, gamma_p, phi_m, gamma_m;
        Eigen::Vector3d p_p, p_m;
        evaluate(x0 + kStep * Derivatives::Unit(k), &phi_p, &gamma_p, &p_p);
        evaluate(x0 - kStep * Derivatives::Unit(k), &phi_m, &gamma_m, &p_m);
        EXPECT_NEAR(gamma.v[k], (gamma_p - gamma_m) / (2 * kStep), 1e-7) << k;
        EXPECT_NEAR(phi.v[k], (phi_p - phi_m) / (2 * kStep), 1e-7) << k;
        for (int r = 0; r < 3; ++r) {
          EXPECT_NEAR(p[r].v[k], (p_p[r] - p_m[r]) / (2 * kStep), 1e-7) << k;
        }
      }
      // Values agree with the double API.
      DiamondData data;
      ForwardKinematics(model, q, &data);
      EXPECT_NEAR(gamma.a, data.task[1], 1e-15);
      EXPECT_NEAR(p[2].a, data.p_O_T.z(), 1e-15);
    }
  }
}

TEST(DiamondModelTest, OutOfWorkspaceInputReturnsStatusNotNaN) {
  const DiamondModel model = DiamondModel::APriori();
  Eigen::Vector2d q(99.0, 99.0);
  // γ beyond α + β: no joint angles close the limbs there; also outside the box.
  DiamondReachability reach = InverseKinematics(model, Eigen::Vector2d(common::kPi / 2, 1.7), &q);
  EXPECT_TRUE(reach.Has(DiamondReach::kUnreachable));
  EXPECT_TRUE(reach.Has(DiamondReach::kGammaOutside));
  EXPECT_EQ(q, Eigen::Vector2d(99.0, 99.0));  // untouched
  EXPECT_THAT(reach.Describe(), AllOf(HasSubstr("unreachable: cos A = 1.13"),
                                      ContainsRegex("gamma = 1\\.7 rad outside the workspace")));
  // φ below the box: θ_2 = φ − A falls below its stop too.
  reach = CheckWorkspace(model, Eigen::Vector2d(-0.8, common::kPi / 4));
  EXPECT_EQ(reach.first(), DiamondReach::kPhiOutside);
  EXPECT_TRUE(reach.Has(DiamondReach::kBelowThetaMin));
  EXPECT_THAT(reach.Describe(), ContainsRegex("theta_2 = -1\\.9[0-9]* rad below theta_min\\[1\\]"));
  // Non-finite input.
  reach = InverseKinematics(model, Eigen::Vector2d(std::nan(""), 0.5), &q);
  EXPECT_EQ(reach.first(), DiamondReach::kInvalidInput);
  EXPECT_FALSE(InverseKinematicsFromDirection(model, Eigen::Vector3d::Zero(), &q).ok());

  DiamondData data;
  reach = ForwardKinematics(model, Eigen::Vector2d(std::nan(""), 0.0), &data);
  EXPECT_EQ(reach.first(), DiamondReach::kInvalidInput);
  EXPECT_FALSE(data.valid);
  // Joint beyond its stop: the pose is still computed, the stop is named.
  reach = ForwardKinematics(model, Eigen::Vector2d(4.9, 4.0), &data);
  EXPECT_TRUE(data.valid);
  EXPECT_TRUE(reach.Has(DiamondReach::kAboveThetaMax));
  EXPECT_THAT(reach.Describe(),
              ContainsRegex("theta_1 = 4\\.9 rad above theta_max\\[0\\] = 4\\.71"));
  // Crossed limbs (θ_1 < θ_2): the other assembly mode, reported as a collision.
  reach = ForwardKinematics(model, Eigen::Vector2d(1.0, 1.5), &data);
  EXPECT_TRUE(reach.Has(DiamondReach::kLimbsTooClose));
  EXPECT_THAT(reach.Describe(), HasSubstr("theta_1 - theta_2 = -0.5 rad below separation_min"));
}

TEST(DiamondModelTest, NoAssemblyAndFoldedBranchAreReported) {
  const DiamondModel model = LongProximalModel();  // α = 1.0 > β = 0.5
  ASSERT_THAT(model.Validate(), IsEmpty());
  // sin²β = 0.230 < (sin α sin A)² = 0.708 · sin²1.0 = 0.501: the distal links cannot meet.
  DiamondData data;
  DiamondReachability reach = ForwardKinematics(model, Eigen::Vector2d(2.5, 0.5), &data);
  EXPECT_TRUE(reach.Has(DiamondReach::kNoAssembly));
  EXPECT_FALSE(data.valid);
  EXPECT_THAT(reach.Describe(), HasSubstr("no assembly at theta_1 - theta_2 = 2 rad"));
  EXPECT_TRUE(std::isfinite(data.task[1]));

  // The "−" root at A = 0.3 has γ > 0 for this model; it is not reachable on our branch.
  const double theta1 = 1.5 + 0.3;
  const double theta2 = 1.5 - 0.3;
  const double folded = SeedEquation35(model.alpha, model.beta, theta1, theta2, -1.0);
  ASSERT_GT(folded, 0.3);
  Eigen::Vector2d q;
  reach = InverseKinematics(model, Eigen::Vector2d(1.5, folded), &q);
  EXPECT_EQ(reach.first(), DiamondReach::kFoldedBranchOnly);
  EXPECT_THAT(reach.Describe(), HasSubstr("folded (colliding) branch"));
  // While the "+" root at the same A round-trips.
  const double open = SeedEquation35(model.alpha, model.beta, theta1, theta2, +1.0);
  reach = InverseKinematics(model, Eigen::Vector2d(1.5, open), &q);
  EXPECT_FALSE(reach.Has(DiamondReach::kFoldedBranchOnly)) << reach.Describe();
  EXPECT_NEAR((q - Eigen::Vector2d(theta1, theta2)).norm(), 0.0, 1e-12);
}

TEST(DiamondModelTest, SingularitiesAreReportedWithTheirCause) {
  const DiamondModel model = DiamondModel::APriori();
  DiamondData data;
  // Home (3-4-5) pose: well conditioned.
  ForwardKinematics(
      model, Eigen::Vector2d(common::kPi / 2 + common::kPi / 3, common::kPi / 2 - common::kPi / 3),
      &data);
  DiamondSingularityReport report = AnalyzeSingularity(model, data);
  EXPECT_EQ(report.kind, DiamondSingularity::kNone);
  EXPECT_NEAR(report.task_condition, 2.0 * std::sqrt(3.0) / 2.0 / 1.25, 1e-12);
  EXPECT_LT(report.point_condition, 2.0);
  // Limbs almost on top of each other (A = 1e-6): γ_A → 0.
  ForwardKinematics(model, Eigen::Vector2d(1.0 + 1e-6, 1.0 - 1e-6), &data);
  report = AnalyzeSingularity(model, data);
  EXPECT_EQ(report.kind, DiamondSingularity::kLimbsAligned);
  EXPECT_GT(report.task_condition, 1e5);
  // Tool axis near z_O (α = β, A → π/2): only the coordinates degenerate.
  ForwardKinematics(
      model, Eigen::Vector2d(1.0 + common::kPi / 2 - 1e-6, 1.0 - common::kPi / 2 + 1e-6), &data);
  report = AnalyzeSingularity(model, data);
  EXPECT_EQ(report.kind, DiamondSingularity::kToolOnBaseAxis);
  EXPECT_LT(report.task_condition, 3.0);
  EXPECT_GT(report.point_condition, 1e5);
  // α > β: approaching the no-assembly boundary sin A = sin β / sin α the roots merge.
  const DiamondModel long_proximal = LongProximalModel();
  const double A_boundary = std::asin(std::sin(0.5) / std::sin(1.0));
  ForwardKinematics(long_proximal,
                    Eigen::Vector2d(1.0 + A_boundary - 1e-10, 1.0 - A_boundary + 1e-10), &data);
  ASSERT_TRUE(data.valid);
  report = AnalyzeSingularity(long_proximal, data);
  EXPECT_EQ(report.kind, DiamondSingularity::kBranchesMerge);
  EXPECT_GT(report.task_condition, 1e3);
}

TEST(DiamondModelTest, KinematicsDoNotAllocate) {
  const DiamondModel model = DiamondModel::SeedIdentified();
  DiamondData data;
  Eigen::Vector2d q;
  double sink = 0.0;
  const long before = kinevis::testing::ThreadAllocations();
  for (int k = 0; k < 100; ++k) {
    const double phi = 0.2 + 0.02 * k;
    DiamondReachability reach = InverseKinematics(model, Eigen::Vector2d(phi, 0.7), &q);
    reach = ForwardKinematics(model, q, &data);
    sink += TaskJacobian(data).sum() + ToolPointJacobian(model, data).sum();
    sink += AnalyzeSingularity(model, data).point_condition;
    reach = InverseKinematicsFromDirection(model, data.u_O, &q);
    reach = CheckWorkspace(model, Eigen::Vector2d(-phi, 2.0));  // fails: records issues
    sink += reach.count;
  }
  EXPECT_EQ(kinevis::testing::ThreadAllocations() - before, 0);
  EXPECT_TRUE(std::isfinite(sink));
}

}  // namespace
}  // namespace kinevis::robots
