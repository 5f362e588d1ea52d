// The checked YAML reader (common/yaml_reader.h): dotted keys with list indices, every bad value
// named with its key and what was there, all problems in one message naming the file.

#include "common/yaml_reader.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>

namespace kinevis::common {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

std::string Write(const std::string& name, const std::string& text) {
  const fs::path dir =
      fs::temp_directory_path() / ("kinevis_yaml_reader_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const std::string path = (dir / name).string();
  std::ofstream(path) << text;
  return path;
}

TEST(YamlReader, ReadsDottedKeysListIndicesPosesAndPaths) {
  const std::string path = Write("good.yaml",
                                 "a: {b: 2.5, name: x, file: f.yaml, abs: /tmp/g.yaml}\n"
                                 "list:\n"
                                 "  - {v: 1}\n"
                                 "  - {v: 2, w: [1, 2, 3]}\n"
                                 "pose: {position: [1, 2, 3], rpy_deg: [0, 90, 0]}\n");
  YamlReader r(path, "test file");
  EXPECT_TRUE(r.Has("a.b"));
  EXPECT_FALSE(r.Has("a.c"));
  EXPECT_EQ(r.Number("a.b", 0), 2.5);
  EXPECT_EQ(r.Number("a.c", 7), 7);
  EXPECT_EQ(r.Text("a.name", ""), "x");
  EXPECT_EQ(r.Path("a.file"), (fs::path(path).parent_path() / "f.yaml").string());
  EXPECT_EQ(r.Path("a.abs"), "/tmp/g.yaml");
  EXPECT_EQ(r.ListSize("list"), 2u);
  EXPECT_EQ(r.ListSize("missing"), 0u);
  EXPECT_EQ(r.Number("list[0].v", 0), 1);
  EXPECT_EQ(r.Number("list[1].v", 0), 2);
  EXPECT_FALSE(r.Has("list[2].v"));
  EXPECT_EQ(r.Numbers("list[1].w", 3, {}), (std::vector<double>{1, 2, 3}));
  const Eigen::Isometry3d X = r.Pose("pose", Eigen::Isometry3d::Identity());
  EXPECT_NEAR((X.translation() - Eigen::Vector3d(1, 2, 3)).norm(), 0, 1e-12);
  // Pitch 90° about y: x goes to −z.
  EXPECT_NEAR((X.linear().col(0) - Eigen::Vector3d(0, 0, -1)).norm(), 0, 1e-12);
  r.CheckKeys("", {"a", "list", "pose"});
  r.CheckKeys("list[1]", {"v", "w"});
  EXPECT_FALSE(r.HasProblems());
  EXPECT_NO_THROW(r.ThrowIfProblems());
}

TEST(YamlReader, EveryProblemIsNamedWithItsKeyAndValueInOneMessage) {
  const std::string path = Write("bad.yaml",
                                 "a: {b: fast, n: [1, 2]}\n"
                                 "list: 3\n"
                                 "items: [{v: 1, typo: 2}]\n"
                                 "pose: {position: [1, 2], spin: 1}\n"
                                 "big: .nan\n");
  YamlReader r(path, "test file");
  EXPECT_TRUE(std::isnan(r.Number("a.b", 0)));
  r.Numbers("a.n", 3, {});
  EXPECT_EQ(r.ListSize("list"), 0u);
  r.CheckKeys("items[0]", {"v"});
  r.Pose("pose", Eigen::Isometry3d::Identity());
  r.Number("big", 0);
  r.CheckKeys("", {"a", "list", "items", "pose"});
  ASSERT_TRUE(r.HasProblems());
  try {
    r.ThrowIfProblems();
    FAIL();
  } catch (const std::invalid_argument& e) {
    const std::string m = e.what();
    EXPECT_THAT(m, HasSubstr(path + ": "));
    EXPECT_THAT(m, HasSubstr("a.b: expected a finite number, got 'fast'"));
    EXPECT_THAT(m, HasSubstr("a.n: need a list of 3 numbers"));
    EXPECT_THAT(m, HasSubstr("list: expected a list"));
    EXPECT_THAT(m, HasSubstr("items[0].typo: unknown key"));
    EXPECT_THAT(m, HasSubstr("pose.position: need a list of 3 numbers"));
    EXPECT_THAT(m, HasSubstr("pose.spin: unknown key"));
    EXPECT_THAT(m, HasSubstr("big: expected a finite number, got '.nan'"));
    EXPECT_THAT(m, HasSubstr("big: unknown key"));
  }
}

TEST(YamlReader, AFileThatIsNotAMappingIsRefusedNamingIt) {
  EXPECT_THROW(YamlReader(Write("list.yaml", "- 1\n"), "test file"), std::invalid_argument);
  try {
    YamlReader(Write("broken.yaml", "a: [1, 2\n"), "test file");
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr("broken.yaml: not valid YAML"));
  }
  try {
    YamlReader("/nonexistent/x.yaml", "deployment file");
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr("/nonexistent/x.yaml: cannot open the deployment file"));
  }
}

}  // namespace
}  // namespace kinevis::common
