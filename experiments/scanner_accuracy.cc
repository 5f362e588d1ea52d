// Issue 7, experiment 1: the scanner's 3-D accuracy over the seed's working range (250–650 mm;
// seed: < 1 mm; target ≤ 0.3 mm RMS) with realistic stripe noise (0.1 px across the stripe by
// default: a sub-pixel centre-of-gravity / Gaussian-fit extractor on a 0.3 mm-σ stripe). The
// points of the rotating laser's stripe on a board (tilted 10° / 8°) at each depth are
// triangulated (eq. 9) and compared with the true surface points:
//   truth/known      the true geometry and the true cot θ_y: the noise floor of eq. 9;
//   truth/eq.11      the true geometry, cot θ_y from the stripes' intersection (eq. 11);
//   calibrated/eq.11 the geometry from a simulated calibration (scanner_calibration's procedure:
//                    rendered board poses, noisy stripes), cot θ_y from eq. 11 — what a scan does.
//
//   build-*/experiments/scanner_accuracy [--noise-px 0.1] [--scans 20]

#include "calibration/laser_scanner/scanner_accuracy.h"

#include <CLI/CLI.hpp>
#include <cmath>
#include <cstdio>

#include "vision/camera/camera_file.h"

using kinevis::calibration::AngleSource;
using kinevis::calibration::EvaluateScannerAccuracy;
using kinevis::calibration::ScannerAccuracyOptions;
using kinevis::vision::laser::ScannerGeometry;

int main(int argc, char** argv) {
  CLI::App app{"Scanner accuracy over 250-650 mm (issue 7, experiment 1)"};
  ScannerAccuracyOptions options;
  app.add_option("--noise-px", options.noise_px, "stripe noise across the stripe (px)");
  app.add_option("--scans", options.scans, "noise draws per depth")->check(CLI::Range(1, 1000));
  CLI11_PARSE(app, argc, argv);

  const auto camera = kinevis::vision::BuiltinCameraModel("tsai-seed004");
  const ScannerGeometry truth = ScannerGeometry::Seed004();
  kinevis::calibration::SimulatedCalibrationOptions calibration_options;
  calibration_options.noise_px = options.noise_px;
  const auto run =
      kinevis::calibration::SimulateScannerCalibration(*camera, truth, calibration_options);
  if (!run.calibration.ok()) {
    std::printf("calibration failed: %s\n", run.calibration.errors.front().c_str());
    return 1;
  }
  const ScannerGeometry calibrated = run.calibration.geometry;
  std::printf(
      "stripe noise %.2f px, %d scans per depth; calibrated b_y %.4f d_y %.4f b_x' %.4f "
      "mm cot_x %.5f\n\n",
      options.noise_px, options.scans, 1e3 * calibrated.rotating_b_y, 1e3 * calibrated.rotating_d_y,
      1e3 * calibrated.fixed_b_x_prime, calibrated.fixed_cot_theta_x);
  std::printf("%8s | %-22s | %-32s | %-32s\n", "depth", "truth/known RMS max",
              "truth/eq.11 RMS max bias cot", "calibrated/eq.11 RMS max bias");
  double ssr[3] = {0, 0, 0};
  int n[3] = {0, 0, 0};
  for (double depth = 0.25; depth <= 0.6501; depth += 0.05) {
    const auto a =
        EvaluateScannerAccuracy(*camera, truth, truth, depth, AngleSource::kKnownAngle, options);
    const auto b =
        EvaluateScannerAccuracy(*camera, truth, truth, depth, AngleSource::kIntersection, options);
    const auto c = EvaluateScannerAccuracy(*camera, truth, calibrated, depth,
                                           AngleSource::kIntersection, options);
    const kinevis::calibration::ScannerAccuracy* all[3] = {&a, &b, &c};
    for (int k = 0; k < 3; ++k) {
      ssr[k] += all[k]->rms * all[k]->rms * all[k]->points;
      n[k] += all[k]->points;
    }
    std::printf("%5.0f mm | %8.3f %8.3f mm   | %7.3f %7.3f %7.3f mm %.1e | %7.3f %7.3f %7.3f mm\n",
                1e3 * depth, 1e3 * a.rms, 1e3 * a.max, 1e3 * b.rms, 1e3 * b.max,
                1e3 * b.mean_depth_error, b.cot_error_rms, 1e3 * c.rms, 1e3 * c.max,
                1e3 * c.mean_depth_error);
  }
  std::printf(
      "\nRMS over 250-650 mm: truth/known %.3f mm, truth/eq.11 %.3f mm, calibrated/eq.11 "
      "%.3f mm (target <= 0.3 mm, seed < 1 mm)\n",
      1e3 * std::sqrt(ssr[0] / n[0]), 1e3 * std::sqrt(ssr[1] / n[1]),
      1e3 * std::sqrt(ssr[2] / n[2]));
  return 0;
}
