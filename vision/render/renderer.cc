#include "vision/render/renderer.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <new>
#include <sstream>
#include <stdexcept>
#include <type_traits>

#include "common/check.h"
#include "common/config_error.h"

namespace kinevis::vision::render {
namespace {

constexpr int kMaxSupersampling = 16;
constexpr double kMaxBlurSigmaPx = 20.0;

bool IsValidRay(const Ray& ray) { return ray.d_C.squaredNorm() > 0.0; }

// splitmix64 finaliser: a counter-based generator, so that the noise of pixel i of frame f is a
// pure function of (seed, f, i) — deterministic, independent of evaluation order, and cheap.
inline uint64_t Mix64(uint64_t z) {
  z += 0x9e3779b97f4a7c15ULL;
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}

// Standard normal deviates by table look-up: z = Φ⁻¹(u) for a uniform u, piecewise linear in u
// on 4096 equal bins (Φ⁻¹ tabulated at the bin edges by bisection on erfc). Three times cheaper
// than Box–Muller's log/sin/cos, which dominated a noisy frame. The two outermost edges (±∞) are
// replaced by the values that give those bins their exact conditional means, −N φ(z₁) (twice
// that minus z₁ for a linear segment), so the deviates have zero mean and unit variance to
// within 0.2 % (checked by NoiseSigmaOnAFlatRegionMatchesTheOption); tails end at ±4.3σ.
constexpr int kNormalBinsLog2 = 12;
constexpr int kNormalBins = 1 << kNormalBinsLog2;

struct NormalTable {
  std::array<float, kNormalBins + 1> z;
  NormalTable() {
    auto inverse_cdf = [](double p) {
      double lo = -12.0, hi = 12.0;
      for (int it = 0; it < 60; ++it) {
        const double mid = 0.5 * (lo + hi);
        (0.5 * std::erfc(-mid / std::sqrt(2.0)) < p ? lo : hi) = mid;
      }
      return 0.5 * (lo + hi);
    };
    for (int k = 1; k <= kNormalBins / 2; ++k) {
      const double value = inverse_cdf(static_cast<double>(k) / kNormalBins);
      z[k] = static_cast<float>(value);
      z[kNormalBins - k] = static_cast<float>(-value);
    }
    const double z1 = z[1];
    const double pdf = std::exp(-0.5 * z1 * z1) / std::sqrt(2.0 * M_PI);
    z[0] = static_cast<float>(2.0 * (-kNormalBins * pdf) - z1);
    z[kNormalBins] = -z[0];
  }
};

const NormalTable& Normals() {
  static const NormalTable table;
  return table;
}

// A standard normal deviate from 32 random bits: 12 select the bin, 20 interpolate within it.
inline float NormalFromBits(const NormalTable& table, uint32_t bits) {
  const uint32_t bin = bits >> (32 - kNormalBinsLog2);
  const float frac = static_cast<float>(bits & ((1u << (32 - kNormalBinsLog2)) - 1)) *
                     (1.0f / static_cast<float>(1u << (32 - kNormalBinsLog2)));
  return table.z[bin] + frac * (table.z[bin + 1] - table.z[bin]);
}

// Edge detection kernels over one row (section 2 of Render). Written as fixed 16-wide chunks on
// restrict-qualified pointers so that the compiler vectorises them at -O2 (GCC's cheap cost model
// refuses loops that need alias checks or a scalar epilogue); the tail is scalar.
constexpr int kChunk = 16;

// flags[u] = pixel u of row a differs from pixel u of row b (object, or radiance by > step).
void DifferRows(const int* __restrict oa, const float* __restrict ra, const int* __restrict ob,
                const float* __restrict rb, int count, float step, uint8_t* __restrict flags) {
  int u = 0;
  for (; u + kChunk <= count; u += kChunk) {
    for (int k = 0; k < kChunk; ++k) {
      flags[u + k] =
          static_cast<uint8_t>((oa[u + k] != ob[u + k]) | (std::abs(ra[u + k] - rb[u + k]) > step));
    }
  }
  for (; u < count; ++u) {
    flags[u] = static_cast<uint8_t>((oa[u] != ob[u]) | (std::abs(ra[u] - rb[u]) > step));
  }
}

// mask[u] |= a[u] | b[u] | c[u].
void Or3Into(uint8_t* __restrict mask, const uint8_t* __restrict a, const uint8_t* __restrict b,
             const uint8_t* __restrict c, int count) {
  int u = 0;
  for (; u + kChunk <= count; u += kChunk) {
    for (int k = 0; k < kChunk; ++k) mask[u + k] |= a[u + k] | b[u + k] | c[u + k];
  }
  for (; u < count; ++u) mask[u] |= a[u] | b[u] | c[u];
}

// mask[u] |= a[u] | b[u].
void Or2Into(uint8_t* __restrict mask, const uint8_t* __restrict a, const uint8_t* __restrict b,
             int count) {
  int u = 0;
  for (; u + kChunk <= count; u += kChunk) {
    for (int k = 0; k < kChunk; ++k) mask[u + k] |= a[u + k] | b[u + k];
  }
  for (; u < count; ++u) mask[u] |= a[u] | b[u];
}

// The constructor's exact sub-sample rays of pixel i (its ss rays), or null when it has none.
// Pixels are asked in ascending order; *cursor walks exact_pixels (also ascending) with them.
const Ray* ExactRaysOf(const std::vector<int>& exact_pixels, const std::vector<Ray>& exact_rays,
                       int ss, int i, size_t* cursor) {
  while (*cursor < exact_pixels.size() && exact_pixels[*cursor] < i) ++*cursor;
  return *cursor < exact_pixels.size() && exact_pixels[*cursor] == i
             ? &exact_rays[*cursor * static_cast<size_t>(ss)]
             : nullptr;
}

// Whether a pixel centre in the 3×3 neighbourhood of (u, v) has a ray (directions: the cached
// pixel-centre rays, zero where there is none): only such a pixel can become an edge pixel, whose
// sub-samples are traced (a pixel with none around sees uniform black background).
bool RayAround(const std::vector<Eigen::Vector3d>& directions, int w, int h, int u, int v) {
  for (int vv = std::max(v - 1, 0); vv <= std::min(v + 1, h - 1); ++vv) {
    for (int uu = std::max(u - 1, 0); uu <= std::min(u + 1, w - 1); ++uu) {
      if (directions[static_cast<size_t>(vv) * w + uu].squaredNorm() > 0.0) return true;
    }
  }
  return false;
}

// The box filter over an edge pixel's s×s sample hits (Render, section 3), in two steps: whether
// the four corner samples settle the pixel (same object, radiances within `step`), with their
// mean; else the mean of all s² samples, summed corners first and the others in order.
bool CornersSettle(const Hit* hits, int s, double step, double* mean) {
  const int last = s - 1;
  const Hit &c00 = hits[0], &c10 = hits[last], &c01 = hits[last * s], &c11 = hits[last * s + last];
  const double lo = std::min({c00.radiance, c10.radiance, c01.radiance, c11.radiance});
  const double hi = std::max({c00.radiance, c10.radiance, c01.radiance, c11.radiance});
  *mean = 0.25 * (c00.radiance + c10.radiance + c01.radiance + c11.radiance);
  return c00.object == c10.object && c00.object == c01.object && c00.object == c11.object &&
         hi - lo <= step;
}

double BoxMean(const Hit* hits, int s) {
  const int last = s - 1, ss = s * s;
  const int k10 = last, k01 = last * s, k11 = last * s + last;
  double sum = hits[0].radiance + hits[k10].radiance + hits[k01].radiance + hits[k11].radiance;
  for (int k = 0; k < ss; ++k) {
    if (k != 0 && k != k10 && k != k01 && k != k11) sum += hits[k].radiance;
  }
  return sum / ss;
}

}  // namespace

void Scene::TraceCameraFixed(const RayBatch& rays, CameraFixedHit* out) const {
  std::fill(out, out + rays.count, CameraFixedHit{});
}

void Scene::ShadeSurface(const Eigen::Vector2d*, int, Hit*) const {
  // Tier 1: only a scene that answered kSurface is asked, and such a scene must override this.
  KINEVIS_DEMAND(!"Scene::ShadeSurface called on a scene without a camera-fixed surface");
}

void Scene::TraceBatch(const RayBatch& rays, Hit* hits) const {
  Ray ray;
  ray.p_C_O = rays.origins[0];
  for (int k = 0; k < rays.count; ++k) {
    if (!rays.shared_origin) ray.p_C_O = rays.origins[k];
    ray.d_C = rays.directions[k];
    // Constructed in place (guaranteed copy elision): Trace() writes the hit straight into
    // hits[k]. An assignment copied it with one 16-byte load from the callee's three separate
    // stores, which store-to-load forwarding cannot serve (issue 5: a third of a cheap scene's
    // frame).
    new (&hits[k]) Hit(Trace(ray));
  }
}

std::string RenderOptions::Validate() const {
  common::Problems problems;
  const auto add = [&problems](const char* field, double value, const char* why) {
    problems.Add(field, value, why);
  };
  if (supersampling < 1 || supersampling > kMaxSupersampling)
    add("supersampling", supersampling, "must be in 1..16");
  if (!std::isfinite(edge_radiance_step) || edge_radiance_step <= 0.0)
    add("edge_radiance_step", edge_radiance_step, "must be finite and > 0");
  if (!std::isfinite(blur_sigma_px) || blur_sigma_px < 0.0 || blur_sigma_px > kMaxBlurSigmaPx)
    add("blur_sigma_px", blur_sigma_px, "must be in [0, 20]");
  if (!std::isfinite(vignetting) || vignetting < 0.0 || vignetting > 1.0)
    add("vignetting", vignetting, "must be in [0, 1]");
  if (!std::isfinite(exposure) || exposure <= 0.0)
    add("exposure", exposure, "must be finite and > 0");
  if (!std::isfinite(noise_sigma) || noise_sigma < 0.0)
    add("noise_sigma", noise_sigma, "must be finite and >= 0");
  const std::string message = problems.Message();
  return message.empty() ? message : "invalid render options: " + message;
}

Renderer::Renderer(const CameraModel& camera, const RenderOptions& options)
    : camera_(camera), options_(options) {
  std::string message = options_.Validate();
  const std::string camera_message = camera_.Validate();
  if (!camera_message.empty()) {
    message += (message.empty() ? "" : "; ") + std::string("camera: ") + camera_message;
  }
  if (camera_.width() <= 0 || camera_.height() <= 0) {
    message += (message.empty() ? "" : "; ") + std::string("camera image size ") +
               std::to_string(camera_.width()) + "x" + std::to_string(camera_.height()) +
               " (must be positive)";
  }
  if (!message.empty()) throw std::invalid_argument(message);

  const int w = camera_.width(), h = camera_.height();
  central_ = camera_.IsCentral();
  width_ = w;
  height_ = h;
  // The pixel-centre rays, stored as directions plus origins — one origin when all rays share it
  // (central models), so that the per-frame pass streams half the memory (96 MB → 48 MB for a
  // 1616×1216 camera).
  std::vector<Ray> rays(static_cast<size_t>(w) * h);
  bool common_origin = true;
  bool have_origin = false;
  for (int v = 0; v < h; ++v) {
    for (int u = 0; u < w; ++u) {
      Ray& ray = rays[static_cast<size_t>(v) * w + u];
      if (camera_.BackProject(Eigen::Vector2d(u, v), &ray) != ProjectionStatus::kOk) {
        ray.p_C_O.setZero();
        ray.d_C.setZero();
        continue;
      }
      if (!have_origin) {
        origin_ = ray.p_C_O;
        have_origin = true;
      } else if (ray.p_C_O != origin_) {
        common_origin = false;
      }
    }
  }
  directions_.resize(rays.size());
  for (size_t i = 0; i < rays.size(); ++i) directions_[i] = rays[i].d_C;
  if (!common_origin) {
    origins_.resize(rays.size());
    for (size_t i = 0; i < rays.size(); ++i) origins_[i] = rays[i].p_C_O;
  }
  rays.clear();
  rays.shrink_to_fit();

  // Verify bilinear ray interpolation cell by cell at the cell centres (see the header). For a
  // non-central camera the re-projected point is taken 1 m along the ray.
  cell_interpolable_.assign(directions_.size(), uint8_t{0});
  long cells = 0, interpolable = 0;
  for (int v = 0; v + 1 < h; ++v) {
    for (int u = 0; u + 1 < w; ++u) {
      ++cells;
      const size_t i = static_cast<size_t>(v) * w + u;
      cell_interpolable_[i] = 1;  // tentatively, so InterpolateRay tries it
      Ray ray;
      Eigen::Vector2d pixel;
      const Eigen::Vector2d target(u + 0.5, v + 0.5);
      bool ok = InterpolateRay(target.x(), target.y(), &ray) &&
                camera_.Project(ray.p_C_O + ray.d_C, &pixel) == ProjectionStatus::kOk;
      if (ok) {
        const double error = (pixel - target).norm();
        ok = error <= kMaxRayInterpolationErrorPx;
        if (ok) max_interpolation_error_px_ = std::max(max_interpolation_error_px_, error);
      }
      cell_interpolable_[i] = ok ? 1 : 0;
      interpolable += ok ? 1 : 0;
    }
  }
  interpolated_cell_fraction_ = cells > 0 ? static_cast<double>(interpolable) / cells : 0.0;

  // Sub-sample table: offsets from the pixel centre, the 2×2 cell of pixel centres around each
  // sample (rows v−1..v or v..v+1, likewise u) and its bilinear weights.
  const int s = options_.supersampling;
  const double inv_s = 1.0 / s;
  subsamples_.resize(static_cast<size_t>(s) * s);
  for (int b = 0; b < s; ++b) {
    for (int a = 0; a < s; ++a) {
      SubSample& sub = subsamples_[static_cast<size_t>(b) * s + a];
      sub.dv = (b + 0.5) * inv_s - 0.5;  // (−½, ½)
      sub.du = (a + 0.5) * inv_s - 0.5;
      sub.cell_dv = sub.dv < 0.0 ? -1 : 0;
      sub.cell_du = sub.du < 0.0 ? -1 : 0;
      sub.cell_delta = sub.cell_dv * w + sub.cell_du;
      const double fb = sub.dv < 0.0 ? 1.0 + sub.dv : sub.dv;
      const double fa = sub.du < 0.0 ? 1.0 + sub.du : sub.du;
      sub.w00 = (1 - fa) * (1 - fb);
      sub.w10 = fa * (1 - fb);
      sub.w01 = (1 - fa) * fb;
      sub.w11 = fa * fb;
      const double lu[3] = {0.5 * sub.du * (sub.du - 1.0), 1.0 - sub.du * sub.du,
                            0.5 * sub.du * (sub.du + 1.0)};
      const double lv[3] = {0.5 * sub.dv * (sub.dv - 1.0), 1.0 - sub.dv * sub.dv,
                            0.5 * sub.dv * (sub.dv + 1.0)};
      for (int j = 0; j < 3; ++j) {
        for (int m = 0; m < 3; ++m) sub.quadratic[3 * j + m] = lu[m] * lv[j];
      }
    }
  }
  // Exact sub-sample rays of the interior pixels next to a cell that failed the interpolation
  // check and with a ray in their 3×3 neighbourhood: for a catadioptric camera the band along
  // the mirror rim, which is an edge in every frame (back-projecting its s² samples per frame cost
  // ~1.4 ms of the soccer frame). Pixels with no ray around cannot become edge pixels (their
  // neighbourhood is uniformly black background); image-border pixels are back-projected when
  // needed.
  if (s > 1) {
    for (int v = 1; v + 1 < h; ++v) {
      for (int u = 1; u + 1 < w; ++u) {
        const size_t i = static_cast<size_t>(v) * w + u;
        if (cell_interpolable_[i] && cell_interpolable_[i - 1] && cell_interpolable_[i - w] &&
            cell_interpolable_[i - w - 1]) {
          continue;
        }
        if (!RayAround(directions_, w, h, u, v)) continue;
        exact_pixels_.push_back(static_cast<int>(i));
        for (const SubSample& sub : subsamples_) {
          Ray ray;
          if (camera_.BackProject(Eigen::Vector2d(u + sub.du, v + sub.dv), &ray) !=
              ProjectionStatus::kOk) {
            ray.p_C_O.setZero();
            ray.d_C.setZero();
          }
          exact_rays_.push_back(ray);
        }
      }
    }
  }

  // Runs of pixels with a ray, row by row, for the batched coarse pass.
  for (int v = 0; v < h; ++v) {
    int u = 0;
    while (u < w) {
      const size_t i = static_cast<size_t>(v) * w + u;
      if (directions_[i].squaredNorm() == 0.0) {
        ++u;
        continue;
      }
      int count = 1;
      while (u + count < w && directions_[i + count].squaredNorm() > 0.0) ++count;
      ray_runs_.emplace_back(static_cast<int>(i), count);
      u += count;
    }
  }
  const size_t batch_rays = static_cast<size_t>(kBatchPixels) * s * s;
  batch_hits_.resize(std::max(static_cast<size_t>(w), batch_rays));
  batch_origins_.resize(batch_rays);
  batch_directions_.resize(batch_rays);
  batch_slots_.resize(batch_rays);
  batch_misses_.resize(batch_rays);
  batch_ones_.assign(std::max(static_cast<size_t>(w), batch_rays), uint8_t{1});
  batch_surface_.resize(batch_rays);
  batch_surface_slots_.resize(batch_rays);
  batch_surface_hits_.resize(batch_rays);
  sample_hits_.resize(batch_rays);

  if (options_.blur_sigma_px > 0.0) {
    const int radius = static_cast<int>(std::ceil(3.0 * options_.blur_sigma_px));
    blur_kernel_.resize(2 * radius + 1);
    double sum = 0.0;
    for (int k = -radius; k <= radius; ++k) {
      const double g = std::exp(-0.5 * k * k / (options_.blur_sigma_px * options_.blur_sigma_px));
      blur_kernel_[k + radius] = static_cast<float>(g);
      sum += g;
    }
    for (float& g : blur_kernel_) g = static_cast<float>(g / sum);
  }
}

bool Renderer::InterpolateRay(double pu, double pv, Ray* ray) const {
  const int w = camera_.width(), h = camera_.height();
  const double fu0 = std::floor(pu), fv0 = std::floor(pv);
  if (!(fu0 >= 0.0 && fv0 >= 0.0 && fu0 < w - 1 && fv0 < h - 1)) return false;
  const int u0 = static_cast<int>(fu0), v0 = static_cast<int>(fv0);
  const size_t i = static_cast<size_t>(v0) * w + u0;
  if (!cell_interpolable_[i]) return false;
  const Ray r00 = PixelRay(i), r10 = PixelRay(i + 1), r01 = PixelRay(i + w);
  const Ray r11 = PixelRay(i + w + 1);
  if (!IsValidRay(r00) || !IsValidRay(r10) || !IsValidRay(r01) || !IsValidRay(r11)) return false;
  const double a = pu - fu0, b = pv - fv0;
  const double w00 = (1 - a) * (1 - b), w10 = a * (1 - b), w01 = (1 - a) * b, w11 = a * b;
  const Eigen::Vector3d d = w00 * r00.d_C + w10 * r10.d_C + w01 * r01.d_C + w11 * r11.d_C;
  const double norm = d.norm();
  if (!(norm > 0.0)) return false;
  ray->d_C = d / norm;
  ray->p_C_O = w00 * r00.p_C_O + w10 * r10.p_C_O + w01 * r01.p_C_O + w11 * r11.p_C_O;
  return true;
}

inline __attribute__((always_inline)) bool Renderer::SampleRay(int i, int u, int v, int k,
                                                               const Ray* exact,
                                                               Eigen::Vector3d* origin,
                                                               Eigen::Vector3d* direction) const {
  const int w = width_, h = height_;
  const SubSample& sub = subsamples_[k];
  const int cell_u = u + sub.cell_du, cell_v = v + sub.cell_dv;
  if (cell_u >= 0 && cell_v >= 0 && cell_u + 1 < w && cell_v + 1 < h) {
    const size_t c = static_cast<size_t>(i + sub.cell_delta);
    if (cell_interpolable_[c]) {  // all four rays valid, interpolation verified
      // Written out per component (Eigen's expression for the same sums took ~120 instructions
      // per sample; issue 5), normalised with one division.
      const Eigen::Vector3d& a = directions_[c];
      const Eigen::Vector3d& b = directions_[c + 1];
      const Eigen::Vector3d& e = directions_[c + w];
      const Eigen::Vector3d& f = directions_[c + w + 1];
      const double dx = sub.w00 * a.x() + sub.w10 * b.x() + sub.w01 * e.x() + sub.w11 * f.x();
      const double dy = sub.w00 * a.y() + sub.w10 * b.y() + sub.w01 * e.y() + sub.w11 * f.y();
      const double dz = sub.w00 * a.z() + sub.w10 * b.z() + sub.w01 * e.z() + sub.w11 * f.z();
      const double inv_norm = 1.0 / std::sqrt(dx * dx + dy * dy + dz * dz);
      *direction = Eigen::Vector3d(dx * inv_norm, dy * inv_norm, dz * inv_norm);
      if (central_) {
        *origin = Origin(c);
      } else {
        const Eigen::Vector3d& oa = origins_[c];
        const Eigen::Vector3d& ob = origins_[c + 1];
        const Eigen::Vector3d& oe = origins_[c + w];
        const Eigen::Vector3d& of = origins_[c + w + 1];
        *origin = Eigen::Vector3d(
            sub.w00 * oa.x() + sub.w10 * ob.x() + sub.w01 * oe.x() + sub.w11 * of.x(),
            sub.w00 * oa.y() + sub.w10 * ob.y() + sub.w01 * oe.y() + sub.w11 * of.y(),
            sub.w00 * oa.z() + sub.w10 * ob.z() + sub.w01 * oe.z() + sub.w11 * of.z());
      }
      return true;
    }
    if (exact != nullptr) {
      *origin = exact[k].p_C_O;
      *direction = exact[k].d_C;
      return IsValidRay(exact[k]);
    }
  }
  Ray ray;
  if (camera_.BackProject(Eigen::Vector2d(u + sub.du, v + sub.dv), &ray) != ProjectionStatus::kOk) {
    return false;  // no ray: black background (header)
  }
  *origin = ray.p_C_O;
  *direction = ray.d_C;
  return IsValidRay(ray);
}

inline __attribute__((always_inline)) Eigen::Vector2d Renderer::InterpolateSurface(int i,
                                                                                   int k) const {
  const std::array<double, 9>& q = subsamples_[k].quadratic;
  const Eigen::Vector2d* row = &centre_surface_[static_cast<size_t>(i) - width_ - 1];
  double x = 0.0, y = 0.0;
  for (int b = 0; b < 3; ++b, row += width_) {
    for (int a = 0; a < 3; ++a) {
      x += q[3 * b + a] * row[a].x();
      y += q[3 * b + a] * row[a].y();
    }
  }
  return Eigen::Vector2d(x, y);
}

void Renderer::PrepareCameraFixed(const Scene& scene) {
  const int w = width_, h = height_;
  const size_t n = static_cast<size_t>(w) * h;
  const int s = options_.supersampling;
  const int ss = s > 1 ? s * s : 0;
  CameraFixedStatistics stats;
  stats.key = scene.CameraFixedKey();
  const float no_depth = std::numeric_limits<float>::infinity();
  centre_kind_.assign(n, CameraFixedHit::kTrace);
  centre_surface_.assign(n, Eigen::Vector2d::Zero());
  centre_depth_.assign(n, no_depth);
  centre_radiance_.assign(n, 0.0f);
  centre_object_.assign(n, 0);
  sample_mode_.assign(n, kSampleRays);
  constant_radiance_.assign(n, 0.0f);
  kept_pixels_.clear();
  kept_samples_.clear();
  kind_runs_.clear();

  // 1. Pixel centres, a run of a row at a time; then the runs split where the kind changes.
  std::vector<CameraFixedHit> fixed(static_cast<size_t>(std::max(w, 1 + ss)));
  const bool own_origins = !origins_.empty();
  for (const auto& [first, count] : ray_runs_) {
    RayBatch batch;
    batch.origins = own_origins ? &origins_[first] : &origin_;
    batch.shared_origin = !own_origins;
    batch.directions = &directions_[first];
    batch.count = count;
    scene.TraceCameraFixed(batch, fixed.data());
    for (int k = 0; k < count; ++k) {
      const size_t i = static_cast<size_t>(first) + k;
      const CameraFixedHit& f = fixed[k];
      KINEVIS_DEMAND(f.kind <= CameraFixedHit::kSurface);
      centre_kind_[i] = f.kind;
      switch (f.kind) {
        case CameraFixedHit::kConstant:
          centre_radiance_[i] = static_cast<float>(f.hit.radiance);
          centre_object_[i] = f.hit.object;
          centre_depth_[i] = static_cast<float>(f.hit.depth);
          ++stats.centres_constant;
          break;
        case CameraFixedHit::kSurface:
          centre_surface_[i] = f.surface;
          centre_depth_[i] = static_cast<float>(f.hit.depth);
          ++stats.centres_on_surface;
          break;
        default:
          ++stats.centres_traced;
          break;
      }
    }
    int start = 0;
    for (int k = 1; k <= count; ++k) {
      if (k == count || fixed[k].kind != fixed[start].kind) {
        kind_runs_.push_back(KindRun{first + start, k - start, fixed[start].kind});
        start = k;
      }
    }
  }

  // 2. Sub-samples of every pixel that can become an edge pixel (a ray in its 3×3 neighbourhood):
  // the rays Render() would trace, asked once; a sample without a ray is constant black.
  if (ss > 0) {
    std::vector<Eigen::Vector3d> origins(ss), directions(ss);
    std::vector<int> asked(ss);  // sample index of each ray asked
    std::vector<CameraFixedHit> answers(ss);
    std::vector<Hit> hits(ss);
    size_t next_exact = 0;
    for (int v = 0; v < h; ++v) {
      for (int u = 0; u < w; ++u) {
        const int i = v * w + u;
        const Ray* exact = ExactRaysOf(exact_pixels_, exact_rays_, ss, i, &next_exact);
        if (!RayAround(directions_, w, h, u, v)) continue;
        int count = 0;
        for (int k = 0; k < ss; ++k) {
          CameraFixedHit& answer = answers[k];
          if (SampleRay(i, u, v, k, exact, &origins[count], &directions[count])) {
            asked[count++] = k;
          } else {
            answer.kind = CameraFixedHit::kConstant;  // no ray: black background
            answer.hit = Hit{0.0, 0, std::numeric_limits<double>::infinity()};
          }
        }
        if (count > 0) {
          RayBatch batch;
          batch.origins = origins.data();
          batch.directions = directions.data();
          batch.count = count;
          scene.TraceCameraFixed(batch, fixed.data());
          for (int r = 0; r < count; ++r) {
            KINEVIS_DEMAND(fixed[r].kind <= CameraFixedHit::kSurface);
            answers[asked[r]] = fixed[r];
          }
        }
        int kinds[4] = {0, 0, 0, 0};
        for (const CameraFixedHit& a : answers) ++kinds[a.kind];
        if (kinds[CameraFixedHit::kConstant] == ss) {
          for (int k = 0; k < ss; ++k) hits[k] = answers[k].hit;
          double mean = 0.0;
          if (!CornersSettle(hits.data(), s, options_.edge_radiance_step, &mean)) {
            mean = BoxMean(hits.data(), s);
          }
          sample_mode_[i] = kSampleConstant;
          constant_radiance_[i] = static_cast<float>(mean);
          ++stats.pixels_constant;
          continue;
        }
        if (kinds[CameraFixedHit::kTrace] == ss || kinds[CameraFixedHit::kWorld] == ss) {
          sample_mode_[i] = kinds[CameraFixedHit::kWorld] == ss ? kSampleWorldRays : kSampleRays;
          ++stats.pixels_traced;
          continue;
        }
        if (kinds[CameraFixedHit::kSurface] == ss) {
          // Interpolated on the surface if every sample's interpolated point is within
          // kMaxRayInterpolationErrorPx of its own ray's, in pixels through the surface's
          // central-difference Jacobian at the pixel.
          bool ok = u >= 1 && v >= 1 && u + 1 < w && v + 1 < h;
          for (int dv = -1; dv <= 1 && ok; ++dv) {
            for (int du = -1; du <= 1 && ok; ++du) {
              ok = centre_kind_[i + dv * w + du] == CameraFixedHit::kSurface;
            }
          }
          double worst = 0.0;
          if (ok) {
            // The surface's Jacobian in pixels by central differences, to measure in pixels.
            const Eigen::Vector2d e1 = 0.5 * (centre_surface_[i + 1] - centre_surface_[i - 1]);
            const Eigen::Vector2d e2 = 0.5 * (centre_surface_[i + w] - centre_surface_[i - w]);
            const double det = e1.x() * e2.y() - e1.y() * e2.x();
            ok = std::isfinite(det) && std::abs(det) > 1e-12 * e1.norm() * e2.norm();
            for (int k = 0; k < ss && ok; ++k) {
              const Eigen::Vector2d d = InterpolateSurface(i, k) - answers[k].surface;
              const double du = (e2.y() * d.x() - e2.x() * d.y()) / det;
              const double dv = (e1.x() * d.y() - e1.y() * d.x()) / det;
              const double error = std::hypot(du, dv);
              ok = error <= kMaxRayInterpolationErrorPx;
              worst = std::max(worst, error);
            }
          }
          if (ok) {
            sample_mode_[i] = kSampleInterpolated;
            stats.max_surface_error_px = std::max(stats.max_surface_error_px, worst);
            ++stats.pixels_interpolated;
            continue;
          }
        }
        sample_mode_[i] = kSampleKept;
        kept_pixels_.push_back(i);
        for (const CameraFixedHit& a : answers) {
          KeptSample kept;
          kept.kind = a.kind;
          kept.surface = a.surface;
          kept.radiance = a.hit.radiance;
          kept.object = a.hit.object;
          kept_samples_.push_back(kept);
        }
        ++stats.pixels_kept;
      }
    }
  }
  camera_fixed_ = stats;
}

void Renderer::Render(const Scene& scene, uint64_t frame_index, const ImageView8& out,
                      GroundTruth* truth) {
  const int w = camera_.width(), h = camera_.height();
  KINEVIS_DEMAND(out.data != nullptr);
  KINEVIS_DEMAND(out.width == w && out.height == h);
  KINEVIS_DEMAND(out.stride >= static_cast<size_t>(w));
  const size_t n = static_cast<size_t>(w) * h;
  if (radiance_.size() != n) {  // first frame at this size: the only allocations
    radiance_.resize(n);
    object_.resize(n);
    edge_mask_.resize(n);
    edge_flags_.resize(4 * static_cast<size_t>(w));
    edge_pixels_.reserve(n);
    if (!blur_kernel_.empty()) blur_scratch_.resize(n);
  }

  // 0. The camera-fixed part of the scene: asked once per key.
  const uint64_t key = scene.CameraFixedKey();
  const bool use_fixed = key != 0;
  if (use_fixed && key != camera_fixed_.key) PrepareCameraFixed(scene);

  // 1. Coarse pass: one ray per pixel centre, from the cache. Depths are kept only for the ground
  // truth, written straight into it.
  float* depth = nullptr;
  if (truth != nullptr) {
    truth->width = w;
    truth->height = h;
    truth->depth.resize(n);
    depth = truth->depth.data();
  }
  // Pixels without a ray are black background; each run of pixels with one is one batch: traced,
  // or (camera-fixed part) copied or shaded on the surface.
  const bool own_origins = !origins_.empty();
  const float no_depth = std::numeric_limits<float>::infinity();
  auto background = [&](size_t from, size_t to) {
    std::fill(radiance_.begin() + from, radiance_.begin() + to, 0.0f);
    std::fill(object_.begin() + from, object_.begin() + to, 0);
    if (depth != nullptr) std::fill(depth + from, depth + to, no_depth);
  };
  auto store = [&](int first, int count, const Hit* hits, bool with_depth) {
    for (int k = 0; k < count; ++k) {
      radiance_[first + k] = static_cast<float>(hits[k].radiance);
      object_[first + k] = hits[k].object;
    }
    if (depth != nullptr && with_depth) {
      for (int k = 0; k < count; ++k) depth[first + k] = static_cast<float>(hits[k].depth);
    }
  };
  auto trace_run = [&](int first, int count, bool world) {
    RayBatch batch;
    batch.origins = own_origins ? &origins_[first] : &origin_;
    batch.shared_origin = !own_origins;
    batch.directions = &directions_[first];
    batch.count = count;
    if (world) batch.misses_camera_fixed = batch_ones_.data();
    scene.TraceBatch(batch, batch_hits_.data());
    store(first, count, batch_hits_.data(), true);
  };
  size_t done = 0;
  if (!use_fixed) {
    for (const auto& [first, count] : ray_runs_) {
      background(done, static_cast<size_t>(first));
      trace_run(first, count, false);
      done = static_cast<size_t>(first) + count;
    }
  } else {
    for (const KindRun& run : kind_runs_) {
      background(done, static_cast<size_t>(run.first));
      const size_t first = static_cast<size_t>(run.first), to = first + run.count;
      switch (run.kind) {
        case CameraFixedHit::kConstant:
          std::copy(&centre_radiance_[first], &centre_radiance_[to], &radiance_[first]);
          std::copy(&centre_object_[first], &centre_object_[to], &object_[first]);
          break;
        case CameraFixedHit::kSurface:
          scene.ShadeSurface(&centre_surface_[first], run.count, batch_hits_.data());
          store(run.first, run.count, batch_hits_.data(), false);
          break;
        default:
          trace_run(run.first, run.count, run.kind == CameraFixedHit::kWorld);
          break;
      }
      if (depth != nullptr &&
          (run.kind == CameraFixedHit::kConstant || run.kind == CameraFixedHit::kSurface)) {
        std::copy(&centre_depth_[first], &centre_depth_[to], depth + first);
      }
      done = to;
    }
  }
  background(done, n);
  if (truth != nullptr) truth->object.assign(object_.begin(), object_.end());

  // 2. Edge pixels: a pixel whose 3×3 neighbourhood sees another object or a radiance jump.
  // Each unordered neighbour pair (right, down, down-right, down-left) is tested once and marks
  // both of its pixels; the tests run row pair by row pair into flag rows (branch-free loops the
  // compiler vectorises), then are OR-ed into the mask. (A 4-neighbourhood suffices for a straight
  // edge between two regions but loses the corners of sub-pixel lines: tried in issue 5's second
  // pass, 135 pixels of the soccer frame moved by up to 61 grey levels.)
  const float step = static_cast<float>(options_.edge_radiance_step);
  uint8_t* horizontal = edge_flags_.data();  // pixel (u, v) differs from (u + 1, v)
  uint8_t* vertical = horizontal + w;        // (u, v) from (u, v + 1)
  uint8_t* diag_right = vertical + w;        // (u, v) from (u + 1, v + 1)
  uint8_t* diag_left = diag_right + w;       // (u, v) from (u − 1, v + 1)
  std::fill(edge_mask_.begin(), edge_mask_.end(), uint8_t{0});
  for (int v = 0; v < h; ++v) {
    const size_t row = static_cast<size_t>(v) * w;
    const int* o = &object_[row];
    const float* r = &radiance_[row];
    uint8_t* mask = &edge_mask_[row];
    // horizontal[u] for u < w − 1; horizontal[w − 1] = 0. Pixel u gets its own flag and that of
    // u − 1 (mask[1..] |= horizontal[0..]).
    horizontal[w - 1] = 0;
    DifferRows(o, r, o + 1, r + 1, w - 1, step, horizontal);
    Or2Into(mask, horizontal, horizontal, w);
    Or2Into(mask + 1, horizontal, horizontal, w - 1);  // mask[u] |= horizontal[u − 1]
    if (v + 1 == h) break;
    const int* o2 = o + w;
    const float* r2 = r + w;
    uint8_t* mask2 = mask + w;
    DifferRows(o, r, o2, r2, w, step, vertical);
    diag_right[w - 1] = 0;
    DifferRows(o, r, o2 + 1, r2 + 1, w - 1, step, diag_right);
    diag_left[0] = 0;
    DifferRows(o + 1, r + 1, o2, r2, w - 1, step, diag_left + 1);
    Or3Into(mask, vertical, diag_right, diag_left, w);
    Or2Into(mask2, vertical, vertical, w);
    Or2Into(mask2 + 1, diag_right, diag_right, w - 1);    // mask2[u] |= diag_right[u − 1]
    Or2Into(mask2, diag_left + 1, diag_left + 1, w - 1);  // mask2[u] |= diag_left[u + 1]
  }
  edge_pixels_.clear();
  size_t j = 0;
  for (; j + 8 <= n; j += 8) {  // most of the mask is zero: skip it eight bytes at a time
    uint64_t word;
    std::memcpy(&word, &edge_mask_[j], sizeof(word));
    if (word == 0) continue;
    for (size_t k = j; k < j + 8; ++k) {
      if (edge_mask_[k]) edge_pixels_.push_back(static_cast<int>(k));
    }
  }
  for (; j < n; ++j) {
    if (edge_mask_[j]) edge_pixels_.push_back(static_cast<int>(j));
  }
  last_edge_pixels_ = static_cast<int>(edge_pixels_.size());

  // 3. Supersample the edge pixels: s×s samples at the centres of an s×s sub-pixel grid (a box
  // filter over the pixel: the value is the covered fraction). Sample rays: interpolated where
  // verified (header), else back-projected.
  // Early out: the four corner samples are traced first; when they see the same object with
  // radiances within edge_radiance_step of each other, no straight edge crosses the grid (a
  // half-plane containing the corners contains their convex hull, hence every sample), and the
  // pixel gets the corners' mean. Half of the edge pixels are neighbours of an edge rather than
  // crossed by it, so this saves about a third of the samples; exact for straight edges, and for
  // the limb conics here the sagitta over the 0.75 px hull is < 0.01 px.
  // Batches: 32 edge pixels at a time, first their corners, then the other samples of those the
  // corners did not settle, each as one Scene::TraceBatch (and one Scene::ShadeSurface for the
  // samples on a camera-fixed surface); sums in the unbatched order.
  // With a camera-fixed part, each pixel's samples are made as PrepareCameraFixed decided: traced,
  // constant (the kept radiance, no sample at all), interpolated on the surface, or from the kept
  // per-sample answers.
  const int s = options_.supersampling;
  if (s > 1) {
    const Hit black{0.0, 0, std::numeric_limits<double>::infinity()};
    const int ss = s * s;
    int queued = 0, queued_surface = 0;
    // Queues sample k of the pixel in batch slot p (hit slot p·s² + k) for tracing or shading.
    auto queue_ray = [&](int slot, int i, int u, int v, int k, const Ray* exact, bool world) {
      if (SampleRay(i, u, v, k, exact, &batch_origins_[queued], &batch_directions_[queued])) {
        batch_misses_[queued] = world ? 1 : 0;
        batch_slots_[queued++] = slot;
      } else {
        sample_hits_[slot] = black;
      }
    };
    auto queue = [&](int p, int i, int u, int v, int k, uint8_t mode, const Ray* exact,
                     const KeptSample* kept) {
      const int slot = p * ss + k;
      switch (mode) {
        case kSampleInterpolated:
          batch_surface_[queued_surface] = InterpolateSurface(i, k);
          batch_surface_slots_[queued_surface++] = slot;
          break;
        case kSampleKept:
          switch (kept[k].kind) {
            case CameraFixedHit::kConstant:
              sample_hits_[slot] = Hit{kept[k].radiance, kept[k].object, 0.0};
              break;
            case CameraFixedHit::kSurface:
              batch_surface_[queued_surface] = kept[k].surface;
              batch_surface_slots_[queued_surface++] = slot;
              break;
            default:
              queue_ray(slot, i, u, v, k, exact, kept[k].kind == CameraFixedHit::kWorld);
              break;
          }
          break;
        default:
          queue_ray(slot, i, u, v, k, exact, mode == kSampleWorldRays);
          break;
      }
    };
    auto trace_queue = [&]() {
      if (queued > 0) {
        RayBatch batch;
        batch.origins = batch_origins_.data();
        batch.directions = batch_directions_.data();
        batch.count = queued;
        if (use_fixed) batch.misses_camera_fixed = batch_misses_.data();
        scene.TraceBatch(batch, batch_hits_.data());
        for (int r = 0; r < queued; ++r) sample_hits_[batch_slots_[r]] = batch_hits_[r];
      }
      if (queued_surface > 0) {
        scene.ShadeSurface(batch_surface_.data(), queued_surface, batch_surface_hits_.data());
        for (int r = 0; r < queued_surface; ++r) {
          sample_hits_[batch_surface_slots_[r]] = batch_surface_hits_[r];
        }
      }
      queued = 0;
      queued_surface = 0;
    };
    const int last = s - 1;
    const int k10 = last, k01 = last * s, k11 = last * s + last;
    std::array<const Ray*, kBatchPixels> exacts;
    std::array<const KeptSample*, kBatchPixels> kepts;
    std::array<uint8_t, kBatchPixels> modes;
    std::array<bool, kBatchPixels> settled;
    size_t next_exact = 0, next_kept = 0;  // the lists ascend with the edge pixels: walk them along
    for (size_t e0 = 0; e0 < edge_pixels_.size(); e0 += kBatchPixels) {
      const int batch_pixels =
          static_cast<int>(std::min<size_t>(kBatchPixels, edge_pixels_.size() - e0));
      for (int p = 0; p < batch_pixels; ++p) {
        const int i = edge_pixels_[e0 + p];
        const int u = i % w, v = i / w;
        modes[p] = use_fixed ? sample_mode_[i] : uint8_t{kSampleRays};
        settled[p] = modes[p] == kSampleConstant;
        if (settled[p]) {
          radiance_[i] = constant_radiance_[i];
          continue;
        }
        exacts[p] = modes[p] == kSampleInterpolated
                        ? nullptr
                        : ExactRaysOf(exact_pixels_, exact_rays_, ss, i, &next_exact);
        kepts[p] = nullptr;
        if (modes[p] == kSampleKept) {
          while (kept_pixels_[next_kept] < i) ++next_kept;
          kepts[p] = &kept_samples_[next_kept * static_cast<size_t>(ss)];
        }
        for (const int k : {0, k10, k01, k11}) queue(p, i, u, v, k, modes[p], exacts[p], kepts[p]);
      }
      trace_queue();
      for (int p = 0; p < batch_pixels; ++p) {
        if (settled[p]) continue;
        const int i = edge_pixels_[e0 + p];
        const Hit* hits = &sample_hits_[static_cast<size_t>(p) * ss];
        double mean = 0.0;
        settled[p] = CornersSettle(hits, s, options_.edge_radiance_step, &mean);
        if (settled[p]) {
          radiance_[i] = static_cast<float>(mean);
          continue;
        }
        const int u = i % w, v = i / w;
        for (int k = 0; k < ss; ++k) {
          if (k != 0 && k != k10 && k != k01 && k != k11) {
            queue(p, i, u, v, k, modes[p], exacts[p], kepts[p]);
          }
        }
      }
      trace_queue();
      for (int p = 0; p < batch_pixels; ++p) {
        if (settled[p]) continue;
        radiance_[edge_pixels_[e0 + p]] =
            static_cast<float>(BoxMean(&sample_hits_[static_cast<size_t>(p) * ss], s));
      }
    }
  }

  // 4. Blur: separable Gaussian, edges clamped.
  if (!blur_kernel_.empty()) {
    const int r = static_cast<int>(blur_kernel_.size() / 2);
    for (int v = 0; v < h; ++v) {
      const float* src = &radiance_[static_cast<size_t>(v) * w];
      float* dst = &blur_scratch_[static_cast<size_t>(v) * w];
      for (int u = 0; u < w; ++u) {
        float acc = 0.0f;
        for (int k = -r; k <= r; ++k) {
          const int uu = std::clamp(u + k, 0, w - 1);
          acc += blur_kernel_[k + r] * src[uu];
        }
        dst[u] = acc;
      }
    }
    for (int v = 0; v < h; ++v) {
      float* dst = &radiance_[static_cast<size_t>(v) * w];
      for (int u = 0; u < w; ++u) dst[u] = 0.0f;
      for (int k = -r; k <= r; ++k) {
        const int vv = std::clamp(v + k, 0, h - 1);
        const float g = blur_kernel_[k + r];
        const float* src = &blur_scratch_[static_cast<size_t>(vv) * w];
        for (int u = 0; u < w; ++u) dst[u] += g * src[u];
      }
    }
  }

  // 5. Vignetting, exposure, noise, quantisation.
  const double cu = 0.5 * (w - 1), cv = 0.5 * (h - 1);
  const double r_corner2 = std::max(cu * cu + cv * cv, 1e-12);
  const float vignetting = static_cast<float>(options_.vignetting / r_corner2);
  const float gain = static_cast<float>(255.0 * options_.exposure);
  const float sigma = static_cast<float>(options_.noise_sigma);
  const uint64_t stream = Mix64(options_.seed ^ Mix64(frame_index + 0x632be59bd9b4e019ULL));
  const NormalTable& normals = Normals();
  const uint64_t pairs_per_row = (static_cast<uint64_t>(w) + 1) / 2;
  // One row, with the optional effects chosen at compile time (no per-pixel branches). One 64-bit
  // hash of (seed, frame, pixel pair) gives the deviates of two pixels.
  auto finish_row = [&](int v, auto with_vignetting, auto with_noise) {
    const float dv2 = static_cast<float>((v - cv) * (v - cv));
    const float* src = &radiance_[static_cast<size_t>(v) * w];
    uint8_t* dst = out.data + static_cast<size_t>(v) * out.stride;
    const uint64_t row_stream = stream + static_cast<uint64_t>(v) * pairs_per_row;
    auto pixel = [&](int u, uint32_t half) {
      float value = src[u] * gain;
      if constexpr (decltype(with_vignetting)::value) {
        const float du = static_cast<float>(u - cu);
        value *= 1.0f - vignetting * (du * du + dv2);
      }
      if constexpr (decltype(with_noise)::value) value += sigma * NormalFromBits(normals, half);
      value = std::min(std::max(value, 0.0f), 255.0f);  // = std::clamp, without branches
      dst[u] = static_cast<uint8_t>(value + 0.5f);
    };
    int u = 0;
    for (; u + 1 < w; u += 2) {
      uint64_t bits = 0;
      if constexpr (decltype(with_noise)::value) bits = Mix64(row_stream + (u >> 1));
      pixel(u, static_cast<uint32_t>(bits >> 32));
      pixel(u + 1, static_cast<uint32_t>(bits));
    }
    if (u < w) {
      uint64_t bits = 0;
      if constexpr (decltype(with_noise)::value) bits = Mix64(row_stream + (u >> 1));
      pixel(u, static_cast<uint32_t>(bits >> 32));
    }
  };
  const std::true_type yes;
  const std::false_type no;
  for (int v = 0; v < h; ++v) {
    if (vignetting > 0.0f) {
      if (sigma > 0.0f) {
        finish_row(v, yes, yes);
      } else {
        finish_row(v, yes, no);
      }
    } else if (sigma > 0.0f) {
      finish_row(v, no, yes);
    } else {
      finish_row(v, no, no);
    }
  }
}

}  // namespace kinevis::vision::render
