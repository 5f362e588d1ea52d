#include "calibration/laser_scanner/laser_scanner_calibration.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <sstream>
#include <stdexcept>

#include "calibration/laser_scanner/laser_scanner_calibration_internal.h"
#include "common/config_error.h"

namespace kinevis::calibration {
namespace {

using vision::CameraModel;
using vision::ProjectionStatus;
using vision::Ray;

std::string Format(double value, int precision = 4) {
  std::ostringstream out;
  out.precision(precision);
  out << value;
  return out.str();
}

// A stripe point met with the board, in C.
struct StripePoint {
  Eigen::Vector3d p;
  int image = 0;
};

// Condition number of A with its columns scaled to unit norm (invariant to the columns' units).
double EquilibratedCondition(Eigen::MatrixXd A) {
  for (int c = 0; c < A.cols(); ++c) {
    const double n = A.col(c).norm();
    if (n > 0.0) A.col(c) /= n;
  }
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd(A);
  const Eigen::VectorXd s = svd.singularValues();
  return s(s.size() - 1) > 0.0 ? s(0) / s(s.size() - 1) : std::numeric_limits<double>::infinity();
}

// The linear fit of one laser plane u + c z = b' over points (u = y for the rotating laser, x for
// the fixed one): rows [z, −1] (c, b') = −u (seed eq. 28/29 before its multiplication by the
// board plane's C and B, see README), with MAD-based outlier rejection.
struct PlaneFit {
  bool ok = false;
  double c = std::nan(""), b = std::nan("");
  Eigen::Matrix2d covariance = Eigen::Matrix2d::Zero();  // (c, b')
  double condition = std::numeric_limits<double>::infinity();
  double rms = std::nan(""), max = std::nan("");  // distance from the plane (m)
  double mean = std::nan("");                     // signed distance (m)
  std::vector<char> inlier;
  Eigen::MatrixXd jacobian;  // of the algebraic residuals of the inliers in (c, b')
  double sigma2 = 0.0;       // their variance
  int inliers = 0;
};

PlaneFit FitPlane(const std::vector<StripePoint>& points, int axis,
                  const LaserScannerCalibrationOptions& options) {
  PlaneFit fit;
  const int n = static_cast<int>(points.size());
  fit.inlier.assign(n, 1);
  std::vector<double> residual(n);
  Eigen::MatrixXd A;
  // Solves with the current inliers; fills the distances of every point from the plane.
  auto solve = [&]() {
    fit.inliers = static_cast<int>(std::count(fit.inlier.begin(), fit.inlier.end(), 1));
    if (fit.inliers < 2) return false;
    A.resize(fit.inliers, 2);
    Eigen::VectorXd rhs(fit.inliers);
    for (int i = 0, row = 0; i < n; ++i) {
      if (!fit.inlier[i]) continue;
      A(row, 0) = points[i].p.z();
      A(row, 1) = -1.0;
      rhs(row) = -points[i].p(axis);
      ++row;
    }
    fit.condition = EquilibratedCondition(A);
    if (!(fit.condition <= options.max_depth_condition)) return false;
    const Eigen::Vector2d x = A.jacobiSvd(Eigen::ComputeThinU | Eigen::ComputeThinV).solve(rhs);
    fit.c = x(0);
    fit.b = x(1);
    const double scale = std::sqrt(1.0 + fit.c * fit.c);
    for (int i = 0; i < n; ++i) {
      residual[i] = (points[i].p(axis) + fit.c * points[i].p.z() - fit.b) / scale;
    }
    return true;
  };
  if (!solve()) return fit;
  for (int round = 0; round < 5 && options.outlier_threshold > 0.0; ++round) {
    std::vector<double> magnitude;
    for (int i = 0; i < n; ++i) {
      if (fit.inlier[i]) magnitude.push_back(std::abs(residual[i]));
    }
    std::nth_element(magnitude.begin(), magnitude.begin() + magnitude.size() / 2, magnitude.end());
    const double robust =
        std::max(1.4826 * magnitude[magnitude.size() / 2], options.min_robust_sigma);
    int changed = 0;
    for (int i = 0; i < n; ++i) {
      const char keep = std::abs(residual[i]) <= options.outlier_threshold * robust;
      changed += keep != fit.inlier[i];
      fit.inlier[i] = keep;
    }
    if (changed == 0) break;
    if (!solve()) return fit;
  }
  double ssr = 0.0, sum = 0.0;
  fit.max = 0.0;
  for (int i = 0; i < n; ++i) {
    if (!fit.inlier[i]) continue;
    sum += residual[i];
    ssr += residual[i] * residual[i];
    fit.max = std::max(fit.max, std::abs(residual[i]));
  }
  fit.rms = std::sqrt(ssr / fit.inliers);
  fit.mean = sum / fit.inliers;
  // σ² of the algebraic residual (distance · |(1, c)|) times (AᵀA)⁻¹.
  const double scale2 = 1.0 + fit.c * fit.c;
  const double sigma2 = fit.inliers > 2 ? ssr * scale2 / (fit.inliers - 2) : 0.0;
  fit.covariance = sigma2 * (A.transpose() * A).inverse();
  fit.jacobian = A;
  fit.sigma2 = sigma2;
  fit.ok = true;
  return fit;
}

// The estimator contract's report. The parameters are the two lasers' (b_y, d_y, b_x', cot θ_x)
// and each stepper position's cot θ_y; one AnalyzeIdentifiability over the block-diagonal
// Jacobian of both solves (a plane that was not calibrated contributes zero columns).
EstimationReport LaserScannerEstimation(const LaserScannerCalibration& out,
                                        const LaserScannerCalibrationOptions& options,
                                        const Eigen::MatrixXd& rotating_jacobian,
                                        const std::vector<std::string>& rotating_names,
                                        double rotating_mean, const PlaneFit& fixed) {
  EstimationReport e;
  e.estimator = "laser scanner planes (seed 004)";
  const bool rotating = out.rotating_calibrated && rotating_jacobian.size() > 0;
  const bool fixed_ok = out.fixed_calibrated && fixed.sigma2 > 0.0;
  std::vector<std::string> names =
      rotating ? rotating_names : std::vector<std::string>{"b_y", "d_y"};
  const Eigen::Index n_rot = static_cast<Eigen::Index>(names.size());
  names.push_back("b_x_prime");
  names.push_back("cot_theta_x");
  const Eigen::Index n = static_cast<Eigen::Index>(names.size());
  const Eigen::Index rows_rot = rotating ? rotating_jacobian.rows() : 0;
  const Eigen::Index rows_fix = fixed_ok ? fixed.jacobian.rows() : 0;
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(std::max<Eigen::Index>(1, rows_rot + rows_fix), n);
  if (rotating) J.topLeftCorner(rows_rot, n_rot) = rotating_jacobian;
  if (fixed_ok) {
    // The fit's columns are (c, b'); the contract's order is (b', c).
    const double w = 1.0 / std::sqrt(fixed.sigma2);
    J.block(rows_rot, n_rot, rows_fix, 1) = w * fixed.jacobian.col(1);
    J.block(rows_rot, n_rot + 1, rows_fix, 1) = w * fixed.jacobian.col(0);
  }
  IdentifiabilityOptions analysis;
  e.identifiability = AnalyzeIdentifiability(J, names, analysis);
  const Identifiability& id = e.identifiability;

  std::vector<double> values(static_cast<size_t>(n), std::nan(""));
  values[0] = out.geometry.rotating_b_y;
  values[1] = out.geometry.rotating_d_y;
  if (rotating) {
    Eigen::Index k = 2;
    for (const RotatingPositionEstimate& p : out.positions) {
      if (p.estimated && k < n_rot) values[static_cast<size_t>(k++)] = p.cot_theta_y;
    }
  }
  values[static_cast<size_t>(n_rot)] = out.geometry.fixed_b_x_prime;
  values[static_cast<size_t>(n_rot + 1)] = out.geometry.fixed_cot_theta_x;
  e.covariance = Eigen::MatrixXd::Zero(n, n);
  bool all_identified = true;
  for (Eigen::Index i = 0; i < n; ++i) {
    ParameterEstimate p;
    p.name = names[static_cast<size_t>(i)];
    p.unit = p.name.rfind("cot", 0) == 0 ? "1" : "m";
    p.value = values[static_cast<size_t>(i)];
    p.estimated = true;
    p.identified = id.identified[static_cast<size_t>(i)];
    p.sigma = p.identified ? std::sqrt(std::max(0.0, id.normal_inverse(i, i)))
                           : std::numeric_limits<double>::infinity();
    all_identified = all_identified && p.identified;
    e.parameters.push_back(p);
  }
  for (Eigen::Index a = 0; a < n; ++a) {
    for (Eigen::Index b = 0; b < n; ++b) {
      e.covariance(a, b) =
          id.identified[static_cast<size_t>(a)] && id.identified[static_cast<size_t>(b)]
              ? id.normal_inverse(a, b)
              : (a == b ? std::numeric_limits<double>::infinity() : 0.0);
    }
  }
  e.iterations = out.iterations;
  const bool diverged = std::any_of(out.errors.begin(), out.errors.end(), [](const std::string& m) {
    return m.find("diverged") != std::string::npos;
  });
  if (diverged) {
    e.status = EstimationStatus::kFailed;
  } else if (!out.rotating_calibrated && !out.fixed_calibrated) {
    e.status = EstimationStatus::kInsufficientData;
  } else if (!all_identified || !out.errors.empty()) {
    e.status = EstimationStatus::kUnidentified;
  } else if (options.refine && !out.converged) {
    e.status = EstimationStatus::kNotConverged;
  } else {
    e.status = EstimationStatus::kConverged;
  }
  for (const std::string& m : out.errors) e.message += (e.message.empty() ? "" : "; ") + m;
  if (e.message.empty()) {
    e.message = options.refine ? (out.converged ? "joint refinement converged"
                                                : "joint refinement did not converge")
                               : "linear solution (no refinement)";
  }
  e.variance_factor = 1.0;  // each plane's σ is estimated from its own residuals
  if (out.rotating_points > 0) {
    e.residuals.push_back({"rotating plane distance", "m", out.rotating_points, rotating_mean,
                           out.rotating_residual_rms, out.rotating_residual_max});
  }
  if (out.fixed_points > 0) {
    e.residuals.push_back({"fixed plane distance", "m", out.fixed_points, fixed.mean,
                           out.fixed_residual_rms, out.fixed_residual_max});
  }
  e.warnings = out.warnings;
  return e;
}

}  // namespace

namespace internal {

void RotatingResiduals(const std::vector<Eigen::Vector3d>& points, const std::vector<int>& position,
                       double b_y, double d_y, const Eigen::VectorXd& c, Eigen::VectorXd* r,
                       Eigen::MatrixXd* J) {
  const int rows = static_cast<int>(points.size());
  r->resize(rows);
  J->setZero(rows, c.size() + 2);
  for (int i = 0; i < rows; ++i) {
    const Eigen::Vector3d& p = points[i];
    const int k = position[i];
    (*r)(i) = p.y() + c(k) * p.z() - b_y - d_y * c(k);
    (*J)(i, 0) = -1.0;
    (*J)(i, 1) = -c(k);
    (*J)(i, 2 + k) = p.z() - d_y;
  }
}

}  // namespace internal

std::string LaserScannerCalibrationOptions::Validate() const {
  common::Problems bad;
  if (min_points_per_position < 2) {
    bad.Add("min_points_per_position", min_points_per_position, "must be >= 2");
  }
  if (min_fixed_points < 2) bad.Add("min_fixed_points", min_fixed_points, "must be >= 2");
  if (!(warn_depth_condition >= 1.0 && warn_depth_condition <= max_depth_condition)) {
    bad.Add("warn_depth_condition", warn_depth_condition,
            "must be >= 1 and <= max_depth_condition");
  }
  if (!(max_depth_condition >= 1.0))
    bad.Add("max_depth_condition", max_depth_condition, "must be >= 1");
  if (!(warn_separation_condition >= 1.0 &&
        warn_separation_condition <= max_separation_condition)) {
    bad.Add("warn_separation_condition", warn_separation_condition,
            "must be >= 1 and <= max_separation_condition");
  }
  if (!(max_separation_condition >= 1.0)) {
    bad.Add("max_separation_condition", max_separation_condition, "must be >= 1");
  }
  if (!(std::isfinite(outlier_threshold) && outlier_threshold >= 0.0)) {
    bad.Add("outlier_threshold", outlier_threshold, "must be >= 0 (0 = off)");
  }
  if (!(std::isfinite(min_robust_sigma) && min_robust_sigma > 0.0)) {
    bad.Add("min_robust_sigma", min_robust_sigma, "must be > 0 m");
  }
  if (max_iterations < 1) bad.Add("max_iterations", max_iterations, "must be >= 1");
  if (!(step_tolerance >= 0.0)) bad.Add("step_tolerance", step_tolerance, "must be >= 0");
  return bad.Message();
}

bool IntersectBoard(const CameraModel& camera, const Eigen::Isometry3d& X_CS,
                    const Eigen::Vector2d& pixel, Eigen::Vector3d* p_C) {
  Ray ray;
  if (camera.BackProject(pixel, &ray) != ProjectionStatus::kOk) return false;
  // Eq. 14–16: n = R e_z, D = −n · T; eq. 24: the ray's point with n · p + D = 0.
  const Eigen::Vector3d n = X_CS.linear().col(2);
  const double D = -n.dot(X_CS.translation());
  const double denominator = n.dot(ray.d_C);
  if (std::abs(denominator) < 1e-9) return false;
  const double t = -(D + n.dot(ray.p_C_O)) / denominator;
  if (!(t > 0.0)) return false;
  *p_C = ray.p_C_O + t * ray.d_C;
  return true;
}

LaserScannerCalibration CalibrateLaserScanner(const std::vector<LaserCalibrationImage>& images,
                                              const CameraModel& camera,
                                              const LaserScannerCalibrationOptions& options) {
  common::Problems bad;
  const std::string option_problems = options.Validate();
  if (!option_problems.empty()) bad.Add(option_problems);
  if (images.empty()) bad.Add("no images");
  if (!camera.IsCentral()) bad.Add("camera " + std::string(camera.Name()) + " is not central");
  for (size_t i = 0; i < images.size(); ++i) {
    const LaserCalibrationImage& image = images[i];
    const std::string where =
        "images[" + std::to_string(i) + "]" + (image.name.empty() ? "" : " (" + image.name + ")");
    const Eigen::Matrix3d R = image.X_CS.linear();
    if (!image.X_CS.matrix().allFinite() ||
        !((R.transpose() * R - Eigen::Matrix3d::Identity()).norm() < 1e-6 &&
          R.determinant() > 0.0)) {
      bad.Add(where + ".X_CS is not a finite rigid transform");
    }
    for (const auto* list : {&image.rotating_pixels, &image.fixed_pixels}) {
      for (size_t k = 0; k < list->size(); ++k) {
        if (!(*list)[k].allFinite()) {
          bad.Add(where +
                  (list == &image.rotating_pixels ? ".rotating_pixels[" : ".fixed_pixels[") +
                  std::to_string(k) + "] is not finite");
          break;
        }
      }
    }
  }
  if (!bad.Message().empty())
    throw std::invalid_argument("CalibrateLaserScanner: " + bad.Message());

  LaserScannerCalibration out;
  out.images = static_cast<int>(images.size());
  const double nan = std::numeric_limits<double>::quiet_NaN();
  out.geometry.rotating_b_y = out.geometry.rotating_d_y = nan;
  out.geometry.fixed_b_x_prime = out.geometry.fixed_cot_theta_x = nan;

  // Stripe points on the board (eq. 23–25).
  std::map<int, std::vector<StripePoint>> rotating;  // by step
  std::map<int, int> images_per_step;
  std::vector<StripePoint> fixed;
  for (size_t i = 0; i < images.size(); ++i) {
    const LaserCalibrationImage& image = images[i];
    for (const Eigen::Vector2d& pixel : image.rotating_pixels) {
      StripePoint s;
      s.image = static_cast<int>(i);
      if (IntersectBoard(camera, image.X_CS, pixel, &s.p)) {
        rotating[image.rotating_step].push_back(s);
      } else {
        ++out.unusable_pixels;
      }
    }
    if (!image.rotating_pixels.empty()) ++images_per_step[image.rotating_step];
    for (const Eigen::Vector2d& pixel : image.fixed_pixels) {
      StripePoint s;
      s.image = static_cast<int>(i);
      if (IntersectBoard(camera, image.X_CS, pixel, &s.p)) {
        fixed.push_back(s);
      } else {
        ++out.unusable_pixels;
      }
    }
  }
  if (out.unusable_pixels > 0) {
    out.warnings.push_back(std::to_string(out.unusable_pixels) +
                           " stripe pixels could not be met with the board (not back-projected, "
                           "or their ray misses the board plane)");
  }

  // Rotating laser, eq. 28 per position.
  std::vector<const std::vector<StripePoint>*> used_points;
  std::vector<std::vector<char>> used_inliers;
  for (const auto& [step, points] : rotating) {
    RotatingPositionEstimate position;
    position.step = step;
    position.images = images_per_step[step];
    const std::string name = "rotating laser, step " + std::to_string(step);
    if (static_cast<int>(points.size()) < options.min_points_per_position) {
      position.problem = std::to_string(points.size()) + " stripe points (need " +
                         std::to_string(options.min_points_per_position) + ")";
      out.warnings.push_back(name + ": not estimated: " + position.problem);
      out.positions.push_back(position);
      continue;
    }
    const PlaneFit fit = FitPlane(points, 1, options);
    position.depth_condition = fit.condition;
    if (!fit.ok) {
      position.problem = "its stripe points do not span depth (condition number " +
                         Format(fit.condition) + " > " + Format(options.max_depth_condition) +
                         "): add board poses at other distances or tilts";
      out.warnings.push_back(name + ": not estimated: " + position.problem);
      out.positions.push_back(position);
      continue;
    }
    if (fit.condition > options.warn_depth_condition) {
      out.warnings.push_back(name + ": its stripe points span little depth (condition number " +
                             Format(fit.condition) + "): cot θ_y and b_y' are weakly separated");
    }
    position.estimated = true;
    position.points = fit.inliers;
    position.outliers = static_cast<int>(points.size()) - fit.inliers;
    position.cot_theta_y_linear = position.cot_theta_y = fit.c;
    position.b_y_prime_linear = position.b_y_prime = fit.b;
    position.cot_theta_y_linear_sigma = position.cot_theta_y_sigma =
        std::sqrt(fit.covariance(0, 0));
    position.b_y_prime_linear_sigma = std::sqrt(fit.covariance(1, 1));
    position.residual_rms = fit.rms;
    out.rotating_outliers += position.outliers;
    out.positions.push_back(position);
    used_points.push_back(&points);
    used_inliers.push_back(fit.inlier);
  }
  std::vector<int> estimated;
  for (size_t k = 0; k < out.positions.size(); ++k) {
    if (out.positions[k].estimated) estimated.push_back(static_cast<int>(k));
  }
  const int N = static_cast<int>(estimated.size());
  // For the estimator contract: the Jacobians of both solves, each row divided by its residual σ
  // (so that the contract's (JᵀJ)⁻¹ is the covariance), the signed mean distances and names.
  Eigen::MatrixXd rotating_jacobian;
  std::vector<std::string> rotating_names;
  double rotating_mean = std::nan("");
  PlaneFit fixed_fit;

  // Eq. 31–32: b_y and d_y from the positions.
  if (rotating.empty()) {
    out.errors.push_back("rotating laser: no stripe points");
  } else if (N < 2) {
    out.errors.push_back("rotating laser: " + std::to_string(N) +
                         " estimated stepper position(s); b_y and d_y (eq. 31–32) need >= 2 "
                         "positions with different angles");
  } else {
    Eigen::MatrixXd A(N, 2);
    Eigen::VectorXd rhs(N);
    for (int k = 0; k < N; ++k) {
      A(k, 0) = 1.0;
      A(k, 1) = out.positions[estimated[k]].cot_theta_y_linear;
      rhs(k) = out.positions[estimated[k]].b_y_prime_linear;
    }
    out.separation_condition = EquilibratedCondition(A);
    if (!(out.separation_condition <= options.max_separation_condition)) {
      out.errors.push_back(
          "rotating laser: the stepper positions cannot separate b_y from d_y "
          "(eq. 32 condition number " +
          Format(out.separation_condition) + " > " + Format(options.max_separation_condition) +
          "): use positions with different cot θ_y");
    } else {
      if (out.separation_condition > options.warn_separation_condition) {
        out.warnings.push_back(
            "rotating laser: the stepper positions separate b_y from d_y "
            "poorly (eq. 32 condition number " +
            Format(out.separation_condition) + "): spread the positions over a wider angle");
      }
      const Eigen::Vector2d x = A.jacobiSvd(Eigen::ComputeThinU | Eigen::ComputeThinV).solve(rhs);
      double b_y = x(0), d_y = x(1);
      Eigen::VectorXd c(N);
      for (int k = 0; k < N; ++k) c(k) = out.positions[estimated[k]].cot_theta_y_linear;
      int rows = 0;
      for (int k = 0; k < N; ++k) {
        for (char keep : used_inliers[k]) rows += keep;
      }
      // Joint refinement over every inlier: unknowns (b_y, d_y, c_1..c_N).
      const int unknowns = N + 2;
      std::vector<Eigen::Vector3d> joint_points;
      std::vector<int> joint_position;
      for (int k = 0; k < N; ++k) {
        const std::vector<StripePoint>& points = *used_points[k];
        for (size_t i = 0; i < points.size(); ++i) {
          if (!used_inliers[k][i]) continue;
          joint_points.push_back(points[i].p);
          joint_position.push_back(k);
        }
      }
      Eigen::MatrixXd J;
      Eigen::VectorXd r;
      auto evaluate = [&](double by, double dy, const Eigen::VectorXd& cs) {
        internal::RotatingResiduals(joint_points, joint_position, by, dy, cs, &r, &J);
      };
      evaluate(b_y, d_y, c);
      if (options.refine) {
        double last_step = std::numeric_limits<double>::infinity();
        for (out.iterations = 0; out.iterations < options.max_iterations;) {
          const Eigen::VectorXd delta = J.colPivHouseholderQr().solve(-r);
          b_y += delta(0);
          d_y += delta(1);
          c += delta.tail(N);
          ++out.iterations;
          evaluate(b_y, d_y, c);
          last_step = delta.norm();
          if (last_step <= options.step_tolerance) {
            out.converged = true;
            break;
          }
        }
        if (!out.converged) {
          out.warnings.push_back("rotating laser: the joint refinement did not converge in " +
                                 std::to_string(out.iterations) + " iteration(s) (last step " +
                                 Format(last_step) + " > step_tolerance " +
                                 Format(options.step_tolerance) +
                                 "): the values are the last iterate");
        }
      }
      double ssr = 0.0, signed_sum = 0.0;
      for (int k = 0, row = 0; k < N; ++k) {
        RotatingPositionEstimate& position = out.positions[estimated[k]];
        const double scale = std::sqrt(1.0 + c(k) * c(k));
        double position_ssr = 0.0;
        for (char keep : used_inliers[k]) {
          if (!keep) continue;
          const double distance = r(row++) / scale;
          signed_sum += distance;
          position_ssr += distance * distance;
          out.rotating_residual_max = std::isnan(out.rotating_residual_max)
                                          ? std::abs(distance)
                                          : std::max(out.rotating_residual_max, std::abs(distance));
        }
        position.residual_rms = std::sqrt(position_ssr / position.points);
        ssr += position_ssr;
      }
      out.rotating_points = rows;
      out.rotating_residual_rms = std::sqrt(ssr / rows);
      const double sigma2 = rows > unknowns ? r.squaredNorm() / (rows - unknowns) : 0.0;
      const Eigen::MatrixXd covariance = sigma2 * (J.transpose() * J).inverse();
      out.rotating_covariance = covariance.topLeftCorner<2, 2>();
      rotating_mean = signed_sum / rows;
      if (sigma2 > 0.0 && J.allFinite()) {
        rotating_jacobian = J / std::sqrt(sigma2);
        rotating_names = {"b_y", "d_y"};
        for (int k = 0; k < N; ++k) {
          rotating_names.push_back("cot_theta_y." + std::to_string(estimated[k]));
        }
      }
      for (int k = 0; k < N; ++k) {
        RotatingPositionEstimate& position = out.positions[estimated[k]];
        position.cot_theta_y = c(k);
        position.cot_theta_y_sigma = std::sqrt(covariance(2 + k, 2 + k));
        position.b_y_prime = b_y + d_y * c(k);
      }
      out.geometry.rotating_b_y = b_y;
      out.geometry.rotating_d_y = d_y;
      out.rotating_calibrated = std::isfinite(b_y) && std::isfinite(d_y);
      if (!out.rotating_calibrated) {
        out.errors.push_back("rotating laser: the joint refinement diverged");
      }
    }
  }
  if (out.rotating_outliers > 0) {
    out.warnings.push_back("rotating laser: " + std::to_string(out.rotating_outliers) +
                           " stripe points dropped as outliers");
  }

  // Stepper: θ = θ0 + Δ · step over the estimated positions.
  if (N >= 2) {
    Eigen::MatrixXd A(N, 2);
    Eigen::VectorXd theta(N);
    for (int k = 0; k < N; ++k) {
      const RotatingPositionEstimate& position = out.positions[estimated[k]];
      A(k, 0) = 1.0;
      A(k, 1) = position.step;
      theta(k) = std::atan2(1.0, position.cot_theta_y);
    }
    if (out.positions[estimated.front()].step != out.positions[estimated.back()].step) {
      const Eigen::Vector2d x = A.colPivHouseholderQr().solve(theta);
      out.stepper.fitted = true;
      out.stepper.theta_at_step0 = x(0);
      out.stepper.theta_per_step = x(1);
      out.stepper.residual_rms = std::sqrt((A * x - theta).squaredNorm() / N);
      out.stepper.positions = N;
    }
  }

  // Fixed laser, eq. 29 over all images.
  if (static_cast<int>(fixed.size()) < options.min_fixed_points) {
    out.errors.push_back("fixed laser: " + std::to_string(fixed.size()) + " stripe points (need " +
                         std::to_string(options.min_fixed_points) + ")");
  } else {
    fixed_fit = FitPlane(fixed, 0, options);
    const PlaneFit& fit = fixed_fit;
    out.fixed_depth_condition = fit.condition;
    if (!fit.ok) {
      out.errors.push_back("fixed laser: its stripe points do not span depth (condition number " +
                           Format(fit.condition) + " > " + Format(options.max_depth_condition) +
                           "): add board poses at other distances or tilts");
    } else {
      if (fit.condition > options.warn_depth_condition) {
        out.warnings.push_back(
            "fixed laser: its stripe points span little depth (condition "
            "number " +
            Format(fit.condition) + ")");
      }
      out.geometry.fixed_cot_theta_x = fit.c;
      out.geometry.fixed_b_x_prime = fit.b;
      // Reorder (c, b') to (b', c).
      out.fixed_covariance << fit.covariance(1, 1), fit.covariance(1, 0), fit.covariance(0, 1),
          fit.covariance(0, 0);
      out.fixed_points = fit.inliers;
      out.fixed_outliers = static_cast<int>(fixed.size()) - fit.inliers;
      out.fixed_residual_rms = fit.rms;
      out.fixed_residual_max = fit.max;
      out.fixed_calibrated = true;
      if (out.fixed_outliers > 0) {
        out.warnings.push_back("fixed laser: " + std::to_string(out.fixed_outliers) +
                               " stripe points dropped as outliers");
      }
    }
  }
  out.estimation = LaserScannerEstimation(out, options, rotating_jacobian, rotating_names,
                                          rotating_mean, fixed_fit);
  return out;
}

}  // namespace kinevis::calibration
