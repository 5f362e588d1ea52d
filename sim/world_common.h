#pragma once

// What every simulated world shares (issue 17: out of sim/hexapod_world.h, so the DIAMOND,
// weld-cell and soccer worlds and the rigs no longer include the hexapod's world): the config of
// one rendered camera, the clock that steps a world when the host waits, and the checked reader of
// world config files.

#include <Eigen/Geometry>
#include <functional>
#include <string>
#include <vector>

#include "common/clock.h"
#include "common/config_error.h"
#include "common/yaml_reader.h"
#include "vision/render/renderer.h"

namespace kinevis::sim {

// One simulated camera of a world, from the config's `cameras:` list.
struct WorldCameraConfig {
  std::string name;   // render source name: the host opens "sim:NAME"
  std::string model;  // vision::OpenCameraModel spec: "builtin:NAME" or a camera model file
  // Pose of the camera frame C in the world's fixed frame W (B for the hexapod, O for the
  // DIAMOND): the true pose the renderer uses.
  Eigen::Isometry3d X_WC = Eigen::Isometry3d::Identity();
  double fps = 30.0;  // nominal frame rate, > 0
  vision::render::RenderOptions render;
};

// Runs a world's time: Now() is the world's simulated time; SleepUntil(deadline) steps the world
// up to the deadline (in steps of the world's step period). Given to an in-process host
// (CanopenMaster, Rs485DriveBus options.clock) so that the host's waits are where simulated time
// passes, exactly as in the HAL tests. Single-threaded use: the host and the stepping share the
// caller's thread.
class WorldClock final : public common::Clock {
 public:
  WorldClock(const common::Clock* time, std::function<void(common::Duration)> step_to)
      : time_(time), step_to_(std::move(step_to)) {}
  common::Duration Now() const override { return time_->Now(); }
  void SleepUntil(common::Duration deadline) override {
    if (deadline > time_->Now()) step_to_(deadline);
  }

 private:
  const common::Clock* time_;
  std::function<void(common::Duration)> step_to_;
};

namespace internal {

// Reading world config files (YAML), shared by the worlds' loaders (common/yaml_reader.h). Keys are
// dotted paths ("drives.counts_per_metre"); a missing key gives the fallback; a bad value is
// recorded as a problem naming the key and the value, and ThrowIfProblems() throws them all at
// once: std::invalid_argument "PATH: p1; p2".
class WorldConfigReader : public common::YamlReader {
 public:
  // Reads `path` and checks that its `world:` key is `kind` (when present). Throws
  // std::invalid_argument when the file cannot be read, is not YAML or not a mapping.
  WorldConfigReader(const std::string& path, const std::string& kind);

  // The `cameras:` list; `fallback` when the key is missing.
  std::vector<WorldCameraConfig> Cameras(const std::vector<WorldCameraConfig>& fallback);
};

void ValidateCameras(const std::vector<WorldCameraConfig>& cameras, common::Problems* problems);

}  // namespace internal

}  // namespace kinevis::sim
