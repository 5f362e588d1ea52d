// `kinevis model ...` end to end: the real binary, JSON out, round trips through the models.

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <nlohmann/json.hpp>

#include "tests/utilities/subprocess.h"

namespace kinevis {
namespace {

using testing::RunKinevis;

using namespace std::chrono_literals;
using ::testing::HasSubstr;
using testing::ProcessResult;

std::string Csv(const nlohmann::json& values) {
  std::string s;
  for (const auto& v : values) s += (s.empty() ? "" : ",") + std::to_string(v.get<double>());
  return s;
}

TEST(ModelCli, HexapodIkThenFkReturnsThePose) {
  const ProcessResult ik =
      RunKinevis({"model", "hexapod", "ik", "--pose", "0.01,-0.02,0.43,3,-2,6", "--json"});
  ASSERT_EQ(ik.exit_code, 0) << ik.err;
  const auto in = nlohmann::json::parse(ik.out);
  EXPECT_TRUE(in["reachable"].get<bool>());
  std::string legs;
  for (const auto& leg : in["legs"])
    legs += (legs.empty() ? "" : ",") + std::to_string(leg["length_m"].get<double>());
  const ProcessResult fk = RunKinevis({"model", "hexapod", "fk", "--legs", legs, "--json"});
  ASSERT_EQ(fk.exit_code, 0) << fk.err;
  const auto out = nlohmann::json::parse(fk.out);
  EXPECT_EQ(out["status"], "converged");
  // std::to_string prints 6 decimals: 1 µm on the legs, so the pose agrees to a few µm.
  const std::vector<double> p = out["pose"]["position_m"];
  const std::vector<double> rpy = out["pose"]["rpy_deg"];
  EXPECT_NEAR(p[0], 0.01, 2e-5);
  EXPECT_NEAR(p[1], -0.02, 2e-5);
  EXPECT_NEAR(p[2], 0.43, 2e-5);
  EXPECT_NEAR(rpy[0], 3.0, 0.01);
  EXPECT_NEAR(rpy[1], -2.0, 0.01);
  EXPECT_NEAR(rpy[2], 6.0, 0.01);
}

TEST(ModelCli, HexapodOutOfStrokeIsAFailedJobNamingTheLeg) {
  const ProcessResult ik = RunKinevis({"model", "hexapod", "ik", "--pose", "0,0,0.70,0,0,0"});
  EXPECT_EQ(ik.exit_code, 1);
  EXPECT_THAT(ik.out, HasSubstr("NOT reachable: leg 0 too long"));
}

TEST(ModelCli, Weld5FkThenIkReturnsTheTorchPose) {
  const ProcessResult fk =
      RunKinevis({"model", "weld5", "fk", "--joints", "10,20,150,30,40", "--json"});
  ASSERT_EQ(fk.exit_code, 0) << fk.err;
  const auto pose = nlohmann::json::parse(fk.out);
  const ProcessResult ik =
      RunKinevis({"model", "weld5", "ik", "--tip", Csv(pose["tip_mm"]), "--axis", Csv(pose["axis"]),
                  "--axis-tolerance", "0.001", "--json"});
  ASSERT_EQ(ik.exit_code, 0) << ik.out << ik.err;
  const auto r = nlohmann::json::parse(ik.out);
  EXPECT_EQ(r["status"], "converged");
  EXPECT_LT(r["position_error_mm"].get<double>(), 1e-3);
  // Feed the IK's joints back through FK: the same tip (to the 6 printed decimals).
  const auto& j = r["joints"];
  const std::string joints = std::to_string(j["theta1_deg"].get<double>()) + "," +
                             std::to_string(j["theta2_deg"].get<double>()) + "," +
                             std::to_string(j["pz3_mm"].get<double>()) + "," +
                             std::to_string(j["theta4_deg"].get<double>()) + "," +
                             std::to_string(j["theta5_deg"].get<double>());
  const auto again =
      nlohmann::json::parse(RunKinevis({"model", "weld5", "fk", "--joints", joints, "--json"}).out);
  for (int i = 0; i < 3; ++i) {
    EXPECT_NEAR(again["tip_mm"][i].get<double>(), pose["tip_mm"][i].get<double>(), 0.01);
  }
}

TEST(ModelCli, Weld5UnreachableTargetIsAFailedJob) {
  const ProcessResult ik =
      RunKinevis({"model", "weld5", "ik", "--tip", "3000,0,0", "--axis", "0,0,-1"});
  EXPECT_EQ(ik.exit_code, 1);
  EXPECT_THAT(ik.out, HasSubstr("not reachable"));
}

TEST(ModelCli, DiamondIkThenFkReturnsTheTaskOnBothParameterSets) {
  for (const char* file : {"diamond_apriori.yaml", "diamond_identified.yaml"}) {
    SCOPED_TRACE(file);
    const std::string robot = std::string(KINEVIS_SOURCE_DIR) + "/robots/diamond/" + file;
    const ProcessResult ik =
        RunKinevis({"model", "diamond", "ik", "--task", "80,50", "--robot", robot, "--json"});
    ASSERT_EQ(ik.exit_code, 0) << ik.err;
    const auto q = nlohmann::json::parse(ik.out)["joints_deg"];
    const ProcessResult fk =
        RunKinevis({"model", "diamond", "fk", "--joints", Csv(q), "--robot", robot, "--json"});
    ASSERT_EQ(fk.exit_code, 0) << fk.err;
    const auto task = nlohmann::json::parse(fk.out)["task_deg"];
    EXPECT_NEAR(task["phi"].get<double>(), 80.0, 1e-5);
    EXPECT_NEAR(task["gamma"].get<double>(), 50.0, 1e-5);
  }
  const ProcessResult out = RunKinevis({"model", "diamond", "ik", "--task", "90,88"});
  EXPECT_EQ(out.exit_code, 1);
  EXPECT_THAT(out.out, HasSubstr("outside the workspace"));
}

TEST(ModelCli, ProjectThenBackProjectThroughEveryBuiltinCentralCamera) {
  for (const char* camera :
       {"builtin:tsai-seed004", "builtin:unified-default", "builtin:scaramuzza-default"}) {
    SCOPED_TRACE(camera);
    const ProcessResult fwd =
        RunKinevis({"project", camera, "--point", "0.05,-0.03,0.5", "--json"});
    ASSERT_EQ(fwd.exit_code, 0) << fwd.out << fwd.err;
    const auto pixel = nlohmann::json::parse(fwd.out)["pixel"];
    const ProcessResult back = RunKinevis({"project", camera, "--pixel", Csv(pixel), "--json"});
    ASSERT_EQ(back.exit_code, 0) << back.err;
    const std::vector<double> d = nlohmann::json::parse(back.out)["ray_direction"];
    const double n = std::sqrt(0.05 * 0.05 + 0.03 * 0.03 + 0.25);
    // std::to_string keeps 6 decimals of the pixel: ~1e-6 px, far below this tolerance.
    EXPECT_NEAR(d[0], 0.05 / n, 1e-5);
    EXPECT_NEAR(d[1], -0.03 / n, 1e-5);
    EXPECT_NEAR(d[2], 0.5 / n, 1e-5);
  }
}

TEST(ModelCli, MirrorCameraPixelGivesAGroundPointAndBehindIsAFailedJob) {
  const ProcessResult r =
      RunKinevis({"project", "builtin:hyperbolic-mirror-4mm", "--pixel", "420,240", "--json"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto out = nlohmann::json::parse(r.out);
  const double distance = out["ground_distance_m"].get<double>();
  EXPECT_GT(distance, 0.3);
  EXPECT_LT(distance, 3.0);
  const ProcessResult behind = RunKinevis({"project", "builtin:tsai-seed004", "--point", "0,0,-1"});
  EXPECT_EQ(behind.exit_code, 1);
  EXPECT_THAT(behind.out, HasSubstr("behind camera"));
}

TEST(ModelCli, BadInputIsAUsageErrorThatSaysWhatIsWrong) {
  ProcessResult r = RunKinevis({"model", "hexapod", "fk", "--legs", "0.45,0.46"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.err, HasSubstr("--legs: need 6 comma-separated values"));
  r = RunKinevis({"model", "hexapod", "ik", "--pose", "0,0,0.4,0,0,0", "--robot",
                  std::string(KINEVIS_SOURCE_DIR) + "/robots/weld5/weld5.yaml"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.err, HasSubstr("robot: expected 'hexapod', got 'weld5'"));
  r = RunKinevis({"model", "weld5", "ik", "--tip", "300,0,0", "--axis", "0,0,0"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.err, HasSubstr("--axis: must not be the zero vector"));
}

TEST(ModelCli, DescriptionFilesLoadThroughTheCli) {
  const ProcessResult r =
      RunKinevis({"model", "hexapod", "ik", "--pose", "0,0,0.4,0,0,0", "--robot",
                  std::string(KINEVIS_SOURCE_DIR) + "/robots/hexapod/hexapod.yaml"});
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("robot: kinevis-default-hexapod\n"));
}

}  // namespace
}  // namespace kinevis
