#pragma once

// The one finite-difference Jacobian checker for tests: central differences of a function
// R^n → R^m, compared with an analytic Jacobian entry by entry, relative to the Jacobian's
// largest entry. Header-only (templates), std + Eigen.

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <functional>
#include <string>

namespace kinevis::testing {

// ∂f/∂x at x by central differences with step h (per coordinate). `f` returns false when it
// cannot be evaluated at a perturbed point; the result is then empty (0 × 0).
inline Eigen::MatrixXd CentralDifferenceJacobian(
    const std::function<bool(const Eigen::VectorXd&, Eigen::VectorXd*)>& f,
    const Eigen::VectorXd& x, double h) {
  Eigen::VectorXd y0;
  if (!f(x, &y0)) return {};
  Eigen::MatrixXd J(y0.size(), x.size());
  for (Eigen::Index i = 0; i < x.size(); ++i) {
    Eigen::VectorXd plus = x, minus = x, y_plus, y_minus;
    plus(i) += h;
    minus(i) -= h;
    if (!f(plus, &y_plus) || !f(minus, &y_minus)) return {};
    J.col(i) = (y_plus - y_minus) / (2.0 * h);
  }
  return J;
}

// Empty when |analytic − numeric| <= tolerance · max |numeric| (relative to the largest entry;
// absolute below 1e-12) everywhere, else a message
// naming the worst entry with both values.
inline std::string CompareJacobians(const Eigen::MatrixXd& analytic, const Eigen::MatrixXd& numeric,
                                    double tolerance) {
  if (analytic.rows() != numeric.rows() || analytic.cols() != numeric.cols()) {
    return "sizes differ: analytic " + std::to_string(analytic.rows()) + "x" +
           std::to_string(analytic.cols()) + ", numeric " + std::to_string(numeric.rows()) + "x" +
           std::to_string(numeric.cols());
  }
  const double scale = std::max(1e-12, numeric.cwiseAbs().maxCoeff());
  Eigen::Index r = 0, c = 0;
  const double worst = (analytic - numeric).cwiseAbs().maxCoeff(&r, &c);
  if (worst <= tolerance * scale) return "";
  return "entry (" + std::to_string(r) + ", " + std::to_string(c) + "): analytic " +
         std::to_string(analytic(r, c)) + ", numeric " + std::to_string(numeric(r, c)) +
         " (difference " + std::to_string(worst) + " > " + std::to_string(tolerance * scale) + ")";
}

}  // namespace kinevis::testing
