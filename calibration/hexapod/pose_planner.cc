#include "calibration/hexapod/pose_planner.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <random>
#include <sstream>
#include <stdexcept>

#include "common/config_error.h"
#include "common/units.h"
#include "vision/camera/camera_model.h"
#include "vision/render/scenes/hexapod_scene.h"

namespace kinevis::calibration {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

// Uniform and normal draws written out on top of std::mt19937_64 (whose output sequence the
// standard fixes), so a plan is the same for a seed on every standard library.
class Draw {
 public:
  explicit Draw(uint64_t seed) : engine_(seed) {}
  double Uniform() { return static_cast<double>(engine_() >> 11) * 0x1.0p-53; }  // [0, 1)
  double Normal() {                                                              // Box–Muller
    const double u1 = 1.0 - Uniform();                                           // (0, 1]
    const double u2 = Uniform();
    return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * common::kPi * u2);
  }

 private:
  std::mt19937_64 engine_;
};

Eigen::Isometry3d PoseAlong(const Eigen::Isometry3d& X_BP_nominal, const robots::Vector6d& dir,
                            double t, const PosePlannerOptions& o) {
  Eigen::Isometry3d X = X_BP_nominal;
  X.translation() += t * o.translation_scale * dir.head<3>();
  const Eigen::Vector3d rotation = t * o.rotation_scale * dir.tail<3>();
  const double angle = rotation.norm();
  if (angle > 0.0) {
    X.linear() =
        Eigen::AngleAxisd(angle, rotation / angle).toRotationMatrix() * X_BP_nominal.linear();
  }
  return X;
}

bool Admissible(const robots::HexapodModel& model, const Eigen::Isometry3d& X_BP,
                const PosePlannerOptions& o) {
  if (!PoseIsAdmissible(model, X_BP, o)) return false;
  return !o.admissible || o.admissible(X_BP);
}

// Unit leg directions of an IK solution (u_B), as an array.
using Directions = std::array<Eigen::Vector3d, robots::kHexapodLegs>;

// Largest over legs of u_a · u_b: the smallest per-leg angle is acos of it.
double MaxDot(const Directions& a, const Directions& b) {
  double m = -1.0;
  for (int j = 0; j < robots::kHexapodLegs; ++j) m = std::max(m, a[j].dot(b[j]));
  return m;
}

}  // namespace

std::string PosePlannerOptions::Validate() const {
  common::Problems problems;
  const auto add = [&problems](const char* name, double value, const char* rule) {
    problems.Add(name, value, rule);
  };
  if (poses < 2) add("poses", poses, "must be >= 2");
  if (candidates < poses) add("candidates", candidates, "must be >= poses");
  if (!X_BP_nominal.matrix().allFinite()) add("X_BP_nominal", kNaN, "must be finite");
  if (!(std::isfinite(translation_scale) && translation_scale > 0.0)) {
    add("translation_scale", translation_scale, "must be finite and > 0");
  }
  if (!(std::isfinite(rotation_scale) && rotation_scale > 0.0)) {
    add("rotation_scale", rotation_scale, "must be finite and > 0");
  }
  if (!(std::isfinite(stroke_margin) && stroke_margin >= 0.0)) {
    add("stroke_margin", stroke_margin, "must be finite and >= 0");
  }
  if (!(std::isfinite(collision_margin) && collision_margin >= 0.0)) {
    add("collision_margin", collision_margin, "must be finite and >= 0");
  }
  if (!(max_jacobian_condition >= 1.0)) {
    add("max_jacobian_condition", max_jacobian_condition, "must be >= 1");
  }
  if (X_CB && !X_CB->matrix().allFinite()) add("X_CB", kNaN, "must be finite when set");
  return problems.Message();
}

double SegmentSegmentDistance(const Eigen::Vector3d& p0, const Eigen::Vector3d& p1,
                              const Eigen::Vector3d& q0, const Eigen::Vector3d& q1) {
  // Closest points p0 + s d1, q0 + t d2 with s, t in [0, 1]: minimise over s for the clamped
  // t(s), the standard case analysis (Ericson, Real-Time Collision Detection §5.1.9).
  const Eigen::Vector3d d1 = p1 - p0, d2 = q1 - q0, r = p0 - q0;
  const double a = d1.squaredNorm(), e = d2.squaredNorm(), f = d2.dot(r);
  double s = 0.0, t = 0.0;
  if (a <= 1e-300 && e <= 1e-300) return r.norm();
  if (a <= 1e-300) {
    t = std::clamp(f / e, 0.0, 1.0);
  } else {
    const double c = d1.dot(r);
    if (e <= 1e-300) {
      s = std::clamp(-c / a, 0.0, 1.0);
    } else {
      const double b = d1.dot(d2);
      const double denom = a * e - b * b;  // >= 0, 0 when parallel
      s = denom > 1e-300 ? std::clamp((b * f - c * e) / denom, 0.0, 1.0) : 0.0;
      t = (b * s + f) / e;
      if (t < 0.0) {
        t = 0.0;
        s = std::clamp(-c / a, 0.0, 1.0);
      } else if (t > 1.0) {
        t = 1.0;
        s = std::clamp((b - c) / a, 0.0, 1.0);
      }
    }
  }
  return ((p0 + s * d1) - (q0 + t * d2)).norm();
}

bool PoseIsAdmissible(const robots::HexapodModel& model, const Eigen::Isometry3d& X_BP,
                      const PosePlannerOptions& o) {
  robots::HexapodData data;
  robots::InverseKinematics(model, X_BP, &data);
  for (int j = 0; j < robots::kHexapodLegs; ++j) {
    const double q = data.q(j);
    if (!(q >= model.leg_length_min + o.stroke_margin &&
          q <= model.leg_length_max - o.stroke_margin)) {
      return false;
    }
  }
  const double clearance = 2.0 * model.leg_radius + o.collision_margin;
  for (int j = 0; j < robots::kHexapodLegs; ++j) {
    for (int k = j + 1; k < robots::kHexapodLegs; ++k) {
      if (!(SegmentSegmentDistance(model.p_B_A[j], data.p_B_B[j], model.p_B_A[k], data.p_B_B[k]) >
            clearance)) {
        return false;
      }
    }
  }
  return robots::ConditionNumber(robots::InverseDifferential(data)) <= o.max_jacobian_condition;
}

HexapodCalibrationData PredictCalibrationData(const robots::HexapodModel& model,
                                              const Eigen::Isometry3d& X_CB,
                                              const std::vector<Eigen::Isometry3d>& X_BP) {
  HexapodCalibrationData out;
  out.leg_radius = model.leg_radius;
  out.configurations.resize(X_BP.size());
  robots::HexapodData data;
  for (size_t k = 0; k < X_BP.size(); ++k) {
    robots::InverseKinematics(model, X_BP[k], &data);
    for (int j = 0; j < robots::kHexapodLegs; ++j) {
      LegLimbs limbs;
      if (vision::render::PredictCylinderLimbs(X_CB * model.p_B_A[j], X_CB * data.p_B_B[j],
                                               model.leg_radius, &limbs.n1_C, &limbs.n2_C)) {
        out.configurations[k][j] = limbs;
      }
    }
  }
  return out;
}

std::array<LegSpread, robots::kHexapodLegs> EvaluatePoseSpread(
    const robots::HexapodModel& model, const std::vector<Eigen::Isometry3d>& X_BP,
    const std::optional<Eigen::Isometry3d>& X_CB) {
  std::array<LegSpread, robots::kHexapodLegs> out{};
  std::array<std::vector<Eigen::Vector3d>, robots::kHexapodLegs> u;
  robots::HexapodData data;
  for (const Eigen::Isometry3d& X : X_BP) {
    robots::InverseKinematics(model, X, &data);
    for (int j = 0; j < robots::kHexapodLegs; ++j) {
      if (data.q(j) > 0.0) u[j].push_back(data.u_B[j]);
    }
  }
  for (int j = 0; j < robots::kHexapodLegs; ++j) {
    double min_dot = 1.0;
    Eigen::Matrix3d m = Eigen::Matrix3d::Zero();
    for (size_t a = 0; a < u[j].size(); ++a) {
      m += Eigen::Matrix3d::Identity() - u[j][a] * u[j][a].transpose();
      for (size_t b = a + 1; b < u[j].size(); ++b)
        min_dot = std::min(min_dot, u[j][a].dot(u[j][b]));
    }
    out[j].max_angle = std::acos(std::clamp(min_dot, -1.0, 1.0));
    out[j].direction_spread =
        u[j].empty() ? 0.0
                     : Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(
                           m / static_cast<double>(u[j].size()), Eigen::EigenvaluesOnly)
                           .eigenvalues()(0);
  }
  if (X_CB) {
    const HexapodCalibrationData predicted = PredictCalibrationData(model, *X_CB, X_BP);
    for (int j = 0; j < robots::kHexapodLegs; ++j) {
      std::vector<Eigen::Vector3d> rows;
      for (const auto& configuration : predicted.configurations) {
        if (!configuration[j]) continue;
        rows.push_back(configuration[j]->n1_C);
        rows.push_back(configuration[j]->n2_C);
      }
      if (rows.size() < 4) {
        out[j].condition_number = kInf;
        continue;
      }
      Eigen::MatrixX3d jm(rows.size(), 3);
      for (size_t i = 0; i < rows.size(); ++i) jm.row(static_cast<long>(i)) = rows[i];
      const Eigen::Vector3d sv = Eigen::JacobiSVD<Eigen::MatrixX3d>(jm).singularValues();
      out[j].condition_number = sv(2) > 0.0 ? sv(0) / sv(2) : kInf;
    }
  }
  return out;
}

PosePlan PlanCalibrationPoses(const robots::HexapodModel& model,
                              const PosePlannerOptions& options) {
  {
    std::string bad = options.Validate();
    const std::string bad_model = model.Validate();
    if (!bad_model.empty()) bad += (bad.empty() ? "model: " : "; model: ") + bad_model;
    if (bad.empty() && !Admissible(model, options.X_BP_nominal, options)) {
      bad =
          "X_BP_nominal is not admissible (out of stroke with the margin, legs in collision, "
          "near a singularity, or refused by the admissible predicate)";
    }
    if (!bad.empty()) throw std::invalid_argument("PlanCalibrationPoses: " + bad);
  }
  PosePlan plan;
  Draw draw(options.seed);
  constexpr double kStep = 1.0 / 16.0;  // of the 6-D direction's unit
  constexpr double kMaxT = 4.0;
  constexpr int kBisections = 10;  // step / 2^10 ≈ 1e-4 of the unit

  std::vector<Eigen::Isometry3d> candidates;
  std::vector<Directions> directions;
  robots::HexapodData data;
  for (int c = 0; c < options.candidates; ++c) {
    ++plan.candidates_tried;
    robots::Vector6d dir;
    for (int i = 0; i < 6; ++i) dir(i) = draw.Normal();
    dir.normalize();
    // March outwards to the first inadmissible pose, then bisect the boundary.
    double t_ok = 0.0, t_bad = kMaxT;
    for (double t = kStep; t <= kMaxT + 1e-12; t += kStep) {
      if (!Admissible(model, PoseAlong(options.X_BP_nominal, dir, t, options), options)) {
        t_bad = t;
        break;
      }
      t_ok = t;
    }
    if (t_ok < t_bad) {
      for (int b = 0; b < kBisections; ++b) {
        const double mid = 0.5 * (t_ok + t_bad);
        (Admissible(model, PoseAlong(options.X_BP_nominal, dir, mid, options), options) ? t_ok
                                                                                        : t_bad) =
            mid;
      }
    }
    if (!(t_ok > 0.0)) continue;  // the boundary is at the nominal pose in this direction
    const Eigen::Isometry3d X = PoseAlong(options.X_BP_nominal, dir, t_ok, options);
    robots::InverseKinematics(model, X, &data);
    candidates.push_back(X);
    directions.push_back(data.u_B);
  }
  plan.candidates_admissible = static_cast<int>(candidates.size());
  if (candidates.empty()) {
    plan.warnings.push_back(
        "no admissible candidate pose: the workspace (with the margins and "
        "the predicate) is empty around the nominal pose");
    return plan;
  }

  // Greedy farthest-point selection; closest[c] = largest MaxDot to the chosen set (smaller is
  // farther).
  robots::InverseKinematics(model, options.X_BP_nominal, &data);
  const Directions nominal = data.u_B;
  std::vector<double> closest(candidates.size());
  for (size_t c = 0; c < candidates.size(); ++c) closest[c] = MaxDot(directions[c], nominal);
  std::vector<bool> chosen(candidates.size(), false);
  const int wanted = std::min<int>(options.poses, static_cast<int>(candidates.size()));
  for (int i = 0; i < wanted; ++i) {
    size_t best = 0;
    double best_dot = 2.0;
    for (size_t c = 0; c < candidates.size(); ++c) {
      if (!chosen[c] && closest[c] < best_dot) {
        best_dot = closest[c];
        best = c;
      }
    }
    chosen[best] = true;
    plan.X_BP.push_back(candidates[best]);
    for (size_t c = 0; c < candidates.size(); ++c) {
      closest[c] = std::max(closest[c], MaxDot(directions[c], directions[best]));
    }
  }
  for (const Eigen::Isometry3d& X : plan.X_BP) {
    robots::InverseKinematics(model, X, &data);
    plan.q.push_back(data.q);
  }
  plan.legs = EvaluatePoseSpread(model, plan.X_BP, options.X_CB);
  if (wanted < options.poses) {
    plan.warnings.push_back("only " + std::to_string(wanted) + " admissible poses found for " +
                            std::to_string(options.poses) + " requested; raise candidates");
  }
  for (int j = 0; j < robots::kHexapodLegs; ++j) {
    if (plan.legs[j].max_angle < 5.0 * common::kPi / 180.0) {
      std::ostringstream msg;
      msg << "leg " << j << ": the planned directions span only "
          << plan.legs[j].max_angle * 180.0 / common::kPi
          << " deg; eq. 14 will be poorly conditioned";
      plan.warnings.push_back(msg.str());
    }
  }
  return plan;
}

bool AllLegsInView(const robots::HexapodModel& model, const vision::CameraModel& camera,
                   const Eigen::Isometry3d& X_CB, const Eigen::Isometry3d& X_BP, double margin_px) {
  const Eigen::Isometry3d X_CP = X_CB * X_BP;
  for (int j = 0; j < robots::kHexapodLegs; ++j) {
    const Eigen::Vector3d a = X_CB * model.p_B_A[j];
    const Eigen::Vector3d b = X_CP * model.p_P_B[j];
    for (const double t : {0.15, 0.5, 0.85}) {
      Eigen::Vector2d px;
      if (camera.Project(a + t * (b - a), &px) != vision::ProjectionStatus::kOk) return false;
      if (px.x() < margin_px || px.y() < margin_px || px.x() > camera.width() - 1 - margin_px ||
          px.y() > camera.height() - 1 - margin_px) {
        return false;
      }
    }
  }
  return true;
}

}  // namespace kinevis::calibration
