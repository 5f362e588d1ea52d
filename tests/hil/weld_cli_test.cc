// The weld-cell commands as a user runs them (issue 7): `kinevis record scanner` and
// `kinevis calibrate scanner` on the simulated cell in the same process (the default), the robot
// reached over Modbus TCP and the scanner through its camera source, as on the real cell.

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <string>

#include "calibration/laser_scanner/laser_scanner_calibration_io.h"
#include "sim/weld_cell_world.h"
#include "tests/utilities/subprocess.h"

namespace kinevis {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using ::testing::HasSubstr;
using testing::ProcessResult;
using testing::RunKinevis;

std::string TempDir(const std::string& name) {
  const fs::path dir =
      fs::temp_directory_path() / ("kinevis_weld_cli_" + name + "_" + std::to_string(::getpid()));
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

// Record on the simulated cell, calibrate from the recording, and compare with the cell's truth
// (seed 004 Table 2): the whole chain of images -> dots -> board poses -> stripes -> eq. 28/32/29.
TEST(WeldCliTest, RecordAndCalibrateTheSimulatedScanner) {
  const std::string dir = TempDir("scanner");
  const std::string dataset = dir + "/dataset";
  const ProcessResult record =
      RunKinevis({"record", "scanner", "--poses", "4", "--steps", "3", "--out", dataset}, 180s);
  ASSERT_EQ(record.exit_code, 0) << record.out << record.err;
  EXPECT_THAT(record.out, HasSubstr("recorded 4 board poses"));
  EXPECT_EQ(Lines(dataset + "/images.csv"), 1u + 4u * 4u);  // header + 4 x (off + 3 on)

  const std::string calib = dir + "/scanner_calib.yaml";
  const ProcessResult calibrate =
      RunKinevis({"calibrate", "scanner", "--dataset", dataset, "--out", calib}, 180s);
  ASSERT_EQ(calibrate.exit_code, 0) << calibrate.out << calibrate.err;
  const calibration::LaserScannerCalibrationFile file =
      calibration::ReadLaserScannerCalibration(calib);
  ASSERT_TRUE(file.result.rotating_calibrated) << calibrate.out;
  ASSERT_TRUE(file.result.fixed_calibrated) << calibrate.out;
  const sim::WeldCellWorldConfig truth;
  const auto& g = file.result.geometry;
  // Rendered stripes and dots found in the images, 4 poses x 3 positions: measured errors 0.018 mm
  // (b_y), 0.074 mm (d_y), 0.004 mm (b_x'), 8e-6 (cot theta_x); bounds about 5x those.
  EXPECT_NEAR(g.rotating_b_y, truth.scanner.rotating_b_y, 0.1e-3) << calibrate.out;
  EXPECT_NEAR(g.rotating_d_y, truth.scanner.rotating_d_y, 0.4e-3) << calibrate.out;
  EXPECT_NEAR(g.fixed_b_x_prime, truth.scanner.fixed_b_x_prime, 0.05e-3) << calibrate.out;
  EXPECT_NEAR(g.fixed_cot_theta_x, truth.scanner.fixed_cot_theta_x, 1e-4) << calibrate.out;
}

TEST(WeldCliTest, CalibrateScannerRefusesAMissingDataset) {
  const ProcessResult r =
      RunKinevis({"calibrate", "scanner", "--dataset", "/nonexistent/kinevis-ds"}, 30s);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_THAT(r.out + r.err, HasSubstr("/nonexistent/kinevis-ds"));
}

}  // namespace
}  // namespace kinevis
