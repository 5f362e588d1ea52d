#include "calibration/diamond/diamond_dataset.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "vision/render/scenes/diamond_marker_scene.h"

namespace kinevis::calibration {
namespace {

using ::testing::HasSubstr;
namespace fs = std::filesystem;

fs::path FreshDir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / ("kinevis_diamond_dataset_" + name);
  fs::remove_all(dir);
  return dir;
}

TEST(DiamondDatasetTest, RoundTripsSamplesImagesAndPose) {
  const fs::path dir = FreshDir("roundtrip");
  DiamondDataset d;
  d.directory = dir.string();
  d.camera_name = "diamond-marker";
  d.camera_model = "builtin:tsai-seed004";
  d.X_OC = vision::render::DiamondCameraPose(0.4462).inverse();
  d.camera_distance_source = "simulated truth";
  d.source = "test";
  CreateDiamondDataset(&d);
  std::vector<uint8_t> image(64 * 32);
  for (size_t i = 0; i < image.size(); ++i) image[i] = static_cast<uint8_t>(i * 7);
  DiamondDatasetSample a;
  a.index = 0;
  a.image = "images/sample_0000.png";
  a.q = {2.1, 0.3};
  a.has_pixel = true;
  a.pixel = {612.25, 301.125};
  AppendDiamondDatasetSample(d, a, image.data(), 64, 32, 64);
  DiamondDatasetSample b;
  b.index = 1;
  b.q = {1.9, 0.1 + 1e-13};  // no image, no pixel yet
  AppendDiamondDatasetSample(d, b);

  const DiamondDataset r = ReadDiamondDataset(dir.string());
  EXPECT_EQ(r.camera_name, "diamond-marker");
  EXPECT_EQ(r.camera_model, "builtin:tsai-seed004");
  EXPECT_EQ(r.camera_distance_source, "simulated truth");
  EXPECT_LT((r.X_OC.matrix() - d.X_OC.matrix()).cwiseAbs().maxCoeff(), 1e-15);
  EXPECT_DOUBLE_EQ(r.nominal.radius, 0.2);
  ASSERT_EQ(r.samples.size(), 2u);
  EXPECT_EQ(r.samples[0].image, a.image);
  EXPECT_EQ(r.samples[0].q, a.q);
  EXPECT_TRUE(r.samples[0].has_pixel);
  EXPECT_EQ(r.samples[0].pixel, a.pixel);
  EXPECT_FALSE(r.samples[1].has_pixel);
  EXPECT_EQ(r.samples[1].q, b.q);  // 17 digits: exact
  int w = 0, h = 0;
  EXPECT_EQ(ReadDiamondDatasetImage(r, r.samples[0], &w, &h), image);
  EXPECT_EQ(w, 64);
  EXPECT_EQ(h, 32);
  EXPECT_THROW(ReadDiamondDatasetImage(r, r.samples[1], &w, &h), std::invalid_argument);
  const std::vector<DiamondSample> s = DiamondSamplesWithPixels(r);
  ASSERT_EQ(s.size(), 1u);
  EXPECT_EQ(s[0].pixel, a.pixel);
  // A second recording into the same directory is refused.
  EXPECT_THROW(CreateDiamondDataset(&d), std::invalid_argument);
  fs::remove_all(dir);
}

TEST(DiamondDatasetTest, RefusesBadFilesNamingLineAndField) {
  const fs::path dir = FreshDir("bad");
  DiamondDataset d;
  d.directory = dir.string();
  d.camera_model = "builtin:tsai-seed004";
  d.X_OC = vision::render::DiamondCameraPose(0.4462).inverse();
  CreateDiamondDataset(&d);
  std::ofstream(dir / "samples.csv", std::ios::app) << "0,,2.1,zero,,\n"
                                                    << "1,images/missing.png,2.1,0.3,,\n"
                                                    << "2,,2.1,0.3,600,\n"
                                                    << "3,,2.1\n";
  try {
    ReadDiamondDataset(dir.string());
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr("line 2: q1_rad/q2_rad '2.1', 'zero'"));
    EXPECT_THAT(e.what(), HasSubstr("line 3: image"));
    EXPECT_THAT(e.what(), HasSubstr("line 4: give both u_px and v_px"));
    EXPECT_THAT(e.what(), HasSubstr("line 5: 3 fields, expected 6"));
  }
  std::ofstream(dir / "samples.csv") << "index,image,q1,q2\n";
  EXPECT_THROW(
      {
        try {
          ReadDiamondDataset(dir.string());
        } catch (const std::invalid_argument& e) {
          EXPECT_THAT(e.what(), HasSubstr("line 1: header 'index,image,q1,q2'"));
          throw;
        }
      },
      std::invalid_argument);
  std::ofstream(dir / "dataset.yaml") << "kind: kinevis-diamond-dataset\nversion: 7\nrobot: "
                                         "apriori\ncamera: {model: builtin:x}\n";
  try {
    ReadDiamondDataset(dir.string());
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr("version: 7"));
    EXPECT_THAT(e.what(), HasSubstr("camera.pose: missing"));
  }
  DiamondDataset bad_pose = d;
  bad_pose.directory = (dir / "sub").string();
  bad_pose.X_OC.linear() *= 2;
  EXPECT_THROW(CreateDiamondDataset(&bad_pose), std::invalid_argument);
  DiamondDatasetSample nan_sample;
  nan_sample.q.x() = std::nan("");
  EXPECT_THROW(AppendDiamondDatasetSample(d, nan_sample), std::invalid_argument);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace kinevis::calibration
