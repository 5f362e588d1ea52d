#include "rigs/deployment.h"

#include <cmath>
#include <set>
#include <stdexcept>

#include "common/config_error.h"
#include "common/yaml_reader.h"
#include "sim/world_common.h"

namespace kinevis::rigs {
bool IsWorldConfig(const std::string& path, const std::string& kind) {
  if (path.empty()) return true;
  return sim::internal::WorldConfigReader(path, kind).Has("world");
}

DeploymentFile::DeploymentFile(const std::string& path, const std::string& kind)
    : reader_(std::make_unique<common::YamlReader>(path, "deployment file")) {
  const std::string rig = reader_->Text("rig", "");
  if (rig != kind) {
    reader_->Problem("rig: expected `rig: " + kind + "` (or `world: " + kind +
                     "` for a simulated one), got " + (rig.empty() ? "none" : "'" + rig + "'"));
  }
}

DeploymentFile::~DeploymentFile() = default;

std::string DeploymentFile::RobotDescription(bool required) {
  const std::string path = reader_->Path("robot");
  if (path.empty() && required) {
    reader_->Problem("robot: missing (the nominal robot description file)");
  }
  return path;
}

DeploymentDrives DeploymentFile::Drives(const DrivesSection& spec) {
  common::YamlReader& r = *reader_;
  DeploymentDrives d;
  d.backend = r.Text("drives.backend", "");
  if (d.backend.empty()) {
    r.Problem("drives.backend: missing (e.g. " + spec.backend_example + ")");
  }
  const std::vector<double> fallback(spec.default_ids.begin(), spec.default_ids.end());
  const std::vector<double> ids =
      r.Numbers("drives." + spec.ids_key, spec.default_ids.size(), fallback);
  std::set<int> seen;
  for (size_t i = 0; i < ids.size(); ++i) {
    const double v = ids[i];
    const std::string where = "drives." + spec.ids_key + "[" + std::to_string(i) + "]";
    if (!(v >= 1 && v <= spec.max_id) || v != std::floor(v)) {
      r.Problem(where + ": must be an integer in [1, " + std::to_string(spec.max_id) + "], got " +
                common::Num(v));
      d.ids.push_back(0);
      continue;
    }
    const int id = static_cast<int>(v);
    if (!seen.insert(id).second) {
      r.Problem(where + ": " + std::to_string(id) + " is given twice (every drive has its own id)");
    }
    d.ids.push_back(id);
  }
  d.counts_per_unit = r.Number("drives." + spec.counts_key, spec.default_counts);
  if (!(d.counts_per_unit > 0) || !std::isfinite(d.counts_per_unit)) {
    r.Problem("drives." + spec.counts_key + ": must be a finite number > 0, got " +
              common::Num(d.counts_per_unit));
  }
  d.cycle_ms = r.Number("drives.cycle_ms", spec.default_cycle_ms);
  if (!(d.cycle_ms >= spec.min_cycle_ms && d.cycle_ms <= spec.max_cycle_ms)) {
    r.Problem("drives.cycle_ms: must be in [" + common::Num(spec.min_cycle_ms) + ", " +
              common::Num(spec.max_cycle_ms) + "] ms, got " + common::Num(d.cycle_ms));
  }
  std::vector<std::string> keys = {"backend", spec.ids_key, spec.counts_key, "cycle_ms"};
  if (spec.heartbeat) {
    d.heartbeat_ms = r.Number("drives.heartbeat_ms", d.heartbeat_ms);
    if (!(d.heartbeat_ms >= 1 && d.heartbeat_ms <= 1000)) {
      r.Problem("drives.heartbeat_ms: must be in [1, 1000] ms, got " + common::Num(d.heartbeat_ms));
    }
    keys.push_back("heartbeat_ms");
  }
  r.CheckKeys("drives", keys);
  return d;
}

DeploymentCamera DeploymentFile::Camera(const CameraSection& spec) {
  common::YamlReader& r = *reader_;
  const std::string s = spec.section + ".";
  DeploymentCamera c;
  std::vector<std::string> keys = {"source", spec.model_key, spec.pose_key, "fps"};
  if (spec.has_name) {
    c.name = r.Text(s + "name", c.name);
    keys.push_back("name");
  }
  c.source = r.Text(s + "source", "");
  if (c.source.empty()) r.Problem(s + "source: missing (e.g. v4l2:/dev/video0)");
  c.model = r.Text(s + spec.model_key, "");
  if (c.model.empty()) {
    r.Problem(s + spec.model_key + ": missing (a camera model file or builtin:NAME)");
  } else if (c.model.rfind("builtin:", 0) != 0) {
    c.model = r.Path(s + spec.model_key);
  }
  if (!r.Has(s + spec.pose_key)) {
    r.Problem(s + spec.pose_key + ": missing (" + spec.pose_meaning + ")");
  }
  c.pose = r.Pose(s + spec.pose_key, c.pose);
  c.fps = r.Number(s + "fps", spec.default_fps);
  if (!(c.fps > 0) || !std::isfinite(c.fps)) {
    r.Problem(s + "fps: must be a finite number > 0, got " + common::Num(c.fps));
  }
  keys.insert(keys.end(), spec.extra_keys.begin(), spec.extra_keys.end());
  r.CheckKeys(spec.section, keys);
  return c;
}

std::string DeploymentFile::Backend(const std::string& section, const std::string& example) {
  const std::string backend = reader_->Text(section + ".backend", "");
  if (backend.empty()) reader_->Problem(section + ".backend: missing (e.g. " + example + ")");
  reader_->CheckKeys(section, {"backend"});
  return backend;
}

void DeploymentFile::Problem(const std::string& text) { reader_->Problem(text); }

void DeploymentFile::Finish(const std::vector<std::string>& sections) {
  std::vector<std::string> keys = {"rig"};
  keys.insert(keys.end(), sections.begin(), sections.end());
  reader_->CheckKeys("", keys);
  reader_->ThrowIfProblems();
}

}  // namespace kinevis::rigs
