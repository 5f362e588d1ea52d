#include "vision/cloud/ply.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>

namespace kinevis::vision::cloud {
namespace {

using ::testing::HasSubstr;
using ::testing::MatchesRegex;

std::string TempPath(const std::string& name) {
  const std::filesystem::path dir = std::filesystem::temp_directory_path() / "kinevis_ply_test";
  std::filesystem::create_directories(dir);
  return (dir / name).string();
}

PointCloud RandomCloud(std::size_t n, bool normals, bool confidence, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  PointCloud c;
  for (std::size_t i = 0; i < n; ++i) {
    c.points.emplace_back(u(rng), u(rng), u(rng) * 1e-3f + 0.5f);
    if (normals) {
      Eigen::Vector3f nrm(u(rng), u(rng), u(rng));
      c.normals.push_back(i % 7 == 3 ? Eigen::Vector3f::Zero() : Eigen::Vector3f(nrm.normalized()));
    }
    if (confidence) c.confidence.push_back(0.5f * (u(rng) + 1.0f));
  }
  return c;
}

bool BitEqual(const std::vector<Eigen::Vector3f>& a, const std::vector<Eigen::Vector3f>& b) {
  return a.size() == b.size() &&
         (a.empty() || std::memcmp(a.data(), b.data(), a.size() * sizeof(Eigen::Vector3f)) == 0);
}

std::string ReadAll(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

void WriteAll(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary);
  out << bytes;
}

std::string Error(const std::string& path) {
  try {
    ReadPly(path);
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "";
}

TEST(Ply, RoundTripIsBitExactWithNormalsAndConfidence) {
  for (int variant = 0; variant < 4; ++variant) {
    const bool normals = variant & 1, confidence = variant & 2;
    const PointCloud c = RandomCloud(1000, normals, confidence, 3 + variant);
    const std::string path = TempPath("round_trip.ply");
    WritePly(path, c, {"frame 0 (robot base)"});
    std::vector<std::string> comments;
    const PointCloud r = ReadPly(path, &comments);
    EXPECT_TRUE(BitEqual(c.points, r.points));
    EXPECT_TRUE(BitEqual(c.normals, r.normals));
    ASSERT_EQ(c.confidence.size(), r.confidence.size());
    EXPECT_EQ(0, c.confidence.empty() ? 0
                                      : std::memcmp(c.confidence.data(), r.confidence.data(),
                                                    c.confidence.size() * sizeof(float)));
    EXPECT_THAT(comments, ::testing::Contains("frame 0 (robot base)"));
    // Header + 4 bytes per float per vertex, nothing else.
    const std::size_t floats = 3 + (normals ? 3 : 0) + (confidence ? 1 : 0);
    const std::string bytes = ReadAll(path);
    const std::size_t header = bytes.find("end_header\n") + 11;
    EXPECT_EQ(bytes.size() - header, 1000 * floats * 4);
  }
}

TEST(Ply, HeaderIsTheDocumentedOne) {
  const std::string path = TempPath("header.ply");
  WritePly(path, RandomCloud(2, true, true, 1));
  const std::string bytes = ReadAll(path);
  EXPECT_EQ(bytes.substr(0, bytes.find("end_header\n") + 11),
            "ply\nformat binary_little_endian 1.0\ncomment kinevis point cloud, units m\n"
            "element vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
            "property float nx\nproperty float ny\nproperty float nz\n"
            "property float confidence\nend_header\n");
}

TEST(Ply, ReadsOtherPropertyOrdersAndSkipsUnknownProperties) {
  const std::string path = TempPath("foreign.ply");
  std::string bytes =
      "ply\r\nformat binary_little_endian 1.0\r\nelement vertex 2\r\nproperty uchar red\r\n"
      "property float z\r\nproperty float y\r\nproperty float x\r\nproperty double t\r\n"
      "element face 0\r\nproperty list uchar int vertex_indices\r\nend_header\r\n";
  for (int i = 0; i < 2; ++i) {
    const unsigned char red = 7;
    const float zyx[3] = {3.0f + i, 2.0f, 1.0f};
    const double t = 9.0;
    bytes.append(reinterpret_cast<const char*>(&red), 1);
    bytes.append(reinterpret_cast<const char*>(zyx), 12);
    bytes.append(reinterpret_cast<const char*>(&t), 8);
  }
  WriteAll(path, bytes);
  const PointCloud c = ReadPly(path);
  ASSERT_EQ(c.size(), 2u);
  EXPECT_EQ(c.points[1], Eigen::Vector3f(1.0f, 2.0f, 4.0f));
  EXPECT_FALSE(c.has_normals());
}

TEST(Ply, RefusesBadFilesNamingTheFileAndTheProblem) {
  const std::string good = TempPath("good.ply");
  WritePly(good, RandomCloud(10, true, true, 2));
  const std::string bytes = ReadAll(good);
  const std::size_t header = bytes.find("end_header\n") + 11;
  const std::string path = TempPath("bad.ply");

  EXPECT_THAT(Error(TempPath("missing.ply")), MatchesRegex(".*missing.ply.*cannot open.*"));
  WriteAll(path, "PLY\n");
  EXPECT_THAT(Error(path), MatchesRegex(".*bad.ply: not a PLY file.*"));
  WriteAll(path, "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nend_header\n");
  EXPECT_THAT(Error(path), HasSubstr("format ascii is not supported"));
  WriteAll(path, "ply\nformat binary_big_endian 1.0\nend_header\n");
  EXPECT_THAT(Error(path), HasSubstr("binary_big_endian is not supported"));
  WriteAll(path, bytes.substr(0, header - 11));
  EXPECT_THAT(Error(path), HasSubstr("no end_header"));
  WriteAll(path, bytes.substr(0, bytes.size() - 5));
  EXPECT_THAT(Error(path),
              MatchesRegex(".*bad.ply: truncated: 10 vertices need 280 bytes, the file has 275.*"));
  WriteAll(path,
           "ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty double x\n"
           "property float y\nproperty float z\nend_header\n" +
               std::string(16, '\0'));
  EXPECT_THAT(Error(path), HasSubstr("vertex property x is double; expected float"));
  WriteAll(path,
           "ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\n"
           "property float y\nend_header\n" +
               std::string(8, '\0'));
  EXPECT_THAT(Error(path), HasSubstr("vertex property z is missing"));
  WriteAll(path,
           "ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\n"
           "property float y\nproperty float z\nproperty float nx\nend_header\n" +
               std::string(16, '\0'));
  EXPECT_THAT(Error(path), HasSubstr("only some of nx, ny, nz"));
  WriteAll(path,
           "ply\nformat binary_little_endian 1.0\nelement face 1\nproperty float x\n"
           "end_header\n" +
               std::string(4, '\0'));
  EXPECT_THAT(Error(path), HasSubstr("first element is not 'vertex'"));

  // A NaN coordinate, a normal of length 2, a confidence of 1.5 (vertex 4 each).
  const auto patch = [&](std::size_t float_index, float value) {
    std::string b = bytes;
    std::memcpy(&b[header + 4 * (4 * 7 + float_index)], &value, 4);
    WriteAll(path, b);
    return Error(path);
  };
  EXPECT_THAT(patch(1, std::nanf("")), HasSubstr("vertex 4 has a non-finite coordinate"));
  EXPECT_THAT(patch(3, 2.0f),
              MatchesRegex(".*vertex 4 has a normal of length .*; expected 1 or 0"));
  EXPECT_THAT(patch(6, 1.5f), HasSubstr("vertex 4 has confidence 1.5; expected within [0, 1]"));
}

TEST(Ply, WriteRefusesAnInconsistentCloud) {
  PointCloud c = RandomCloud(3, true, false, 4);
  c.normals.pop_back();
  try {
    WritePly(TempPath("inconsistent.ply"), c);
    FAIL() << "no exception";
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr("normals has 2 entries for 3 points"));
  }
  EXPECT_THROW(WritePly(TempPath("comment.ply"), RandomCloud(1, false, false, 1), {"a\nb"}),
               std::invalid_argument);
  EXPECT_THROW(WritePly("/nonexistent-dir/x.ply", RandomCloud(1, false, false, 1)),
               std::runtime_error);
}

}  // namespace
}  // namespace kinevis::vision::cloud
