#include "vision/render/scenes/soccer_field_scene.h"

#include <emmintrin.h>  // SSE2: part of every x86-64 target

#include <algorithm>
#include <cmath>
#include <cstring>
#include <sstream>
#include <stdexcept>

#include "common/config_error.h"
#include "vision/render/primitives.h"

namespace kinevis::vision::render {
namespace {

double SegmentDistance(const Eigen::Vector2d& p, const Eigen::Vector4d& s) {
  const Eigen::Vector2d a = s.head<2>(), b = s.tail<2>();
  const Eigen::Vector2d ab = b - a;
  const double t = std::clamp((p - a).dot(ab) / ab.squaredNorm(), 0.0, 1.0);
  return (p - a - t * ab).norm();
}

// Whether the ray o + t d (t ≥ 0) comes within sqrt(radius2) of an axis at or below the axial
// height `top` (a solid of that radius around the axis, below `top`, can only be hit there). In
// the axis's terms: o⊥, d⊥ the components perpendicular to it (relative to a point on it), h0
// and dw = d·w the axial ones. Without a division: if the ray starts above `top` it must descend
// (s = −dw > 0) and from t_lo = (h0 − top)/s on, where s P = s o⊥ + (h0 − top) d⊥; the closest
// approach from there is |P| if the ray moves away from the axis at P (P·d⊥ ≥ 0), else the
// unconstrained |o⊥|² − (o⊥·d⊥)²/|d⊥|²; likewise from t = 0 when it starts below `top`. The
// callers' radius margins (1e-6 relative) cover the rounding.
template <typename Vector>
inline __attribute__((always_inline)) bool MayReachBelow(const Vector& o_perp, const Vector& d_perp,
                                                         double h0, double dw, double top,
                                                         double radius2) {
  const double A = d_perp.squaredNorm(), B = o_perp.dot(d_perp), O = o_perp.squaredNorm();
  if (h0 > top) {
    const double s = -dw;
    if (!(s > 0.0)) return false;
    const Vector sP = s * o_perp + (h0 - top) * d_perp;
    if (sP.dot(d_perp) >= 0.0) return sP.squaredNorm() <= radius2 * s * s;
    return O * A - B * B <= radius2 * A;
  }
  return B >= 0.0 ? O <= radius2 : O * A - B * B <= radius2 * A;
}

// IntersectCylinder (primitives.h) for a cylinder whose axis runs along +y_C from `a` for
// `length` (posts, lens body), with the same arithmetic: with the axis exactly (0, 1, 0) its
// perpendicular components are the x and z ones exactly and the axial one is y, so this gives the
// same bits without the axis normalisation (a square root and three divisions per call).
double IntersectCylinderAlongY(const Ray& ray, const Eigen::Vector3d& a, double length,
                               double radius) {
  const double qx = ray.p_C_O.x() - a.x(), qy = ray.p_C_O.y() - a.y();
  const double qz = ray.p_C_O.z() - a.z();
  const double dx = ray.d_C.x(), dy = ray.d_C.y(), dz = ray.d_C.z();
  const double A = dx * dx + dz * dz;
  if (A < 1e-18) return kNoHit;
  const double B = qx * dx + qz * dz;
  const double C = (qx * qx + qz * qz) - radius * radius;
  const double disc = B * B - A * C;
  if (disc < 0.0) return kNoHit;
  const double s = std::sqrt(disc);
  for (int root = 0; root < 2; ++root) {
    const double t = (root == 0 ? -B - s : -B + s) / A;
    if (!(t > 1e-9)) continue;
    const double along = qy + t * dy;
    if (along < 0.0 || along > length) continue;
    return t;
  }
  return kNoHit;
}

}  // namespace

std::string SoccerFieldSceneParameters::Validate() const {
  common::Problems bad;
  auto positive = [&bad](const char* name, double v) {
    if (!(std::isfinite(v) && v > 0.0)) bad.Add(name, v, "must be > 0");
  };
  positive("field_length", field_length);
  positive("field_width", field_width);
  positive("line_width", line_width);
  positive("centre_circle_radius", centre_circle_radius);
  positive("goal_area_depth", goal_area_depth);
  positive("goal_area_width", goal_area_width);
  positive("penalty_area_depth", penalty_area_depth);
  positive("penalty_area_width", penalty_area_width);
  if (!(std::isfinite(carpet_border) && carpet_border >= 0.0)) {
    bad.Add("carpet_border", carpet_border, "must be >= 0");
  }
  if (goal_area_width >= field_width) {
    bad.Add("goal_area_width", goal_area_width, "must be < field_width");
  }
  if (penalty_area_width >= field_width) {
    bad.Add("penalty_area_width", penalty_area_width, "must be < field_width");
  }
  if (2.0 * penalty_area_depth >= field_length) {
    bad.Add("penalty_area_depth", penalty_area_depth, "must be < field_length / 2");
  }
  if (goal_area_depth >= penalty_area_depth) {
    bad.Add("goal_area_depth", goal_area_depth, "must be < penalty_area_depth");
  }
  if (!std::isfinite(robot_x)) bad.Add("robot_x", robot_x, "must be finite");
  if (!std::isfinite(robot_y)) bad.Add("robot_y", robot_y, "must be finite");
  if (!std::isfinite(robot_heading)) bad.Add("robot_heading", robot_heading, "must be finite");
  positive("body_radius", body_radius);
  positive("body_height", body_height);
  positive("lens_radius", lens_radius);
  if (post_count < 0 || post_count > 8) bad.Add("post_count", post_count, "must be in 0..8");
  positive("post_radius", post_radius);
  if (!(std::isfinite(post_ring_radius) && post_ring_radius - post_radius > lens_radius)) {
    bad.Add("post_ring_radius", post_ring_radius,
            "must exceed lens_radius + post_radius (posts outside the lens body)");
  }
  if (!std::isfinite(post_azimuth)) bad.Add("post_azimuth", post_azimuth, "must be finite");
  const double radiances[7] = {line_radiance, carpet_radiance, floor_radiance,       body_radiance,
                               lens_radiance, post_radiance,   surroundings_radiance};
  const char* names[7] = {"line_radiance",        "carpet_radiance", "floor_radiance",
                          "body_radiance",        "lens_radiance",   "post_radiance",
                          "surroundings_radiance"};
  for (int i = 0; i < 7; ++i) {
    if (!(std::isfinite(radiances[i]) && radiances[i] >= 0.0 && radiances[i] <= 1.0)) {
      bad.Add(names[i], radiances[i], "must be in [0, 1]");
    }
  }
  return bad.Message();
}

SoccerFieldScene::SoccerFieldScene(const HyperbolicMirrorCamera& camera,
                                   const SoccerFieldSceneParameters& parameters)
    : parameters_(parameters), X_CG_(camera.X_CG()), X_GC_(camera.X_CG().inverse()) {
  std::string message = parameters.Validate();
  pinhole_height_ = (X_GC_ * Eigen::Vector3d::Zero()).z();
  if (message.empty() && !(parameters.body_height < pinhole_height_)) {
    std::ostringstream out;
    out << "body_height = " << parameters.body_height << " (must be below the pinhole, which is "
        << pinhole_height_ << " m above the ground)";
    message = out.str();
  }
  if (!message.empty()) throw std::invalid_argument("SoccerFieldScene: " + message);

  X_FG_ = Eigen::Translation3d(parameters.robot_x, parameters.robot_y, 0.0) *
          Eigen::AngleAxisd(parameters.robot_heading, Eigen::Vector3d::UnitZ());

  // Posts: parallel to y_C (the mirror axis) from the pinhole's height to the mirror surface (or
  // the rim's height when outside the rim). Azimuth ψ from x_G (= z_C untilted) towards y_G
  // (= x_C).
  const HyperbolicMirrorParameters& m = camera.parameters();
  const double rho = std::min(parameters.post_ring_radius, m.mirror_radius);
  const double top_y = std::sqrt(m.mirror_constant + rho * rho) + m.mirror_offset();
  for (int i = 0; i < parameters.post_count; ++i) {
    const double psi = parameters.post_azimuth + 2.0 * M_PI * i / parameters.post_count;
    const double x = m.mirror_axis_x + parameters.post_ring_radius * std::sin(psi);
    const double z = m.mirror_axis_z + parameters.post_ring_radius * std::cos(psi);
    post_bottom_C_[i] = Eigen::Vector3d(x, 0.0, z);
    post_x_[i] = x;
    post_z_[i] = z;
    post_top_C_[i] = Eigen::Vector3d(x, top_y, z);
    post_length_[i] = (post_top_C_[i] - post_bottom_C_[i]).norm();
  }
  // Lens body: along y_C below the pinhole down to the robot body's top.
  lens_bottom_C_ = Eigen::Vector3d(0.0, -(pinhole_height_ - parameters.body_height), 0.0);
  lens_length_ = (Eigen::Vector3d::Zero() - lens_bottom_C_).norm();

  // Field lines (centre-lines) in F.
  const double L = 0.5 * parameters.field_length, W = 0.5 * parameters.field_width;
  int k = 0;
  auto add = [this, &k](double x0, double y0, double x1, double y1) {
    segments_F_[k++] = Eigen::Vector4d(x0, y0, x1, y1);
  };
  add(-L, -W, L, -W);
  add(-L, W, L, W);
  add(-L, -W, -L, W);
  add(L, -W, L, W);
  add(0.0, -W, 0.0, W);
  for (double side : {-1.0, 1.0}) {
    for (const auto& [depth, half_width] :
         {std::pair<double, double>{parameters.goal_area_depth, 0.5 * parameters.goal_area_width},
          {parameters.penalty_area_depth, 0.5 * parameters.penalty_area_width}}) {
      const double x_front = side * (L - depth);
      add(x_front, -half_width, x_front, half_width);
      add(x_front, -half_width, side * L, -half_width);
      add(x_front, half_width, side * L, half_width);
    }
  }

  // Culls for Trace(). A cylinder hit (or a hit on a disc capping it) lies at exactly its radius
  // from the axis; the relative margin 1e-6 covers rounding, so a culled test is one the exact
  // primitive answers with "no hit".
  constexpr double kMargin = 1e-6;
  double post_min = kNoHit;
  for (int i = 0; i < parameters.post_count; ++i) {
    const double r_xz = std::hypot(post_bottom_C_[i].x(), post_bottom_C_[i].z());
    post_min = std::min(post_min, r_xz - parameters.post_radius);
  }
  const double incoming = std::max(0.0, post_min * (1.0 - kMargin));
  incoming_post_cull_radius2_ = parameters.post_count > 0 ? incoming * incoming : kNoHit;
  const double post = parameters.post_radius * (1.0 + kMargin);
  post_cull_radius2_ = post * post;
  const double lens = parameters.lens_radius * (1.0 + kMargin);
  lens_cull_radius2_ = lens * lens;
  R_GC_xy_ = X_GC_.linear().topRows<2>();
  t_GC_xy_ = X_GC_.translation().head<2>();
  R_FG_xy_ = X_FG_.linear().topLeftCorner<2, 2>();
  body_axis_C_ = X_CG_.linear().col(2);
  body_bottom_C_ = X_CG_.translation();
  body_top_C_ = X_CG_ * Eigen::Vector3d(0.0, 0.0, parameters.body_height);
  const Eigen::Vector3d body_axis = body_top_C_ - body_bottom_C_;
  body_along_y_ = body_axis.x() == 0.0 && body_axis.z() == 0.0 && body_axis.y() > 0.0 &&
                  body_axis_C_ == Eigen::Vector3d::UnitY();
  body_length_ = body_axis.norm();
  const double body = parameters.body_radius * (1.0 + kMargin);
  body_cull_radius2_ = body * body;

  for (size_t k = 0; k < segments_F_.size(); ++k) {
    const Eigen::Vector4d& seg = segments_F_[k];
    segment_boxes_F_[k] = Eigen::Vector4d(std::min(seg[0], seg[2]), std::min(seg[1], seg[3]),
                                          std::max(seg[0], seg[2]), std::max(seg[1], seg[3]));
  }
  const double circle_inner =
      std::max(0.0, parameters.centre_circle_radius - 0.5 * parameters.line_width);
  const double circle_outer = parameters.centre_circle_radius + 0.5 * parameters.line_width;
  circle_inner2_ = circle_inner * circle_inner;
  circle_outer2_ = circle_outer * circle_outer;

  // Line grid over the carpet, one cell of slack around it.
  const double half_line = 0.5 * parameters.line_width * (1.0 + kMargin) + 1e-9;
  line_cells_x0_ = -(L + parameters.carpet_border) - kLineCellSize;
  line_cells_y0_ = -(W + parameters.carpet_border) - kLineCellSize;
  line_cells_x_ = static_cast<int>(std::ceil(-2.0 * line_cells_x0_ / kLineCellSize));
  line_cells_y_ = static_cast<int>(std::ceil(-2.0 * line_cells_y0_ / kLineCellSize));
  line_cells_.assign(static_cast<size_t>(line_cells_x_) * line_cells_y_, 0u);
  const double R = parameters.centre_circle_radius;
  for (int iy = 0; iy < line_cells_y_; ++iy) {
    const double y0 = line_cells_y0_ + iy * kLineCellSize, y1 = y0 + kLineCellSize;
    for (int ix = 0; ix < line_cells_x_; ++ix) {
      const double x0 = line_cells_x0_ + ix * kLineCellSize, x1 = x0 + kLineCellSize;
      uint32_t bits = 0;
      for (int k = 0; k < static_cast<int>(segments_F_.size()); ++k) {
        const Eigen::Vector4d& seg = segments_F_[k];
        const double sx0 = std::min(seg[0], seg[2]) - half_line;
        const double sx1 = std::max(seg[0], seg[2]) + half_line;
        const double sy0 = std::min(seg[1], seg[3]) - half_line;
        const double sy1 = std::max(seg[1], seg[3]) + half_line;
        if (sx0 <= x1 && x0 <= sx1 && sy0 <= y1 && y0 <= sy1) bits |= 1u << k;
      }
      // The annulus R ± half_line meets the cell unless the cell is wholly inside or outside it.
      const double nx = std::clamp(0.0, x0, x1), ny = std::clamp(0.0, y0, y1);
      const double near = std::hypot(nx, ny);
      const double far =
          std::hypot(std::max(std::abs(x0), std::abs(x1)), std::max(std::abs(y0), std::abs(y1)));
      if (near <= R + half_line && far >= R - half_line) bits |= 1u << kCircleBit;
      line_cells_[static_cast<size_t>(iy) * line_cells_x_ + ix] = bits;
    }
  }

  // Key of the camera-fixed part (renderer.h): FNV-1a over everything TraceFixed() reads.
  uint64_t key = 0xcbf29ce484222325ULL;
  auto mix = [&key](double x) {
    unsigned char bytes[sizeof x];
    std::memcpy(bytes, &x, sizeof x);
    for (unsigned char b : bytes) key = (key ^ b) * 0x100000001b3ULL;
  };
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) mix(X_CG_.matrix()(r, c));
  }
  mix(parameters.post_count);
  mix(parameters.post_radius);
  mix(parameters.lens_radius);
  mix(parameters.body_radius);
  mix(parameters.body_height);
  mix(parameters.post_radiance);
  mix(parameters.lens_radiance);
  mix(parameters.body_radiance);
  mix(parameters.surroundings_radiance);
  mix(incoming_post_cull_radius2_);
  mix(lens_length_);
  mix(body_length_);
  for (int i = 0; i < parameters.post_count; ++i) {
    for (int j = 0; j < 3; ++j) mix(post_bottom_C_[i][j]);
    mix(post_length_[i]);
  }
  for (int j = 0; j < 3; ++j) mix(lens_bottom_C_[j]);
  camera_fixed_key_ = key == 0 ? 1 : key;
}

bool SoccerFieldScene::OnLine(const Eigen::Vector2d& p_F) const {
  const double half_width = 0.5 * parameters_.line_width;
  // Truncation = floor here: on the carpet the offsets are ≥ one cell (the grid's slack).
  const int ix = std::clamp(static_cast<int>((p_F.x() - line_cells_x0_) * (1.0 / kLineCellSize)), 0,
                            line_cells_x_ - 1);
  const int iy = std::clamp(static_cast<int>((p_F.y() - line_cells_y0_) * (1.0 / kLineCellSize)), 0,
                            line_cells_y_ - 1);
  uint32_t bits = line_cells_[static_cast<size_t>(iy) * line_cells_x_ + ix];
  if (bits == 0) return false;
  // LineDistance()'s test, within rounding (a point within ~1e-16 m of a line's border may go
  // either way), without square roots: the circle by |p|² against (R ± w/2)², and a segment
  // (all are axis-parallel) by the squared distance to it as a degenerate box.
  const double half_width2 = half_width * half_width;
  if ((bits >> kCircleBit) & 1u) {
    const double r2 = p_F.squaredNorm();
    if (r2 >= circle_inner2_ && r2 <= circle_outer2_) return true;
    bits &= ~(1u << kCircleBit);
  }
  while (bits != 0) {
    const int k = __builtin_ctz(bits);
    bits &= bits - 1;
    const Eigen::Vector4d& box = segment_boxes_F_[k];  // (x_min, y_min, x_max, y_max)
    const double ex = std::max({box[0] - p_F.x(), 0.0, p_F.x() - box[2]});
    const double ey = std::max({box[1] - p_F.y(), 0.0, p_F.y() - box[3]});
    if (ex * ex + ey * ey <= half_width2) return true;
  }
  return false;
}

void SoccerFieldScene::PostAxis(int i, Eigen::Vector3d* bottom_C, Eigen::Vector3d* top_C) const {
  *bottom_C = post_bottom_C_.at(i);
  *top_C = post_top_C_.at(i);
}

double SoccerFieldScene::LineDistance(const Eigen::Vector2d& p_F) const {
  double d = std::abs(p_F.norm() - parameters_.centre_circle_radius);
  for (const Eigen::Vector4d& s : segments_F_) d = std::min(d, SegmentDistance(p_F, s));
  return d;
}

FieldPoint SoccerFieldScene::ClassifyGround(const Eigen::Vector2d& p_G_xy) const {
  FieldPoint out;
  out.p_F = (X_FG_ * Eigen::Vector3d(p_G_xy.x(), p_G_xy.y(), 0.0)).head<2>();
  out.line_distance = LineDistance(out.p_F);
  out.on_line = out.line_distance <= 0.5 * parameters_.line_width;
  out.on_carpet =
      std::abs(out.p_F.x()) <= 0.5 * parameters_.field_length + parameters_.carpet_border &&
      std::abs(out.p_F.y()) <= 0.5 * parameters_.field_width + parameters_.carpet_border;
  return out;
}

inline __attribute__((always_inline)) bool SoccerFieldScene::TraceRobot(const Eigen::Vector3d& o,
                                                                        const Eigen::Vector3d& d,
                                                                        double* t_out,
                                                                        int* object_out) const {
  const SoccerFieldSceneParameters& p = parameters_;
  Ray ray_C;  // for the primitives
  ray_C.p_C_O = o;
  ray_C.d_C = d;
  // 1. The path pinhole → mirror point, against the posts (only a mirror point beyond the posts'
  // inner reach from y_C can be hidden: the segment's points are no farther from y_C than it).
  const double o_xz2 = o.x() * o.x() + o.z() * o.z();
  if (o_xz2 >= incoming_post_cull_radius2_ && o_xz2 > 0.0) {
    for (int i = 0; i < p.post_count; ++i) {
      // The segment's xz-projection (0 → o_xz) must pass within the post's radius of its axis.
      // Squared distance of the axis from the segment, written without a division.
      const double cx = post_bottom_C_[i].x(), cz = post_bottom_C_[i].z();
      const double k = cx * o.x() + cz * o.z(), c2 = cx * cx + cz * cz;
      if (k <= 0.0) {
        if (c2 > post_cull_radius2_) continue;
      } else if (k >= o_xz2) {
        const double ex = cx - o.x(), ez = cz - o.z();
        if (ex * ex + ez * ez > post_cull_radius2_) continue;
      } else if (c2 * o_xz2 - k * k > post_cull_radius2_ * o_xz2) {
        continue;
      }
      const double to_mirror = o.norm();
      Ray incoming;
      incoming.p_C_O = Eigen::Vector3d::Zero();
      incoming.d_C = o / to_mirror;
      if (IntersectCylinderAlongY(incoming, post_bottom_C_[i], post_length_[i], p.post_radius) <
          to_mirror) {
        *t_out = 0.0;
        *object_out = kFieldMirrorPost;
        return true;
      }
    }
  }
  // 2. The reflected ray: nearest of posts, lens body, robot body, ground. The exact tests run in
  // the original order (ties keep the first), each only when its cull (header) lets it.
  double best = kNoHit;
  int object = kFieldSurroundings;
  auto consider = [&best, &object](double t, int id) {
    if (t < best) {
      best = t;
      object = id;
    }
  };
  {
    // Posts and lens body are parallel to y_C: closest approach in the xz-plane of the ray
    // q + t d_xz (t ≥ 0) to a post's axis at q = 0 is |q| when b = q·d_xz ≥ 0, else
    // sqrt(|q|² − b²/a), compared below multiplied out by a = |d_xz|² (no division).
    const double ox = o.x(), oz = o.z(), dx = d.x(), dz = d.z();
    const double a = dx * dx + dz * dz, r2 = post_cull_radius2_;
    const int posts = p.post_count;
    // Two posts per instruction (SSE2, the same IEEE operations as the scalar form
    //   miss = b ≥ 0 ? q2 > r2 : q2 a − b² > r2 a,
    // so the same bits; post_x_/post_z_ have room for the pair beyond post_count), both branches
    // evaluated: the sign of b flips from ray to ray and was mispredicted. Issue 5: the posts'
    // culls were a fifth of a frame's instructions.
    unsigned near = 0;
    {
      const __m128d vox = _mm_set1_pd(ox), voz = _mm_set1_pd(oz);
      const __m128d vdx = _mm_set1_pd(dx), vdz = _mm_set1_pd(dz);
      const __m128d va = _mm_set1_pd(a), vr2 = _mm_set1_pd(r2), vr2a = _mm_set1_pd(r2 * a);
      for (int i = 0; i < posts; i += 2) {
        const __m128d qx = _mm_sub_pd(vox, _mm_loadu_pd(&post_x_[i]));
        const __m128d qz = _mm_sub_pd(voz, _mm_loadu_pd(&post_z_[i]));
        const __m128d q2 = _mm_add_pd(_mm_mul_pd(qx, qx), _mm_mul_pd(qz, qz));
        const __m128d b = _mm_add_pd(_mm_mul_pd(qx, vdx), _mm_mul_pd(qz, vdz));
        const __m128d ahead = _mm_cmpge_pd(b, _mm_setzero_pd());
        const __m128d miss_ahead = _mm_cmpgt_pd(q2, vr2);
        const __m128d miss_beside =
            _mm_cmpgt_pd(_mm_sub_pd(_mm_mul_pd(q2, va), _mm_mul_pd(b, b)), vr2a);
        const __m128d miss =
            _mm_or_pd(_mm_and_pd(ahead, miss_ahead), _mm_andnot_pd(ahead, miss_beside));
        near |= static_cast<unsigned>(~_mm_movemask_pd(miss) & 3) << i;
      }
      near &= (1u << posts) - 1u;
    }
    while (near != 0) {
      const int i = __builtin_ctz(near);
      near &= near - 1;
      consider(IntersectCylinderAlongY(ray_C, post_bottom_C_[i], post_length_[i], p.post_radius),
               kFieldMirrorPost);
    }
    // The lens body and its front disc lie at y_C ≤ 0.
    if (MayReachBelow(Eigen::Vector2d(o.x(), o.z()), Eigen::Vector2d(d.x(), d.z()), o.y(), d.y(),
                      0.0, lens_cull_radius2_)) {
      consider(IntersectCylinderAlongY(ray_C, lens_bottom_C_, lens_length_, p.lens_radius),
               kFieldLensBody);
      consider(
          IntersectDisc(ray_C, Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitY(), p.lens_radius),
          kFieldLensBody);
    }
  }
  {
    // The robot body (cylinder and top disc) lies at axial heights ≤ body_height.
    const Eigen::Vector3d oa = o - body_bottom_C_;
    if (body_along_y_) {  // untilted ground: the body's axis is y_C
      if (MayReachBelow(Eigen::Vector2d(oa.x(), oa.z()), Eigen::Vector2d(d.x(), d.z()), oa.y(),
                        d.y(), p.body_height, body_cull_radius2_)) {
        consider(IntersectCylinderAlongY(ray_C, body_bottom_C_, body_length_, p.body_radius),
                 kFieldRobotBody);
        consider(IntersectDisc(ray_C, body_top_C_, body_axis_C_, p.body_radius), kFieldRobotBody);
      }
    } else {
      const double h0 = oa.dot(body_axis_C_), dw = d.dot(body_axis_C_);
      if (MayReachBelow(Eigen::Vector3d(oa - h0 * body_axis_C_),
                        Eigen::Vector3d(d - dw * body_axis_C_), h0, dw, p.body_height,
                        body_cull_radius2_)) {
        consider(IntersectCylinder(ray_C, body_bottom_C_, body_top_C_, p.body_radius),
                 kFieldRobotBody);
        consider(IntersectDisc(ray_C, body_top_C_, body_axis_C_, p.body_radius), kFieldRobotBody);
      }
    }
  }
  *t_out = best;
  *object_out = object;
  return false;
}

inline __attribute__((always_inline)) CameraFixedHit SoccerFieldScene::TraceFixed(
    const Eigen::Vector3d& o, const Eigen::Vector3d& d) const {
  const SoccerFieldSceneParameters& p = parameters_;
  // IntersectPlane(ray, body_bottom_C_, body_axis_C_), inlined (the same expressions) and first,
  // so that its division overlaps the robot's tests.
  double t_ground = kNoHit;
  {
    const double denom = body_axis_C_.dot(d);
    if (!(std::abs(denom) < 1e-15)) {
      const double t = body_axis_C_.dot(body_bottom_C_ - o) / denom;
      if (t > 1e-9) t_ground = t;
    }
  }
  CameraFixedHit out;
  out.kind = CameraFixedHit::kConstant;
  double best = kNoHit;
  int object = kFieldSurroundings;
  if (TraceRobot(o, d, &best, &object)) {  // a post hides the mirror point
    out.hit = Hit{p.post_radiance, kFieldMirrorPost, 0.0};
    return out;
  }
  // The ground last: ties keep the robot's hit, as in the original order of tests.
  if (t_ground < best) {
    // The ground point in G (x and y only; Eigen's Isometry product goes through 4×4).
    const Eigen::Vector3d p_C = o + t_ground * d;
    out.kind = CameraFixedHit::kSurface;
    out.surface = Eigen::Vector2d(R_GC_xy_.row(0).dot(p_C) + t_GC_xy_.x(),
                                  R_GC_xy_.row(1).dot(p_C) + t_GC_xy_.y());
    out.hit.depth = t_ground;
    return out;
  }
  out.hit.depth = best;
  out.hit.object = object;
  switch (object) {
    case kFieldMirrorPost:
      out.hit.radiance = p.post_radiance;
      break;
    case kFieldLensBody:
      out.hit.radiance = p.lens_radiance;
      break;
    case kFieldRobotBody:
      out.hit.radiance = p.body_radiance;
      break;
    default:
      out.hit.radiance = p.surroundings_radiance;
      break;
  }
  return out;
}

inline __attribute__((always_inline)) void SoccerFieldScene::ShadeGround(const Eigen::Vector2d& p_G,
                                                                         Hit* hit) const {
  // As ClassifyGround(), with the line distances only for the lines near the point, and G → F
  // written out.
  const SoccerFieldSceneParameters& p = parameters_;
  const double x_G = p_G.x(), y_G = p_G.y();
  const Eigen::Vector2d p_F(R_FG_xy_(0, 0) * x_G + R_FG_xy_(0, 1) * y_G + p.robot_x,
                            R_FG_xy_(1, 0) * x_G + R_FG_xy_(1, 1) * y_G + p.robot_y);
  const bool on_carpet = std::abs(p_F.x()) <= 0.5 * p.field_length + p.carpet_border &&
                         std::abs(p_F.y()) <= 0.5 * p.field_width + p.carpet_border;
  if (!on_carpet) {
    hit->object = kFieldFloor;
    hit->radiance = p.floor_radiance;
  } else if (OnLine(p_F)) {
    hit->object = kFieldLine;
    hit->radiance = p.line_radiance;
  } else {
    hit->object = kFieldCarpet;
    hit->radiance = p.carpet_radiance;
  }
}

Hit SoccerFieldScene::Trace(const Ray& ray_C) const {
  const CameraFixedHit fixed = TraceFixed(ray_C.p_C_O, ray_C.d_C);
  Hit hit = fixed.hit;
  if (fixed.kind == CameraFixedHit::kSurface) ShadeGround(fixed.surface, &hit);
  return hit;
}

// Trace() inlined into one loop over the batch (no virtual call or Ray copy per ray). The scene
// answers no ray kWorld, so the renderer's flags are never set for it.
void SoccerFieldScene::TraceBatch(const RayBatch& rays, Hit* hits) const {
  for (int k = 0; k < rays.count; ++k) {
    const CameraFixedHit fixed =
        TraceFixed(rays.origins[rays.shared_origin ? 0 : k], rays.directions[k]);
    hits[k] = fixed.hit;
    if (fixed.kind == CameraFixedHit::kSurface) ShadeGround(fixed.surface, &hits[k]);
  }
}

void SoccerFieldScene::TraceCameraFixed(const RayBatch& rays, CameraFixedHit* out) const {
  for (int k = 0; k < rays.count; ++k) {
    out[k] = TraceFixed(rays.origins[rays.shared_origin ? 0 : k], rays.directions[k]);
  }
}

void SoccerFieldScene::ShadeSurface(const Eigen::Vector2d* points_G, int count, Hit* hits) const {
  for (int k = 0; k < count; ++k) ShadeGround(points_G[k], &hits[k]);
}

}  // namespace kinevis::vision::render
