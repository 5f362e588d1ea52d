#include "robots/weld5/weld5_model.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>

#include "common/config_error.h"
#include "common/units.h"

namespace kinevis::robots {
namespace {

Weld5Model MakeModel(double alpha1, double a1, double theta1_offset, double theta2_offset,
                     const Eigen::Isometry3d& X_5T) {
  Weld5Model m;
  // seed 004 §4.1 and README numbers; links 3–5 from the structure of eq. (35)–(46).
  m.joints[0] = DhJoint{a1, alpha1, 0.275, theta1_offset, false};
  m.joints[1] = DhJoint{0.033389, 90.0 * common::kDeg, 0.104718, theta2_offset, false};
  m.joints[2] = DhJoint{0.0, -90.0 * common::kDeg, 0.0, 0.0, true};
  m.joints[3] = DhJoint{0.0, 90.0 * common::kDeg, 0.0, 0.0, false};
  m.joints[4] = DhJoint{0.0, 0.0, 0.0, 0.0, false};
  // The same limits as the weld-robot simulator's defaults and robots/weld5/weld5.yaml.
  m.q_min << -170.0 * common::kDeg, -120.0 * common::kDeg, 0.0, -180.0 * common::kDeg,
      -120.0 * common::kDeg;
  m.q_max << 170.0 * common::kDeg, 120.0 * common::kDeg, 0.50, 180.0 * common::kDeg,
      120.0 * common::kDeg;
  m.qd_max << 90.0 * common::kDeg, 90.0 * common::kDeg, 0.05, 90.0 * common::kDeg,
      90.0 * common::kDeg;
  m.X_5T = X_5T;
  return m;
}

double WrapToPi(double x) {
  const double y = std::remainder(x, 2.0 * common::kPi);
  return y <= -common::kPi ? y + 2.0 * common::kPi : y;
}

struct Residual {
  Eigen::Matrix<double, 5, 1> r;
  Eigen::Matrix<double, 5, 5> J;  // d r / d q with the sign of "desired motion" (r ≈ J Δq)
  double position_error;
  double axis_error;
};

Residual ComputeResidual(const Weld5Model& model, const Vector5d& q, const Eigen::Vector3d& p_t,
                         const Eigen::Vector3d& u_t, Weld5Data* data) {
  Weld5ForwardKinematics(model, q, data);
  Residual res;
  const Eigen::Vector3d dp = p_t - data->p_0T;
  const Eigen::Vector3d& u = data->u_0T;
  // Basis of the plane ⊥ u: roll about u is the free sixth direction and is left out.
  const Eigen::Vector3d e1 = u.unitOrthogonal();
  const Eigen::Vector3d e2 = u.cross(e1);
  const Eigen::Vector3d c = u.cross(u_t);
  const double angle = std::atan2(c.norm(), u.dot(u_t));
  // Rotation vector taking u to u_t; for antiparallel axes any axis ⊥ u will do.
  const Eigen::Vector3d eps =
      c.norm() > 1e-12 ? Eigen::Vector3d(angle * c.normalized()) : Eigen::Vector3d(angle * e1);
  res.r.head<3>() = dp;
  res.r(3) = e1.dot(eps);
  res.r(4) = e2.dot(eps);
  res.J.topRows<3>() = data->J.topRows<3>();
  res.J.row(3) = e1.transpose() * data->J.bottomRows<3>();
  res.J.row(4) = e2.transpose() * data->J.bottomRows<3>();
  res.position_error = dp.norm();
  res.axis_error = angle;
  return res;
}

struct Solve {
  bool converged = false;
  int iterations = 0;
  Vector5d q = Vector5d::Zero();
  double position_error = 0.0;
  double axis_error = 0.0;
};

Solve RunDls(const Weld5Model& model, const Eigen::Vector3d& p_t, const Eigen::Vector3d& u_t,
             const Vector5d& q_guess, const Weld5IkOptions& o, bool enforce_limits) {
  Solve s;
  Weld5Data data;
  Vector5d q = q_guess;
  if (enforce_limits) q = q.cwiseMax(model.q_min).cwiseMin(model.q_max);
  for (int it = 0; it <= o.max_iterations; ++it) {
    const Residual res = ComputeResidual(model, q, p_t, u_t, &data);
    s.q = q;
    s.iterations = it;
    s.position_error = res.position_error;
    s.axis_error = res.axis_error;
    if (res.position_error <= o.position_tolerance && res.axis_error <= o.axis_tolerance) {
      s.converged = true;
      return s;
    }
    if (it == o.max_iterations) break;
    // Damped least squares: Δq = Jᵀ (J Jᵀ + λ² I)⁻¹ r. λ shrinks with the residual
    // (Levenberg's rule, λ = damping · min(1, |r| / 1 cm)): full damping far from the target keeps
    // steps sane near singular poses, and near it the iteration becomes Gauss–Newton, so a nearly
    // singular pose still converges in a few steps instead of crawling at λ²/(σ² + λ²) per step.
    const double lambda = o.damping * std::min(1.0, res.r.norm() / 0.01);
    const Eigen::Matrix<double, 5, 5> A =
        res.J * res.J.transpose() + (lambda * lambda) * Eigen::Matrix<double, 5, 5>::Identity();
    Vector5d dq = res.J.transpose() * A.ldlt().solve(res.r);
    const double m = dq.cwiseAbs().maxCoeff();
    if (m > o.max_step) dq *= o.max_step / m;
    q += dq;
    if (enforce_limits) q = q.cwiseMax(model.q_min).cwiseMin(model.q_max);
  }
  return s;
}

}  // namespace

Weld5Model Weld5Model::Seed(const Eigen::Isometry3d& X_5T) {
  return MakeModel(-89.827 * common::kDeg, -0.059e-3, 0.1097 * common::kDeg, 89.602 * common::kDeg,
                   X_5T);
}

Weld5Model Weld5Model::Ideal(const Eigen::Isometry3d& X_5T) {
  return MakeModel(-90.0 * common::kDeg, 0.0, 0.0, 0.0, X_5T);
}

std::string Weld5Model::Validate() const {
  common::Problems p;
  for (int i = 0; i < kWeld5Joints; ++i) {
    const std::string name = Weld5JointName(i);
    const DhJoint& j = joints[i];
    p.Finite(name + ".a", j.a);
    p.Finite(name + ".alpha", j.alpha);
    p.Finite(name + ".d", j.d);
    p.Finite(name + ".theta_offset", j.theta_offset);
    p.Finite(name + ".q_min", q_min(i));
    p.Finite(name + ".q_max", q_max(i));
    if (std::isfinite(q_min(i)) && std::isfinite(q_max(i)) && !(q_min(i) < q_max(i))) {
      p.Add(name + ".limits: need q_min < q_max, got [" + common::Num(q_min(i)) + ", " +
            common::Num(q_max(i)) + "]");
    }
    p.Positive(name + ".qd_max", qd_max(i));
  }
  const Eigen::Matrix4d& X = X_5T.matrix();
  if (!X.allFinite()) {
    p.Add("X_5T: must be finite");
  } else {
    const Eigen::Matrix3d R = X_5T.linear();
    const double orthogonality = (R.transpose() * R - Eigen::Matrix3d::Identity()).norm();
    if (orthogonality > 1e-9 || R.determinant() < 0.0) {
      p.Add("X_5T.linear: must be a rotation, got |RᵀR − I| = " + common::Num(orthogonality) +
            ", det = " + common::Num(R.determinant()));
    }
  }
  return p.Message();
}

Eigen::Isometry3d Weld5TorchTransform(double px5, double pz5, double beta) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = Eigen::AngleAxisd(beta, Eigen::Vector3d::UnitY()).toRotationMatrix();
  X.translation() = Eigen::Vector3d(px5, 0.0, pz5);
  return X;
}

void Weld5ForwardKinematics(const Weld5Model& model, const Vector5d& q, Weld5Data* data) {
  data->X_0T = DhForwardKinematics(model.joints, q, &data->X_0L) * model.X_5T;
  data->p_0T = data->X_0T.translation();
  data->u_0T = data->X_0T.linear().col(2);
  const Eigen::Vector3d& p_T = data->p_0T;
  for (int i = 0; i < kWeld5Joints; ++i) {
    const Eigen::Vector3d z =
        i == 0 ? Eigen::Vector3d::UnitZ() : Eigen::Vector3d(data->X_0L[i - 1].linear().col(2));
    const Eigen::Vector3d o =
        i == 0 ? Eigen::Vector3d::Zero() : Eigen::Vector3d(data->X_0L[i - 1].translation());
    if (model.joints[i].prismatic) {
      data->J.block<3, 1>(0, i) = z;
      data->J.block<3, 1>(3, i).setZero();
    } else {
      data->J.block<3, 1>(0, i) = z.cross(p_T - o);
      data->J.block<3, 1>(3, i) = z;
    }
  }
}

const char* ToString(Weld5IkStatus status) {
  switch (status) {
    case Weld5IkStatus::kConverged:
      return "converged";
    case Weld5IkStatus::kNotReachable:
      return "not reachable";
    case Weld5IkStatus::kJointLimit:
      return "joint limit";
  }
  return "unknown";
}

const char* Weld5JointName(int joint) {
  static constexpr const char* kNames[kWeld5Joints] = {"theta1", "theta2", "pz3", "theta4",
                                                       "theta5"};
  return joint >= 0 && joint < kWeld5Joints ? kNames[joint] : "";
}

Weld5IkResult Weld5InverseKinematics(const Weld5Model& model, const Eigen::Vector3d& p_0T_target,
                                     const Eigen::Vector3d& u_0T_target, const Vector5d& q_guess,
                                     const Weld5IkOptions& options) {
  const Eigen::Vector3d u_t = u_0T_target.normalized();
  Weld5IkResult result;
  // DLS is local: besides the caller's guess, try the other branches of the arm (base turned by
  // multiples of 90°, shoulder mirrored). Only reached when the guess itself fails.
  const int starts = 1 + std::clamp(options.extra_starts, 0, 7);
  bool have_free = false;
  Solve free_first;
  for (int k = 0; k < starts; ++k) {
    Vector5d q0 = q_guess;
    q0(0) = WrapToPi(q_guess(0) + (k % 4) * 0.5 * common::kPi);
    if (k >= 4) {
      // Mirror the shoulder and wrist; a guess at (near) zero is moved off it first.
      q0(1) = std::abs(q_guess(1)) > 0.2 ? -q_guess(1) : q_guess(1) + 0.8;
      q0(3) = std::abs(q_guess(3)) > 0.2 ? -q_guess(3) : q_guess(3) - 0.8;
    }
    const Solve limited = RunDls(model, p_0T_target, u_t, q0, options, true);
    if (k == 0) {
      result.q = limited.q;
      result.iterations = limited.iterations;
      result.position_error = limited.position_error;
      result.axis_error = limited.axis_error;
    }
    if (limited.converged) {
      result.status = Weld5IkStatus::kConverged;
      result.q = limited.q;
      result.iterations = limited.iterations;
      result.position_error = limited.position_error;
      result.axis_error = limited.axis_error;
      return result;
    }
    if (!have_free) {
      const Solve free = RunDls(model, p_0T_target, u_t, q0, options, false);
      if (free.converged) {
        have_free = true;
        free_first = free;
      }
    }
  }
  if (!have_free) {
    result.status = Weld5IkStatus::kNotReachable;
    return result;
  }
  Vector5d q = free_first.q;
  for (int i = 0; i < kWeld5Joints; ++i) {
    if (!model.joints[i].prismatic) q(i) = WrapToPi(q(i));
  }
  for (int i = 0; i < kWeld5Joints; ++i) {
    if (q(i) < model.q_min(i) || q(i) > model.q_max(i)) {
      result.status = Weld5IkStatus::kJointLimit;
      result.limiting_joint = i;
      result.limiting_joint_name = Weld5JointName(i);
      return result;
    }
  }
  // An unclamped solve found an in-limit solution the clamped ones missed: report it.
  result.status = Weld5IkStatus::kConverged;
  result.q = q;
  result.iterations = free_first.iterations;
  result.position_error = free_first.position_error;
  result.axis_error = free_first.axis_error;
  return result;
}

}  // namespace kinevis::robots
