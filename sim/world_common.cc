#include "sim/world_common.h"

#include <cmath>
#include <cstdint>
#include <set>
#include <stdexcept>

namespace kinevis::sim::internal {

void ValidateCameras(const std::vector<WorldCameraConfig>& cameras, common::Problems* p) {
  std::set<std::string> names;
  for (size_t i = 0; i < cameras.size(); ++i) {
    const WorldCameraConfig& c = cameras[i];
    const std::string key = "cameras[" + std::to_string(i) + "]";
    if (c.name.empty()) {
      p->Add(key + ".name: must not be empty");
    } else if (!names.insert(c.name).second) {
      p->Add(key + ".name: \"" + c.name + "\" appears twice");
    }
    if (c.model.empty()) p->Add(key + ".model: must not be empty");
    p->Positive(key + ".fps", c.fps);
    if (!c.X_WC.matrix().allFinite()) p->Add(key + ": pose not finite");
    const std::string render = c.render.Validate();
    if (!render.empty()) p->Add(key + ".render: " + render);
  }
}

// ---- WorldConfigReader

WorldConfigReader::WorldConfigReader(const std::string& path, const std::string& kind)
    : common::YamlReader(path, "world config") {
  const std::string world = Text("world", kind);
  if (world != kind) {
    throw std::invalid_argument(path + ": world: expected \"" + kind + "\", got \"" + world + "\"");
  }
}

std::vector<WorldCameraConfig> WorldConfigReader::Cameras(
    const std::vector<WorldCameraConfig>& fallback) {
  if (!Has("cameras")) return fallback;
  std::vector<WorldCameraConfig> cameras;
  const size_t n = ListSize("cameras");
  for (size_t i = 0; i < n; ++i) {
    const std::string key = "cameras[" + std::to_string(i) + "]";
    CheckKeys(key, {"name", "model", "fps", "pose", "render"});
    WorldCameraConfig c;
    c.name = Text(key + ".name", c.name);
    c.model = Text(key + ".model", c.model);
    if (!c.model.empty() && c.model.rfind("builtin:", 0) != 0) c.model = Resolve(c.model);
    c.fps = Number(key + ".fps", c.fps);
    c.X_WC = Pose(key + ".pose", c.X_WC);
    const std::string r = key + ".render.";
    CheckKeys(key + ".render",
              {"supersampling", "blur_sigma_px", "vignetting", "exposure", "noise_sigma", "seed"});
    // Counts arrive as numbers; a bad one is already a problem (NaN), not cast.
    const double supersampling = Number(r + "supersampling", c.render.supersampling);
    if (std::isfinite(supersampling) && std::abs(supersampling) < 1e6) {
      c.render.supersampling = static_cast<int>(supersampling);
    }
    c.render.blur_sigma_px = Number(r + "blur_sigma_px", c.render.blur_sigma_px);
    c.render.vignetting = Number(r + "vignetting", c.render.vignetting);
    c.render.exposure = Number(r + "exposure", c.render.exposure);
    c.render.noise_sigma = Number(r + "noise_sigma", c.render.noise_sigma);
    const double seed = Number(r + "seed", static_cast<double>(c.render.seed));
    if (seed >= 0 && seed < 1.8e19) c.render.seed = static_cast<uint64_t>(seed);
    cameras.push_back(c);
  }
  return cameras;
}

}  // namespace kinevis::sim::internal
