#include "control/weld/weld_plan_io.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <ctime>
#include <fstream>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <stdexcept>

#include "common/units.h"
#include "vision/plot/line_plot.h"

namespace kinevis::control {
namespace {

constexpr int kFormatVersion = 1;
const char* const kFormat = "kinevis-weld-plan";

std::string NowUtc() {
  const std::time_t t = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buf;
}

void EmitMm(YAML::Emitter& out, const Eigen::Vector3d& v) {
  out << YAML::Flow << YAML::BeginSeq << v.x() * 1e3 << v.y() * 1e3 << v.z() * 1e3 << YAML::EndSeq;
}

robots::Weld5IkStatus IkFromString(const std::string& s, bool* ok) {
  *ok = true;
  for (auto st : {robots::Weld5IkStatus::kConverged, robots::Weld5IkStatus::kNotReachable,
                  robots::Weld5IkStatus::kJointLimit}) {
    if (s == robots::ToString(st)) return st;
  }
  *ok = false;
  return robots::Weld5IkStatus::kNotReachable;
}

// The point columns, in the order of docs/weld-paths.md.
const char* const kPointColumns[] = {
    "kind",       "x_mm",         "y_mm",     "z_mm",       "axis_x",     "axis_y",
    "axis_z",     "sx_mm",        "sy_mm",    "sz_mm",      "u_mm",       "v_mm",
    "depth_mm",   "stand_off_mm", "tilt_deg", "arc_on",     "speed_mm_s", "ik",
    "theta1_deg", "theta2_deg",   "pz3_mm",   "theta4_deg", "theta5_deg"};
constexpr int kPointColumnCount = sizeof(kPointColumns) / sizeof(kPointColumns[0]);
const char* const kTrajectoryColumns[] = {"theta1_deg", "theta2_deg", "pz3_mm", "theta4_deg",
                                          "theta5_deg", "duration_s", "arc_on", "region",
                                          "layer",      "bead",       "point"};
constexpr int kTrajectoryColumnCount = sizeof(kTrajectoryColumns) / sizeof(kTrajectoryColumns[0]);

// Joint i in file units (deg, or mm for pz3).
double JointToFile(int i, double q) { return i == 2 ? q * 1e3 : q / common::kDeg; }
double JointFromFile(int i, double v) { return i == 2 ? v * 1e-3 : v * common::kDeg; }

// Collects every missing or bad key of a file, then throws once.
class Reader {
 public:
  explicit Reader(std::string path) : path_(std::move(path)) {}
  template <typename T>
  T Get(const YAML::Node& node, const std::string& key, const std::string& where, T fallback) {
    const YAML::Node v = node[key];
    if (!v) {
      Bad(where + key + ": missing");
      return fallback;
    }
    try {
      return v.as<T>();
    } catch (const YAML::Exception&) {
      Bad(where + key + ": bad value '" + Dump(v) + "'");
      return fallback;
    }
  }
  double Number(const YAML::Node& node, const std::string& key, const std::string& where) {
    return Get<double>(node, key, where, 0.0);
  }
  Eigen::Vector3d Vector(const YAML::Node& node, const std::string& key, const std::string& where,
                         double scale) {
    const YAML::Node v = node[key];
    if (!v || !v.IsSequence() || v.size() != 3) {
      Bad(where + key + (v ? ": not a list of 3 numbers: '" + Dump(v) + "'" : ": missing"));
      return Eigen::Vector3d::Zero();
    }
    try {
      return Eigen::Vector3d(v[0].as<double>(), v[1].as<double>(), v[2].as<double>()) * scale;
    } catch (const YAML::Exception&) {
      Bad(where + key + ": bad value '" + Dump(v) + "'");
      return Eigen::Vector3d::Zero();
    }
  }
  void Bad(const std::string& what) { problems_.push_back(what); }
  void ThrowIfBad() const {
    if (problems_.empty()) return;
    std::string m = path_ + ": ";
    for (size_t i = 0; i < problems_.size() && i < 20; ++i) m += (i ? "; " : "") + problems_[i];
    if (problems_.size() > 20) m += "; and " + std::to_string(problems_.size() - 20) + " more";
    throw std::invalid_argument(m);
  }
  static std::string Dump(const YAML::Node& n) {
    YAML::Emitter e;
    e << YAML::Flow << n;
    return e.c_str();
  }

 private:
  std::string path_;
  std::vector<std::string> problems_;
};

}  // namespace

void WriteWeldPlan(const std::string& path, const WeldPlan& plan,
                   const WeldPlanMetadata& metadata) {
  const WeldPlanOptions& o = plan.options;
  const ReferenceFit& fit = plan.reference;
  const WeldPlanSummary& s = plan.summary;
  YAML::Emitter out;
  out.SetDoublePrecision(10);
  out << YAML::BeginMap;
  out << YAML::Key << "format" << YAML::Value << kFormat;
  out << YAML::Key << "version" << YAML::Value << kFormatVersion;
  out << YAML::Key << "frame" << YAML::Value << "robot base 0";
  out << YAML::Key << "created" << YAML::Value
      << (metadata.created.empty() ? NowUtc() : metadata.created);
  out << YAML::Key << "source" << YAML::Value << metadata.source;
  out << YAML::Key << "robot" << YAML::Value << metadata.robot;
  out << YAML::Key << "status" << YAML::Value << ToString(s.status);
  out << YAML::Key << "message" << YAML::Value << s.message;

  out << YAML::Key << "options" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "reference_degree" << YAML::Value << o.reference.degree;
  out << YAML::Key << "grid_cell_mm" << YAML::Value << o.grid_cell * 1e3;
  out << YAML::Key << "depth_threshold_mm" << YAML::Value << o.depth_threshold * 1e3;
  out << YAML::Key << "min_region_area_mm2" << YAML::Value << o.min_region_area * 1e6;
  out << YAML::Key << "bead_width_mm" << YAML::Value << o.bead_width * 1e3;
  out << YAML::Key << "overlap" << YAML::Value << o.overlap;
  out << YAML::Key << "layer_height_mm" << YAML::Value << o.layer_height * 1e3;
  out << YAML::Key << "margin_mm" << YAML::Value << o.margin * 1e3;
  out << YAML::Key << "pattern" << YAML::Value << ToString(o.pattern);
  out << YAML::Key << "contour_pass" << YAML::Value << o.contour_pass;
  out << YAML::Key << "raster_angle_deg" << YAML::Value;
  if (std::isnan(o.raster_angle)) {
    out << "auto";
  } else {
    out << o.raster_angle / common::kDeg;
  }
  out << YAML::Key << "alternate_layers" << YAML::Value << o.alternate_layers;
  out << YAML::Key << "allow_reversal" << YAML::Value << o.allow_reversal;
  out << YAML::Key << "stand_off_mm" << YAML::Value << o.stand_off * 1e3;
  out << YAML::Key << "travel_speed_mm_s" << YAML::Value << o.travel_speed * 1e3;
  out << YAML::Key << "air_speed_mm_s" << YAML::Value << o.air_speed * 1e3;
  out << YAML::Key << "clearance_mm" << YAML::Value << o.clearance * 1e3;
  out << YAML::Key << "lead_in_mm" << YAML::Value << o.lead_in * 1e3;
  out << YAML::Key << "lead_out_mm" << YAML::Value << o.lead_out * 1e3;
  out << YAML::Key << "point_spacing_mm" << YAML::Value << o.point_spacing * 1e3;
  out << YAML::Key << "transit_spacing_mm" << YAML::Value << o.transit_spacing * 1e3;
  out << YAML::Key << "max_torch_tilt_deg" << YAML::Value << o.ik.max_tilt / common::kDeg;
  out << YAML::Key << "air_joint_speed_fraction" << YAML::Value << o.air_joint_speed_fraction;
  out << YAML::Key << "max_segment_duration_s" << YAML::Value << o.max_segment_duration;
  out << YAML::EndMap;

  out << YAML::Key << "process" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "wire_diameter_mm" << YAML::Value << o.process.wire_diameter * 1e3;
  out << YAML::Key << "wire_feed_speed_m_min" << YAML::Value << o.process.wire_feed_speed * 60.0;
  out << YAML::Key << "current_A" << YAML::Value << o.process.current;
  out << YAML::Key << "voltage_V" << YAML::Value << o.process.voltage;
  out << YAML::Key << "deposition_efficiency" << YAML::Value << o.process.deposition_efficiency;
  out << YAML::EndMap;

  const ReferenceSurface& ref = fit.surface;
  const Eigen::Quaterniond qr(ref.X_0R.linear());
  out << YAML::Key << "reference_surface" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "status" << YAML::Value << ToString(fit.status);
  out << YAML::Key << "position_mm" << YAML::Value;
  EmitMm(out, ref.X_0R.translation());
  out << YAML::Key << "quaternion_wxyz" << YAML::Value << YAML::Flow << YAML::BeginSeq << qr.w()
      << qr.x() << qr.y() << qr.z() << YAML::EndSeq;
  out << YAML::Key << "degree" << YAML::Value << ref.degree;
  out << YAML::Key << "length_scale_mm" << YAML::Value << ref.length_scale * 1e3;
  out << YAML::Key << "coefficients_mm" << YAML::Value << YAML::Flow << YAML::BeginSeq;
  for (int k = 0; k < ref.coefficients.size(); ++k) out << ref.coefficients(k) * 1e3;
  out << YAML::EndSeq;
  out << YAML::Key << "points" << YAML::Value << fit.points;
  out << YAML::Key << "inlier_fraction" << YAML::Value << fit.inlier_fraction;
  out << YAML::Key << "inlier_rms_mm" << YAML::Value << fit.inlier_rms * 1e3;
  out << YAML::Key << "robust_scale_mm" << YAML::Value << fit.robust_scale * 1e3;
  out << YAML::Key << "max_slope_deg" << YAML::Value << fit.max_slope_deg;
  out << YAML::Key << "iterations" << YAML::Value << fit.iterations;
  out << YAML::EndMap;

  out << YAML::Key << "summary" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "map_points" << YAML::Value << s.map_points;
  out << YAML::Key << "regions" << YAML::Value << s.regions;
  out << YAML::Key << "rejected_regions" << YAML::Value << s.rejected_regions;
  out << YAML::Key << "layers" << YAML::Value << s.layers;
  out << YAML::Key << "beads" << YAML::Value << s.beads;
  out << YAML::Key << "executable_beads" << YAML::Value << s.executable_beads;
  out << YAML::Key << "points" << YAML::Value << s.points;
  out << YAML::Key << "unreachable_points" << YAML::Value << s.unreachable_points;
  out << YAML::Key << "damaged_area_mm2" << YAML::Value << s.damaged_area * 1e6;
  out << YAML::Key << "coverage" << YAML::Value << s.coverage;
  out << YAML::Key << "coverage_executable" << YAML::Value << s.coverage_executable;
  out << YAML::Key << "weld_length_mm" << YAML::Value << s.weld_length * 1e3;
  out << YAML::Key << "arc_time_s" << YAML::Value << s.arc_time;
  out << YAML::Key << "total_time_s" << YAML::Value << s.total_time;
  out << YAML::Key << "max_joint_speed_ratio" << YAML::Value << s.max_joint_speed_ratio;
  out << YAML::Key << "max_tilt_deg" << YAML::Value << s.max_tilt / common::kDeg;
  out << YAML::Key << "mean_tilt_deg" << YAML::Value << s.mean_tilt / common::kDeg;
  out << YAML::Key << "max_interpolation_error_mm" << YAML::Value
      << s.max_interpolation_error * 1e3;
  out << YAML::Key << "speed_limited_segments" << YAML::Value << s.speed_limited_segments;
  out << YAML::Key << "problems" << YAML::Value << YAML::BeginSeq;
  for (const auto& p : s.problems) out << p;
  out << YAML::EndSeq;
  out << YAML::Key << "warnings" << YAML::Value << YAML::BeginSeq;
  for (const auto& w : s.warnings) out << w;
  out << YAML::EndSeq;
  out << YAML::EndMap;

  out << YAML::Key << "rejected_regions" << YAML::Value << YAML::BeginSeq;
  for (const auto& r : plan.rejected) {
    out << YAML::BeginMap;
    out << YAML::Key << "cells" << YAML::Value << r.cells;
    out << YAML::Key << "area_mm2" << YAML::Value << r.area * 1e6;
    out << YAML::Key << "max_depth_mm" << YAML::Value << r.max_depth * 1e3;
    out << YAML::Key << "centroid_mm" << YAML::Value;
    EmitMm(out, r.centroid_0);
    out << YAML::Key << "reason" << YAML::Value << r.reason;
    out << YAML::EndMap;
  }
  out << YAML::EndSeq;

  out << YAML::Key << "point_columns" << YAML::Value << YAML::Flow << YAML::BeginSeq;
  for (const char* c : kPointColumns) out << c;
  out << YAML::EndSeq;
  out << YAML::Key << "regions" << YAML::Value << YAML::BeginSeq;
  for (const auto& rp : plan.regions) {
    const DamageRegion& r = rp.region;
    out << YAML::BeginMap;
    out << YAML::Key << "id" << YAML::Value << r.id;
    out << YAML::Key << "cells" << YAML::Value << r.cells;
    out << YAML::Key << "area_mm2" << YAML::Value << r.area * 1e6;
    out << YAML::Key << "max_depth_mm" << YAML::Value << r.max_depth * 1e3;
    out << YAML::Key << "mean_depth_mm" << YAML::Value << r.mean_depth * 1e3;
    out << YAML::Key << "volume_mm3" << YAML::Value << r.volume * 1e9;
    out << YAML::Key << "centroid_mm" << YAML::Value;
    EmitMm(out, r.centroid_0);
    out << YAML::Key << "deepest_uv_mm" << YAML::Value << YAML::Flow << YAML::BeginSeq
        << r.deepest_uv.x() * 1e3 << r.deepest_uv.y() * 1e3 << YAML::EndSeq;
    out << YAML::Key << "touches_map_edge" << YAML::Value << r.touches_map_edge;
    out << YAML::Key << "layers" << YAML::Value << YAML::BeginSeq;
    for (const auto& layer : rp.layers) {
      out << YAML::BeginMap;
      out << YAML::Key << "index" << YAML::Value << layer.index;
      out << YAML::Key << "depth_top_mm" << YAML::Value << layer.depth_top * 1e3;
      out << YAML::Key << "depth_bottom_mm" << YAML::Value << layer.depth_bottom * 1e3;
      out << YAML::Key << "footprint_area_mm2" << YAML::Value << layer.footprint_area * 1e6;
      out << YAML::Key << "beads" << YAML::Value << YAML::BeginSeq;
      for (const auto& b : layer.beads) {
        out << YAML::BeginMap;
        out << YAML::Key << "id" << YAML::Value << b.id;
        out << YAML::Key << "kind" << YAML::Value << ToString(b.kind);
        out << YAML::Key << "weld_length_mm" << YAML::Value << b.weld_length * 1e3;
        out << YAML::Key << "reachable" << YAML::Value << b.reachable;
        out << YAML::Key << "executable" << YAML::Value << b.executable;
        out << YAML::Key << "problem" << YAML::Value << b.problem;
        out << YAML::Key << "points" << YAML::Value << YAML::BeginSeq;
        for (const auto& p : b.points) {
          out << YAML::Flow << YAML::BeginSeq << ToString(p.kind) << p.p_0T.x() * 1e3
              << p.p_0T.y() * 1e3 << p.p_0T.z() * 1e3 << p.u_0T.x() << p.u_0T.y() << p.u_0T.z()
              << p.p_0S.x() * 1e3 << p.p_0S.y() * 1e3 << p.p_0S.z() * 1e3 << p.uv_R.x() * 1e3
              << p.uv_R.y() * 1e3 << p.depth * 1e3 << p.stand_off * 1e3 << p.tilt / common::kDeg
              << (p.arc_on ? 1 : 0) << p.speed * 1e3 << robots::ToString(p.ik);
          for (int i = 0; i < robots::kWeld5Joints; ++i) out << JointToFile(i, p.q(i));
          out << YAML::EndSeq;
        }
        out << YAML::EndSeq;
        out << YAML::EndMap;
      }
      out << YAML::EndSeq;
      out << YAML::EndMap;
    }
    out << YAML::EndSeq;
    out << YAML::EndMap;
  }
  out << YAML::EndSeq;

  out << YAML::Key << "trajectory_columns" << YAML::Value << YAML::Flow << YAML::BeginSeq;
  for (const char* c : kTrajectoryColumns) out << c;
  out << YAML::EndSeq;
  out << YAML::Key << "trajectory" << YAML::Value << YAML::BeginSeq;
  for (size_t k = 0; k < plan.trajectory.size(); ++k) {
    const auto& t = plan.trajectory[k];
    const auto& src = plan.trajectory_source[k];
    out << YAML::Flow << YAML::BeginSeq;
    for (int i = 0; i < robots::kWeld5Joints; ++i) out << JointToFile(i, t.joints[i]);
    out << t.duration << (t.arc_on ? 1 : 0) << src.region << src.layer << src.bead << src.point
        << YAML::EndSeq;
  }
  out << YAML::EndSeq;
  out << YAML::EndMap;

  std::ofstream f(path);
  f << out.c_str() << "\n";
  f.close();
  if (!f) throw std::runtime_error("WriteWeldPlan: cannot write " + path);
}

WeldPlanFile ReadWeldPlan(const std::string& path) {
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::BadFile&) {
    throw std::runtime_error("ReadWeldPlan: cannot read " + path);
  } catch (const YAML::Exception& e) {
    throw std::runtime_error("ReadWeldPlan: " + path + ": not YAML: " + e.what());
  }
  Reader rd(path);
  WeldPlanFile file;
  WeldPlan& plan = file.plan;
  if (rd.Get<std::string>(root, "format", "", "") != kFormat) {
    rd.Bad("format: not '" + std::string(kFormat) + "'");
    rd.ThrowIfBad();
  }
  const int version = rd.Get<int>(root, "version", "", 0);
  if (version != kFormatVersion) rd.Bad("version: " + std::to_string(version) + " (reads 1)");
  file.metadata.created = rd.Get<std::string>(root, "created", "", "");
  file.metadata.source = rd.Get<std::string>(root, "source", "", "");
  file.metadata.robot = rd.Get<std::string>(root, "robot", "", "");
  const std::string status = rd.Get<std::string>(root, "status", "", "");
  bool status_ok = false;
  for (auto st : {WeldPlanStatus::kPlanned, WeldPlanStatus::kPartial,
                  WeldPlanStatus::kNothingToRepair, WeldPlanStatus::kFailed}) {
    if (status == ToString(st)) plan.summary.status = st, status_ok = true;
  }
  if (!status_ok) rd.Bad("status: bad value '" + status + "'");
  plan.summary.message = rd.Get<std::string>(root, "message", "", "");

  WeldPlanOptions& o = plan.options;
  const YAML::Node on = root["options"];
  const std::string w = "options.";
  if (!on) {
    rd.Bad("options: missing");
  } else {
    o.reference.degree = rd.Get<int>(on, "reference_degree", w, 2);
    o.grid_cell = rd.Number(on, "grid_cell_mm", w) * 1e-3;
    o.depth_threshold = rd.Number(on, "depth_threshold_mm", w) * 1e-3;
    o.min_region_area = rd.Number(on, "min_region_area_mm2", w) * 1e-6;
    o.bead_width = rd.Number(on, "bead_width_mm", w) * 1e-3;
    o.overlap = rd.Number(on, "overlap", w);
    o.layer_height = rd.Number(on, "layer_height_mm", w) * 1e-3;
    o.margin = rd.Number(on, "margin_mm", w) * 1e-3;
    const std::string pattern = rd.Get<std::string>(on, "pattern", w, "raster");
    if (pattern == "raster") {
      o.pattern = BeadPattern::kRaster;
    } else if (pattern == "zigzag") {
      o.pattern = BeadPattern::kZigZag;
    } else {
      rd.Bad(w + "pattern: bad value '" + pattern + "' (raster or zigzag)");
    }
    o.contour_pass = rd.Get<bool>(on, "contour_pass", w, true);
    const std::string angle = rd.Get<std::string>(on, "raster_angle_deg", w, "auto");
    if (angle == "auto") {
      o.raster_angle = std::nan("");
    } else {
      o.raster_angle = rd.Number(on, "raster_angle_deg", w) * common::kDeg;
    }
    o.alternate_layers = rd.Get<bool>(on, "alternate_layers", w, true);
    o.allow_reversal = rd.Get<bool>(on, "allow_reversal", w, true);
    o.stand_off = rd.Number(on, "stand_off_mm", w) * 1e-3;
    o.travel_speed = rd.Number(on, "travel_speed_mm_s", w) * 1e-3;
    o.air_speed = rd.Number(on, "air_speed_mm_s", w) * 1e-3;
    o.clearance = rd.Number(on, "clearance_mm", w) * 1e-3;
    o.lead_in = rd.Number(on, "lead_in_mm", w) * 1e-3;
    o.lead_out = rd.Number(on, "lead_out_mm", w) * 1e-3;
    o.point_spacing = rd.Number(on, "point_spacing_mm", w) * 1e-3;
    o.transit_spacing = rd.Number(on, "transit_spacing_mm", w) * 1e-3;
    o.ik.max_tilt = rd.Number(on, "max_torch_tilt_deg", w) * common::kDeg;
    o.air_joint_speed_fraction = rd.Number(on, "air_joint_speed_fraction", w);
    o.max_segment_duration = rd.Number(on, "max_segment_duration_s", w);
  }
  if (const YAML::Node pn = root["process"]; !pn) {
    rd.Bad("process: missing");
  } else {
    const std::string p = "process.";
    o.process.wire_diameter = rd.Number(pn, "wire_diameter_mm", p) * 1e-3;
    o.process.wire_feed_speed = rd.Number(pn, "wire_feed_speed_m_min", p) / 60.0;
    o.process.current = rd.Number(pn, "current_A", p);
    o.process.voltage = rd.Number(pn, "voltage_V", p);
    o.process.deposition_efficiency = rd.Number(pn, "deposition_efficiency", p);
  }

  if (const YAML::Node rn = root["reference_surface"]; !rn) {
    rd.Bad("reference_surface: missing");
  } else {
    const std::string p = "reference_surface.";
    ReferenceFit& fit = plan.reference;
    const std::string st = rd.Get<std::string>(rn, "status", p, "");
    bool ok = false;
    for (auto s : {ReferenceFitStatus::kOk, ReferenceFitStatus::kTooFewPoints,
                   ReferenceFitStatus::kDegenerate}) {
      if (st == ToString(s)) fit.status = s, ok = true;
    }
    if (!ok) rd.Bad(p + "status: bad value '" + st + "'");
    ReferenceSurface& ref = fit.surface;
    ref.X_0R.translation() = rd.Vector(rn, "position_mm", p, 1e-3);
    const YAML::Node qn = rn["quaternion_wxyz"];
    if (!qn || !qn.IsSequence() || qn.size() != 4) {
      rd.Bad(p + "quaternion_wxyz: missing or not 4 numbers");
    } else {
      Eigen::Quaterniond q(qn[0].as<double>(), qn[1].as<double>(), qn[2].as<double>(),
                           qn[3].as<double>());
      if (std::abs(q.norm() - 1.0) > 1e-6) {
        rd.Bad(p + "quaternion_wxyz: not unit (norm " + std::to_string(q.norm()) + ")");
      }
      ref.X_0R.linear() = q.normalized().toRotationMatrix();
    }
    ref.degree = rd.Get<int>(rn, "degree", p, 2);
    ref.length_scale = rd.Number(rn, "length_scale_mm", p) * 1e-3;
    const YAML::Node cn = rn["coefficients_mm"];
    if (ref.degree < 1 || ref.degree > 4) {
      rd.Bad(p + "degree: " + std::to_string(ref.degree) + " (1..4)");
    } else if (!cn || !cn.IsSequence() ||
               static_cast<int>(cn.size()) != ReferenceSurface::CoefficientCount(ref.degree)) {
      rd.Bad(p + "coefficients_mm: need " +
             std::to_string(ReferenceSurface::CoefficientCount(ref.degree)) + " numbers");
    } else {
      ref.coefficients.resize(cn.size());
      for (size_t k = 0; k < cn.size(); ++k) ref.coefficients(k) = cn[k].as<double>() * 1e-3;
    }
    fit.points = rd.Get<int>(rn, "points", p, 0);
    fit.inlier_fraction = rd.Number(rn, "inlier_fraction", p);
    fit.inlier_rms = rd.Number(rn, "inlier_rms_mm", p) * 1e-3;
    fit.robust_scale = rd.Number(rn, "robust_scale_mm", p) * 1e-3;
    fit.max_slope_deg = rd.Number(rn, "max_slope_deg", p);
    fit.iterations = rd.Get<int>(rn, "iterations", p, 0);
  }

  if (const YAML::Node sn = root["summary"]; !sn) {
    rd.Bad("summary: missing");
  } else {
    const std::string p = "summary.";
    WeldPlanSummary& s = plan.summary;
    s.map_points = rd.Get<size_t>(sn, "map_points", p, 0);
    s.regions = rd.Get<int>(sn, "regions", p, 0);
    s.rejected_regions = rd.Get<int>(sn, "rejected_regions", p, 0);
    s.layers = rd.Get<int>(sn, "layers", p, 0);
    s.beads = rd.Get<int>(sn, "beads", p, 0);
    s.executable_beads = rd.Get<int>(sn, "executable_beads", p, 0);
    s.points = rd.Get<int>(sn, "points", p, 0);
    s.unreachable_points = rd.Get<int>(sn, "unreachable_points", p, 0);
    s.damaged_area = rd.Number(sn, "damaged_area_mm2", p) * 1e-6;
    s.coverage = rd.Number(sn, "coverage", p);
    s.coverage_executable = rd.Number(sn, "coverage_executable", p);
    s.weld_length = rd.Number(sn, "weld_length_mm", p) * 1e-3;
    s.arc_time = rd.Number(sn, "arc_time_s", p);
    s.total_time = rd.Number(sn, "total_time_s", p);
    s.max_joint_speed_ratio = rd.Number(sn, "max_joint_speed_ratio", p);
    s.max_tilt = rd.Number(sn, "max_tilt_deg", p) * common::kDeg;
    s.mean_tilt = rd.Number(sn, "mean_tilt_deg", p) * common::kDeg;
    s.max_interpolation_error = rd.Number(sn, "max_interpolation_error_mm", p) * 1e-3;
    s.speed_limited_segments = rd.Get<int>(sn, "speed_limited_segments", p, 0);
    s.problems = rd.Get<std::vector<std::string>>(sn, "problems", p, {});
    s.warnings = rd.Get<std::vector<std::string>>(sn, "warnings", p, {});
  }

  for (const YAML::Node& rn : root["rejected_regions"]) {
    RejectedRegion r;
    const std::string p = "rejected_regions[].";
    r.cells = rd.Get<int>(rn, "cells", p, 0);
    r.area = rd.Number(rn, "area_mm2", p) * 1e-6;
    r.max_depth = rd.Number(rn, "max_depth_mm", p) * 1e-3;
    r.centroid_0 = rd.Vector(rn, "centroid_mm", p, 1e-3);
    r.reason = rd.Get<std::string>(rn, "reason", p, "");
    plan.rejected.push_back(r);
  }

  const YAML::Node pc = root["point_columns"];
  if (!pc || !pc.IsSequence() || static_cast<int>(pc.size()) != kPointColumnCount) {
    rd.Bad("point_columns: missing or not the " + std::to_string(kPointColumnCount) +
           " columns of version 1");
  } else {
    for (int k = 0; k < kPointColumnCount; ++k) {
      if (pc[k].as<std::string>() != kPointColumns[k]) {
        rd.Bad("point_columns[" + std::to_string(k) + "]: '" + pc[k].as<std::string>() +
               "', expected '" + kPointColumns[k] + "'");
      }
    }
  }
  rd.ThrowIfBad();

  int ri = 0;
  for (const YAML::Node& rn : root["regions"]) {
    const std::string p = "regions[" + std::to_string(ri++) + "].";
    WeldRegionPlan rp;
    DamageRegion& r = rp.region;
    r.id = rd.Get<int>(rn, "id", p, 0);
    r.cells = rd.Get<int>(rn, "cells", p, 0);
    r.area = rd.Number(rn, "area_mm2", p) * 1e-6;
    r.max_depth = rd.Number(rn, "max_depth_mm", p) * 1e-3;
    r.mean_depth = rd.Number(rn, "mean_depth_mm", p) * 1e-3;
    r.volume = rd.Number(rn, "volume_mm3", p) * 1e-9;
    r.centroid_0 = rd.Vector(rn, "centroid_mm", p, 1e-3);
    const auto duv = rd.Get<std::vector<double>>(rn, "deepest_uv_mm", p, {0.0, 0.0});
    if (duv.size() == 2) r.deepest_uv = Eigen::Vector2d(duv[0], duv[1]) * 1e-3;
    r.touches_map_edge = rd.Get<bool>(rn, "touches_map_edge", p, false);
    int li = 0;
    for (const YAML::Node& ln : rn["layers"]) {
      const std::string lp = p + "layers[" + std::to_string(li++) + "].";
      WeldLayer layer;
      layer.index = rd.Get<int>(ln, "index", lp, 0);
      layer.depth_top = rd.Number(ln, "depth_top_mm", lp) * 1e-3;
      layer.depth_bottom = rd.Number(ln, "depth_bottom_mm", lp) * 1e-3;
      layer.footprint_area = rd.Number(ln, "footprint_area_mm2", lp) * 1e-6;
      int bi = 0;
      for (const YAML::Node& bn : ln["beads"]) {
        const std::string bp = lp + "beads[" + std::to_string(bi++) + "].";
        WeldBead b;
        b.id = rd.Get<int>(bn, "id", bp, 0);
        const std::string kind = rd.Get<std::string>(bn, "kind", bp, "raster");
        bool kind_ok = false;
        for (auto k : {BeadKind::kRaster, BeadKind::kZigZag, BeadKind::kContour}) {
          if (kind == ToString(k)) b.kind = k, kind_ok = true;
        }
        if (!kind_ok) rd.Bad(bp + "kind: bad value '" + kind + "'");
        b.weld_length = rd.Number(bn, "weld_length_mm", bp) * 1e-3;
        b.reachable = rd.Get<bool>(bn, "reachable", bp, false);
        b.executable = rd.Get<bool>(bn, "executable", bp, false);
        b.problem = rd.Get<std::string>(bn, "problem", bp, "");
        int pi = 0;
        for (const YAML::Node& pn : bn["points"]) {
          const std::string pp = bp + "points[" + std::to_string(pi++) + "]";
          if (!pn.IsSequence() || static_cast<int>(pn.size()) != kPointColumnCount) {
            rd.Bad(pp + ": not " + std::to_string(kPointColumnCount) + " columns");
            continue;
          }
          try {
            WeldPoint q;
            const std::string k = pn[0].as<std::string>();
            bool k_ok = false;
            for (auto kk :
                 {WeldPointKind::kTransit, WeldPointKind::kApproach, WeldPointKind::kLeadIn,
                  WeldPointKind::kWeld, WeldPointKind::kLeadOut, WeldPointKind::kRetract}) {
              if (k == ToString(kk)) q.kind = kk, k_ok = true;
            }
            if (!k_ok) rd.Bad(pp + ": kind '" + k + "'");
            auto num = [&](int c) { return pn[c].as<double>(); };
            q.p_0T = Eigen::Vector3d(num(1), num(2), num(3)) * 1e-3;
            q.u_0T = Eigen::Vector3d(num(4), num(5), num(6));
            q.p_0S = Eigen::Vector3d(num(7), num(8), num(9)) * 1e-3;
            q.uv_R = Eigen::Vector2d(num(10), num(11)) * 1e-3;
            q.depth = num(12) * 1e-3;
            q.stand_off = num(13) * 1e-3;
            q.tilt = num(14) * common::kDeg;
            q.arc_on = num(15) != 0.0;
            q.speed = num(16) * 1e-3;
            bool ik_ok = false;
            q.ik = IkFromString(pn[17].as<std::string>(), &ik_ok);
            if (!ik_ok) rd.Bad(pp + ": ik '" + pn[17].as<std::string>() + "'");
            for (int i = 0; i < robots::kWeld5Joints; ++i) q.q(i) = JointFromFile(i, num(18 + i));
            b.points.push_back(q);
          } catch (const YAML::Exception&) {
            rd.Bad(pp + ": bad value '" + Reader::Dump(pn) + "'");
          }
        }
        layer.beads.push_back(std::move(b));
      }
      rp.layers.push_back(std::move(layer));
    }
    plan.regions.push_back(std::move(rp));
  }

  const YAML::Node tc = root["trajectory_columns"];
  if (!tc || !tc.IsSequence() || static_cast<int>(tc.size()) != kTrajectoryColumnCount) {
    rd.Bad("trajectory_columns: missing or not the " + std::to_string(kTrajectoryColumnCount) +
           " columns of version 1");
  }
  int ti = 0;
  for (const YAML::Node& tn : root["trajectory"]) {
    const std::string tp = "trajectory[" + std::to_string(ti++) + "]";
    if (!tn.IsSequence() || static_cast<int>(tn.size()) != kTrajectoryColumnCount) {
      rd.Bad(tp + ": not " + std::to_string(kTrajectoryColumnCount) + " columns");
      continue;
    }
    try {
      hal::WeldTrajectoryPoint t;
      for (int i = 0; i < robots::kWeld5Joints; ++i) {
        t.joints[i] = JointFromFile(i, tn[i].as<double>());
      }
      t.duration = tn[5].as<double>();
      t.arc_on = tn[6].as<double>() != 0.0;
      TrajectorySource s{tn[7].as<int>(), tn[8].as<int>(), tn[9].as<int>(), tn[10].as<int>()};
      const bool in_range =
          s.region >= 0 && s.region < static_cast<int>(plan.regions.size()) && s.layer >= 0 &&
          s.layer < static_cast<int>(plan.regions[s.region].layers.size()) && s.bead >= 0 &&
          s.bead < static_cast<int>(plan.regions[s.region].layers[s.layer].beads.size()) &&
          s.point >= 0 &&
          s.point <
              static_cast<int>(plan.regions[s.region].layers[s.layer].beads[s.bead].points.size());
      if (!in_range) rd.Bad(tp + ": source (region, layer, bead, point) not in the plan");
      if (!(t.duration >= 1e-3))
        rd.Bad(tp + ": duration_s " + std::to_string(t.duration) + " < 0.001");
      plan.trajectory.push_back(t);
      plan.trajectory_source.push_back(s);
    } catch (const YAML::Exception&) {
      rd.Bad(tp + ": bad value '" + Reader::Dump(tn) + "'");
    }
  }
  rd.ThrowIfBad();
  return file;
}

namespace {

cv::Scalar LayerColour(int layer) {
  static const cv::Scalar kPalette[] = {{255, 255, 255}, {255, 200, 0}, {0, 255, 0},
                                        {255, 0, 255},   {0, 200, 255}, {255, 128, 128},
                                        {128, 255, 255}, {180, 180, 0}};
  return kPalette[layer % 8];
}

void RequireGrid(const WeldPlan& plan, const char* who) {
  if (plan.grid.nu <= 0 || plan.grid.nv <= 0 || plan.grid.depth.empty()) {
    throw std::invalid_argument(std::string(who) +
                                ": the plan has no depth grid (plan it with PlanWeldRepair)");
  }
}

}  // namespace

void WriteWeldPlanTopView(const std::string& path, const WeldPlan& plan) {
  RequireGrid(plan, "WriteWeldPlanTopView");
  const DepthGrid& g = plan.grid;
  const int scale = std::max(1, 1000 / std::max(g.nu, g.nv));
  double max_depth = plan.options.depth_threshold * 2.0;
  for (const auto& r : plan.regions) max_depth = std::max(max_depth, r.region.max_depth);
  cv::Mat grey(g.nv, g.nu, CV_8UC1), valid(g.nv, g.nu, CV_8UC1), regions(g.nv, g.nu, CV_8UC1);
  for (int j = 0; j < g.nv; ++j) {
    for (int i = 0; i < g.nu; ++i) {
      const int row = g.nv - 1 - j;  // y_R up
      const float d = g.depth[g.index(i, j)];
      valid.at<uint8_t>(row, i) = std::isfinite(d) ? 255 : 0;
      grey.at<uint8_t>(row, i) = static_cast<uint8_t>(
          std::clamp(std::isfinite(d) ? d / max_depth * 255.0 : 0.0, 0.0, 255.0));
      regions.at<uint8_t>(row, i) = g.region[g.index(i, j)] >= 0 ? 255 : 0;
    }
  }
  cv::Mat colour;
  cv::applyColorMap(grey, colour, cv::COLORMAP_TURBO);
  colour.setTo(cv::Scalar(0, 0, 0), valid == 0);
  cv::Mat big;
  cv::resize(colour, big, cv::Size(g.nu * scale, g.nv * scale), 0, 0, cv::INTER_NEAREST);
  cv::Mat regions_big;
  cv::resize(regions, regions_big, big.size(), 0, 0, cv::INTER_NEAREST);
  std::vector<std::vector<cv::Point>> outlines;
  cv::findContours(regions_big, outlines, cv::RETR_LIST, cv::CHAIN_APPROX_SIMPLE);
  cv::drawContours(big, outlines, -1, cv::Scalar(255, 255, 255), 1, cv::LINE_AA);
  auto px = [&](const Eigen::Vector2d& uv) {
    return cv::Point2d((uv.x() - g.u0) / g.cell * scale, (g.nv - (uv.y() - g.v0) / g.cell) * scale);
  };
  const ReferenceSurface& ref = plan.reference.surface;
  for (const auto& r : plan.rejected) {
    const Eigen::Vector3d q = ref.ToR(r.centroid_0);
    cv::circle(big, px(q.head<2>()), 6, cv::Scalar(255, 0, 255), 1, cv::LINE_AA);
  }
  for (const auto& rp : plan.regions) {
    for (const auto& layer : rp.layers) {
      for (const auto& b : layer.beads) {
        const cv::Scalar c = b.executable ? LayerColour(layer.index) : cv::Scalar(0, 0, 255);
        for (size_t k = 1; k < b.points.size(); ++k) {
          if (!b.points[k].arc_on) continue;
          cv::line(big, px(b.points[k - 1].uv_R), px(b.points[k].uv_R), c, 1, cv::LINE_AA);
        }
      }
    }
  }
  // Scale bar, legend.
  const int bar = static_cast<int>(std::lround(0.010 / g.cell * scale));
  const cv::Point o(10, big.rows - 12);
  cv::line(big, o, o + cv::Point(bar, 0), cv::Scalar(255, 255, 255), 2);
  cv::putText(big, "10 mm", o + cv::Point(bar + 6, 4), cv::FONT_HERSHEY_SIMPLEX, 0.45,
              cv::Scalar(255, 255, 255), 1, cv::LINE_AA);
  std::ostringstream legend;
  legend.precision(3);
  legend << "depth 0.." << max_depth * 1e3 << " mm (turbo); beads by layer, red: unreachable";
  cv::putText(big, legend.str(), cv::Point(10, 18), cv::FONT_HERSHEY_SIMPLEX, 0.45,
              cv::Scalar(255, 255, 255), 1, cv::LINE_AA);
  bool written = false;
  try {
    written = cv::imwrite(path, big);
  } catch (const cv::Exception&) {
    written = false;
  }
  if (!written) throw std::runtime_error("WriteWeldPlanTopView: cannot write " + path);
}

void WriteWeldPlanSection(const std::string& path, const WeldPlan& plan, int region) {
  RequireGrid(plan, "WriteWeldPlanSection");
  if (region < 0 || region >= static_cast<int>(plan.regions.size())) {
    throw std::invalid_argument("WriteWeldPlanSection: region " + std::to_string(region) +
                                " out of range (the plan has " +
                                std::to_string(plan.regions.size()) + ")");
  }
  const DepthGrid& g = plan.grid;
  const WeldRegionPlan& rp = plan.regions[region];
  const double v0 = rp.region.deepest_uv.y();
  const int j = std::clamp(static_cast<int>((v0 - g.v0) / g.cell), 0, g.nv - 1);
  int imin = g.nu, imax = -1;
  for (int i = 0; i < g.nu; ++i) {
    if (g.region[g.index(i, j)] == rp.region.id) imin = std::min(imin, i), imax = std::max(imax, i);
  }
  const int pad = static_cast<int>((plan.options.margin + plan.options.bead_width + 5e-3) / g.cell);
  imin = std::max(0, imin - pad);
  imax = std::min(g.nu - 1, imax + pad);
  vision::plot::LinePlotOptions po;
  po.title = "region " + std::to_string(rp.region.id) +
             ": section along x_R at y_R = " + std::to_string(v0 * 1e3).substr(0, 6) + " mm";
  po.x_label = "x_R (mm)";
  po.y_label = "height above the reference (mm)";
  vision::plot::LinePlot plot(po);
  vision::plot::Series scan{"scan (cell medians)", {}, {}};
  vision::plot::Series refl{"reference", {}, {}};
  vision::plot::Series thr{"damage threshold", {}, {}};
  for (int i = imin; i <= imax; ++i) {
    const double u = g.Centre(i, j).x() * 1e3;
    const float d = g.depth[g.index(i, j)];
    scan.x.push_back(u);
    scan.y.push_back(std::isfinite(d) ? -d * 1e3 : std::nan(""));
  }
  const double u_lo = g.Centre(imin, j).x() * 1e3, u_hi = g.Centre(imax, j).x() * 1e3;
  refl.x = {u_lo, u_hi};
  refl.y = {0.0, 0.0};
  thr.x = {u_lo, u_hi};
  thr.y = {-plan.options.depth_threshold * 1e3, -plan.options.depth_threshold * 1e3};
  plot.AddSeries(scan);
  plot.AddSeries(refl);
  plot.AddSeries(thr);
  const double band = 0.5 * (1.0 - plan.options.overlap) * plan.options.bead_width;
  for (const auto& layer : rp.layers) {
    // The deposition surface under this layer's weld points that lie on the section.
    std::vector<std::pair<double, double>> pts;
    for (const auto& b : layer.beads) {
      for (const auto& p : b.points) {
        if (p.kind == WeldPointKind::kWeld && std::abs(p.uv_R.y() - v0) <= band) {
          pts.push_back({p.uv_R.x() * 1e3, -p.depth * 1e3});
        }
      }
    }
    if (pts.empty()) continue;
    std::sort(pts.begin(), pts.end());
    vision::plot::Series s{"layer " + std::to_string(layer.index) + " deposition surface", {}, {}};
    s.thickness_px = 1;
    for (const auto& [x, y] : pts) s.x.push_back(x), s.y.push_back(y);
    plot.AddSeries(s);
    vision::plot::Series top{"layer " + std::to_string(layer.index) + " top", {}, {}};
    top.x = {pts.front().first, pts.back().first};
    top.y = {-layer.depth_top * 1e3, -layer.depth_top * 1e3};
    top.thickness_px = 1;
    plot.AddSeries(top);
  }
  plot.WritePng(path);
}

}  // namespace kinevis::control
