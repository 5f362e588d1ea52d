#pragma once

// The estimator contract: what every calibration in kinevis reports, in one shape, whatever it
// estimates (hexapod legs, DIAMOND kinematics, laser-scanner planes, scanner mount, camera
// intrinsics). Each estimator keeps its own result struct for what is particular to its science
// and fills an EstimationReport beside it; the CLI prints BriefReport()/FullReport() and every
// result file writes the same `estimation:` block (calibration/common/estimation_yaml_internal.h).
//
// One identifiability analysis, AnalyzeIdentifiability(), serves every estimator that has a
// Jacobian: rank, condition, the parameter combinations the data cannot fix, per-parameter
// "identified" flags, strong correlations and the rank-truncated (JᵀJ)⁺ the covariance comes from.

#include <Eigen/Core>
#include <limits>
#include <string>
#include <vector>

namespace kinevis::calibration {

enum class EstimationStatus {
  kConverged,         // solved, and the data fix every estimated parameter
  kUnidentified,      // solved, but the data cannot fix some estimated parameters
  kNotConverged,      // the iteration limit, or the solver stopped without meeting a tolerance
  kInsufficientData,  // too few (or too alike) measurements to estimate at all
  kFailed,            // the solver failed (nothing could be predicted, numerical failure)
};
// "converged", "unidentified", "not-converged", "insufficient-data", "failed".
const char* ToString(EstimationStatus status);
// The inverse of ToString; false for any other text.
bool ParseEstimationStatus(const std::string& text, EstimationStatus* status);

// One kind of residual (a measured minus a predicted quantity) over the measurements used.
struct ResidualSummary {
  std::string name;  // what is compared, e.g. "pixel u", "point-to-plane"
  std::string unit;  // SI or px: "m", "rad", "px"
  int count = 0;
  double mean = 0.0;
  double rms = 0.0;
  double max_abs = 0.0;  // largest |r|
};
// The summary of `values` (count 0, zeros when empty).
ResidualSummary SummarizeResiduals(std::string name, std::string unit,
                                   const std::vector<double>& values);

// One parameter of the estimator's state, in SI units (or px for pixel quantities).
struct ParameterEstimate {
  std::string name;  // unique within a report, e.g. "leg1.p_C_A.x", "radius"
  std::string unit;  // "m", "rad", "px", "1"
  double initial = std::numeric_limits<double>::quiet_NaN();
  double value = std::numeric_limits<double>::quiet_NaN();
  // 1σ from the covariance; 0 for a parameter held fixed, +inf for one estimated but not
  // identified by the data.
  double sigma = 0.0;
  bool estimated = false;   // free in the solve (false: held at `initial`)
  bool identified = false;  // estimated, and no unidentified direction involves it
};

struct IdentifiabilityOptions {
  // How the Jacobian's columns are scaled before the SVD, so parameters in different units
  // compare: by their Euclidean norm, or by their largest |entry|.
  enum class Scaling { kColumnNorm, kMaxAbs };
  Scaling scaling = Scaling::kColumnNorm;
  // Singular values below rank_tolerance · σ_max count as zero, in (0, 1).
  double rank_tolerance = 1e-7;
  // A parameter is identified when the norm of its component in the null space is below this,
  // in (0, 1].
  double null_tolerance = 0.1;
  // Coefficients of a null direction below this are left out of its text, in [0, 1).
  double min_coefficient = 0.05;
  // Pairs of identified parameters with |correlation| >= this are listed, in (0, 1].
  double warn_correlation = 0.99;

  // Empty when usable, otherwise every bad field and its value ("field: rule, got value").
  std::string Validate() const;
};

struct Identifiability {
  int parameters = 0;  // columns analysed (the estimated parameters)
  int rank = 0;
  // σ_max/σ_min of the scaled Jacobian; +inf when it is rank-deficient.
  double condition_number = std::numeric_limits<double>::infinity();
  // σ_max/σ_rank: the condition of the part the data fix; +inf when the rank is 0.
  double condition_number_identified = std::numeric_limits<double>::infinity();
  std::vector<double> singular_values;  // of the scaled Jacobian, descending
  // Each null direction as a combination of the scaled parameters, largest term first and
  // positive: "0.707 radius - 0.707 camera_distance".
  std::vector<std::string> unidentified;
  // The gauges the estimator fixed, in words (filled by the estimator, not by the analysis).
  std::vector<std::string> gauges;
  // Identified pairs with |correlation| >= warn_correlation: "alpha ~ beta: -0.995".
  std::vector<std::string> strong_correlations;

  // Per analysed column (not written to files): identified, and the rank-truncated
  // pseudo-inverse (JᵀJ)⁺ in the unscaled parameters; times the variance factor it is the
  // covariance.
  std::vector<bool> identified;
  Eigen::MatrixXd normal_inverse;
};

// Analyses J (residuals × parameters, the Jacobian at the solution, of residuals already
// weighted by their σ) whose columns are named by `names`. A column of zeros is unidentified.
// Throws std::invalid_argument when the sizes disagree, J holds a non-finite entry or the
// options are bad. O(rows · cols²).
Identifiability AnalyzeIdentifiability(const Eigen::MatrixXd& J,
                                       const std::vector<std::string>& names,
                                       const IdentifiabilityOptions& options = {});

// What every estimator reports.
struct EstimationReport {
  std::string estimator;  // what was estimated and from what, e.g. "hexapod legs A_j (eq. 14)"
  EstimationStatus status = EstimationStatus::kFailed;
  std::string message;  // one line: the solver's termination, or why nothing was estimated
  int iterations = 0;
  // ½ Σ r² of the weighted residuals at the start and at the solution (NaN when not defined).
  double initial_cost = std::numeric_limits<double>::quiet_NaN();
  double final_cost = std::numeric_limits<double>::quiet_NaN();
  // The a-posteriori variance factor σ̂² = Σ r²/(m − rank) of the weighted residuals: ≈ 1 when
  // the assumed measurement σ is right (NaN when not defined).
  double variance_factor = std::numeric_limits<double>::quiet_NaN();
  std::vector<ResidualSummary> residuals;
  std::vector<ParameterEstimate> parameters;
  // parameters × parameters in their order and units; zero rows and columns for held
  // parameters, +inf on the diagonal of unidentified ones. Empty when not computed.
  Eigen::MatrixXd covariance;
  Identifiability identifiability;
  std::vector<std::string> warnings;

  bool ok() const { return status == EstimationStatus::kConverged; }
  // The parameter named `name`, or nullptr.
  const ParameterEstimate* Find(const std::string& name) const;
  // One line: estimator, status, parameters identified of estimated, rank, the first residual's
  // RMS and the number of warnings.
  std::string BriefReport() const;
  // Several lines: the brief line, the message, costs, every residual kind, the parameter table
  // (name, value, σ, unit, flags), identifiability and the warnings.
  std::string FullReport() const;
  // Empty when the report is self-consistent (sizes of covariance and flags agree with
  // `parameters`, names unique, σ ≥ 0, a converged status has every estimated parameter
  // identified), otherwise every inconsistency. For tests and for the file readers.
  std::string Validate() const;
};

}  // namespace kinevis::calibration
