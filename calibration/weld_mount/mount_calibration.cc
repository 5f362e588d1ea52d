#include "calibration/weld_mount/mount_calibration.h"

#include <ceres/ceres.h>

#include <Eigen/QR>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <iomanip>
#include <limits>
#include <memory>
#include <sstream>
#include <stdexcept>

#include "calibration/common/estimation.h"
#include "calibration/weld_mount/mount_residuals_internal.h"
#include "common/config_error.h"

namespace kinevis::calibration {
namespace {

using internal::DhChain;
using internal::kDhErrors;

constexpr double kInf = std::numeric_limits<double>::infinity();
const char* const kPoseNames[6] = {"rx", "ry", "rz", "x", "y", "z"};

// A vector's coefficients as text, for problem messages.
template <typename M>
std::string Text(const M& m) {
  std::ostringstream s;
  s << m;
  return s.str();
}

bool IsRigid(const Eigen::Isometry3d& X) {
  const Eigen::Matrix3d R = X.linear();
  return X.matrix().allFinite() &&
         (R.transpose() * R - Eigen::Matrix3d::Identity()).norm() < 1e-6 && R.determinant() > 0.0;
}

// What the solves share: the data with the scan points that are used, the anchors and the
// current parameter values.
struct Context {
  const MountCalibrationData* data = nullptr;
  const MountCalibrationOptions* options = nullptr;
  std::vector<std::vector<Eigen::Vector3d>> points;  // per scan, the subsample used
  Eigen::Isometry3d X_5C0, X_0B0;                    // anchors
  double mount[6] = {0, 0, 0, 0, 0, 0};
  double block[6] = {0, 0, 0, 0, 0, 0};
  double dh[kDhErrors] = {};
  int scan_points = 0;

  Eigen::Vector3d half() const { return data->block.half(); }
  Eigen::Vector3d p_5T() const { return data->robot.X_5T.translation(); }
  Eigen::Isometry3d X_05(const robots::Vector5d& q) const {
    Eigen::VectorXd delta = Eigen::Map<const Eigen::VectorXd>(dh, kDhErrors);
    const robots::Weld5Model model = ApplyDhErrors(data->robot, delta);
    return robots::DhForwardKinematics(model.joints, q);
  }
};

enum class Stage { kTouches, kAll };

// Builds the problem of `stage`. with_dh_in_scans: the scans use the D–H residual (the D–H block
// a parameter of every scan point).
void Build(Context* c, Stage stage, bool with_dh_in_scans, double k, ceres::Problem* problem) {
  const MountCalibrationOptions& o = *c->options;
  const auto loss = [&]() -> ceres::LossFunction* {
    switch (o.loss) {
      case MountLoss::kHuber:
        return new ceres::HuberLoss(k);
      case MountLoss::kCauchy:
        return new ceres::CauchyLoss(k);
      case MountLoss::kNone:
        break;
    }
    return nullptr;
  };
  for (const MountTouch& t : c->data->touches) {
    problem->AddResidualBlock(
        internal::TouchResidual::Create(DhChain(c->data->robot, t.q), c->p_5T(), t.feature.sign,
                                        c->X_0B0, c->half(), o.touch_sigma),
        loss(), c->block, c->dh);
  }
  if (stage == Stage::kAll) {
    for (size_t s = 0; s < c->points.size(); ++s) {
      const robots::Vector5d& q = c->data->scans[s].q;
      if (with_dh_in_scans) {
        const DhChain chain(c->data->robot, q);
        for (const Eigen::Vector3d& p : c->points[s]) {
          problem->AddResidualBlock(internal::ScanPointDhResidual::Create(
                                        p, chain, c->X_5C0, c->X_0B0, c->half(), o.scan_sigma),
                                    loss(), c->mount, c->block, c->dh);
        }
      } else {
        const Eigen::Isometry3d X_05 = c->X_05(q);
        for (const Eigen::Vector3d& p : c->points[s]) {
          problem->AddResidualBlock(internal::ScanPointResidual::Create(p, X_05, c->X_5C0, c->X_0B0,
                                                                        c->half(), o.scan_sigma),
                                    loss(), c->mount, c->block);
        }
      }
    }
  }
}

struct SolveResult {
  bool converged = false;
  int iterations = 0;
  double initial_cost = 0.0;
  double final_cost = 0.0;
};

SolveResult Solve(const MountCalibrationOptions& o, ceres::Problem* problem) {
  ceres::Solver::Options so;
  so.linear_solver_type = ceres::DENSE_QR;
  so.max_num_iterations = o.max_iterations;
  so.num_threads = o.threads;
  so.function_tolerance = 1e-12;
  so.gradient_tolerance = 1e-14;
  so.parameter_tolerance = 1e-12;
  so.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(so, problem, &summary);
  SolveResult r;
  r.converged = summary.termination_type == ceres::CONVERGENCE;
  r.iterations = static_cast<int>(summary.iterations.size());
  r.initial_cost = summary.initial_cost;
  r.final_cost = summary.final_cost;
  return r;
}

// The Jacobian (dense) of `problem` with respect to `blocks`, the loss applied.
Eigen::MatrixXd Jacobian(ceres::Problem* problem, const std::vector<double*>& blocks,
                         double* cost) {
  ceres::Problem::EvaluateOptions eo;
  eo.parameter_blocks = blocks;
  eo.apply_loss_function = true;
  ceres::CRSMatrix crs;
  problem->Evaluate(eo, cost, nullptr, nullptr, &crs);
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(crs.num_rows, crs.num_cols);
  for (int r = 0; r < crs.num_rows; ++r) {
    for (int i = crs.rows[static_cast<size_t>(r)]; i < crs.rows[static_cast<size_t>(r) + 1]; ++i) {
      J(r, crs.cols[static_cast<size_t>(i)]) = crs.values[static_cast<size_t>(i)];
    }
  }
  return J;
}

ResidualStats Stats(std::vector<double> d, double k_distance) {
  ResidualStats s;
  s.count = static_cast<int>(d.size());
  if (d.empty()) return s;
  double sum = 0.0, sum2 = 0.0;
  for (double x : d) {
    sum += x;
    sum2 += x * x;
    s.max = std::max(s.max, x);
    s.beyond_k += x > k_distance ? 1 : 0;
  }
  s.mean = sum / static_cast<double>(d.size());
  s.rms = std::sqrt(sum2 / static_cast<double>(d.size()));
  std::nth_element(d.begin(), d.begin() + static_cast<long>(d.size() / 2), d.end());
  s.median = d[d.size() / 2];
  return s;
}

}  // namespace

std::string GaugeBlock::Validate() const {
  common::Problems p;
  if (!(size.allFinite() && size.minCoeff() > 0.0)) {
    p.Add("block.size", Text(size.transpose()), "must be finite and > 0 (m)");
  }
  return p.Message();
}

std::string BlockFeature::Name() const {
  if (sign == Eigen::Vector3i(0, 0, 1)) return "top";
  if (sign == Eigen::Vector3i(0, 0, -1)) return "board";
  std::string name;
  for (int k = 0; k < 3; ++k) {
    if (sign(k) != 0) {
      name += sign(k) > 0 ? '+' : '-';
      name += "xyz"[k];
    }
  }
  return name;
}

bool BlockFeature::Valid() const {
  return sign.cwiseAbs().maxCoeff() == 1 && sign.minCoeff() >= -1 && Equations() >= 1;
}

BlockFeature BlockFeature::Parse(const std::string& text) {
  BlockFeature f;
  if (text == "top") return f;
  if (text == "board") {
    f.sign = Eigen::Vector3i(0, 0, -1);
    return f;
  }
  f.sign.setZero();
  const auto fail = [&text]() {
    throw std::invalid_argument("block feature '" + text +
                                "': expected top, board, or signed axes in x, y, z order "
                                "(+x, -y+z, +x-y-z)");
  };
  if (text.empty() || text.size() % 2 != 0) fail();
  int last_axis = -1;
  for (size_t i = 0; i < text.size(); i += 2) {
    const char s = text[i], axis = text[i + 1];
    if ((s != '+' && s != '-') || axis < 'x' || axis > 'z') fail();
    const int k = axis - 'x';
    if (k <= last_axis) fail();
    last_axis = k;
    f.sign(k) = s == '+' ? 1 : -1;
  }
  return f;
}

std::string MountCalibrationData::Validate() const {
  common::Problems p;
  const std::string block_problem = block.Validate();
  std::string out = block_problem;
  if (!IsRigid(X_5C_guess))
    p.Add("X_5C_guess", "(not a rigid transform)", "must be a rotation and a translation");
  if (!IsRigid(X_0B_guess))
    p.Add("X_0B_guess", "(not a rigid transform)", "must be a rotation and a translation");
  if (!IsRigid(robot.X_5T))
    p.Add("robot.X_5T", "(not a rigid transform)", "must be a rotation and a translation");
  for (size_t i = 0; i < touches.size(); ++i) {
    if (!touches[i].q.allFinite()) {
      p.Add("touches[" + std::to_string(i) + "].q", Text(touches[i].q.transpose()),
            "must be finite");
    }
    if (!touches[i].feature.Valid()) {
      p.Add("touches[" + std::to_string(i) + "].feature", Text(touches[i].feature.sign.transpose()),
            "must be signs in {-1, 0, 1}, not all 0");
    }
  }
  for (size_t s = 0; s < scans.size(); ++s) {
    if (!scans[s].q.allFinite()) {
      p.Add("scans[" + std::to_string(s) + "].q", Text(scans[s].q.transpose()), "must be finite");
    }
    for (size_t i = 0; i < scans[s].p_C.size(); ++i) {
      if (!scans[s].p_C[i].allFinite()) {
        p.Add("scans[" + std::to_string(s) + "].p_C[" + std::to_string(i) + "]",
              Text(scans[s].p_C[i].transpose()), "must be finite");
        break;
      }
    }
  }
  const std::string rest = p.Message();
  if (!out.empty() && !rest.empty()) out += "; ";
  return out + rest;
}

const char* ToString(MountLoss loss) {
  switch (loss) {
    case MountLoss::kNone:
      return "none";
    case MountLoss::kHuber:
      return "huber";
    case MountLoss::kCauchy:
      return "cauchy";
  }
  return "?";
}

const char* ToString(MountCalibrationStatus status) {
  switch (status) {
    case MountCalibrationStatus::kOk:
      return "ok";
    case MountCalibrationStatus::kUnidentified:
      return "unidentified";
    case MountCalibrationStatus::kNotConverged:
      return "not-converged";
  }
  return "?";
}

std::string MountCalibrationOptions::Validate() const {
  common::Problems p;
  if (!(touch_sigma > 0.0 && std::isfinite(touch_sigma)))
    p.Add("touch_sigma", touch_sigma, "must be > 0 (m)");
  if (!(scan_sigma > 0.0 && std::isfinite(scan_sigma)))
    p.Add("scan_sigma", scan_sigma, "must be > 0 (m)");
  if (!(k > 0.0 && std::isfinite(k))) p.Add("k", k, "must be > 0");
  if (!(coarse_k > 0.0 && std::isfinite(coarse_k))) p.Add("coarse_k", coarse_k, "must be > 0");
  if (max_points_per_scan < 0) p.Add("max_points_per_scan", max_points_per_scan, "must be >= 0");
  if (!(rank_tolerance > 0.0 && rank_tolerance < 1.0)) {
    p.Add("rank_tolerance", rank_tolerance, "must be in (0, 1)");
  }
  if (!(dh_min_independence > 0.0 && dh_min_independence < 1.0)) {
    p.Add("dh_min_independence", dh_min_independence, "must be in (0, 1)");
  }
  if (!(warn_condition_number > 1.0))
    p.Add("warn_condition_number", warn_condition_number, "must be > 1");
  if (!(warn_position_std > 0.0)) p.Add("warn_position_std", warn_position_std, "must be > 0 (m)");
  if (!(warn_angle_std > 0.0)) p.Add("warn_angle_std", warn_angle_std, "must be > 0 (rad)");
  if (max_iterations < 1) p.Add("max_iterations", max_iterations, "must be >= 1");
  if (threads < 1) p.Add("threads", threads, "must be >= 1");
  return p.Message();
}

std::vector<std::string> DhErrorNames() {
  std::vector<std::string> names;
  for (int i = 1; i <= robots::kWeld5Joints; ++i) {
    const std::string n = std::to_string(i);
    names.push_back("a" + n);
    names.push_back("alpha" + n);
    names.push_back("d" + n);
    names.push_back("theta" + n);
  }
  return names;
}

robots::Weld5Model ApplyDhErrors(const robots::Weld5Model& model, const Eigen::VectorXd& delta) {
  if (delta.size() != kDhErrors) {
    throw std::invalid_argument("ApplyDhErrors: " + std::to_string(delta.size()) +
                                " D-H errors; expected " + std::to_string(kDhErrors));
  }
  robots::Weld5Model out = model;
  for (int i = 0; i < robots::kWeld5Joints; ++i) {
    robots::DhJoint& j = out.joints[static_cast<size_t>(i)];
    j.a += delta(4 * i + 0);
    j.alpha += delta(4 * i + 1);
    j.d += delta(4 * i + 2);
    j.theta_offset += delta(4 * i + 3);
  }
  return out;
}

namespace {

MountCalibrationSummary Calibrate(const MountCalibrationData& data,
                                  const MountCalibrationOptions& options) {
  const std::string bad_options = options.Validate();
  if (!bad_options.empty()) {
    throw std::invalid_argument("scanner mount calibration: options: " + bad_options);
  }
  const std::string bad_data = data.Validate();
  if (!bad_data.empty())
    throw std::invalid_argument("scanner mount calibration: data: " + bad_data);
  if (data.touches.empty()) {
    throw std::invalid_argument(
        "scanner mount calibration: data: no touches (the block's pose "
        "in the base frame comes from them)");
  }

  Context c;
  c.data = &data;
  c.options = &options;
  c.X_5C0 = data.X_5C_guess;
  c.X_0B0 = data.X_0B_guess;
  for (const MountScan& scan : data.scans) {
    std::vector<Eigen::Vector3d> used;
    const size_t n = scan.p_C.size();
    const size_t m = options.max_points_per_scan == 0
                         ? n
                         : std::min(n, static_cast<size_t>(options.max_points_per_scan));
    for (size_t k = 0; k < m; ++k) {
      const size_t i = m == 1 ? 0 : (k * (n - 1) + (m - 1) / 2) / (m - 1);
      used.push_back(scan.p_C[i]);
    }
    c.scan_points += static_cast<int>(used.size());
    c.points.push_back(std::move(used));
  }
  if (c.scan_points == 0) {
    throw std::invalid_argument("scanner mount calibration: data: no scan points");
  }

  MountCalibrationSummary out;
  const std::vector<std::string> dh_names = DhErrorNames();
  for (const char* prefix : {"mount.", "block."}) {
    for (const char* n : kPoseNames) out.parameter_names.push_back(std::string(prefix) + n);
  }
  if (options.estimate_dh) {
    for (const std::string& n : dh_names) out.parameter_names.push_back(n);
  }
  const int n_all = static_cast<int>(out.parameter_names.size());

  // The cost of the final problem at the guess.
  {
    ceres::Problem p;
    Build(&c, Stage::kAll, false, options.k, &p);
    p.Evaluate(ceres::Problem::EvaluateOptions(), &out.initial_cost, nullptr, nullptr, nullptr);
  }

  // 1. The block from the touches alone (robot nominal), 2. mount and block, coarse loss.
  bool converged = true;
  {
    ceres::Problem p;
    Build(&c, Stage::kTouches, false, options.coarse_k, &p);
    p.SetParameterBlockConstant(c.dh);
    const SolveResult r = Solve(options, &p);
    out.iterations += r.iterations;
  }
  {
    ceres::Problem p;
    Build(&c, Stage::kAll, false, options.coarse_k, &p);
    p.SetParameterBlockConstant(c.dh);
    const SolveResult r = Solve(options, &p);
    out.iterations += r.iterations;
  }

  // 3. Which D–H errors the data identify once mount and block are free: the part of each one's
  // unit Jacobian column outside the span of the mount's, the block's and the D–H columns chosen
  // before it (column-pivoted QR of the projected columns).
  std::vector<int> free_dh;
  if (options.estimate_dh) {
    ceres::Problem p;
    Build(&c, Stage::kAll, true, options.k, &p);
    double cost = 0.0;
    const Eigen::MatrixXd J = Jacobian(&p, {c.mount, c.block, c.dh}, &cost);
    Eigen::MatrixXd J_mb = J.leftCols(12), J_dh = J.rightCols(kDhErrors);
    for (int j = 0; j < 12; ++j) {
      const double nrm = J_mb.col(j).norm();
      if (nrm > 0.0) J_mb.col(j) /= nrm;
    }
    for (int j = 0; j < kDhErrors; ++j) {
      const double nrm = J_dh.col(j).norm();
      if (nrm > 0.0) J_dh.col(j) /= nrm;
    }
    Eigen::JacobiSVD<Eigen::MatrixXd> svd_mb(J_mb, Eigen::ComputeThinU);
    const Eigen::VectorXd& s = svd_mb.singularValues();
    int r_mb = 0;
    for (Eigen::Index i = 0; i < s.size(); ++i)
      r_mb += s(i) > options.rank_tolerance * s(0) ? 1 : 0;
    const Eigen::MatrixXd U = svd_mb.matrixU().leftCols(r_mb);
    const Eigen::MatrixXd P = J_dh - U * (U.transpose() * J_dh);
    Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(P);
    const Eigen::MatrixXd R = qr.matrixR().topRows(kDhErrors).triangularView<Eigen::Upper>();
    for (int i = 0; i < kDhErrors; ++i) {
      const int column = qr.colsPermutation().indices()(i);
      if (std::abs(R(i, i)) > options.dh_min_independence) {
        free_dh.push_back(column);
      } else {
        out.fixed_dh.push_back(dh_names[static_cast<size_t>(column)]);
      }
    }
    std::sort(free_dh.begin(), free_dh.end());
  }

  // 4. The final solve.
  {
    ceres::Problem p;
    Build(&c, Stage::kAll, options.estimate_dh, options.k, &p);
    if (!options.estimate_dh || free_dh.empty()) {
      p.SetParameterBlockConstant(c.dh);
    } else if (static_cast<int>(free_dh.size()) < kDhErrors) {
      std::vector<int> fixed;
      for (int i = 0; i < kDhErrors; ++i) {
        if (!std::binary_search(free_dh.begin(), free_dh.end(), i)) fixed.push_back(i);
      }
      p.SetManifold(c.dh, new ceres::SubsetManifold(kDhErrors, fixed));
    }
    const SolveResult r = Solve(options, &p);
    out.iterations += r.iterations;
    converged = r.converged;
  }

  // The estimate; then re-anchor at it so that the analysis is in the tangent at the estimate.
  out.X_5C = internal::PerturbPose(c.X_5C0, c.mount);
  out.X_0B = internal::PerturbPose(c.X_0B0, c.block);
  const Eigen::VectorXd dh = Eigen::Map<const Eigen::VectorXd>(c.dh, kDhErrors);
  out.robot = ApplyDhErrors(data.robot, dh);
  out.correction = Eigen::VectorXd::Zero(n_all);
  {
    const Eigen::Isometry3d dm = data.X_5C_guess.inverse() * out.X_5C;
    const Eigen::Isometry3d db = data.X_0B_guess.inverse() * out.X_0B;
    const Eigen::AngleAxisd am(dm.linear()), ab(db.linear());
    out.correction.segment<3>(0) = am.angle() * am.axis();
    out.correction.segment<3>(3) = dm.translation();
    out.correction.segment<3>(6) = ab.angle() * ab.axis();
    out.correction.segment<3>(9) = db.translation();
    if (options.estimate_dh) out.correction.tail(kDhErrors) = dh;
  }
  c.X_5C0 = out.X_5C;
  c.X_0B0 = out.X_0B;
  std::fill(std::begin(c.mount), std::end(c.mount), 0.0);
  std::fill(std::begin(c.block), std::end(c.block), 0.0);

  ceres::Problem p;
  Build(&c, Stage::kAll, options.estimate_dh, options.k, &p);
  std::vector<double*> blocks = {c.mount, c.block};
  if (options.estimate_dh) blocks.push_back(c.dh);
  const Eigen::MatrixXd J = Jacobian(&p, blocks, &out.final_cost);

  // Residual statistics (unweighted distances).
  {
    std::vector<double> touch, scan;
    double touch_equations = 0.0;
    for (const MountTouch& t : data.touches) {
      const internal::TouchResidual f(DhChain(data.robot, t.q), c.p_5T(), t.feature.sign, c.X_0B0,
                                      c.half(), 1.0);
      double r[3];
      f(c.block, c.dh, r);
      touch.push_back(Eigen::Map<Eigen::Vector3d>(r).norm());
      touch_equations += t.feature.Equations();
    }
    for (size_t s = 0; s < c.points.size(); ++s) {
      const Eigen::Isometry3d X_05 = c.X_05(data.scans[s].q);
      for (const Eigen::Vector3d& pt : c.points[s]) {
        const internal::ScanPointResidual f(pt, X_05, c.X_5C0, c.X_0B0, c.half(), 1.0);
        double r[3];
        f(c.mount, c.block, r);
        scan.push_back(Eigen::Map<Eigen::Vector3d>(r).norm());
      }
    }
    out.touch = Stats(touch, options.k * options.touch_sigma);
    out.scan = Stats(scan, options.k * options.scan_sigma);
    // Degrees of freedom: one equation per touched coordinate, one per scan point (its residual
    // lies along the surface normal).
    const double m = touch_equations + c.scan_points;
    const double n_free = 12.0 + static_cast<double>(free_dh.size());
    out.sigma_ratio = m > n_free ? std::sqrt(2.0 * out.final_cost / (m - n_free)) : kInf;
  }

  // Identifiability of all parameters (rank, the directions the data cannot fix), then of the
  // estimated ones (condition, identified flags, covariance), unit-norm column scaling.
  IdentifiabilityOptions analysis;
  analysis.rank_tolerance = options.rank_tolerance;
  const Identifiability all = AnalyzeIdentifiability(J, out.parameter_names, analysis);
  out.rank = all.rank;
  out.singular_values = Eigen::Map<const Eigen::VectorXd>(
      all.singular_values.data(), static_cast<Eigen::Index>(all.singular_values.size()));
  out.unidentified = all.unidentified;

  std::vector<int> est;
  for (int i = 0; i < 12; ++i) est.push_back(i);
  for (int i : free_dh) est.push_back(12 + i);
  out.estimated.assign(static_cast<size_t>(n_all), false);
  for (int i : est) out.estimated[static_cast<size_t>(i)] = true;
  Eigen::MatrixXd J_est(J.rows(), static_cast<Eigen::Index>(est.size()));
  std::vector<std::string> est_names;
  for (size_t k = 0; k < est.size(); ++k) {
    J_est.col(static_cast<Eigen::Index>(k)) = J.col(est[k]);
    est_names.push_back(out.parameter_names[static_cast<size_t>(est[k])]);
  }
  const Identifiability e = AnalyzeIdentifiability(J_est, est_names, analysis);
  const Eigen::Index n_est = J_est.cols();
  out.condition_number = e.condition_number_identified;
  const double s2 = std::isfinite(out.sigma_ratio) ? out.sigma_ratio * out.sigma_ratio : 1.0;
  out.covariance = Eigen::MatrixXd::Zero(n_all, n_all);
  out.identified.assign(static_cast<size_t>(n_all), false);
  out.std_dev = Eigen::VectorXd::Constant(n_all, kInf);
  for (Eigen::Index a = 0; a < n_est; ++a) {
    for (Eigen::Index b = 0; b < n_est; ++b) {
      out.covariance(est[static_cast<size_t>(a)], est[static_cast<size_t>(b)]) =
          s2 * e.normal_inverse(a, b);
    }
  }
  for (Eigen::Index a = 0; a < n_est; ++a) {
    const int i = est[static_cast<size_t>(a)];
    if (e.identified[static_cast<size_t>(a)]) {
      out.identified[static_cast<size_t>(i)] = true;
      out.std_dev(i) = std::sqrt(out.covariance(i, i));
    } else {
      out.covariance(i, i) = kInf;
    }
  }
  out.mount_covariance = out.covariance.topLeftCorner<6, 6>();
  bool mount_identified = true;
  for (int i = 0; i < 6; ++i)
    mount_identified = mount_identified && out.identified[static_cast<size_t>(i)];
  if (mount_identified) {
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> rot(out.mount_covariance.topLeftCorner<3, 3>());
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> pos(
        out.mount_covariance.bottomRightCorner<3, 3>());
    out.mount_angle_std = std::sqrt(std::max(0.0, rot.eigenvalues()(2)));
    out.mount_position_std = std::sqrt(std::max(0.0, pos.eigenvalues()(2)));
  } else {
    out.mount_angle_std = kInf;
    out.mount_position_std = kInf;
  }

  // Status and warnings.
  out.converged = converged;
  if (!mount_identified) {
    out.status = MountCalibrationStatus::kUnidentified;
    std::string names;
    for (int i = 0; i < 6; ++i) {
      if (!out.identified[static_cast<size_t>(i)]) {
        names += (names.empty() ? "" : ", ") + out.parameter_names[static_cast<size_t>(i)];
      }
    }
    out.warnings.push_back("the data do not identify the mount: " + names +
                           " (scans from more robot orientations, seeing more faces of the "
                           "block, are needed)");
  } else if (!converged) {
    out.status = MountCalibrationStatus::kNotConverged;
    out.warnings.push_back("the solver did not converge in " +
                           std::to_string(options.max_iterations) + " iterations");
  } else {
    out.status = MountCalibrationStatus::kOk;
  }
  for (int i = 6; i < 12; ++i) {
    if (!out.identified[static_cast<size_t>(i)]) {
      out.warnings.push_back("the block's " + out.parameter_names[static_cast<size_t>(i)] +
                             " is not identified (touch more faces of the block)");
    }
  }
  for (const std::string& u : out.unidentified) {
    out.warnings.push_back("unidentified combination: " + u);
  }
  if (!out.fixed_dh.empty()) {
    std::string names;
    for (const std::string& n : out.fixed_dh) names += (names.empty() ? "" : ", ") + n;
    out.warnings.push_back(
        "D-H errors held at nominal (not separable from the mount, the block "
        "or each other with these data): " +
        names);
  }
  if (std::isfinite(out.condition_number) && out.condition_number > options.warn_condition_number) {
    std::ostringstream w;
    w << "condition number " << out.condition_number << " > " << options.warn_condition_number
      << ": the data separate the parameters badly";
    out.warnings.push_back(w.str());
  }
  if (mount_identified && out.mount_position_std > options.warn_position_std) {
    std::ostringstream w;
    w << "mount position uncertain: std " << out.mount_position_std * 1e3 << " mm > "
      << options.warn_position_std * 1e3 << " mm";
    out.warnings.push_back(w.str());
  }
  if (mount_identified && out.mount_angle_std > options.warn_angle_std) {
    std::ostringstream w;
    w << "mount orientation uncertain: std " << out.mount_angle_std * 180.0 / M_PI << " deg > "
      << options.warn_angle_std * 180.0 / M_PI << " deg";
    out.warnings.push_back(w.str());
  }
  if (out.sigma_ratio > 3.0 && std::isfinite(out.sigma_ratio)) {
    std::ostringstream w;
    w << "residuals are " << out.sigma_ratio
      << " times the given sigmas: the sigmas are too small, or the model does not fit "
         "(wrong block size, D-H errors, a bad scanner calibration)";
    out.warnings.push_back(w.str());
  }
  return out;
}

}  // namespace

MountCalibrationSummary CalibrateScannerMount(const MountCalibrationData& data,
                                              const MountCalibrationOptions& options) {
  MountCalibrationSummary summary = Calibrate(data, options);
  summary.estimation = MountEstimationReport(summary);
  return summary;
}

EstimationReport MountEstimationReport(const MountCalibrationSummary& s) {
  EstimationReport e;
  e.estimator = "scanner mount X_5C (with the block pose and D-H errors)";
  const size_t n = s.parameter_names.size();
  bool all_identified = true;
  for (size_t i = 0; i < n; ++i) {
    const std::string& name = s.parameter_names[i];
    ParameterEstimate p;
    p.name = name;
    // rx, ry, rz and the D–H angles alpha, theta are rad; x, y, z, a and d are m.
    const bool angle = name.find(".r") != std::string::npos || name.rfind("alpha", 0) == 0 ||
                       name.rfind("theta", 0) == 0;
    p.unit = angle ? "rad" : "m";
    p.initial = 0.0;  // corrections from the nominal (tangent at the nominal)
    p.value = i < static_cast<size_t>(s.correction.size())
                  ? s.correction(static_cast<Eigen::Index>(i))
                  : 0.0;
    p.estimated = i < s.estimated.size() && s.estimated[i];
    p.identified = i < s.identified.size() && s.identified[i];
    p.sigma = !p.estimated   ? 0.0
              : p.identified ? s.std_dev(static_cast<Eigen::Index>(i))
                             : std::numeric_limits<double>::infinity();
    all_identified = all_identified && (!p.estimated || p.identified);
    e.parameters.push_back(p);
  }
  switch (s.status) {
    case MountCalibrationStatus::kOk:
      e.status = all_identified ? EstimationStatus::kConverged : EstimationStatus::kUnidentified;
      break;
    case MountCalibrationStatus::kUnidentified:
      e.status = EstimationStatus::kUnidentified;
      break;
    case MountCalibrationStatus::kNotConverged:
      e.status = EstimationStatus::kNotConverged;
      break;
  }
  e.message = ToString(s.status);
  e.iterations = s.iterations;
  e.initial_cost = s.initial_cost;
  e.final_cost = s.final_cost;
  e.variance_factor = s.sigma_ratio * s.sigma_ratio;
  for (const auto& [name, r] :
       {std::pair{"touch distance", &s.touch}, std::pair{"scan distance", &s.scan}}) {
    e.residuals.push_back({name, "m", r->count, r->mean, r->rms, r->max});
  }
  if (s.covariance.rows() == static_cast<Eigen::Index>(n)) {
    e.covariance = s.covariance;
    for (size_t i = 0; i < n; ++i) {
      if (e.parameters[i].estimated && !e.parameters[i].identified) {
        e.covariance(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(i)) =
            std::numeric_limits<double>::infinity();
      }
    }
  }
  Identifiability& id = e.identifiability;
  id.parameters = static_cast<int>(n);
  id.rank = s.rank;
  id.condition_number =
      s.rank == static_cast<int>(n) ? s.condition_number : std::numeric_limits<double>::infinity();
  id.condition_number_identified = s.condition_number;
  id.singular_values.assign(s.singular_values.data(),
                            s.singular_values.data() + s.singular_values.size());
  id.unidentified = s.unidentified;
  for (const std::string& d : s.fixed_dh) id.gauges.push_back(d + " held at nominal");
  e.warnings = s.warnings;
  return e;
}

}  // namespace kinevis::calibration
