#pragma once

// The DIAMOND part of `kinevis demo` (cmd_diamond.cc) and the servo run's exit code.

#include <cmath>
#include <functional>
#include <string>

#include "rigs/diamond/diamond_jobs.h"

namespace kinevis::cli {

// The exit code of a servo run (docs/cli.md): 0 completed, 3 drive fault / lost link / camera
// failure, 1 otherwise (lost marker, not converged, limit, timeout).
int DiamondServoExitCode(const rigs::DiamondServoRun& run);

// --- demo ---------------------------------------------------------------------------------------

struct DiamondDemoResult {
  int samples_recorded = 0;
  bool identified = false;
  // Relative errors of the identified R, α, β against the world's truth.
  double radius_error = NAN, alpha_error = NAN, beta_error = NAN;
  // Straightness (seed Table III) of the horizontal top-view line, true path (m), and the
  // camera-measured one with the identified measurement model, a priori vs identified.
  double straightness_apriori = NAN, straightness_identified = NAN;
  double measured_apriori = NAN, measured_identified = NAN;
  double position_apriori = NAN, position_identified = NAN;  // RMS position error (m)
  double wall_seconds = 0.0;
  std::string dataset, calibration, log_apriori, log_identified;  // files written
};

// The DIAMOND part of `kinevis demo`: on the built-in simulated world, records `samples`
// configurations into OUT_DIR/diamond-dataset, calibrates (OUT_DIR/diamond_calib.yaml), then runs
// the straightness validation (the seed's horizontal line in the top view) with the a-priori and
// with the identified parameters (OUT_DIR/diamond_line_apriori.csv, _identified.csv). Each check
// is reported through expect(ok, what). Catches nothing: a throw is the caller's to report.
// About 25 s wall time with the default 30 samples (a 2-core machine under load).
DiamondDemoResult RunDiamondDemo(
    const std::string& out_dir, const std::function<void(bool ok, const std::string& what)>& expect,
    int samples = 30);

}  // namespace kinevis::cli
