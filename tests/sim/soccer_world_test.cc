#include "sim/soccer_world.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include "common/units.h"
#include "hal/camera/sim_camera.h"

namespace kinevis::sim {
namespace {

using ::testing::HasSubstr;
using vision::ProjectionStatus;

SoccerWorldConfig RobotNearTheCentreLine() {
  SoccerWorldConfig c;
  c.field.robot_x = -1.2;  // halfway line 1.2 m ahead, centre circle to the front left
  c.field.robot_y = 0.4;
  c.field.robot_heading = 20 * common::kDeg;
  c.render.supersampling = 2;
  return c;
}

TEST(SoccerRobotWorld, GroundTruthOfEveryPixelThatSeesALineLiesOnThatLine) {
  SoccerRobotWorld world(RobotNearTheCentreLine());
  const int width = world.true_camera().width(), height = world.true_camera().height();
  std::vector<uint8_t> image(static_cast<size_t>(width) * height);
  vision::render::GroundTruth truth;
  world.Render(0, vision::ImageView8{image.data(), width, height, static_cast<size_t>(width)},
               &truth);
  const double half_width = 0.5 * world.config().field.line_width;
  int line_pixels = 0, carpet_pixels = 0;
  double worst_line = 0.0, nearest_carpet = 1e9, line_grey = 0.0;
  for (int v = 0; v < height; ++v) {
    for (int u = 0; u < width; ++u) {
      const int object = truth.object[static_cast<size_t>(v) * width + u];
      if (object != vision::render::kFieldLine && object != vision::render::kFieldCarpet) continue;
      const SoccerPixelTruth t = world.GroundTruth(Eigen::Vector2d(u, v));
      ASSERT_TRUE(t.valid) << u << "," << v;
      const double d = world.scene()->LineDistance(t.p_F);
      if (object == vision::render::kFieldLine) {
        ++line_pixels;
        worst_line = std::max(worst_line, d);
        line_grey += image[static_cast<size_t>(v) * width + u];
      } else {
        ++carpet_pixels;
        nearest_carpet = std::min(nearest_carpet, d);
      }
    }
  }
  std::printf(
      "%d line pixels, farthest %.4f m from a line's centre; %d carpet pixels, nearest "
      "%.4f m\n",
      line_pixels, worst_line, carpet_pixels, nearest_carpet);
  EXPECT_GT(line_pixels, 1000);
  // Drawn white on the whole (lines far away are thinner than a pixel and blend with the carpet).
  EXPECT_GT(line_grey / line_pixels, 150.0);
  EXPECT_LE(worst_line, half_width + 1e-9);
  EXPECT_GE(nearest_carpet, half_width - 1e-9);
}

TEST(SoccerRobotWorld, GroundTruthMapIsThePerPixelTruthInTheFieldFrame) {
  SoccerRobotWorld world(RobotNearTheCentreLine());
  const SoccerGroundTruthMap map = world.GroundTruthMap();
  const int width = map.map_G.width;
  ASSERT_EQ(width, 640);
  ASSERT_EQ(map.map_G.height, 480);
  EXPECT_GT(map.map_G.valid_count, 50000);
  std::mt19937 generator(5);
  std::uniform_int_distribution<int> u_dist(0, 639), v_dist(0, 479);
  int checked = 0;
  for (int i = 0; i < 2000; ++i) {
    const int u = u_dist(generator), v = v_dist(generator);
    const size_t k = static_cast<size_t>(v) * width + u;
    const SoccerPixelTruth t = world.GroundTruth(Eigen::Vector2d(u, v));
    ASSERT_EQ(t.valid, map.map_G.valid[k] != 0) << u << "," << v;
    if (!t.valid) {
      EXPECT_TRUE(std::isnan(map.distance[k]));
      EXPECT_TRUE(std::isnan(world.GroundTruthDistance(Eigen::Vector2d(u, v))));
      continue;
    }
    EXPECT_NEAR(map.x_F[k], t.p_F.x(), 1e-8);
    EXPECT_NEAR(map.y_F[k], t.p_F.y(), 1e-8);
    EXPECT_NEAR(map.distance[k], t.distance, 1e-8);
    // F from G: the robot's pose on the field.
    const double c = std::cos(20 * common::kDeg), s = std::sin(20 * common::kDeg);
    EXPECT_NEAR(t.p_F.x(), -1.2 + c * t.p_G.x() - s * t.p_G.y(), 1e-12);
    EXPECT_NEAR(t.p_F.y(), 0.4 + s * t.p_G.x() + c * t.p_G.y(), 1e-12);
    ++checked;
  }
  EXPECT_GT(checked, 300);

  // Moving the robot moves the field coordinates, not the robot-centred distances.
  const Eigen::Vector2d pixel(320 + 150, 240);
  const SoccerPixelTruth before = world.GroundTruth(pixel);
  world.SetRobotPose(2.0, -1.0, 0.0);
  const SoccerPixelTruth after = world.GroundTruth(pixel);
  ASSERT_TRUE(before.valid && after.valid);
  EXPECT_EQ(before.distance, after.distance);
  EXPECT_NEAR((after.p_F - Eigen::Vector2d(2.0, -1.0)).norm(), after.distance, 1e-12);
  EXPECT_THROW(world.SetRobotPose(std::nan(""), 0, 0), std::invalid_argument);
}

// Distance-map error of the misalignment-free camera against the truth, for ground points at
// `range` m all around the robot (every 5°): the true camera images the point; the nominal one
// maps that pixel back to the ground. Returns the RMS and largest error (m) of the position and
// writes the largest |distance error| to *distance_error.
void NominalMapError(const SoccerRobotWorld& world, double range, double* rms, double* worst,
                     double* distance_error) {
  double sum = 0.0;
  int n = 0;
  *worst = *distance_error = 0.0;
  for (int k = 0; k < 72; ++k) {
    const double a = k * 5 * common::kDeg;
    const Eigen::Vector2d p_G = range * Eigen::Vector2d(std::cos(a), std::sin(a));
    Eigen::Vector2d pixel, p_G_nominal;
    ASSERT_EQ(world.true_camera().ProjectGroundPoint(p_G, &pixel), ProjectionStatus::kOk) << k;
    // The ground truth of that pixel is the point itself.
    ASSERT_NEAR(world.GroundTruthDistance(pixel), range, 1e-6 * range);
    ASSERT_EQ(world.nominal_camera().BackProjectToGround(pixel, &p_G_nominal),
              ProjectionStatus::kOk);
    const double e = (p_G_nominal - p_G).norm();
    sum += e * e;
    *worst = std::max(*worst, e);
    *distance_error = std::max(*distance_error, std::abs(p_G_nominal.norm() - range));
    ++n;
  }
  *rms = std::sqrt(sum / n);
}

TEST(SoccerRobotWorld, TheNominalCameraMapIsOffByWhatCalibrationMustRemove) {
  SoccerRobotWorld world{SoccerWorldConfig()};
  // Seed 000's precision after calibration: ±1.5 cm at 1 m, ±4 cm at 2 m, ±20 cm at 5 m.
  const double ranges[] = {1.0, 2.0, 5.0};
  const double calibrated[] = {0.015, 0.04, 0.20};
  for (int i = 0; i < 3; ++i) {
    double rms = 0, worst = 0, distance_error = 0;
    NominalMapError(world, ranges[i], &rms, &worst, &distance_error);
    std::printf(
        "at %.0f m: nominal map position error RMS %.3f m, max %.3f m; max distance "
        "error %.3f m\n",
        ranges[i], rms, worst, distance_error);
    // Larger than the calibrated precision (there is something to calibrate), and a realistic
    // amount (a usable but visibly wrong map, seed 000 Fig. 12 left): under 60 % of the range.
    // Measured with the defaults: max 0.17 m at 1 m, 0.43 m at 2 m, 2.35 m at 5 m.
    EXPECT_GT(worst, 2 * calibrated[i]) << ranges[i];
    EXPECT_LT(worst, 0.6 * ranges[i]) << ranges[i];
  }
  // Without misalignments the nominal camera is the truth.
  SoccerWorldConfig aligned;
  aligned.camera = WithoutMisalignment(aligned.camera);
  SoccerRobotWorld exact(aligned);
  double rms = 0, worst = 0, distance_error = 0;
  NominalMapError(exact, 2.0, &rms, &worst, &distance_error);
  EXPECT_LT(worst, 1e-6);
}

TEST(SoccerRobotWorld, TheShippedConfigHoldsTheDefaults) {
  const std::string root = KINEVIS_SOURCE_DIR;
  const SoccerWorldConfig c = LoadSoccerWorldConfig(root + "/config/soccer-sim.yaml");
  const SoccerWorldConfig d;
  EXPECT_NEAR(c.camera.sensor_offset_x, d.camera.sensor_offset_x, 1e-15);
  EXPECT_NEAR(c.camera.sensor_offset_z, d.camera.sensor_offset_z, 1e-15);
  EXPECT_NEAR(c.camera.sensor_gamma, d.camera.sensor_gamma, 1e-15);
  EXPECT_NEAR(c.camera.sensor_rho, d.camera.sensor_rho, 1e-15);
  EXPECT_NEAR(c.camera.sensor_theta, d.camera.sensor_theta, 1e-15);
  EXPECT_NEAR(c.camera.ground_rho, d.camera.ground_rho, 1e-15);
  EXPECT_NEAR(c.camera.ground_theta, d.camera.ground_theta, 1e-15);
  EXPECT_EQ(c.camera.focal_length, d.camera.focal_length);
  EXPECT_EQ(c.field.robot_x, d.field.robot_x);
  EXPECT_EQ(c.field.line_width, d.field.line_width);
  EXPECT_EQ(c.camera_name, d.camera_name);
  EXPECT_EQ(c.fps, d.fps);
}

TEST(SoccerRobotWorld, ConfigFileAndBadValues) {
  const std::string path = ::testing::TempDir() + "soccer_world_test.yaml";
  {
    std::ofstream f(path);
    f << "world: soccer\n"
         "camera: {lens: 4mm, sensor_offset_mm: [0.1, -0.4], sensor_rotation_deg: [1, 0.5, -0.7],\n"
         "         mirror_tilt_deg: [0.2, 0.4]}\n"
         "robot: {x: 3, y: -2, heading_deg: 90}\n"
         "name: omni-test\n"
         "fps: 25\n";
  }
  const SoccerWorldConfig c = LoadSoccerWorldConfig(path);
  EXPECT_NEAR(c.camera.sensor_offset_z, -0.4e-3, 1e-15);
  EXPECT_NEAR(c.camera.sensor_gamma, 1 * common::kDeg, 1e-15);
  EXPECT_NEAR(c.camera.sensor_theta, -0.7 * common::kDeg, 1e-15);
  EXPECT_NEAR(c.camera.ground_theta, 0.4 * common::kDeg, 1e-15);
  EXPECT_EQ(c.camera.focal_length, 4.56e-3);
  EXPECT_EQ(c.field.robot_x, 3.0);
  EXPECT_NEAR(c.field.robot_heading, M_PI / 2, 1e-15);
  EXPECT_EQ(c.camera_name, "omni-test");
  EXPECT_EQ(c.fps, 25.0);
  {
    std::ofstream f(path);
    f << "world: soccer\ncamera: {lens: 5mm, sensor_rotation_deg: [40, 0, 0]}\nfps: 0\nball: 1\n";
  }
  try {
    LoadSoccerWorldConfig(path);
    FAIL() << "no exception";
  } catch (const std::invalid_argument& e) {
    const std::string m = e.what();
    EXPECT_THAT(m, HasSubstr("camera.lens: expected 4mm or 6mm, got '5mm'"));
    EXPECT_THAT(m, HasSubstr("ball: unknown key"));
  }
  SoccerWorldConfig bad;
  bad.fps = 0;
  bad.camera.sensor_gamma = 1.0;  // beyond |0.5| rad
  bad.field.line_width = -1;
  const std::string m = bad.Validate();
  EXPECT_THAT(m, HasSubstr("fps: must be > 0, got 0"));
  EXPECT_THAT(m, HasSubstr("camera: "));
  EXPECT_THAT(m, HasSubstr("sensor_gamma"));
  EXPECT_THAT(m, HasSubstr("field: "));
  EXPECT_THROW(SoccerRobotWorld world(bad), std::invalid_argument);
}

TEST(SoccerRobotWorld, TheCameraIsARenderSource) {
  SoccerWorldConfig c;
  c.camera_name = "soccer-omni-test";
  SoccerRobotWorld world(c);
  ASSERT_EQ(world.RegisterCamera(), "soccer-omni-test");
  hal::SimCameraOptions o;
  o.source = "soccer-omni-test";
  hal::SimCamera camera("sim:soccer-omni-test", o, world.clock());
  camera.Open();
  ASSERT_FALSE(camera.Start());
  hal::Image image;
  ASSERT_FALSE(camera.Grab(&image, std::chrono::milliseconds(100)));
  EXPECT_EQ(image.width, 640);
  EXPECT_EQ(image.height, 480);
  // The robot at the centre spot sees the centre circle and the halfway line: white pixels.
  const int white = static_cast<int>(
      std::count_if(image.data.begin(), image.data.end(), [](uint8_t g) { return g > 200; }));
  EXPECT_GT(white, 500);
}

}  // namespace
}  // namespace kinevis::sim
