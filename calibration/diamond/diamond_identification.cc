#include "calibration/diamond/diamond_identification.h"

#include <ceres/ceres.h>

#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>
#include <random>
#include <sstream>
#include <stdexcept>

#include "calibration/diamond/diamond_residuals_internal.h"
#include "vision/diamond/spherical_positioning.h"

namespace kinevis::calibration {
namespace {

using internal::ParameterFrame;
using X = std::array<double, kDiamondParameterCount>;

std::string Fmt(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.6g", v);
  return buf;
}

// Free parameter indices of the options.
std::vector<int> FreeParameters(const DiamondIdentificationOptions& o) {
  const bool flags[kDiamondParameterCount] = {o.estimate_radius,
                                              o.estimate_alpha,
                                              o.estimate_beta,
                                              o.estimate_mean_offset,
                                              o.estimate_offset_difference,
                                              o.estimate_camera_rotation,
                                              o.estimate_camera_rotation,
                                              o.estimate_camera_rotation,
                                              o.estimate_camera_direction,
                                              o.estimate_camera_direction,
                                              o.estimate_camera_distance};
  std::vector<int> free;
  for (int j = 0; j < kDiamondParameterCount; ++j) {
    if (flags[j]) free.push_back(j);
  }
  return free;
}

ResidualStatistics Statistics(const std::vector<Eigen::Vector2d>& r) {
  ResidualStatistics s;
  s.count = static_cast<int>(r.size());
  if (r.empty()) return s;
  double sq = 0.0;
  for (const Eigen::Vector2d& e : r) {
    s.mean += e;
    s.rms += e.cwiseAbs2();
    s.sup = s.sup.cwiseMax(e.cwiseAbs());
    sq += e.squaredNorm();
  }
  s.mean /= s.count;
  s.rms = (s.rms / s.count).cwiseSqrt();
  s.rms_norm = std::sqrt(sq / s.count);
  return s;
}

// Stacked Jacobian ∂r/∂z (rows: residuals, all kDiamondParameterCount columns) and residuals.
bool EvaluateAll(const std::vector<ceres::CostFunction*>& costs, const double* z,
                 Eigen::MatrixXd* J, Eigen::VectorXd* r) {
  const int n = static_cast<int>(costs.size());
  J->resize(2 * n, kDiamondParameterCount);
  r->resize(2 * n);
  const double* params[1] = {z};
  for (int k = 0; k < n; ++k) {
    double res[2];
    double jac[2 * kDiamondParameterCount];
    double* jacs[1] = {jac};
    if (!costs[k]->Evaluate(params, res, jacs)) return false;
    (*r)(2 * k) = res[0];
    (*r)(2 * k + 1) = res[1];
    for (int c = 0; c < kDiamondParameterCount; ++c) {
      (*J)(2 * k, c) = jac[c];
      (*J)(2 * k + 1, c) = jac[kDiamondParameterCount + c];
    }
  }
  return true;
}

// W = L⁻¹ with L Lᵀ = σ² J Jᵀ, the covariance of (φ, γ) from pixel noise σ.
bool Whitening(const vision::SphereFix& fix, double sigma, Eigen::Matrix2d* W) {
  const Eigen::Matrix2d cov = sigma * sigma * fix.J_task_pixel * fix.J_task_pixel.transpose();
  const Eigen::LLT<Eigen::Matrix2d> llt(cov);
  if (llt.info() != Eigen::Success || !(cov.determinant() > 0)) return false;
  *W = Eigen::Matrix2d(llt.matrixL()).inverse();
  return true;
}

Eigen::Matrix3d Exp(const Eigen::Vector3d& w) {
  const double angle = w.norm();
  if (angle == 0.0) return Eigen::Matrix3d::Identity();
  return Eigen::AngleAxisd(angle, w / angle).toRotationMatrix();
}

}  // namespace

const char* DiamondParameterName(int parameter) {
  static const char* const kNames[kDiamondParameterCount] = {"radius",
                                                             "alpha",
                                                             "beta",
                                                             "mean_offset",
                                                             "half_offset_difference",
                                                             "camera_rotation_x",
                                                             "camera_rotation_y",
                                                             "camera_rotation_z",
                                                             "camera_direction_1",
                                                             "camera_direction_2",
                                                             "camera_distance"};
  if (parameter < 0 || parameter >= kDiamondParameterCount) return "?";
  return kNames[parameter];
}

const char* DiamondParameterUnit(int parameter) {
  return parameter == kDiamondRadius || parameter == kDiamondCameraDistance ? "m" : "rad";
}

const char* ToString(DiamondResidual residual) {
  return residual == DiamondResidual::kPixel ? "pixel" : "spherical";
}

const char* ToString(ColumnScaling scaling) {
  switch (scaling) {
    case ColumnScaling::kNone:
      return "none";
    case ColumnScaling::kExtremal:
      return "extremal";
    case ColumnScaling::kColumnNorm:
      return "column-norm";
  }
  return "?";
}

const char* ToString(DiamondIdentificationStatus status) {
  switch (status) {
    case DiamondIdentificationStatus::kConverged:
      return "converged";
    case DiamondIdentificationStatus::kNoConvergence:
      return "no convergence";
    case DiamondIdentificationStatus::kTooFewSamples:
      return "too few samples";
    case DiamondIdentificationStatus::kNothingToEstimate:
      return "nothing to estimate";
    case DiamondIdentificationStatus::kSolverFailed:
      return "solver failed";
  }
  return "?";
}

std::string DiamondIdentificationOptions::Validate() const {
  std::vector<std::string> p;
  if (!(std::isfinite(pixel_sigma) && pixel_sigma > 0)) {
    p.push_back("pixel_sigma = " + Fmt(pixel_sigma) + " px (need > 0)");
  }
  if (max_iterations < 1)
    p.push_back("max_iterations = " + std::to_string(max_iterations) + " (need >= 1)");
  if (!(function_tolerance >= 0)) p.push_back("function_tolerance = " + Fmt(function_tolerance));
  if (!(parameter_tolerance >= 0)) {
    p.push_back("parameter_tolerance = " + Fmt(parameter_tolerance));
  }
  if (!(gradient_tolerance >= 0)) p.push_back("gradient_tolerance = " + Fmt(gradient_tolerance));
  if (!(rank_tolerance > 0 && rank_tolerance < 1)) {
    p.push_back("rank_tolerance = " + Fmt(rank_tolerance) + " (need (0, 1))");
  }
  if (!(warn_condition_number >= 1)) {
    p.push_back("warn_condition_number = " + Fmt(warn_condition_number) + " (need >= 1)");
  }
  if (!(warn_correlation > 0 && warn_correlation <= 1)) {
    p.push_back("warn_correlation = " + Fmt(warn_correlation) + " (need (0, 1])");
  }
  if (!(min_incidence_cosine >= 0 && min_incidence_cosine < 1)) {
    p.push_back("min_incidence_cosine = " + Fmt(min_incidence_cosine) + " (need [0, 1))");
  }
  if (min_samples < 1) p.push_back("min_samples = " + std::to_string(min_samples) + " (need >= 1)");
  std::string out;
  for (const std::string& s : p) out += (out.empty() ? "" : "; ") + s;
  return out;
}

std::string DiamondSimulationOptions::Validate() const {
  std::string out;
  if (!(std::isfinite(pixel_noise_sigma) && pixel_noise_sigma >= 0)) {
    out += "pixel_noise_sigma = " + Fmt(pixel_noise_sigma) + " px (need >= 0)";
  }
  if (!(std::isfinite(joint_noise_sigma) && joint_noise_sigma >= 0)) {
    out += std::string(out.empty() ? "" : "; ") + "joint_noise_sigma = " + Fmt(joint_noise_sigma) +
           " rad (need >= 0)";
  }
  return out;
}

X DiamondInitialParameters(const robots::DiamondModel& model, const Eigen::Isometry3d& X_OC) {
  X x{};
  x[kDiamondRadius] = model.radius;
  x[kDiamondAlpha] = model.alpha;
  x[kDiamondBeta] = model.beta;
  x[kDiamondMeanOffset] = 0.5 * (model.joint_offsets[0] + model.joint_offsets[1]);
  x[kDiamondHalfOffsetDifference] = 0.5 * (model.joint_offsets[0] - model.joint_offsets[1]);
  x[kDiamondCameraDistance] = X_OC.translation().norm();
  return x;
}

Eigen::Isometry3d DiamondCameraPoseFromParameters(const X& x,
                                                  const Eigen::Isometry3d& X_OC_initial) {
  const ParameterFrame frame(x, X_OC_initial);
  const Eigen::Vector3d e1(frame.e1[0], frame.e1[1], frame.e1[2]);
  const Eigen::Vector3d e2(frame.e2[0], frame.e2[1], frame.e2[2]);
  const Eigen::Vector3d c_hat(frame.c0_hat[0], frame.c0_hat[1], frame.c0_hat[2]);
  const Eigen::Matrix3d G =
      Exp(x[kDiamondCameraDirection1] * e1 + x[kDiamondCameraDirection2] * e2);
  const Eigen::Vector3d w(x[kDiamondCameraRotationX], x[kDiamondCameraRotationY],
                          x[kDiamondCameraRotationZ]);
  Eigen::Isometry3d X_OC = Eigen::Isometry3d::Identity();
  X_OC.linear() = G * X_OC_initial.linear() * Exp(w);
  X_OC.translation() = x[kDiamondCameraDistance] * (G * c_hat);
  return X_OC;
}

namespace {

EstimationStatus ContractStatus(const DiamondIdentificationSummary& s) {
  switch (s.status) {
    case DiamondIdentificationStatus::kConverged:
      return s.identifiability.rank == s.identifiability.parameters
                 ? EstimationStatus::kConverged
                 : EstimationStatus::kUnidentified;
    case DiamondIdentificationStatus::kNoConvergence:
      return EstimationStatus::kNotConverged;
    case DiamondIdentificationStatus::kTooFewSamples:
      return EstimationStatus::kInsufficientData;
    case DiamondIdentificationStatus::kNothingToEstimate:
    case DiamondIdentificationStatus::kSolverFailed:
      break;
  }
  return EstimationStatus::kFailed;
}

void AddAxes(const ResidualStatistics& r, const char* name_x, const char* name_y, const char* unit,
             std::vector<ResidualSummary>* out) {
  for (int axis = 0; axis < 2; ++axis) {
    ResidualSummary s;
    s.name = axis == 0 ? name_x : name_y;
    s.unit = unit;
    s.count = r.count;
    s.mean = r.mean[axis];
    s.rms = r.rms[axis];
    s.max_abs = r.sup[axis];
    out->push_back(s);
  }
}

}  // namespace

EstimationReport DiamondEstimationReport(const DiamondIdentificationSummary& s) {
  EstimationReport e;
  e.estimator = "DIAMOND kinematics and camera pose (seed 001)";
  e.status = ContractStatus(s);
  e.message = s.solver_message;
  if (s.status == DiamondIdentificationStatus::kNothingToEstimate ||
      s.status == DiamondIdentificationStatus::kTooFewSamples) {
    e.message = ToString(s.status);
  }
  e.iterations = s.iterations;
  e.initial_cost = s.initial_cost;
  e.final_cost = s.final_cost;
  e.variance_factor = s.variance_factor;
  if (s.pixel_residuals.count > 0)
    AddAxes(s.pixel_residuals, "pixel u", "pixel v", "px", &e.residuals);
  if (s.task_residuals.count > 0)
    AddAxes(s.task_residuals, "task phi", "task gamma", "rad", &e.residuals);
  for (int j = 0; j < kDiamondParameterCount; ++j) {
    const DiamondParameterEstimate& p = s.parameters[j];
    e.parameters.push_back({DiamondParameterName(j), DiamondParameterUnit(j), p.initial, p.value,
                            p.sigma, p.estimated, p.identified});
  }
  if (s.covariance.rows() == kDiamondParameterCount) e.covariance = s.covariance;
  e.identifiability = s.identifiability;
  e.warnings = s.warnings;
  return e;
}

namespace {

DiamondIdentificationSummary Identify(const std::vector<DiamondSample>& samples,
                                      const vision::CameraModel& camera,
                                      const robots::DiamondModel& initial_model,
                                      const Eigen::Isometry3d& X_OC_initial,
                                      const DiamondIdentificationOptions& options) {
  // --- set-up checks: throw once, naming everything -----------------------------------------
  std::vector<std::string> bad;
  if (const std::string o = options.Validate(); !o.empty()) bad.push_back("options: " + o);
  if (const std::string m = initial_model.Validate(); !m.empty()) {
    bad.push_back("initial_model: " + m);
  }
  {
    const Eigen::Matrix3d R = X_OC_initial.linear();
    if (!R.allFinite() || !X_OC_initial.translation().allFinite()) {
      bad.push_back("X_OC_initial is not finite");
    } else {
      const double orth = (R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
      if (orth > 1e-9 || R.determinant() < 0) {
        bad.push_back("X_OC_initial's linear part is not a rotation (|R^T R - I| = " + Fmt(orth) +
                      ", det = " + Fmt(R.determinant()) + ")");
      }
      if (!(X_OC_initial.translation().norm() > 1e-6)) {
        bad.push_back("X_OC_initial: the camera centre is at the RCM (|c| = " +
                      Fmt(X_OC_initial.translation().norm()) + " m)");
      }
    }
  }
  for (size_t k = 0; k < samples.size(); ++k) {
    if (!samples[k].q.allFinite() || !samples[k].pixel.allFinite()) {
      bad.push_back("sample " + std::to_string(k) + ": q = (" + Fmt(samples[k].q.x()) + ", " +
                    Fmt(samples[k].q.y()) + ") rad, pixel = (" + Fmt(samples[k].pixel.x()) + ", " +
                    Fmt(samples[k].pixel.y()) + ") px: not finite");
      if (bad.size() > 12) break;
    }
  }
  if (!bad.empty()) {
    std::string message = "IdentifyDiamond: ";
    for (size_t i = 0; i < bad.size(); ++i) message += (i ? "; " : "") + bad[i];
    throw std::invalid_argument(message);
  }

  DiamondIdentificationSummary summary;
  summary.residual = options.residual;
  summary.scaling = options.scaling;
  summary.pixel_sigma = options.pixel_sigma;
  summary.samples = static_cast<int>(samples.size());
  summary.model = initial_model;
  summary.X_OC = X_OC_initial;
  summary.covariance = Eigen::MatrixXd::Zero(kDiamondParameterCount, kDiamondParameterCount);

  const X x0 = DiamondInitialParameters(initial_model, X_OC_initial);
  const std::vector<int> free = FreeParameters(options);
  for (int j = 0; j < kDiamondParameterCount; ++j) {
    summary.parameters[j].initial = summary.parameters[j].value = x0[j];
  }
  for (int j : free) summary.parameters[j].estimated = true;

  // Gauges fixed by the options.
  IdentifiabilityReport& report = summary.identifiability;
  if (!options.estimate_camera_distance &&
      (options.estimate_radius || options.estimate_camera_direction)) {
    report.gauges.push_back("camera_distance fixed at " + Fmt(x0[kDiamondCameraDistance]) +
                            " m (scale gauge: R is identified relative to it)");
  }
  if (!options.estimate_mean_offset &&
      (options.estimate_camera_rotation || options.estimate_camera_direction)) {
    report.gauges.push_back("mean_offset fixed at " + Fmt(x0[kDiamondMeanOffset]) +
                            " rad (azimuth gauge: it and the camera's azimuth about z_O are one "
                            "unknown)");
  }

  if (free.empty()) {
    summary.status = DiamondIdentificationStatus::kNothingToEstimate;
    summary.warnings.push_back("no parameter is estimated (every estimate_* option is false)");
    return summary;
  }

  // --- residuals ------------------------------------------------------------------------------
  auto frame = std::make_unique<ParameterFrame>(x0, X_OC_initial);
  std::vector<double> z(kDiamondParameterCount, 0.0);
  std::vector<ceres::CostFunction*> costs;
  std::vector<int> used;
  // kSpherical: the whitening of each used sample (stable addresses: reserved up front).
  std::vector<Eigen::Matrix2d> weights;
  weights.reserve(samples.size());
  const double* z_ptr[1] = {z.data()};
  vision::SphericalPositioningOptions sphere_options;
  sphere_options.min_incidence_cosine = options.min_incidence_cosine;
  // A sample's residual at the current z; kSpherical weights from the fix at (X_OC, R). Null
  // with the reason when it has no prediction there.
  const auto make_cost = [&](size_t k, const Eigen::Isometry3d& X_OC, double R,
                             std::string* reason) -> std::unique_ptr<ceres::CostFunction> {
    std::unique_ptr<ceres::CostFunction> cost;
    if (options.residual == DiamondResidual::kPixel) {
      cost.reset(internal::DiamondPixelCost::Create(frame.get(), &camera, samples[k],
                                                    options.pixel_sigma));
    } else {
      const vision::SphereFix fix =
          vision::LocateOnSphere(camera, X_OC, R, samples[k].pixel, sphere_options);
      vision::Ray ray;
      Eigen::Matrix2d W;
      if (fix.status != vision::SphereFixStatus::kOk) {
        *reason = std::string("its ray does not give a sphere fix (") +
                  vision::ToString(fix.status) + ")";
      } else if (camera.BackProject(samples[k].pixel, &ray) != vision::ProjectionStatus::kOk) {
        *reason = "its pixel does not back-project";
      } else if (!Whitening(fix, options.pixel_sigma, &W)) {
        *reason = "its (phi, gamma) covariance is singular";
      } else {
        weights.push_back(W);
        cost.reset(internal::DiamondSphericalResidual::Create(
            frame.get(), samples[k].q, ray, &weights.back(), options.min_incidence_cosine));
      }
    }
    if (cost) {
      double r[2];
      if (!cost->Evaluate(z_ptr, r, nullptr)) {
        *reason =
            "no prediction (the limbs cannot close, the predicted marker does not "
            "project, or its ray misses the sphere)";
        cost.reset();
      }
    }
    if (!cost && options.residual == DiamondResidual::kSpherical && weights.size() > costs.size()) {
      weights.pop_back();
    }
    return cost;
  };
  std::vector<std::pair<int, std::string>> rejected;
  for (size_t k = 0; k < samples.size(); ++k) {
    std::string reason;
    std::unique_ptr<ceres::CostFunction> cost =
        make_cost(k, X_OC_initial, initial_model.radius, &reason);
    if (!cost) {
      rejected.emplace_back(static_cast<int>(k), reason + " at the initial parameters");
      continue;
    }
    costs.push_back(cost.release());
    used.push_back(static_cast<int>(k));
  }
  const auto report_rejected = [&] {
    summary.rejected_samples.clear();
    summary.rejected_reasons.clear();
    for (const auto& [k, reason] : rejected) {
      summary.rejected_samples.push_back(k);
      summary.rejected_reasons.push_back("sample " + std::to_string(k) + ": " + reason);
    }
  };
  report_rejected();
  summary.samples_used = static_cast<int>(costs.size());
  const auto delete_costs = [&costs] {
    for (ceres::CostFunction* c : costs) delete c;
    costs.clear();
  };
  const int n_free = static_cast<int>(free.size());
  if (summary.samples_used < options.min_samples || 2 * summary.samples_used < n_free) {
    summary.status = DiamondIdentificationStatus::kTooFewSamples;
    summary.warnings.push_back("only " + std::to_string(summary.samples_used) +
                               " usable samples (need " + std::to_string(options.min_samples) +
                               " and at least " + std::to_string((n_free + 1) / 2) + " for " +
                               std::to_string(n_free) + " free parameters)");
    delete_costs();
    return summary;
  }

  // --- column scaling (seed: "extremal scaling") at the start ----------------------------------
  Eigen::MatrixXd J;
  Eigen::VectorXd r;
  if (!EvaluateAll(costs, z.data(), &J, &r)) {  // cannot happen: each was evaluated above
    summary.status = DiamondIdentificationStatus::kSolverFailed;
    delete_costs();
    return summary;
  }
  summary.initial_cost = 0.5 * r.squaredNorm();
  for (int j : free) {
    const double extremal = J.col(j).cwiseAbs().maxCoeff();
    const double norm = J.col(j).norm();
    double s = 1.0;
    if (options.scaling == ColumnScaling::kExtremal && extremal > 0) s = 1.0 / extremal;
    if (options.scaling == ColumnScaling::kColumnNorm && norm > 0) s = 1.0 / norm;
    if (!(extremal > 0)) {
      summary.warnings.push_back(std::string(DiamondParameterName(j)) +
                                 " has no effect on any residual at the initial parameters");
    }
    frame->scale[j] = s;
  }
  for (int j = 0; j < kDiamondParameterCount; ++j) summary.column_scale[j] = frame->scale[j];

  // --- Levenberg–Marquardt ---------------------------------------------------------------------
  ceres::Problem::Options problem_options;
  problem_options.cost_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(problem_options);
  for (ceres::CostFunction* c : costs) problem.AddResidualBlock(c, nullptr, z.data());
  std::vector<int> fixed;
  for (int j = 0; j < kDiamondParameterCount; ++j) {
    if (!summary.parameters[j].estimated) fixed.push_back(j);
  }
  if (!fixed.empty()) {
    problem.SetManifold(z.data(), new ceres::SubsetManifold(kDiamondParameterCount, fixed));
  }
  ceres::Solver::Options so;
  so.minimizer_type = ceres::TRUST_REGION;
  so.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
  so.linear_solver_type = ceres::DENSE_QR;
  // Marquardt's μ₀ = 0.001 (seed §II) is a trust region of 1/μ₀ in Ceres's terms.
  so.initial_trust_region_radius = 1e3;
  so.jacobi_scaling = options.scaling == ColumnScaling::kNone;
  so.max_num_iterations = options.max_iterations;
  so.function_tolerance = options.function_tolerance;
  so.parameter_tolerance = options.parameter_tolerance;
  so.gradient_tolerance = options.gradient_tolerance;
  so.num_threads = 1;
  so.logging_type = ceres::SILENT;
  ceres::Solver::Summary ceres_summary;
  ceres::Solve(so, &problem, &ceres_summary);
  summary.iterations = static_cast<int>(ceres_summary.iterations.size()) - 1;
  // kSpherical: the weights depend on the pose and R through ∂(φ,γ)/∂pixel; recompute them at
  // the solution and solve again until they settle (a few passes: they change to first order in
  // the parameter change only).
  for (int pass = 0; options.residual == DiamondResidual::kSpherical && pass < 4 &&
                     ceres_summary.termination_type == ceres::CONVERGENCE;
       ++pass) {
    X xs{};
    for (int j = 0; j < kDiamondParameterCount; ++j) xs[j] = frame->X(z.data(), j);
    const Eigen::Isometry3d X_OC = DiamondCameraPoseFromParameters(xs, X_OC_initial);
    double change = 0.0;
    for (size_t i = 0; i < used.size(); ++i) {
      const vision::SphereFix fix = vision::LocateOnSphere(camera, X_OC, xs[kDiamondRadius],
                                                           samples[used[i]].pixel, sphere_options);
      Eigen::Matrix2d W;
      if (fix.status != vision::SphereFixStatus::kOk || !Whitening(fix, options.pixel_sigma, &W)) {
        continue;  // keep the old weight; the residual itself reports a miss
      }
      change = std::max(change, (W - weights[i]).norm() / weights[i].norm());
      weights[i] = W;
    }
    // Samples whose ray missed the initial (too small or misplaced) sphere may meet this one.
    size_t admitted = 0;
    for (auto it = rejected.begin(); it != rejected.end();) {
      std::string reason;
      std::unique_ptr<ceres::CostFunction> cost =
          make_cost(it->first, X_OC, xs[kDiamondRadius], &reason);
      if (!cost) {
        ++it;
        continue;
      }
      problem.AddResidualBlock(cost.get(), nullptr, z.data());
      costs.push_back(cost.release());
      used.push_back(it->first);
      it = rejected.erase(it);
      ++admitted;
    }
    if (change < 1e-3 && admitted == 0) break;
    ceres::Solve(so, &problem, &ceres_summary);
    summary.iterations += static_cast<int>(ceres_summary.iterations.size()) - 1;
  }
  summary.solver_message = ceres_summary.message;
  summary.final_cost = ceres_summary.final_cost;
  summary.samples_used = static_cast<int>(costs.size());
  report_rejected();
  if (!rejected.empty()) {
    summary.warnings.push_back(std::to_string(rejected.size()) + " of " +
                               std::to_string(samples.size()) +
                               " samples rejected (rejected_reasons)");
  }
  if (ceres_summary.termination_type == ceres::CONVERGENCE) {
    summary.status = DiamondIdentificationStatus::kConverged;
  } else if (ceres_summary.termination_type == ceres::NO_CONVERGENCE) {
    summary.status = DiamondIdentificationStatus::kNoConvergence;
    summary.warnings.push_back("no convergence in " + std::to_string(options.max_iterations) +
                               " iterations: " + ceres_summary.message);
  } else {
    summary.status = DiamondIdentificationStatus::kSolverFailed;
    summary.warnings.push_back("solver failed: " + ceres_summary.message);
  }

  X x{};
  for (int j = 0; j < kDiamondParameterCount; ++j) {
    x[j] = frame->X(z.data(), j);
    summary.parameters[j].value = x[j];
  }
  summary.model.radius = x[kDiamondRadius];
  summary.model.alpha = x[kDiamondAlpha];
  summary.model.beta = x[kDiamondBeta];
  summary.model.joint_offsets = {x[kDiamondMeanOffset] + x[kDiamondHalfOffsetDifference],
                                 x[kDiamondMeanOffset] - x[kDiamondHalfOffsetDifference]};
  summary.X_OC = DiamondCameraPoseFromParameters(x, X_OC_initial);

  // --- residual statistics, Jacobian at the solution --------------------------------------------
  if (!EvaluateAll(costs, z.data(), &J, &r)) {
    summary.status = DiamondIdentificationStatus::kSolverFailed;
    summary.warnings.push_back("a sample has no prediction at the solution");
    delete_costs();
    return summary;
  }
  std::vector<Eigen::Vector2d> pixel_residuals;
  std::vector<Eigen::Vector2d> task_residuals;
  for (size_t i = 0; i < used.size(); ++i) {
    const DiamondSample& s = samples[used[i]];
    robots::DiamondData data;
    robots::ForwardKinematics(summary.model, s.q, &data);
    if (!data.valid) continue;
    Eigen::Vector2d predicted;
    if (camera.Project(summary.X_OC.inverse() * data.p_O_T, &predicted) ==
        vision::ProjectionStatus::kOk) {
      pixel_residuals.push_back(s.pixel - predicted);
    }
    const vision::SphereFix fix =
        vision::LocateOnSphere(camera, summary.X_OC, summary.model.radius, s.pixel, sphere_options);
    if (fix.ok()) {
      Eigen::Vector2d e = fix.task - data.task;
      e.x() -= 2 * M_PI * std::round(e.x() / (2 * M_PI));
      task_residuals.push_back(e);
    }
  }
  summary.pixel_residuals = Statistics(pixel_residuals);
  summary.task_residuals = Statistics(task_residuals);
  summary.per_sample_pixel_residuals = std::move(pixel_residuals);
  delete_costs();

  // --- identifiability and covariance ------------------------------------------------------------
  // J is ∂r/∂z; ∂r/∂x_j = J_j / s_j. The report scales ∂r/∂x again at the solution.
  Eigen::MatrixXd Jx(J.rows(), n_free);
  for (int c = 0; c < n_free; ++c) Jx.col(c) = J.col(free[c]) / frame->scale[free[c]];
  std::vector<std::string> names;
  for (int c = 0; c < n_free; ++c) names.push_back(DiamondParameterName(free[c]));
  IdentifiabilityOptions analysis;
  analysis.scaling = IdentifiabilityOptions::Scaling::kMaxAbs;
  analysis.rank_tolerance = options.rank_tolerance;
  analysis.null_tolerance = 1e-3;  // |null component| of an identified parameter
  analysis.warn_correlation = options.warn_correlation;
  {
    std::vector<std::string> gauges = std::move(report.gauges);
    report = AnalyzeIdentifiability(Jx, names, analysis);
    report.gauges = std::move(gauges);
  }
  const int dof = static_cast<int>(J.rows()) - report.rank;
  summary.variance_factor = dof > 0 ? 2.0 * summary.final_cost / dof : 0.0;
  const Eigen::MatrixXd cov_free = summary.variance_factor * report.normal_inverse;
  for (int a = 0; a < n_free; ++a) {
    for (int b = 0; b < n_free; ++b) summary.covariance(free[a], free[b]) = cov_free(a, b);
  }
  for (int c = 0; c < n_free; ++c) {
    DiamondParameterEstimate& p = summary.parameters[free[c]];
    p.identified = report.identified[static_cast<size_t>(c)];
    p.sigma = p.identified ? std::sqrt(std::max(0.0, cov_free(c, c)))
                           : std::numeric_limits<double>::infinity();
  }
  {
    const Eigen::MatrixXd& C = summary.covariance;
    const int m = kDiamondMeanOffset, h = kDiamondHalfOffsetDifference;
    const bool m_ok = !summary.parameters[m].estimated || summary.parameters[m].identified;
    const bool h_ok = !summary.parameters[h].estimated || summary.parameters[h].identified;
    for (int i = 0; i < robots::kDiamondJoints; ++i) {
      const double sign = i == 0 ? 1.0 : -1.0;
      const double var = C(m, m) + C(h, h) + 2 * sign * C(m, h);
      summary.offset_sigma[i] =
          m_ok && h_ok ? std::sqrt(std::max(0.0, var)) : std::numeric_limits<double>::infinity();
    }
  }
  // --- warnings
  // ------------------------------------------------------------------------------------
  if (report.rank < n_free) {
    std::string text = "rank-deficient identification Jacobian (rank " +
                       std::to_string(report.rank) + " of " + std::to_string(n_free) +
                       "): not identified:";
    for (const std::string& u : report.unidentified) text += " [" + u + "]";
    summary.warnings.push_back(text +
                               "; fix a gauge (estimate_camera_distance / "
                               "estimate_mean_offset) or add excitation");
  } else if (report.condition_number > options.warn_condition_number) {
    summary.warnings.push_back(
        "ill-conditioned identification (condition number " + Fmt(report.condition_number) + " > " +
        Fmt(options.warn_condition_number) + "): spread the samples over more of the workspace");
  }
  if (!report.strong_correlations.empty()) {
    std::string text = "strongly correlated estimates:";
    for (const std::string& c : report.strong_correlations) text += " " + c + ";";
    text.pop_back();
    summary.warnings.push_back(text);
  }
  if (options.residual == DiamondResidual::kPixel && summary.variance_factor > 0) {
    const double seen = options.pixel_sigma * std::sqrt(summary.variance_factor);
    if (summary.variance_factor > 4.0 || summary.variance_factor < 0.25) {
      summary.warnings.push_back("the residuals say the marker noise is " + Fmt(seen) +
                                 " px, not pixel_sigma = " + Fmt(options.pixel_sigma) +
                                 " px (model error or outliers if larger)");
    }
  }
  return summary;
}

}  // namespace

DiamondIdentificationSummary IdentifyDiamond(const std::vector<DiamondSample>& samples,
                                             const vision::CameraModel& camera,
                                             const robots::DiamondModel& initial_model,
                                             const Eigen::Isometry3d& X_OC_initial,
                                             const DiamondIdentificationOptions& options) {
  DiamondIdentificationSummary summary =
      Identify(samples, camera, initial_model, X_OC_initial, options);
  summary.estimation = DiamondEstimationReport(summary);
  return summary;
}

std::vector<Eigen::Vector2d> DiamondVisibleTaskGrid(const robots::DiamondModel& model,
                                                    const vision::CameraModel& camera,
                                                    const Eigen::Isometry3d& X_OC, int n_phi,
                                                    int n_gamma, double inset, double margin_px) {
  if (n_phi < 2 || n_gamma < 2 || !(inset >= 0) || !(margin_px >= 0)) {
    throw std::invalid_argument("DiamondVisibleTaskGrid: n_phi = " + std::to_string(n_phi) +
                                ", n_gamma = " + std::to_string(n_gamma) +
                                " (need >= 2), inset = " + Fmt(inset) +
                                " rad, margin_px = " + Fmt(margin_px) + " (need >= 0)");
  }
  std::vector<Eigen::Vector2d> tasks;
  const Eigen::Isometry3d X_CO = X_OC.inverse();
  const Eigen::Vector3d c = X_OC.translation();
  for (int i = 0; i < n_phi; ++i) {
    const double phi =
        model.phi_min + inset + (model.phi_max - model.phi_min - 2 * inset) * i / (n_phi - 1);
    for (int k = 0; k < n_gamma; ++k) {
      const double gamma = model.gamma_min + inset +
                           (model.gamma_max - model.gamma_min - 2 * inset) * k / (n_gamma - 1);
      const Eigen::Vector2d task(phi, gamma);
      if (!robots::CheckWorkspace(model, task).ok()) continue;
      const Eigen::Vector3d p = robots::DiamondToolPoint(model.radius, phi, gamma);
      if ((c - p).dot(p) <= 0) continue;
      Eigen::Vector2d px;
      if (camera.Project(X_CO * p, &px) != vision::ProjectionStatus::kOk) continue;
      if (px.x() < margin_px - 0.5 || px.y() < margin_px - 0.5 ||
          px.x() > camera.width() - 0.5 - margin_px || px.y() > camera.height() - 0.5 - margin_px) {
        continue;
      }
      tasks.push_back(task);
    }
  }
  return tasks;
}

std::vector<DiamondSample> SimulateDiamondSamples(const robots::DiamondModel& nominal,
                                                  const robots::DiamondModel& truth,
                                                  const vision::CameraModel& camera,
                                                  const Eigen::Isometry3d& X_OC,
                                                  const std::vector<Eigen::Vector2d>& tasks,
                                                  const DiamondSimulationOptions& options) {
  if (const std::string bad = options.Validate(); !bad.empty()) {
    throw std::invalid_argument("SimulateDiamondSamples: " + bad);
  }
  std::mt19937_64 rng(options.seed);
  std::normal_distribution<double> unit(0.0, 1.0);
  const Eigen::Isometry3d X_CO = X_OC.inverse();
  std::vector<DiamondSample> samples;
  for (const Eigen::Vector2d& task : tasks) {
    Eigen::Vector2d q;
    if (!robots::InverseKinematics(nominal, task, &q).ok()) continue;
    robots::DiamondData data;
    robots::ForwardKinematics(truth, q, &data);
    if (!data.valid) continue;
    Eigen::Vector2d px;
    if (camera.Project(X_CO * data.p_O_T, &px) != vision::ProjectionStatus::kOk) continue;
    if ((X_OC.translation() - data.p_O_T).dot(data.p_O_T) <= 0) continue;  // marker faces away
    DiamondSample s;
    s.pixel = px + options.pixel_noise_sigma * Eigen::Vector2d(unit(rng), unit(rng));
    s.q = q + options.joint_noise_sigma * Eigen::Vector2d(unit(rng), unit(rng));
    if (!camera.InImage(s.pixel)) continue;
    samples.push_back(s);
  }
  return samples;
}

}  // namespace kinevis::calibration
