#include "vision/camera/camera_file.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <random>

#include "vision/camera/camera_info_yaml.h"
#include "vision/camera/hyperbolic_mirror_camera.h"
#include "vision/camera/tsai_camera.h"

namespace kinevis::vision {
namespace {

using ::testing::AllOf;
using ::testing::HasSubstr;

std::string WriteTemp(const std::string& name, const std::string& text) {
  const auto path = std::filesystem::temp_directory_path() /
                    ("kinevis_camera_file_" + std::to_string(::getpid()) + "_" + name);
  std::ofstream(path) << text;
  return path.string();
}

std::string Error(const std::function<void()>& f) {
  try {
    f();
  } catch (const std::exception& e) {
    return e.what();
  }
  return "(no error)";
}

// Two models are the same camera when they map the same points to the same pixels.
void ExpectSameProjection(const CameraModel& a, const CameraModel& b, const Eigen::Vector3d& axis) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> d(-0.3, 0.3);
  int compared = 0;
  for (int i = 0; i < 200; ++i) {
    const Eigen::Vector3d p = axis + Eigen::Vector3d(d(rng), d(rng), d(rng));
    Eigen::Vector2d pa, pb;
    const ProjectionStatus sa = a.Project(p, &pa), sb = b.Project(p, &pb);
    ASSERT_EQ(sa, sb);
    if (sa != ProjectionStatus::kOk) continue;
    EXPECT_LT((pa - pb).norm(), 1e-9);
    ++compared;
  }
  EXPECT_GT(compared, 100);
}

TEST(CameraFile, TsaiFileInSeedUnitsIsTheBuiltinSeedCamera) {
  const std::string path = WriteTemp("tsai.yaml", R"(
model: tsai
width: 1616
height: 1216
focal_length_mm: 9.43773
cx: 738
cy: 585
pixel_pitch_x_mm: 0.0044000528
pixel_pitch_y_mm: 0.0044000528
kappa1_per_mm2: 4.886380e-4
distortion_form: division
)");
  const auto loaded = LoadCameraModel(path);
  const TsaiParameters seed = TsaiParameters::Seed004();
  const auto* tsai = dynamic_cast<const TsaiCamera*>(loaded.get());
  ASSERT_NE(tsai, nullptr);
  EXPECT_NEAR(tsai->parameters().pixel_pitch_x_mm, seed.pixel_pitch_x_mm, 1e-9);
  EXPECT_NEAR(tsai->parameters().kappa1_per_mm2, seed.kappa1_per_mm2, 1e-8);
  // 1e-9 relative in pitch and 1e-5 relative in κ1 move pixels by < 1e-3 px; same camera.
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> d(-0.1, 0.1);
  const auto builtin = BuiltinCameraModel("tsai-seed004");
  for (int i = 0; i < 100; ++i) {
    const Eigen::Vector3d p(d(rng), d(rng), 0.4);
    Eigen::Vector2d a, b;
    ASSERT_EQ(loaded->Project(p, &a), ProjectionStatus::kOk);
    ASSERT_EQ(builtin->Project(p, &b), ProjectionStatus::kOk);
    EXPECT_LT((a - b).norm(), 1e-3);
  }
  std::filesystem::remove(path);
}

TEST(CameraFile, UnifiedAndScaramuzzaFilesLoad) {
  const std::string unified = WriteTemp("unified.yaml", R"(
model: unified
width: 640
height: 480
xi: 0.95
gamma1: 230
gamma2: 230
u0: 319.5
v0: 239.5
)");
  ExpectSameProjection(*LoadCameraModel(unified), *BuiltinCameraModel("unified-default"),
                       Eigen::Vector3d(0, 0, 0.5));
  const std::string scaramuzza = WriteTemp("scaramuzza.yaml", R"(
model: scaramuzza
width: 640
height: 480
poly: [-180.0, 0.0, 0.0012, 0.0, 0.0]
u0: 320
v0: 240
max_radius_px: 230
)");
  const auto camera = LoadCameraModel(scaramuzza);
  EXPECT_EQ(camera->Name(), "scaramuzza");
  Ray ray;
  ASSERT_EQ(camera->BackProject(Eigen::Vector2d(400, 260), &ray), ProjectionStatus::kOk);
  Eigen::Vector2d pixel;
  ASSERT_EQ(camera->Project(ray.d_C, &pixel), ProjectionStatus::kOk);
  EXPECT_LT((pixel - Eigen::Vector2d(400, 260)).norm(), 1e-6);
  std::filesystem::remove(unified);
  std::filesystem::remove(scaramuzza);
}

TEST(CameraFile, HyperbolicMirrorFileInSeedUnitsIsTheBuiltin) {
  const std::string path = WriteTemp("mirror.yaml", R"(
model: hyperbolic-mirror
width: 640
height: 480
pixel_pitch_um: 4.65
cx: 319.5
cy: 239.5
focal_length_mm: 4.56
lens_correction: [0, 0, 0.001, 0.0045]
mirror_constant_mm2: 1000
mirror_radius_mm: 35
apex_distance_mm: 110
apex_to_ground_mm: 680
)");
  const auto loaded = LoadCameraModel(path);
  const auto builtin = BuiltinCameraModel("hyperbolic-mirror-4mm");
  const auto* a = dynamic_cast<const HyperbolicMirrorCamera*>(loaded.get());
  const auto* b = dynamic_cast<const HyperbolicMirrorCamera*>(builtin.get());
  ASSERT_TRUE(a && b);
  for (const Eigen::Vector2d& pixel :
       {Eigen::Vector2d(420, 240), Eigen::Vector2d(300, 100), Eigen::Vector2d(200, 330)}) {
    Eigen::Vector2d ga, gb;
    ASSERT_EQ(a->BackProjectToGround(pixel, &ga), ProjectionStatus::kOk);
    ASSERT_EQ(b->BackProjectToGround(pixel, &gb), ProjectionStatus::kOk);
    EXPECT_LT((ga - gb).norm(), 1e-9);
  }
  std::filesystem::remove(path);
}

TEST(CameraFile, RosIntrinsicsFileIsAPinholeModel) {
  PinholeBrownParameters p;
  p.width = 640;
  p.height = 480;
  p.fx = 600;
  p.fy = 601;
  p.cx = 320;
  p.cy = 241;
  p.distortion = {-0.2, 0.05, 0.001, -0.001, 0.0, 0, 0, 0};
  const std::string path = WriteTemp("ros.yaml", "");
  WritePinholeIntrinsics(path, p);
  const auto camera = LoadCameraModel(path);
  EXPECT_EQ(camera->Name(), "pinhole-brown");
  EXPECT_EQ(camera->width(), 640);
  Eigen::Vector2d pixel;
  ASSERT_EQ(camera->Project(Eigen::Vector3d(0, 0, 1), &pixel), ProjectionStatus::kOk);
  EXPECT_LT((pixel - Eigen::Vector2d(320, 241)).norm(), 1e-12);
  std::filesystem::remove(path);
}

TEST(CameraFile, EveryBadKeyIsNamed) {
  const std::string path = WriteTemp("bad.yaml", R"(
model: unified
width: 640.5
xi: abc
gamma1: 230
gamma1_px: 230
gamma2: 230
u0: 319.5
v0: 239.5
distortion: [0, 0, 0, 0, 0]
focal: 3
)");
  EXPECT_THAT(
      Error([&] { LoadCameraModel(path); }),
      AllOf(HasSubstr(path), HasSubstr("width: expected an integer, got '640.5'"),
            HasSubstr("height: missing"), HasSubstr("xi: expected a finite number, got 'abc'"),
            HasSubstr("distortion: need a list of up to 4 numbers"),
            HasSubstr("focal: unknown key"), HasSubstr("gamma1_px: unknown key")));
  std::filesystem::remove(path);
}

TEST(CameraFile, ModelValidationNamesTheFile) {
  const std::string path = WriteTemp("invalid.yaml", R"(
model: tsai
width: 1616
height: 1216
focal_length_mm: -9
cx: 738
cy: 585
pixel_pitch_x_mm: 0.0044
pixel_pitch_y_mm: 0.0044
)");
  EXPECT_THAT(Error([&] { LoadCameraModel(path); }),
              AllOf(HasSubstr(path), HasSubstr("focal_length_mm")));
  std::filesystem::remove(path);
}

TEST(CameraFile, UnknownModelMissingFileAndBuiltinNames) {
  const std::string path = WriteTemp("fisheye.yaml", "model: kannala-brandt\n");
  EXPECT_THAT(Error([&] { LoadCameraModel(path); }), HasSubstr("model: unknown 'kannala-brandt'"));
  EXPECT_THAT(Error([] { LoadCameraModel("/nonexistent/camera.yaml"); }),
              HasSubstr("/nonexistent/camera.yaml: cannot open"));
  EXPECT_THAT(
      Error([] { OpenCameraModel("builtin:nope"); }),
      AllOf(HasSubstr("unknown"), HasSubstr("tsai-seed004"), HasSubstr("hyperbolic-mirror-4mm")));
  for (const std::string& name : BuiltinCameraModelNames()) {
    EXPECT_TRUE(OpenCameraModel("builtin:" + name)->Validate().empty()) << name;
  }
  std::filesystem::remove(path);
}

}  // namespace
}  // namespace kinevis::vision
