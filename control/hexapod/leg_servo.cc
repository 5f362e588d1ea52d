#include "control/hexapod/leg_servo.h"

#include <visp3/core/vpColVector.h>
#include <visp3/core/vpMatrix.h>
#include <visp3/visual_features/vpGenericFeature.h>
#include <visp3/vs/vpAdaptiveGain.h>
#include <visp3/vs/vpServo.h>

#include <array>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "common/so3.h"

namespace kinevis::control {
namespace {

bool IsUnit(const Eigen::Vector3d& u) { return u.allFinite() && std::abs(u.norm() - 1.0) <= 1e-6; }

}  // namespace

// Seed 002, eq. (8)–(9). The printed eq. 9 is garbled (a fraction of two matrices); we use the
// form re-derived in robots/hexapod/README.md: q u = B − A ⇒ q̇ u + q u̇ = Ḃ, and projecting
// with (I − u uᵀ) (u ⟂ u̇) gives u̇ = (I − u uᵀ) Ḃ / q. With the twist referred to C's origin,
// Ḃ = v + ω × B = [I₃, −[B]×] τ and B = A + q u: the reading of eq. 9 is
// L = (I − u uᵀ)/q · [I₃, −[A + q u]×]. Checked against central differences of a moving
// platform and against robots::LegDirectionInteractionMatrixInCamera in leg_servo_test.cc.
Matrix36d LegDirectionInteractionMatrixAtCameraOrigin(const Eigen::Vector3d& p_C_A,
                                                      const Eigen::Vector3d& u_C, double q) {
  const Eigen::Matrix3d P = (Eigen::Matrix3d::Identity() - u_C * u_C.transpose()) / q;
  Matrix36d L;
  L.leftCols<3>() = P;
  L.rightCols<3>() = -P * common::Skew(p_C_A + q * u_C);
  return L;
}

// Seed 002, eq. (7): q̇ = uᵀ Ḃ = uᵀ v + uᵀ (ω × B) = uᵀ v + (B × u)ᵀ ω, and B × u = A × u.
Eigen::Matrix<double, 1, 6> InverseDifferentialRowAtCameraOrigin(const Eigen::Vector3d& p_C_A,
                                                                 const Eigen::Vector3d& u_C) {
  Eigen::Matrix<double, 1, 6> row;
  row.leftCols<3>() = u_C.transpose();
  row.rightCols<3>() = p_C_A.cross(u_C).transpose();
  return row;
}

robots::Matrix6d InverseDifferentialAtCameraOrigin(const LegPoints& p_C_A,
                                                   const LegDirections& u_C) {
  robots::Matrix6d D;
  for (int j = 0; j < kHexapodLegs; ++j) {
    D.row(j) = InverseDifferentialRowAtCameraOrigin(p_C_A[j], u_C[j]);
  }
  return D;
}

robots::Reachability DesiredLegDirections(const robots::HexapodModel& model,
                                          const Eigen::Isometry3d& X_BP_desired,
                                          const Eigen::Isometry3d& X_CB, LegDirections* u_C_star) {
  robots::HexapodData data;
  const robots::Reachability reach = robots::InverseKinematics(model, X_BP_desired, &data);
  for (int j = 0; j < kHexapodLegs; ++j) (*u_C_star)[j] = X_CB.linear() * data.u_B[j];
  return reach;
}

LegPoints AttachmentPointsInCamera(const robots::HexapodModel& model,
                                   const Eigen::Isometry3d& X_CB) {
  LegPoints p;
  for (int j = 0; j < kHexapodLegs; ++j) p[j] = X_CB * model.p_B_A[j];
  return p;
}

std::string LegServoOptions::Validate() const {
  std::ostringstream out;
  const auto bad = [&](const char* field, double value, const char* rule) {
    if (out.tellp() > 0) out << "; ";
    out << field << ": " << rule << ", got " << value;
  };
  if (!(std::isfinite(gain) && gain > 0)) bad("gain", gain, "must be finite and > 0");
  if (adaptive_gain) {
    if (!(std::isfinite(gain_at_zero) && gain_at_zero > 0)) {
      bad("gain_at_zero", gain_at_zero, "must be finite and > 0");
    }
    if (!(std::isfinite(gain_at_infinity) && gain_at_infinity > 0)) {
      bad("gain_at_infinity", gain_at_infinity, "must be finite and > 0");
    }
    if (!(std::isfinite(slope_at_zero) && slope_at_zero > 0)) {
      bad("slope_at_zero", slope_at_zero, "must be finite and > 0");
    }
    if (gain_at_zero <= gain_at_infinity) {
      bad("gain_at_zero", gain_at_zero, "must exceed gain_at_infinity");
    }
  }
  if (min_visible_legs < 3 || min_visible_legs > kHexapodLegs) {
    bad("min_visible_legs", min_visible_legs, "must be in 3..6");
  }
  return out.str();
}

const char* ToString(LegServoStatus status) {
  switch (status) {
    case LegServoStatus::kOk:
      return "ok";
    case LegServoStatus::kTooFewLegs:
      return "too few legs visible";
    case LegServoStatus::kRankDeficient:
      return "interaction matrix rank < 6";
    case LegServoStatus::kNoDirection:
      return "a hidden leg was never seen";
    case LegServoStatus::kInvalidInput:
      return "invalid input";
  }
  return "?";
}

int StackLegServoTask(const LegPoints& p_C_A, const LegDirections& u_C,
                      const LegDirections& u_C_star, const LegMask& visible, const Vector6d& q,
                      Eigen::Matrix<double, 18, 6>* L, Eigen::Matrix<double, 18, 1>* e) {
  int rows = 0;
  for (int j = 0; j < kHexapodLegs; ++j) {
    if (!visible[j]) continue;
    L->middleRows<3>(rows) = LegDirectionInteractionMatrixAtCameraOrigin(p_C_A[j], u_C[j], q[j]);
    e->segment<3>(rows) = u_C[j] - u_C_star[j];
    rows += 3;
  }
  return rows;
}

// vpServo and its features: one vpGenericFeature of dimension 3 per visible leg (a single
// 18-row feature does not work: vpBasicFeature::FEATURE_ALL selects only 16 rows). The task is
// rebuilt when the set of visible legs changes (rare: a leg lost or found).
struct LegServo::Impl {
  LegMask mask{};
  bool built = false;
  std::array<std::unique_ptr<vpGenericFeature>, kHexapodLegs> s, s_star;
  std::unique_ptr<vpServo> task;  // declared after the features: destroyed before them
  vpMatrix L = vpMatrix(3, 6);

  Impl() {
    for (int j = 0; j < kHexapodLegs; ++j) {
      s[j] = std::make_unique<vpGenericFeature>(3);
      s_star[j] = std::make_unique<vpGenericFeature>(3);
    }
  }

  void Build(const LegMask& visible, const LegServoOptions& options) {
    task = std::make_unique<vpServo>();
    // EYEINHAND_CAMERA: the task Jacobian is L itself (cVe = eJe = I, sign +1), so
    // computeControlLaw() returns exactly −λ L⁺ (s − s*) in the frame of our L: the platform
    // twist in C at C's origin. (The eye-to-hand modes flip the sign of L; our L already maps
    // the platform's twist, so that flip must not be applied.)
    task->setServo(vpServo::EYEINHAND_CAMERA);
    task->setInteractionMatrixType(vpServo::CURRENT, vpServo::PSEUDO_INVERSE);
    if (options.adaptive_gain) {
      task->setLambda(
          vpAdaptiveGain(options.gain_at_zero, options.gain_at_infinity, options.slope_at_zero));
    } else {
      task->setLambda(options.gain);
    }
    for (int j = 0; j < kHexapodLegs; ++j) {
      if (visible[j]) task->addFeature(*s[j], *s_star[j]);
    }
    mask = visible;
    built = true;
  }
};

LegServo::LegServo(const LegPoints& p_C_A, const LegServoOptions& options)
    : p_C_A_(p_C_A), options_(options), impl_(std::make_unique<Impl>()) {
  std::string message = options.Validate();
  for (int j = 0; j < kHexapodLegs; ++j) {
    if (!p_C_A[j].allFinite()) {
      if (!message.empty()) message += "; ";
      message += "p_C_A[" + std::to_string(j) + "]: must be finite";
    }
  }
  if (!message.empty()) throw std::invalid_argument("LegServo: " + message);
}

LegServo::~LegServo() = default;

void LegServo::SetDesired(const LegDirections& u_C_star) {
  std::string message;
  for (int j = 0; j < kHexapodLegs; ++j) {
    if (!IsUnit(u_C_star[j])) {
      std::ostringstream out;
      out << (message.empty() ? "" : "; ") << "u_C_star[" << j
          << "]: must be a finite unit vector, got norm " << u_C_star[j].norm();
      message += out.str();
    }
  }
  if (!message.empty()) throw std::invalid_argument("LegServo::SetDesired: " + message);
  u_star_ = u_C_star;
  has_desired_ = true;
}

void LegServo::Reset() {
  seen_ = {};
  last_seen_ = {};
}

LegServoResult LegServo::Compute(const LegDirections& u_C, const LegMask& visible,
                                 const Vector6d& q) {
  LegServoResult result;
  for (auto& v : result.error) v.setZero();
  if (!has_desired_ || !q.allFinite() || (q.array() <= 0).any()) return result;
  for (int j = 0; j < kHexapodLegs; ++j) {
    if (!visible[j]) continue;
    if (!IsUnit(u_C[j])) return result;
    ++result.visible_legs;
  }
  for (int j = 0; j < kHexapodLegs; ++j) {
    if (!visible[j]) continue;
    last_seen_[j] = u_C[j];
    seen_[j] = true;
    result.error[j] = u_C[j] - u_star_[j];
  }
  Eigen::Matrix<double, 18, 6> L;
  Eigen::Matrix<double, 18, 1> e;
  const int rows = StackLegServoTask(p_C_A_, u_C, u_star_, visible, q, &L, &e);
  result.error_norm = e.head(rows).norm();
  if (result.visible_legs < options_.min_visible_legs) {
    result.status = LegServoStatus::kTooFewLegs;
    return result;
  }
  // D_inv needs a direction for every leg, the hidden ones included: their last measured one.
  LegDirections u_for_dinv;
  for (int j = 0; j < kHexapodLegs; ++j) {
    if (visible[j]) {
      u_for_dinv[j] = u_C[j];
    } else if (seen_[j]) {
      u_for_dinv[j] = last_seen_[j];
      result.stale_direction[j] = true;
    } else {
      result.status = LegServoStatus::kNoDirection;
      return result;
    }
  }

  if (!impl_->built || impl_->mask != visible) impl_->Build(visible, options_);
  for (int j = 0; j < kHexapodLegs; ++j) {
    if (!visible[j]) continue;
    const Matrix36d Lj = LegDirectionInteractionMatrixAtCameraOrigin(p_C_A_[j], u_C[j], q[j]);
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 6; ++c) impl_->L[r][c] = Lj(r, c);
    }
    impl_->s[j]->set_s(u_C[j].x(), u_C[j].y(), u_C[j].z());
    impl_->s[j]->setInteractionMatrix(impl_->L);
    impl_->s_star[j]->set_s(u_star_[j].x(), u_star_[j].y(), u_star_[j].z());
  }
  vpColVector tau;
  try {
    tau = impl_->task->computeControlLaw();
  } catch (const std::exception&) {
    result.status = LegServoStatus::kInvalidInput;
    return result;
  }
  result.rank = static_cast<int>(impl_->task->getTaskRank());
  if (result.rank < 6) {
    result.status = LegServoStatus::kRankDeficient;
    return result;
  }
  for (int k = 0; k < 6; ++k) result.twist_C[k] = tau[k];
  {
    // L⁺e at C's origin, moved to the platform centre: δp_c = δp_0 + δθ × c.
    const vpColVector d = impl_->task->getTaskJacobianPseudoInverse() * impl_->task->getError();
    Eigen::Vector3d c = Eigen::Vector3d::Zero();
    for (int j = 0; j < kHexapodLegs; ++j) c += p_C_A_[j] + q[j] * u_for_dinv[j];
    c /= kHexapodLegs;
    const Eigen::Vector3d dp(d[0], d[1], d[2]);
    const Eigen::Vector3d dtheta(d[3], d[4], d[5]);
    result.remaining_displacement << dp + dtheta.cross(c), dtheta;
  }
  result.q_dot = InverseDifferentialAtCameraOrigin(p_C_A_, u_for_dinv) * result.twist_C;
  result.status = LegServoStatus::kOk;
  return result;
}

}  // namespace kinevis::control
