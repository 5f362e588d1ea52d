#pragma once

// The one reader of the rigs' deployment files (docs/deployment.md): a YAML file that says which
// real devices make up a machine — `rig:` (which machine), `robot:` (its nominal description),
// `drives:` (the motor drives' bus), `camera:` / `scanner:` (a camera, its model and pose),
// `welder:` (the weld robot's controller). Every rig (hexapod, DIAMOND, weld cell) reads its file
// through this class, so the sections mean the same thing everywhere and every bad key is named
// with its file in one message (common/yaml_reader.h, the one checked YAML reader).
//
// A path whose top level has `world:` is a simulated world's config instead (sim/), read by the
// world itself: IsWorldConfig() tells them apart, and an empty path means the built-in world.

#include <Eigen/Geometry>
#include <memory>
#include <string>
#include <vector>

namespace kinevis::common {
class YamlReader;
}

namespace kinevis::rigs {

// True when `path` is empty (the built-in simulated world) or its top level has `world:`.
// Throws std::invalid_argument when the file cannot be read or is not a YAML mapping.
bool IsWorldConfig(const std::string& path, const std::string& kind);

// How a rig's `drives:` section is spelt: the key of the device ids and of the encoder scale.
struct DrivesSection {
  std::string ids_key = "nodes";  // CANopen node ids ("nodes") or Modbus unit ids ("units")
  std::vector<int> default_ids;   // also fixes how many ids there are
  int max_id = 127;               // ids are in 1..max_id, all different
  std::string counts_key = "counts_per_metre";
  double default_counts = 1e6;
  double default_cycle_ms = 4.0, min_cycle_ms = 1.0, max_cycle_ms = 100.0;
  bool heartbeat = true;        // CANopen: `heartbeat_ms` (the drives' heartbeat producer time)
  std::string backend_example;  // for the "missing" message, e.g. "socketcan:can0"
};

struct DeploymentDrives {
  std::string backend;
  std::vector<int> ids;
  double counts_per_unit = 0.0;
  double cycle_ms = 0.0;
  double heartbeat_ms = 20.0;
};

// How a rig's camera section is spelt (the weld cell's is `scanner:` with `camera:` for the model
// and `nominal_mount:` for the pose) and which rig-specific keys it also allows.
struct CameraSection {
  std::string section = "camera";
  std::string model_key = "model";
  std::string pose_key = "pose";
  std::string pose_meaning;  // for the "missing" message: "the camera's pose in the base frame"
  bool has_name = true;      // a `name:` key (default "camera")
  double default_fps = 10.0;
  std::vector<std::string> extra_keys;  // read by the rig through reader()
};

struct DeploymentCamera {
  std::string name = "camera";
  std::string source;  // hal camera source ("v4l2:/dev/video0", "net:host:port", ...)
  std::string model;   // builtin:NAME, or the model file's path resolved against the file's folder
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  double fps = 10.0;
};

class DeploymentFile {
 public:
  // Reads `path` and checks `rig: kind` (a problem when not). Throws std::invalid_argument when
  // the file cannot be read or is not a YAML mapping.
  DeploymentFile(const std::string& path, const std::string& kind);
  ~DeploymentFile();
  DeploymentFile(const DeploymentFile&) = delete;
  DeploymentFile& operator=(const DeploymentFile&) = delete;

  // `robot:`: the nominal robot description's path (resolved); a problem when missing and
  // `required`, "" then.
  std::string RobotDescription(bool required = true);
  DeploymentDrives Drives(const DrivesSection& spec);
  DeploymentCamera Camera(const CameraSection& spec);
  // `section.backend` (and no other key in the section): e.g. the weld robot's Modbus backend.
  std::string Backend(const std::string& section, const std::string& example);

  // Rig-specific keys, and problems the rig finds itself (a description that does not load).
  common::YamlReader& reader() { return *reader_; }
  void Problem(const std::string& text);
  // Checks the top-level keys against `sections` (plus `rig`) and throws std::invalid_argument
  // naming the file and every problem found so far.
  void Finish(const std::vector<std::string>& sections);

 private:
  std::unique_ptr<common::YamlReader> reader_;
};

}  // namespace kinevis::rigs
