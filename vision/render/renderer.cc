#include "vision/render/renderer.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace kinevis::vision::render {
namespace {

// Tier-1 check: a broken invariant (caller bug) aborts with file and line.
#define KINEVIS_RENDER_DEMAND(cond)                                                           \
  do {                                                                                        \
    if (!(cond)) {                                                                            \
      std::fprintf(stderr, "%s:%d: renderer: check failed: %s\n", __FILE__, __LINE__, #cond); \
      std::abort();                                                                           \
    }                                                                                         \
  } while (0)

constexpr int kMaxSupersampling = 16;
constexpr double kMaxBlurSigmaPx = 20.0;

bool IsValidRay(const Ray& ray) { return ray.d_C.squaredNorm() > 0.0; }

// A pixel (or sub-pixel sample) the camera cannot back-project sees nothing: background (object 0)
// and black, as outside a catadioptric camera's mirror rim.
Hit TraceOrBlack(const Scene& scene, const Ray& ray) {
  if (!IsValidRay(ray)) return Hit{0.0, 0, std::numeric_limits<double>::infinity()};
  return scene.Trace(ray);
}

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

}  // namespace

std::string RenderOptions::Validate() const {
  std::ostringstream bad;
  const char* sep = "";
  auto add = [&](const char* field, double value, const char* why) {
    bad << sep << field << " = " << value << " (" << why << ")";
    sep = "; ";
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
  const std::string message = bad.str();
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
  rays_.resize(static_cast<size_t>(w) * h);
  for (int v = 0; v < h; ++v) {
    for (int u = 0; u < w; ++u) {
      Ray& ray = rays_[static_cast<size_t>(v) * w + u];
      if (camera_.BackProject(Eigen::Vector2d(u, v), &ray) != ProjectionStatus::kOk) {
        ray.p_C_O.setZero();
        ray.d_C.setZero();
      }
    }
  }

  // Verify bilinear ray interpolation cell by cell at the cell centres (see the header). For a
  // non-central camera the re-projected point is taken 1 m along the ray.
  cell_interpolable_.assign(rays_.size(), uint8_t{0});
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
  const Ray& r00 = rays_[i];
  const Ray& r10 = rays_[i + 1];
  const Ray& r01 = rays_[i + w];
  const Ray& r11 = rays_[i + w + 1];
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

void Renderer::Render(const Scene& scene, uint64_t frame_index, const ImageView8& out,
                      GroundTruth* truth) {
  const int w = camera_.width(), h = camera_.height();
  KINEVIS_RENDER_DEMAND(out.data != nullptr);
  KINEVIS_RENDER_DEMAND(out.width == w && out.height == h);
  KINEVIS_RENDER_DEMAND(out.stride >= static_cast<size_t>(w));
  const size_t n = static_cast<size_t>(w) * h;
  if (radiance_.size() != n) {  // first frame at this size: the only allocations
    radiance_.resize(n);
    object_.resize(n);
    depth_.resize(n);
    edge_mask_.resize(n);
    edge_flags_.resize(4 * static_cast<size_t>(w));
    edge_pixels_.reserve(n);
    if (!blur_kernel_.empty()) blur_scratch_.resize(n);
  }

  // 1. Coarse pass: one ray per pixel centre, from the cache.
  for (size_t i = 0; i < n; ++i) {
    const Hit hit = TraceOrBlack(scene, rays_[i]);
    radiance_[i] = static_cast<float>(hit.radiance);
    object_[i] = hit.object;
    depth_[i] = static_cast<float>(hit.depth);
  }
  if (truth != nullptr) {
    truth->width = w;
    truth->height = h;
    truth->object.assign(object_.begin(), object_.end());
    truth->depth.assign(depth_.begin(), depth_.end());
  }

  // 2. Edge pixels: a pixel whose 3×3 neighbourhood sees another object or a radiance jump.
  // Each unordered neighbour pair (right, down, down-right, down-left) is tested once and marks
  // both of its pixels; the tests run row pair by row pair into flag rows (branch-free loops the
  // compiler vectorises), then are OR-ed into the mask.
  const float step = static_cast<float>(options_.edge_radiance_step);
  uint8_t* horizontal = edge_flags_.data();  // pixel (u, v) differs from (u + 1, v)
  uint8_t* vertical = horizontal + w;        // (u, v) from (u, v + 1)
  uint8_t* diag_right = vertical + w;        // (u, v) from (u + 1, v + 1)
  uint8_t* diag_left = diag_right + w;       // (u, v) from (u − 1, v + 1)
  auto differ_rows = [&](const int* oa, const float* ra, const int* ob, const float* rb, int count,
                         uint8_t* flags) {
    for (int u = 0; u < count; ++u) {
      flags[u] = static_cast<uint8_t>((oa[u] != ob[u]) | (std::abs(ra[u] - rb[u]) > step));
    }
  };
  std::fill(edge_mask_.begin(), edge_mask_.end(), uint8_t{0});
  for (int v = 0; v < h; ++v) {
    const size_t row = static_cast<size_t>(v) * w;
    const int* o = &object_[row];
    const float* r = &radiance_[row];
    uint8_t* mask = &edge_mask_[row];
    horizontal[w - 1] = 0;
    differ_rows(o, r, o + 1, r + 1, w - 1, horizontal);
    for (int u = 0; u < w; ++u) mask[u] |= horizontal[u];
    for (int u = 1; u < w; ++u) mask[u] |= horizontal[u - 1];
    if (v + 1 == h) break;
    const int* o2 = o + w;
    const float* r2 = r + w;
    uint8_t* mask2 = mask + w;
    differ_rows(o, r, o2, r2, w, vertical);
    diag_right[w - 1] = 0;
    differ_rows(o, r, o2 + 1, r2 + 1, w - 1, diag_right);
    diag_left[0] = 0;
    differ_rows(o + 1, r + 1, o2, r2, w - 1, diag_left + 1);
    for (int u = 0; u < w; ++u) {
      mask[u] |= vertical[u] | diag_right[u] | diag_left[u];
      mask2[u] |= vertical[u];
    }
    for (int u = 1; u < w; ++u) mask2[u] |= diag_right[u - 1];
    for (int u = 0; u + 1 < w; ++u) mask2[u] |= diag_left[u + 1];
  }
  edge_pixels_.clear();
  for (size_t i = 0; i < n; ++i) {
    if (edge_mask_[i]) edge_pixels_.push_back(static_cast<int>(i));
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
  const int s = options_.supersampling;
  if (s > 1) {
    const double inv_s = 1.0 / s;
    const bool central = camera_.IsCentral();
    auto sample = [&](int u, int v, int a, int b) -> Hit {
      const double dv = (b + 0.5) * inv_s - 0.5;  // offset from the pixel centre, (−½, ½)
      const double du = (a + 0.5) * inv_s - 0.5;
      // The 2×2 cell of pixel centres around the sample: rows v−1..v or v..v+1, likewise u.
      const int cell_v = dv < 0.0 ? v - 1 : v;
      const double fb = dv < 0.0 ? 1.0 + dv : dv;
      const int cell_u = du < 0.0 ? u - 1 : u;
      const double fa = du < 0.0 ? 1.0 + du : du;
      Ray ray;
      if (cell_u >= 0 && cell_v >= 0 && cell_u + 1 < w && cell_v + 1 < h) {
        const size_t c = static_cast<size_t>(cell_v) * w + cell_u;
        if (cell_interpolable_[c]) {  // all four rays valid, interpolation verified
          const double w00 = (1 - fa) * (1 - fb), w10 = fa * (1 - fb);
          const double w01 = (1 - fa) * fb, w11 = fa * fb;
          const Ray& r00 = rays_[c];
          const Ray& r10 = rays_[c + 1];
          const Ray& r01 = rays_[c + w];
          const Ray& r11 = rays_[c + w + 1];
          const Eigen::Vector3d d = w00 * r00.d_C + w10 * r10.d_C + w01 * r01.d_C + w11 * r11.d_C;
          ray.d_C = d / d.norm();
          ray.p_C_O = central ? r00.p_C_O
                              : Eigen::Vector3d(w00 * r00.p_C_O + w10 * r10.p_C_O +
                                                w01 * r01.p_C_O + w11 * r11.p_C_O);
          return scene.Trace(ray);
        }
      }
      if (camera_.BackProject(Eigen::Vector2d(u + du, v + dv), &ray) != ProjectionStatus::kOk) {
        ray.d_C.setZero();  // no ray: black background (see TraceOrBlack)
      }
      return TraceOrBlack(scene, ray);
    };
    const int last = s - 1;
    for (const int i : edge_pixels_) {
      const int u = i % w, v = i / w;
      const Hit c00 = sample(u, v, 0, 0), c10 = sample(u, v, last, 0);
      const Hit c01 = sample(u, v, 0, last), c11 = sample(u, v, last, last);
      const double lo = std::min({c00.radiance, c10.radiance, c01.radiance, c11.radiance});
      const double hi = std::max({c00.radiance, c10.radiance, c01.radiance, c11.radiance});
      const double corners = c00.radiance + c10.radiance + c01.radiance + c11.radiance;
      if (c00.object == c10.object && c00.object == c01.object && c00.object == c11.object &&
          hi - lo <= options_.edge_radiance_step) {
        radiance_[i] = static_cast<float>(0.25 * corners);
        continue;
      }
      double sum = corners;
      for (int b = 0; b < s; ++b) {
        const bool edge_row = b == 0 || b == last;
        for (int a = 0; a < s; ++a) {
          if (edge_row && (a == 0 || a == last)) continue;  // a corner, traced above
          sum += sample(u, v, a, b).radiance;
        }
      }
      radiance_[i] = static_cast<float>(sum / (s * s));
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
  for (int v = 0; v < h; ++v) {
    const float dv2 = static_cast<float>((v - cv) * (v - cv));
    const float* src = &radiance_[static_cast<size_t>(v) * w];
    uint8_t* dst = out.data + static_cast<size_t>(v) * out.stride;
    // One 64-bit hash of (seed, frame, pixel pair) gives the deviates of two pixels.
    uint64_t bits = 0;
    for (int u = 0; u < w; ++u) {
      float value = src[u] * gain;
      if (vignetting > 0.0f) {
        const float du = static_cast<float>(u - cu);
        value *= 1.0f - vignetting * (du * du + dv2);
      }
      if (sigma > 0.0f) {
        if ((u & 1) == 0)
          bits = Mix64(stream + static_cast<uint64_t>(v) * pairs_per_row + (u >> 1));
        const uint32_t half =
            (u & 1) == 0 ? static_cast<uint32_t>(bits >> 32) : static_cast<uint32_t>(bits);
        value += sigma * NormalFromBits(normals, half);
      }
      value = std::clamp(value, 0.0f, 255.0f);
      dst[u] = static_cast<uint8_t>(value + 0.5f);
    }
  }
}

}  // namespace kinevis::vision::render
