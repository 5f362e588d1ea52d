// The DIAMOND commands as a user runs them (issue 8): `kinevis record diamond`, `calibrate
// diamond`, `servo diamond` and `plan-camera diamond` on the simulated world in the same process
// (config/diamond-sim.yaml), the two drives reached over RS485 (Modbus RTU on a pty) and the
// marker through the world's camera, as on the real robot.

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <regex>
#include <string>
#include <thread>

#include "calibration/diamond/diamond_calibration_io.h"
#include "sim/diamond_world.h"
#include "tests/utilities/subprocess.h"

namespace kinevis {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using testing::BackgroundProcess;
using ::testing::ContainsRegex;
using ::testing::HasSubstr;
using testing::KinevisCliPath;
using ::testing::Not;
using testing::ProcessResult;
using testing::RunKinevis;

const std::string kConfig = std::string(KINEVIS_SOURCE_DIR) + "/config/diamond-sim.yaml";

std::string TempDir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() /
                       ("kinevis_diamond_cli_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir.string();
}

size_t Lines(const std::string& path) {
  std::ifstream in(path);
  size_t n = 0;
  for (std::string line; std::getline(in, line);) ++n;
  return n;
}

// The first number after `prefix` in `text`; NaN when absent.
double NumberAfter(const std::string& text, const std::string& prefix) {
  const size_t at = text.find(prefix);
  if (at == std::string::npos) return NAN;
  return std::strtod(text.c_str() + at + prefix.size(), nullptr);
}

// Record on the simulated world, calibrate from the recording, compare with the world's truth
// (seed 001 Table I), then follow the seed's horizontal line (straight in the top view) with the
// a-priori and with the identified parameters (Table III).
TEST(DiamondCliTest, RecordCalibrateAndValidateOnTheSimulatedWorld) {
  const std::string dir = TempDir("calibrate");
  const std::string dataset = dir + "/dataset";
  const ProcessResult record = RunKinevis(
      {"record", "diamond", "--config", kConfig, "--samples", "16", "--out", dataset}, 60s);
  ASSERT_EQ(record.exit_code, 0) << record.out << record.err;
  EXPECT_THAT(record.out, HasSubstr("recorded 16 of 16 samples"));
  EXPECT_EQ(Lines(dataset + "/samples.csv"), 1u + 16u);
  EXPECT_TRUE(fs::exists(dataset + "/images/sample_0015.png"));
  EXPECT_TRUE(fs::exists(dataset + "/simulation_truth.yaml"));

  const std::string calib = dir + "/diamond_calib.yaml";
  const ProcessResult calibrate =
      RunKinevis({"calibrate", "diamond", "--dataset", dataset, "--out", calib}, 60s);
  ASSERT_EQ(calibrate.exit_code, 0) << calibrate.out << calibrate.err;
  EXPECT_THAT(calibrate.out, HasSubstr("marker found in 16"));
  // Full rank: every free parameter identified (R, alpha, beta, the offsets' difference and the
  // camera's rotation and direction; the distance and the mean offset are the gauges).
  std::smatch rank;
  ASSERT_TRUE(std::regex_search(calibrate.out, rank, std::regex(R"(rank (\d+) of (\d+) free)")))
      << calibrate.out;
  EXPECT_EQ(rank[1], rank[2]);
  EXPECT_EQ(rank[2], "9");
  EXPECT_THAT(calibrate.out, HasSubstr("simulation truth"));
  const calibration::DiamondCalibrationFile file = calibration::ReadDiamondCalibration(calib);
  ASSERT_TRUE(file.summary.ok());
  const robots::DiamondModel truth = sim::TrueDiamondModel(sim::LoadDiamondWorldConfig(kConfig));
  const robots::DiamondModel& m = file.summary.model;
  // Rendered images (4x supersampling, noise 1), detector ~0.1 px. Measured relative errors, worst
  // of five recordings of 16-40 samples: R 0.0048 %, alpha 0.0073 %, beta 0.0152 % (this one,
  // 16 samples: 0.0016 %, 0.0003 %, 0.0005 %); bounds 5x the worst, rounded up. The issue's
  // target is 0.2 %.
  EXPECT_NEAR(m.radius / truth.radius - 1, 0.0, 2.5e-4) << calibrate.out;
  EXPECT_NEAR(m.alpha / truth.alpha - 1, 0.0, 4e-4) << calibrate.out;
  EXPECT_NEAR(m.beta / truth.beta - 1, 0.0, 8e-4) << calibrate.out;
  // And it moved far from where it started (0.2 m, pi/4, pi/4).
  EXPECT_GT(std::abs(m.radius - 0.2), 0.02);

  double straightness[2] = {NAN, NAN};
  for (int k = 0; k < 2; ++k) {
    const std::string log = dir + (k == 0 ? "/line_apriori.csv" : "/line_identified.csv");
    std::vector<std::string> args = {"servo", "diamond", "--config", kConfig, "--from",
                                     "60,45", "--to",    "120,45",   "--log", log};
    if (k == 1) {
      args.push_back("--calib");
      args.push_back(calib);
    }
    const ProcessResult servo = RunKinevis(args, 60s);
    ASSERT_EQ(servo.exit_code, 0) << servo.out << servo.err;
    EXPECT_THAT(servo.out, HasSubstr("line: completed"));
    const double measured = NumberAfter(servo.out, "straightness (seed Table III): ");
    EXPECT_TRUE(std::isfinite(measured)) << servo.out;
    EXPECT_THAT(servo.out, HasSubstr("loop: "));
    straightness[k] = NumberAfter(servo.out, "true path straightness ");
    ASSERT_TRUE(std::isfinite(straightness[k])) << servo.out;
    EXPECT_GT(Lines(log), 3000u);  // one row per 1 ms cycle over the 3 s line
  }
  // Measured 0.176 cm -> 0.0002 cm (true path); the issue's target is x3.
  EXPECT_GT(straightness[0], 3 * straightness[1]);
  EXPECT_GT(straightness[0], 0.05);  // cm: the a-priori model bends the line visibly
}

TEST(DiamondCliTest, PlanCameraReproducesTheSeedsDistance) {
  const std::string dir = TempDir("plan");
  const std::string plot = dir + "/benefit.png";
  const ProcessResult r = RunKinevis(
      {"plan-camera", "diamond", "--q", "5", "--half-angle-deg", "26.90", "--plot", plot}, 30s);
  ASSERT_EQ(r.exit_code, 0) << r.out << r.err;
  // The table row for q = 5: "    5.00 |        44.6x ...".
  std::smatch match;
  ASSERT_TRUE(std::regex_search(r.out, match, std::regex(R"(\n\s+5\.00 \|\s+([0-9.]+))"))) << r.out;
  EXPECT_NEAR(std::stod(match[1]), 44.62, 0.05) << r.out;
  EXPECT_THAT(r.out, HasSubstr("theta = 26.90 deg"));
  EXPECT_GT(fs::file_size(plot), 1000u);

  // With the world's camera (its smallest half-angle is narrower: the camera goes farther).
  const ProcessResult world = RunKinevis({"plan-camera", "diamond"}, 30s);
  ASSERT_EQ(world.exit_code, 0) << world.out << world.err;
  ASSERT_TRUE(std::regex_search(world.out, match, std::regex(R"(\n\s+5\.00 \|\s+([0-9.]+))")))
      << world.out;
  EXPECT_GT(std::stod(match[1]), 44.62);
}

TEST(DiamondCliTest, IbvsServoesTheMarkerToTheTarget) {
  const ProcessResult r = RunKinevis({"servo", "diamond", "--config", kConfig, "--law", "ibvs",
                                      "--from", "80,50", "--to", "100,40"},
                                     60s);
  ASSERT_EQ(r.exit_code, 0) << r.out << r.err;
  const double detected = NumberAfter(r.out, "final marker error: ");
  EXPECT_LT(detected, 0.5) << r.out;
  const double truth = NumberAfter(r.out, "true marker ");
  EXPECT_LT(truth, 0.5) << r.out;  // issue 8: <= 0.5 px
}

// The world in its own process (`kinevis sim world diamond`), the host reaching its drives over
// the pty and its camera over TCP through a `rig: diamond` deployment file, as on the real robot.
// Two jobs in a row: the first must leave the drives disabled with their watchdog off, or the
// second finds them in a lost-heartbeat fault (0x8130) and cannot enable them.
TEST(DiamondCliTest, DeploymentFileDrivesAWorldInAnotherProcessJobAfterJob) {
  const std::string dir = TempDir("deployment");
  const std::string root = KINEVIS_SOURCE_DIR;
  // config/diamond-sim.yaml with absolute robot paths and a 0.2 rad following-error window (the
  // host's set-points can stall for tens of milliseconds between two processes on a loaded
  // 2-core machine; this test is about the transports and the exit, the fault path has its own).
  const std::string world_config = dir + "/diamond-sim.yaml";
  {
    std::ifstream in(kConfig);
    std::ofstream out(world_config);
    for (std::string l; std::getline(in, l);) {
      const size_t rel = l.find("../robots/");
      if (rel != std::string::npos) l.replace(rel, 2, root);
      if (l.find("following_error_window:") != std::string::npos) {
        l = "  following_error_window: 0.2";
      }
      out << l << "\n";
    }
  }
  BackgroundProcess world({KinevisCliPath(), "sim", "world", "diamond", "--config", world_config});
  std::string backend, camera;
  ASSERT_TRUE(world.ReadLine(&backend, 20s));
  ASSERT_THAT(backend, ContainsRegex("^modbus-rtu:"));
  ASSERT_TRUE(world.ReadLine(&camera, 5s));
  ASSERT_THAT(camera, ContainsRegex("^net:.* diamond-marker$"));
  camera = camera.substr(0, camera.find(' '));
  const std::string deployment = dir + "/diamond.yaml";
  {
    std::ofstream out(deployment);
    out << "rig: diamond\n"
        << "drives: {backend: \"" << backend
        << "\", units: [1, 2], counts_per_rad: 20860.756700940907, cycle_ms: 2}\n"
        << "camera:\n"
        << "  name: marker\n"
        << "  source: \"" << camera << ",timeout_ms=5000\"\n"
        << "  model: builtin:tsai-seed004\n"
        << "  pose: {position: [0.0, 0.3155, 0.3155], rpy_deg: [135, 0, 0]}\n"
        << "  distance_source: \"the world config\"\n"
        << "  fps: 30\n"
        << "  marker_half_side_mm: 5\n";
  }
  for (int job = 0; job < 2; ++job) {
    const ProcessResult servo =
        RunKinevis({"servo", "diamond", "--config", deployment, "--path", "line", "--from", "70,45",
                    "--to", "110,45", "--duration", "2"},
                   90s);
    EXPECT_EQ(servo.exit_code, 0) << "job " << job << "\n" << servo.out << servo.err;
    EXPECT_THAT(servo.out, HasSubstr("loop: "));
    EXPECT_THAT(servo.out, HasSubstr("timer slack 1 ns: set"));
    EXPECT_THAT(servo.out, HasSubstr("straightness (seed Table III)"));
    EXPECT_THAT(servo.err, Not(HasSubstr("reset the fault first")));
    // Longer than the drives' 200 ms watchdog: a drive still watching would fault now.
    std::this_thread::sleep_for(500ms);
  }
  EXPECT_EQ(world.Stop(SIGTERM), 0);
}

TEST(DiamondCliTest, BadInputIsAUsageErrorNamingTheProblem) {
  const ProcessResult missing =
      RunKinevis({"calibrate", "diamond", "--dataset", "/nonexistent/kinevis-diamond-ds"}, 30s);
  EXPECT_EQ(missing.exit_code, 2);
  EXPECT_THAT(missing.out + missing.err, HasSubstr("/nonexistent/kinevis-diamond-ds"));

  // A directory that is not a dataset: the reader names the file it needs.
  const std::string empty = TempDir("empty");
  const ProcessResult not_dataset = RunKinevis({"calibrate", "diamond", "--dataset", empty}, 30s);
  EXPECT_EQ(not_dataset.exit_code, 2);
  EXPECT_THAT(not_dataset.err, HasSubstr("dataset.yaml"));

  const ProcessResult outside = RunKinevis(
      {"servo", "diamond", "--config", kConfig, "--from", "60,120", "--to", "120,45"}, 30s);
  EXPECT_EQ(outside.exit_code, 2);
  EXPECT_THAT(outside.err, HasSubstr("--from"));
  EXPECT_THAT(outside.err, HasSubstr("workspace"));

  const ProcessResult garbled =
      RunKinevis({"servo", "diamond", "--from", "sixty,45", "--to", "120,45"}, 30s);
  EXPECT_EQ(garbled.exit_code, 2);
  EXPECT_THAT(garbled.out + garbled.err, HasSubstr("--from"));

  const ProcessResult one = RunKinevis({"servo", "diamond", "--from", "60", "--to", "120,45"}, 30s);
  EXPECT_EQ(one.exit_code, 2);
  EXPECT_THAT(one.out + one.err, HasSubstr("--from"));
}

}  // namespace
}  // namespace kinevis
