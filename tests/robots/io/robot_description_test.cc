#include "robots/io/robot_description.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>

#include "hal/mock/weld_robot_sim.h"

namespace kinevis::robots {
namespace {

using ::testing::AllOf;
using ::testing::HasSubstr;

const std::string kSource = KINEVIS_SOURCE_DIR;

std::string WriteTemp(const std::string& name, const std::string& text) {
  const auto path = std::filesystem::temp_directory_path() /
                    ("kinevis_robot_description_" + std::to_string(::getpid()) + "_" + name);
  std::ofstream(path) << text;
  return path.string();
}

std::string LoadError(const std::function<void()>& load) {
  try {
    load();
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "(no error)";
}

TEST(RobotDescription, ShippedHexapodFileIsTheDefaultModel) {
  const std::string path = kSource + "/robots/hexapod/hexapod.yaml";
  EXPECT_EQ(ReadRobotKind(path), "hexapod");
  const HexapodDescription d = LoadHexapodDescription(path);
  const HexapodModel expected = HexapodModel::Default();
  for (int j = 0; j < kHexapodLegs; ++j) {
    EXPECT_LT((d.model.p_B_A[j] - expected.p_B_A[j]).norm(), 1e-12) << "A_" << j;
    EXPECT_LT((d.model.p_P_B[j] - expected.p_P_B[j]).norm(), 1e-12) << "B_" << j;
    EXPECT_DOUBLE_EQ(d.model.q0[j], expected.q0[j]);
  }
  EXPECT_DOUBLE_EQ(d.model.leg_radius, expected.leg_radius);
  EXPECT_DOUBLE_EQ(d.model.leg_length_min, expected.leg_length_min);
  EXPECT_DOUBLE_EQ(d.model.leg_length_max, expected.leg_length_max);
  EXPECT_TRUE(d.X_BP_home.isApprox(HexapodModel::NominalPose(), 1e-12));
  EXPECT_EQ(d.name, "kinevis-default-hexapod");
}

TEST(RobotDescription, ShippedWeld5FileIsTheSeedModelAndTheSimulatorsLimits) {
  const std::string path = kSource + "/robots/weld5/weld5.yaml";
  EXPECT_EQ(ReadRobotKind(path), "weld5");
  const Weld5Description d = LoadWeld5Description(path);
  const Weld5Model expected = Weld5Model::Seed(Weld5TorchTransform(0.025, 0.250, 0.0));
  for (int i = 0; i < kWeld5Joints; ++i) {
    SCOPED_TRACE(Weld5JointName(i));
    const DhJoint& a = d.model.joints[i];
    const DhJoint& b = expected.joints[i];
    EXPECT_NEAR(a.a, b.a, 1e-15);
    EXPECT_NEAR(a.alpha, b.alpha, 1e-15);
    EXPECT_NEAR(a.d, b.d, 1e-15);
    EXPECT_NEAR(a.theta_offset, b.theta_offset, 1e-15);
    EXPECT_EQ(a.prismatic, b.prismatic);
  }
  EXPECT_LT((d.model.q_min - expected.q_min).norm(), 1e-12);
  EXPECT_LT((d.model.q_max - expected.q_max).norm(), 1e-12);
  EXPECT_LT((d.model.qd_max - expected.qd_max).norm(), 1e-12);
  EXPECT_TRUE(d.model.X_5T.isApprox(expected.X_5T, 1e-12));
  // One source of truth for the limits: the weld-robot simulator's defaults agree.
  const auto sim = hal::WeldRobotSim::DefaultJointLimits();
  for (int i = 0; i < kWeld5Joints; ++i) {
    SCOPED_TRACE(Weld5JointName(i));
    EXPECT_NEAR(sim[i].min, d.model.q_min(i), 1e-12);
    EXPECT_NEAR(sim[i].max, d.model.q_max(i), 1e-12);
    EXPECT_NEAR(sim[i].max_speed, d.model.qd_max(i), 1e-12);
  }
}

void ExpectSameDiamond(const DiamondModel& a, const DiamondModel& b) {
  EXPECT_NEAR(a.radius, b.radius, 1e-15);
  EXPECT_NEAR(a.alpha, b.alpha, 1e-12);
  EXPECT_NEAR(a.beta, b.beta, 1e-12);
  for (int i = 0; i < kDiamondJoints; ++i) {
    EXPECT_NEAR(a.joint_offsets[i], b.joint_offsets[i], 1e-12);
    EXPECT_NEAR(a.theta_min[i], b.theta_min[i], 1e-12);
    EXPECT_NEAR(a.theta_max[i], b.theta_max[i], 1e-12);
  }
  EXPECT_NEAR(a.separation_min, b.separation_min, 1e-12);
  EXPECT_NEAR(a.separation_max, b.separation_max, 1e-12);
  EXPECT_NEAR(a.phi_min, b.phi_min, 1e-12);
  EXPECT_NEAR(a.phi_max, b.phi_max, 1e-12);
  EXPECT_NEAR(a.gamma_min, b.gamma_min, 1e-12);
  EXPECT_NEAR(a.gamma_max, b.gamma_max, 1e-12);
}

TEST(RobotDescription, ShippedDiamondFilesAreTheSeedsTwoParameterSets) {
  const std::string apriori = kSource + "/robots/diamond/diamond_apriori.yaml";
  const std::string identified = kSource + "/robots/diamond/diamond_identified.yaml";
  EXPECT_EQ(ReadRobotKind(apriori), "diamond");
  ExpectSameDiamond(LoadDiamondDescription(apriori).model, DiamondModel::APriori());
  ExpectSameDiamond(LoadDiamondDescription(identified).model, DiamondModel::SeedIdentified());
}

TEST(RobotDescription, DiamondErrorsNameTheKeys) {
  const std::string path = WriteTemp("diamond_bad.yaml", R"(
robot: diamond
radius: -0.2
alpha_deg: 45
beta: 0.78
beta_deg: 45
joint_offsets: [0]
theta_min_deg: [0, -90]
theta_max_deg: [270, 180]
separation_min_deg: 20
separation_max_deg: 170
phi_min: 0
phi_max_deg: 180
gamma_max_deg: 85
)");
  EXPECT_THAT(LoadError([&] { LoadDiamondDescription(path); }),
              AllOf(HasSubstr("beta and beta_deg: give one, not both"),
                    HasSubstr("joint_offsets: need a list of 2 numbers, got 1"),
                    HasSubstr("gamma_min (or gamma_min_deg): missing")));
  std::filesystem::remove(path);
}

TEST(RobotDescription, ExplicitPointsAndPerLegOffsetsAreRead) {
  const std::string path = WriteTemp("explicit.yaml", R"(
robot: hexapod
base_points: [[0.3, 0, 0], [0.2, 0.2, 0], [-0.1, 0.3, 0], [-0.3, 0.05, 0], [-0.1, -0.3, 0], [0.2, -0.2, 0]]
platform_points: [[0.1, 0.05, 0], [0.05, 0.1, 0], [-0.1, 0.05, 0], [-0.1, -0.05, 0], [0.0, -0.12, 0], [0.08, -0.08, 0]]
leg_radius_mm: 25
leg_length: {min_mm: 300, max: 0.6}
joint_offsets: [0.30, 0.31, 0.32, 0.33, 0.34, 0.35]
)");
  const HexapodDescription d = LoadHexapodDescription(path);
  EXPECT_DOUBLE_EQ(d.model.leg_radius, 0.025);
  EXPECT_DOUBLE_EQ(d.model.leg_length_min, 0.300);
  EXPECT_DOUBLE_EQ(d.model.leg_length_max, 0.6);
  EXPECT_DOUBLE_EQ(d.model.q0[3], 0.33);
  EXPECT_TRUE(d.model.p_B_A[3].isApprox(Eigen::Vector3d(-0.3, 0.05, 0)));
  EXPECT_TRUE(d.X_BP_home.isApprox(Eigen::Isometry3d::Identity()));
  std::filesystem::remove(path);
}

TEST(RobotDescription, EveryBadKeyIsNamedInOneMessage) {
  const std::string path = WriteTemp("bad.yaml", R"(
robot: hexapod
base_points: [[0.3, 0, 0], [0.2, 0.2], [-0.1, 0.3, 0], [-0.3, 0.05, 0], [-0.1, -0.3, 0], [0.2, -0.2, 0]]
platform_points_polar: {radius: 0.15, angles_deg: [1, 2, 3]}
leg_radius: -0.02
leg_radius_mm: 20
leg_length: {min: abc, max: 0.6}
joint_offsets: 0.35
)");
  const std::string message = LoadError([&] { LoadHexapodDescription(path); });
  EXPECT_THAT(message,
              AllOf(HasSubstr(path), HasSubstr("base_points[1]: need a list of 3 numbers, got 2"),
                    HasSubstr("platform_points_polar.angles_deg: need a list of 6 numbers"),
                    HasSubstr("leg_radius and leg_radius_mm: give one, not both"),
                    HasSubstr("leg_length.min: expected a finite number, got 'abc'")));
  std::filesystem::remove(path);
}

TEST(RobotDescription, ModelValidationProblemsAreReported) {
  const std::string path = WriteTemp("invalid.yaml", R"(
robot: hexapod
base_points_polar: {radius: 0.30, angles_deg: [0, 0, 110, 130, 230, 250]}
platform_points_polar: {radius: 0.15, angles_deg: [-50, 50, 70, 170, 190, 290]}
leg_radius: 0.02
leg_length: {min: 0.6, max: 0.5}
joint_offsets: 0.35
)");
  const std::string message = LoadError([&] { LoadHexapodDescription(path); });
  EXPECT_THAT(message, HasSubstr(path));
  EXPECT_THAT(message, HasSubstr("leg_length"));
  std::filesystem::remove(path);
}

TEST(RobotDescription, Weld5ErrorsNameTheJoint) {
  const std::string path = WriteTemp("weld5_bad.yaml", R"(
robot: weld5
joints:
  - {type: revolute, a: 0, alpha_deg: -90, d_mm: 275, theta_offset: 0, limits: {min_deg: 10, max_deg: -10, speed_deg_s: 90}}
  - {type: hinge, a: 0, alpha_deg: 90, d: 0.1, theta_offset: 0, limits: {min_deg: -120, max_deg: 120, speed_deg_s: 90}}
  - {type: prismatic, a: 0, alpha_deg: -90, d: 0, theta_offset: 0, limits: {min_mm: 0, max_mm: 500, speed_mm_s: 0}}
  - {type: revolute, a: 0, alpha_deg: 90, d: 0, limits: {min_deg: -180, max_deg: 180, speed_deg_s: 90}}
  - {type: revolute, a: 0, alpha_deg: 0, d: 0, theta_offset: 0, limits: {min_deg: -120, max_deg: 120, speed_deg_s: 90}}
torch: {px5_mm: 25, pz5_mm: 250, beta_deg: 0}
)");
  const std::string message = LoadError([&] { LoadWeld5Description(path); });
  EXPECT_THAT(message,
              AllOf(HasSubstr("joints[0].limits.min < max does not hold"),
                    HasSubstr("joints[1].type: expected revolute or prismatic, got 'hinge'"),
                    HasSubstr("joints[2].limits.speed: must be > 0"),
                    HasSubstr("joints[3].theta_offset (or theta_offset_deg): missing")));
  std::filesystem::remove(path);
}

TEST(RobotDescription, MissingFileWrongKindAndBrokenYamlAreClearErrors) {
  EXPECT_THAT(LoadError([] { LoadHexapodDescription("/nonexistent/hexapod.yaml"); }),
              HasSubstr("/nonexistent/hexapod.yaml: cannot open"));
  EXPECT_THAT(LoadError([] { LoadHexapodDescription(kSource + "/robots/weld5/weld5.yaml"); }),
              HasSubstr("robot: expected 'hexapod', got 'weld5'"));
  const std::string broken = WriteTemp("broken.yaml", "robot: [hexapod\n");
  EXPECT_THAT(LoadError([&] { ReadRobotKind(broken); }), HasSubstr("not valid YAML"));
  const std::string unknown = WriteTemp("unknown.yaml", "robot: delta\n");
  EXPECT_THAT(LoadError([&] { ReadRobotKind(unknown); }), HasSubstr("unknown kind 'delta'"));
  std::filesystem::remove(broken);
  std::filesystem::remove(unknown);
}

}  // namespace
}  // namespace kinevis::robots
