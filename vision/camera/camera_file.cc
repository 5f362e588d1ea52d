#include "vision/camera/camera_file.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <map>
#include <stdexcept>

#include "common/units.h"
#include "vision/camera/camera_info_yaml.h"
#include "vision/camera/hyperbolic_mirror_camera.h"
#include "vision/camera/pinhole_camera.h"
#include "vision/camera/scaramuzza_camera.h"
#include "vision/camera/tsai_camera.h"
#include "vision/camera/unified_camera.h"

namespace kinevis::vision {
namespace {

// Collects every problem of one file; throws them together.
class Fields {
 public:
  Fields(std::string path, YAML::Node root) : path_(std::move(path)), root_(std::move(root)) {}

  void Problem(const std::string& message) { problems_.push_back(message); }
  void ThrowIfAny() const {
    if (problems_.empty()) return;
    std::string message = path_ + ": ";
    for (size_t i = 0; i < problems_.size(); ++i) message += (i ? "; " : "") + problems_[i];
    throw std::invalid_argument(message);
  }
  const std::string& path() const { return path_; }

  // A number under `key`, or under `key + suffix` scaled to SI. Missing: `fallback` when given
  // (optional key), otherwise a problem.
  double Number(const std::string& key, const char* suffix = nullptr, double scale = 1.0,
                const double* fallback = nullptr) {
    used_.push_back(key);
    const bool si = static_cast<bool>(root_[key]);
    const bool scaled = suffix && root_[key + suffix];
    if (suffix) used_.push_back(key + suffix);
    if (si && scaled) {
      Problem(key + " and " + key + suffix + ": give one, not both");
      return std::nan("");
    }
    if (!si && !scaled) {
      if (fallback) return *fallback;
      Problem(key + (suffix ? std::string(" (or ") + key + suffix + ")" : std::string()) +
              ": missing");
      return std::nan("");
    }
    const std::string name = si ? key : key + suffix;
    return Scalar(root_[name], name) * (si ? 1.0 : scale);
  }
  double Optional(const std::string& key, double fallback) {
    return Number(key, nullptr, 1.0, &fallback);
  }
  int Integer(const std::string& key) {
    used_.push_back(key);
    const YAML::Node n = root_[key];
    int v = 0;
    if (!n) {
      Problem(key + ": missing");
    } else if (!n.IsScalar() || !YAML::convert<int>::decode(n, v)) {
      Problem(key + ": expected an integer, got '" + (n.IsScalar() ? n.Scalar() : "a list or map") +
              "'");
    }
    return v;
  }
  std::string Text(const std::string& key, const std::string& fallback) {
    used_.push_back(key);
    const YAML::Node n = root_[key];
    if (!n) return fallback;
    if (!n.IsScalar()) {
      Problem(key + ": expected a string");
      return fallback;
    }
    return n.Scalar();
  }
  template <size_t N>
  std::array<double, N> List(const std::string& key, bool required) {
    used_.push_back(key);
    std::array<double, N> out{};
    const YAML::Node n = root_[key];
    if (!n) {
      if (required) Problem(key + ": missing");
      return out;
    }
    if (!n.IsSequence() || n.size() > N || (required && n.size() != N)) {
      Problem(key + ": need a list of " + (required ? "" : "up to ") + std::to_string(N) +
              " numbers");
      return out;
    }
    for (size_t i = 0; i < n.size(); ++i)
      out[i] = Scalar(n[i], key + "[" + std::to_string(i) + "]");
    return out;
  }
  // Keys in the file that no reader asked for: almost always a typo.
  void RejectUnknownKeys() {
    used_.push_back("model");
    used_.push_back("name");
    for (const auto& kv : root_) {
      const std::string key = kv.first.as<std::string>();
      if (std::find(used_.begin(), used_.end(), key) == used_.end()) {
        Problem(key + ": unknown key for this model");
      }
    }
  }

 private:
  double Scalar(const YAML::Node& n, const std::string& name) {
    double v = std::nan("");
    if (!n.IsScalar() || !YAML::convert<double>::decode(n, v) || !std::isfinite(v)) {
      Problem(name + ": expected a finite number, got '" + (n.IsScalar() ? n.Scalar() : "a list") +
              "'");
      return std::nan("");
    }
    return v;
  }

  std::string path_;
  YAML::Node root_;
  std::vector<std::string> problems_;
  std::vector<std::string> used_;
};

// Builds the model, turning the constructor's validation error into one naming the file.
template <typename Camera, typename Parameters>
std::unique_ptr<CameraModel> Make(const Fields& f, const Parameters& p) {
  try {
    return std::make_unique<Camera>(p);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(f.path() + ": " + e.what());
  }
}

std::unique_ptr<CameraModel> ReadPinhole(Fields& f) {
  PinholeBrownParameters p;
  p.width = f.Integer("width");
  p.height = f.Integer("height");
  p.fx = f.Number("fx");
  p.fy = f.Number("fy");
  p.cx = f.Number("cx");
  p.cy = f.Number("cy");
  p.distortion = f.List<8>("distortion", false);
  f.RejectUnknownKeys();
  f.ThrowIfAny();
  return Make<PinholeBrownCamera>(f, p);
}

std::unique_ptr<CameraModel> ReadTsai(Fields& f) {
  TsaiParameters p;
  p.width = f.Integer("width");
  p.height = f.Integer("height");
  p.focal_length_mm = f.Number("focal_length_mm");
  p.cx = f.Number("cx");
  p.cy = f.Number("cy");
  p.pixel_pitch_x_mm = f.Number("pixel_pitch_x_mm");
  p.pixel_pitch_y_mm = f.Number("pixel_pitch_y_mm");
  p.scale_x = f.Optional("scale_x", 1.0);
  p.kappa1_per_mm2 = f.Optional("kappa1_per_mm2", 0.0);
  const std::string form = f.Text("distortion_form", "tsai");
  if (form == "tsai") {
    p.distortion_form = TsaiDistortionForm::kTsai;
  } else if (form == "division") {
    p.distortion_form = TsaiDistortionForm::kDivision;
  } else {
    f.Problem("distortion_form: expected tsai or division, got '" + form + "'");
  }
  f.RejectUnknownKeys();
  f.ThrowIfAny();
  return Make<TsaiCamera>(f, p);
}

std::unique_ptr<CameraModel> ReadUnified(Fields& f) {
  UnifiedParameters p;
  p.width = f.Integer("width");
  p.height = f.Integer("height");
  p.xi = f.Number("xi");
  p.gamma1 = f.Number("gamma1");
  p.gamma2 = f.Number("gamma2");
  p.skew = f.Optional("skew", 0.0);
  p.u0 = f.Number("u0");
  p.v0 = f.Number("v0");
  p.distortion = f.List<4>("distortion", false);
  f.RejectUnknownKeys();
  f.ThrowIfAny();
  return Make<UnifiedCamera>(f, p);
}

std::unique_ptr<CameraModel> ReadScaramuzza(Fields& f) {
  ScaramuzzaParameters p;
  p.width = f.Integer("width");
  p.height = f.Integer("height");
  p.poly = f.List<5>("poly", false);
  p.u0 = f.Number("u0");
  p.v0 = f.Number("v0");
  p.c = f.Optional("c", 1.0);
  p.d = f.Optional("d", 0.0);
  p.e = f.Optional("e", 0.0);
  p.max_radius_px = f.Optional("max_radius_px", 0.0);
  p.inverse_fit_tolerance_px = f.Optional("inverse_fit_tolerance_px", 0.01);
  f.RejectUnknownKeys();
  f.ThrowIfAny();
  return Make<ScaramuzzaCamera>(f, p);
}

std::unique_ptr<CameraModel> ReadHyperbolicMirror(Fields& f) {
  HyperbolicMirrorParameters p;
  p.width = f.Integer("width");
  p.height = f.Integer("height");
  // Lengths in m, or in mm with the _mm suffix; the mirror constant in m² or mm² (seed: 1000 mm²).
  p.pixel_pitch = f.Number("pixel_pitch", "_um", 1e-6);
  p.cx = f.Number("cx");
  p.cy = f.Number("cy");
  p.focal_length = f.Number("focal_length", "_mm", 1e-3);
  p.lens_correction = f.List<4>("lens_correction", true);
  p.mirror_constant = f.Number("mirror_constant", "_mm2", 1e-6);
  p.mirror_radius = f.Number("mirror_radius", "_mm", 1e-3);
  p.apex_distance = f.Number("apex_distance", "_mm", 1e-3);
  const double zero = 0.0;
  p.mirror_axis_x = f.Number("mirror_axis_x", "_mm", 1e-3, &zero);
  p.mirror_axis_z = f.Number("mirror_axis_z", "_mm", 1e-3, &zero);
  p.apex_to_ground = f.Number("apex_to_ground", "_mm", 1e-3);
  p.sensor_offset_x = f.Number("sensor_offset_x", "_mm", 1e-3, &zero);
  p.sensor_offset_z = f.Number("sensor_offset_z", "_mm", 1e-3, &zero);
  p.sensor_gamma = f.Number("sensor_gamma", "_deg", common::kDeg, &zero);
  p.sensor_rho = f.Number("sensor_rho", "_deg", common::kDeg, &zero);
  p.sensor_theta = f.Number("sensor_theta", "_deg", common::kDeg, &zero);
  p.ground_rho = f.Number("ground_rho", "_deg", common::kDeg, &zero);
  p.ground_theta = f.Number("ground_theta", "_deg", common::kDeg, &zero);
  f.RejectUnknownKeys();
  f.ThrowIfAny();
  return Make<HyperbolicMirrorCamera>(f, p);
}

const std::map<std::string, std::function<std::unique_ptr<CameraModel>()>>& Builtins() {
  static const auto* builtins =
      new std::map<std::string, std::function<std::unique_ptr<CameraModel>()>>{
          {"tsai-seed004", [] { return std::make_unique<TsaiCamera>(TsaiParameters::Seed004()); }},
          {"unified-default",
           [] { return std::make_unique<UnifiedCamera>(UnifiedParameters::Default()); }},
          {"scaramuzza-default",
           [] { return std::make_unique<ScaramuzzaCamera>(ScaramuzzaParameters::Default()); }},
          {"hyperbolic-mirror-4mm",
           [] {
             return std::make_unique<HyperbolicMirrorCamera>(
                 HyperbolicMirrorParameters::Seed000Lens4mm());
           }},
          {"hyperbolic-mirror-6mm",
           [] {
             return std::make_unique<HyperbolicMirrorCamera>(
                 HyperbolicMirrorParameters::Seed000Lens6mm());
           }},
      };
  return *builtins;
}

}  // namespace

std::unique_ptr<CameraModel> LoadCameraModel(const std::string& path) {
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::BadFile&) {
    throw std::runtime_error(path + ": cannot open the camera model file");
  } catch (const YAML::Exception& e) {
    throw std::invalid_argument(path + ": not valid YAML: " + e.what());
  }
  if (!root.IsMap()) throw std::invalid_argument(path + ": expected a YAML mapping at the top");
  if (root["camera_matrix"] && !root["model"]) {
    return std::make_unique<PinholeBrownCamera>(ReadPinholeIntrinsics(path));
  }
  if (!root["model"] || !root["model"].IsScalar()) {
    throw std::invalid_argument(
        path +
        ": model: missing (pinhole-brown, tsai, unified, scaramuzza, hyperbolic-mirror), "
        "and no camera_matrix key of a ROS/OpenCV intrinsics file");
  }
  const std::string model = root["model"].Scalar();
  Fields f(path, root);
  if (model == "pinhole-brown") return ReadPinhole(f);
  if (model == "tsai") return ReadTsai(f);
  if (model == "unified") return ReadUnified(f);
  if (model == "scaramuzza") return ReadScaramuzza(f);
  if (model == "hyperbolic-mirror") return ReadHyperbolicMirror(f);
  throw std::invalid_argument(path + ": model: unknown '" + model +
                              "' (pinhole-brown, tsai, unified, scaramuzza, hyperbolic-mirror)");
}

std::vector<std::string> BuiltinCameraModelNames() {
  std::vector<std::string> names;
  for (const auto& kv : Builtins()) names.push_back(kv.first);
  return names;
}

std::unique_ptr<CameraModel> BuiltinCameraModel(const std::string& name) {
  const auto it = Builtins().find(name);
  if (it == Builtins().end()) {
    std::string known;
    for (const auto& n : BuiltinCameraModelNames()) known += (known.empty() ? "" : ", ") + n;
    throw std::invalid_argument("camera model builtin:" + name + ": unknown (" + known + ")");
  }
  return it->second();
}

std::unique_ptr<CameraModel> OpenCameraModel(const std::string& spec) {
  constexpr char kBuiltin[] = "builtin:";
  if (spec.rfind(kBuiltin, 0) == 0) return BuiltinCameraModel(spec.substr(sizeof kBuiltin - 1));
  return LoadCameraModel(spec);
}

}  // namespace kinevis::vision
