#include "robots/diamond/diamond_model.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <sstream>
#include <stdexcept>

#include "common/check.h"
#include "common/units.h"

namespace kinevis::robots {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
// Below this |sin γ| the tool axis is treated as lying on z_O (φ undefined).
constexpr double kMinSinGamma = 1e-12;

double DegToRad(double deg) { return deg * common::kPi / 180.0; }

// The limits shared by both seed parameter sets (assumptions; the seed gives none, README.md).
DiamondModel WithSeedLimits(double radius, double alpha, double beta) {
  DiamondModel model;
  model.radius = radius;
  model.alpha = alpha;
  model.beta = beta;
  model.joint_offsets = {0.0, 0.0};
  model.theta_min = {0.0, -common::kPi / 2};
  model.theta_max = {3 * common::kPi / 2, common::kPi};
  model.separation_min = DegToRad(20.0);
  model.separation_max = DegToRad(170.0);
  model.phi_min = 0.0;
  model.phi_max = common::kPi;
  model.gamma_min = DegToRad(30.0);
  model.gamma_max = DegToRad(85.0);
  return model;
}

// θ and separation limits, shared by FK and IK.
void CheckJointLimits(const DiamondModel& model, const Eigen::Vector2d& theta,
                      DiamondReachability* reach) {
  for (int i = 0; i < kDiamondJoints; ++i) {
    if (theta[i] < model.theta_min[i]) {
      reach->Add(DiamondReach::kBelowThetaMin, i, theta[i], model.theta_min[i]);
    } else if (theta[i] > model.theta_max[i]) {
      reach->Add(DiamondReach::kAboveThetaMax, i, theta[i], model.theta_max[i]);
    }
  }
  const double separation = theta[0] - theta[1];
  if (separation < model.separation_min) {
    reach->Add(DiamondReach::kLimbsTooClose, -1, separation, model.separation_min);
  } else if (separation > model.separation_max) {
    reach->Add(DiamondReach::kLimbsTooFar, -1, separation, model.separation_max);
  }
}

void CheckTaskBox(const DiamondModel& model, const Eigen::Vector2d& task,
                  DiamondReachability* reach) {
  if (task[0] < model.phi_min) reach->Add(DiamondReach::kPhiOutside, -1, task[0], model.phi_min);
  if (task[0] > model.phi_max) reach->Add(DiamondReach::kPhiOutside, -1, task[0], model.phi_max);
  if (task[1] < model.gamma_min) {
    reach->Add(DiamondReach::kGammaOutside, -1, task[1], model.gamma_min);
  }
  if (task[1] > model.gamma_max) {
    reach->Add(DiamondReach::kGammaOutside, -1, task[1], model.gamma_max);
  }
}

// Condition number of a matrix with two columns from the eigenvalues of the 2×2 Gram matrix
// (closed form, no allocation).
template <int Rows>
double TwoColumnConditionNumber(const Eigen::Matrix<double, Rows, 2>& m) {
  const Eigen::Matrix2d g = m.transpose() * m;
  const double mean = 0.5 * (g(0, 0) + g(1, 1));
  const double diff = 0.5 * (g(0, 0) - g(1, 1));
  const double radius = std::sqrt(diff * diff + g(0, 1) * g(0, 1));
  const double lambda_max = mean + radius;
  const double lambda_min = std::max(0.0, mean - radius);
  if (!std::isfinite(lambda_max)) return kInf;
  if (lambda_min <= lambda_max * 1e-300 || lambda_min == 0.0) return kInf;
  return std::sqrt(lambda_max / lambda_min);
}

}  // namespace

std::string DiamondModel::Validate() const {
  std::ostringstream errors;
  if (!std::isfinite(radius) || radius <= 0.0) {
    errors << "radius = " << radius << " must be finite and > 0 m; ";
  }
  const bool alpha_ok = std::isfinite(alpha) && alpha > 0.0 && alpha < common::kPi;
  const bool beta_ok = std::isfinite(beta) && beta > 0.0 && beta < common::kPi;
  if (!alpha_ok) errors << "alpha = " << alpha << " must be in (0, pi) rad; ";
  if (!beta_ok) errors << "beta = " << beta << " must be in (0, pi) rad; ";
  if (alpha_ok && beta_ok && !(alpha + beta < common::kPi)) {
    // Eq. (35)'s denominator cα + cβ must be > 0: otherwise the stretched limbs reach past −z_O
    // and γ leaves [0, π].
    errors << "alpha + beta = " << alpha + beta << " must be < pi rad; ";
  }
  for (int i = 0; i < kDiamondJoints; ++i) {
    if (!std::isfinite(joint_offsets[i])) {
      errors << "joint_offsets[" << i << "] = " << joint_offsets[i] << " is not finite; ";
    }
    if (!std::isfinite(theta_min[i]) || !std::isfinite(theta_max[i]) ||
        !(theta_min[i] < theta_max[i])) {
      errors << "theta_min[" << i << "] = " << theta_min[i] << ", theta_max[" << i
             << "] = " << theta_max[i] << " must be finite with min < max; ";
    }
  }
  if (!std::isfinite(separation_min) || !std::isfinite(separation_max) || !(separation_min > 0.0) ||
      !(separation_min < separation_max) || !(separation_max < 2 * common::kPi)) {
    errors << "separation_min = " << separation_min << ", separation_max = " << separation_max
           << " must satisfy 0 < min < max < 2 pi rad; ";
  }
  if (!std::isfinite(phi_min) || !std::isfinite(phi_max) || !(phi_min < phi_max)) {
    errors << "phi_min = " << phi_min << ", phi_max = " << phi_max
           << " must be finite with min < max; ";
  }
  if (!std::isfinite(gamma_min) || !std::isfinite(gamma_max) || !(gamma_min >= 0.0) ||
      !(gamma_min < gamma_max) || !(gamma_max <= common::kPi)) {
    errors << "gamma_min = " << gamma_min << ", gamma_max = " << gamma_max
           << " must satisfy 0 <= min < max <= pi rad; ";
  }
  std::string message = errors.str();
  if (message.size() >= 2) message.resize(message.size() - 2);  // drop the trailing "; "
  return message;
}

DiamondModel DiamondModel::Checked(const DiamondModel& model) {
  const std::string message = model.Validate();
  if (!message.empty()) throw std::invalid_argument("DiamondModel: " + message);
  return model;
}

// Seed 001, Table I.
DiamondModel DiamondModel::APriori() {
  return WithSeedLimits(0.2000, common::kPi / 4, common::kPi / 4);
}
DiamondModel DiamondModel::SeedIdentified() { return WithSeedLimits(0.2221, 0.7634, 0.8037); }

const char* ToString(DiamondReach reach) {
  switch (reach) {
    case DiamondReach::kOk:
      return "ok";
    case DiamondReach::kInvalidInput:
      return "invalid input";
    case DiamondReach::kNoAssembly:
      return "no assembly (eq. 35 has no real root)";
    case DiamondReach::kUnreachable:
      return "unreachable";
    case DiamondReach::kFoldedBranchOnly:
      return "reachable only on the folded (colliding) branch";
    case DiamondReach::kBelowThetaMin:
      return "below theta_min";
    case DiamondReach::kAboveThetaMax:
      return "above theta_max";
    case DiamondReach::kLimbsTooClose:
      return "limbs too close (collision)";
    case DiamondReach::kLimbsTooFar:
      return "limbs too far apart";
    case DiamondReach::kPhiOutside:
      return "phi outside the workspace";
    case DiamondReach::kGammaOutside:
      return "gamma outside the workspace";
  }
  return "unknown";
}

const char* ToString(DiamondSingularity singularity) {
  switch (singularity) {
    case DiamondSingularity::kNone:
      return "none";
    case DiamondSingularity::kLimbsAligned:
      return "limbs aligned (rhombus folded flat)";
    case DiamondSingularity::kBranchesMerge:
      return "branches of eq. 35 merge (parallel singularity)";
    case DiamondSingularity::kToolOnBaseAxis:
      return "tool axis on the base axis (phi undefined)";
  }
  return "unknown";
}

bool DiamondReachability::Has(DiamondReach reach) const {
  for (int k = 0; k < count; ++k) {
    if (issues[k].reach == reach) return true;
  }
  return false;
}

void DiamondReachability::Add(DiamondReach reach, int joint, double value, double bound) {
  if (count >= kMaxIssues) return;
  issues[count++] = DiamondIssue{reach, joint, value, bound};
}

std::string DiamondReachability::Describe() const {
  std::ostringstream out;
  for (int k = 0; k < count; ++k) {
    const DiamondIssue& issue = issues[k];
    if (k > 0) out << "; ";
    switch (issue.reach) {
      case DiamondReach::kBelowThetaMin:
        out << "theta_" << issue.joint + 1 << " = " << issue.value << " rad below theta_min["
            << issue.joint << "] = " << issue.bound << " rad";
        break;
      case DiamondReach::kAboveThetaMax:
        out << "theta_" << issue.joint + 1 << " = " << issue.value << " rad above theta_max["
            << issue.joint << "] = " << issue.bound << " rad";
        break;
      case DiamondReach::kLimbsTooClose:
        out << "theta_1 - theta_2 = " << issue.value
            << " rad below separation_min = " << issue.bound << " rad (limbs collide)";
        break;
      case DiamondReach::kLimbsTooFar:
        out << "theta_1 - theta_2 = " << issue.value
            << " rad above separation_max = " << issue.bound << " rad";
        break;
      case DiamondReach::kPhiOutside:
        out << "phi = " << issue.value << " rad outside the workspace (bound " << issue.bound
            << " rad)";
        break;
      case DiamondReach::kGammaOutside:
        out << "gamma = " << issue.value << " rad outside the workspace (bound " << issue.bound
            << " rad)";
        break;
      case DiamondReach::kNoAssembly:
        out << "no assembly at theta_1 - theta_2 = " << issue.value
            << " rad: sin^2(beta) < (sin(alpha) sin(A))^2, eq. (35) has no real root";
        break;
      case DiamondReach::kUnreachable:
        out << "unreachable: cos A = " << issue.value << " outside [-1, 1] (or sin gamma <= 0)";
        break;
      case DiamondReach::kFoldedBranchOnly:
        out << "gamma = " << issue.value
            << " rad reachable only on the folded (colliding) branch of eq. (35)";
        break;
      case DiamondReach::kInvalidInput:
        out << "invalid input: " << (issue.joint >= 0 ? "component " : "value ")
            << (issue.joint >= 0 ? issue.joint : 0) << " = " << issue.value;
        break;
      case DiamondReach::kOk:
        out << "ok";
        break;
    }
  }
  return out.str();
}

DiamondReachability ForwardKinematics(const DiamondModel& model, const Eigen::Vector2d& q,
                                      DiamondData* data) {
  KINEVIS_DEMAND(data != nullptr);
  DiamondData& d = *data;
  d = DiamondData{};
  d.q = q;
  DiamondReachability& reach = d.reach;
  for (int i = 0; i < kDiamondJoints; ++i) {
    if (!std::isfinite(q[i])) reach.Add(DiamondReach::kInvalidInput, i, q[i], 0.0);
  }
  if (!reach.ok()) return reach;

  d.theta = Eigen::Vector2d(q[0] + model.joint_offsets[0], q[1] + model.joint_offsets[1]);
  d.half_separation = 0.5 * (d.theta[0] - d.theta[1]);
  const double sa = std::sin(model.alpha);
  const double ca = std::cos(model.alpha);
  for (int i = 0; i < kDiamondJoints; ++i) {
    d.w_O[i] = Eigen::Vector3d(sa * std::cos(d.theta[i]), sa * std::sin(d.theta[i]), ca);
  }
  CheckJointLimits(model, d.theta, &reach);

  double phi = 0.0;
  double gamma = 0.0;
  if (DiamondTaskFromThetas<double>(model.alpha, model.beta, d.theta[0], d.theta[1], &phi,
                                    &gamma) != DiamondSolve::kOk) {
    reach.Add(DiamondReach::kNoAssembly, -1, d.theta[0] - d.theta[1], 0.0);
    return reach;
  }
  d.task = Eigen::Vector2d(phi, gamma);
  d.u_O = DiamondToolAxis(phi, gamma);
  d.p_O_T = model.radius * d.u_O;
  // Implicit differentiation of sα cA sγ + cα cγ = cβ. On the "+" root the denominator is
  // −ρ sin(acos(cβ/ρ)) <= 0; it is zero where the roots merge (γ_A infinite).
  const double sA = std::sin(d.half_separation);
  const double cA = std::cos(d.half_separation);
  const double sg = std::sin(gamma);
  const double cg = std::cos(gamma);
  const double numerator = sa * sA * sg;
  const double denominator = sa * cA * cg - ca * sg;
  d.dgamma_dA = denominator != 0.0 ? numerator / denominator
                                   : (numerator == 0.0 ? 0.0 : -std::copysign(kInf, numerator));
  d.valid = true;
  CheckTaskBox(model, d.task, &reach);
  return reach;
}

DiamondReachability InverseKinematics(const DiamondModel& model, const Eigen::Vector2d& task,
                                      Eigen::Vector2d* q) {
  KINEVIS_DEMAND(q != nullptr);
  DiamondReachability reach;
  for (int i = 0; i < 2; ++i) {
    if (!std::isfinite(task[i])) reach.Add(DiamondReach::kInvalidInput, i, task[i], 0.0);
  }
  if (!reach.ok()) return reach;
  CheckTaskBox(model, task, &reach);

  double theta1 = 0.0;
  double theta2 = 0.0;
  const DiamondSolve solve =
      DiamondThetasFromTask<double>(model.alpha, model.beta, task[0], task[1], &theta1, &theta2);
  if (solve == DiamondSolve::kNoSolution) {
    const double sg = std::sin(task[1]);
    const double cos_half =
        sg > kMinSinGamma ? (std::cos(model.beta) - std::cos(model.alpha) * std::cos(task[1])) /
                                (std::sin(model.alpha) * sg)
                          : kInf;
    reach.Add(DiamondReach::kUnreachable, -1, cos_half, 1.0);
    return reach;
  }
  if (solve == DiamondSolve::kFoldedBranchOnly) {
    reach.Add(DiamondReach::kFoldedBranchOnly, -1, task[1], 0.0);
    return reach;
  }
  const Eigen::Vector2d theta(theta1, theta2);
  *q = Eigen::Vector2d(theta1 - model.joint_offsets[0], theta2 - model.joint_offsets[1]);
  CheckJointLimits(model, theta, &reach);
  return reach;
}

DiamondReachability InverseKinematicsFromDirection(const DiamondModel& model,
                                                   const Eigen::Vector3d& u_O, Eigen::Vector2d* q) {
  KINEVIS_DEMAND(q != nullptr);
  const double norm = u_O.norm();
  if (!std::isfinite(norm) || norm == 0.0) {
    DiamondReachability reach;
    reach.Add(DiamondReach::kInvalidInput, -1, norm, 0.0);
    return reach;
  }
  const double phi = std::atan2(u_O.y(), u_O.x());
  const double gamma = std::atan2(std::hypot(u_O.x(), u_O.y()), u_O.z());
  return InverseKinematics(model, Eigen::Vector2d(phi, gamma), q);
}

DiamondReachability CheckWorkspace(const DiamondModel& model, const Eigen::Vector2d& task) {
  Eigen::Vector2d q;
  return InverseKinematics(model, task, &q);
}

Eigen::Matrix2d TaskJacobian(const DiamondData& data) {
  KINEVIS_DEMAND(data.valid);  // call ForwardKinematics() first
  // φ = (θ_1 + θ_2)/2, γ = γ(A), A = (θ_1 − θ_2)/2.
  const double g = data.dgamma_dA;
  Eigen::Matrix2d J;
  J << 0.5, 0.5, 0.5 * g, -0.5 * g;
  return J;
}

Matrix32d ToolPointJacobian(const DiamondModel& model, const DiamondData& data) {
  KINEVIS_DEMAND(data.valid);
  const double phi = data.task[0];
  const double gamma = data.task[1];
  const double sp = std::sin(phi);
  const double cp = std::cos(phi);
  const double sg = std::sin(gamma);
  const double cg = std::cos(gamma);
  Matrix32d du_dtask;
  du_dtask << -sg * sp, cg * cp,  //
      sg * cp, cg * sp,           //
      0.0, -sg;
  return model.radius * du_dtask * TaskJacobian(data);
}

DiamondSingularityReport AnalyzeSingularity(const DiamondModel& model, const DiamondData& data,
                                            double max_condition) {
  KINEVIS_DEMAND(data.valid);
  KINEVIS_DEMAND(max_condition > 1.0);
  DiamondSingularityReport report;
  // The rows of TaskJacobian are orthogonal with norms 1/√2 and |γ_A|/√2.
  const double g = std::abs(data.dgamma_dA);
  report.task_condition = (g == 0.0 || !std::isfinite(g)) ? kInf : std::max(g, 1.0 / g);
  report.point_condition =
      std::isfinite(g) ? TwoColumnConditionNumber<3>(ToolPointJacobian(model, data)) : kInf;
  // γ_A = sα sA sγ / (sα cA cγ − cα sγ): it vanishes with sA (limbs aligned) or with sγ (tool on
  // z_O, where (φ, γ) themselves degenerate) and blows up where the roots merge. The singular
  // values of ToolPointJacobian are R sγ/√2 and R |γ_A|/√2.
  const double s_half = std::abs(std::sin(data.half_separation));
  const double s_gamma = std::abs(std::sin(data.task[1]));
  if (report.task_condition > max_condition) {
    if (g > 1.0) {
      report.kind = DiamondSingularity::kBranchesMerge;
    } else {
      report.kind = s_half <= s_gamma ? DiamondSingularity::kLimbsAligned
                                      : DiamondSingularity::kToolOnBaseAxis;
    }
  } else if (report.point_condition > max_condition) {
    report.kind = DiamondSingularity::kToolOnBaseAxis;
  }
  return report;
}

}  // namespace kinevis::robots
