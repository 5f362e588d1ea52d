#include "control/weld/torch_ik.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>

#include "common/so3.h"

namespace kinevis::control {
namespace {

using robots::Vector5d;
using Matrix35 = Eigen::Matrix<double, 3, 5>;
using Matrix25 = Eigen::Matrix<double, 2, 5>;
using Matrix5d = Eigen::Matrix<double, 5, 5>;

double WrapToPi(double x) {
  const double y = std::remainder(x, 2.0 * M_PI);
  return y <= -M_PI ? y + 2.0 * M_PI : y;
}

// Damped pseudo-inverse of a wide matrix A (m×5): Aᵀ (A Aᵀ + λ² I)⁻¹.
template <int M>
Eigen::Matrix<double, 5, M> DampedPinv(const Eigen::Matrix<double, M, 5>& A, double lambda) {
  Eigen::Matrix<double, M, M> G = A * A.transpose();
  G.diagonal().array() += lambda * lambda + 1e-14;
  return A.transpose() * G.ldlt().solve(Eigen::Matrix<double, M, M>::Identity());
}

struct Run {
  bool position_ok = false;
  Vector5d q = Vector5d::Zero();
  double position_error = 0.0, tilt = 0.0;
  Eigen::Vector3d p = Eigen::Vector3d::Zero(), u = Eigen::Vector3d::UnitZ();
  int iterations = 0;
};

// Weight of the axis residual against the wire point's (m/rad): small, so the position wins
// (at the optimum |r_w| ≈ μ² · tilt / lever ≈ 1e-13 m with the arm's ~0.5 m lever), large enough
// to keep the 5×5 normal equations well conditioned.
constexpr double kAxisWeight = 1e-3;

struct Eval {
  Eigen::Vector3d r_w = Eigen::Vector3d::Zero();
  Eigen::Vector2d r_a = Eigen::Vector2d::Zero();
  double angle = 0.0;
  double cost = 0.0;
  Matrix35 J_w;
  Matrix25 J_a;
  Eigen::Vector3d p = Eigen::Vector3d::Zero(), u = Eigen::Vector3d::UnitZ();
};

void Evaluate(const robots::Weld5Model& model, const Vector5d& q, const Eigen::Vector3d& p_W,
              const Eigen::Vector3d& u_t, double d, Eval* e) {
  robots::Weld5Data data;
  robots::Weld5ForwardKinematics(model, q, &data);
  const Eigen::Vector3d& u = data.u_0T;
  e->p = data.p_0T;
  e->u = u;
  e->r_w = p_W - (data.p_0T + d * u);
  const Eigen::Vector3d c = u.cross(u_t);
  e->angle = std::atan2(c.norm(), u.dot(u_t));
  const Eigen::Vector3d e1 = u.unitOrthogonal(), e2 = u.cross(e1);
  const Eigen::Vector3d eps = c.norm() > 1e-12 ? Eigen::Vector3d(e->angle * c.normalized())
                                               : Eigen::Vector3d(e->angle * e1);
  e->r_a = Eigen::Vector2d(e1.dot(eps), e2.dot(eps));
  e->J_w = data.J.topRows<3>() - d * common::Skew(u) * data.J.bottomRows<3>();
  e->J_a.row(0) = e1.transpose() * data.J.bottomRows<3>();
  e->J_a.row(1) = e2.transpose() * data.J.bottomRows<3>();
  e->cost = e->r_w.squaredNorm() + kAxisWeight * kAxisWeight * e->r_a.squaredNorm();
}

// Levenberg–Marquardt on [r_w; μ r_a], then Gauss–Newton steps on r_w alone (minimum norm) to
// put the wire point on p_W to the tolerance whatever tilt remains.
Run RunPriority(const robots::Weld5Model& model, const Eigen::Vector3d& p_W,
                const Eigen::Vector3d& u_t, double d, const Vector5d& guess,
                const TorchIkOptions& o, bool clamp) {
  Run run;
  Vector5d q = guess;
  if (clamp) q = q.cwiseMax(model.q_min).cwiseMin(model.q_max);
  Eval e, trial;
  Evaluate(model, q, p_W, u_t, d, &e);
  int it = 0;
  // Where the axis is reachable exactly, Gauss–Newton on the unweighted 5×5 system converges
  // quadratically from a warm start: a few steps of it first.
  for (int k = 0; k < 12; ++k, ++it) {
    if (e.r_w.norm() <= o.position_tolerance && e.angle <= o.axis_tolerance) break;
    Eigen::Matrix<double, 5, 5> J;
    J.topRows<3>() = e.J_w;
    J.bottomRows<2>() = e.J_a;
    Eigen::Matrix<double, 5, 1> r;
    r << e.r_w, e.r_a;
    Matrix5d M = J * J.transpose();
    M.diagonal().array() += o.damping * o.damping + 1e-14;
    Vector5d dq = J.transpose() * M.ldlt().solve(r);
    const double m = dq.cwiseAbs().maxCoeff();
    if (m > o.max_step) dq *= o.max_step / m;
    Vector5d q_new = q + dq;
    if (clamp) q_new = q_new.cwiseMax(model.q_min).cwiseMin(model.q_max);
    Evaluate(model, q_new, p_W, u_t, d, &trial);
    if (trial.r_w.squaredNorm() + trial.r_a.squaredNorm() >=
        e.r_w.squaredNorm() + e.r_a.squaredNorm()) {
      break;
    }
    q = q_new;
    e = trial;
  }
  double lambda = 1e-6;
  for (; it < o.max_iterations; ++it) {
    if (e.r_w.norm() <= o.position_tolerance && e.angle <= o.axis_tolerance) break;
    Eigen::Matrix<double, 5, 5> J;
    J.topRows<3>() = e.J_w;
    J.bottomRows<2>() = kAxisWeight * e.J_a;
    Eigen::Matrix<double, 5, 1> r;
    r << e.r_w, kAxisWeight * e.r_a;
    const Matrix5d A = J.transpose() * J;
    const Vector5d g = J.transpose() * r;
    bool accepted = false;
    double step_size = 0.0;
    for (int tries = 0; tries < 10 && !accepted; ++tries) {
      Matrix5d M = A;
      M.diagonal() += lambda * (A.diagonal() + Vector5d::Constant(o.damping * o.damping + 1e-12));
      Vector5d dq = M.ldlt().solve(g);
      const double m = dq.cwiseAbs().maxCoeff();
      if (m > o.max_step) dq *= o.max_step / m;
      Vector5d q_new = q + dq;
      if (clamp) q_new = q_new.cwiseMax(model.q_min).cwiseMin(model.q_max);
      Evaluate(model, q_new, p_W, u_t, d, &trial);
      if (trial.cost < e.cost) {
        step_size = (q_new - q).cwiseAbs().maxCoeff();
        // The tilt settles at its attainable minimum: stop once the wire point is on target and
        // a step changes the tilt by less than 1e-7 rad.
        if (trial.r_w.norm() <= o.position_tolerance && std::abs(trial.angle - e.angle) < 1e-7) {
          step_size = 0.0;
        }
        q = q_new;
        e = trial;
        lambda = std::max(lambda / 10.0, 1e-15);
        accepted = true;
      } else {
        lambda *= 10.0;
      }
    }
    // No descent left (or steps below round-off): at the attainable minimum of the tilt.
    if (!accepted || step_size < 1e-13) break;
  }
  for (int k = 0; k < 5 && e.r_w.norm() > 1e-3 * o.position_tolerance; ++k) {
    const Vector5d dq = DampedPinv<3>(e.J_w, 1e-9) * e.r_w;
    Vector5d q_new = q + dq;
    if (clamp) q_new = q_new.cwiseMax(model.q_min).cwiseMin(model.q_max);
    Evaluate(model, q_new, p_W, u_t, d, &trial);
    if (trial.r_w.norm() >= e.r_w.norm()) break;
    q = q_new;
    e = trial;
  }
  run.q = q;
  run.iterations = it;
  run.position_error = e.r_w.norm();
  run.tilt = e.angle;
  run.p = e.p;
  run.u = e.u;
  run.position_ok = run.position_error <= o.position_tolerance;
  return run;
}

}  // namespace

Eigen::Vector3d WirePoint(const robots::Weld5Model& model, const robots::Vector5d& q, double d,
                          Eigen::Matrix<double, 3, 5>* J_w) {
  robots::Weld5Data data;
  robots::Weld5ForwardKinematics(model, q, &data);
  if (J_w != nullptr) {
    *J_w = data.J.topRows<3>() - d * common::Skew(data.u_0T) * data.J.bottomRows<3>();
  }
  return data.p_0T + d * data.u_0T;
}

TorchIkResult SolveTorchIk(const robots::Weld5Model& model, const Eigen::Vector3d& p_0W,
                           const Eigen::Vector3d& u_target, double d,
                           const robots::Vector5d& q_guess, const TorchIkOptions& o) {
  const Eigen::Vector3d u_t = u_target.normalized();
  TorchIkResult result;
  auto accept = [&](const Run& r) {
    return r.position_ok && r.tilt <= o.max_tilt + o.axis_tolerance;
  };
  auto fill = [&](const Run& r) {
    result.q = r.q;
    result.position_error = r.position_error;
    result.tilt = r.tilt;
    result.p_0T = r.p;
    result.u_0T = r.u;
    result.iterations = r.iterations;
  };
  const int starts = 1 + std::clamp(o.extra_starts, 0, 7);
  for (int k = 0; k < starts; ++k) {
    Vector5d q0 = q_guess;
    q0(0) = WrapToPi(q_guess(0) + (k % 4) * 0.5 * M_PI);
    if (k >= 4) {
      q0(1) = std::abs(q_guess(1)) > 0.2 ? -q_guess(1) : q_guess(1) + 0.8;
      q0(3) = std::abs(q_guess(3)) > 0.2 ? -q_guess(3) : q_guess(3) - 0.8;
    }
    const Run r = RunPriority(model, p_0W, u_t, d, q0, o, true);
    if (k == 0) fill(r);
    if (accept(r)) {
      fill(r);
      result.status = robots::Weld5IkStatus::kConverged;
      return result;
    }
  }
  // Would the arm reach it outside its limits?
  Run free = RunPriority(model, p_0W, u_t, d, q_guess, o, false);
  if (accept(free)) {
    Vector5d q = free.q;
    for (int i = 0; i < robots::kWeld5Joints; ++i) {
      if (!model.joints[i].prismatic) q(i) = WrapToPi(q(i));
    }
    for (int i = 0; i < robots::kWeld5Joints; ++i) {
      if (q(i) < model.q_min(i) || q(i) > model.q_max(i)) {
        result.status = robots::Weld5IkStatus::kJointLimit;
        result.limiting_joint = i;
        return result;
      }
    }
    // The unclamped solve found an in-limit solution the clamped ones missed.
    fill(free);
    result.q = q;
    result.status = robots::Weld5IkStatus::kConverged;
    return result;
  }
  result.status = robots::Weld5IkStatus::kNotReachable;
  return result;
}

}  // namespace kinevis::control
