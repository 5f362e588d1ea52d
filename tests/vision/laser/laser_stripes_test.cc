#include "vision/laser/laser_stripes.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>
#include <random>
#include <vector>

#include "tests/utilities/allocation_counter.h"
#include "vision/camera/camera_file.h"
#include "vision/render/renderer.h"
#include "vision/render/scenes/laser_scene.h"

namespace kinevis::vision::laser {
namespace {

using render::LaserId;
using render::LaserScene;
using render::LaserSceneParameters;
using render::LaserSurfaceKind;

// The scanner camera of seed 004 (1616 × 1216) and one renderer for all tests (its constructor
// back-projects every pixel once).
const CameraModel& Camera() {
  static const std::unique_ptr<CameraModel> camera = BuiltinCameraModel("tsai-seed004");
  return *camera;
}

struct Frame {
  std::vector<uint8_t> pixels;
  int width = 0;
  int height = 0;
  vision::ImageView8 view() {
    return vision::ImageView8{pixels.data(), width, height, static_cast<size_t>(width)};
  }
};

Frame Render(const render::Scene& scene, double noise_sigma = 0.0, double exposure = 1.0,
             uint64_t seed = 1) {
  render::RenderOptions options;
  options.noise_sigma = noise_sigma;
  options.exposure = exposure;
  options.seed = seed;
  static std::unique_ptr<render::Renderer> renderer;
  static render::RenderOptions cached;
  if (renderer == nullptr || cached.noise_sigma != noise_sigma || cached.exposure != exposure ||
      cached.seed != seed) {
    renderer = std::make_unique<render::Renderer>(Camera(), options);
    cached = options;
  }
  Frame frame;
  frame.width = Camera().width();
  frame.height = Camera().height();
  frame.pixels.assign(static_cast<size_t>(frame.width) * frame.height, 0);
  renderer->Render(scene, 0, frame.view());
  return frame;
}

// The scene's exact stripe (StripeCurve, 20 µm spacing) projected into the image.
std::vector<Eigen::Vector2d> ProjectedStripe(const LaserScene& scene, LaserId id) {
  std::vector<Eigen::Vector2d> out;
  for (const Eigen::Vector3d& p : scene.StripeCurve(id, 2e-5)) {
    Eigen::Vector2d px;
    if (Camera().Project(p, &px) == ProjectionStatus::kOk) out.push_back(px);
  }
  return out;
}

// Distance (px) from p to the nearest segment of the polyline, over segments shorter than 2 px
// (longer ones are jumps of the stripe at a step of the surface, not stripe).
double DistanceToCurve(const std::vector<Eigen::Vector2d>& curve, const Eigen::Vector2d& p) {
  double best = std::numeric_limits<double>::infinity();
  for (size_t i = 1; i < curve.size(); ++i) {
    const Eigen::Vector2d& a = curve[i - 1];
    if (std::abs(a.x() - p.x()) > 6.0 || std::abs(a.y() - p.y()) > 6.0) continue;
    const Eigen::Vector2d ab = curve[i] - a;
    if (ab.norm() > 2.0) continue;
    const double t = std::clamp((p - a).dot(ab) / ab.squaredNorm(), 0.0, 1.0);
    best = std::min(best, (a + t * ab - p).norm());
  }
  return best;
}

struct ErrorStats {
  int points = 0;
  int far = 0;  // more than 6 px from the exact stripe (or no exact stripe near)
  double median = 0.0;
  double p95 = 0.0;
  double max = 0.0;
};

ErrorStats StripeErrors(const std::vector<StripePoint>& points,
                        const std::vector<Eigen::Vector2d>& curve) {
  ErrorStats stats;
  std::vector<double> errors;
  for (const StripePoint& p : points) {
    const double d = DistanceToCurve(curve, p.pixel);
    if (!std::isfinite(d)) {
      ++stats.far;
      continue;
    }
    errors.push_back(d);
  }
  stats.points = static_cast<int>(errors.size());
  if (errors.empty()) return stats;
  std::sort(errors.begin(), errors.end());
  stats.median = errors[errors.size() / 2];
  stats.p95 = errors[static_cast<size_t>(0.95 * (errors.size() - 1))];
  stats.max = errors.back();
  return stats;
}

void Print(const char* what, const ErrorStats& s, const StripeCounts& c) {
  std::printf(
      "%-28s %4d pts (%d far) median %.4f p95 %.4f max %.4f px | searched %d found %d "
      "none %d rejected",
      what, s.points, s.far, s.median, s.p95, s.max, c.lines_searched, c.found,
      c.lines_without_candidate);
  for (int r = 0; r < kStripeRejectionCount; ++r) {
    if (c.rejected[r] > 0)
      std::printf(" %s:%d", ToString(static_cast<StripeRejection>(r)), c.rejected[r]);
  }
  std::printf(" | 2nd ignored %d resolved %d\n", c.secondary_peaks_ignored,
              c.double_peaks_resolved);
}

// Where the rotating stripe meets the fixed laser's plane, projected.
Eigen::Vector2d TrueCrossing(const LaserScene& scene) {
  const std::vector<Eigen::Vector3d> curve = scene.StripeCurve(LaserId::kRotating, 1e-5);
  const render::LaserPlane& fixed = scene.plane(LaserId::kFixed);
  for (size_t i = 1; i < curve.size(); ++i) {
    const double d0 = fixed.SignedDistance(curve[i - 1]);
    const double d1 = fixed.SignedDistance(curve[i]);
    if ((d0 > 0.0) != (d1 > 0.0) && (curve[i] - curve[i - 1]).norm() < 1e-4) {
      const Eigen::Vector3d p = curve[i - 1] + d0 / (d0 - d1) * (curve[i] - curve[i - 1]);
      Eigen::Vector2d px;
      EXPECT_EQ(Camera().Project(p, &px), ProjectionStatus::kOk);
      return px;
    }
  }
  ADD_FAILURE() << "no crossing in the scene";
  return Eigen::Vector2d::Zero();
}

LaserSceneParameters TiltedBoard() {
  LaserSceneParameters p;
  p.surface = LaserSurfaceKind::kBoard;
  p.X_CS = Eigen::Translation3d(0.0, 0.0, 0.42) *
           Eigen::AngleAxisd(0.3, Eigen::Vector3d(0.3, 1.0, 0.2).normalized()) *
           Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX());
  return p;
}

LaserSceneParameters PittedBlade() {
  LaserSceneParameters p;
  p.curvature_xx = 2.0;  // R = 0.5 m across, like a turbine blade
  p.curvature_yy = 0.5;
  p.curvature_xy = 0.3;
  // Pits on the rotating stripe (y_S ≈ 2 mm) and on the fixed one (x_S ≈ 30 mm).
  p.pits = {{Eigen::Vector2d(0.02, 0.002), 1.0e-3, 3e-3},
            {Eigen::Vector2d(-0.04, 0.004), 0.5e-3, 2e-3},
            {Eigen::Vector2d(0.03, 0.03), 0.8e-3, 2.5e-3}};
  return p;
}

// Every searched line ends in exactly one state.
void ExpectCountsAddUp(const StripeResult& r) {
  const StripeCounts& c = r.counts;
  EXPECT_EQ(c.lines_searched, c.lines_without_candidate + c.found + c.rejected_total());
  EXPECT_EQ(c.found, static_cast<int>(r.points.size()));
  for (size_t i = 1; i < r.points.size(); ++i) EXPECT_LT(r.points[i - 1].line, r.points[i].line);
  for (const StripePoint& p : r.points) {
    EXPECT_GT(p.confidence, 0.0);
    EXPECT_LE(p.confidence, 1.0);
  }
}

const char* LocatorName(PeakLocator locator) {
  switch (locator) {
    case PeakLocator::kCentreOfGravity:
      return "centre of gravity";
    case PeakLocator::kGaussian3Point:
      return "gaussian 3-point";
    case PeakLocator::kGaussianFit:
      return "gaussian LM fit";
  }
  return "?";
}

LaserStripes ExtractWith(const Frame& frame, const LaserStripeOptions& options) {
  LaserStripeExtractor extractor(options);
  LaserStripes result;
  Frame copy = frame;
  extractor.Extract(copy.view(), &result);
  for (const StripeResult& r : result.stripes) ExpectCountsAddUp(r);
  return result;
}

// Accuracy against the exact stripe on a tilted board, no noise, both lasers on: the error is
// the perpendicular distance from each point to the projected StripeCurve. The bounds are about
// 3× the 95th percentiles measured (printed); the largest errors (≈ 0.3 px) sit at the board's
// ends where the stripe is cut by the edge.
TEST(LaserStripes, TiltedBoardBothStripesAreSubPixelForEveryLocator) {
  const LaserScene scene(TiltedBoard());
  const Frame frame = Render(scene);
  const auto rotating_curve = ProjectedStripe(scene, LaserId::kRotating);
  const auto fixed_curve = ProjectedStripe(scene, LaserId::kFixed);
  const Eigen::Vector2d crossing_truth = TrueCrossing(scene);
  for (PeakLocator locator :
       {PeakLocator::kCentreOfGravity, PeakLocator::kGaussian3Point, PeakLocator::kGaussianFit}) {
    SCOPED_TRACE(LocatorName(locator));
    LaserStripeOptions options;
    options.locator = locator;
    const LaserStripes result = ExtractWith(frame, options);
    const ErrorStats rot = StripeErrors(result.stripe(Stripe::kRotating).points, rotating_curve);
    const ErrorStats fix = StripeErrors(result.stripe(Stripe::kFixed).points, fixed_curve);
    std::printf("board, %s:\n", LocatorName(locator));
    Print("  rotating", rot, result.stripe(Stripe::kRotating).counts);
    Print("  fixed", fix, result.stripe(Stripe::kFixed).counts);
    const double crossing_error = (result.crossing.pixel - crossing_truth).norm();
    std::printf("  crossing %s, error %.4f px (σ from the fits %.4f, %.4f px)\n",
                ToString(result.crossing.status), crossing_error,
                std::sqrt(result.crossing.covariance(0, 0)),
                std::sqrt(result.crossing.covariance(1, 1)));
    EXPECT_GT(rot.points, 950);  // the board spans ≈ 1000 columns and 830 rows
    EXPECT_GT(fix.points, 800);
    EXPECT_EQ(rot.far + fix.far, 0);
    EXPECT_LT(rot.median, 0.03);
    EXPECT_LT(fix.median, 0.03);
    EXPECT_LT(rot.p95, 0.1);
    EXPECT_LT(fix.p95, 0.1);
    EXPECT_LT(rot.max, 0.6);
    EXPECT_LT(fix.max, 0.6);
    ASSERT_TRUE(result.crossing.found());
    EXPECT_LT(crossing_error, 0.08);  // 0.008–0.023 measured
    EXPECT_GT(result.crossing.rotating_points, 50);
    EXPECT_GT(result.crossing.fixed_points, 50);
    // Separation at the crossing: a handful of lines lost there, none given to the wrong laser
    // (no point far from its own stripe, checked above).
    EXPECT_LT(result.stripe(Stripe::kRotating).counts.rejected_total(), 10);
  }
}

// The blade with cavitation pits on both stripes, sensor noise σ = 2 grey levels. Measured p95:
// 0.032 (centre of gravity), 0.059 (3-point: three noisy pixels), 0.026 px (LM fit).
TEST(LaserStripes, PittedBladeWithNoiseFollowsTheExactStripe) {
  const LaserScene scene(PittedBlade());
  const Frame frame = Render(scene, 2.0);
  const auto rotating_curve = ProjectedStripe(scene, LaserId::kRotating);
  const auto fixed_curve = ProjectedStripe(scene, LaserId::kFixed);
  const Eigen::Vector2d crossing_truth = TrueCrossing(scene);
  for (PeakLocator locator :
       {PeakLocator::kCentreOfGravity, PeakLocator::kGaussian3Point, PeakLocator::kGaussianFit}) {
    SCOPED_TRACE(LocatorName(locator));
    LaserStripeOptions options;
    options.locator = locator;
    const LaserStripes result = ExtractWith(frame, options);
    const ErrorStats rot = StripeErrors(result.stripe(Stripe::kRotating).points, rotating_curve);
    const ErrorStats fix = StripeErrors(result.stripe(Stripe::kFixed).points, fixed_curve);
    std::printf("blade, noise 2, %s:\n", LocatorName(locator));
    Print("  rotating", rot, result.stripe(Stripe::kRotating).counts);
    Print("  fixed", fix, result.stripe(Stripe::kFixed).counts);
    const double crossing_error = (result.crossing.pixel - crossing_truth).norm();
    std::printf("  crossing %s, error %.4f px\n", ToString(result.crossing.status), crossing_error);
    EXPECT_GT(rot.points, 1050);
    EXPECT_GT(fix.points, 820);
    EXPECT_EQ(rot.far + fix.far, 0);
    EXPECT_LT(rot.median, 0.05);
    EXPECT_LT(fix.median, 0.05);
    EXPECT_LT(rot.p95, 0.15);
    EXPECT_LT(fix.p95, 0.15);
    EXPECT_LT(rot.max, 1.5);
    EXPECT_LT(fix.max, 1.5);
    ASSERT_TRUE(result.crossing.found());
    EXPECT_LT(crossing_error, 0.08);  // 0.005–0.018 measured
  }
}

// The board with the gauge block (its top carries the stripe 10 mm nearer; its shadows cut the
// stripe on the board): the points follow the exact stripe on both surfaces, the steps start new
// chains, and the crossing's fits use only the chains through it (a step of the rotating stripe
// lies 30 px from the crossing).
TEST(LaserStripes, GaugeBlockStepsAndShadowsSplitTheStripeIntoChains) {
  LaserSceneParameters p;
  p.surface = LaserSurfaceKind::kBoard;
  p.gauge_block = true;
  p.gauge_centre_S = Eigen::Vector2d(-0.03, 0.0);
  p.gauge_heading = 0.2;
  const LaserScene scene(p);
  const Frame frame = Render(scene, 1.0);
  const LaserStripes result = ExtractWith(frame, LaserStripeOptions{});
  const StripeResult& rotating = result.stripe(Stripe::kRotating);
  const ErrorStats rot = StripeErrors(rotating.points, ProjectedStripe(scene, LaserId::kRotating));
  const ErrorStats fix =
      StripeErrors(result.stripe(Stripe::kFixed).points, ProjectedStripe(scene, LaserId::kFixed));
  Print("gauge block rotating", rot, rotating.counts);
  Print("gauge block fixed", fix, result.stripe(Stripe::kFixed).counts);
  const double crossing_error = (result.crossing.pixel - TrueCrossing(scene)).norm();
  std::printf("  crossing %s, error %.4f px, rotating fit rms %.4f px\n",
              ToString(result.crossing.status), crossing_error, result.crossing.rotating_rms_px);
  EXPECT_GT(rot.points, 1000);
  EXPECT_EQ(rot.far + fix.far, 0);
  EXPECT_LT(rot.p95, 0.1);
  EXPECT_LT(fix.p95, 0.1);
  // Pixels straddling the block's edges mix two surfaces: ≈ 0.9 px measured there.
  EXPECT_LT(rot.max, 2.0);
  // The stripe on the board, the block top, the board (measured: columns 203–291, 294–853,
  // 855–1273, the block's part 13 px lower): three chains longer than 50 columns, with steps of
  // more than 10 px between them.
  int long_chains = 0, steps = 0;
  for (size_t i = 0, first = 0; i < rotating.points.size(); ++i) {
    const bool last =
        i + 1 == rotating.points.size() || rotating.points[i + 1].chain != rotating.points[i].chain;
    if (!last) continue;
    std::printf("  chain %d: columns %d-%d, v %.1f-%.1f\n", rotating.points[i].chain,
                rotating.points[first].line, rotating.points[i].line,
                rotating.points[first].position, rotating.points[i].position);
    if (rotating.points[i].line - rotating.points[first].line > 50) ++long_chains;
    if (i + 1 < rotating.points.size() &&
        std::abs(rotating.points[i + 1].position - rotating.points[i].position) > 10.0) {
      ++steps;
    }
    first = i + 1;
  }
  EXPECT_GE(long_chains, 3);
  EXPECT_GE(steps, 2);
  ASSERT_TRUE(result.crossing.found());
  EXPECT_LT(crossing_error, 0.08);  // 0.014 measured (1.2 px when the fit took the step in)
  EXPECT_LT(result.crossing.rotating_rms_px, 0.1);
}

TEST(LaserStripes, OneLaserOffGivesTheOtherStripeAndNothingElse) {
  for (bool fixed_on : {false, true}) {
    SCOPED_TRACE(fixed_on ? "rotating off" : "fixed off");
    LaserSceneParameters p = PittedBlade();
    p.fixed_on = fixed_on;
    p.rotating_on = !fixed_on;
    const LaserScene scene(p);
    const Frame frame = Render(scene, 1.0);
    const LaserStripes result = ExtractWith(frame, LaserStripeOptions{});
    const Stripe on = fixed_on ? Stripe::kFixed : Stripe::kRotating;
    const Stripe off = fixed_on ? Stripe::kRotating : Stripe::kFixed;
    const ErrorStats stats =
        StripeErrors(result.stripe(on).points,
                     ProjectedStripe(scene, fixed_on ? LaserId::kFixed : LaserId::kRotating));
    Print(fixed_on ? "fixed only" : "rotating only", stats, result.stripe(on).counts);
    Print("  the laser that is off", ErrorStats{}, result.stripe(off).counts);
    EXPECT_GT(stats.points, 800);
    EXPECT_EQ(stats.far, 0);
    EXPECT_LT(stats.p95, 0.06);
    // The stripe's lines through the other search are long bright runs, never peaks.
    EXPECT_TRUE(result.stripe(off).points.empty());
    EXPECT_EQ(result.crossing.status, CrossingStatus::kStripeMissing);
    // With the other search switched off (what calibration does): the same points, no crossing.
    LaserStripeOptions only;
    only.search_fixed = fixed_on;
    only.search_rotating = !fixed_on;
    const LaserStripes single = ExtractWith(frame, only);
    EXPECT_EQ(single.stripe(on).points.size(), result.stripe(on).points.size());
    EXPECT_EQ(single.stripe(off).counts.lines_searched, 0);
    EXPECT_EQ(single.crossing.status, CrossingStatus::kNotSearched);
  }
}

// No laser on, noise σ = 3 and clutter: hot pixels, 2×2 specks and a short bright dash (an arc
// spark, a reflection): no point at all, and the counts say why.
TEST(LaserStripes, NoStripeReportsNothing) {
  LaserSceneParameters p = PittedBlade();
  p.fixed_on = false;
  p.rotating_on = false;
  const LaserScene scene(p);
  Frame frame = Render(scene, 3.0);
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> u(20, frame.width - 21), v(20, frame.height - 21);
  auto at = [&](int x, int y) -> uint8_t& {
    return frame.pixels[static_cast<size_t>(y) * frame.width + x];
  };
  for (int k = 0; k < 300; ++k) at(u(rng), v(rng)) = 255;  // hot pixels
  for (int k = 0; k < 50; ++k) {                           // 2×2 specks
    const int x = u(rng), y = v(rng);
    at(x, y) = at(x + 1, y) = at(x, y + 1) = at(x + 1, y + 1) = 200;
  }
  for (int x = 500; x < 503; ++x) at(x, 300) = at(x, 301) = at(x, 302) = 180;  // a 3-px dash
  const LaserStripes result = ExtractWith(frame, LaserStripeOptions{});
  for (Stripe s : {Stripe::kFixed, Stripe::kRotating}) {
    const StripeResult& r = result.stripe(s);
    Print(s == Stripe::kFixed ? "no stripe, fixed" : "no stripe, rotating", ErrorStats{}, r.counts);
    EXPECT_TRUE(r.points.empty());
    EXPECT_GT(r.counts.candidates, 300);  // the clutter was seen, and rejected
    EXPECT_GT(r.counts.rejected[static_cast<int>(StripeRejection::kTooNarrow)] +
                  r.counts.rejected[static_cast<int>(StripeRejection::kIsolated)],
              300);
  }
  EXPECT_EQ(result.crossing.status, CrossingStatus::kStripeMissing);
}

// A specular reflection: a second copy of the rotating stripe, 25 rows lower and nearly as
// bright, over 60 columns; elsewhere a weak one (30 %). Continuity picks the true stripe in the
// strong one's columns; the weak one is ignored and lowers the confidence.
TEST(LaserStripes, ReflectionsAreResolvedByContinuityOrIgnored) {
  LaserSceneParameters p = TiltedBoard();
  p.fixed_on = false;
  const LaserScene scene(p);
  Frame frame = Render(scene);
  const Frame clean = frame;
  auto add_reflection = [&](int u0, int u1, double gain) {
    for (int u = u0; u < u1; ++u) {
      for (int v = frame.height - 1; v >= 25; --v) {
        const int source = clean.pixels[static_cast<size_t>(v - 25) * frame.width + u];
        uint8_t& out = frame.pixels[static_cast<size_t>(v) * frame.width + u];
        out = static_cast<uint8_t>(std::min(255.0, out + gain * std::max(0, source - 20)));
      }
    }
  };
  add_reflection(600, 660, 0.9);
  add_reflection(900, 960, 0.3);
  const auto curve = ProjectedStripe(scene, LaserId::kRotating);
  const LaserStripes result = ExtractWith(frame, LaserStripeOptions{});
  const StripeResult& r = result.stripe(Stripe::kRotating);
  const ErrorStats stats = StripeErrors(r.points, curve);
  Print("reflections", stats, r.counts);
  EXPECT_EQ(stats.far, 0);
  EXPECT_LT(stats.max, 0.6);  // no point on a reflection
  EXPECT_GE(r.counts.double_peaks_resolved, 55);
  EXPECT_GE(r.counts.secondary_peaks_ignored, 55);
  int strong = 0, weak = 0, clean_columns = 0;
  double confidence_weak = 0.0, confidence_clean = 0.0;
  for (const StripePoint& point : r.points) {
    if (point.line >= 600 && point.line < 660) ++strong;
    if (point.line >= 900 && point.line < 960) {
      ++weak;
      confidence_weak += point.confidence;
    } else if (point.line >= 700 && point.line < 860) {
      ++clean_columns;
      confidence_clean += point.confidence;
    }
  }
  EXPECT_GE(strong, 55);
  EXPECT_GE(weak, 55);
  ASSERT_GT(clean_columns, 100);
  std::printf("mean confidence: weak reflection %.3f, clean %.3f\n", confidence_weak / weak,
              confidence_clean / clean_columns);
  EXPECT_LT(confidence_weak / weak, 0.8 * confidence_clean / clean_columns);
  // With the reflection where continuity cannot help (the strong one over all columns of the
  // stripe, so no unambiguous neighbour), the lines are rejected, not guessed.
  frame = clean;
  add_reflection(0, frame.width, 0.9);
  const LaserStripes all = ExtractWith(frame, LaserStripeOptions{});
  const StripeResult& a = all.stripe(Stripe::kRotating);
  Print("reflection everywhere", StripeErrors(a.points, curve), a.counts);
  EXPECT_LT(a.points.size(), 20u);
  EXPECT_GT(a.counts.rejected[static_cast<int>(StripeRejection::kDoublePeak)], 900);
}

// Over-exposure (gain 1.6: the stripe's core clips at 255 over 3–4 px): the LM fit leaves the
// clipped pixels out and stays sub-pixel; a zero tolerance rejects them as saturated.
TEST(LaserStripes, SaturatedStripes) {
  LaserSceneParameters p = TiltedBoard();
  const LaserScene scene(p);
  const Frame frame = Render(scene, 1.0, 1.6);
  const auto curve = ProjectedStripe(scene, LaserId::kRotating);
  LaserStripeOptions options;
  options.locator = PeakLocator::kGaussianFit;
  options.max_saturated_pixels = 6;
  const LaserStripes fitted = ExtractWith(frame, options);
  const StripeResult& r = fitted.stripe(Stripe::kRotating);
  const ErrorStats stats = StripeErrors(r.points, curve);
  Print("saturated, LM fit", stats, r.counts);
  int saturated = 0;
  for (const StripePoint& point : r.points) saturated += point.saturated_pixels > 0 ? 1 : 0;
  EXPECT_GT(saturated, 800);
  EXPECT_GT(stats.points, 900);
  EXPECT_LT(stats.p95, 0.1);
  options.max_saturated_pixels = 0;
  const LaserStripes strict = ExtractWith(frame, options);
  Print("saturated, none allowed", ErrorStats{}, strict.stripe(Stripe::kRotating).counts);
  EXPECT_GT(strict.stripe(Stripe::kRotating)
                .counts.rejected[static_cast<int>(StripeRejection::kSaturated)],
            800);
}

TEST(LaserStripes, ConfidenceDropsWithNoise) {
  const LaserScene scene(PittedBlade());
  auto mean_confidence = [&](double noise) {
    const LaserStripes result = ExtractWith(Render(scene, noise), LaserStripeOptions{});
    double sum = 0.0;
    for (const StripePoint& p : result.stripe(Stripe::kRotating).points) sum += p.confidence;
    return sum / result.stripe(Stripe::kRotating).points.size();
  };
  const double clean = mean_confidence(0.0), noisy = mean_confidence(6.0);
  std::printf("mean confidence: clean %.3f, noise 6: %.3f\n", clean, noisy);
  EXPECT_GT(clean, 0.8);
  EXPECT_LT(noisy, clean - 0.1);
}

// position_sigma_px (from the noise seen in the flank windows) against the actual scatter of the
// centres about the exact stripe, with noise σ = 4 on the board: the same order (the formula is
// the centre of gravity's; within a factor 2 for the LM fit).
TEST(LaserStripes, PositionSigmaPredictsTheScatter) {
  const LaserScene scene(TiltedBoard());
  const Frame frame = Render(scene, 4.0);
  const auto curve = ProjectedStripe(scene, LaserId::kRotating);
  for (PeakLocator locator : {PeakLocator::kCentreOfGravity, PeakLocator::kGaussianFit}) {
    SCOPED_TRACE(LocatorName(locator));
    LaserStripeOptions options;
    options.locator = locator;
    options.search_fixed = false;
    const LaserStripes result = ExtractWith(frame, options);
    double predicted = 0.0, actual = 0.0;
    int n = 0;
    for (const StripePoint& p : result.stripe(Stripe::kRotating).points) {
      const double d = DistanceToCurve(curve, p.pixel);
      if (!std::isfinite(d)) continue;
      predicted += p.position_sigma_px * p.position_sigma_px;
      actual += d * d;
      ++n;
    }
    ASSERT_GT(n, 900);
    predicted = std::sqrt(predicted / n);
    actual = std::sqrt(actual / n);
    std::printf("%s: RMS position_sigma %.4f px, RMS error %.4f px\n", LocatorName(locator),
                predicted, actual);
    EXPECT_GT(predicted, 0.5 * actual);
    EXPECT_LT(predicted, 2.0 * actual);
  }
}

TEST(LaserStripes, SecondExtractAtTheSameSizeDoesNotAllocate) {
  const LaserScene scene(PittedBlade());
  Frame frame = Render(scene, 1.0);
  for (PeakLocator locator : {PeakLocator::kGaussian3Point, PeakLocator::kGaussianFit}) {
    LaserStripeOptions options;
    options.locator = locator;
    LaserStripeExtractor extractor(options);
    LaserStripes result;
    extractor.Extract(frame.view(), &result);
    const size_t first = result.stripe(Stripe::kRotating).points.size();
    const long before = kinevis::testing::ThreadAllocations();
    extractor.Extract(frame.view(), &result);
    EXPECT_EQ(kinevis::testing::ThreadAllocations() - before, 0);
    EXPECT_EQ(result.stripe(Stripe::kRotating).points.size(), first);
    EXPECT_TRUE(result.crossing.found());
  }
  // Reserve() alone sizes everything too.
  LaserStripeExtractor extractor{LaserStripeOptions{}};
  LaserStripes result;
  extractor.Reserve(frame.width, frame.height, &result);
  const long before = kinevis::testing::ThreadAllocations();
  extractor.Extract(frame.view(), &result);
  EXPECT_EQ(kinevis::testing::ThreadAllocations() - before, 0);
}

TEST(LaserStripes, GaussianProfileJacobianMatchesFiniteDifferences) {
  const double h = 1e-6;
  for (const Eigen::Vector4d& q :
       {Eigen::Vector4d(180.0, 10.3, 1.6, 11.0), Eigen::Vector4d(40.0, -2.0, 0.7, -1.2),
        Eigen::Vector4d(255.0, 5.0, 4.0, 13.5)}) {
    Eigen::Vector3d analytic;
    GaussianProfile(q(0), q(1), q(2), q(3), &analytic);
    for (int i = 0; i < 3; ++i) {
      Eigen::Vector3d plus = q.head<3>(), minus = q.head<3>();
      plus(i) += h;
      minus(i) -= h;
      const double numeric = (GaussianProfile(plus(0), plus(1), plus(2), q(3), nullptr) -
                              GaussianProfile(minus(0), minus(1), minus(2), q(3), nullptr)) /
                             (2 * h);
      EXPECT_NEAR(analytic(i), numeric, 1e-6 * std::max(1.0, std::abs(numeric)))
          << "parameter " << i << " at " << q.transpose();
    }
  }
}

TEST(LaserStripes, BadOptionsAreNamedInOneMessage) {
  EXPECT_EQ(LaserStripeOptions{}.Validate(), "");
  LaserStripeOptions o;
  o.background_offset_px = 1;
  o.min_contrast = std::nan("");
  o.max_width_px = 40.0;
  o.double_peak_ratio = 0.0;
  o.locator = static_cast<PeakLocator>(7);
  EXPECT_THAT(o.Validate(),
              ::testing::MatchesRegex(".*background_offset_px = 1 .*min_contrast = nan.*"
                                      "max_width_px = 40 .*locator = 7 .*"
                                      "double_peak_ratio = 0 .*"));
  try {
    LaserStripeExtractor extractor(o);
    ADD_FAILURE() << "no throw";
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), ::testing::HasSubstr("LaserStripeOptions: background_offset_px = 1"));
  }
  LaserStripeOptions crossing;
  crossing.crossing_exclusion_px = 60;
  EXPECT_THAT(crossing.Validate(), ::testing::HasSubstr("crossing_exclusion_px = 60"));
}

TEST(LaserStripes, BadImagesThrow) {
  LaserStripeExtractor extractor{LaserStripeOptions{}};
  LaserStripes result;
  std::vector<uint8_t> pixels(100 * 50, 0);
  EXPECT_THROW(extractor.Extract(vision::ImageView8{nullptr, 100, 50, 100}, &result),
               std::invalid_argument);
  EXPECT_THAT(
      [&] {
        extractor.Extract(vision::ImageView8{pixels.data(), 100, 50, 99}, &result);
      },
      ::testing::ThrowsMessage<std::invalid_argument>(::testing::HasSubstr("stride 99")));
  EXPECT_THROW(extractor.Extract(vision::ImageView8{pixels.data(), 0, 50, 100}, &result),
               std::invalid_argument);
  // A tiny black image is fine: nothing found.
  extractor.Extract(vision::ImageView8{pixels.data(), 100, 50, 100}, &result);
  EXPECT_TRUE(result.stripe(Stripe::kRotating).points.empty());
  EXPECT_EQ(result.stripe(Stripe::kRotating).counts.lines_searched, 100);
  EXPECT_EQ(result.stripe(Stripe::kFixed).counts.lines_without_candidate, 50);
}

}  // namespace
}  // namespace kinevis::vision::laser
