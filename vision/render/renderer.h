#pragma once

// Synthetic images through any camera model (issue 5): a Scene says what a ray sees; the Renderer
// casts one ray per pixel through a CameraModel, supersamples the pixels on edges (anti-aliasing,
// so sub-pixel edge extraction has something real to find), and applies the optics and sensor
// effects (blur, vignetting, exposure, noise). Deterministic for a given seed. Grey images only
// (what the seeds' algorithms use); 8-bit output.
//
// Frames: rays are in the camera frame C of the CameraModel (camera_model.h). A Scene holds its
// geometry in a world frame W and the pose X_WC of the camera (or is built directly in C).
//
// Cost model: the back-projected rays of a camera are cached per pixel (Renderer::Prepare), so a
// frame costs one trace per pixel plus s² per edge pixel, handed to the scene in batches
// (Scene::TraceBatch: a run of pixels of one row, the sub-samples of 32 edge pixels). The target
// is a 640×480 frame in ≤ 10 ms on one core (bench/render_bench.cc). A scene with a camera-fixed
// part (Scene::CameraFixedKey: a robot's own body and the ground it moves on, seen by its own
// camera) is asked once per key what every ray sees of that part; its frames then cost a copy or
// one Scene::ShadeSurface per pixel and sample instead of a trace.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "vision/camera/camera_model.h"
#include "vision/image/image_view.h"

namespace kinevis::vision::render {

// What a ray hit. radiance in [0, 1] (1 = white at exposure 1); object = a scene-defined id of the
// surface hit (0 = background), used to find edges and for the ground-truth record; depth = ray
// parameter t of the hit (m), +inf for the background.
struct Hit {
  double radiance = 0.0;
  int object = 0;
  double depth = 0.0;
};

// A batch of rays for Scene::TraceBatch: ray k starts at origins[shared_origin ? 0 : k] and runs
// along directions[k] (unit, never zero: the renderer never passes a pixel it cannot back-project).
struct RayBatch {
  const Eigen::Vector3d* origins = nullptr;
  const Eigen::Vector3d* directions = nullptr;
  int count = 0;
  bool shared_origin = false;
  // Null, or per ray: nonzero when the scene's TraceCameraFixed() said the ray misses its
  // camera-fixed geometry (CameraFixedHit::kWorld; the renderer passes it only to a scene whose
  // CameraFixedKey() is the one it asked with), so TraceBatch may skip testing that geometry.
  const uint8_t* misses_camera_fixed = nullptr;
};

// What a ray sees of the part of a scene that is fixed to the camera (Scene::TraceCameraFixed): the
// same in every frame of every scene with the same CameraFixedKey().
struct CameraFixedHit {
  enum Kind : uint8_t {
    // No claim: Trace() the ray in every frame.
    kTrace = 0,
    // The ray misses the camera-fixed geometry and sees the world, which moves: traced in every
    // frame, with RayBatch::misses_camera_fixed set.
    kWorld = 1,
    // The ray sees `hit` in every frame (the robot's own body, or nothing at all).
    kConstant = 2,
    // The ray meets the scene's camera-fixed surface at `surface` (2-D coordinates the scene
    // defines, smooth along the surface), at ray parameter hit.depth; what it sees there in a
    // frame is Scene::ShadeSurface(surface). (The soccer field's ground: the robot moves in the
    // ground plane, so each ray meets it at the same point of the robot's ground frame in every
    // frame, and only the field's lines move across it.)
    kSurface = 3,
  };
  Kind kind = kTrace;
  Hit hit;                                            // kConstant; kSurface: depth only
  Eigen::Vector2d surface = Eigen::Vector2d::Zero();  // kSurface
};

// A scene: pure function of the ray, const, thread-safe.
class Scene {
 public:
  virtual ~Scene() = default;
  virtual Hit Trace(const Ray& ray_C) const = 0;
  // hits[k] = Trace(ray k) for every ray of the batch (the renderer traces a row of pixels, or the
  // sub-samples of a few dozen edge pixels, per call). The default calls Trace(); a scene may
  // override it to amortise per-ray set-up or trace several rays at once, but must return exactly
  // what Trace() returns (the renderer mixes both).
  virtual void TraceBatch(const RayBatch& rays, Hit* hits) const;

  // Camera-fixed part of a scene. Geometry fixed to the camera (a robot's own body seen by its
  // own camera) is where it was in every frame, for every pose of the robot in the world; so may
  // be a surface the robot moves on (its ground plane). A scene with such a part returns a key
  // for it (equal keys = the same camera-fixed part, radiances included; 0 = none, the default),
  // and TraceCameraFixed() says for each ray what it sees of that part (CameraFixedHit). The
  // renderer asks once per key, for every ray it will ever trace (pixel centres and sub-samples:
  // they are the same in every frame), and keeps the answers. The answer must be exact:
  //   kConstant: Trace(ray) returns `hit`;
  //   kSurface:  Trace(ray) returns ShadeSurface(surface) with depth hit.depth;
  //   kWorld:    Trace(ray) returns what TraceBatch returns for it with misses_camera_fixed set.
  // The default answers kTrace for every ray.
  virtual uint64_t CameraFixedKey() const { return 0; }
  virtual void TraceCameraFixed(const RayBatch& rays, CameraFixedHit* out) const;
  // hits[k].radiance and .object of the camera-fixed surface at points[k] in this frame (.depth is
  // not read). Called only with points a TraceCameraFixed() answer (kSurface) gave, or
  // biquadratic interpolations of nine of them (Renderer, sub-samples). The default aborts: a
  // scene that answers kSurface overrides it.
  virtual void ShadeSurface(const Eigen::Vector2d* points, int count, Hit* hits) const;
};

struct RenderOptions {
  // Edge pixels (whose 3×3 neighbourhood sees more than one object, or whose radiance jumps by
  // more than `edge_radiance_step`) are rendered with s×s samples on a regular sub-pixel grid,
  // s = supersampling (1 = off). The anti-aliasing error of an edge position is then at most
  // 1/(2s) px for a straight edge.
  int supersampling = 4;
  double edge_radiance_step = 0.05;
  // Optics and sensor, applied in this order: blur (Gaussian, σ in px, 0 = none), vignetting
  // (cos⁴-like falloff: gain 1 − vignetting·(r/r_corner)², 0 = none), exposure (gain), noise
  // (Gaussian, σ in grey levels 0..255, 0 = none), then rounding and clamping to 0..255.
  double blur_sigma_px = 0.0;
  double vignetting = 0.0;
  double exposure = 1.0;
  double noise_sigma = 0.0;
  uint64_t seed = 1;  // noise generator seed; the frame index is mixed in (RenderFrame)
  // Empty when usable, otherwise every bad field and its value.
  std::string Validate() const;
};

// Ground truth of a rendered frame: per pixel the object id seen at the pixel centre and the
// depth (m), kept only when requested.
struct GroundTruth {
  int width = 0;
  int height = 0;
  std::vector<int> object;   // width * height, row-major
  std::vector<float> depth;  // width * height, +inf for background
};

class Renderer {
 public:
  // Caches the camera's rays (one BackProject per pixel centre). The camera must outlive the
  // renderer. Throws std::invalid_argument for bad options.
  Renderer(const CameraModel& camera, const RenderOptions& options);

  const CameraModel& camera() const { return camera_; }
  const RenderOptions& options() const { return options_; }

  // Renders frame `frame_index` of `scene` into `out` (must be camera-sized). Noise is seeded by
  // (options.seed, frame_index): the same inputs give the same bytes. `truth` may be null.
  // No allocation after the first call at a given size and camera-fixed key. A pixel (or sub-pixel
  // sample) the camera cannot back-project is black background: radiance 0, object 0, depth +inf.
  void Render(const Scene& scene, uint64_t frame_index, const ImageView8& out,
              GroundTruth* truth = nullptr);

  // Number of pixels supersampled in the last Render() (for tests and the bench).
  int last_edge_pixels() const { return last_edge_pixels_; }
  // For a scene with a camera-fixed part (Scene::CameraFixedKey()): what the renderer keeps of it
  // (key 0 before the first such frame; a frame with another key asks again, about s² + 1
  // camera-fixed traces per pixel). Pixel centres by what they see, and edge-capable pixels (a ray
  // in their 3×3 neighbourhood) by how their sub-samples are made when supersampled: traced every
  // frame (rays), the same every frame (constant: the supersampled radiance is kept), interpolated
  // on the camera-fixed surface (biquadratic in the surface points of the 3×3 pixel centres around
  // the pixel, verified for every sample to lie within kMaxRayInterpolationErrorPx of the point
  // that sample's own ray meets), or from one kept answer per sample.
  struct CameraFixedStatistics {
    uint64_t key = 0;
    long centres_traced = 0;  // kTrace or kWorld
    long centres_constant = 0;
    long centres_on_surface = 0;
    long pixels_traced = 0;
    long pixels_constant = 0;
    long pixels_interpolated = 0;
    long pixels_kept = 0;
    // Largest verified distance (px) between an interpolated surface point and the one of the
    // sample's own ray, mapped to the image through the surface's central-difference Jacobian at
    // the pixel.
    double max_surface_error_px = 0.0;
  };
  uint64_t camera_fixed_key() const { return camera_fixed_.key; }
  const CameraFixedStatistics& camera_fixed_statistics() const { return camera_fixed_; }

  // Sub-pixel sample rays are interpolated (bilinearly, direction renormalised) from the four
  // cached pixel-centre rays around them wherever the constructor verified, at the centre of that
  // 2×2 cell (the worst point for bilinear interpolation), that the interpolated ray re-projects
  // within kMaxRayInterpolationErrorPx of the sample position; elsewhere (image border, cells
  // touching the model's domain boundary, strongly curved models) they are back-projected
  // exactly. Added by the renderer's implementer: back-projecting every sub-sample cost ~35 % of
  // a frame. The largest verified error and the fraction of cells interpolated, for tests:
  static constexpr double kMaxRayInterpolationErrorPx = 0.005;
  double max_ray_interpolation_error_px() const { return max_interpolation_error_px_; }
  double interpolated_cell_fraction() const { return interpolated_cell_fraction_; }

 private:
  const CameraModel& camera_;
  RenderOptions options_;
  // The pixel-centre rays: directions (zero where BackProject failed) and origins, one for all
  // pixels (origins_ empty) when they share it, as for every central model.
  std::vector<Eigen::Vector3d> directions_;
  std::vector<Eigen::Vector3d> origins_;
  Eigen::Vector3d origin_ = Eigen::Vector3d::Zero();
  bool central_ = true;          // camera_.IsCentral()
  int width_ = 0, height_ = 0;   // camera_'s (no virtual call per sample)
  std::vector<float> radiance_;  // scratch
  std::vector<int> object_;      // scratch
  std::vector<float> blur_scratch_;
  std::vector<uint8_t> edge_mask_;          // scratch: 1 where the pixel is supersampled
  std::vector<int> edge_pixels_;            // scratch: indices of the supersampled pixels
  std::vector<uint8_t> edge_flags_;         // scratch: 4 rows of neighbour-difference flags
  std::vector<float> blur_kernel_;          // normalised Gaussian taps, radius ceil(3σ)
  std::vector<uint8_t> cell_interpolable_;  // per 2×2 cell with top-left pixel (u, v)
  // Per sub-sample k = b·s + a of the s×s grid: offset (du, dv) from the pixel centre, the cell
  // of pixel centres around it relative to the pixel (cell_du, cell_dv ∈ {−1, 0}; cell_delta the
  // same as an index offset) and the bilinear weights of its four corner rays.
  // quadratic[3b + a]: the weight of the pixel centre (u + a − 1, v + b − 1) in the biquadratic
  // (Lagrange) interpolation at the sample over the 3×3 pixel centres around it.
  struct SubSample {
    double du = 0.0, dv = 0.0;
    int cell_du = 0, cell_dv = 0, cell_delta = 0;
    double w00 = 0.0, w10 = 0.0, w01 = 0.0, w11 = 0.0;
    std::array<double, 9> quadratic{};
  };
  std::vector<SubSample> subsamples_;
  // Pixels (ascending indices) whose sub-sample rays cannot all be interpolated, with their s²
  // exact rays (direction zero where BackProject failed), computed once by the constructor.
  std::vector<int> exact_pixels_;
  std::vector<Ray> exact_rays_;
  // Runs of consecutive pixels of one row with a ray, (first index, count) pairs in ascending
  // order: the coarse pass traces each run as one batch.
  std::vector<std::pair<int, int>> ray_runs_;
  // Batch scratch (sized by the constructor): the hits of one run or sample batch, and the
  // sub-sample rays of up to kBatchPixels edge pixels with the hit slot each fills.
  static constexpr int kBatchPixels = 32;
  std::vector<Hit> batch_hits_;
  std::vector<Eigen::Vector3d> batch_origins_;
  std::vector<Eigen::Vector3d> batch_directions_;
  std::vector<int> batch_slots_;
  std::vector<Hit> sample_hits_;  // kBatchPixels × s² per-sample hits
  // The camera-fixed part of the scenes with key camera_fixed_.key (PrepareCameraFixed; empty
  // while no such scene was rendered). Per pixel: its centre's kind (CameraFixedHit::Kind), surface
  // point, depth, and constant radiance and object.
  CameraFixedStatistics camera_fixed_;
  std::vector<uint8_t> centre_kind_;
  std::vector<Eigen::Vector2d> centre_surface_;
  std::vector<float> centre_depth_;
  std::vector<float> centre_radiance_;
  std::vector<int> centre_object_;
  // Runs of consecutive pixels of one row with a ray and the same centre kind, for the coarse pass.
  struct KindRun {
    int first = 0;
    int count = 0;
    uint8_t kind = CameraFixedHit::kTrace;
  };
  std::vector<KindRun> kind_runs_;
  // Per pixel: how its sub-samples are made (CameraFixedStatistics), and for kSampleConstant its
  // supersampled radiance.
  enum SampleMode : uint8_t {
    kSampleRays = 0,
    kSampleWorldRays = 1,  // every sample kWorld: traced with misses_camera_fixed
    kSampleConstant = 2,
    kSampleInterpolated = 3,
    kSampleKept = 4,
  };
  std::vector<uint8_t> sample_mode_;
  std::vector<float> constant_radiance_;
  // kSampleKept: the pixels (ascending) and their s² answers each.
  struct KeptSample {
    Eigen::Vector2d surface = Eigen::Vector2d::Zero();
    double radiance = 0.0;
    int object = 0;
    uint8_t kind = CameraFixedHit::kTrace;
  };
  std::vector<int> kept_pixels_;
  std::vector<KeptSample> kept_samples_;
  // Batch scratch: per queued ray its flag; the surface points queued for ShadeSurface with the
  // hit slot each fills, and their hits.
  std::vector<uint8_t> batch_misses_;
  std::vector<uint8_t> batch_ones_;  // all 1: the flags of a run of kWorld pixel centres
  std::vector<Eigen::Vector2d> batch_surface_;
  std::vector<int> batch_surface_slots_;
  std::vector<Hit> batch_surface_hits_;
  double max_interpolation_error_px_ = 0.0;
  double interpolated_cell_fraction_ = 0.0;
  int last_edge_pixels_ = 0;

  const Eigen::Vector3d& Origin(size_t i) const { return origins_.empty() ? origin_ : origins_[i]; }
  Ray PixelRay(size_t i) const {
    Ray ray;
    ray.p_C_O = Origin(i);
    ray.d_C = directions_[i];
    return ray;
  }

  // Bilinear interpolation of the cached rays at sub-pixel position (pu, pv) if the cell is
  // marked interpolable (used to verify the cells in the constructor).
  bool InterpolateRay(double pu, double pv, Ray* ray) const;
  // The ray of sub-sample k of pixel i = (u, v): bilinear in the verified cell around it, else
  // the exact ray cached by the constructor (`exact`: the pixel's s² rays, or null), else
  // back-projected now (image border). False when there is none. Render() and
  // PrepareCameraFixed() both trace exactly these rays.
  bool SampleRay(int i, int u, int v, int k, const Ray* exact, Eigen::Vector3d* origin,
                 Eigen::Vector3d* direction) const;
  // Surface point of sub-sample k of pixel i: biquadratic in the surface points of the 3×3 pixel
  // centres around pixel i, which must all be kSurface (PrepareCameraFixed checks).
  Eigen::Vector2d InterpolateSurface(int i, int k) const;
  // Asks the scene's camera-fixed part about every ray and fills the members above.
  void PrepareCameraFixed(const Scene& scene);
};

}  // namespace kinevis::vision::render
