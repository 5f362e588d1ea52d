#include "calibration/weld_mount/mount_calibration_io.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <regex>
#include <sstream>
#include <string>

#include "tests/calibration/weld_mount/simulated_mount_data.h"
#include "tests/utilities/version_one_file.h"

namespace kinevis::calibration {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;
using ::testing::MatchesRegex;

std::string TempFile(const std::string& name) {
  const fs::path dir =
      fs::temp_directory_path() / ("kinevis_mount_io_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  return (dir / name).string();
}

std::string ReadText(const std::string& path) {
  std::ifstream in(path);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

void WriteText(const std::string& path, const std::string& text) {
  std::ofstream out(path);
  out << text;
}

// Replaces the first match of `pattern` in the file (the test fails when there is none).
void Edit(const std::string& path, const std::string& pattern, const std::string& replacement) {
  const std::string text = ReadText(path);
  const std::regex re(pattern);
  ASSERT_TRUE(std::regex_search(text, re)) << pattern;
  WriteText(path,
            std::regex_replace(text, re, replacement, std::regex_constants::format_first_only));
}

ScannerMountCalibrationMetadata Metadata(const testing::SimulatedMount& s) {
  ScannerMountCalibrationMetadata m;
  m.created = "2026-01-02T03:04:05Z";
  m.source = "simulated mount data";
  m.robot = "robots/weld5/weld5.yaml";
  m.scanner = "builtin:tsai-seed004 + seed 004 Table 2";
  m.X_5C_guess = s.data.X_5C_guess;
  m.X_0B_guess = s.data.X_0B_guess;
  m.block = s.data.block;
  return m;
}

// A real summary from a small simulated calibration (3 viewpoints).
struct Solved {
  testing::SimulatedMount sim;
  MountCalibrationSummary summary;
};

Solved Solve(bool dh) {
  testing::SimulatedMountOptions o;
  o.wrist = {{0.0, 0.0}, {0.25, 0.5}, {-0.25, -0.5}, {0.0, 0.9}, {0.0, -0.9}};
  o.cot_theta_y = {0.22, 0.28};
  if (dh) {
    o.dh_length_sigma_mm = 0.2;
    o.dh_angle_sigma_deg = 0.05;
  }
  Solved s{testing::MakeSimulatedMount(o), {}};
  MountCalibrationOptions options;
  options.estimate_dh = dh;
  options.max_points_per_scan = 100;
  s.summary = CalibrateScannerMount(s.sim.data, options);
  return s;
}

// Solved once per test program (each solve takes about a second).
const Solved& Cached(bool dh) {
  static const Solved without = Solve(false);
  static const Solved with = Solve(true);
  return dh ? with : without;
}

// |a − b| <= tol, or both the same infinity.
::testing::AssertionResult Near(double a, double b, double tol) {
  if ((std::isinf(a) && a == b) || std::abs(a - b) <= tol) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << a << " vs " << b << " (tolerance " << tol << ")";
}

double Angle(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  return testing::AngleBetween(a, b);
}

void ExpectSameSummary(const MountCalibrationSummary& a, const MountCalibrationSummary& b) {
  EXPECT_EQ(a.status, b.status);
  EXPECT_EQ(a.converged, b.converged);
  EXPECT_EQ(a.iterations, b.iterations);
  EXPECT_DOUBLE_EQ(a.initial_cost, b.initial_cost);
  EXPECT_DOUBLE_EQ(a.final_cost, b.final_cost);
  EXPECT_DOUBLE_EQ(a.sigma_ratio, b.sigma_ratio);
  EXPECT_LT(testing::DistanceBetween(a.X_5C, b.X_5C), 1e-12);
  EXPECT_LT(Angle(a.X_5C, b.X_5C), 1e-12);
  EXPECT_LT(testing::DistanceBetween(a.X_0B, b.X_0B), 1e-12);
  EXPECT_LT(Angle(a.X_0B, b.X_0B), 1e-12);
  EXPECT_EQ(a.parameter_names, b.parameter_names);
  ASSERT_EQ(a.correction.size(), b.correction.size());
  for (int i = 0; i < a.correction.size(); ++i) {
    EXPECT_NEAR(a.correction(i), b.correction(i), 1e-14) << a.parameter_names[i];
    if (std::isfinite(a.std_dev(i))) {
      EXPECT_NEAR(a.std_dev(i), b.std_dev(i), 1e-14 + 1e-12 * a.std_dev(i));
    } else {
      EXPECT_FALSE(std::isfinite(b.std_dev(i))) << a.parameter_names[i];
    }
  }
  EXPECT_EQ(a.estimated, b.estimated);
  EXPECT_EQ(a.identified, b.identified);
  for (int r = 0; r < 6; ++r)
    for (int c = 0; c < 6; ++c)
      EXPECT_TRUE(Near(a.mount_covariance(r, c), b.mount_covariance(r, c),
                       1e-12 * std::abs(a.mount_covariance(r, c))))
          << r << ", " << c;
  EXPECT_TRUE(Near(a.mount_position_std, b.mount_position_std, 1e-15));
  EXPECT_TRUE(Near(a.mount_angle_std, b.mount_angle_std, 1e-15));
  EXPECT_EQ(a.rank, b.rank);
  EXPECT_TRUE(Near(a.condition_number, b.condition_number, 1e-12 * a.condition_number));
  ASSERT_EQ(a.singular_values.size(), b.singular_values.size());
  for (int i = 0; i < a.singular_values.size(); ++i)
    EXPECT_DOUBLE_EQ(a.singular_values(i), b.singular_values(i));
  EXPECT_EQ(a.unidentified, b.unidentified);
  EXPECT_EQ(a.fixed_dh, b.fixed_dh);
  EXPECT_EQ(a.warnings, b.warnings);
  EXPECT_EQ(a.touch.count, b.touch.count);
  EXPECT_NEAR(a.touch.rms, b.touch.rms, 1e-15);
  EXPECT_NEAR(a.touch.median, b.touch.median, 1e-15);
  EXPECT_NEAR(a.touch.max, b.touch.max, 1e-15);
  EXPECT_EQ(a.touch.beyond_k, b.touch.beyond_k);
  EXPECT_EQ(a.scan.count, b.scan.count);
  EXPECT_NEAR(a.scan.rms, b.scan.rms, 1e-15);
  EXPECT_EQ(a.scan.beyond_k, b.scan.beyond_k);
  EXPECT_EQ(a.estimation.status, b.estimation.status);
  ASSERT_EQ(a.estimation.parameters.size(), b.estimation.parameters.size());
  for (size_t i = 0; i < a.estimation.parameters.size(); ++i) {
    EXPECT_EQ(a.estimation.parameters[i].name, b.estimation.parameters[i].name);
    EXPECT_EQ(a.estimation.parameters[i].sigma, b.estimation.parameters[i].sigma);  // inf too
    EXPECT_EQ(a.estimation.parameters[i].value, b.estimation.parameters[i].value);
  }
  EXPECT_EQ(a.estimation.covariance, b.estimation.covariance);
  EXPECT_EQ(a.estimation.identifiability.unidentified, b.estimation.identifiability.unidentified);
}

TEST(MountCalibrationIoTest, RoundTripsAMountOnlyCalibration) {
  const Solved& s = Cached(/*dh=*/false);
  ASSERT_TRUE(s.summary.ok()) << s.summary.warnings.size();
  const std::string path = TempFile("mount.yaml");
  const ScannerMountCalibrationMetadata m = Metadata(s.sim);
  WriteScannerMountCalibration(path, s.summary, m);
  const ScannerMountCalibrationFile f = ReadScannerMountCalibration(path);
  ExpectSameSummary(s.summary, f.summary);
  EXPECT_FALSE(f.dh_estimated);
  EXPECT_EQ(f.dh_errors, Eigen::VectorXd::Zero(20));
  EXPECT_EQ(f.metadata.created, m.created);
  EXPECT_EQ(f.metadata.source, m.source);
  EXPECT_EQ(f.metadata.robot, m.robot);
  EXPECT_EQ(f.metadata.scanner, m.scanner);
  EXPECT_LT(testing::DistanceBetween(f.metadata.X_5C_guess, m.X_5C_guess), 1e-12);
  EXPECT_LT(Angle(f.metadata.X_0B_guess, m.X_0B_guess), 1e-12);
  EXPECT_LT((f.metadata.block.size - m.block.size).norm(), 1e-15);

  // What `kinevis scan` uses.
  const Eigen::Isometry3d X_5C = ReadScannerMount(path);
  EXPECT_LT(testing::DistanceBetween(X_5C, s.summary.X_5C), 1e-12);
  const robots::Weld5Model nominal = s.sim.data.robot;
  const robots::Weld5Model calibrated = CalibratedRobot(f, nominal);
  for (int i = 0; i < robots::kWeld5Joints; ++i) {
    EXPECT_EQ(calibrated.joints[static_cast<size_t>(i)].a,
              nominal.joints[static_cast<size_t>(i)].a);
  }

  // The keys a person reads are in mm and deg, and the correction from the CAD value is there.
  const std::string text = ReadText(path);
  EXPECT_THAT(text, HasSubstr("kind: kinevis-scanner-mount-calibration"));
  EXPECT_THAT(text, HasSubstr("position_mm:"));
  EXPECT_THAT(text, HasSubstr("quaternion_wxyz:"));
  EXPECT_THAT(text, HasSubstr("correction:"));
  const Eigen::Vector3d p_mm = 1e3 * s.summary.X_5C.translation();
  EXPECT_NEAR(p_mm.x(), -49.4, 1.0);  // the true mount: -49.4 mm along x_5
}

TEST(MountCalibrationIoTest, RoundTripsDhErrorsAndAppliesThemToTheRobot) {
  const Solved& s = Cached(/*dh=*/true);
  const std::string path = TempFile("mount_dh.yaml");
  WriteScannerMountCalibration(path, s.summary, Metadata(s.sim));
  const ScannerMountCalibrationFile f = ReadScannerMountCalibration(path);
  ExpectSameSummary(s.summary, f.summary);
  ASSERT_TRUE(f.dh_estimated);
  EXPECT_FALSE(f.summary.fixed_dh.empty());  // some D–H errors are absorbed by mount and block
  // The errors applied to the nominal robot give the summary's robot.
  const robots::Weld5Model r = CalibratedRobot(f, s.sim.data.robot);
  for (int i = 0; i < robots::kWeld5Joints; ++i) {
    const auto& a = r.joints[static_cast<size_t>(i)];
    const auto& b = s.summary.robot.joints[static_cast<size_t>(i)];
    EXPECT_NEAR(a.a, b.a, 1e-15);
    EXPECT_NEAR(a.alpha, b.alpha, 1e-15);
    EXPECT_NEAR(a.d, b.d, 1e-15);
    EXPECT_NEAR(a.theta_offset, b.theta_offset, 1e-15);
  }
  // Fixed D–H errors are written as not estimated with an error of 0.
  const std::string text = ReadText(path);
  EXPECT_THAT(text, HasSubstr("name: " + f.summary.fixed_dh.front()));
}

TEST(MountCalibrationIoTest, RoundTripsAnUnidentifiedCalibrationWithInfiniteSigmas) {
  // One viewpoint, top face only: the mount cannot be fixed.
  testing::SimulatedMountOptions o;
  o.wrist = {{0.0, 0.0}};
  o.cot_theta_y = {0.25};
  o.touch_sides = false;
  const testing::SimulatedMount sim = testing::MakeSimulatedMount(o);
  const MountCalibrationSummary summary = CalibrateScannerMount(sim.data);
  ASSERT_EQ(summary.status, MountCalibrationStatus::kUnidentified);
  const std::string path = TempFile("unidentified.yaml");
  WriteScannerMountCalibration(path, summary, Metadata(sim));
  const ScannerMountCalibrationFile f = ReadScannerMountCalibration(path);
  ExpectSameSummary(summary, f.summary);
  EXPECT_FALSE(f.summary.unidentified.empty());
  // Not usable for scans.
  try {
    ReadScannerMount(path);
    FAIL() << "an unidentified mount was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr(path));
    EXPECT_THAT(e.what(), HasSubstr("unidentified"));
  }
}

// A file from before the estimator contract (version 1, no estimation: block) still reads, with
// the report derived from what it holds.
TEST(MountCalibrationIoTest, ReadsVersionOneFilesWithoutTheEstimationBlock) {
  const Solved& s = Cached(/*dh=*/false);
  const std::string path = TempFile("version1.yaml");
  WriteScannerMountCalibration(path, s.summary, Metadata(s.sim));
  kinevis::testing::RewriteAsVersionOne(path);
  const ScannerMountCalibrationFile f = ReadScannerMountCalibration(path);
  EXPECT_EQ(f.summary.estimation.status, s.summary.estimation.status);
  EXPECT_EQ(f.summary.estimation.Validate(), "");
  EXPECT_EQ(f.summary.estimation.Find("mount.y")->sigma,
            s.summary.estimation.Find("mount.y")->sigma);
}

TEST(MountCalibrationIoTest, NamesEveryBadKeyInOneMessage) {
  const Solved& s = Cached(/*dh=*/false);
  const std::string path = TempFile("bad.yaml");
  WriteScannerMountCalibration(path, s.summary, Metadata(s.sim));
  Edit(path, "status: ok", "status: fine");
  Edit(path, "sigma_ratio: [^\\n]*", "sigma_ratio: -1");
  Edit(path, "quaternion_wxyz: \\[[^\\]]*\\]", "quaternion_wxyz: [0.5, 0.5, 0.5, 0.1]");
  Edit(path, "size_mm: \\[[^\\]]*\\]", "size_mm: [100, 0, 10]");
  Edit(path, "name: mount.ry", "name: mount.rz");
  Edit(path, "  scan: \\{count: [0-9]+", "  scan: {count: many");
  try {
    ReadScannerMountCalibration(path);
    FAIL() << "a bad file was accepted";
  } catch (const std::invalid_argument& e) {
    const std::string what = e.what();
    EXPECT_THAT(what, HasSubstr("scanner mount calibration file " + path));
    EXPECT_THAT(what, HasSubstr("status: unknown 'fine'"));
    EXPECT_THAT(what, HasSubstr("sigma_ratio: must be >= 0"));
    EXPECT_THAT(what, HasSubstr("mount.quaternion_wxyz: not a unit quaternion"));
    EXPECT_THAT(what, HasSubstr("block.size_mm: each size must be > 0"));
    EXPECT_THAT(what,
                HasSubstr("identifiability.parameters[1].name: 'mount.rz' (expected mount.ry)"));
    EXPECT_THAT(what, HasSubstr("residuals.scan.count: not an integer"));
  }
}

TEST(MountCalibrationIoTest, RefusesRpyThatDisagreesWithTheQuaternion) {
  const Solved& s = Cached(/*dh=*/false);
  const std::string path = TempFile("rpy.yaml");
  WriteScannerMountCalibration(path, s.summary, Metadata(s.sim));
  Edit(path, "rpy_deg: \\[[^\\]]*\\]", "rpy_deg: [0, 0, 5]");
  try {
    ReadScannerMountCalibration(path);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr("mount.quaternion_wxyz: disagrees with rpy_deg"));
  }
}

TEST(MountCalibrationIoTest, RefusesAnotherKindMissingKeysAndAMissingFile) {
  const std::string path = TempFile("other.yaml");
  WriteText(path, "kind: kinevis-laser-scanner-calibration\nversion: 9\n");
  try {
    ReadScannerMountCalibration(path);
    FAIL();
  } catch (const std::invalid_argument& e) {
    const std::string what = e.what();
    EXPECT_THAT(what, HasSubstr("kind: must be kinevis-scanner-mount-calibration"));
    EXPECT_THAT(what, HasSubstr("version: unsupported (9"));
    EXPECT_THAT(what, HasSubstr("mount: missing"));
    EXPECT_THAT(what, HasSubstr("status: missing"));
  }
  WriteText(path, "[1, 2");
  EXPECT_THROW(ReadScannerMountCalibration(path), std::invalid_argument);
  EXPECT_THROW(ReadScannerMountCalibration(TempFile("does_not_exist.yaml")), std::runtime_error);
}

TEST(MountCalibrationIoTest, RefusesAnInconsistentSummaryAndAnUnwritablePath) {
  const Solved& s = Cached(/*dh=*/false);
  MountCalibrationSummary bad = s.summary;
  bad.parameter_names.pop_back();
  EXPECT_THROW(WriteScannerMountCalibration(TempFile("x.yaml"), bad, Metadata(s.sim)),
               std::invalid_argument);
  try {
    WriteScannerMountCalibration("/nonexistent-dir/mount.yaml", s.summary, Metadata(s.sim));
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_THAT(e.what(), HasSubstr("/nonexistent-dir/mount.yaml"));
  }
}

}  // namespace
}  // namespace kinevis::calibration
