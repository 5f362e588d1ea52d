#include "calibration/hexapod/hexapod_calibration_io.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <ctime>
#include <fstream>
#include <limits>
#include <sstream>
#include <stdexcept>

#include "calibration/common/estimation_yaml_internal.h"
#include "calibration/common/yaml_reader_internal.h"

namespace kinevis::calibration {
namespace {

constexpr const char* kKind = "kinevis-hexapod-calibration";
// 2: the estimator contract's `estimation:` block; version 1 files (without it) are read, their
// report rebuilt from the legs.
constexpr int kVersion = 2;

using internal::NowUtc;

void EmitVector(YAML::Emitter& out, const Eigen::Vector3d& v) {
  out << YAML::Flow << YAML::BeginSeq << v.x() << v.y() << v.z() << YAML::EndSeq;
}

// A version 1 file's report: the legs' p_C_A with their covariances (block-diagonal); the
// residual summary and the identifiability analysis were not stored.
EstimationReport VersionOneEstimation(const HexapodCalibrationResult& r) {
  EstimationReport e;
  e.estimator = "hexapod legs A_j (seed 002 eq. 14)";
  e.message = "read from a version 1 file (before the estimator contract)";
  constexpr int n = 3 * robots::kHexapodLegs;
  e.covariance = Eigen::MatrixXd::Zero(n, n);
  int identified = 0;
  for (int j = 0; j < robots::kHexapodLegs; ++j) {
    const LegCalibration& leg = r.legs[j];
    const bool ok = leg.status == LegStatus::kEstimated;
    if (ok) e.covariance.block<3, 3>(3 * j, 3 * j) = leg.covariance;
    for (int k = 0; k < 3; ++k) {
      ParameterEstimate p;
      p.name = "leg" + std::to_string(j) + ".p_C_A." + "xyz"[k];
      p.unit = "m";
      p.value = r.p_C_A[j](k);
      p.estimated = true;
      p.identified = ok;
      p.sigma = ok ? std::sqrt(std::max(0.0, leg.covariance(k, k)))
                   : std::numeric_limits<double>::infinity();
      if (!ok) e.covariance(3 * j + k, 3 * j + k) = std::numeric_limits<double>::infinity();
      identified += ok ? 1 : 0;
      e.parameters.push_back(p);
    }
  }
  e.identifiability.parameters = n;
  e.identifiability.rank = identified;
  e.status = identified == n   ? EstimationStatus::kConverged
             : identified == 0 ? EstimationStatus::kInsufficientData
                               : EstimationStatus::kUnidentified;
  e.warnings = r.warnings;
  return e;
}

class Reader : public internal::CheckedYamlReader {
 public:
  explicit Reader(std::string path)
      : CheckedYamlReader("hexapod calibration file", std::move(path)) {}
};

template <typename Enum, int Count>
bool ParseEnum(const std::string& text, Enum* value) {
  for (int i = 0; i < Count; ++i) {
    if (text == ToString(static_cast<Enum>(i))) {
      *value = static_cast<Enum>(i);
      return true;
    }
  }
  return false;
}

}  // namespace

void WriteHexapodCalibration(const std::string& path, const HexapodCalibrationResult& r,
                             const HexapodCalibrationMetadata& metadata) {
  YAML::Emitter out;
  out.SetDoublePrecision(17);
  out << YAML::BeginMap;
  out << YAML::Key << "kind" << YAML::Value << kKind;
  out << YAML::Key << "version" << YAML::Value << kVersion;
  out << YAML::Key << "camera" << YAML::Value << metadata.camera;
  out << YAML::Key << "created" << YAML::Value
      << (metadata.created.empty() ? NowUtc() : metadata.created);
  out << YAML::Key << "robot" << YAML::Value << metadata.robot;
  out << YAML::Key << "source" << YAML::Value << metadata.source;
  out << YAML::Key << "leg_radius" << YAML::Value << r.leg_radius;
  out << YAML::Key << "configurations" << YAML::Value << r.configurations;
  out << YAML::Key << "loss" << YAML::Value << ToString(r.loss);
  out << YAML::Key << "legs" << YAML::Value << YAML::BeginSeq;
  for (int j = 0; j < robots::kHexapodLegs; ++j) {
    const LegCalibration& leg = r.legs[j];
    out << YAML::BeginMap;
    out << YAML::Key << "leg" << YAML::Value << j;
    out << YAML::Key << "status" << YAML::Value << ToString(leg.status);
    out << YAML::Key << "p_C_A" << YAML::Value;
    EmitVector(out, r.p_C_A[j]);
    out << YAML::Key << "sigma" << YAML::Value << leg.sigma;
    out << YAML::Key << "covariance" << YAML::Value << YAML::Flow << YAML::BeginSeq;
    for (int i = 0; i < 9; ++i) out << leg.covariance(i / 3, i % 3);
    out << YAML::EndSeq;
    out << YAML::Key << "condition_number" << YAML::Value << leg.condition_number;
    out << YAML::Key << "configurations" << YAML::Value << leg.configurations;
    out << YAML::Key << "equations" << YAML::Value << leg.equations;
    out << YAML::Key << "down_weighted" << YAML::Value << leg.down_weighted;
    out << YAML::Key << "residual_rms" << YAML::Value << leg.residual_rms;
    out << YAML::Key << "residual_max" << YAML::Value << leg.residual_max;
    out << YAML::Key << "residual_rms_inliers" << YAML::Value << leg.residual_rms_inliers;
    out << YAML::Key << "robust_scale" << YAML::Value << leg.robust_scale;
    out << YAML::Key << "rigid_fit_residual" << YAML::Value << leg.rigid_fit_residual;
    out << YAML::EndMap;
  }
  out << YAML::EndSeq;
  out << YAML::Key << "rigid_fit" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "ok" << YAML::Value << r.rigid_fit;
  const Eigen::Quaterniond q(r.X_CB.linear());
  out << YAML::Key << "X_CB" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "position" << YAML::Value;
  EmitVector(out, r.X_CB.translation());
  out << YAML::Key << "quaternion_wxyz" << YAML::Value << YAML::Flow << YAML::BeginSeq << q.w()
      << q.x() << q.y() << q.z() << YAML::EndSeq;
  out << YAML::EndMap;
  out << YAML::Key << "rms" << YAML::Value << r.rigid_fit_rms;
  out << YAML::Key << "max" << YAML::Value << r.rigid_fit_max;
  out << YAML::EndMap;
  out << YAML::Key << "scale" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "estimator" << YAML::Value << ToString(r.scale_estimator);
  out << YAML::Key << "value" << YAML::Value << r.scale;
  out << YAML::Key << "least_squares" << YAML::Value << r.scale_least_squares;
  out << YAML::Key << "median_ratio" << YAML::Value << r.scale_median_ratio;
  out << YAML::Key << "max_ratio" << YAML::Value << r.scale_max_ratio;
  out << YAML::Key << "corrected" << YAML::Value << r.scale_corrected;
  out << YAML::EndMap;
  out << YAML::Key << "down_weighted" << YAML::Value << YAML::BeginSeq;
  for (const DownWeightedEquation& d : r.down_weighted) {
    out << YAML::Flow << YAML::BeginMap << YAML::Key << "configuration" << YAML::Value
        << d.configuration << YAML::Key << "leg" << YAML::Value << d.leg << YAML::Key << "limb"
        << YAML::Value << d.limb << YAML::Key << "residual" << YAML::Value << d.residual
        << YAML::Key << "weight" << YAML::Value << d.weight << YAML::EndMap;
  }
  out << YAML::EndSeq;
  out << YAML::Key << "errors" << YAML::Value << YAML::BeginSeq;
  for (const std::string& e : r.errors) out << e;
  out << YAML::EndSeq;
  out << YAML::Key << "warnings" << YAML::Value << YAML::BeginSeq;
  for (const std::string& w : r.warnings) out << w;
  out << YAML::EndSeq;
  internal::EmitEstimation(out, r.estimation);
  out << YAML::EndMap;
  std::ofstream file(path);
  file
      << "# kinevis hexapod calibration (seed 002 eq. 14-16); format: docs/hexapod-calibration.md\n"
      << out.c_str() << "\n";
  if (!file) throw std::runtime_error("hexapod calibration: cannot write " + path);
}

HexapodCalibrationFile ReadHexapodCalibration(const std::string& path) {
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::BadFile&) {
    throw std::runtime_error("hexapod calibration file " + path + ": cannot be read");
  } catch (const YAML::Exception& e) {
    throw std::invalid_argument("hexapod calibration file " + path + ": not YAML (" + e.what() +
                                ")");
  }
  Reader in(path);
  HexapodCalibrationFile f;
  HexapodCalibrationResult& r = f.result;
  if (!root.IsMap()) {
    in.Bad("(top level)", "must be a map");
    in.ThrowIfBad();
  }
  const std::string kind = in.String(root, "kind", "kind");
  if (root["kind"] && kind != kKind)
    in.Bad("kind", "must be " + std::string(kKind) + " (" + kind + ")");
  const int version = in.Int(root, "version", "version", 0);
  if (root["version"] && (version < 1 || version > kVersion)) {
    in.Bad("version", "unsupported (" + std::to_string(version) + ", expected 1 or 2)");
  }
  f.metadata.camera = in.String(root, "camera", "camera");
  f.metadata.created = in.String(root, "created", "created");
  f.metadata.robot = in.String(root, "robot", "robot");
  f.metadata.source = in.String(root, "source", "source");
  r.leg_radius = in.Double(root, "leg_radius", "leg_radius");
  if (root["leg_radius"] && !(r.leg_radius > 0.0)) {
    in.Bad("leg_radius", "must be > 0 (" + std::to_string(r.leg_radius) + ")");
  }
  r.configurations = in.Int(root, "configurations", "configurations", 0);
  const std::string loss = in.String(root, "loss", "loss");
  if (root["loss"] && !ParseEnum<RobustLoss, 3>(loss, &r.loss)) {
    in.Bad("loss", "unknown (" + loss + "; least-squares, huber or tukey)");
  }
  const YAML::Node legs = in.Child(root, "legs", "legs");
  if (legs && (!legs.IsSequence() || legs.size() != robots::kHexapodLegs)) {
    in.Bad("legs", "must be a list of 6 legs");
  } else if (legs) {
    for (int j = 0; j < robots::kHexapodLegs; ++j) {
      const YAML::Node l = legs[j];
      const std::string k = "legs[" + std::to_string(j) + "].";
      LegCalibration& leg = r.legs[j];
      const int index = in.Int(l, "leg", k + "leg", 0);
      if (l["leg"] && index != j)
        in.Bad(k + "leg", "must be " + std::to_string(j) + " (" + std::to_string(index) + ")");
      const std::string status = in.String(l, "status", k + "status");
      if (l["status"] && !ParseEnum<LegStatus, 3>(status, &leg.status)) {
        in.Bad(k + "status", "unknown (" + status + ")");
      }
      const bool estimated = leg.status == LegStatus::kEstimated;
      leg.p_C_A = in.Numbers<3>(l, "p_C_A", k + "p_C_A", estimated);
      r.p_C_A[j] = leg.p_C_A;
      leg.sigma = in.Double(l, "sigma", k + "sigma", false);
      const Eigen::Matrix<double, 9, 1> cov =
          in.Numbers<9>(l, "covariance", k + "covariance", false);
      for (int i = 0; i < 9; ++i) leg.covariance(i / 3, i % 3) = cov(i);
      leg.condition_number = in.Double(l, "condition_number", k + "condition_number", false);
      leg.configurations = in.Int(l, "configurations", k + "configurations", 0);
      leg.equations = in.Int(l, "equations", k + "equations", 0);
      leg.down_weighted = in.Int(l, "down_weighted", k + "down_weighted", 0);
      leg.residual_rms = in.Double(l, "residual_rms", k + "residual_rms", false);
      leg.residual_max = in.Double(l, "residual_max", k + "residual_max", false);
      leg.residual_rms_inliers =
          in.Double(l, "residual_rms_inliers", k + "residual_rms_inliers", false);
      leg.robust_scale = in.Double(l, "robust_scale", k + "robust_scale", false);
      leg.rigid_fit_residual = in.Double(l, "rigid_fit_residual", k + "rigid_fit_residual", false);
    }
  }
  const YAML::Node rigid = in.Child(root, "rigid_fit", "rigid_fit");
  if (rigid) {
    r.rigid_fit = in.Bool(rigid, "ok", "rigid_fit.ok");
    const YAML::Node x = in.Child(rigid, "X_CB", "rigid_fit.X_CB");
    if (x) {
      const Eigen::Vector3d p = in.Numbers<3>(x, "position", "rigid_fit.X_CB.position");
      const Eigen::Vector4d q =
          in.Numbers<4>(x, "quaternion_wxyz", "rigid_fit.X_CB.quaternion_wxyz");
      if (q.allFinite() && std::abs(q.norm() - 1.0) > 1e-6) {
        std::ostringstream v;
        v << "must be a unit quaternion (norm " << q.norm() << ")";
        in.Bad("rigid_fit.X_CB.quaternion_wxyz", v.str());
      } else if (q.allFinite() && p.allFinite()) {
        r.X_CB.setIdentity();
        r.X_CB.linear() =
            Eigen::Quaterniond(q(0), q(1), q(2), q(3)).normalized().toRotationMatrix();
        r.X_CB.translation() = p;
      }
    }
    r.rigid_fit_rms = in.Double(rigid, "rms", "rigid_fit.rms", false);
    r.rigid_fit_max = in.Double(rigid, "max", "rigid_fit.max", false);
  }
  const YAML::Node scale = in.Child(root, "scale", "scale");
  if (scale) {
    const std::string estimator = in.String(scale, "estimator", "scale.estimator");
    if (scale["estimator"] && !ParseEnum<ScaleEstimator, 3>(estimator, &r.scale_estimator)) {
      in.Bad("scale.estimator", "unknown (" + estimator + ")");
    }
    r.scale = in.Double(scale, "value", "scale.value", false);
    r.scale_least_squares = in.Double(scale, "least_squares", "scale.least_squares", false);
    r.scale_median_ratio = in.Double(scale, "median_ratio", "scale.median_ratio", false);
    r.scale_max_ratio = in.Double(scale, "max_ratio", "scale.max_ratio", false);
    r.scale_corrected = in.Bool(scale, "corrected", "scale.corrected");
  }
  const YAML::Node down = in.Child(root, "down_weighted", "down_weighted");
  if (down && !down.IsSequence()) {
    in.Bad("down_weighted", "must be a list");
  } else if (down) {
    for (size_t i = 0; i < down.size(); ++i) {
      const std::string k = "down_weighted[" + std::to_string(i) + "].";
      DownWeightedEquation d;
      d.configuration = in.Int(down[i], "configuration", k + "configuration", 0);
      d.leg = in.Int(down[i], "leg", k + "leg", 0);
      if (d.leg >= robots::kHexapodLegs)
        in.Bad(k + "leg", "must be 0..5 (" + std::to_string(d.leg) + ")");
      d.limb = in.Int(down[i], "limb", k + "limb", 1);
      if (d.limb > 2) in.Bad(k + "limb", "must be 1 or 2 (" + std::to_string(d.limb) + ")");
      d.residual = in.Double(down[i], "residual", k + "residual");
      d.weight = in.Double(down[i], "weight", k + "weight");
      r.down_weighted.push_back(d);
    }
  }
  for (const char* list : {"errors", "warnings"}) {
    const YAML::Node node = in.Child(root, list, list);
    if (!node) continue;
    if (!node.IsSequence()) {
      in.Bad(list, "must be a list of strings");
      continue;
    }
    auto& target = std::string(list) == "errors" ? r.errors : r.warnings;
    for (const auto& item : node) target.push_back(item.Scalar());
  }
  if (version >= 2) r.estimation = internal::ReadEstimation(in, root);
  in.ThrowIfBad();
  if (version < 2) r.estimation = VersionOneEstimation(r);
  return f;
}

}  // namespace kinevis::calibration
