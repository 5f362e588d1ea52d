#include "calibration/hexapod/leg_calibration.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <random>
#include <sstream>
#include <stdexcept>

namespace kinevis::calibration {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();
// 1 / Φ⁻¹(3/4): makes the median absolute residual a consistent estimate of σ at the normal.
constexpr double kMadToSigma = 1.482602218505602;

// One row of eq. 14: n ᵀ A = −R.
struct Equation {
  Eigen::Vector3d n;
  int configuration;
  int limb;  // 1 or 2
};

// Robust scale of the residuals: 1.4826 · median |r| (the MAD about zero: a correct model has
// zero-mean residuals and eq. 14 has no intercept to absorb an offset).
double RobustScale(const std::vector<double>& residuals, std::vector<double>* scratch,
                   double floor) {
  scratch->resize(residuals.size());
  for (size_t i = 0; i < residuals.size(); ++i) (*scratch)[i] = std::abs(residuals[i]);
  const size_t mid = scratch->size() / 2;
  std::nth_element(scratch->begin(), scratch->begin() + static_cast<long>(mid), scratch->end());
  double median = (*scratch)[mid];
  if (scratch->size() % 2 == 0) {
    const double lower =
        *std::max_element(scratch->begin(), scratch->begin() + static_cast<long>(mid));
    median = 0.5 * (median + lower);
  }
  return std::max(kMadToSigma * median, floor);
}

// IRLS weight w(x) = ψ(x)/x of a standardised residual x = r/s.
double Weight(RobustLoss loss, double x, const HexapodCalibrationOptions& o) {
  const double a = std::abs(x);
  switch (loss) {
    case RobustLoss::kLeastSquares:
      return 1.0;
    case RobustLoss::kHuber:
      return a <= o.huber_k ? 1.0 : o.huber_k / a;
    case RobustLoss::kTukey: {
      if (a >= o.tukey_c) return 0.0;
      const double t = 1.0 - (x / o.tukey_c) * (x / o.tukey_c);
      return t * t;
    }
  }
  return 1.0;
}

void Residuals(const std::vector<Equation>& eqs, const Eigen::Vector3d& a, double radius,
               std::vector<double>* r) {
  r->resize(eqs.size());
  for (size_t i = 0; i < eqs.size(); ++i) (*r)[i] = eqs[i].n.dot(a) + radius;
}

// Weighted normal equations (3×3; the system is well conditioned whenever the leg is accepted,
// cond ≤ 1e4 so cond² ≤ 1e8 leaves > 7 significant digits, and exact data still come out to
// ~1e-15 m because the residual vanishes).
bool SolveWeighted(const std::vector<Equation>& eqs, const std::vector<double>& w, double radius,
                   Eigen::Vector3d* a, Eigen::Matrix3d* normal_matrix) {
  Eigen::Matrix3d m = Eigen::Matrix3d::Zero();
  Eigen::Vector3d rhs = Eigen::Vector3d::Zero();
  for (size_t i = 0; i < eqs.size(); ++i) {
    m.noalias() += w[i] * eqs[i].n * eqs[i].n.transpose();
    rhs -= w[i] * radius * eqs[i].n;
  }
  const Eigen::LDLT<Eigen::Matrix3d> ldlt(m);
  if (ldlt.info() != Eigen::Success || !(ldlt.vectorD().minCoeff() > 0.0)) return false;
  *a = ldlt.solve(rhs);
  *normal_matrix = m;
  return a->allFinite();
}

// IRLS with the robust scale s held fixed (the MM-estimator's M step): re-estimating s from
// the current residuals lets a monotone ψ (Huber) run away, since each step's bias along the weak
// direction inflates s, which gives the outliers more pull. Returns the iterations used.
int IrlsStage(RobustLoss loss, const std::vector<Equation>& eqs, double radius, double scale,
              const HexapodCalibrationOptions& o, Eigen::Vector3d* a, std::vector<double>* w,
              std::vector<double>* r) {
  int it = 0;
  for (; it < o.max_iterations; ++it) {
    Residuals(eqs, *a, radius, r);
    for (size_t i = 0; i < eqs.size(); ++i) (*w)[i] = Weight(loss, (*r)[i] / scale, o);
    Eigen::Vector3d next;
    Eigen::Matrix3d m;
    // With Tukey the kept equations can become rank-deficient; keep the last iterate then.
    if (!SolveWeighted(eqs, *w, radius, &next, &m)) break;
    const double step = (next - *a).norm();
    *a = next;
    if (step <= o.step_tolerance) {
      ++it;
      break;
    }
  }
  return it;
}

// Least median of squares start (Rousseeuw): the plain least-squares start is useless here, because
// eq. 14 is weak along the viewing ray of A_j (only the apparent width of the leg, sin θ = R/d,
// constrains it) and an outlying normal, which is not perpendicular to that ray, drags the
// least-squares solution far along it (metres, in the perspective test), where every residual
// looks alike and IRLS cannot tell inliers from outliers.
Eigen::Vector3d LeastMedianStart(const std::vector<Equation>& eqs, double radius,
                                 const HexapodCalibrationOptions& o, uint64_t seed,
                                 const Eigen::Vector3d& fallback, std::vector<double>* r,
                                 std::vector<double>* scratch) {
  std::mt19937_64 engine(seed);
  const uint64_t configurations = eqs.size() / 2;
  Eigen::Vector3d best = fallback;
  Residuals(eqs, best, radius, r);
  double best_median = RobustScale(*r, scratch, 0.0);
  for (int sample = 0; sample < o.robust_start_samples; ++sample) {
    const uint64_t k = engine() % configurations;
    const uint64_t l = (k + 1 + engine() % (configurations - 1)) % configurations;
    Eigen::Matrix3d m = Eigen::Matrix3d::Zero();
    Eigen::Vector3d rhs = Eigen::Vector3d::Zero();
    for (uint64_t i : {2 * k, 2 * k + 1, 2 * l, 2 * l + 1}) {
      m.noalias() += eqs[i].n * eqs[i].n.transpose();
      rhs -= radius * eqs[i].n;
    }
    const Eigen::LDLT<Eigen::Matrix3d> ldlt(m);
    // Two nearly parallel legs do not fix the point along them: skip the pair.
    if (!(ldlt.vectorD().minCoeff() > 1e-10 * ldlt.vectorD().maxCoeff())) continue;
    const Eigen::Vector3d candidate = ldlt.solve(rhs);
    if (!candidate.allFinite()) continue;
    Residuals(eqs, candidate, radius, r);
    const double median = RobustScale(*r, scratch, 0.0);
    if (median < best_median) {
      best_median = median;
      best = candidate;
    }
  }
  return best;
}

std::string LegName(int j) { return "leg " + std::to_string(j); }

// The estimator contract's report: the 18 coordinates of p_C_A, one identifiability analysis of
// the block-diagonal weighted system of eq. 14 (a refused leg has zero columns: unidentified).
EstimationReport HexapodEstimation(
    const HexapodCalibrationResult& result,
    const std::array<std::vector<Eigen::Vector3d>, robots::kHexapodLegs>& rows,
    const std::vector<double>& residuals) {
  EstimationReport e;
  e.estimator = "hexapod legs A_j (seed 002 eq. 14)";
  size_t total = 0;
  for (const auto& leg_rows : rows) total += leg_rows.size();
  constexpr int n = 3 * robots::kHexapodLegs;
  Eigen::MatrixXd J =
      Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(std::max<size_t>(1, total)), n);
  std::vector<std::string> names;
  Eigen::Index row = 0;
  for (int j = 0; j < robots::kHexapodLegs; ++j) {
    for (const char* axis : {"x", "y", "z"}) {
      names.push_back("leg" + std::to_string(j) + ".p_C_A." + axis);
    }
    // After the a-posteriori scale correction p' = p/s, ∂r/∂p' = s ∂r/∂p.
    const double s = result.scale_corrected ? result.scale : 1.0;
    for (const Eigen::Vector3d& v : rows[j]) J.block<1, 3>(row++, 3 * j) = s * v.transpose();
  }
  e.identifiability = AnalyzeIdentifiability(J, names);
  const Identifiability& id = e.identifiability;
  e.covariance = Eigen::MatrixXd::Zero(n, n);
  bool all = true;
  int iterations = 0;
  for (int j = 0; j < robots::kHexapodLegs; ++j) {
    const LegCalibration& leg = result.legs[j];
    iterations = std::max(iterations, leg.iterations);
    for (int k = 0; k < 3; ++k) {
      const int i = 3 * j + k;
      ParameterEstimate p;
      p.name = names[static_cast<size_t>(i)];
      p.unit = "m";
      p.value = result.p_C_A[j](k);
      p.estimated = true;
      p.identified = leg.status == LegStatus::kEstimated && id.identified[static_cast<size_t>(i)];
      p.sigma = p.identified ? std::sqrt(std::max(0.0, id.normal_inverse(i, i))) : kInf;
      all = all && p.identified;
      e.parameters.push_back(p);
    }
  }
  for (int a = 0; a < n; ++a) {
    for (int b = 0; b < n; ++b) {
      const bool both = e.parameters[static_cast<size_t>(a)].identified &&
                        e.parameters[static_cast<size_t>(b)].identified;
      e.covariance(a, b) = both ? id.normal_inverse(a, b) : (a == b ? kInf : 0.0);
    }
  }
  int estimated_legs = 0;
  for (const LegCalibration& leg : result.legs) {
    estimated_legs += leg.status == LegStatus::kEstimated ? 1 : 0;
  }
  e.status = all                   ? EstimationStatus::kConverged
             : estimated_legs == 0 ? EstimationStatus::kInsufficientData
                                   : EstimationStatus::kUnidentified;
  for (const std::string& m : result.errors) e.message += (e.message.empty() ? "" : "; ") + m;
  if (e.message.empty()) {
    e.message = "every leg estimated (" + std::string(ToString(result.loss)) + " loss)";
  }
  e.iterations = iterations;
  e.variance_factor = 1.0;  // each leg's σ is estimated from its own weighted residuals
  e.residuals.push_back(SummarizeResiduals("point-to-plane", "m", residuals));
  e.warnings = result.warnings;
  return e;
}

}  // namespace

const char* ToString(RobustLoss loss) {
  switch (loss) {
    case RobustLoss::kLeastSquares:
      return "least-squares";
    case RobustLoss::kHuber:
      return "huber";
    case RobustLoss::kTukey:
      return "tukey";
  }
  return "?";
}

const char* ToString(ScaleEstimator estimator) {
  switch (estimator) {
    case ScaleEstimator::kLeastSquares:
      return "least-squares";
    case ScaleEstimator::kMedianRatio:
      return "median-ratio";
    case ScaleEstimator::kMaxRatio:
      return "max-ratio";
  }
  return "?";
}

const char* ToString(LegStatus status) {
  switch (status) {
    case LegStatus::kEstimated:
      return "estimated";
    case LegStatus::kTooFewConfigurations:
      return "too few configurations";
    case LegStatus::kConfigurationsTooAlike:
      return "configurations too alike";
  }
  return "?";
}

std::string HexapodCalibrationData::Validate() const {
  std::ostringstream bad;
  const char* sep = "";
  if (!std::isfinite(leg_radius) || leg_radius <= 0.0) {
    bad << sep << "leg_radius = " << leg_radius << " (must be finite and > 0)";
    sep = "; ";
  }
  if (configurations.empty()) {
    bad << sep << "configurations is empty";
    sep = "; ";
  }
  for (size_t k = 0; k < configurations.size(); ++k) {
    for (int j = 0; j < robots::kHexapodLegs; ++j) {
      const auto& limbs = configurations[k][j];
      if (!limbs) continue;
      const Eigen::Vector3d* n[2] = {&limbs->n1_C, &limbs->n2_C};
      for (int l = 0; l < 2; ++l) {
        const double norm = n[l]->norm();
        if (!n[l]->allFinite() || std::abs(norm - 1.0) > 1e-6) {
          bad << sep << "configurations[" << k << "] leg " << j << " n" << (l + 1) << "_C = ("
              << n[l]->transpose() << ") (must be a finite unit vector, |n| = " << norm << ")";
          sep = "; ";
        }
      }
    }
  }
  return bad.str();
}

std::string HexapodCalibrationOptions::Validate() const {
  std::ostringstream bad;
  const char* sep = "";
  auto add = [&](const char* name, double value, const char* rule) {
    bad << sep << name << " = " << value << " (" << rule << ")";
    sep = "; ";
  };
  if (!(std::isfinite(huber_k) && huber_k > 0.0)) add("huber_k", huber_k, "must be finite and > 0");
  if (!(std::isfinite(tukey_c) && tukey_c > 0.0)) add("tukey_c", tukey_c, "must be finite and > 0");
  if (max_iterations < 1) add("max_iterations", max_iterations, "must be >= 1");
  if (robust_start_samples < 1) add("robust_start_samples", robust_start_samples, "must be >= 1");
  if (!(std::isfinite(step_tolerance) && step_tolerance >= 0.0)) {
    add("step_tolerance", step_tolerance, "must be finite and >= 0");
  }
  if (!(std::isfinite(min_scale) && min_scale > 0.0))
    add("min_scale", min_scale, "must be finite and > 0");
  if (!(report_weight_below >= 0.0 && report_weight_below <= 1.0)) {
    add("report_weight_below", report_weight_below, "must be in [0, 1]");
  }
  if (!(warn_condition_number >= 1.0)) {
    add("warn_condition_number", warn_condition_number, "must be >= 1");
  }
  if (!(max_condition_number >= warn_condition_number)) {
    add("max_condition_number", max_condition_number, "must be >= warn_condition_number");
  }
  if (min_configurations < 2) add("min_configurations", min_configurations, "must be >= 2");
  if (!(std::isfinite(warn_scale_deviation) && warn_scale_deviation >= 0.0)) {
    add("warn_scale_deviation", warn_scale_deviation, "must be finite and >= 0");
  }
  if (!(warn_down_weighted_fraction >= 0.0 && warn_down_weighted_fraction <= 1.0)) {
    add("warn_down_weighted_fraction", warn_down_weighted_fraction, "must be in [0, 1]");
  }
  const int loss_value = static_cast<int>(loss);
  if (loss_value < 0 || loss_value > 2) add("loss", loss_value, "unknown");
  const int scale_value = static_cast<int>(scale_estimator);
  if (scale_value < 0 || scale_value > 2) add("scale_estimator", scale_value, "unknown");
  return bad.str();
}

bool FitRigidTransform(const std::vector<Eigen::Vector3d>& p_A,
                       const std::vector<Eigen::Vector3d>& p_B, Eigen::Isometry3d* X_AB) {
  if (p_A.size() != p_B.size() || p_A.size() < 3) return false;
  const double n = static_cast<double>(p_A.size());
  Eigen::Vector3d c_A = Eigen::Vector3d::Zero(), c_B = Eigen::Vector3d::Zero();
  for (size_t i = 0; i < p_A.size(); ++i) {
    c_A += p_A[i];
    c_B += p_B[i];
  }
  c_A /= n;
  c_B /= n;
  Eigen::Matrix3d h = Eigen::Matrix3d::Zero();  // Σ (b − c_B)(a − c_A)ᵀ
  Eigen::Matrix3d spread_B = Eigen::Matrix3d::Zero();
  for (size_t i = 0; i < p_A.size(); ++i) {
    h += (p_B[i] - c_B) * (p_A[i] - c_A).transpose();
    spread_B += (p_B[i] - c_B) * (p_B[i] - c_B).transpose();
  }
  // The rotation is determined when the (model) points span at least a plane.
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> spread(spread_B);
  const Eigen::Vector3d ev = spread.eigenvalues();  // ascending
  if (!(ev(1) > 1e-12 * ev(2)) || !(ev(2) > 0.0)) return false;
  // Kabsch: R = V diag(1, 1, det(V Uᵀ)) Uᵀ maximises tr(R H) over proper rotations.
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(h, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d d = Eigen::Matrix3d::Identity();
  d(2, 2) = (svd.matrixV() * svd.matrixU().transpose()).determinant() < 0.0 ? -1.0 : 1.0;
  const Eigen::Matrix3d r = svd.matrixV() * d * svd.matrixU().transpose();
  X_AB->setIdentity();
  X_AB->linear() = r;
  X_AB->translation() = c_A - r * c_B;
  return X_AB->matrix().allFinite();
}

bool EstimateScale(const std::vector<Eigen::Vector3d>& p_est,
                   const std::vector<Eigen::Vector3d>& p_cad, ScaleEstimates* scales) {
  if (p_est.size() != p_cad.size() || p_est.size() < 2) return false;
  const size_t n = p_est.size();
  // Pairwise ratios (seed eq. 16's quantity).
  std::vector<double> ratios;
  for (size_t j = 0; j < n; ++j) {
    for (size_t k = j + 1; k < n; ++k) {
      const double d_cad = (p_cad[j] - p_cad[k]).norm();
      if (!(d_cad > 0.0)) return false;
      ratios.push_back((p_est[j] - p_est[k]).norm() / d_cad);
    }
  }
  scales->max_ratio = *std::max_element(ratios.begin(), ratios.end());
  std::sort(ratios.begin(), ratios.end());
  const size_t m = ratios.size();
  scales->median_ratio = m % 2 ? ratios[m / 2] : 0.5 * (ratios[m / 2 - 1] + ratios[m / 2]);
  // Umeyama (1991): for p_est ≈ s R p_cad + t, s = tr(D S) / Σ|p_cad − c_cad|², with D the
  // singular values of Σ (p_est − c_est)(p_cad − c_cad)ᵀ and S = diag(1, 1, ±1) the reflection fix.
  Eigen::Vector3d c_e = Eigen::Vector3d::Zero(), c_c = Eigen::Vector3d::Zero();
  for (size_t i = 0; i < n; ++i) {
    c_e += p_est[i];
    c_c += p_cad[i];
  }
  c_e /= static_cast<double>(n);
  c_c /= static_cast<double>(n);
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  double var_cad = 0.0;
  for (size_t i = 0; i < n; ++i) {
    cov += (p_est[i] - c_e) * (p_cad[i] - c_c).transpose();
    var_cad += (p_cad[i] - c_c).squaredNorm();
  }
  if (!(var_cad > 0.0)) return false;
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(cov, Eigen::ComputeFullU | Eigen::ComputeFullV);
  const double sign = svd.matrixU().determinant() * svd.matrixV().determinant() < 0.0 ? -1.0 : 1.0;
  const Eigen::Vector3d sv = svd.singularValues();
  scales->least_squares = (sv(0) + sv(1) + sign * sv(2)) / var_cad;
  return std::isfinite(scales->least_squares);
}

HexapodCalibrationResult CalibrateHexapod(const HexapodCalibrationData& data,
                                          const robots::HexapodModel& cad,
                                          const HexapodCalibrationOptions& options) {
  {
    std::string bad = data.Validate();
    const std::string bad_options = options.Validate();
    if (!bad_options.empty()) bad += (bad.empty() ? "" : "; ") + bad_options;
    for (int j = 0; j < robots::kHexapodLegs; ++j) {
      if (!cad.p_B_A[j].allFinite()) {
        bad += (bad.empty() ? "" : "; ") + std::string("cad.p_B_A[") + std::to_string(j) +
               "] is not finite";
      }
    }
    if (!bad.empty()) throw std::invalid_argument("CalibrateHexapod: " + bad);
  }
  HexapodCalibrationResult result;
  result.leg_radius = data.leg_radius;
  result.configurations = static_cast<int>(data.configurations.size());
  result.loss = options.loss;
  result.scale_estimator = options.scale_estimator;
  const double radius = data.leg_radius;

  std::vector<Equation> eqs;
  std::vector<double> w, r, scratch;
  // For the estimator contract: each estimated leg's rows √w n / σ (so that (JᵀJ)⁻¹ is its
  // covariance) and every equation's residual.
  std::array<std::vector<Eigen::Vector3d>, robots::kHexapodLegs> contract_rows;
  std::vector<double> contract_residuals;
  eqs.reserve(2 * data.configurations.size());
  for (int j = 0; j < robots::kHexapodLegs; ++j) {
    LegCalibration& leg = result.legs[j];
    eqs.clear();
    for (size_t k = 0; k < data.configurations.size(); ++k) {
      const auto& limbs = data.configurations[k][j];
      if (!limbs) continue;
      eqs.push_back({limbs->n1_C, static_cast<int>(k), 1});
      eqs.push_back({limbs->n2_C, static_cast<int>(k), 2});
    }
    leg.configurations = static_cast<int>(eqs.size() / 2);
    leg.equations = static_cast<int>(eqs.size());
    if (leg.configurations < options.min_configurations) {
      leg.status = LegStatus::kTooFewConfigurations;
      result.errors.push_back(LegName(j) + ": seen with both limbs in " +
                              std::to_string(leg.configurations) + " configuration(s); eq. 14 " +
                              "needs at least " + std::to_string(options.min_configurations) +
                              " with different leg directions");
      continue;
    }
    // Condition number of the unweighted 2N×3 system (unit rows).
    Eigen::MatrixX3d j_matrix(eqs.size(), 3);
    for (size_t i = 0; i < eqs.size(); ++i) j_matrix.row(static_cast<long>(i)) = eqs[i].n;
    const Eigen::JacobiSVD<Eigen::MatrixX3d> svd(j_matrix);
    const Eigen::Vector3d sv = svd.singularValues();
    leg.condition_number = sv(2) > 0.0 ? sv(0) / sv(2) : kInf;
    if (!(leg.condition_number <= options.max_condition_number)) {
      leg.status = LegStatus::kConfigurationsTooAlike;
      std::ostringstream msg;
      msg << LegName(j) << ": configurations too alike: condition number of eq. 14 is "
          << leg.condition_number << " > " << options.max_condition_number
          << " (the leg directions do not vary enough to fix A_j along the leg; record poses "
             "with larger angles between the leg directions, e.g. PlanCalibrationPoses)";
      result.errors.push_back(msg.str());
      continue;
    }
    if (leg.condition_number > options.warn_condition_number) {
      std::ostringstream msg;
      msg << LegName(j) << ": condition number of eq. 14 is " << leg.condition_number << " > "
          << options.warn_condition_number
          << ": A_j is poorly determined along its weakest direction (configurations too alike "
             "or the camera too far for the leg's apparent width); see the covariance";
      result.warnings.push_back(msg.str());
    }

    // Plain least squares first: the answer for kLeastSquares, the fallback start otherwise.
    w.assign(eqs.size(), 1.0);
    Eigen::Vector3d a;
    Eigen::Matrix3d normal_matrix;
    SolveWeighted(eqs, w, radius, &a, &normal_matrix);  // cond checked above: solvable
    // Robust losses: an MM-estimator. A high-breakdown start (least median of squares), the
    // scale s = 1.4826 · (1 + 5/(n − 3)) · median|r| (MAD about zero, finite-sample corrected) of
    // its residuals, then IRLS for the chosen loss with s fixed.
    double s = options.min_scale;
    if (options.loss != RobustLoss::kLeastSquares) {
      a = LeastMedianStart(eqs, radius, options, options.seed + static_cast<uint64_t>(j), a, &r,
                           &scratch);
      Residuals(eqs, a, radius, &r);
      // The start minimised the median residual over its candidates, so with few equations its
      // MAD underestimates the noise and Tukey's cut-off would reject good equations (a leg seen
      // in ~10 configurations once locked onto a 3 cm wrong answer). Rousseeuw & Leroy's
      // finite-sample correction of the LMedS scale, (1 + 5/(n − p)) with p = 3 unknowns.
      const double n_minus_p = static_cast<double>(eqs.size()) - 3.0;
      s = RobustScale(r, &scratch, options.min_scale) * (1.0 + 5.0 / std::max(1.0, n_minus_p));
      leg.iterations = IrlsStage(options.loss, eqs, radius, s, options, &a, &w, &r);
    }
    leg.robust_scale = s;
    // Final weights at the final estimate, from which the statistics and covariance come.
    Residuals(eqs, a, radius, &r);
    double sum_w = 0.0, sum_wr2 = 0.0, sum_r2 = 0.0, sum_r2_in = 0.0, max_r = 0.0;
    int inliers = 0;
    Eigen::Matrix3d jtwj = Eigen::Matrix3d::Zero();
    for (size_t i = 0; i < eqs.size(); ++i) {
      w[i] = Weight(options.loss, r[i] / s, options);
      sum_w += w[i];
      sum_wr2 += w[i] * r[i] * r[i];
      sum_r2 += r[i] * r[i];
      max_r = std::max(max_r, std::abs(r[i]));
      jtwj.noalias() += w[i] * eqs[i].n * eqs[i].n.transpose();
      if (w[i] < options.report_weight_below) {
        result.down_weighted.push_back({eqs[i].configuration, j, eqs[i].limb, r[i], w[i]});
        ++leg.down_weighted;
      } else {
        sum_r2_in += r[i] * r[i];
        ++inliers;
      }
    }
    const double n_eq = static_cast<double>(eqs.size());
    leg.residual_rms = std::sqrt(sum_r2 / n_eq);
    leg.residual_max = max_r;
    leg.residual_rms_inliers = inliers > 0 ? std::sqrt(sum_r2_in / inliers) : kNaN;
    // σ² = Σ w r² / (Σ w − 3): the weighted residual variance with the 3 parameters' degrees of
    // freedom removed; cov = σ² (JᵀWJ)⁻¹ (the usual IRLS approximation; it ignores ψ' and so
    // slightly under-states the spread for Tukey near the rejection point).
    leg.sigma = sum_w > 3.0 ? std::sqrt(sum_wr2 / (sum_w - 3.0)) : kNaN;
    const Eigen::FullPivLU<Eigen::Matrix3d> lu(jtwj);
    leg.covariance = lu.isInvertible() ? Eigen::Matrix3d(leg.sigma * leg.sigma * lu.inverse())
                                       : Eigen::Matrix3d::Constant(kInf);
    leg.p_C_A = a;
    leg.status = LegStatus::kEstimated;
    if (leg.sigma > 0.0) {
      for (size_t i = 0; i < eqs.size(); ++i) {
        contract_rows[j].push_back(std::sqrt(w[i]) / leg.sigma * eqs[i].n);
      }
    }
    contract_residuals.insert(contract_residuals.end(), r.begin(), r.end());
    if (leg.down_weighted > options.warn_down_weighted_fraction * n_eq) {
      std::ostringstream msg;
      msg << LegName(j) << ": " << leg.down_weighted << " of " << leg.equations
          << " equations down-weighted (more than " << 100.0 * options.warn_down_weighted_fraction
          << " %): check the edge extraction of this leg";
      result.warnings.push_back(msg.str());
    }
  }

  // Eq. 16 (scale) and eq. 15 (rigid fit) on the estimated legs.
  std::vector<Eigen::Vector3d> est, cad_points;
  std::vector<int> index;
  for (int j = 0; j < robots::kHexapodLegs; ++j) {
    result.p_C_A[j] = result.legs[j].p_C_A;
    if (result.legs[j].status != LegStatus::kEstimated) continue;
    est.push_back(result.legs[j].p_C_A);
    cad_points.push_back(cad.p_B_A[j]);
    index.push_back(j);
  }
  ScaleEstimates scales;
  if (EstimateScale(est, cad_points, &scales)) {
    result.scale_least_squares = scales.least_squares;
    result.scale_median_ratio = scales.median_ratio;
    result.scale_max_ratio = scales.max_ratio;
    switch (options.scale_estimator) {
      case ScaleEstimator::kLeastSquares:
        result.scale = scales.least_squares;
        break;
      case ScaleEstimator::kMedianRatio:
        result.scale = scales.median_ratio;
        break;
      case ScaleEstimator::kMaxRatio:
        result.scale = scales.max_ratio;
        break;
    }
    if (std::abs(result.scale - 1.0) > options.warn_scale_deviation) {
      std::ostringstream msg;
      msg << "scale (eq. 16, " << ToString(options.scale_estimator) << ") is " << result.scale
          << ": the estimated base is " << 100.0 * (result.scale - 1.0)
          << " % larger than the CAD; an error on the leg radius R scales every A_j (R_true ≈ "
          << radius / result.scale << " m if the CAD is right)";
      result.warnings.push_back(msg.str());
    }
    if (options.correct_scale && result.scale > 0.0) {
      for (size_t i = 0; i < est.size(); ++i) {
        const int j = index[i];
        est[i] /= result.scale;
        result.p_C_A[j] = est[i];
        result.legs[j].p_C_A = est[i];
        result.legs[j].covariance /= result.scale * result.scale;
        result.legs[j].sigma /= result.scale;
      }
      result.scale_corrected = true;
    }
  } else {
    result.warnings.push_back("no scale (eq. 16): fewer than 2 legs estimated");
  }
  if (FitRigidTransform(est, cad_points, &result.X_CB)) {
    result.rigid_fit = true;
    double sum = 0.0, worst = 0.0;
    for (size_t i = 0; i < est.size(); ++i) {
      const double e = (est[i] - result.X_CB * cad_points[i]).norm();
      result.legs[index[i]].rigid_fit_residual = e;
      sum += e * e;
      worst = std::max(worst, e);
    }
    result.rigid_fit_rms = std::sqrt(sum / static_cast<double>(est.size()));
    result.rigid_fit_max = worst;
  } else {
    result.X_CB.setIdentity();
    result.warnings.push_back("no rigid fit (eq. 15): fewer than 3 legs estimated (" +
                              std::to_string(est.size()) + ") or their CAD points are collinear");
  }
  result.estimation = HexapodEstimation(result, contract_rows, contract_residuals);
  return result;
}

}  // namespace kinevis::calibration
