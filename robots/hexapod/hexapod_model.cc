#include "robots/hexapod/hexapod_model.h"

#include <Eigen/LU>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <sstream>

#include "common/check.h"
#include "common/so3.h"
#include "common/units.h"

namespace kinevis::robots {
namespace {

// Below this a leg length is treated as zero (direction undefined).
constexpr double kMinLegLength = 1e-12;
// Attachment points closer than this are "coincident" for Validate().
constexpr double kCoincidentDistance = 1e-6;

double DegToRad(double deg) { return deg * common::kPi / 180.0; }

const char* ToString(LegReach reach) {
  switch (reach) {
    case LegReach::kOk:
      return "ok";
    case LegReach::kTooShort:
      return "too short";
    case LegReach::kTooLong:
      return "too long";
    case LegReach::kDegenerate:
      return "degenerate (zero length)";
  }
  return "unknown";
}

std::string FormatPoint(const Eigen::Vector3d& p) {
  std::ostringstream out;
  out << "(" << p.x() << ", " << p.y() << ", " << p.z() << ")";
  return out.str();
}

void CheckPoints(const std::array<Eigen::Vector3d, kHexapodLegs>& points, const char* name,
                 std::ostringstream& errors) {
  for (int j = 0; j < kHexapodLegs; ++j) {
    if (!points[j].allFinite()) {
      errors << name << "[" << j << "] = " << FormatPoint(points[j]) << " is not finite; ";
    }
  }
  for (int i = 0; i < kHexapodLegs; ++i) {
    for (int j = i + 1; j < kHexapodLegs; ++j) {
      if (points[i].allFinite() && points[j].allFinite() &&
          (points[i] - points[j]).norm() < kCoincidentDistance) {
        errors << name << "[" << i << "] and " << name << "[" << j << "] coincide at "
               << FormatPoint(points[i]) << "; ";
      }
    }
  }
}

void RequireIkData(const HexapodData& data) {
  KINEVIS_DEMAND(data.valid);  // call InverseKinematics() first
}

}  // namespace

std::string HexapodModel::Validate() const {
  std::ostringstream errors;
  CheckPoints(p_B_A, "p_B_A", errors);
  CheckPoints(p_P_B, "p_P_B", errors);
  if (!std::isfinite(leg_radius) || leg_radius <= 0.0) {
    errors << "leg_radius = " << leg_radius << " must be finite and > 0; ";
  }
  if (!std::isfinite(leg_length_min) || leg_length_min <= 0.0) {
    errors << "leg_length_min = " << leg_length_min << " must be finite and > 0; ";
  }
  if (!std::isfinite(leg_length_max) || !(leg_length_max > leg_length_min)) {
    errors << "leg_length_max = " << leg_length_max
           << " must be finite and > leg_length_min = " << leg_length_min << "; ";
  }
  for (int j = 0; j < kHexapodLegs; ++j) {
    if (!std::isfinite(q0[j])) errors << "q0[" << j << "] = " << q0[j] << " is not finite; ";
  }
  std::string message = errors.str();
  if (message.size() >= 2) message.resize(message.size() - 2);  // drop the trailing "; "
  return message;
}

HexapodModel HexapodModel::Default() {
  constexpr double kBaseRadius = 0.30;
  constexpr double kPlatformRadius = 0.15;
  constexpr double kBaseSpreadDeg = 20.0;
  constexpr double kPlatformSpreadDeg = 20.0;
  HexapodModel model;
  for (int k = 0; k < 3; ++k) {
    const double centre = 120.0 * k;
    // Leg 2k leaves base pair k towards the platform pair at centre − 60°, leg 2k+1 towards the
    // pair at centre + 60°: the usual crossed-leg 6-6 layout.
    const double a0 = DegToRad(centre - kBaseSpreadDeg / 2);
    const double a1 = DegToRad(centre + kBaseSpreadDeg / 2);
    const double b0 = DegToRad(centre - 60.0 + kPlatformSpreadDeg / 2);
    const double b1 = DegToRad(centre + 60.0 - kPlatformSpreadDeg / 2);
    model.p_B_A[2 * k] = kBaseRadius * Eigen::Vector3d(std::cos(a0), std::sin(a0), 0.0);
    model.p_B_A[2 * k + 1] = kBaseRadius * Eigen::Vector3d(std::cos(a1), std::sin(a1), 0.0);
    model.p_P_B[2 * k] = kPlatformRadius * Eigen::Vector3d(std::cos(b0), std::sin(b0), 0.0);
    model.p_P_B[2 * k + 1] = kPlatformRadius * Eigen::Vector3d(std::cos(b1), std::sin(b1), 0.0);
  }
  model.leg_radius = 0.02;
  model.leg_length_min = 0.35;
  model.leg_length_max = 0.55;
  model.q0.fill(0.35);
  return model;
}

Eigen::Isometry3d HexapodModel::NominalPose() {
  Eigen::Isometry3d X_BP = Eigen::Isometry3d::Identity();
  X_BP.translation() = Eigen::Vector3d(0.0, 0.0, 0.40);
  return X_BP;
}

bool Reachability::ok() const { return FirstBadLeg() < 0; }

int Reachability::FirstBadLeg() const {
  for (int j = 0; j < kHexapodLegs; ++j) {
    if (legs[j] != LegReach::kOk) return j;
  }
  return -1;
}

std::string Reachability::Describe(const HexapodModel& model, const Vector6d& q) const {
  std::ostringstream out;
  bool first = true;
  for (int j = 0; j < kHexapodLegs; ++j) {
    if (legs[j] == LegReach::kOk) continue;
    if (!first) out << "; ";
    first = false;
    out << "leg " << j << " " << ToString(legs[j]) << " (q = " << q[j] << " m, stroke ["
        << model.leg_length_min << ", " << model.leg_length_max << "] m)";
  }
  return out.str();
}

// seed 002, eq. (4)–(5), written in B instead of the mirror frame.
Reachability InverseKinematics(const HexapodModel& model, const Eigen::Isometry3d& X_BP,
                               HexapodData* data) {
  KINEVIS_DEMAND(data != nullptr);
  const Eigen::Matrix3d R_BP = X_BP.linear();
  const Eigen::Vector3d p_BP = X_BP.translation();
  data->X_BP = X_BP;
  for (int j = 0; j < kHexapodLegs; ++j) {
    data->r_B_PB[j] = R_BP * model.p_P_B[j];
    data->p_B_B[j] = data->r_B_PB[j] + p_BP;
    data->l_B[j] = data->p_B_B[j] - model.p_B_A[j];
    const double q = data->l_B[j].norm();
    data->q[j] = q;
    if (!(q > kMinLegLength)) {  // also catches NaN
      data->u_B[j].setZero();
      data->reach.legs[j] = LegReach::kDegenerate;
      continue;
    }
    data->u_B[j] = data->l_B[j] / q;
    if (q < model.leg_length_min) {
      data->reach.legs[j] = LegReach::kTooShort;
    } else if (q > model.leg_length_max) {
      data->reach.legs[j] = LegReach::kTooLong;
    } else {
      data->reach.legs[j] = LegReach::kOk;
    }
  }
  data->valid = true;
  return data->reach;
}

Vector6d JointPositionsFromLegLengths(const HexapodModel& model, const Vector6d& q) {
  return q - Eigen::Map<const Vector6d>(model.q0.data());
}

Vector6d LegLengthsFromJointPositions(const HexapodModel& model, const Vector6d& s) {
  return s + Eigen::Map<const Vector6d>(model.q0.data());
}

// seed 002, eq. (7). The seed refers the twist to the origin of the mirror frame, giving
// (A_j × u_j); here it is referred to the platform origin, q̇_j = u_jᵀ (v + ω × r_j) =
// u_jᵀ v + (r_j × u_j)ᵀ ω with r_j = R_BP p_P_Bj. Both agree since B_j × u_j = A_j × u_j.
Matrix6d InverseDifferential(const HexapodData& data) {
  RequireIkData(data);
  Matrix6d D_inv;
  for (int j = 0; j < kHexapodLegs; ++j) {
    D_inv.block<1, 3>(j, 0) = data.u_B[j].transpose();
    D_inv.block<1, 3>(j, 3) = data.r_B_PB[j].cross(data.u_B[j]).transpose();
  }
  return D_inv;
}

double ConditionNumber(const Matrix6d& m) {
  const Eigen::JacobiSVD<Matrix6d> svd(m);
  const Vector6d& s = svd.singularValues();
  if (!s.allFinite()) return std::numeric_limits<double>::infinity();
  if (s[5] <= 0.0) return std::numeric_limits<double>::infinity();
  return s[0] / s[5];
}

// seed 002, eq. (8)–(9) (garbled in the text), re-derived. u_j = (p_B_Bj − p_B_Aj)/q_j with
// A_j fixed, so differentiating q_j u_j = l_j gives q̇_j u_j + q_j u̇_j = l̇_j; projecting out
// the component along u_j (u_jᵀ u̇_j = 0 because |u_j| = 1) leaves
//   u̇_j = (I − u_j u_jᵀ) l̇_j / q_j,  l̇_j = ṗ_B_Bj = v + ω × r_j = [I, −[r_j]×] [v; ω].
// The seed's form (twist at the camera origin) is [I, −[A_j + q_j u_j]×]; see README.md.
Matrix36d LegDirectionInteractionMatrix(const HexapodData& data, int leg) {
  RequireIkData(data);
  KINEVIS_DEMAND(leg >= 0 && leg < kHexapodLegs);
  const double q = data.q[leg];
  KINEVIS_DEMAND(q > kMinLegLength);
  const Eigen::Vector3d& u = data.u_B[leg];
  const Eigen::Matrix3d projector = (Eigen::Matrix3d::Identity() - u * u.transpose()) / q;
  Matrix36d L;
  L.leftCols<3>() = projector;
  L.rightCols<3>() = -projector * common::Skew(data.r_B_PB[leg]);
  return L;
}

// u_C = R_CB u_B, the camera being fixed to B; twist_B = blockdiag(R_BC, R_BC) twist_C (the
// reference point, the platform origin, does not change with the frame of expression).
Matrix36d LegDirectionInteractionMatrixInCamera(const HexapodData& data, int leg,
                                                const Eigen::Isometry3d& X_CB) {
  const Matrix36d L_B = LegDirectionInteractionMatrix(data, leg);
  const Eigen::Matrix3d R_CB = X_CB.linear();
  Matrix36d L_C;
  L_C.leftCols<3>() = R_CB * L_B.leftCols<3>() * R_CB.transpose();
  L_C.rightCols<3>() = R_CB * L_B.rightCols<3>() * R_CB.transpose();
  return L_C;
}

std::string ForwardKinematicsOptions::Validate() const {
  std::ostringstream errors;
  if (max_iterations < 1) errors << "max_iterations = " << max_iterations << " must be >= 1; ";
  if (!(residual_tolerance > 0.0) || !std::isfinite(residual_tolerance)) {
    errors << "residual_tolerance = " << residual_tolerance << " must be finite and > 0; ";
  }
  if (!(max_condition_number > 1.0)) {
    errors << "max_condition_number = " << max_condition_number << " must be > 1; ";
  }
  if (!(max_step_translation > 0.0) || !std::isfinite(max_step_translation)) {
    errors << "max_step_translation = " << max_step_translation << " must be finite and > 0; ";
  }
  if (!(max_step_rotation > 0.0) || !std::isfinite(max_step_rotation)) {
    errors << "max_step_rotation = " << max_step_rotation << " must be finite and > 0; ";
  }
  std::string message = errors.str();
  if (message.size() >= 2) message.resize(message.size() - 2);
  return message;
}

const char* ToString(ForwardKinematicsStatus status) {
  switch (status) {
    case ForwardKinematicsStatus::kConverged:
      return "converged";
    case ForwardKinematicsStatus::kMaxIterations:
      return "max iterations reached";
    case ForwardKinematicsStatus::kSingular:
      return "singular Jacobian";
    case ForwardKinematicsStatus::kInvalidInput:
      return "invalid input";
  }
  return "unknown";
}

ForwardKinematicsSummary ForwardKinematics(const HexapodModel& model, const Vector6d& q,
                                           const Eigen::Isometry3d& X_BP_guess,
                                           const ForwardKinematicsOptions& options,
                                           HexapodData* data) {
  KINEVIS_DEMAND(data != nullptr);
  ForwardKinematicsSummary summary;
  summary.X_BP = X_BP_guess;
  summary.residual = std::numeric_limits<double>::quiet_NaN();
  summary.condition_number = std::numeric_limits<double>::quiet_NaN();
  // Options::Validate() allocates only to build a message; the checks are repeated cheaply here
  // so that a valid call stays allocation-free.
  const bool options_ok =
      options.max_iterations >= 1 && options.residual_tolerance > 0.0 &&
      std::isfinite(options.residual_tolerance) && options.max_condition_number > 1.0 &&
      options.max_step_translation > 0.0 && std::isfinite(options.max_step_translation) &&
      options.max_step_rotation > 0.0 && std::isfinite(options.max_step_rotation);
  const bool q_ok = q.allFinite() && (q.array() > 0.0).all();
  if (!options_ok || !q_ok || !X_BP_guess.matrix().allFinite()) {
    summary.status = ForwardKinematicsStatus::kInvalidInput;
    data->valid = false;
    return summary;
  }

  // Keep the rotation as a unit quaternion so repeated updates stay orthonormal.
  Eigen::Quaterniond R_BP(X_BP_guess.linear());
  R_BP.normalize();
  Eigen::Vector3d p_BP = X_BP_guess.translation();
  Eigen::Isometry3d X_BP = Eigen::Isometry3d::Identity();

  for (int iteration = 0;; ++iteration) {
    X_BP.linear() = R_BP.toRotationMatrix();
    X_BP.translation() = p_BP;
    InverseKinematics(model, X_BP, data);
    const Vector6d residual = data->q - q;
    const Matrix6d D_inv = InverseDifferential(*data);
    summary.X_BP = X_BP;
    summary.iterations = iteration;
    summary.residual = residual.cwiseAbs().maxCoeff();
    if (!std::isfinite(summary.residual)) {
      summary.status = ForwardKinematicsStatus::kSingular;  // a degenerate leg: no direction
      summary.condition_number = std::numeric_limits<double>::infinity();
      return summary;
    }
    // The exact 2-norm condition number needs an SVD (~µs); the Newton steps only need an LU and
    // its cheap 1-norm reciprocal-condition estimate, so the SVD runs once, at the final iterate,
    // or when the estimate says the pose may be singular.
    if (summary.residual <= options.residual_tolerance) {
      summary.condition_number = ConditionNumber(D_inv);
      summary.status = ForwardKinematicsStatus::kConverged;
      return summary;
    }
    const Eigen::PartialPivLU<Matrix6d> lu(D_inv);
    const double rcond = lu.rcond();
    // cond_1 and cond_2 differ by at most a factor n = 6; the estimate is within a small factor.
    if (!(rcond > 0.0) || 1.0 / rcond > options.max_condition_number / 100.0) {
      summary.condition_number = ConditionNumber(D_inv);
      if (!(summary.condition_number <= options.max_condition_number)) {
        summary.status = ForwardKinematicsStatus::kSingular;
        return summary;
      }
    }
    if (iteration >= options.max_iterations) {
      summary.condition_number = ConditionNumber(D_inv);
      summary.status = ForwardKinematicsStatus::kMaxIterations;
      return summary;
    }
    // Newton: q(X ⊕ δ) ≈ q(X) + D_inv δ = q_target.
    Vector6d delta = -lu.solve(residual);
    // Far from the solution a full step can jump to another assembly mode; bound it.
    const double scale =
        std::min({1.0, options.max_step_translation / std::max(delta.head<3>().norm(), 1e-300),
                  options.max_step_rotation / std::max(delta.tail<3>().norm(), 1e-300)});
    delta *= scale;
    p_BP += delta.head<3>();
    const double angle = delta.tail<3>().norm();
    if (angle > 0.0) {
      R_BP = Eigen::Quaterniond(Eigen::AngleAxisd(angle, delta.tail<3>() / angle)) * R_BP;
      R_BP.normalize();
    }
  }
}

}  // namespace kinevis::robots
