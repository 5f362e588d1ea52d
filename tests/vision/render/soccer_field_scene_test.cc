#include "vision/render/scenes/soccer_field_scene.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <random>
#include <set>
#include <vector>

#include "vision/camera/hyperbolic_mirror_camera.h"
#include "vision/render/primitives.h"

namespace kinevis::vision::render {
namespace {

HyperbolicMirrorCamera SeedCamera() {
  return HyperbolicMirrorCamera(HyperbolicMirrorParameters::Seed000Lens4mm());
}

bool IsGround(int object) {
  return object == kFieldCarpet || object == kFieldLine || object == kFieldFloor;
}

// Every pixel that sees the ground: the scene's line/carpet decision is the analytic line distance
// of the camera's own BackProjectToGround() point, and the traced ground point is that point.
void CheckLinesAgainstGroundMap(const HyperbolicMirrorCamera& camera, const SoccerFieldScene& scene,
                                int* line_pixels, int* ground_pixels) {
  *line_pixels = 0;
  *ground_pixels = 0;
  int mismatches = 0;
  double worst_point = 0.0;
  const double half_width = 0.5 * scene.parameters().line_width;
  for (int v = 0; v < camera.height(); ++v) {
    for (int u = 0; u < camera.width(); ++u) {
      const Eigen::Vector2d pixel(u, v);
      Ray ray;
      if (camera.BackProject(pixel, &ray) != ProjectionStatus::kOk) continue;
      const Hit hit = scene.Trace(ray);
      if (!IsGround(hit.object)) continue;
      Eigen::Vector2d p_G;
      ASSERT_EQ(camera.BackProjectToGround(pixel, &p_G), ProjectionStatus::kOk) << u << "," << v;
      const Eigen::Vector3d traced_G = scene.X_CG().inverse() * (ray.p_C_O + hit.depth * ray.d_C);
      // The camera's ground map and our ray–plane intersection agree to rounding, which grows with
      // the distance (grazing rays): 8e-6 m at 10 m measured with a misaligned sensor.
      const double tolerance = 2e-6 * (1.0 + p_G.norm());
      worst_point = std::max(worst_point, (traced_G.head<2>() - p_G).norm() / tolerance);
      EXPECT_NEAR(traced_G.z(), 0.0, 1e-9);
      const FieldPoint truth = scene.ClassifyGround(p_G);
      ++*ground_pixels;
      if (truth.on_line) ++*line_pixels;
      // Undecidable within rounding: skip points on a line's border.
      if (std::abs(truth.line_distance - half_width) < tolerance) continue;
      if (truth.on_line != (hit.object == kFieldLine)) ++mismatches;
    }
  }
  EXPECT_EQ(mismatches, 0);
  EXPECT_LT(worst_point, 1.0);
}

// Trace() as first written (issue 5), without the culls, the grid of lines and the specialised
// cylinder tests that make it fast: every post, the lens body and disc, the robot body and disc
// and the ground by the generic primitives, nearest wins (ties to the first), the ground point
// classified by ClassifyGround().
Hit ReferenceTrace(const SoccerFieldScene& scene, const Ray& ray_C, double* line_distance) {
  const SoccerFieldSceneParameters& p = scene.parameters();
  const Eigen::Isometry3d& X_CG = scene.X_CG();
  const Eigen::Isometry3d X_GC = X_CG.inverse();
  *line_distance = kNoHit;
  const double to_mirror = ray_C.p_C_O.norm();
  Ray incoming;
  incoming.d_C = ray_C.p_C_O / to_mirror;
  Eigen::Vector3d bottom, top;
  for (int i = 0; i < p.post_count; ++i) {
    scene.PostAxis(i, &bottom, &top);
    if (IntersectCylinder(incoming, bottom, top, p.post_radius) < to_mirror) {
      return Hit{p.post_radiance, kFieldMirrorPost, 0.0};
    }
  }
  double best = kNoHit;
  int object = kFieldSurroundings;
  auto consider = [&](double t, int id) {
    if (t < best) {
      best = t;
      object = id;
    }
  };
  for (int i = 0; i < p.post_count; ++i) {
    scene.PostAxis(i, &bottom, &top);
    consider(IntersectCylinder(ray_C, bottom, top, p.post_radius), kFieldMirrorPost);
  }
  const double pinhole_height = (X_GC * Eigen::Vector3d::Zero()).z();
  const Eigen::Vector3d lens_bottom(0.0, -(pinhole_height - p.body_height), 0.0);
  consider(IntersectCylinder(ray_C, lens_bottom, Eigen::Vector3d::Zero(), p.lens_radius),
           kFieldLensBody);
  consider(IntersectDisc(ray_C, Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitY(), p.lens_radius),
           kFieldLensBody);
  const Eigen::Vector3d z_G = X_CG.linear().col(2);
  const Eigen::Vector3d body_bottom = X_CG.translation();
  const Eigen::Vector3d body_top = X_CG * Eigen::Vector3d(0.0, 0.0, p.body_height);
  consider(IntersectCylinder(ray_C, body_bottom, body_top, p.body_radius), kFieldRobotBody);
  consider(IntersectDisc(ray_C, body_top, z_G, p.body_radius), kFieldRobotBody);
  const double t_ground = IntersectPlane(ray_C, body_bottom, z_G);
  const bool ground_nearest = t_ground < best;
  consider(t_ground, kFieldCarpet);
  Hit hit{0.0, object, best};
  if (ground_nearest) {
    const Eigen::Vector3d p_G = X_GC * (ray_C.p_C_O + t_ground * ray_C.d_C);
    const FieldPoint field = scene.ClassifyGround(p_G.head<2>());
    *line_distance = field.line_distance;
    hit.object = !field.on_carpet ? kFieldFloor : field.on_line ? kFieldLine : kFieldCarpet;
  }
  switch (hit.object) {
    case kFieldMirrorPost:
      hit.radiance = p.post_radiance;
      break;
    case kFieldLensBody:
      hit.radiance = p.lens_radiance;
      break;
    case kFieldRobotBody:
      hit.radiance = p.body_radiance;
      break;
    case kFieldSurroundings:
      hit.radiance = p.surroundings_radiance;
      break;
    case kFieldFloor:
      hit.radiance = p.floor_radiance;
      break;
    case kFieldLine:
      hit.radiance = p.line_radiance;
      break;
    default:
      hit.radiance = p.carpet_radiance;
      break;
  }
  return hit;
}

// Random sub-pixel rays over the whole mirror (posts, lens, body, lines, horizon included).
void CheckTraceAgainstReference(const HyperbolicMirrorCamera& camera, const SoccerFieldScene& scene,
                                int samples) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-0.5, camera.width() - 0.5);
  std::uniform_real_distribution<double> v(-0.5, camera.height() - 0.5);
  const double half_width = 0.5 * scene.parameters().line_width;
  int traced = 0, different = 0, undecidable = 0;
  std::array<int, 8> seen{};
  for (int k = 0; k < samples; ++k) {
    Ray ray;
    if (camera.BackProject(Eigen::Vector2d(u(rng), v(rng)), &ray) != ProjectionStatus::kOk) {
      continue;
    }
    ++traced;
    double line_distance = kNoHit;
    const Hit expected = ReferenceTrace(scene, ray, &line_distance);
    const Hit hit = scene.Trace(ray);
    ++seen[hit.object];
    // The fast line test compares squared distances: a point within rounding of a line's border
    // may go either way.
    if (std::abs(line_distance - half_width) < 1e-12) {
      ++undecidable;
      continue;
    }
    if (hit.object != expected.object || hit.radiance != expected.radiance ||
        hit.depth != expected.depth) {
      ++different;
    }
  }
  EXPECT_EQ(different, 0);
  EXPECT_LT(undecidable, 3);
  EXPECT_GT(traced, samples / 2);
  // Every object but the surroundings (this mirror sees nothing above the horizon).
  for (int object :
       {kFieldCarpet, kFieldLine, kFieldFloor, kFieldRobotBody, kFieldLensBody, kFieldMirrorPost}) {
    EXPECT_GT(seen[object], 20) << "object " << object;
  }
}

TEST(SoccerFieldScene, FastTraceEqualsTheUnculledReference) {
  const HyperbolicMirrorCamera camera = SeedCamera();
  SoccerFieldSceneParameters p;
  p.robot_x = 6.2;  // near a goal area and the side line, so that every object is seen
  p.robot_y = 4.9;
  p.robot_heading = 0.4;
  CheckTraceAgainstReference(camera, SoccerFieldScene(camera, p), 200000);
  // A tilted mirror: the robot body's axis is no longer y_C (the generic cylinder path).
  HyperbolicMirrorParameters mp = HyperbolicMirrorParameters::Seed000Lens4mm();
  mp.ground_rho = 0.02;
  mp.ground_theta = -0.015;
  const HyperbolicMirrorCamera tilted(mp);
  p.robot_heading = -2.5;
  CheckTraceAgainstReference(tilted, SoccerFieldScene(tilted, p), 200000);
}

TEST(SoccerFieldScene, LinePixelsAreWhereTheGroundMapPutsLines) {
  const HyperbolicMirrorCamera camera = SeedCamera();
  SoccerFieldSceneParameters p;
  p.robot_x = 1.2;
  p.robot_y = -0.7;
  p.robot_heading = 0.4;
  const SoccerFieldScene scene(camera, p);
  int lines = 0, ground = 0;
  CheckLinesAgainstGroundMap(camera, scene, &lines, &ground);
  std::printf("robot at (1.2, -0.7, 0.4): %d ground pixels, %d on lines\n", ground, lines);
  EXPECT_GT(ground, 100000);
  EXPECT_GT(lines, 500);
}

TEST(SoccerFieldScene, LinesNearAGoalAreaWithATiltedMirror) {
  HyperbolicMirrorParameters mp = HyperbolicMirrorParameters::Seed000Lens4mm();
  mp.ground_rho = 0.02;
  mp.ground_theta = -0.015;
  mp.sensor_offset_x = 0.0003;
  const HyperbolicMirrorCamera camera(mp);
  SoccerFieldSceneParameters p;
  p.robot_x = 7.5;
  p.robot_y = 1.0;
  p.robot_heading = -2.5;
  const SoccerFieldScene scene(camera, p);
  int lines = 0, ground = 0;
  CheckLinesAgainstGroundMap(camera, scene, &lines, &ground);
  EXPECT_GT(lines, 500);
}

TEST(SoccerFieldScene, RenderedLineMaskMatchesTheGroundTruth) {
  // Through the Renderer: pixels well inside a line are white, well inside the carpet green-grey;
  // a threshold mask of the 8-bit image equals the analytic line mask away from line borders.
  const HyperbolicMirrorCamera camera = SeedCamera();
  SoccerFieldSceneParameters p;
  p.robot_x = 0.4;
  p.robot_y = 0.3;
  p.robot_heading = -0.7;
  const SoccerFieldScene scene(camera, p);
  Renderer renderer(camera, RenderOptions{});
  const int width = camera.width(), height = camera.height();
  std::vector<uint8_t> image(static_cast<size_t>(width) * height);
  GroundTruth truth;
  renderer.Render(scene, 0, ImageView8{image.data(), width, height, static_cast<size_t>(width)},
                  &truth);
  const double threshold = 255.0 * 0.5 * (p.line_radiance + p.carpet_radiance);
  int checked = 0, line_pixels = 0, wrong = 0, dark_outside = 0, outside = 0;
  for (int v = 1; v < height - 1; ++v) {
    for (int u = 1; u < width - 1; ++u) {
      const int i = v * width + u;
      // Whether the 3×3 neighbourhood sees one kind of thing (no anti-aliasing mix).
      bool all_background = true, all_ground = true;
      for (int dv = -1; dv <= 1; ++dv) {
        for (int du = -1; du <= 1; ++du) {
          const int object = truth.object[i + dv * width + du];
          all_background = all_background && object == kFieldBackground;
          all_ground = all_ground && IsGround(object);
        }
      }
      Ray ray;
      if (camera.BackProject(Eigen::Vector2d(u, v), &ray) != ProjectionStatus::kOk) {
        if (all_background) {
          ++outside;
          dark_outside += image[i] == 0;  // beyond the rim: background radiance 0
        }
        continue;
      }
      if (!all_ground) continue;
      Eigen::Vector2d p_G;
      if (!IsGround(truth.object[i]) ||
          camera.BackProjectToGround(Eigen::Vector2d(u, v), &p_G) != ProjectionStatus::kOk) {
        continue;
      }
      // Pixel footprint on the ground: from the ground map's Jacobian.
      Eigen::Matrix2d J;
      camera.BackProjectToGround(Eigen::Vector2d(u, v), &p_G, &J);
      const double footprint = J.colwise().norm().maxCoeff();
      const FieldPoint field = scene.ClassifyGround(p_G);
      const double margin = std::abs(field.line_distance - 0.5 * p.line_width);
      if (margin < 1.5 * footprint) continue;  // a border pixel: mixed by anti-aliasing
      ++checked;
      line_pixels += field.on_line;
      wrong += field.on_line != (image[i] > threshold);
    }
  }
  std::printf("rendered: %d pixels checked, %d on lines, %d wrong; %d of %d beyond the rim dark\n",
              checked, line_pixels, wrong, dark_outside, outside);
  EXPECT_GT(checked, 100000);
  EXPECT_GT(line_pixels, 300);
  EXPECT_EQ(wrong, 0);
  EXPECT_EQ(dark_outside, outside);
}

TEST(SoccerFieldScene, CentreCircleAppearsAroundARobotAtTheCentre) {
  const HyperbolicMirrorCamera camera = SeedCamera();
  SoccerFieldSceneParameters p;
  p.robot_heading = 0.3;
  const SoccerFieldScene scene(camera, p);
  const Eigen::Isometry3d X_GF = scene.X_FG().inverse();
  int on_circle = 0, occluded = 0, off_circle_carpet = 0, off_checked = 0;
  Eigen::Vector2d first_pixel = Eigen::Vector2d::Zero(), opposite_pixel = first_pixel;
  for (int k = 0; k < 720; ++k) {
    const double a = 2.0 * M_PI * k / 720;
    const Eigen::Vector2d dir(std::cos(a), std::sin(a));
    for (double radius :
         {p.centre_circle_radius, p.centre_circle_radius + 0.1, p.centre_circle_radius - 0.06}) {
      const Eigen::Vector3d p_G = X_GF * Eigen::Vector3d(radius * dir.x(), radius * dir.y(), 0);
      Eigen::Vector2d pixel;
      ASSERT_EQ(camera.ProjectGroundPoint(p_G.head<2>(), &pixel), ProjectionStatus::kOk);
      ASSERT_TRUE(camera.InImage(pixel));
      Ray ray;
      ASSERT_EQ(camera.BackProject(pixel, &ray), ProjectionStatus::kOk);
      const Hit hit = scene.Trace(ray);
      if (radius == p.centre_circle_radius) {
        if (k == 0) first_pixel = pixel;
        if (k == 360) opposite_pixel = pixel;
        if (hit.object == kFieldLine) {
          ++on_circle;
        } else {
          EXPECT_EQ(hit.object, kFieldMirrorPost) << "angle " << a;
          ++occluded;
        }
      } else if (std::abs(dir.x()) > 0.2 && hit.object != kFieldMirrorPost) {
        // Off the circle and away from the halfway line (x_F = 0): carpet.
        ++off_checked;
        if (hit.object == kFieldCarpet) ++off_circle_carpet;
      }
    }
  }
  std::printf("centre circle: %d of 720 samples white, %d behind posts\n", on_circle, occluded);
  EXPECT_GT(on_circle, 650);
  EXPECT_EQ(off_circle_carpet, off_checked);
  EXPECT_GT(off_checked, 800);
  // A ring around the image centre: opposite points of the circle lie on opposite sides of it.
  const Eigen::Vector2d centre(camera.parameters().cx, camera.parameters().cy);
  EXPECT_LT((first_pixel - centre).dot(opposite_pixel - centre), 0.0);
}

TEST(SoccerFieldScene, PostsHideThePartOfTheMirrorBehindThem) {
  const HyperbolicMirrorCamera camera = SeedCamera();
  SoccerFieldSceneParameters p;
  const SoccerFieldScene scene(camera, p);
  int hidden = 0;
  for (int i = 0; i < p.post_count; ++i) {
    Eigen::Vector3d bottom, top;
    scene.PostAxis(i, &bottom, &top);
    // A point on the post's axis just below the mirror, seen directly.
    const Eigen::Vector3d on_post = top - Eigen::Vector3d(0.0, 0.002, 0.0);
    Eigen::Vector2d pixel;
    ASSERT_EQ(camera.ProjectDirect(on_post, &pixel), ProjectionStatus::kOk);
    Ray ray;
    ASSERT_EQ(camera.BackProject(pixel, &ray), ProjectionStatus::kOk);
    const Hit hit = scene.Trace(ray);
    EXPECT_EQ(hit.object, kFieldMirrorPost);
    EXPECT_EQ(hit.depth, 0.0);
    hidden += hit.object == kFieldMirrorPost;
    // 20° of azimuth away the mirror is seen.
    const Eigen::Vector3d axis(camera.parameters().mirror_axis_x, 0.0,
                               camera.parameters().mirror_axis_z);
    const Eigen::Vector3d away =
        axis + Eigen::AngleAxisd(0.35, Eigen::Vector3d::UnitY()) * (on_post - axis);
    ASSERT_EQ(camera.ProjectDirect(away, &pixel), ProjectionStatus::kOk);
    ASSERT_EQ(camera.BackProject(pixel, &ray), ProjectionStatus::kOk);
    EXPECT_NE(scene.Trace(ray).object, kFieldMirrorPost);
  }
  EXPECT_EQ(hidden, 3);
}

TEST(SoccerFieldScene, RobotHidesTheGroundNearItAndTheImageCentreSeesTheLens) {
  const HyperbolicMirrorCamera camera = SeedCamera();
  SoccerFieldSceneParameters p;
  p.robot_x = -3.0;
  const SoccerFieldScene scene(camera, p);
  Ray ray;
  // The image centre looks at the apex, which reflects the camera itself.
  ASSERT_EQ(
      camera.BackProject(Eigen::Vector2d(camera.parameters().cx, camera.parameters().cy), &ray),
      ProjectionStatus::kOk);
  EXPECT_EQ(scene.Trace(ray).object, kFieldLensBody);
  // Ground points inside the body's footprint project into the image but are hidden by the body
  // (or the lens), and a point at 0.3 m is hidden by the body's top edge.
  for (double r : {0.1, 0.2, 0.3}) {
    Eigen::Vector2d pixel;
    ASSERT_EQ(camera.ProjectGroundPoint(Eigen::Vector2d(r, 0.05), &pixel), ProjectionStatus::kOk);
    ASSERT_EQ(camera.BackProject(pixel, &ray), ProjectionStatus::kOk);
    const int object = scene.Trace(ray).object;
    EXPECT_TRUE(object == kFieldRobotBody || object == kFieldLensBody) << r << ": " << object;
  }
  // ... and at 0.6 m the carpet is seen.
  Eigen::Vector2d pixel;
  ASSERT_EQ(camera.ProjectGroundPoint(Eigen::Vector2d(0.6, 0.05), &pixel), ProjectionStatus::kOk);
  ASSERT_EQ(camera.BackProject(pixel, &ray), ProjectionStatus::kOk);
  EXPECT_EQ(scene.Trace(ray).object, kFieldCarpet);
  // Pixels beyond the mirror rim are not back-projected: the renderer's background (dark).
  EXPECT_NE(camera.BackProject(Eigen::Vector2d(2, 2), &ray), ProjectionStatus::kOk);
  EXPECT_LT(SoccerFieldScene::kBackgroundRadiance, 0.05);
}

TEST(SoccerFieldScene, LineDistanceOfKnownPoints) {
  const HyperbolicMirrorCamera camera = SeedCamera();
  const SoccerFieldScene scene(camera, SoccerFieldSceneParameters{});
  EXPECT_NEAR(scene.LineDistance(Eigen::Vector2d(0.0, 0.0)), 0.0, 1e-12);   // halfway line
  EXPECT_NEAR(scene.LineDistance(Eigen::Vector2d(0.3, 0.0)), 0.2, 1e-12);   // circle at 0.5
  EXPECT_NEAR(scene.LineDistance(Eigen::Vector2d(3.0, 5.0)), 1.0, 1e-12);   // side line y = 6
  EXPECT_NEAR(scene.LineDistance(Eigen::Vector2d(8.0, 1.0)), 0.25, 1e-12);  // goal area front
  EXPECT_NEAR(scene.LineDistance(Eigen::Vector2d(6.9, 2.0)), 0.15, 1e-12);  // penalty area front
  EXPECT_NEAR(scene.LineDistance(Eigen::Vector2d(8.5, 3.4)), 0.15, 1e-12);  // penalty side y=3.25
}

TEST(SoccerFieldScene, BadParametersAreNamedInOneMessage) {
  const HyperbolicMirrorCamera camera = SeedCamera();
  SoccerFieldSceneParameters p;
  p.line_width = -0.05;
  p.post_count = 12;
  p.carpet_radiance = 2.0;
  EXPECT_THAT(p.Validate(),
              ::testing::MatchesRegex(
                  ".*line_width: must be > 0, got -0.05.*post_count: must be .*, got 12.*"
                  "carpet_radiance: must be .*, got 2"));
  EXPECT_THROW(SoccerFieldScene(camera, p), std::invalid_argument);
  SoccerFieldSceneParameters tall;
  tall.body_height = 0.7;  // above the pinhole (0.57 m)
  EXPECT_THROW(SoccerFieldScene(camera, tall), std::invalid_argument);
}

// TraceBatch (the trace inlined into a loop) gives exactly Trace()'s hits for every pixel ray of
// the mirror camera (a non-central model: one origin per ray).
TEST(SoccerFieldScene, TraceBatchEqualsTrace) {
  const HyperbolicMirrorCamera camera = SeedCamera();
  SoccerFieldSceneParameters p;
  p.robot_x = 6.2;
  p.robot_y = 4.9;
  p.robot_heading = 0.4;
  const SoccerFieldScene scene(camera, p);
  std::vector<Eigen::Vector3d> origins, directions;
  for (int v = 0; v < camera.height(); ++v) {
    for (int u = 0; u < camera.width(); ++u) {
      Ray ray;
      if (camera.BackProject(Eigen::Vector2d(u, v), &ray) != ProjectionStatus::kOk) continue;
      origins.push_back(ray.p_C_O);
      directions.push_back(ray.d_C);
    }
  }
  std::vector<Hit> hits(directions.size());
  RayBatch batch;
  batch.origins = origins.data();
  batch.directions = directions.data();
  batch.count = static_cast<int>(directions.size());
  scene.TraceBatch(batch, hits.data());
  int different = 0;
  std::set<int> objects;
  for (size_t k = 0; k < directions.size(); ++k) {
    Ray ray;
    ray.p_C_O = origins[k];
    ray.d_C = directions[k];
    const Hit one = scene.Trace(ray);
    objects.insert(one.object);
    if (one.object != hits[k].object || one.radiance != hits[k].radiance ||
        !(one.depth == hits[k].depth)) {
      ++different;
    }
  }
  EXPECT_GT(directions.size(), 100000u);
  EXPECT_EQ(different, 0);
  EXPECT_GE(objects.size(), 6u);
}

// The camera-fixed part (renderer.h): the robot rides with the camera and moves in the ground
// plane. For every ray, TraceCameraFixed() and ShadeSurface() give exactly Trace()'s hit: the robot
// (and the surroundings) as constants, the ground as a point of G shaded for the pose; the key
// follows the robot's geometry and radiances, not its pose.
TEST(SoccerFieldScene, CameraFixedAnswersGiveExactlyTraceForEveryPose) {
  const HyperbolicMirrorCamera camera = SeedCamera();
  std::vector<Eigen::Vector3d> origins, directions;
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-0.5, camera.width() - 0.5);
  std::uniform_real_distribution<double> v(-0.5, camera.height() - 0.5);
  while (directions.size() < 100000) {
    Ray ray;
    if (camera.BackProject(Eigen::Vector2d(u(rng), v(rng)), &ray) != ProjectionStatus::kOk) {
      continue;
    }
    origins.push_back(ray.p_C_O);
    directions.push_back(ray.d_C);
  }
  RayBatch batch;
  batch.origins = origins.data();
  batch.directions = directions.data();
  batch.count = static_cast<int>(directions.size());
  SoccerFieldSceneParameters p;
  p.robot_x = 6.2;
  p.robot_y = 4.9;
  p.robot_heading = 0.4;
  std::vector<CameraFixedHit> fixed(directions.size());
  SoccerFieldScene(camera, p).TraceCameraFixed(batch, fixed.data());
  // The answers of one pose, used for others (as the renderer does).
  for (const auto& [x, y, heading] :
       {std::array<double, 3>{6.2, 4.9, 0.4}, {-3.0, 0.2, 2.0}, {0.1, -0.3, -2.5}}) {
    SoccerFieldSceneParameters pose = p;
    pose.robot_x = x;
    pose.robot_y = y;
    pose.robot_heading = heading;
    const SoccerFieldScene scene(camera, pose);
    int different = 0, robot = 0, robot_on_surface = 0, surface = 0;
    std::set<int> shaded_objects;
    for (size_t k = 0; k < directions.size(); ++k) {
      Ray ray;
      ray.p_C_O = origins[k];
      ray.d_C = directions[k];
      const Hit one = scene.Trace(ray);
      Hit answer = fixed[k].hit;
      if (fixed[k].kind == CameraFixedHit::kSurface) {
        ++surface;
        scene.ShadeSurface(&fixed[k].surface, 1, &answer);
        shaded_objects.insert(answer.object);
      } else {
        EXPECT_EQ(fixed[k].kind, CameraFixedHit::kConstant);
      }
      const bool own = one.object == kFieldRobotBody || one.object == kFieldLensBody ||
                       one.object == kFieldMirrorPost;
      robot += own ? 1 : 0;
      robot_on_surface += own && fixed[k].kind == CameraFixedHit::kSurface ? 1 : 0;
      if (one.object != answer.object || one.radiance != answer.radiance ||
          !(one.depth == answer.depth)) {
        ++different;
      }
    }
    EXPECT_EQ(different, 0) << x << " " << y;
    EXPECT_EQ(robot_on_surface, 0);
    EXPECT_GT(robot, 1000);
    EXPECT_GT(surface, 50000);  // most of the view is the ground
    EXPECT_GE(shaded_objects.size(), 2u);
  }

  const SoccerFieldScene scene(camera, p);
  EXPECT_NE(scene.CameraFixedKey(), 0u);
  SoccerFieldSceneParameters moved = p;
  moved.robot_x = -3.0;
  moved.robot_heading = 2.0;
  moved.line_radiance = 0.95;  // the field is not camera-fixed
  EXPECT_EQ(SoccerFieldScene(camera, moved).CameraFixedKey(), scene.CameraFixedKey());
  SoccerFieldSceneParameters wider = p;
  wider.body_radius = 0.23;
  EXPECT_NE(SoccerFieldScene(camera, wider).CameraFixedKey(), scene.CameraFixedKey());
  SoccerFieldSceneParameters darker = p;
  darker.body_radiance = 0.02;  // a constant answer
  EXPECT_NE(SoccerFieldScene(camera, darker).CameraFixedKey(), scene.CameraFixedKey());
  HyperbolicMirrorParameters mp = HyperbolicMirrorParameters::Seed000Lens4mm();
  mp.ground_rho = 0.02;
  EXPECT_NE(SoccerFieldScene(HyperbolicMirrorCamera(mp), p).CameraFixedKey(),
            scene.CameraFixedKey());
}

// Rendered through its camera-fixed part (the robot's pixels kept, the ground shaded at surface
// points interpolated between pixel centres) the frame is the ray-traced one: the same ground
// truth, and the same bytes but where a sample lies within the verified interpolation error of an
// edge (measured: 8-21 pixels of ~17 k edge pixels per pose). Nothing is traced per frame.
TEST(SoccerFieldScene, RenderedThroughItsCameraFixedPartMatchesTheRayTracedFrame) {
  const HyperbolicMirrorCamera camera = SeedCamera();
  Renderer renderer(camera, RenderOptions{});
  const int n = camera.width() * camera.height();
  std::vector<uint8_t> fast(n), traced(n);
  const ImageView8 fast_view{fast.data(), camera.width(), camera.height(),
                             static_cast<size_t>(camera.width())};
  const ImageView8 traced_view{traced.data(), camera.width(), camera.height(),
                               static_cast<size_t>(camera.width())};
  class TraceOnly final : public Scene {
   public:
    explicit TraceOnly(const Scene& inner) : inner_(inner) {}
    Hit Trace(const Ray& ray) const override { return inner_.Trace(ray); }
    void TraceBatch(const RayBatch& rays, Hit* hits) const override {
      inner_.TraceBatch(rays, hits);
    }

   private:
    const Scene& inner_;
  };
  class Counting final : public Scene {
   public:
    explicit Counting(const SoccerFieldScene& inner) : inner_(inner) {}
    Hit Trace(const Ray& ray) const override {
      ++traced_;
      return inner_.Trace(ray);
    }
    void TraceBatch(const RayBatch& rays, Hit* hits) const override {
      traced_ += rays.count;
      inner_.TraceBatch(rays, hits);
    }
    uint64_t CameraFixedKey() const override { return inner_.CameraFixedKey(); }
    void TraceCameraFixed(const RayBatch& rays, CameraFixedHit* out) const override {
      inner_.TraceCameraFixed(rays, out);
    }
    void ShadeSurface(const Eigen::Vector2d* points, int count, Hit* hits) const override {
      inner_.ShadeSurface(points, count, hits);
    }
    mutable long traced_ = 0;

   private:
    const SoccerFieldScene& inner_;
  };
  for (const auto& [x, y, heading] :
       {std::array<double, 3>{1.2, -0.7, 0.4}, {-7.6, 5.1, 2.2}, {3.0, 0.0, -1.0}}) {
    SoccerFieldSceneParameters p;
    p.robot_x = x;
    p.robot_y = y;
    p.robot_heading = heading;
    const SoccerFieldScene scene(camera, p);
    const Counting counting(scene);
    GroundTruth fast_truth, traced_truth;
    renderer.Render(counting, 5, fast_view, &fast_truth);
    EXPECT_EQ(counting.traced_, 0);
    const int edges = renderer.last_edge_pixels();
    renderer.Render(TraceOnly(scene), 5, traced_view, &traced_truth);
    EXPECT_EQ(renderer.last_edge_pixels(), edges);
    EXPECT_EQ(fast_truth.object, traced_truth.object);
    EXPECT_EQ(fast_truth.depth, traced_truth.depth);
    int different = 0;
    for (int i = 0; i < n; ++i) different += fast[i] != traced[i];
    EXPECT_GT(edges, 10000);
    EXPECT_LE(different, edges / 200) << x << " " << y;
  }
  const Renderer::CameraFixedStatistics& stats = renderer.camera_fixed_statistics();
  EXPECT_EQ(stats.centres_traced, 0);
  EXPECT_EQ(stats.pixels_traced, 0);
  EXPECT_GT(stats.pixels_interpolated, 150000);
  EXPECT_LT(stats.pixels_kept, 20000);
  EXPECT_LE(stats.max_surface_error_px, Renderer::kMaxRayInterpolationErrorPx);
}

}  // namespace
}  // namespace kinevis::vision::render
