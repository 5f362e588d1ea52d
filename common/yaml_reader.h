#pragma once

// The one checked reader of kinevis's YAML config files (world configs, deployment files, and the
// readers built on it): values by dotted key with list indices ("drives.backend",
// "cameras[1].render.noise_sigma"), each checked as it is read, every problem collected with the
// key and the value that was there, and all of them thrown together naming the file
// (common::Problems' format). yaml-cpp stays in the .cc (library kinevis::common_yaml).

#include <Eigen/Geometry>
#include <memory>
#include <string>
#include <vector>

namespace kinevis::common {

class YamlReader {
 public:
  // Reads `path` (`what` names the kind of file in messages: "world config", "deployment file").
  // Throws std::invalid_argument when the file cannot be read, is not YAML or not a mapping.
  YamlReader(const std::string& path, const std::string& what);
  virtual ~YamlReader();
  YamlReader(const YamlReader&) = delete;
  YamlReader& operator=(const YamlReader&) = delete;

  bool Has(const std::string& key) const;
  // A finite number; a problem ("expected a finite number, got 'x'") and NaN otherwise.
  double Number(const std::string& key, double fallback);
  // NOLINTNEXTLINE(google-runtime-int): the type of yaml-cpp's and std::stoll's integers
  long long Integer(const std::string& key, long long fallback);
  std::string Text(const std::string& key, const std::string& fallback);
  // Exactly n numbers (a scalar is repeated n times when scalar_ok).
  std::vector<double> Numbers(const std::string& key, size_t n, std::vector<double> fallback,
                              bool scalar_ok = false);
  // {position: [x, y, z] (m), rpy_deg: [roll, pitch, yaw]}, R = Rz(yaw) Ry(pitch) Rx(roll), as
  // in robot description files.
  Eigen::Isometry3d Pose(const std::string& key, const Eigen::Isometry3d& fallback);
  // A file name relative to the file's folder (absolute names are kept); empty when missing.
  std::string Path(const std::string& key);
  // A path as Path() resolves it.
  std::string Resolve(const std::string& file) const;
  // The length of the list at `key`: 0 when missing, and a problem ("expected a list") when it is
  // something else.
  size_t ListSize(const std::string& key);
  // Records every key of the mapping at `key` ("" = the top level) that is not in `known`, and a
  // `key` that is not a mapping.
  void CheckKeys(const std::string& key, const std::vector<std::string>& known);
  void Problem(const std::string& text);
  bool HasProblems() const;
  // Throws std::invalid_argument "PATH: problem; problem; ..." when there is any.
  void ThrowIfProblems() const;
  const std::string& path() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace kinevis::common
