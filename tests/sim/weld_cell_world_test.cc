#include "sim/weld_cell_world.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include "common/units.h"
#include "hal/camera/sim_camera.h"
#include "hal/weld/weld_robot_client.h"
#include "vision/render/scenes/laser_scene.h"

namespace kinevis::sim {
namespace {

using ::testing::HasSubstr;
using vision::render::LaserId;
using Joints = std::array<double, robots::kWeld5Joints>;

// A rendered scan, kept for triangulation.
struct Scan {
  std::vector<uint8_t> image;
  int width = 0, height = 0;
  ScanRecord record;
  vision::render::GroundTruth truth;
};

Scan RenderScan(WeldCellWorld* world) {
  Scan s;
  s.width = world->scanner_camera().width();
  s.height = world->scanner_camera().height();
  s.image.assign(static_cast<size_t>(s.width) * s.height, 0);
  s.record = world->RenderScan(
      0, vision::ImageView8{s.image.data(), s.width, s.height, static_cast<size_t>(s.width)},
      &s.truth);
  return s;
}

// The rotating laser's stripe, column by column: centre of gravity of the grey levels above the
// window's minimum in ±12 rows around the brightest pixel. Columns where the stripe is not a
// short run (the fixed laser's vertical stripe crosses there) or too faint are skipped.
std::vector<Eigen::Vector2d> RotatingStripePixels(const Scan& s) {
  std::vector<Eigen::Vector2d> pixels;
  for (int u = 20; u < s.width - 20; ++u) {
    int peak = 0, peak_v = 0, bright = 0;
    for (int v = 0; v < s.height; ++v) {
      const int g = s.image[static_cast<size_t>(v) * s.width + u];
      if (g > peak) peak = g, peak_v = v;
      bright += g > 100;
    }
    if (peak < 150 || bright > 20 || peak_v < 13 || peak_v >= s.height - 13) continue;
    int floor = 255;
    for (int v = peak_v - 12; v <= peak_v + 12; ++v) {
      floor = std::min<int>(floor, s.image[static_cast<size_t>(v) * s.width + u]);
    }
    double sum = 0.0, first = 0.0;
    for (int v = peak_v - 12; v <= peak_v + 12; ++v) {
      const double w = s.image[static_cast<size_t>(v) * s.width + u] - floor;
      sum += w;
      first += w * v;
    }
    if (sum > 100.0) pixels.emplace_back(u, first / sum);
  }
  return pixels;
}

// Triangulates a stripe pixel with a camera model and a laser plane in C (the ray meets the
// plane; seed 004 eq. (9) is this intersection, laser_scene.h).
bool Triangulate(const vision::CameraModel& camera, const vision::render::LaserPlane& plane,
                 const Eigen::Vector2d& pixel, Eigen::Vector3d* p_C) {
  vision::Ray ray;
  if (camera.BackProject(pixel, &ray) != vision::ProjectionStatus::kOk) return false;
  const double denominator = plane.normal.dot(ray.d_C);
  if (std::abs(denominator) < 1e-9) return false;
  const double t = plane.normal.dot(plane.point - ray.p_C_O) / denominator;
  if (!(t > 0)) return false;
  *p_C = ray.p_C_O + t * ray.d_C;
  return true;
}

WeldCellWorldConfig BoardConfig() {
  WeldCellWorldConfig c;
  c.workpiece = vision::render::LaserSceneParameters();
  c.workpiece.surface = vision::render::LaserSurfaceKind::kBoard;
  c.workpiece.half_extent = Eigen::Vector2d(0.15, 0.10);
  c.workpiece.gauge_block = true;  // 100 × 50 × 10 mm at the board's centre, 100 mm along x_S
  return c;
}

// Moves the robot through the real host driver over Modbus TCP; the driver's waits step the
// world (its clock is the world's).
void MoveTo(WeldCellWorld* world, const Joints& target, double duration) {
  hal::WeldRobotClient::Options o;
  o.clock = &world->clock();
  auto client = hal::WeldRobotClient::Open(world->backend(), o);
  client->Configure();
  ASSERT_FALSE(client->Activate());
  hal::WeldTrajectoryPoint point;
  point.joints = target;
  point.duration = duration;
  hal::WeldStreamReport report;
  const std::error_code ec =
      client->StreamTrajectory({point}, {}, nullptr, hal::WeldStreamOptions(), &report);
  ASSERT_FALSE(ec) << client->last_error_text();
  EXPECT_EQ(report.executed, 1u);
}

TEST(WeldCellWorld, TrueRobotDiffersFromTheNominalByRealisticSeededDhErrors) {
  WeldCellWorldConfig c;
  const robots::Weld5Model a = TrueWeld5Model(c);
  const robots::Weld5Model b = TrueWeld5Model(c);
  double max_length = 0.0, max_angle = 0.0;
  for (int i = 0; i < robots::kWeld5Joints; ++i) {
    const robots::DhJoint& t = a.joints[i];
    const robots::DhJoint& n = c.nominal.joints[i];
    EXPECT_EQ(t.a, b.joints[i].a);  // deterministic
    EXPECT_EQ(t.theta_offset, b.joints[i].theta_offset);
    max_length = std::max({max_length, std::abs(t.a - n.a), std::abs(t.d - n.d)});
    max_angle = std::max(
        {max_angle, std::abs(t.alpha - n.alpha), std::abs(t.theta_offset - n.theta_offset)});
  }
  std::printf("largest D-H error: %.3f mm, %.4f deg\n", max_length * 1e3, max_angle / common::kDeg);
  EXPECT_GT(max_length, 0.05e-3);
  EXPECT_LT(max_length, 1.0e-3);  // 5 σ
  EXPECT_GT(max_angle, 0.01 * common::kDeg);
  EXPECT_LT(max_angle, 0.25 * common::kDeg);

  c.seed = 2;
  EXPECT_NE(TrueWeld5Model(c).joints[0].a, a.joints[0].a);
  c.dh_length_sigma_mm = 0.0;
  c.dh_angle_sigma_deg = 0.0;
  const robots::Weld5Model exact = TrueWeld5Model(c);
  for (int i = 0; i < robots::kWeld5Joints; ++i) {
    EXPECT_EQ(exact.joints[i].d, c.nominal.joints[i].d);
    EXPECT_EQ(exact.joints[i].alpha, c.nominal.joints[i].alpha);
  }
}

TEST(WeldCellWorld, BadConfigIsRefusedWithEveryBadFieldNamed) {
  WeldCellWorldConfig c;
  c.dh_length_sigma_mm = -1.0;
  c.fps = 0.0;
  c.unit = 0;
  c.initial_joints[2] = 0.9;  // pz3 beyond 0.5 m
  c.workpiece.half_extent.x() = -0.1;
  const std::string message = c.Validate();
  EXPECT_THAT(message, HasSubstr("truth.dh_length_sigma_mm: must be >= 0, got -1"));
  EXPECT_THAT(message, HasSubstr("scanner.fps: must be > 0, got 0"));
  EXPECT_THAT(message, HasSubstr("modbus.unit: must be in 1..247, got 0"));
  EXPECT_THAT(message, HasSubstr("modbus.initial_joints[2]: 0.9 is outside the limits of pz3"));
  EXPECT_THAT(message, HasSubstr("workpiece: "));
  EXPECT_THROW(WeldCellWorld world(c), std::invalid_argument);
  EXPECT_EQ(WeldCellWorldConfig().Validate(), "");
}

TEST(WeldCellWorld, ConfigFileSetsTheTruthScannerWorkpieceAndController) {
  const std::string path = ::testing::TempDir() + "weld_cell_world_test.yaml";
  {
    std::ofstream f(path);
    f << "world: weld-cell\n"
         "seed: 7\n"
         "truth: {dh_length_sigma_mm: 0.1, dh_angle_sigma_deg: 0.02,\n"
         "        scanner_mount: {position: [-0.05, -0.06, 0.101], rpy_deg: [0, 0, 1]}}\n"
         "scanner: {cot_theta_y: 0.3, fixed_laser: false, name: my-scanner, fps: 2,\n"
         "          render: {supersampling: 2}}\n"
         "workpiece:\n"
         "  kind: blade\n"
         "  half_extent_mm: [90, 70]\n"
         "  curvature: [1, 0, 0]\n"
         "  pits: [{centre_mm: [10, -5], depth_mm: 0.8, sigma_mm: 2.5}]\n"
         "modbus: {transport: tcp, port: 0, unit: 3, buffer: 8, initial_joints: [5, 0, 150, 0, "
         "0]}\n"
         "step_period_ms: 2\n";
  }
  const WeldCellWorldConfig c = LoadWeldCellWorldConfig(path);
  EXPECT_EQ(c.seed, 7u);
  EXPECT_DOUBLE_EQ(c.dh_length_sigma_mm, 0.1);
  EXPECT_NEAR(c.X_5C.translation().z(), 0.101, 1e-12);
  EXPECT_DOUBLE_EQ(c.cot_theta_y, 0.3);
  EXPECT_FALSE(c.fixed_laser_on);
  EXPECT_EQ(c.camera_name, "my-scanner");
  EXPECT_EQ(c.render.supersampling, 2);
  EXPECT_NEAR(c.workpiece.half_extent.x(), 0.09, 1e-12);
  ASSERT_EQ(c.workpiece.pits.size(), 1u);
  EXPECT_NEAR(c.workpiece.pits[0].centre_S.y(), -0.005, 1e-12);
  EXPECT_NEAR(c.workpiece.pits[0].sigma, 2.5e-3, 1e-12);
  EXPECT_EQ(c.unit, 3);
  EXPECT_EQ(c.buffer_capacity, 8);
  EXPECT_NEAR(c.initial_joints[0], 5 * common::kDeg, 1e-12);
  EXPECT_NEAR(c.initial_joints[2], 0.150, 1e-12);
  EXPECT_NEAR(c.step_period_s, 0.002, 1e-12);

  {
    std::ofstream f(path);
    f << "world: weld-cell\n"
         "scanner: {fps: -1, colour: red}\n"
         "workpiece: {kind: plate, pits: [{depth_mm: x}]}\n"
         "modbus: {transport: udp}\n";
  }
  try {
    LoadWeldCellWorldConfig(path);
    FAIL() << "no exception";
  } catch (const std::invalid_argument& e) {
    const std::string m = e.what();
    EXPECT_THAT(m, HasSubstr(path));
    EXPECT_THAT(m, HasSubstr("scanner.colour: unknown key"));
    EXPECT_THAT(m, HasSubstr("workpiece.kind: expected blade or board, got 'plate'"));
    EXPECT_THAT(m, HasSubstr("workpiece.pits[0].depth_mm: expected a finite number"));
    EXPECT_THAT(m, HasSubstr("modbus.transport: expected tcp or rtu, got 'udp'"));
  }
}

TEST(WeldCellWorld, TheShippedConfigHoldsTheDefaults) {
  const std::string root = KINEVIS_SOURCE_DIR;
  const WeldCellWorldConfig c = LoadWeldCellWorldConfig(root + "/config/weld-cell-sim.yaml");
  const WeldCellWorldConfig d;
  EXPECT_THAT(c.robot_description, HasSubstr("robots/weld5/weld5.yaml"));
  for (int i = 0; i < robots::kWeld5Joints; ++i) {
    EXPECT_NEAR(c.nominal.joints[i].a, d.nominal.joints[i].a, 1e-12) << i;
    EXPECT_NEAR(c.nominal.joints[i].alpha, d.nominal.joints[i].alpha, 1e-12) << i;
    EXPECT_NEAR(c.nominal.joints[i].d, d.nominal.joints[i].d, 1e-12) << i;
    EXPECT_NEAR(c.nominal.joints[i].theta_offset, d.nominal.joints[i].theta_offset, 1e-12) << i;
    EXPECT_NEAR(c.initial_joints[i], d.initial_joints[i], 1e-12) << i;
  }
  EXPECT_TRUE(c.nominal.X_5T.isApprox(d.nominal.X_5T, 1e-12));
  EXPECT_EQ(c.seed, d.seed);
  EXPECT_EQ(c.dh_length_sigma_mm, d.dh_length_sigma_mm);
  EXPECT_EQ(c.dh_angle_sigma_deg, d.dh_angle_sigma_deg);
  EXPECT_TRUE(c.X_5C.isApprox(d.X_5C, 1e-12));
  EXPECT_TRUE(c.X_5C_nominal.isApprox(d.X_5C_nominal, 1e-12));
  EXPECT_TRUE(c.X_0S.isApprox(d.X_0S, 1e-12));
  EXPECT_NEAR(c.scanner.rotating_d_y, d.scanner.rotating_d_y, 1e-15);
  EXPECT_EQ(c.cot_theta_y, d.cot_theta_y);
  EXPECT_EQ(c.camera_name, d.camera_name);
  EXPECT_EQ(c.workpiece.curvature_xy, d.workpiece.curvature_xy);
  ASSERT_EQ(c.workpiece.pits.size(), d.workpiece.pits.size());
  for (size_t i = 0; i < c.workpiece.pits.size(); ++i) {
    EXPECT_TRUE(c.workpiece.pits[i].centre_S.isApprox(d.workpiece.pits[i].centre_S, 1e-12));
    EXPECT_NEAR(c.workpiece.pits[i].depth, d.workpiece.pits[i].depth, 1e-15);
    EXPECT_NEAR(c.workpiece.pits[i].sigma, d.workpiece.pits[i].sigma, 1e-15);
  }
  EXPECT_EQ(c.tcp_port, 0);
  EXPECT_FALSE(c.rtu);
}

TEST(WeldCellWorld, AMoveOverModbusTcpMovesTheScannerAndTheStripeTriangulatesOntoTheBlade) {
  WeldCellWorld world{WeldCellWorldConfig()};
  ASSERT_THAT(world.backend(), ::testing::StartsWith("modbus-tcp:127.0.0.1:"));
  const Joints start = world.joints();
  EXPECT_EQ(start, world.config().initial_joints);

  // θ1 +3°, pz3 +25 mm (towards the blade), θ4 −2°, θ5 +4°: a scan pose.
  const Joints target{3 * common::kDeg, 0.0, 0.225, -2 * common::kDeg, 4 * common::kDeg};
  MoveTo(&world, target, 0.8);
  const Joints now = world.joints();
  for (int j = 0; j < robots::kWeld5Joints; ++j) EXPECT_NEAR(now[j], target[j], 1e-6) << j;

  const Scan s = RenderScan(&world);
  EXPECT_EQ(s.record.joints, now);  // the joint reading at the scan
  ASSERT_EQ(world.scan_log().size(), 1u);
  EXPECT_EQ(world.scan_log()[0].joints, now);
  EXPECT_TRUE(s.record.X_0C.isApprox(world.TrueScannerPose(now)));

  const std::unique_ptr<vision::render::LaserScene> scene = world.SceneAt(now);
  const vision::render::LaserPlane& plane = scene->plane(LaserId::kRotating);
  const Eigen::Isometry3d X_S0 = world.config().X_0S.inverse();
  // The same pixels as the host would triangulate them with the NOMINAL robot and mount.
  robots::Vector5d q;
  for (int j = 0; j < 5; ++j) q(j) = now[j];
  // The true scanner pose from the true robot and mount, independently of the world's own.
  const Eigen::Isometry3d X_0C_true =
      robots::DhForwardKinematics(world.true_model().joints, q) * world.config().X_5C;
  EXPECT_TRUE(s.record.X_0C.isApprox(X_0C_true, 1e-12));
  const Eigen::Isometry3d X_0C_nominal =
      robots::DhForwardKinematics(world.nominal_model().joints, q) * world.config().X_5C_nominal;

  const std::vector<Eigen::Vector2d> pixels = RotatingStripePixels(s);
  int points = 0;
  double worst = 0.0, nominal_sum = 0.0;
  for (const Eigen::Vector2d& pixel : pixels) {
    Eigen::Vector3d p_C;
    ASSERT_TRUE(Triangulate(world.scanner_camera(), plane, pixel, &p_C));
    const Eigen::Vector3d p_S = X_S0 * X_0C_true * p_C;  // via the base frame
    const auto& w = world.config().workpiece;
    if (std::abs(p_S.x()) > w.half_extent.x() - 2e-3 ||
        std::abs(p_S.y()) > w.half_extent.y() - 2e-3) {
      continue;  // the sheet's edge
    }
    worst = std::max(worst, std::abs(p_S.z() - scene->Height(p_S.x(), p_S.y())));
    const Eigen::Vector3d p_S_nominal = X_S0 * X_0C_nominal * p_C;
    nominal_sum += std::abs(p_S_nominal.z() - scene->Height(p_S_nominal.x(), p_S_nominal.y()));
    ++points;
  }
  const double nominal_mean = nominal_sum / std::max(points, 1);
  std::printf(
      "blade scan at %.3f m: %d stripe points, worst |z_S - f| = %.4f mm with the true robot and "
      "mount; mean %.3f mm with the nominal ones\n",
      (s.record.X_0C.inverse() * world.config().X_0S).translation().z(), points, worst * 1e3,
      nominal_mean * 1e3);
  EXPECT_GT(points, 500);  // the stripe crosses the whole blade (≈ 1000 columns at 0.37 m)
  EXPECT_LT(worst, 0.15e-3);
  // The nominal robot and mount put the same points millimetres off the surface: what kinematic
  // and hand-eye calibration have to remove.
  EXPECT_GT(nominal_mean, 0.5e-3);
}

TEST(WeldCellWorld, TheControllerCanServeModbusRtuOnAPseudoTerminal) {
  WeldCellWorldConfig c;
  c.rtu = true;
  c.unit = 7;
  WeldCellWorld world(c);
  ASSERT_THAT(world.backend(),
              ::testing::MatchesRegex("modbus-rtu:/dev/pts/[0-9]+@115200,8E1,unit=7"));
  hal::WeldRobotClient::Options o;
  o.clock = &world.clock();
  auto client = hal::WeldRobotClient::Open(world.backend(), o);
  client->Configure();
  hal::WeldRobotState state;
  ASSERT_FALSE(client->ReadState(&state)) << client->last_error_text();
  for (int j = 0; j < robots::kWeld5Joints; ++j) {
    EXPECT_NEAR(state.joints[j], c.initial_joints[j], 1e-6) << j;
  }
}

TEST(WeldCellWorld, TheGaugeBlockAppearsInTheBoardScan) {
  WeldCellWorld world(BoardConfig());
  const Scan s = RenderScan(&world);
  const std::unique_ptr<vision::render::LaserScene> scene = world.SceneAt(s.record.joints);
  const vision::render::LaserPlane& plane = scene->plane(LaserId::kRotating);
  const Eigen::Isometry3d X_S0 = world.config().X_0S.inverse();
  const double height = world.config().workpiece.gauge_size.z();
  int on_board = 0, on_block = 0, elsewhere = 0;
  double worst_block = 0.0;
  for (const Eigen::Vector2d& pixel : RotatingStripePixels(s)) {
    Eigen::Vector3d p_C;
    ASSERT_TRUE(Triangulate(world.scanner_camera(), plane, pixel, &p_C));
    const Eigen::Vector3d p_S = X_S0 * s.record.X_0C * p_C;
    if (std::abs(p_S.z()) < 0.15e-3) {
      ++on_board;
    } else if (std::abs(p_S.z() - height) < 0.15e-3) {
      ++on_block;
      // On the block's top face: within its 100 × 50 mm footprint.
      worst_block = std::max({worst_block, std::abs(p_S.x()) - 0.05, std::abs(p_S.y()) - 0.025});
    } else {
      ++elsewhere;  // the centroid straddles a step of the surface
    }
  }
  int block_pixels = 0;
  for (int object : s.truth.object) block_pixels += object == vision::render::kLaserGaugeBlock;
  std::printf("board scan: %d stripe points on the board, %d on the 10 mm block, %d at steps\n",
              on_board, on_block, elsewhere);
  EXPECT_GT(block_pixels, 100000);
  EXPECT_GT(on_block, 300);  // 100 mm of stripe at ≈ 5.5 px/mm
  EXPECT_GT(on_board, 300);
  EXPECT_LT(elsewhere, 20);
  EXPECT_LT(worst_block, 0.5e-3);
}

TEST(WeldCellWorld, TheScannerIsARenderSourceThatLogsTheJointsOfEveryFrame) {
  WeldCellWorldConfig c;
  c.camera_name = "weld-scanner-test";
  c.render.supersampling = 1;
  WeldCellWorld world(c);
  ASSERT_EQ(world.RegisterCamera(), "weld-scanner-test");
  hal::SimCameraOptions o;
  o.source = "weld-scanner-test";
  hal::SimCamera camera("sim:weld-scanner-test", o, world.clock());
  camera.Open();
  ASSERT_FALSE(camera.Start());
  hal::Image image;
  ASSERT_FALSE(camera.Grab(&image, std::chrono::milliseconds(1000)));
  ASSERT_FALSE(camera.Grab(&image, std::chrono::milliseconds(1000)));
  EXPECT_EQ(image.width, 1616);
  EXPECT_EQ(image.height, 1216);
  EXPECT_GT(*std::max_element(image.data.begin(), image.data.end()), 150);  // a stripe
  const std::vector<ScanRecord> log = world.scan_log();
  ASSERT_EQ(log.size(), 2u);
  EXPECT_EQ(log[1].frame_id, 1u);
  EXPECT_GT(log[1].time, log[0].time);  // the grab waited for the frame on the world's clock
  EXPECT_EQ(log[1].joints, c.initial_joints);

  world.SetLaserAngle(0.3);
  EXPECT_EQ(world.laser_angle(), 0.3);
  EXPECT_THROW(world.SetLaserAngle(std::nan("")), std::invalid_argument);
}

}  // namespace
}  // namespace kinevis::sim
