#include "vision/render/renderer.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <random>
#include <vector>

#include "tests/utilities/allocation_counter.h"
#include "vision/camera/pinhole_camera.h"

namespace kinevis::vision::render {
namespace {

using ::testing::ContainsRegex;
using ::testing::HasSubstr;
using ::testing::MatchesRegex;

constexpr double kInf = std::numeric_limits<double>::infinity();

// A uniform scene.
class FlatScene final : public Scene {
 public:
  explicit FlatScene(double radiance) : radiance_(radiance) {}
  Hit Trace(const Ray&) const override { return Hit{radiance_, 0, kInf}; }

 private:
  double radiance_;
};

// Object 1 (radiance hi, at depth 2) wherever n · d > 0, background (lo) elsewhere: for a central
// camera at the origin the edge is the image of the plane n · X = 0 — a straight line for a
// pinhole camera without distortion.
class HalfSpaceScene final : public Scene {
 public:
  HalfSpaceScene(const Eigen::Vector3d& n, double lo, double hi) : n_(n), lo_(lo), hi_(hi) {}
  Hit Trace(const Ray& ray) const override {
    return n_.dot(ray.d_C) > 0.0 ? Hit{hi_, 1, 2.0} : Hit{lo_, 0, kInf};
  }

 private:
  Eigen::Vector3d n_;
  double lo_, hi_;
};

// A scene's Trace() alone: the default TraceBatch, no camera-fixed part. The reference frame.
class TraceOnly final : public Scene {
 public:
  explicit TraceOnly(const Scene& inner) : inner_(inner) {}
  Hit Trace(const Ray& ray) const override { return inner_.Trace(ray); }

 private:
  const Scene& inner_;
};

// An ideal pinhole (f = 200 px, 160×120) whose model domain ends at u = max_u: pixels beyond it
// have no ray (kOutsideDomain), so the renderer must treat them as black background.
class ClippedPinhole final : public CameraModel {
 public:
  explicit ClippedPinhole(double max_u) : max_u_(max_u) {}
  std::string_view Name() const override { return "clipped-pinhole"; }
  int width() const override { return 160; }
  int height() const override { return 120; }
  bool IsCentral() const override { return true; }
  ProjectionStatus Project(const Eigen::Vector3d& p, Eigen::Vector2d* pixel,
                           Matrix23d* = nullptr) const override {
    if (p.z() <= 0.0) return ProjectionStatus::kBehindCamera;
    *pixel = Eigen::Vector2d(200.0 * p.x() / p.z() + 79.5, 200.0 * p.y() / p.z() + 59.5);
    return pixel->x() > max_u_ ? ProjectionStatus::kOutsideDomain : ProjectionStatus::kOk;
  }
  ProjectionStatus BackProject(const Eigen::Vector2d& pixel, Ray* ray,
                               RayJacobian* = nullptr) const override {
    if (pixel.x() > max_u_) return ProjectionStatus::kOutsideDomain;
    ray->p_C_O.setZero();
    ray->d_C =
        Eigen::Vector3d((pixel.x() - 79.5) / 200.0, (pixel.y() - 59.5) / 200.0, 1.0).normalized();
    return ProjectionStatus::kOk;
  }
  std::string Validate() const override { return ""; }

 private:
  double max_u_;
};

// A non-central camera (160×120) whose rays exist only inside an off-centre ellipse of pixels,
// with origins that move with the pixel: its cells next to the ellipse fail the interpolation
// check, so the renderer must use its exact sub-sample rays there (cached by the constructor for
// interior pixels, back-projected per frame on the image border).
class EllipseCamera final : public CameraModel {
 public:
  std::string_view Name() const override { return "ellipse"; }
  int width() const override { return 160; }
  int height() const override { return 120; }
  bool IsCentral() const override { return false; }
  static bool Inside(const Eigen::Vector2d& pixel) {
    const double x = (pixel.x() - 70.3) / 75.0, y = (pixel.y() - 70.1) / 52.0;
    return x * x + y * y <= 1.0;
  }
  ProjectionStatus Project(const Eigen::Vector3d&, Eigen::Vector2d*,
                           Matrix23d* = nullptr) const override {
    return ProjectionStatus::kOutsideDomain;  // never verified: no cell is interpolated
  }
  ProjectionStatus BackProject(const Eigen::Vector2d& pixel, Ray* ray,
                               RayJacobian* = nullptr) const override {
    if (!Inside(pixel)) return ProjectionStatus::kOutsideDomain;
    ray->p_C_O = Eigen::Vector3d(1e-4 * pixel.x(), 2e-4 * pixel.y(), 0.0);
    ray->d_C = Eigen::Vector3d(0.0, 0.0, 1.0);
    return ProjectionStatus::kOk;
  }
  std::string Validate() const override { return ""; }
};

PinholeBrownCamera Pinhole(int width, int height, double f) {
  PinholeBrownParameters p;
  p.width = width;
  p.height = height;
  p.fx = p.fy = f;
  p.cx = 0.5 * (width - 1) + 0.3;
  p.cy = 0.5 * (height - 1) - 0.2;
  return PinholeBrownCamera(p);
}

struct Frame {
  std::vector<uint8_t> pixels;
  ImageView8 view;
};

Frame MakeFrame(const CameraModel& camera) {
  Frame f;
  f.pixels.assign(static_cast<size_t>(camera.width()) * camera.height(), 0);
  f.view = ImageView8{f.pixels.data(), camera.width(), camera.height(),
                      static_cast<size_t>(camera.width())};
  return f;
}

TEST(RenderOptionsTest, DefaultsAreValid) { EXPECT_EQ(RenderOptions{}.Validate(), ""); }

TEST(RenderOptionsTest, ValidateNamesEveryBadFieldAndValue) {
  RenderOptions o;
  o.supersampling = 0;
  o.edge_radiance_step = -1.0;
  o.blur_sigma_px = std::nan("");
  o.vignetting = 1.5;
  o.exposure = 0.0;
  o.noise_sigma = -2.0;
  const std::string message = o.Validate();
  EXPECT_THAT(message, ContainsRegex("supersampling: [^;]*, got 0"));
  EXPECT_THAT(message, ContainsRegex("edge_radiance_step: [^;]*, got -1"));
  EXPECT_THAT(message, ContainsRegex("blur_sigma_px: [^;]*, got nan"));
  EXPECT_THAT(message, ContainsRegex("vignetting: [^;]*, got 1.5"));
  EXPECT_THAT(message, ContainsRegex("exposure: [^;]*, got 0"));
  EXPECT_THAT(message, ContainsRegex("noise_sigma: [^;]*, got -2"));
  const ClippedPinhole camera(1e9);
  try {
    Renderer renderer(camera, o);
    FAIL() << "no exception";
  } catch (const std::invalid_argument& e) {
    EXPECT_EQ(std::string(e.what()), message);
  }
}

TEST(RendererTest, ExposureAndQuantisation) {
  const ClippedPinhole camera(1e9);
  Frame f = MakeFrame(camera);
  RenderOptions o;
  o.exposure = 1.5;
  Renderer(camera, o).Render(FlatScene(0.4), 0, f.view);
  for (const uint8_t p : f.pixels) ASSERT_EQ(p, 153);  // 0.4 · 1.5 · 255 = 153
  o.exposure = 3.0;
  Renderer(camera, o).Render(FlatScene(0.4), 0, f.view);
  for (const uint8_t p : f.pixels) ASSERT_EQ(p, 255);  // clamped
}

TEST(RendererTest, VignettingFallsOffQuadraticallyToTheCorner) {
  const ClippedPinhole camera(1e9);
  Frame f = MakeFrame(camera);
  RenderOptions o;
  o.vignetting = 0.5;
  Renderer(camera, o).Render(FlatScene(0.8), 0, f.view);
  const int w = camera.width(), h = camera.height();
  EXPECT_EQ(f.pixels[0], 102);  // corner: 204 · (1 − 0.5)
  EXPECT_EQ(f.pixels[static_cast<size_t>(h - 1) * w + w - 1], 102);
  EXPECT_NEAR(f.pixels[static_cast<size_t>(h / 2) * w + w / 2], 204, 1);  // centre
  // Half-way to the corner along the diagonal: 1 − 0.5 · 0.25.
  const int u = static_cast<int>(std::lround(0.25 * (w - 1))),
            v = static_cast<int>(std::lround(0.25 * (h - 1)));
  const double r2 = (std::pow(u - 0.5 * (w - 1), 2) + std::pow(v - 0.5 * (h - 1), 2)) /
                    (std::pow(0.5 * (w - 1), 2) + std::pow(0.5 * (h - 1), 2));
  EXPECT_NEAR(f.pixels[static_cast<size_t>(v) * w + u], 204 * (1 - 0.5 * r2), 1.0);
}

TEST(RendererTest, SameInputsGiveIdenticalBytesAndSeedOrFrameChangeTheNoise) {
  const PinholeBrownCamera camera = Pinhole(200, 150, 180.0);
  const HalfSpaceScene scene(Eigen::Vector3d(1.0, 0.3, -0.1).normalized(), 0.2, 0.7);
  RenderOptions o;
  o.noise_sigma = 3.0;
  o.blur_sigma_px = 0.8;
  o.vignetting = 0.1;
  o.seed = 42;
  Frame a = MakeFrame(camera), b = MakeFrame(camera), c = MakeFrame(camera), d = MakeFrame(camera);
  Renderer(camera, o).Render(scene, 7, a.view);
  Renderer(camera, o).Render(scene, 7, b.view);
  EXPECT_EQ(a.pixels, b.pixels);
  Renderer reused(camera, o);
  reused.Render(scene, 3, c.view);
  reused.Render(scene, 7, c.view);  // a renderer's history does not matter
  EXPECT_EQ(a.pixels, c.pixels);
  reused.Render(scene, 8, d.view);
  EXPECT_NE(a.pixels, d.pixels);
  o.seed = 43;
  Renderer(camera, o).Render(scene, 7, d.view);
  EXPECT_NE(a.pixels, d.pixels);
  // The difference is noise-sized, not a different picture.
  double sum2 = 0.0;
  for (size_t i = 0; i < a.pixels.size(); ++i) {
    sum2 += std::pow(static_cast<double>(a.pixels[i]) - d.pixels[i], 2);
  }
  EXPECT_NEAR(std::sqrt(sum2 / a.pixels.size()), 3.0 * std::sqrt(2.0), 0.5);
}

TEST(RendererTest, NoiseSigmaOnAFlatRegionMatchesTheOption) {
  const PinholeBrownCamera camera = Pinhole(321, 241, 300.0);  // odd sizes on purpose
  Frame f = MakeFrame(camera);
  for (const double sigma : {2.0, 5.0, 12.0}) {
    RenderOptions o;
    o.noise_sigma = sigma;
    o.seed = 11;
    Renderer(camera, o).Render(FlatScene(0.5), 0, f.view);
    double sum = 0.0, sum2 = 0.0;
    for (const uint8_t p : f.pixels) {
      sum += p;
      sum2 += static_cast<double>(p) * p;
    }
    const double n = static_cast<double>(f.pixels.size());
    const double mean = sum / n;
    const double measured = std::sqrt(sum2 / n - mean * mean);
    // Rounding to integers adds 1/12 grey level² of variance.
    const double expected = std::sqrt(sigma * sigma + 1.0 / 12.0);
    EXPECT_NEAR(mean, 127.5, 0.2) << sigma;
    EXPECT_NEAR(measured, expected, 0.1 * sigma) << sigma;
    EXPECT_NEAR(measured, expected, 0.02 * sigma) << sigma;  // in fact much closer
    // Independent pixels: a row's last pixel and the next row's first do not repeat each other,
    // nor do horizontal neighbours (equal by chance with probability ≈ 1/(2√π σ)).
    int same_wrap = 0, same_next = 0;
    for (int v = 0; v + 1 < 241; ++v) {
      same_wrap += f.pixels[v * 321 + 320] == f.pixels[(v + 1) * 321];
      same_next += f.pixels[v * 321 + 100] == f.pixels[v * 321 + 101];
    }
    EXPECT_LT(same_wrap, 240 * (0.1 + 0.3 / sigma)) << sigma;
    EXPECT_LT(same_next, 240 * (0.1 + 0.3 / sigma)) << sigma;
  }
}

// The sub-pixel position of a straight edge along row v from the anti-aliased coverage: the
// strip of row v between pixel columns [first, last] (background at first, object at last, or
// the reverse) holds Σ f_k pixels of object, f_k = (I_k − lo)/(hi − lo); exact for a straight
// edge that stays inside the window over the row's height, for a box filter.
double EdgeAlongRow(const std::vector<uint8_t>& image, int width, int v, int first, int last,
                    double lo, double hi, bool object_on_right) {
  double covered = 0.0;
  for (int u = first; u <= last; ++u) {
    covered += (image[static_cast<size_t>(v) * width + u] - lo) / (hi - lo);
  }
  return object_on_right ? last + 0.5 - covered : first - 0.5 + covered;
}

TEST(RendererTest, StraightEdgeLiesWhereTheModelSaysToTheAntiAliasingBound) {
  const PinholeBrownCamera camera = Pinhole(320, 240, 250.0);
  const auto& k = camera.parameters();
  Frame f = MakeFrame(camera);
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> tilt(-0.6, 0.6);
  // The grey levels of the two sides as rendered (0.1 · 255 and 0.9 · 255, rounded).
  const double kLo = std::round(0.1 * 255), kHi = std::round(0.9 * 255);
  for (const int s : {1, 2, 4, 8}) {
    double max_error = 0.0;
    for (int trial = 0; trial < 4; ++trial) {
      // A near-vertical edge through the image (|du/dv| < 0.6 keeps it inside a ±3 px window).
      const double slope = tilt(rng), u_mid = 120.0 + 20.0 * trial + 0.37 * trial;
      // Image line u = u_mid + slope (v − cy) ⇔ x = (u_mid − cx)/f + slope y in normalised
      // coordinates ⇒ plane normal (1, −slope, −(u_mid − cx)/f).
      const Eigen::Vector3d n(1.0, -slope, -(u_mid - k.cx) / k.fx);
      RenderOptions o;
      o.supersampling = s;
      Renderer renderer(camera, o);
      renderer.Render(HalfSpaceScene(n.normalized(), 0.1, 0.9), 0, f.view);
      EXPECT_GT(renderer.last_edge_pixels(), 0);
      for (int v = 5; v < camera.height() - 5; ++v) {
        const double u_true = u_mid + slope * (v - k.cy);
        const int c = static_cast<int>(std::floor(u_true));
        const double u_measured =
            EdgeAlongRow(f.pixels, camera.width(), v, c - 3, c + 4, kLo, kHi, true);
        max_error = std::max(max_error, std::abs(u_measured - u_true));
      }
    }
    // Anti-aliasing bound 1/(2s) px, plus 8-bit quantisation: ±0.5 grey level in each of the (at
    // most 3) partly covered window pixels over a contrast of 204 levels, < 0.01 px.
    EXPECT_LT(max_error, 0.5 / s + 0.01) << "s = " << s;
    if (s == 1) {
      EXPECT_GT(max_error, 0.2);  // without supersampling the edge is aliased
    }
    RecordProperty("max_edge_error_px_s" + std::to_string(s), std::to_string(max_error));
    std::printf("straight edge, s = %d: max error %.4f px (bound %.4f)\n", s, max_error,
                0.5 / s + 0.01);
  }
}

TEST(RendererTest, SubsampleRayInterpolationIsVerifiedAndTiny) {
  const PinholeBrownCamera camera = Pinhole(320, 240, 250.0);
  const Renderer renderer(camera, RenderOptions{});
  EXPECT_EQ(renderer.interpolated_cell_fraction(), 1.0);
  EXPECT_LT(renderer.max_ray_interpolation_error_px(), 1e-3);
  // Cells touching the model's domain boundary are not interpolated.
  const ClippedPinhole clipped(100.2);
  const Renderer clipped_renderer(clipped, RenderOptions{});
  EXPECT_NEAR(clipped_renderer.interpolated_cell_fraction(), 100.0 / 159.0, 1e-9);
}

TEST(RendererTest, PixelsWithoutARayAreBlackBackgroundAndTheDomainEdgeIsAntiAliased) {
  // Domain ends at u = 100.2: pixel 100 has 0.7 of its area in the domain (u ∈ [99.5, 100.2]).
  const ClippedPinhole camera(100.2);
  Frame f = MakeFrame(camera);
  GroundTruth truth;
  RenderOptions o;
  o.supersampling = 10;
  Renderer renderer(camera, o);
  renderer.Render(FlatScene(1.0), 0, f.view, &truth);
  const int w = camera.width();
  for (int v = 0; v < camera.height(); ++v) {
    EXPECT_EQ(f.pixels[static_cast<size_t>(v) * w + 99], 255);
    EXPECT_EQ(f.pixels[static_cast<size_t>(v) * w + 100], 179);  // 0.7 · 255 = 178.5
    EXPECT_EQ(f.pixels[static_cast<size_t>(v) * w + 101], 0);
    EXPECT_EQ(truth.object[static_cast<size_t>(v) * w + 101], 0);
    EXPECT_TRUE(std::isinf(truth.depth[static_cast<size_t>(v) * w + 101]));
  }
}

// Radiance 0.25 + 0.5 x, x ∈ [0, 1) the sub-pixel column of the ray (EllipseCamera's origin
// encodes the pixel), object 1: uniform at pixel centres, a ramp across every pixel.
class SubpixelRampScene final : public Scene {
 public:
  Hit Trace(const Ray& ray) const override {
    const double pu = 1e4 * ray.p_C_O.x();
    return Hit{0.25 + 0.5 * (pu - std::round(pu) + 0.5), 1, 1.0};
  }
};

TEST(RendererTest, ExactSubsampleRaysOfANonCentralCameraGiveTheBoxFilterAlongItsDomainEdge) {
  // Every pixel along the domain's edge must be the mean of the scene over its s×s sub-samples
  // (0 where there is no ray), whether on the image border (back-projected per frame) or inside
  // (rays cached by the constructor); the scene varies across the pixel, so a sample taken at the
  // wrong place shows.
  const EllipseCamera camera;
  RenderOptions o;
  o.supersampling = 5;
  Renderer renderer(camera, o);
  EXPECT_EQ(renderer.interpolated_cell_fraction(), 0.0);
  Frame f = MakeFrame(camera);
  const SubpixelRampScene scene;
  renderer.Render(scene, 0, f.view);
  const long before = kinevis::testing::ThreadAllocations();
  renderer.Render(scene, 1, f.view);
  EXPECT_EQ(kinevis::testing::ThreadAllocations() - before, 0);
  const int s = o.supersampling;
  int partial = 0, partial_border = 0, wrong = 0;
  for (int v = 0; v < camera.height(); ++v) {
    for (int u = 0; u < camera.width(); ++u) {
      int inside = 0;
      double sum = 0.0;
      for (int b = 0; b < s; ++b) {
        for (int a = 0; a < s; ++a) {
          const double du = (a + 0.5) / s - 0.5, dv = (b + 0.5) / s - 0.5;
          if (!EllipseCamera::Inside(Eigen::Vector2d(u + du, v + dv))) continue;
          ++inside;
          sum += 0.25 + 0.5 * (du + 0.5);
        }
      }
      // Only pixels whose 3×3 neighbourhood of centres is not uniform are supersampled (where
      // the boundary grazes a pixel between centres it goes unseen, a documented limit).
      const bool centre = EllipseCamera::Inside(Eigen::Vector2d(u, v));
      bool supersampled = false;
      for (int dv = -1; dv <= 1; ++dv) {
        for (int du = -1; du <= 1; ++du) {
          const int uu = u + du, vv = v + dv;
          if (uu < 0 || vv < 0 || uu >= camera.width() || vv >= camera.height()) continue;
          supersampled = supersampled || EllipseCamera::Inside(Eigen::Vector2d(uu, vv)) != centre;
        }
      }
      const double expected = supersampled ? sum / (s * s) : (centre ? 0.5 : 0.0);
      if (supersampled && inside > 0 && inside < s * s) {
        ++partial;
        if (u == 0 || v == 0 || u + 1 == camera.width() || v + 1 == camera.height()) {
          ++partial_border;
        }
      }
      // Within one grey level (the renderer sums the samples in another order).
      wrong +=
          std::abs(f.pixels[static_cast<size_t>(v) * camera.width() + u] - 255.0 * expected) > 1.0;
    }
  }
  EXPECT_EQ(wrong, 0);
  EXPECT_GT(partial, 300);
  EXPECT_GT(partial_border, 5);  // the ellipse leaves the image at the left and bottom
}

TEST(RendererTest, GroundTruthIsTheObjectAndDepthAtPixelCentres) {
  const PinholeBrownCamera camera = Pinhole(160, 120, 150.0);
  const HalfSpaceScene scene(Eigen::Vector3d(1.0, 0.5, 0.2).normalized(), 0.2, 0.6);
  Frame f = MakeFrame(camera);
  GroundTruth truth;
  Renderer renderer(camera, RenderOptions{});
  renderer.Render(scene, 0, f.view, &truth);
  ASSERT_EQ(truth.width, 160);
  ASSERT_EQ(truth.height, 120);
  ASSERT_EQ(truth.object.size(), 160u * 120u);
  int objects = 0;
  for (int v = 0; v < 120; ++v) {
    for (int u = 0; u < 160; ++u) {
      Ray ray;
      ASSERT_EQ(camera.BackProject(Eigen::Vector2d(u, v), &ray), ProjectionStatus::kOk);
      const Hit hit = scene.Trace(ray);
      ASSERT_EQ(truth.object[v * 160 + u], hit.object);
      ASSERT_EQ(truth.depth[v * 160 + u], static_cast<float>(hit.depth));
      objects += hit.object;
    }
  }
  EXPECT_GT(objects, 1000);
  EXPECT_LT(objects, 160 * 120 - 1000);
}

TEST(RendererTest, BlurKeepsFlatRegionsAndSoftensEdges) {
  const PinholeBrownCamera camera = Pinhole(160, 120, 150.0);
  const HalfSpaceScene scene(Eigen::Vector3d(1.0, 0.0, 0.0), 0.2, 0.8);  // edge at u = cx
  Frame sharp = MakeFrame(camera), soft = MakeFrame(camera);
  RenderOptions o;
  Renderer(camera, o).Render(scene, 0, sharp.view);
  o.blur_sigma_px = 2.0;
  Renderer(camera, o).Render(scene, 0, soft.view);
  const int v = 60, cu = static_cast<int>(camera.parameters().cx);
  EXPECT_EQ(soft.pixels[v * 160 + 5], sharp.pixels[v * 160 + 5]);  // far from the edge
  EXPECT_EQ(soft.pixels[v * 160 + 155], sharp.pixels[v * 160 + 155]);
  EXPECT_EQ(sharp.pixels[v * 160 + cu + 3], 204);
  EXPECT_LT(soft.pixels[v * 160 + cu + 3], 200);  // 3 px ≈ 1.5σ from the edge: softened
  // Blur conserves the row's total (edges far from the borders).
  long sum_sharp = 0, sum_soft = 0;
  for (int u = 0; u < 160; ++u) {
    sum_sharp += sharp.pixels[v * 160 + u];
    sum_soft += soft.pixels[v * 160 + u];
  }
  EXPECT_NEAR(sum_soft, sum_sharp, 10);
}

TEST(RendererTest, NoAllocationAfterTheFirstFrame) {
  const PinholeBrownCamera camera = Pinhole(200, 150, 180.0);
  const HalfSpaceScene scene(Eigen::Vector3d(1.0, 0.3, -0.1).normalized(), 0.2, 0.7);
  RenderOptions o;
  o.noise_sigma = 2.0;
  o.blur_sigma_px = 1.0;
  o.vignetting = 0.2;
  Renderer renderer(camera, o);
  Frame f = MakeFrame(camera);
  GroundTruth truth;
  renderer.Render(scene, 0, f.view, &truth);
  const long before = kinevis::testing::ThreadAllocations();
  renderer.Render(scene, 1, f.view, &truth);
  renderer.Render(scene, 2, f.view);
  EXPECT_EQ(kinevis::testing::ThreadAllocations() - before, 0);
}

TEST(RendererTest, EdgePixelsAreOnlyFoundWhereThereIsAnEdge) {
  const PinholeBrownCamera camera = Pinhole(160, 120, 150.0);
  Frame f = MakeFrame(camera);
  Renderer renderer(camera, RenderOptions{});
  renderer.Render(FlatScene(0.3), 0, f.view);
  EXPECT_EQ(renderer.last_edge_pixels(), 0);
  renderer.Render(HalfSpaceScene(Eigen::Vector3d(1.0, 0.0, 0.0), 0.2, 0.8), 0, f.view);
  // A vertical edge: the two columns either side of it, every row.
  EXPECT_EQ(renderer.last_edge_pixels(), 2 * 120);
}

// A scene that traces its batches itself (and differently from Trace(): mirrored pairs of rays in
// reverse order, so that a renderer that mixed up the hits of a batch would show), counting rays
// and checking that no batch holds a ray the camera could not back-project.
class BatchCheckingScene final : public Scene {
 public:
  explicit BatchCheckingScene(const Scene& inner) : inner_(inner) {}
  Hit Trace(const Ray& ray) const override {
    ++single_;
    return inner_.Trace(ray);
  }
  void TraceBatch(const RayBatch& rays, Hit* hits) const override {
    for (int k = rays.count - 1; k >= 0; --k) {
      Ray ray;
      ray.p_C_O = rays.origins[rays.shared_origin ? 0 : k];
      ray.d_C = rays.directions[k];
      if (!(ray.d_C.squaredNorm() > 0.5)) ++invalid_;
      hits[k] = inner_.Trace(ray);
    }
    batched_ += rays.count;
    ++batches_;
  }
  mutable int single_ = 0, invalid_ = 0, batched_ = 0, batches_ = 0;

 private:
  const Scene& inner_;
};

TEST(RendererTest, RendersThroughTraceBatchWithValidRaysOnlyAndTheSameBytes) {
  // A domain that ends mid-row (no ray beyond u = 100.2) and a non-central camera with holes, both
  // with edges to supersample; the batched frame must equal the one through Trace() alone.
  const ClippedPinhole clipped(100.2);
  const EllipseCamera ellipse;
  const HalfSpaceScene half(Eigen::Vector3d(0.3, -1.0, 0.1).normalized(), 0.2, 0.9);
  const SubpixelRampScene ramp;
  struct Case {
    const CameraModel* camera;
    const Scene* scene;
  };
  for (const Case& c : {Case{&clipped, &half}, Case{&ellipse, &ramp}}) {
    RenderOptions o;
    o.supersampling = 4;
    Renderer renderer(*c.camera, o);
    const BatchCheckingScene batching(*c.scene);
    // The reference: a scene with only Trace(), i.e. the default TraceBatch.
    const TraceOnly reference(*c.scene);
    Frame a = MakeFrame(*c.camera), b = MakeFrame(*c.camera);
    GroundTruth truth_a, truth_b;
    renderer.Render(batching, 3, a.view, &truth_a);
    renderer.Render(reference, 3, b.view, &truth_b);
    EXPECT_EQ(a.pixels, b.pixels);
    EXPECT_EQ(truth_a.object, truth_b.object);
    EXPECT_EQ(truth_a.depth, truth_b.depth);
    EXPECT_EQ(batching.single_, 0);
    EXPECT_EQ(batching.invalid_, 0);
    EXPECT_GT(renderer.last_edge_pixels(), 100);
    // Every pixel with a ray once, plus the sub-samples of the edge pixels, in few batches.
    EXPECT_GT(batching.batched_, 10000);
    EXPECT_LT(batching.batches_, batching.batched_ / 20);
  }
}

// A disc fixed to the camera (z = 1, radius 0.2 about the optical axis: object 2) in front of a
// half-space of the world (HalfSpaceScene): the disc is camera-fixed geometry (renderer.h), and a
// ray that misses it sees the world (kWorld). Counts what the renderer asked and flagged.
class CameraFixedDiscScene final : public Scene {
 public:
  CameraFixedDiscScene(const Eigen::Vector3d& n, double disc_radius)
      : world_(n, 0.2, 0.9), radius_(disc_radius) {}
  Hit Trace(const Ray& ray) const override {
    return HitsDisc(ray.p_C_O, ray.d_C) ? Disc(ray.d_C) : world_.Trace(ray);
  }
  void TraceBatch(const RayBatch& rays, Hit* hits) const override {
    for (int k = 0; k < rays.count; ++k) {
      Ray ray;
      ray.p_C_O = rays.origins[rays.shared_origin ? 0 : k];
      ray.d_C = rays.directions[k];
      const bool skip = rays.misses_camera_fixed != nullptr && rays.misses_camera_fixed[k];
      flagged_ += skip ? 1 : 0;
      hits[k] = skip ? world_.Trace(ray) : Trace(ray);
    }
  }
  uint64_t CameraFixedKey() const override { return 1000 + static_cast<uint64_t>(radius_ * 1e6); }
  void TraceCameraFixed(const RayBatch& rays, CameraFixedHit* out) const override {
    ++asked_;
    for (int k = 0; k < rays.count; ++k) {
      const Eigen::Vector3d& d = rays.directions[k];
      if (HitsDisc(rays.origins[rays.shared_origin ? 0 : k], d)) {
        out[k].kind = CameraFixedHit::kConstant;
        out[k].hit = Disc(d);
      } else {
        out[k].kind = CameraFixedHit::kWorld;
      }
    }
  }
  mutable long flagged_ = 0;
  mutable long asked_ = 0;

 private:
  bool HitsDisc(const Eigen::Vector3d& o, const Eigen::Vector3d& d) const {
    if (!(d.z() > 0.0)) return false;
    const double t = (1.0 - o.z()) / d.z();
    return t > 0.0 && (o + t * d).head<2>().squaredNorm() <= radius_ * radius_;
  }
  static Hit Disc(const Eigen::Vector3d& d) { return Hit{0.05, 2, 1.0 / d.z()}; }
  HalfSpaceScene world_;
  double radius_;
};

TEST(RendererTest, CameraFixedGeometryIsAskedOncePerKeyAndTheFrameIsUnchanged) {
  const PinholeBrownCamera camera = Pinhole(200, 150, 180.0);
  RenderOptions o;
  o.supersampling = 4;
  Renderer renderer(camera, o);
  EXPECT_EQ(renderer.camera_fixed_key(), 0u);
  const CameraFixedDiscScene a(Eigen::Vector3d(0.3, -1.0, 0.1).normalized(), 0.2);
  const TraceOnly reference(a);
  Frame with = MakeFrame(camera), without = MakeFrame(camera);
  GroundTruth truth_with, truth_without;
  renderer.Render(a, 1, with.view, &truth_with);
  renderer.Render(reference, 1, without.view, &truth_without);
  EXPECT_EQ(with.pixels, without.pixels);
  EXPECT_EQ(truth_with.object, truth_without.object);
  EXPECT_EQ(truth_with.depth, truth_without.depth);
  const Renderer::CameraFixedStatistics& stats = renderer.camera_fixed_statistics();
  EXPECT_EQ(renderer.camera_fixed_key(), a.CameraFixedKey());
  EXPECT_EQ(stats.centres_on_surface, 0);
  EXPECT_GT(stats.centres_constant, 1000);  // the disc
  EXPECT_GT(stats.centres_traced, stats.centres_constant);
  EXPECT_EQ(stats.centres_constant + stats.centres_traced, 200 * 150);
  EXPECT_GT(stats.pixels_constant, 1000);  // inside the disc
  EXPECT_GT(stats.pixels_traced, 10000);   // outside it
  EXPECT_GT(stats.pixels_kept, 50);        // on its outline
  EXPECT_GT(a.flagged_, 10000);
  EXPECT_GT(std::count(truth_with.object.begin(), truth_with.object.end(), 2), 100);
  const long asked = a.asked_;
  EXPECT_GT(asked, 0);

  // Another world behind the same camera-fixed disc: not asked again.
  const CameraFixedDiscScene b(Eigen::Vector3d(-0.5, 1.0, 0.2).normalized(), 0.2);
  renderer.Render(b, 2, with.view);
  EXPECT_EQ(b.asked_, 0);
  EXPECT_GT(b.flagged_, 10000);
  // Another disc: asked again, and the frame still equals the reference.
  const CameraFixedDiscScene c(Eigen::Vector3d(0.3, -1.0, 0.1).normalized(), 0.35);
  const TraceOnly reference_c(c);
  renderer.Render(c, 3, with.view, &truth_with);
  EXPECT_GT(c.asked_, 0);
  EXPECT_EQ(renderer.camera_fixed_key(), c.CameraFixedKey());
  renderer.Render(reference_c, 3, without.view, &truth_without);
  EXPECT_EQ(with.pixels, without.pixels);
  EXPECT_EQ(truth_with.object, truth_without.object);
}

// A floor fixed to the camera (the plane y_C = 0.5, the camera 0.5 m above it looking along it;
// surface coordinates (x_C, z_C) of the hit) on which the world's texture moves: object 1
// (radiance 0.8) where x_C + shift < 0, object 0 (0.2) elsewhere, so the texture's edge is the
// image line u = cx − shift (v − cy) / 0.5. Above the horizon: constant sky (object 3). A small
// disc fixed to the camera (object 2, z = 1, centre (−0.15, 0.25), radius 0.05) hides part of the
// floor. Counts the renderer's calls.
class CameraFixedFloorScene final : public Scene {
 public:
  explicit CameraFixedFloorScene(double shift) : shift_(shift) {}
  Hit Trace(const Ray& ray) const override {
    const CameraFixedHit fixed = Fixed(ray.d_C);
    if (fixed.kind != CameraFixedHit::kSurface) return fixed.hit;
    Hit hit = fixed.hit;
    Shade(fixed.surface, &hit);
    return hit;
  }
  void TraceBatch(const RayBatch& rays, Hit* hits) const override {
    traced_ += rays.count;
    Scene::TraceBatch(rays, hits);
  }
  uint64_t CameraFixedKey() const override { return 77; }
  void TraceCameraFixed(const RayBatch& rays, CameraFixedHit* out) const override {
    ++asked_;
    for (int k = 0; k < rays.count; ++k) out[k] = Fixed(rays.directions[k]);
  }
  void ShadeSurface(const Eigen::Vector2d* points, int count, Hit* hits) const override {
    shaded_ += count;
    for (int k = 0; k < count; ++k) Shade(points[k], &hits[k]);
  }
  mutable long asked_ = 0, traced_ = 0, shaded_ = 0;

 private:
  CameraFixedHit Fixed(const Eigen::Vector3d& d) const {  // the camera is at the origin
    CameraFixedHit out;
    out.kind = CameraFixedHit::kConstant;
    if (d.z() > 0.0) {
      const Eigen::Vector3d p = d / d.z();
      if ((p.head<2>() - Eigen::Vector2d(-0.15, 0.25)).squaredNorm() <= 0.05 * 0.05) {
        out.hit = Hit{0.05, 2, 1.0 / d.z()};
        return out;
      }
    }
    if (!(d.y() > 0.0)) {
      out.hit = Hit{0.5, 3, kInf};
      return out;
    }
    const double t = 0.5 / d.y();
    out.kind = CameraFixedHit::kSurface;
    out.surface = Eigen::Vector2d(t * d.x(), t * d.z());
    out.hit.depth = t;
    return out;
  }
  void Shade(const Eigen::Vector2d& p, Hit* hit) const {
    const bool left = p.x() + shift_ < 0.0;
    hit->object = left ? 1 : 0;
    hit->radiance = left ? 0.8 : 0.2;
  }
  double shift_;
};

TEST(RendererTest, CameraFixedSurfaceIsShadedNotTracedAndItsEdgesLieWhereTheModelSays) {
  const PinholeBrownCamera camera = Pinhole(200, 150, 180.0);
  const auto& k = camera.parameters();
  RenderOptions o;
  o.supersampling = 4;
  Renderer renderer(camera, o);
  Frame f = MakeFrame(camera), ray_traced = MakeFrame(camera);
  GroundTruth truth, ray_truth;
  const double kLo = std::round(0.2 * 255), kHi = std::round(0.8 * 255);
  double max_error = 0.0, max_ray_error = 0.0;
  std::vector<long> asked;
  for (const double shift : {-0.031, 0.0123, 0.047}) {
    const CameraFixedFloorScene scene(shift);
    const long allocations = kinevis::testing::ThreadAllocations();
    renderer.Render(scene, 1, f.view, &truth);
    if (!asked.empty()) {  // the same key: nothing asked, nothing allocated
      EXPECT_EQ(kinevis::testing::ThreadAllocations() - allocations, 0);
    }
    // Every pixel from the kept answers: nothing traced; asked for the first scene only.
    EXPECT_EQ(scene.traced_, 0);
    EXPECT_GT(scene.shaded_, 200 * 75);
    asked.push_back(scene.asked_);
    // The same scene traced ray by ray: the same ground truth, and the same frame but where a
    // sample lies within the verified interpolation error of an edge.
    const TraceOnly reference(scene);
    renderer.Render(reference, 1, ray_traced.view, &ray_truth);
    // The texture's edge, row by row below the horizon (the disc is far to its left), in both.
    for (int v = static_cast<int>(k.cy) + 8; v < camera.height() - 2; ++v) {
      const double u_true = k.cx - shift * (v - k.cy) / 0.5;
      const int c = static_cast<int>(std::floor(u_true));
      max_error = std::max(max_error, std::abs(EdgeAlongRow(f.pixels, camera.width(), v, c - 3,
                                                            c + 4, kLo, kHi, false) -
                                               u_true));
      max_ray_error =
          std::max(max_ray_error, std::abs(EdgeAlongRow(ray_traced.pixels, camera.width(), v, c - 3,
                                                        c + 4, kLo, kHi, false) -
                                           u_true));
    }
    EXPECT_EQ(truth.object, ray_truth.object);
    EXPECT_EQ(truth.depth, ray_truth.depth);
    int different = 0;
    for (size_t i = 0; i < f.pixels.size(); ++i) different += f.pixels[i] != ray_traced.pixels[i];
    EXPECT_LE(different, renderer.last_edge_pixels() / 100);
  }
  // One key: asked for the first scene only (a batch per run of a row and per pixel).
  EXPECT_GT(asked[0], 0);
  EXPECT_EQ(asked[1], 0);
  EXPECT_EQ(asked[2], 0);
  // The anti-aliasing bound (StraightEdgeLiesWhereTheModelSays...), and as close as the frame
  // traced ray by ray.
  EXPECT_LT(max_error, 0.5 / 4 + 0.01);
  EXPECT_LT(max_error, max_ray_error + 0.01);
  std::printf("camera-fixed surface edge: max error %.4f px (traced ray by ray %.4f; bound %.4f)\n",
              max_error, max_ray_error, 0.5 / 4 + 0.01);
  const Renderer::CameraFixedStatistics& stats = renderer.camera_fixed_statistics();
  EXPECT_EQ(stats.centres_traced, 0);
  EXPECT_GT(stats.centres_on_surface, 200 * 70);
  EXPECT_GT(stats.centres_constant, 200 * 70);  // sky and disc
  EXPECT_GT(stats.pixels_interpolated, 200 * 60);
  EXPECT_GT(stats.pixels_kept, 100);  // the horizon and the disc's outline
  EXPECT_GT(stats.pixels_constant, 200 * 60);
  EXPECT_EQ(stats.pixels_traced, 0);
  EXPECT_LE(stats.max_surface_error_px, Renderer::kMaxRayInterpolationErrorPx);
}

}  // namespace
}  // namespace kinevis::vision::render
