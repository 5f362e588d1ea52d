#pragma once

// Robot description files: the nominal (CAD) parameters of each robot as YAML, read into the
// models of robots/. The format is documented in docs/robot-description.md; the shipped files are
// robots/hexapod/hexapod.yaml, robots/weld5/weld5.yaml and
// robots/diamond/diamond_{apriori,identified}.yaml.
//
// This folder is the one part of robots/ that reads files (yaml-cpp); the models themselves stay
// Eigen-only. Values are SI unless the key names its unit (`alpha_deg`, `d_mm`): the reader
// converts at this one edge.
//
// Every loader throws std::invalid_argument when the file cannot be read or is wrong, with one
// message that names the file and every bad key and value ("hexapod.yaml: leg_radius: must be
// > 0, got -0.02; base_points[3]: need 3 numbers, got 2").

#include <Eigen/Geometry>
#include <string>

#include "robots/diamond/diamond_model.h"
#include "robots/hexapod/hexapod_model.h"
#include "robots/weld5/weld5_model.h"

namespace kinevis::robots {

// The `robot:` key of a description file: "hexapod", "weld5" or "diamond". Throws as above.
std::string ReadRobotKind(const std::string& path);

struct HexapodDescription {
  std::string name;
  HexapodModel model;
  Eigen::Isometry3d X_BP_home = Eigen::Isometry3d::Identity();  // home pose of P in B
};
HexapodDescription LoadHexapodDescription(const std::string& path);

struct Weld5Description {
  std::string name;
  Weld5Model model;  // including the torch transform X_5T and joint/speed limits
};
Weld5Description LoadWeld5Description(const std::string& path);

struct DiamondDescription {
  std::string name;
  DiamondModel model;  // checked with DiamondModel::Validate()
};
DiamondDescription LoadDiamondDescription(const std::string& path);

}  // namespace kinevis::robots
