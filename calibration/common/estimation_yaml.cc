#include <cmath>
#include <limits>
#include <vector>

#include "calibration/common/estimation_yaml_internal.h"

namespace kinevis::calibration::internal {
namespace {

void EmitNumbers(YAML::Emitter& out, const double* v, Eigen::Index n) {
  out << YAML::Flow << YAML::BeginSeq;
  for (Eigen::Index i = 0; i < n; ++i) out << v[i];
  out << YAML::EndSeq;
}

void EmitStrings(YAML::Emitter& out, const std::vector<std::string>& v) {
  out << YAML::BeginSeq;
  for (const std::string& s : v) out << s;
  out << YAML::EndSeq;
}

std::vector<double> Doubles(CheckedYamlReader& in, const YAML::Node& node, const std::string& name,
                            const std::string& key) {
  std::vector<double> out;
  const YAML::Node v = in.Child(node, name, key);
  if (!v) return out;
  if (!v.IsSequence()) {
    in.Bad(key, "not a list (" + CheckedYamlReader::Dump(v) + ")");
    return out;
  }
  for (size_t i = 0; i < v.size(); ++i) {
    double d = 0.0;
    if (!v[i].IsScalar() || !YAML::convert<double>::decode(v[i], d)) {
      in.Bad(key, "element " + std::to_string(i) + " is not a number (" +
                      CheckedYamlReader::Dump(v[i]) + ")");
      return {};
    }
    out.push_back(d);
  }
  return out;
}

YAML::Node List(CheckedYamlReader& in, const YAML::Node& node, const std::string& name,
                const std::string& key) {
  const YAML::Node v = in.Child(node, name, key);
  if (v && !v.IsSequence()) {
    in.Bad(key, "not a list (" + CheckedYamlReader::Dump(v) + ")");
    return YAML::Node();
  }
  return v;
}

}  // namespace

void EmitEstimation(YAML::Emitter& out, const EstimationReport& r, const std::string& key) {
  out << YAML::Key << key << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "estimator" << YAML::Value << r.estimator;
  out << YAML::Key << "status" << YAML::Value << ToString(r.status);
  out << YAML::Key << "message" << YAML::Value << r.message;
  out << YAML::Key << "iterations" << YAML::Value << r.iterations;
  out << YAML::Key << "initial_cost" << YAML::Value << r.initial_cost;
  out << YAML::Key << "final_cost" << YAML::Value << r.final_cost;
  out << YAML::Key << "variance_factor" << YAML::Value << r.variance_factor;
  out << YAML::Key << "residuals" << YAML::Value << YAML::BeginSeq;
  for (const ResidualSummary& s : r.residuals) {
    out << YAML::Flow << YAML::BeginMap;
    out << YAML::Key << "name" << YAML::Value << s.name;
    out << YAML::Key << "unit" << YAML::Value << s.unit;
    out << YAML::Key << "count" << YAML::Value << s.count;
    out << YAML::Key << "mean" << YAML::Value << s.mean;
    out << YAML::Key << "rms" << YAML::Value << s.rms;
    out << YAML::Key << "max_abs" << YAML::Value << s.max_abs;
    out << YAML::EndMap;
  }
  out << YAML::EndSeq;
  out << YAML::Key << "parameters" << YAML::Value << YAML::BeginSeq;
  for (const ParameterEstimate& p : r.parameters) {
    out << YAML::Flow << YAML::BeginMap;
    out << YAML::Key << "name" << YAML::Value << p.name;
    out << YAML::Key << "unit" << YAML::Value << p.unit;
    out << YAML::Key << "initial" << YAML::Value << p.initial;
    out << YAML::Key << "value" << YAML::Value << p.value;
    out << YAML::Key << "sigma" << YAML::Value << p.sigma;
    out << YAML::Key << "estimated" << YAML::Value << p.estimated;
    out << YAML::Key << "identified" << YAML::Value << p.identified;
    out << YAML::EndMap;
  }
  out << YAML::EndSeq;
  out << YAML::Key << "covariance" << YAML::Value << YAML::BeginSeq;
  for (Eigen::Index i = 0; i < r.covariance.rows(); ++i) {
    const Eigen::VectorXd row = r.covariance.row(i).transpose();
    EmitNumbers(out, row.data(), row.size());
  }
  out << YAML::EndSeq;
  const Identifiability& id = r.identifiability;
  out << YAML::Key << "identifiability" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "parameters" << YAML::Value << id.parameters;
  out << YAML::Key << "rank" << YAML::Value << id.rank;
  out << YAML::Key << "condition_number" << YAML::Value << id.condition_number;
  out << YAML::Key << "condition_number_identified" << YAML::Value
      << id.condition_number_identified;
  out << YAML::Key << "singular_values" << YAML::Value;
  EmitNumbers(out, id.singular_values.data(), static_cast<Eigen::Index>(id.singular_values.size()));
  out << YAML::Key << "unidentified" << YAML::Value;
  EmitStrings(out, id.unidentified);
  out << YAML::Key << "gauges" << YAML::Value;
  EmitStrings(out, id.gauges);
  out << YAML::Key << "strong_correlations" << YAML::Value;
  EmitStrings(out, id.strong_correlations);
  out << YAML::EndMap;
  out << YAML::Key << "warnings" << YAML::Value;
  EmitStrings(out, r.warnings);
  out << YAML::EndMap;
}

EstimationReport ReadEstimation(CheckedYamlReader& in, const YAML::Node& node,
                                const std::string& key) {
  EstimationReport r;
  const YAML::Node e = in.Child(node, key, key);
  if (!e) return r;
  if (!e.IsMap()) {
    in.Bad(key, "not a mapping (" + CheckedYamlReader::Dump(e) + ")");
    return r;
  }
  const std::string k = key + ".";
  r.estimator = in.String(e, "estimator", k + "estimator");
  const std::string status = in.String(e, "status", k + "status");
  if (!status.empty() && !ParseEstimationStatus(status, &r.status)) {
    in.Bad(k + "status", "unknown (" + status + ")");
  }
  r.message = in.String(e, "message", k + "message");
  r.iterations = in.Int(e, "iterations", k + "iterations", 0);
  r.initial_cost = in.Double(e, "initial_cost", k + "initial_cost", false);
  r.final_cost = in.Double(e, "final_cost", k + "final_cost", false);
  r.variance_factor = in.Double(e, "variance_factor", k + "variance_factor", false);
  if (const YAML::Node list = List(in, e, "residuals", k + "residuals")) {
    for (size_t i = 0; i < list.size(); ++i) {
      const std::string rk = k + "residuals[" + std::to_string(i) + "].";
      ResidualSummary s;
      s.name = in.String(list[i], "name", rk + "name");
      s.unit = in.String(list[i], "unit", rk + "unit");
      s.count = in.Int(list[i], "count", rk + "count", 0);
      s.mean = in.Double(list[i], "mean", rk + "mean", false);
      s.rms = in.Double(list[i], "rms", rk + "rms", false);
      s.max_abs = in.Double(list[i], "max_abs", rk + "max_abs", false);
      r.residuals.push_back(s);
    }
  }
  if (const YAML::Node list = List(in, e, "parameters", k + "parameters")) {
    for (size_t i = 0; i < list.size(); ++i) {
      const std::string pk = k + "parameters[" + std::to_string(i) + "].";
      ParameterEstimate p;
      p.name = in.String(list[i], "name", pk + "name");
      p.unit = in.String(list[i], "unit", pk + "unit");
      p.initial = in.Double(list[i], "initial", pk + "initial", false);
      p.value = in.Double(list[i], "value", pk + "value", false);
      p.sigma = in.Double(list[i], "sigma", pk + "sigma", false);
      p.estimated = in.Bool(list[i], "estimated", pk + "estimated");
      p.identified = in.Bool(list[i], "identified", pk + "identified");
      r.parameters.push_back(p);
    }
  }
  if (const YAML::Node rows = List(in, e, "covariance", k + "covariance")) {
    const Eigen::Index n = static_cast<Eigen::Index>(rows.size());
    if (n > 0) r.covariance = Eigen::MatrixXd::Zero(n, n);
    for (Eigen::Index i = 0; i < n; ++i) {
      const std::string ck = k + "covariance[" + std::to_string(i) + "]";
      YAML::Node holder;
      holder["row"] = rows[static_cast<size_t>(i)];
      const std::vector<double> row = Doubles(in, holder, "row", ck);
      if (static_cast<Eigen::Index>(row.size()) != n) {
        in.Bad(ck, "must hold " + std::to_string(n) + " numbers");
        r.covariance.resize(0, 0);
        break;
      }
      for (Eigen::Index j = 0; j < n; ++j) r.covariance(i, j) = row[static_cast<size_t>(j)];
    }
  }
  const YAML::Node id = in.Child(e, "identifiability", k + "identifiability");
  if (id) {
    const std::string ik = k + "identifiability.";
    Identifiability& a = r.identifiability;
    a.parameters = in.Int(id, "parameters", ik + "parameters", 0);
    a.rank = in.Int(id, "rank", ik + "rank", 0);
    a.condition_number = in.Double(id, "condition_number", ik + "condition_number", false);
    a.condition_number_identified =
        in.Double(id, "condition_number_identified", ik + "condition_number_identified", false);
    a.singular_values = Doubles(in, id, "singular_values", ik + "singular_values");
    a.unidentified = in.Strings(id, "unidentified", ik + "unidentified");
    a.gauges = in.Strings(id, "gauges", ik + "gauges");
    a.strong_correlations = in.Strings(id, "strong_correlations", ik + "strong_correlations");
  }
  r.warnings = in.Strings(e, "warnings", k + "warnings");
  const std::string inconsistent = r.Validate();
  if (!inconsistent.empty()) in.Bad(key, inconsistent);
  return r;
}

}  // namespace kinevis::calibration::internal
