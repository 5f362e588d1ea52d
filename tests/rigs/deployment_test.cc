// The deployment-file reader shared by the rigs (rigs/deployment.h): a good file gives back what
// it says, a bad one is refused with every bad key, its value and the file in one message.

#include "rigs/deployment.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>

namespace kinevis::rigs {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

std::string Write(const std::string& name, const std::string& text) {
  const fs::path dir =
      fs::temp_directory_path() / ("kinevis_deployment_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const std::string path = (dir / name).string();
  std::ofstream(path) << text;
  return path;
}

DrivesSection CanopenDrives() {
  DrivesSection d;
  d.ids_key = "nodes";
  d.default_ids = {1, 2, 3};
  d.counts_key = "counts_per_metre";
  d.backend_example = "socketcan:can0";
  return d;
}

TEST(Deployment, AGoodFileGivesBackWhatItSays) {
  const std::string path = Write("good.yaml",
                                 "rig: hexapod\n"
                                 "robot: robot.yaml\n"
                                 "drives: {backend: socketcan:can1, nodes: [4, 5, 6], "
                                 "counts_per_metre: 2e6, cycle_ms: 2, heartbeat_ms: 50}\n"
                                 "camera:\n"
                                 "  name: top\n"
                                 "  source: v4l2:/dev/video2\n"
                                 "  model: builtin:tsai-seed004\n"
                                 "  pose: {position: [0.1, -0.2, 1.0], rpy_deg: [0, 0, 90]}\n"
                                 "  fps: 25\n");
  EXPECT_FALSE(IsWorldConfig(path, "hexapod"));
  EXPECT_TRUE(IsWorldConfig("", "hexapod"));
  DeploymentFile f(path, "hexapod");
  EXPECT_EQ(f.RobotDescription(), (fs::path(path).parent_path() / "robot.yaml").string());
  const DeploymentDrives d = f.Drives(CanopenDrives());
  EXPECT_EQ(d.backend, "socketcan:can1");
  EXPECT_EQ(d.ids, (std::vector<int>{4, 5, 6}));
  EXPECT_EQ(d.counts_per_unit, 2e6);
  EXPECT_EQ(d.cycle_ms, 2.0);
  EXPECT_EQ(d.heartbeat_ms, 50.0);
  CameraSection cs;
  cs.pose_meaning = "the camera's pose";
  const DeploymentCamera c = f.Camera(cs);
  EXPECT_EQ(c.name, "top");
  EXPECT_EQ(c.source, "v4l2:/dev/video2");
  EXPECT_EQ(c.model, "builtin:tsai-seed004");
  EXPECT_EQ(c.fps, 25.0);
  EXPECT_NEAR((c.pose.translation() - Eigen::Vector3d(0.1, -0.2, 1.0)).norm(), 0.0, 1e-12);
  // yaw 90°: x_C along y_B.
  EXPECT_NEAR((c.pose.linear().col(0) - Eigen::Vector3d::UnitY()).norm(), 0.0, 1e-12);
  EXPECT_NO_THROW(f.Finish({"robot", "drives", "camera"}));
}

TEST(Deployment, EveryBadKeyIsNamedWithItsValueInOneMessage) {
  const std::string path = Write("bad.yaml",
                                 "rig: diamond\n"
                                 "drives: {nodes: [3, 3, 200], counts_per_metre: -1, "
                                 "cycle_ms: 0.1, speed: 3}\n"
                                 "camera: {source: v4l2:/dev/video0, fps: 0}\n"
                                 "extra: 1\n");
  DeploymentFile f(path, "hexapod");
  f.RobotDescription();
  f.Drives(CanopenDrives());
  CameraSection cs;
  cs.pose_meaning = "the camera's pose in the base frame";
  f.Camera(cs);
  try {
    f.Finish({"robot", "drives", "camera"});
    FAIL() << "a bad deployment file was accepted";
  } catch (const std::invalid_argument& e) {
    const std::string m = e.what();
    EXPECT_THAT(m, HasSubstr(path));
    EXPECT_THAT(m, HasSubstr("rig: expected `rig: hexapod`"));
    EXPECT_THAT(m, HasSubstr("got 'diamond'"));
    EXPECT_THAT(m, HasSubstr("robot: missing"));
    EXPECT_THAT(m, HasSubstr("drives.backend: missing (e.g. socketcan:can0)"));
    EXPECT_THAT(m, HasSubstr("drives.nodes[1]: 3 is given twice"));
    EXPECT_THAT(m, HasSubstr("drives.nodes[2]: must be an integer in [1, 127], got 200"));
    EXPECT_THAT(m, HasSubstr("drives.counts_per_metre: must be a finite number > 0, got -1"));
    EXPECT_THAT(m, HasSubstr("drives.cycle_ms: must be in [1, 100] ms, got 0.1"));
    EXPECT_THAT(m, HasSubstr("speed"));
    EXPECT_THAT(m, HasSubstr("camera.model: missing"));
    EXPECT_THAT(m, HasSubstr("camera.pose: missing (the camera's pose in the base frame)"));
    EXPECT_THAT(m, HasSubstr("camera.fps: must be a finite number > 0, got 0"));
    EXPECT_THAT(m, HasSubstr("extra"));
  }
}

TEST(Deployment, AWorldConfigIsToldApart) {
  const std::string path = Write("world.yaml", "world: weld-cell\n");
  EXPECT_TRUE(IsWorldConfig(path, "weld-cell"));
  EXPECT_THROW(IsWorldConfig(Write("list.yaml", "- 1\n- 2\n"), "weld-cell"), std::invalid_argument);
}

}  // namespace
}  // namespace kinevis::rigs
