#include "calibration/common/estimation.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <limits>
#include <random>

#include "calibration/common/estimation_yaml_internal.h"

namespace kinevis::calibration {
namespace {

using ::testing::HasSubstr;
constexpr double kInf = std::numeric_limits<double>::infinity();

Eigen::MatrixXd RandomJacobian(int rows, int cols, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> n(0.0, 1.0);
  Eigen::MatrixXd J(rows, cols);
  for (int i = 0; i < rows; ++i) {
    for (int j = 0; j < cols; ++j) J(i, j) = n(rng);
  }
  return J;
}

TEST(AnalyzeIdentifiabilityTest, FullRankGivesTheInverseOfTheNormalMatrixAndItsCondition) {
  Eigen::MatrixXd J = RandomJacobian(40, 4, 1);
  J.col(2) *= 1e-3;  // a parameter in other units: the scaling must not call it unidentified
  const Identifiability a = AnalyzeIdentifiability(J, {"a", "b", "c", "d"});
  EXPECT_EQ(a.parameters, 4);
  EXPECT_EQ(a.rank, 4);
  EXPECT_TRUE(a.unidentified.empty());
  for (bool id : a.identified) EXPECT_TRUE(id);
  // Independent: (JᵀJ)⁻¹ by a direct inverse, and the condition of J D⁻¹ (column norms).
  const Eigen::MatrixXd expected = (J.transpose() * J).inverse();
  EXPECT_LT((a.normal_inverse - expected).norm(), 1e-9 * expected.norm());
  Eigen::MatrixXd Js = J;
  for (int j = 0; j < 4; ++j) Js.col(j).normalize();
  const Eigen::VectorXd sv = Js.jacobiSvd().singularValues();
  EXPECT_NEAR(a.condition_number, sv(0) / sv(3), 1e-9 * a.condition_number);
  EXPECT_DOUBLE_EQ(a.condition_number, a.condition_number_identified);
  ASSERT_EQ(a.singular_values.size(), 4u);
  EXPECT_NEAR(a.singular_values[0], sv(0), 1e-12);
}

TEST(AnalyzeIdentifiabilityTest, TwoColumnsThatOnlyActTogetherAreOneNamedNullDirection) {
  Eigen::MatrixXd J = RandomJacobian(30, 3, 2);
  J.col(1) = -2.0 * J.col(0);  // r depends on x0 − 2·x1 only... in scaled units: x0' + x1'
  const Identifiability a = AnalyzeIdentifiability(J, {"radius", "camera_distance", "alpha"});
  EXPECT_EQ(a.rank, 2);
  EXPECT_EQ(a.condition_number, kInf);
  EXPECT_TRUE(std::isfinite(a.condition_number_identified));
  ASSERT_EQ(a.unidentified.size(), 1u);
  // Scaled columns are s and −s: the null vector is (1, 1)/√2 in scaled units.
  EXPECT_EQ(a.unidentified[0], "0.707 radius + 0.707 camera_distance");
  EXPECT_FALSE(a.identified[0]);
  EXPECT_FALSE(a.identified[1]);
  EXPECT_TRUE(a.identified[2]);
}

TEST(AnalyzeIdentifiabilityTest, AZeroColumnIsUnidentifiedAndCorrelationsAreListed) {
  Eigen::MatrixXd J = RandomJacobian(50, 3, 3);
  J.col(1) = J.col(0) + 1e-4 * J.col(1);  // nearly the same effect: correlation close to ±1
  J.col(2).setZero();
  const Identifiability a = AnalyzeIdentifiability(J, {"x", "y", "z"});
  EXPECT_EQ(a.rank, 2);
  EXPECT_FALSE(a.identified[2]);
  EXPECT_TRUE(a.identified[0]);
  ASSERT_EQ(a.unidentified.size(), 1u);
  EXPECT_EQ(a.unidentified[0], "1.000 z");
  ASSERT_EQ(a.strong_correlations.size(), 1u);
  EXPECT_THAT(a.strong_correlations[0], HasSubstr("x ~ y: -1.000"));
}

TEST(AnalyzeIdentifiabilityTest, BadInputIsNamed) {
  Eigen::MatrixXd J = RandomJacobian(5, 2, 4);
  EXPECT_THAT([&] { AnalyzeIdentifiability(J, {"only one"}); },
              ::testing::ThrowsMessage<std::invalid_argument>(HasSubstr("names")));
  J(1, 1) = std::nan("");
  EXPECT_THAT(
      [&] {
        AnalyzeIdentifiability(J, {"a", "b"});
      },
      ::testing::ThrowsMessage<std::invalid_argument>(HasSubstr("J: must be finite")));
  IdentifiabilityOptions o;
  o.rank_tolerance = 2.0;
  EXPECT_THAT(o.Validate(), HasSubstr("rank_tolerance: must be in (0, 1), got 2"));
}

TEST(SummarizeResidualsTest, MeanRmsAndLargestMagnitude) {
  const ResidualSummary s = SummarizeResiduals("pixel u", "px", {3.0, -4.0, 1.0});
  EXPECT_EQ(s.count, 3);
  EXPECT_DOUBLE_EQ(s.mean, 0.0);
  EXPECT_DOUBLE_EQ(s.rms, std::sqrt(26.0 / 3.0));
  EXPECT_DOUBLE_EQ(s.max_abs, 4.0);
  EXPECT_EQ(SummarizeResiduals("r", "m", {}).count, 0);
}

EstimationReport SampleReport() {
  EstimationReport r;
  r.estimator = "test estimator";
  r.status = EstimationStatus::kUnidentified;
  r.message = "solver: function tolerance reached";
  r.iterations = 7;
  r.initial_cost = 12.5;
  r.final_cost = 0.25;
  r.variance_factor = 1.1;
  r.residuals.push_back(SummarizeResiduals("pixel u", "px", {0.1, -0.2}));
  r.parameters.push_back({"radius", "m", 0.1, 0.1002, 1e-5, true, true});
  r.parameters.push_back({"camera_distance", "m", 0.4, 0.4, kInf, true, false});
  r.parameters.push_back({"held", "rad", 0.0, 0.0, 0.0, false, false});
  r.covariance = Eigen::Matrix3d::Zero();
  r.covariance(0, 0) = 1e-10;
  r.covariance(1, 1) = kInf;
  r.identifiability.parameters = 2;
  r.identifiability.rank = 1;
  r.identifiability.singular_values = {1.0, 0.0};
  r.identifiability.unidentified = {"1.000 camera_distance"};
  r.identifiability.gauges = {"the camera distance is held by the gauge"};
  r.warnings = {"one warning"};
  return r;
}

TEST(EstimationReportTest, ReportsNameStatusParametersAndWarnings) {
  const EstimationReport r = SampleReport();
  EXPECT_EQ(r.Validate(), "");
  EXPECT_FALSE(r.ok());
  EXPECT_THAT(r.BriefReport(), HasSubstr("test estimator: unidentified, 1 of 2 estimated"));
  EXPECT_THAT(r.BriefReport(), HasSubstr("1 warning"));
  const std::string full = r.FullReport();
  EXPECT_THAT(full, HasSubstr("radius = 0.1002 m ± 1e-05"));
  EXPECT_THAT(full, HasSubstr("camera_distance = 0.4 m ± unidentified"));
  EXPECT_THAT(full, HasSubstr("held = 0 rad (held)"));
  EXPECT_THAT(full, HasSubstr("unidentified: 1.000 camera_distance"));
  ASSERT_NE(r.Find("radius"), nullptr);
  EXPECT_EQ(r.Find("nothing"), nullptr);
}

TEST(EstimationReportTest, InconsistentReportsAreNamed) {
  EstimationReport r = SampleReport();
  r.status = EstimationStatus::kConverged;  // with an unidentified parameter
  EXPECT_THAT(r.Validate(), HasSubstr("parameters.camera_distance"));
  r = SampleReport();
  r.covariance = Eigen::Matrix2d::Zero();
  EXPECT_THAT(r.Validate(), HasSubstr("covariance"));
  r = SampleReport();
  r.parameters[2].name = "radius";
  EXPECT_THAT(r.Validate(), HasSubstr("names must be unique"));
}

TEST(EstimationYamlTest, TheBlockReadsBackWhatWasWritten) {
  const EstimationReport r = SampleReport();
  YAML::Emitter out;
  out << YAML::BeginMap;
  internal::EmitEstimation(out, r);
  out << YAML::EndMap;
  ASSERT_TRUE(out.good()) << out.GetLastError();
  internal::CheckedYamlReader in("test file", "memory");
  const EstimationReport b = internal::ReadEstimation(in, YAML::Load(out.c_str()));
  EXPECT_NO_THROW(in.ThrowIfBad());
  EXPECT_EQ(b.estimator, r.estimator);
  EXPECT_EQ(b.status, r.status);
  EXPECT_EQ(b.message, r.message);
  EXPECT_EQ(b.iterations, r.iterations);
  EXPECT_DOUBLE_EQ(b.final_cost, r.final_cost);
  ASSERT_EQ(b.parameters.size(), 3u);
  EXPECT_EQ(b.parameters[1].name, "camera_distance");
  EXPECT_EQ(b.parameters[1].sigma, kInf);
  EXPECT_FALSE(b.parameters[1].identified);
  EXPECT_DOUBLE_EQ(b.parameters[0].value, 0.1002);
  ASSERT_EQ(b.covariance.rows(), 3);
  EXPECT_DOUBLE_EQ(b.covariance(0, 0), 1e-10);
  EXPECT_EQ(b.covariance(1, 1), kInf);
  EXPECT_EQ(b.identifiability.unidentified, r.identifiability.unidentified);
  EXPECT_EQ(b.identifiability.gauges, r.identifiability.gauges);
  EXPECT_EQ(b.warnings, r.warnings);
  ASSERT_EQ(b.residuals.size(), 1u);
  EXPECT_EQ(b.residuals[0].count, 2);
}

TEST(EstimationYamlTest, ABadBlockNamesTheKey) {
  internal::CheckedYamlReader in("test file", "f.yaml");
  internal::ReadEstimation(
      in, YAML::Load("estimation: {status: sideways, parameters: [{name: a}], covariance: 3}"));
  EXPECT_THAT([&] { in.ThrowIfBad(); },
              ::testing::ThrowsMessage<std::invalid_argument>(::testing::AllOf(
                  HasSubstr("test file f.yaml"), HasSubstr("estimation.status: unknown (sideways)"),
                  HasSubstr("estimation.parameters[0].value: missing"),
                  HasSubstr("estimation.covariance: not a list"))));
}

}  // namespace
}  // namespace kinevis::calibration
