#include "calibration/common/estimation.h"

#include <Eigen/QR>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <set>
#include <sstream>
#include <stdexcept>
#include <utility>

#include "common/config_error.h"

namespace kinevis::calibration {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

struct StatusName {
  EstimationStatus status;
  const char* name;
};
constexpr StatusName kStatusNames[] = {
    {EstimationStatus::kConverged, "converged"},
    {EstimationStatus::kUnidentified, "unidentified"},
    {EstimationStatus::kNotConverged, "not-converged"},
    {EstimationStatus::kInsufficientData, "insufficient-data"},
    {EstimationStatus::kFailed, "failed"},
};

// "0.707 radius - 0.707 camera_distance": terms >= min_coefficient, largest first and positive
// (the sign of a null vector is arbitrary).
std::string Combination(const Eigen::VectorXd& v, const std::vector<std::string>& names,
                        double min_coefficient) {
  std::vector<std::pair<double, size_t>> terms;
  for (Eigen::Index i = 0; i < v.size(); ++i) {
    if (std::abs(v(i)) >= min_coefficient) terms.emplace_back(v(i), static_cast<size_t>(i));
  }
  std::sort(terms.begin(), terms.end(),
            [](const auto& a, const auto& b) { return std::abs(a.first) > std::abs(b.first); });
  const double sign = terms.empty() || terms.front().first > 0.0 ? 1.0 : -1.0;
  std::string out;
  for (size_t k = 0; k < terms.size(); ++k) {
    const double w = sign * terms[k].first;
    char buffer[32];
    std::snprintf(buffer, sizeof buffer, "%.3f ", k == 0 ? w : std::abs(w));
    if (k > 0) out += w < 0 ? " - " : " + ";
    out += buffer + names[terms[k].second];
  }
  return out;
}

// Report figures: 4 significant digits ("nan", "inf" as such).
std::string Short(double value) {
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%.4g", value);
  return buffer;
}

std::string Sigma(double sigma) { return std::isinf(sigma) ? "unidentified" : Short(sigma); }

}  // namespace

const char* ToString(EstimationStatus status) {
  for (const StatusName& s : kStatusNames) {
    if (s.status == status) return s.name;
  }
  return "unknown";
}

bool ParseEstimationStatus(const std::string& text, EstimationStatus* status) {
  for (const StatusName& s : kStatusNames) {
    if (text == s.name) {
      *status = s.status;
      return true;
    }
  }
  return false;
}

ResidualSummary SummarizeResiduals(std::string name, std::string unit,
                                   const std::vector<double>& values) {
  ResidualSummary s;
  s.name = std::move(name);
  s.unit = std::move(unit);
  s.count = static_cast<int>(values.size());
  if (values.empty()) return s;
  double sum = 0.0, sum2 = 0.0;
  for (double v : values) {
    sum += v;
    sum2 += v * v;
    s.max_abs = std::max(s.max_abs, std::abs(v));
  }
  const double n = static_cast<double>(values.size());
  s.mean = sum / n;
  s.rms = std::sqrt(sum2 / n);
  return s;
}

std::string IdentifiabilityOptions::Validate() const {
  common::Problems p;
  if (!(rank_tolerance > 0.0 && rank_tolerance < 1.0)) {
    p.Add("rank_tolerance", rank_tolerance, "must be in (0, 1)");
  }
  if (!(null_tolerance > 0.0 && null_tolerance <= 1.0)) {
    p.Add("null_tolerance", null_tolerance, "must be in (0, 1]");
  }
  if (!(min_coefficient >= 0.0 && min_coefficient < 1.0)) {
    p.Add("min_coefficient", min_coefficient, "must be in [0, 1)");
  }
  if (!(warn_correlation > 0.0 && warn_correlation <= 1.0)) {
    p.Add("warn_correlation", warn_correlation, "must be in (0, 1]");
  }
  return p.Message();
}

Identifiability AnalyzeIdentifiability(const Eigen::MatrixXd& J,
                                       const std::vector<std::string>& names,
                                       const IdentifiabilityOptions& options) {
  {
    common::Problems p("AnalyzeIdentifiability");
    const std::string bad_options = options.Validate();
    if (!bad_options.empty()) p.Add(bad_options);
    if (static_cast<size_t>(J.cols()) != names.size()) {
      p.Add("names", std::to_string(names.size()),
            "must name every column of J (" + std::to_string(J.cols()) + ")");
    }
    if (!J.allFinite()) p.Add("J: must be finite");
    p.ThrowIfAny();
  }
  Identifiability out;
  const Eigen::Index n = J.cols();
  out.parameters = static_cast<int>(n);
  out.identified.assign(static_cast<size_t>(n), false);
  out.normal_inverse = Eigen::MatrixXd::Zero(n, n);
  if (n == 0) return out;

  // Column scaling d_j: J_s = J D⁻¹. Zero columns stay zero (and land in the null space).
  Eigen::VectorXd scale(n);
  for (Eigen::Index j = 0; j < n; ++j) {
    scale(j) = options.scaling == IdentifiabilityOptions::Scaling::kColumnNorm
                   ? J.col(j).norm()
                   : J.col(j).cwiseAbs().maxCoeff();
  }
  Eigen::MatrixXd Js = J;
  for (Eigen::Index j = 0; j < n; ++j) {
    if (scale(j) > 0.0) Js.col(j) /= scale(j);
  }
  // The SVD of a tall J through the n×n R of its QR (same singular values and V, cheaper).
  Eigen::MatrixXd R;
  if (Js.rows() > n) {
    const Eigen::HouseholderQR<Eigen::MatrixXd> qr(Js);
    R = qr.matrixQR().topRows(n).triangularView<Eigen::Upper>();
  } else {
    R = Js;
  }
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd(R, Eigen::ComputeFullV);
  Eigen::VectorXd sv = Eigen::VectorXd::Zero(n);
  sv.head(svd.singularValues().size()) = svd.singularValues();
  const Eigen::MatrixXd& V = svd.matrixV();
  out.singular_values.assign(sv.data(), sv.data() + sv.size());
  const double threshold = options.rank_tolerance * sv(0);
  for (Eigen::Index i = 0; i < n; ++i) out.rank += sv(i) > threshold ? 1 : 0;
  out.condition_number = out.rank == n && sv(n - 1) > 0.0 ? sv(0) / sv(n - 1) : kInf;
  out.condition_number_identified = out.rank > 0 ? sv(0) / sv(out.rank - 1) : kInf;

  Eigen::VectorXd in_null = Eigen::VectorXd::Zero(n);
  for (Eigen::Index i = out.rank; i < n; ++i) {
    in_null += V.col(i).cwiseAbs2();
    out.unidentified.push_back(Combination(V.col(i), names, options.min_coefficient));
  }
  Eigen::MatrixXd inverse_scaled = Eigen::MatrixXd::Zero(n, n);
  for (Eigen::Index i = 0; i < out.rank; ++i) {
    inverse_scaled.noalias() += V.col(i) * V.col(i).transpose() / (sv(i) * sv(i));
  }
  for (Eigen::Index a = 0; a < n; ++a) {
    out.identified[static_cast<size_t>(a)] =
        scale(a) > 0.0 && std::sqrt(in_null(a)) < options.null_tolerance;
    for (Eigen::Index b = 0; b < n; ++b) {
      if (scale(a) > 0.0 && scale(b) > 0.0) {
        out.normal_inverse(a, b) = inverse_scaled(a, b) / (scale(a) * scale(b));
      }
    }
  }
  for (Eigen::Index a = 0; a < n; ++a) {
    for (Eigen::Index b = a + 1; b < n; ++b) {
      if (!out.identified[static_cast<size_t>(a)] || !out.identified[static_cast<size_t>(b)]) {
        continue;
      }
      const double denominator = std::sqrt(out.normal_inverse(a, a) * out.normal_inverse(b, b));
      if (!(denominator > 0.0)) continue;
      const double rho = out.normal_inverse(a, b) / denominator;
      if (std::abs(rho) >= options.warn_correlation) {
        char buffer[32];
        std::snprintf(buffer, sizeof buffer, ": %.3f", rho);
        out.strong_correlations.push_back(names[static_cast<size_t>(a)] + " ~ " +
                                          names[static_cast<size_t>(b)] + buffer);
      }
    }
  }
  return out;
}

const ParameterEstimate* EstimationReport::Find(const std::string& name) const {
  for (const ParameterEstimate& p : parameters) {
    if (p.name == name) return &p;
  }
  return nullptr;
}

std::string EstimationReport::BriefReport() const {
  int estimated = 0, identified = 0;
  for (const ParameterEstimate& p : parameters) {
    estimated += p.estimated ? 1 : 0;
    identified += p.identified ? 1 : 0;
  }
  std::ostringstream s;
  s << estimator << ": " << ToString(status) << ", " << identified << " of " << estimated
    << " estimated parameters identified (rank " << identifiability.rank << ")";
  if (!residuals.empty()) {
    const ResidualSummary& r = residuals.front();
    s << ", " << r.name << " rms " << Short(r.rms) << " " << r.unit << " over " << r.count;
  }
  s << ", " << warnings.size() << " warning" << (warnings.size() == 1 ? "" : "s");
  return s.str();
}

std::string EstimationReport::FullReport() const {
  std::ostringstream s;
  s << BriefReport() << "\n";
  if (!message.empty()) s << "  message: " << message << "\n";
  s << "  iterations " << iterations << ", cost " << Short(initial_cost) << " -> "
    << Short(final_cost) << ", variance factor " << Short(variance_factor) << "\n";
  for (const ResidualSummary& r : residuals) {
    s << "  residual " << r.name << " (" << r.unit << "): count " << r.count << ", mean "
      << Short(r.mean) << ", rms " << Short(r.rms) << ", max " << Short(r.max_abs) << "\n";
  }
  for (const ParameterEstimate& p : parameters) {
    s << "  " << p.name << " = " << common::Num(p.value) << " " << p.unit;
    if (!p.estimated) {
      s << " (held)";
    } else {
      s << " ± " << Sigma(p.sigma) << " (from " << common::Num(p.initial) << ")";
    }
    s << "\n";
  }
  const Identifiability& id = identifiability;
  s << "  identifiability: rank " << id.rank << " of " << id.parameters << ", condition "
    << Short(id.condition_number) << "\n";
  for (const std::string& u : id.unidentified) s << "    unidentified: " << u << "\n";
  for (const std::string& g : id.gauges) s << "    gauge: " << g << "\n";
  for (const std::string& c : id.strong_correlations) s << "    correlated: " << c << "\n";
  for (const std::string& w : warnings) s << "  warning: " << w << "\n";
  return s.str();
}

std::string EstimationReport::Validate() const {
  common::Problems p;
  const Eigen::Index n = static_cast<Eigen::Index>(parameters.size());
  std::set<std::string> names;
  for (const ParameterEstimate& e : parameters) {
    if (!names.insert(e.name).second) p.Add("parameters", e.name, "names must be unique");
    if (!(e.sigma >= 0.0)) p.Add("parameters." + e.name + ".sigma", e.sigma, "must be >= 0");
    if (e.identified && !e.estimated) {
      p.Add("parameters." + e.name, "identified", "cannot be identified when held");
    }
    if (status == EstimationStatus::kConverged && e.estimated && !e.identified) {
      p.Add("parameters." + e.name, "unidentified",
            "a converged estimate identifies every "
            "estimated parameter");
    }
  }
  if (covariance.size() > 0 && (covariance.rows() != n || covariance.cols() != n)) {
    p.Add("covariance", std::to_string(covariance.rows()) + "x" + std::to_string(covariance.cols()),
          "must be parameters x parameters (" + std::to_string(n) + ")");
  }
  if (identifiability.rank < 0 || identifiability.rank > identifiability.parameters) {
    p.Add("identifiability.rank", identifiability.rank, "must be in [0, parameters]");
  }
  for (const ResidualSummary& r : residuals) {
    if (r.count < 0 || !(r.rms >= 0.0) || !(r.max_abs >= 0.0)) {
      p.Add("residuals." + r.name, r.rms, "count, rms and max must be >= 0");
    }
  }
  return p.Message();
}

}  // namespace kinevis::calibration
