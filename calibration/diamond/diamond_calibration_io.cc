#include "calibration/diamond/diamond_calibration_io.h"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <ctime>
#include <fstream>
#include <stdexcept>

#include "calibration/common/estimation_yaml_internal.h"

namespace kinevis::calibration {
namespace {

constexpr const char* kKind = "kinevis-diamond-calibration";
// 2: the estimator contract's `estimation:` block (calibration/common/estimation_yaml_internal.h).
// Version 1 files (without it) are read, their report derived from what they hold.
constexpr int kVersion = 2;

using internal::NowUtc;

template <typename Vec>
void EmitList(YAML::Emitter& out, const Vec& v, int n) {
  out << YAML::Flow << YAML::BeginSeq;
  for (int i = 0; i < n; ++i) out << v[i];
  out << YAML::EndSeq;
}

void EmitStrings(YAML::Emitter& out, const char* key, const std::vector<std::string>& v) {
  out << YAML::Key << key << YAML::Value << YAML::BeginSeq;
  for (const std::string& s : v) out << s;
  out << YAML::EndSeq;
}

void EmitStatistics(YAML::Emitter& out, const char* key, const ResidualStatistics& s,
                    const char* suffix) {
  const std::string sfx = suffix;
  out << YAML::Key << key << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "count" << YAML::Value << s.count;
  out << YAML::Key << ("mean" + sfx) << YAML::Value;
  EmitList(out, s.mean, 2);
  out << YAML::Key << ("rms" + sfx) << YAML::Value;
  EmitList(out, s.rms, 2);
  out << YAML::Key << ("sup" + sfx) << YAML::Value;
  EmitList(out, s.sup, 2);
  out << YAML::Key << ("rms_norm" + sfx) << YAML::Value << s.rms_norm;
  out << YAML::EndMap;
}

// Collects every problem of a file, then throws once.
class Reader {
 public:
  explicit Reader(std::string path) : path_(std::move(path)) {}

  void Bad(const std::string& key, const std::string& what) {
    errors_ += (errors_.empty() ? "" : "; ") + key + ": " + what;
  }
  void ThrowIfBad() const {
    if (!errors_.empty()) {
      throw std::invalid_argument("diamond calibration file " + path_ + ": " + errors_);
    }
  }
  YAML::Node Child(const YAML::Node& node, const std::string& name, const std::string& key) {
    if (!node || !node.IsMap() || !node[name]) {
      Bad(key, "missing");
      return YAML::Node();
    }
    return node[name];
  }
  double Double(const YAML::Node& node, const std::string& name, const std::string& key,
                bool finite = true) {
    const YAML::Node v = Child(node, name, key);
    if (!v) return std::nan("");
    double d = 0.0;
    if (!v.IsScalar() || !YAML::convert<double>::decode(v, d)) {
      Bad(key, "not a number (" + Dump(v) + ")");
      return std::nan("");
    }
    if (finite && !std::isfinite(d)) Bad(key, "must be finite (" + v.Scalar() + ")");
    return d;
  }
  int Int(const YAML::Node& node, const std::string& name, const std::string& key, int min) {
    const YAML::Node v = Child(node, name, key);
    if (!v) return 0;
    int i = 0;
    if (!v.IsScalar() || !YAML::convert<int>::decode(v, i)) {
      Bad(key, "not an integer (" + Dump(v) + ")");
      return 0;
    }
    if (i < min) Bad(key, "must be >= " + std::to_string(min) + " (" + v.Scalar() + ")");
    return i;
  }
  bool Bool(const YAML::Node& node, const std::string& name, const std::string& key) {
    const YAML::Node v = Child(node, name, key);
    bool b = false;
    if (v && (!v.IsScalar() || !YAML::convert<bool>::decode(v, b))) {
      Bad(key, "not true/false (" + Dump(v) + ")");
    }
    return b;
  }
  std::string String(const YAML::Node& node, const std::string& name, const std::string& key) {
    const YAML::Node v = Child(node, name, key);
    if (!v) return "";
    if (!v.IsScalar()) {
      Bad(key, "not a string (" + Dump(v) + ")");
      return "";
    }
    return v.Scalar();
  }
  std::vector<double> Numbers(const YAML::Node& node, const std::string& name,
                              const std::string& key, int n, bool finite = true) {
    std::vector<double> out(n > 0 ? n : 0, std::nan(""));
    const YAML::Node v = Child(node, name, key);
    if (!v) return out;
    if (!v.IsSequence() || (n >= 0 && static_cast<int>(v.size()) != n)) {
      Bad(key, "must be a list of " + (n >= 0 ? std::to_string(n) + " " : std::string()) +
                   "numbers (" + Dump(v) + ")");
      return out;
    }
    out.assign(v.size(), std::nan(""));
    for (size_t i = 0; i < v.size(); ++i) {
      double d = 0.0;
      if (!v[i].IsScalar() || !YAML::convert<double>::decode(v[i], d) ||
          (finite && !std::isfinite(d))) {
        Bad(key, "element " + std::to_string(i) + " is not a " + (finite ? "finite " : "") +
                     "number (" + Dump(v) + ")");
        return out;
      }
      out[i] = d;
    }
    return out;
  }
  std::vector<std::string> Strings(const YAML::Node& node, const std::string& name,
                                   const std::string& key) {
    std::vector<std::string> out;
    const YAML::Node v = Child(node, name, key);
    if (!v) return out;
    if (!v.IsSequence()) {
      Bad(key, "must be a list of strings (" + Dump(v) + ")");
      return out;
    }
    for (const YAML::Node& e : v) {
      if (!e.IsScalar()) {
        Bad(key, "must be a list of strings (" + Dump(v) + ")");
        return {};
      }
      out.push_back(e.Scalar());
    }
    return out;
  }
  ResidualStatistics Statistics(const YAML::Node& node, const std::string& name,
                                const std::string& key, const std::string& sfx) {
    ResidualStatistics s;
    const YAML::Node m = Child(node, name, key);
    if (!m) return s;
    s.count = Int(m, "count", key + ".count", 0);
    const auto pair = [&](const std::string& k, Eigen::Vector2d* v) {
      const std::vector<double> n = Numbers(m, k + sfx, key + "." + k + sfx, 2);
      *v = Eigen::Vector2d(n[0], n[1]);
    };
    pair("mean", &s.mean);
    pair("rms", &s.rms);
    pair("sup", &s.sup);
    s.rms_norm = Double(m, "rms_norm" + sfx, key + ".rms_norm" + sfx);
    return s;
  }

  static std::string Dump(const YAML::Node& v) {
    YAML::Emitter e;
    e << YAML::Flow << v;
    return e.c_str();
  }

 private:
  std::string path_;
  std::string errors_;
};

template <typename Enum>
bool ParseEnum(const std::string& text, int count, Enum* value) {
  for (int i = 0; i < count; ++i) {
    if (text == ToString(static_cast<Enum>(i))) {
      *value = static_cast<Enum>(i);
      return true;
    }
  }
  return false;
}

}  // namespace

void WriteDiamondCalibration(const std::string& path, const DiamondIdentificationSummary& s,
                             const DiamondCalibrationMetadata& metadata) {
  const robots::DiamondModel& m = s.model;
  YAML::Emitter out;
  out.SetDoublePrecision(17);
  out << YAML::BeginMap;
  out << YAML::Key << "robot" << YAML::Value << "diamond";
  out << YAML::Key << "name" << YAML::Value << metadata.name;
  out << YAML::Key << "kind" << YAML::Value << kKind;
  out << YAML::Key << "version" << YAML::Value << kVersion;
  out << YAML::Key << "created" << YAML::Value
      << (metadata.created.empty() ? NowUtc() : metadata.created);
  out << YAML::Key << "camera" << YAML::Value << metadata.camera;
  out << YAML::Key << "initial_robot" << YAML::Value << metadata.robot;
  out << YAML::Key << "source" << YAML::Value << metadata.source;
  // The robot description part (robots/io, docs/robot-description.md).
  out << YAML::Key << "radius" << YAML::Value << m.radius;
  out << YAML::Key << "alpha" << YAML::Value << m.alpha;
  out << YAML::Key << "beta" << YAML::Value << m.beta;
  out << YAML::Key << "joint_offsets" << YAML::Value;
  EmitList(out, m.joint_offsets, 2);
  out << YAML::Key << "theta_min" << YAML::Value;
  EmitList(out, m.theta_min, 2);
  out << YAML::Key << "theta_max" << YAML::Value;
  EmitList(out, m.theta_max, 2);
  out << YAML::Key << "separation_min" << YAML::Value << m.separation_min;
  out << YAML::Key << "separation_max" << YAML::Value << m.separation_max;
  out << YAML::Key << "phi_min" << YAML::Value << m.phi_min;
  out << YAML::Key << "phi_max" << YAML::Value << m.phi_max;
  out << YAML::Key << "gamma_min" << YAML::Value << m.gamma_min;
  out << YAML::Key << "gamma_max" << YAML::Value << m.gamma_max;
  // The camera.
  const Eigen::Quaterniond q(s.X_OC.linear());
  out << YAML::Key << "camera_pose" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "position" << YAML::Value;
  EmitList(out, s.X_OC.translation(), 3);
  out << YAML::Key << "quaternion_wxyz" << YAML::Value << YAML::Flow << YAML::BeginSeq << q.w()
      << q.x() << q.y() << q.z() << YAML::EndSeq;
  out << YAML::EndMap;
  // How it was identified.
  out << YAML::Key << "identification" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "status" << YAML::Value << ToString(s.status);
  out << YAML::Key << "residual" << YAML::Value << ToString(s.residual);
  out << YAML::Key << "scaling" << YAML::Value << ToString(s.scaling);
  out << YAML::Key << "pixel_sigma_px" << YAML::Value << s.pixel_sigma;
  out << YAML::Key << "iterations" << YAML::Value << s.iterations;
  out << YAML::Key << "initial_cost" << YAML::Value << s.initial_cost;
  out << YAML::Key << "final_cost" << YAML::Value << s.final_cost;
  out << YAML::Key << "variance_factor" << YAML::Value << s.variance_factor;
  out << YAML::Key << "samples" << YAML::Value << s.samples;
  out << YAML::Key << "samples_used" << YAML::Value << s.samples_used;
  out << YAML::Key << "rejected_samples" << YAML::Value;
  EmitList(out, s.rejected_samples, static_cast<int>(s.rejected_samples.size()));
  EmitStrings(out, "rejected_reasons", s.rejected_reasons);
  out << YAML::Key << "column_scale" << YAML::Value;
  EmitList(out, s.column_scale, kDiamondParameterCount);
  out << YAML::EndMap;
  out << YAML::Key << "parameters" << YAML::Value << YAML::BeginMap;
  for (int j = 0; j < kDiamondParameterCount; ++j) {
    const DiamondParameterEstimate& p = s.parameters[j];
    out << YAML::Key << DiamondParameterName(j) << YAML::Value << YAML::Flow << YAML::BeginMap;
    out << YAML::Key << "value" << YAML::Value << p.value;
    out << YAML::Key << "initial" << YAML::Value << p.initial;
    out << YAML::Key << "sigma" << YAML::Value << p.sigma;
    out << YAML::Key << "estimated" << YAML::Value << p.estimated;
    out << YAML::Key << "identified" << YAML::Value << p.identified;
    out << YAML::EndMap;
  }
  out << YAML::EndMap;
  out << YAML::Key << "joint_offset_sigma" << YAML::Value;
  EmitList(out, s.offset_sigma, 2);
  out << YAML::Key << "covariance" << YAML::Value << YAML::BeginSeq;
  for (int r = 0; r < kDiamondParameterCount; ++r) {
    out << YAML::Flow << YAML::BeginSeq;
    for (int c = 0; c < kDiamondParameterCount; ++c) {
      out << (s.covariance.rows() == kDiamondParameterCount ? s.covariance(r, c) : 0.0);
    }
    out << YAML::EndSeq;
  }
  out << YAML::EndSeq;
  out << YAML::Key << "residuals" << YAML::Value << YAML::BeginMap;
  EmitStatistics(out, "pixel", s.pixel_residuals, "_px");
  EmitStatistics(out, "task", s.task_residuals, "_rad");
  out << YAML::EndMap;
  const IdentifiabilityReport& id = s.identifiability;
  out << YAML::Key << "identifiability" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "free_parameters" << YAML::Value << id.parameters;
  out << YAML::Key << "rank" << YAML::Value << id.rank;
  out << YAML::Key << "condition_number" << YAML::Value << id.condition_number;
  out << YAML::Key << "singular_values" << YAML::Value;
  EmitList(out, id.singular_values, static_cast<int>(id.singular_values.size()));
  EmitStrings(out, "unidentified", id.unidentified);
  EmitStrings(out, "gauges", id.gauges);
  EmitStrings(out, "strong_correlations", id.strong_correlations);
  out << YAML::EndMap;
  EmitStrings(out, "warnings", s.warnings);
  internal::EmitEstimation(out, s.estimation);
  out << YAML::EndMap;
  std::ofstream file(path);
  file << "# kinevis DIAMOND calibration (seed 001); format: docs/diamond-calibration.md.\n"
       << "# Also a robot description: robots::LoadDiamondDescription() reads the model.\n"
       << out.c_str() << "\n";
  if (!file) throw std::runtime_error("diamond calibration: cannot write " + path);
}

DiamondCalibrationFile ReadDiamondCalibration(const std::string& path) {
  YAML::Node root;
  {
    std::ifstream probe(path);
    if (!probe) throw std::runtime_error("diamond calibration file " + path + ": cannot read");
  }
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::Exception& e) {
    throw std::invalid_argument("diamond calibration file " + path + ": not YAML (" + e.what() +
                                ")");
  }
  Reader r(path);
  DiamondCalibrationFile f;
  if (!root.IsMap()) {
    r.Bad("(top level)", "not a mapping");
    r.ThrowIfBad();
  }
  const std::string kind = r.String(root, "kind", "kind");
  if (!kind.empty() && kind != kKind)
    r.Bad("kind", "expected " + std::string(kKind) + ", got " + kind);
  const int version = r.Int(root, "version", "version", 1);
  if (version > kVersion) {
    r.Bad("version", std::to_string(version) + " is newer than this reader (" +
                         std::to_string(kVersion) + ")");
  }
  if (r.String(root, "robot", "robot") != "diamond") r.Bad("robot", "must be diamond");
  f.metadata.name = r.String(root, "name", "name");
  f.metadata.created = r.String(root, "created", "created");
  f.metadata.camera = r.String(root, "camera", "camera");
  f.metadata.robot = r.String(root, "initial_robot", "initial_robot");
  f.metadata.source = r.String(root, "source", "source");

  DiamondIdentificationSummary& s = f.summary;
  robots::DiamondModel& m = s.model;
  m.radius = r.Double(root, "radius", "radius");
  m.alpha = r.Double(root, "alpha", "alpha");
  m.beta = r.Double(root, "beta", "beta");
  const auto pair = [&](const char* key, std::array<double, 2>* out) {
    const std::vector<double> v = r.Numbers(root, key, key, 2);
    *out = {v[0], v[1]};
  };
  pair("joint_offsets", &m.joint_offsets);
  pair("theta_min", &m.theta_min);
  pair("theta_max", &m.theta_max);
  m.separation_min = r.Double(root, "separation_min", "separation_min");
  m.separation_max = r.Double(root, "separation_max", "separation_max");
  m.phi_min = r.Double(root, "phi_min", "phi_min");
  m.phi_max = r.Double(root, "phi_max", "phi_max");
  m.gamma_min = r.Double(root, "gamma_min", "gamma_min");
  m.gamma_max = r.Double(root, "gamma_max", "gamma_max");

  const YAML::Node pose = r.Child(root, "camera_pose", "camera_pose");
  if (pose) {
    const std::vector<double> p = r.Numbers(pose, "position", "camera_pose.position", 3);
    const std::vector<double> qv =
        r.Numbers(pose, "quaternion_wxyz", "camera_pose.quaternion_wxyz", 4);
    const Eigen::Quaterniond q(qv[0], qv[1], qv[2], qv[3]);
    if (std::isfinite(q.norm()) && std::abs(q.norm() - 1.0) > 1e-6) {
      r.Bad("camera_pose.quaternion_wxyz",
            "not a unit quaternion (norm " + std::to_string(q.norm()) + ")");
    }
    s.X_OC = Eigen::Isometry3d::Identity();
    if (std::isfinite(q.norm()) && q.norm() > 0) s.X_OC.linear() = q.normalized().matrix();
    s.X_OC.translation() = Eigen::Vector3d(p[0], p[1], p[2]);
  }

  const YAML::Node ident = r.Child(root, "identification", "identification");
  if (ident) {
    const std::string status = r.String(ident, "status", "identification.status");
    if (!ParseEnum(status, 5, &s.status)) {
      r.Bad("identification.status", "unknown '" + status + "'");
    }
    const std::string residual = r.String(ident, "residual", "identification.residual");
    if (!ParseEnum(residual, 2, &s.residual)) {
      r.Bad("identification.residual", "unknown '" + residual + "' (pixel, spherical)");
    }
    const std::string scaling = r.String(ident, "scaling", "identification.scaling");
    if (!ParseEnum(scaling, 3, &s.scaling)) {
      r.Bad("identification.scaling", "unknown '" + scaling + "' (none, extremal, column-norm)");
    }
    s.pixel_sigma = r.Double(ident, "pixel_sigma_px", "identification.pixel_sigma_px");
    s.iterations = r.Int(ident, "iterations", "identification.iterations", -1);
    s.initial_cost = r.Double(ident, "initial_cost", "identification.initial_cost");
    s.final_cost = r.Double(ident, "final_cost", "identification.final_cost");
    s.variance_factor = r.Double(ident, "variance_factor", "identification.variance_factor");
    s.samples = r.Int(ident, "samples", "identification.samples", 0);
    s.samples_used = r.Int(ident, "samples_used", "identification.samples_used", 0);
    for (double v : r.Numbers(ident, "rejected_samples", "identification.rejected_samples", -1)) {
      s.rejected_samples.push_back(static_cast<int>(v));
    }
    s.rejected_reasons = r.Strings(ident, "rejected_reasons", "identification.rejected_reasons");
    const std::vector<double> cs =
        r.Numbers(ident, "column_scale", "identification.column_scale", kDiamondParameterCount);
    for (int j = 0; j < kDiamondParameterCount; ++j) s.column_scale[j] = cs[j];
    if (s.samples_used > s.samples) {
      r.Bad("identification.samples_used",
            std::to_string(s.samples_used) + " > samples = " + std::to_string(s.samples));
    }
  }

  const YAML::Node params = r.Child(root, "parameters", "parameters");
  for (int j = 0; j < kDiamondParameterCount && params; ++j) {
    const std::string key = std::string("parameters.") + DiamondParameterName(j);
    const YAML::Node p = r.Child(params, DiamondParameterName(j), key);
    if (!p) continue;
    DiamondParameterEstimate& e = s.parameters[j];
    e.value = r.Double(p, "value", key + ".value");
    e.initial = r.Double(p, "initial", key + ".initial");
    e.sigma = r.Double(p, "sigma", key + ".sigma", false);
    e.estimated = r.Bool(p, "estimated", key + ".estimated");
    e.identified = r.Bool(p, "identified", key + ".identified");
    if (std::isnan(e.sigma) || e.sigma < 0) r.Bad(key + ".sigma", "must be >= 0 or .inf");
  }
  {
    const std::vector<double> os =
        r.Numbers(root, "joint_offset_sigma", "joint_offset_sigma", 2, false);
    s.offset_sigma = {os[0], os[1]};
  }
  s.covariance = Eigen::MatrixXd::Zero(kDiamondParameterCount, kDiamondParameterCount);
  const YAML::Node cov = r.Child(root, "covariance", "covariance");
  if (cov) {
    if (!cov.IsSequence() || cov.size() != kDiamondParameterCount) {
      r.Bad("covariance", "must be " + std::to_string(kDiamondParameterCount) + " rows of " +
                              std::to_string(kDiamondParameterCount) + " numbers");
    } else {
      for (int i = 0; i < kDiamondParameterCount; ++i) {
        YAML::Node row_holder;
        row_holder["row"] = cov[i];
        const std::vector<double> row = r.Numbers(
            row_holder, "row", "covariance[" + std::to_string(i) + "]", kDiamondParameterCount);
        for (int c = 0; c < kDiamondParameterCount; ++c) s.covariance(i, c) = row[c];
      }
      const double asym = (s.covariance - s.covariance.transpose()).cwiseAbs().maxCoeff();
      if (asym > 1e-12 * std::max(1e-300, s.covariance.cwiseAbs().maxCoeff())) {
        r.Bad("covariance", "not symmetric (max |C - C^T| = " + std::to_string(asym) + ")");
      }
    }
  }
  const YAML::Node res = r.Child(root, "residuals", "residuals");
  if (res) {
    s.pixel_residuals = r.Statistics(res, "pixel", "residuals.pixel", "_px");
    s.task_residuals = r.Statistics(res, "task", "residuals.task", "_rad");
  }
  const YAML::Node id = r.Child(root, "identifiability", "identifiability");
  if (id) {
    IdentifiabilityReport& rep = s.identifiability;
    rep.parameters = r.Int(id, "free_parameters", "identifiability.free_parameters", 0);
    rep.rank = r.Int(id, "rank", "identifiability.rank", 0);
    rep.condition_number =
        r.Double(id, "condition_number", "identifiability.condition_number", false);
    rep.singular_values = r.Numbers(id, "singular_values", "identifiability.singular_values", -1);
    rep.unidentified = r.Strings(id, "unidentified", "identifiability.unidentified");
    rep.gauges = r.Strings(id, "gauges", "identifiability.gauges");
    rep.strong_correlations =
        r.Strings(id, "strong_correlations", "identifiability.strong_correlations");
    if (rep.rank > rep.parameters) {
      r.Bad("identifiability.rank",
            std::to_string(rep.rank) + " > free_parameters = " + std::to_string(rep.parameters));
    }
  }
  s.warnings = r.Strings(root, "warnings", "warnings");
  r.ThrowIfBad();
  if (const std::string bad = m.Validate(); !bad.empty()) r.Bad("model", bad);
  r.ThrowIfBad();
  if (version >= 2) {
    internal::CheckedYamlReader contract("diamond calibration file", path);
    s.estimation = internal::ReadEstimation(contract, root);
    contract.ThrowIfBad();
  } else {
    s.estimation = DiamondEstimationReport(s);
  }
  return f;
}

}  // namespace kinevis::calibration
