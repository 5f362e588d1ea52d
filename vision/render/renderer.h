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
// is a 640×480 frame in ≤ 10 ms on one core (bench/render_bench.cc).

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "vision/camera/camera_model.h"

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
  // Null, or per ray: nonzero when the scene's MissesCameraFixed() said the ray misses the
  // scene's camera-fixed geometry (the renderer passes it only to a scene whose CameraFixedKey()
  // is the one it asked with), so TraceBatch may skip testing that geometry.
  const uint8_t* misses_camera_fixed = nullptr;
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

  // Geometry fixed to the camera (a robot's own body seen by its own camera) is where it was in
  // every frame, for every pose of the robot in the world. A scene with such geometry returns a
  // key for it (equal keys = the same camera-fixed geometry in C; 0 = none, the default). The
  // renderer then asks once per key which of the rays it will ever trace (pixel centres and
  // sub-samples: they are the same every frame) miss that geometry, and passes the answer with
  // each batch (RayBatch::misses_camera_fixed). out[k] may be nonzero only when Trace(ray k)
  // returns exactly what the scene returns for that ray without its camera-fixed geometry. The
  // default says no ray misses it.
  virtual uint64_t CameraFixedKey() const { return 0; }
  virtual void MissesCameraFixed(const RayBatch& rays, uint8_t* out) const;
};

// A non-owning 8-bit grey image view (row-major, `stride` bytes per row); hal::Image and cv::Mat
// both provide one without copying.
struct ImageView8 {
  uint8_t* data = nullptr;
  int width = 0;
  int height = 0;
  size_t stride = 0;
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
  // No allocation after the first call at a given size. A pixel (or sub-pixel sample) the camera
  // cannot back-project is black background: radiance 0, object 0, depth +inf.
  void Render(const Scene& scene, uint64_t frame_index, const ImageView8& out,
              GroundTruth* truth = nullptr);

  // Number of pixels supersampled in the last Render() (for tests and the bench).
  int last_edge_pixels() const { return last_edge_pixels_; }
  // For a scene with camera-fixed geometry (Scene::CameraFixedKey()): the key the renderer's
  // per-pixel answers are for (0 before the first such frame; a frame with another key asks
  // again, which costs about s² + 1 camera-fixed tests per pixel), and the fraction of pixels
  // whose every ray misses that geometry (traced without it).
  uint64_t camera_fixed_key() const { return camera_fixed_key_; }
  double camera_fixed_miss_fraction() const { return camera_fixed_miss_fraction_; }

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
  struct SubSample {
    double du = 0.0, dv = 0.0;
    int cell_du = 0, cell_dv = 0, cell_delta = 0;
    double w00 = 0.0, w10 = 0.0, w01 = 0.0, w11 = 0.0;
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
  // Per pixel: 1 when its centre ray and every sub-sample ray miss the camera-fixed geometry of
  // scenes with key camera_fixed_key_ (empty while no such scene was rendered).
  std::vector<uint8_t> misses_camera_fixed_;
  uint64_t camera_fixed_key_ = 0;
  double camera_fixed_miss_fraction_ = 0.0;
  std::vector<uint8_t> batch_misses_;  // per queued sample ray: its pixel's flag
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
  // Fills misses_camera_fixed_ for the scene's key.
  void PrepareCameraFixed(const Scene& scene);
};

}  // namespace kinevis::vision::render
