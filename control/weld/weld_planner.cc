#include "control/weld/weld_planner.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <numeric>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <stdexcept>

namespace kinevis::control {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
// Grids larger than this are refused as data (the map spans more than one repair patch).
constexpr size_t kMaxGridCells = 40'000'000;

std::string Mm(double m, int precision = 2) {
  std::ostringstream o;
  o.setf(std::ios::fixed);
  o.precision(precision);
  o << m * 1e3;
  return o.str();
}

std::string MmPoint(const Eigen::Vector3d& p) {
  return "(" + Mm(p.x(), 1) + ", " + Mm(p.y(), 1) + ", " + Mm(p.z(), 1) + ") mm";
}

// A bead's geometry before IK: the pass polyline in R and its kind.
struct BeadPath {
  BeadKind kind = BeadKind::kRaster;
  std::vector<Eigen::Vector2d> uv;  // the weld part, in order
  bool closed = false;
};

// Resamples a polyline so consecutive points are at most `spacing` apart (keeps the vertices).
std::vector<Eigen::Vector2d> Densify(const std::vector<Eigen::Vector2d>& in, double spacing) {
  std::vector<Eigen::Vector2d> out;
  if (in.empty()) return out;
  out.push_back(in.front());
  for (size_t i = 1; i < in.size(); ++i) {
    const Eigen::Vector2d d = in[i] - in[i - 1];
    const int n = std::max(1, static_cast<int>(std::ceil(d.norm() / spacing - 1e-9)));
    for (int k = 1; k <= n; ++k) out.push_back(in[i - 1] + d * (static_cast<double>(k) / n));
  }
  return out;
}

double PolylineLength(const std::vector<Eigen::Vector2d>& p) {
  double l = 0.0;
  for (size_t i = 1; i < p.size(); ++i) l += (p[i] - p[i - 1]).norm();
  return l;
}

// The point at arc length s along a closed loop (s in [0, length)).
Eigen::Vector2d AlongLoop(const std::vector<Eigen::Vector2d>& loop, double s) {
  const double L = PolylineLength(loop);
  s = std::fmod(std::fmod(s, L) + L, L);
  for (size_t i = 1; i < loop.size(); ++i) {
    const double seg = (loop[i] - loop[i - 1]).norm();
    if (s <= seg && seg > 0) return loop[i - 1] + (loop[i] - loop[i - 1]) * (s / seg);
    s -= seg;
  }
  return loop.back();
}

double SegmentDistance(const Eigen::Vector2d& p, const Eigen::Vector2d& a,
                       const Eigen::Vector2d& b) {
  const Eigen::Vector2d ab = b - a;
  const double l2 = ab.squaredNorm();
  const double t = l2 > 0 ? std::clamp((p - a).dot(ab) / l2, 0.0, 1.0) : 0.0;
  return (a + t * ab - p).norm();
}

// Marks the grid cells whose centre lies within r of segment ab (in R).
void MarkCapsule(const DepthGrid& g, const Eigen::Vector2d& a, const Eigen::Vector2d& b, double r,
                 std::vector<char>* mark) {
  const int i0 =
      std::max(0, static_cast<int>(std::floor((std::min(a.x(), b.x()) - r - g.u0) / g.cell)));
  const int i1 = std::min(
      g.nu - 1, static_cast<int>(std::floor((std::max(a.x(), b.x()) + r - g.u0) / g.cell)));
  const int j0 =
      std::max(0, static_cast<int>(std::floor((std::min(a.y(), b.y()) - r - g.v0) / g.cell)));
  const int j1 = std::min(
      g.nv - 1, static_cast<int>(std::floor((std::max(a.y(), b.y()) + r - g.v0) / g.cell)));
  for (int j = j0; j <= j1; ++j) {
    for (int i = i0; i <= i1; ++i) {
      if (SegmentDistance(g.Centre(i, j), a, b) <= r) (*mark)[g.index(i, j)] = 1;
    }
  }
}

// Raster / zig-zag passes over a footprint (cell centres in R), at angle phi, step-over s.
std::vector<BeadPath> RasterPasses(const std::vector<Eigen::Vector2d>& cells, double cell,
                                   double phi, double step, double spacing, BeadPattern pattern) {
  const Eigen::Vector2d ea(std::cos(phi), std::sin(phi)), ec(-std::sin(phi), std::cos(phi));
  double cmin = 1e300, cmax = -1e300;
  for (const auto& p : cells) {
    cmin = std::min(cmin, p.dot(ec));
    cmax = std::max(cmax, p.dot(ec));
  }
  cmin -= 0.5 * cell;
  cmax += 0.5 * cell;
  const int lines = std::max(1, static_cast<int>(std::ceil((cmax - cmin) / step - 1e-9)));
  // Centre the set of lines on the footprint's extent.
  const double c_first = 0.5 * (cmin + cmax) - 0.5 * (lines - 1) * step;
  std::vector<std::vector<double>> band(lines);
  for (const auto& p : cells) {
    const int j = std::clamp(
        static_cast<int>(std::floor((p.dot(ec) - (c_first - 0.5 * step)) / step)), 0, lines - 1);
    band[j].push_back(p.dot(ea));
  }
  // Intervals along each line: cells of a band closer than 2 cells merge into one pass.
  const double gap = 2.0 * cell;
  std::vector<std::vector<std::pair<double, double>>> intervals(lines);
  for (int j = 0; j < lines; ++j) {
    auto& b = band[j];
    std::sort(b.begin(), b.end());
    for (size_t k = 0; k < b.size(); ++k) {
      if (k == 0 || b[k] - b[k - 1] > gap) {
        intervals[j].push_back({b[k] - 0.5 * cell, b[k] + 0.5 * cell});
      } else {
        intervals[j].back().second = b[k] + 0.5 * cell;
      }
    }
  }
  auto point = [&](double a, double c) -> Eigen::Vector2d { return a * ea + c * ec; };
  std::vector<BeadPath> out;
  bool forward = true;
  BeadPath chain;
  chain.kind = BeadKind::kZigZag;
  for (int j = 0; j < lines; ++j) {
    const double c = c_first + j * step;
    for (const auto& iv : intervals[j]) {
      const double a0 = forward ? iv.first : iv.second, a1 = forward ? iv.second : iv.first;
      if (pattern == BeadPattern::kRaster) {
        BeadPath b;
        b.kind = BeadKind::kRaster;
        b.uv = Densify({point(a0, c), point(a1, c)}, spacing);
        out.push_back(std::move(b));
        forward = !forward;
        continue;
      }
      // Zig-zag: continue the chain when this line has one interval, the previous line had one
      // and they overlap along the pass (the turn then stays over the footprint).
      const bool single = intervals[j].size() == 1;
      bool joined = false;
      if (!chain.uv.empty() && single && j > 0 && intervals[j - 1].size() == 1) {
        const auto& prev = intervals[j - 1].front();
        if (std::min(prev.second, iv.second) > std::max(prev.first, iv.first)) joined = true;
      }
      if (!joined && !chain.uv.empty()) {
        out.push_back(chain);
        chain.uv.clear();
      }
      std::vector<Eigen::Vector2d> line = Densify({point(a0, c), point(a1, c)}, spacing);
      if (joined) {
        std::vector<Eigen::Vector2d> turn = Densify({chain.uv.back(), line.front()}, spacing);
        chain.uv.insert(chain.uv.end(), turn.begin() + 1, turn.end());
        chain.uv.insert(chain.uv.end(), line.begin() + 1, line.end());
      } else {
        chain.uv = line;
      }
      forward = !forward;
      if (!single) {
        out.push_back(chain);
        chain.uv.clear();
      }
    }
  }
  if (!chain.uv.empty()) out.push_back(chain);
  return out;
}

// Boundary passes of a footprint mask (local ROI), inset by the bead's half width.
std::vector<BeadPath> ContourPasses(const cv::Mat& mask, const DepthGrid& g, int i_off, int j_off,
                                    double half_width, double spacing, double min_length) {
  std::vector<BeadPath> out;
  const int r = static_cast<int>(std::lround(half_width / g.cell));
  cv::Mat inset;
  if (r > 0) {
    const cv::Mat k = cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(2 * r + 1, 2 * r + 1));
    cv::erode(mask, inset, k, cv::Point(-1, -1), 1, cv::BORDER_CONSTANT, cv::Scalar(0));
  } else {
    inset = mask.clone();
  }
  std::vector<std::vector<cv::Point>> contours;
  cv::findContours(inset, contours, cv::RETR_LIST, cv::CHAIN_APPROX_NONE);
  for (const auto& c : contours) {
    if (c.size() < 8) continue;
    // Moving average over ±half a bead width smooths the pixel staircase.
    const int n = static_cast<int>(c.size());
    const int win = std::clamp(r, 1, n / 4);
    std::vector<Eigen::Vector2d> loop;
    for (int k = 0; k < n; k += std::max(1, win / 2)) {
      Eigen::Vector2d m = Eigen::Vector2d::Zero();
      for (int d = -win; d <= win; ++d) {
        const cv::Point& q = c[((k + d) % n + n) % n];
        m += g.Centre(q.x + i_off, q.y + j_off);
      }
      loop.push_back(m / (2 * win + 1));
    }
    loop.push_back(loop.front());
    if (PolylineLength(loop) < min_length) continue;
    BeadPath b;
    b.kind = BeadKind::kContour;
    b.closed = true;
    b.uv = Densify(loop, spacing);
    out.push_back(std::move(b));
  }
  return out;
}

// Endpoints of a pass, for ordering.
struct OrderNode {
  Eigen::Vector3d start, end;
  bool reversible = true;
};

// Nearest neighbour from `from`, then 2-opt (segment reversal flips the passes in it). Returns the
// order and whether each pass is welded reversed.
void OrderPasses(const std::vector<OrderNode>& nodes, const Eigen::Vector3d& from, bool reversal,
                 std::vector<int>* order, std::vector<char>* reversed) {
  const int n = static_cast<int>(nodes.size());
  order->clear();
  reversed->assign(n, 0);
  std::vector<char> used(n, 0);
  Eigen::Vector3d at = from;
  for (int k = 0; k < n; ++k) {
    int best = -1;
    bool best_rev = false;
    double best_d = 1e300;
    for (int i = 0; i < n; ++i) {
      if (used[i]) continue;
      const double d = (nodes[i].start - at).norm();
      if (d < best_d) best_d = d, best = i, best_rev = false;
      if (reversal && nodes[i].reversible) {
        const double dr = (nodes[i].end - at).norm();
        if (dr < best_d) best_d = dr, best = i, best_rev = true;
      }
    }
    used[best] = 1;
    order->push_back(best);
    (*reversed)[best] = best_rev;
    at = best_rev ? nodes[best].start : nodes[best].end;
  }
  if (!reversal) return;
  for (const auto& nd : nodes) {
    if (!nd.reversible) return;  // 2-opt reverses passes: only when every pass may be reversed
  }
  auto s = [&](int k) {
    const int i = (*order)[k];
    return (*reversed)[i] ? nodes[i].end : nodes[i].start;
  };
  auto e = [&](int k) {
    const int i = (*order)[k];
    return (*reversed)[i] ? nodes[i].start : nodes[i].end;
  };
  for (int pass = 0; pass < 50; ++pass) {
    bool improved = false;
    for (int a = 0; a < n - 1; ++a) {
      for (int b = a + 1; b < n; ++b) {
        // Reverse order[a..b]: the link into a and out of b change.
        const Eigen::Vector3d before = a == 0 ? from : e(a - 1);
        double old_cost = (s(a) - before).norm();
        double new_cost = (e(b) - before).norm();
        if (b + 1 < n) {
          old_cost += (s(b + 1) - e(b)).norm();
          new_cost += (s(b + 1) - s(a)).norm();
        }
        if (new_cost < old_cost - 1e-9) {
          std::reverse(order->begin() + a, order->begin() + b + 1);
          for (int k = a; k <= b; ++k) (*reversed)[(*order)[k]] ^= 1;
          improved = true;
        }
      }
    }
    if (!improved) break;
  }
}

void CheckModel(const robots::Weld5Model& model, const WeldPlanOptions& o) {
  std::ostringstream bad;
  const std::string model_problems = model.Validate();
  if (!model_problems.empty()) bad << "model: " << model_problems;
  for (int i = 0; i < robots::kWeld5Joints; ++i) {
    const char* name = robots::Weld5JointName(i);
    if (!(o.q_start(i) >= model.q_min(i) && o.q_start(i) <= model.q_max(i))) {
      bad << (bad.tellp() > 0 ? "; " : "") << "q_start " << name << " = " << o.q_start(i)
          << " outside [" << model.q_min(i) << ", " << model.q_max(i) << "]";
    }
  }
  if (bad.tellp() > 0) throw std::invalid_argument("PlanWeldRepair: " + bad.str());
}

}  // namespace

const char* ToString(BeadPattern pattern) {
  return pattern == BeadPattern::kRaster ? "raster" : "zigzag";
}

const char* ToString(WeldPointKind kind) {
  switch (kind) {
    case WeldPointKind::kTransit:
      return "transit";
    case WeldPointKind::kApproach:
      return "approach";
    case WeldPointKind::kLeadIn:
      return "lead_in";
    case WeldPointKind::kWeld:
      return "weld";
    case WeldPointKind::kLeadOut:
      return "lead_out";
    case WeldPointKind::kRetract:
      return "retract";
  }
  return "?";
}

const char* ToString(BeadKind kind) {
  switch (kind) {
    case BeadKind::kRaster:
      return "raster";
    case BeadKind::kZigZag:
      return "zigzag";
    case BeadKind::kContour:
      return "contour";
  }
  return "?";
}

const char* ToString(WeldPlanStatus status) {
  switch (status) {
    case WeldPlanStatus::kPlanned:
      return "planned";
    case WeldPlanStatus::kPartial:
      return "partial";
    case WeldPlanStatus::kNothingToRepair:
      return "nothing to repair";
    case WeldPlanStatus::kFailed:
      return "failed";
  }
  return "?";
}

std::string WeldPlanOptions::Validate() const {
  std::ostringstream bad;
  auto sep = [&]() -> std::ostringstream& {
    if (bad.tellp() > 0) bad << "; ";
    return bad;
  };
  // Lengths are given in m and judged against ranges in mm, the unit a welder reads.
  auto length = [&](const char* name, double v, double lo_mm, double hi_mm) {
    if (!(v >= lo_mm * 1e-3 && v <= hi_mm * 1e-3)) {
      sep() << name << " = " << v << " m (" << lo_mm << ".." << hi_mm << " mm)";
    }
  };
  auto range = [&](const char* name, double v, double lo, double hi, const char* unit) {
    if (!(v >= lo && v <= hi))
      sep() << name << " = " << v << " " << unit << " (" << lo << ".." << hi << ")";
  };
  if (const std::string r = reference.Validate(); !r.empty()) sep() << "reference: " << r;
  length("grid_cell", grid_cell, 0.05, 5.0);
  length("depth_threshold", depth_threshold, 0.05, 10.0);
  if (!(min_region_area >= 0.0) || !std::isfinite(min_region_area)) {
    sep() << "min_region_area = " << min_region_area << " m² (>= 0)";
  }
  length("bead_width", bead_width, 1.0, 30.0);
  range("overlap", overlap, 0.0, 0.8, "");
  length("layer_height", layer_height, 0.2, 10.0);
  length("margin", margin, 0.0, 50.0);
  if (std::isinf(raster_angle))
    sep() << "raster_angle = " << raster_angle << " rad (finite or NaN)";
  length("stand_off", stand_off, 3.0, 40.0);
  range("travel_speed", travel_speed, 1e-3, 30e-3, "m/s");
  range("air_speed", air_speed, 5e-3, 0.5, "m/s");
  length("clearance", clearance, 2.0, 200.0);
  length("lead_in", lead_in, 0.0, 30.0);
  length("lead_out", lead_out, 0.0, 30.0);
  length("point_spacing", point_spacing, 0.2, 10.0);
  length("transit_spacing", transit_spacing, 1.0, 100.0);
  if (!(process.wire_diameter > 0.0 && process.wire_diameter <= 3e-3)) {
    sep() << "process.wire_diameter = " << process.wire_diameter << " m (0..3 mm)";
  }
  if (!(process.wire_feed_speed > 0.0) || !std::isfinite(process.wire_feed_speed)) {
    sep() << "process.wire_feed_speed = " << process.wire_feed_speed << " m/s (> 0)";
  }
  if (!(process.current > 0.0) || !std::isfinite(process.current)) {
    sep() << "process.current = " << process.current << " A (> 0)";
  }
  if (!(process.voltage > 0.0) || !std::isfinite(process.voltage)) {
    sep() << "process.voltage = " << process.voltage << " V (> 0)";
  }
  range("process.deposition_efficiency", process.deposition_efficiency, 1e-3, 1.0, "");
  if (!(ik.position_tolerance > 0.0) || !(ik.axis_tolerance > 0.0) || ik.max_iterations < 1 ||
      !(ik.max_step > 0.0) || !(ik.damping >= 0.0)) {
    sep() << "ik: position_tolerance = " << ik.position_tolerance
          << " m, axis_tolerance = " << ik.axis_tolerance
          << " rad, max_iterations = " << ik.max_iterations << ", max_step = " << ik.max_step
          << ", damping = " << ik.damping << " (all > 0, damping >= 0)";
  }
  range("ik.max_tilt", ik.max_tilt, 0.0, 30.0 * M_PI / 180.0, "rad (0..30 deg)");
  if (!q_start.allFinite()) sep() << "q_start not finite";
  range("air_joint_speed_fraction", air_joint_speed_fraction, 1e-3, 1.0, "");
  range("max_segment_duration", max_segment_duration, 0.01, 60.0, "s");
  if (!(max_interpolation_error > 0.0)) {
    sep() << "max_interpolation_error = " << max_interpolation_error << " m (> 0)";
  }
  if (bead_width * (1.0 - overlap) < grid_cell) {
    sep() << "step-over (1 - overlap) * bead_width = " << bead_width * (1.0 - overlap)
          << " m is below grid_cell = " << grid_cell << " m";
  }
  return bad.str();
}

double DepthGrid::SubstrateDepth(double u, double v) const {
  if (nu == 0 || nv == 0) return 0.0;
  const double x = (u - u0) / cell - 0.5, y = (v - v0) / cell - 0.5;
  const int i = static_cast<int>(std::floor(x)), j = static_cast<int>(std::floor(y));
  const double fx = x - i, fy = y - j;
  double sum = 0.0, wsum = 0.0;
  for (int dj = 0; dj <= 1; ++dj) {
    for (int di = 0; di <= 1; ++di) {
      const int ii = i + di, jj = j + dj;
      const double w = (di ? fx : 1.0 - fx) * (dj ? fy : 1.0 - fy);
      double d = 0.0;
      if (ii >= 0 && jj >= 0 && ii < nu && jj < nv) {
        const float s = smoothed[index(ii, jj)];
        if (std::isfinite(s)) d = s;
      }
      sum += w * d;
      wsum += w;
    }
  }
  return wsum > 0 ? sum / wsum : 0.0;
}

namespace {

// Builds the depth grid from every finite point.
bool BuildGrid(const std::vector<Eigen::Vector3d>& p_0, const ReferenceSurface& ref, double cell,
               DepthGrid* g, std::string* why) {
  const Eigen::Isometry3d X_R0 = ref.X_0R.inverse();
  std::vector<Eigen::Vector3f> q;  // u, v, depth
  q.reserve(p_0.size());
  double umin = 1e300, umax = -1e300, vmin = 1e300, vmax = -1e300;
  for (const auto& p : p_0) {
    if (!p.allFinite()) continue;
    const Eigen::Vector3d r = X_R0 * p;
    const double d = ref.Height(r.x(), r.y()) - r.z();
    q.emplace_back(static_cast<float>(r.x()), static_cast<float>(r.y()), static_cast<float>(d));
    umin = std::min(umin, r.x()), umax = std::max(umax, r.x());
    vmin = std::min(vmin, r.y()), vmax = std::max(vmax, r.y());
  }
  g->cell = cell;
  g->u0 = umin;
  g->v0 = vmin;
  const double nu = std::floor((umax - umin) / cell) + 1, nv = std::floor((vmax - vmin) / cell) + 1;
  if (nu * nv > static_cast<double>(kMaxGridCells)) {
    *why = "the map spans " + Mm(umax - umin, 0) + " x " + Mm(vmax - vmin, 0) +
           " mm: " + std::to_string(static_cast<long long>(nu * nv)) + " cells of " + Mm(cell) +
           " mm exceed " + std::to_string(kMaxGridCells) + " (increase grid_cell or split the map)";
    return false;
  }
  g->nu = static_cast<int>(nu);
  g->nv = static_cast<int>(nv);
  const size_t N = static_cast<size_t>(g->nu) * g->nv;
  g->count.assign(N, 0);
  std::vector<int> cell_of(q.size());
  for (size_t k = 0; k < q.size(); ++k) {
    const int i = std::min(g->nu - 1, static_cast<int>((q[k].x() - umin) / cell));
    const int j = std::min(g->nv - 1, static_cast<int>((q[k].y() - vmin) / cell));
    cell_of[k] = g->index(i, j);
    ++g->count[cell_of[k]];
  }
  std::vector<size_t> start(N + 1, 0);
  for (size_t c = 0; c < N; ++c) start[c + 1] = start[c] + g->count[c];
  std::vector<float> depth_sorted(q.size());
  std::vector<size_t> fill(start.begin(), start.end() - 1);
  for (size_t k = 0; k < q.size(); ++k) depth_sorted[fill[cell_of[k]]++] = q[k].z();
  g->depth.assign(N, std::numeric_limits<float>::quiet_NaN());
  for (size_t c = 0; c < N; ++c) {
    if (g->count[c] == 0) continue;
    auto b = depth_sorted.begin() + static_cast<std::ptrdiff_t>(start[c]);
    auto e = depth_sorted.begin() + static_cast<std::ptrdiff_t>(start[c + 1]);
    // The lower median: with an even count and one outlier the shallower reading wins.
    auto mid = b + (e - b - 1) / 2;
    std::nth_element(b, mid, e);
    g->depth[c] = *mid;
  }
  g->smoothed.assign(N, std::numeric_limits<float>::quiet_NaN());
  for (int j = 0; j < g->nv; ++j) {
    for (int i = 0; i < g->nu; ++i) {
      double s = 0.0;
      int n = 0;
      for (int dj = -1; dj <= 1; ++dj) {
        for (int di = -1; di <= 1; ++di) {
          const int ii = i + di, jj = j + dj;
          if (ii < 0 || jj < 0 || ii >= g->nu || jj >= g->nv) continue;
          const float d = g->depth[g->index(ii, jj)];
          if (std::isfinite(d)) s += d, ++n;
        }
      }
      if (n > 0) g->smoothed[g->index(i, j)] = static_cast<float>(s / n);
    }
  }
  g->region.assign(N, -1);
  return true;
}

struct Component {
  std::vector<int> cells;
  bool edge = false;
};

std::vector<Component> DamagedComponents(const DepthGrid& g, double threshold) {
  std::vector<Component> out;
  std::vector<char> seen(g.depth.size(), 0);
  std::vector<int> stack;
  for (int c0 = 0; c0 < static_cast<int>(g.depth.size()); ++c0) {
    if (seen[c0] || !(g.depth[c0] > threshold)) continue;
    Component comp;
    stack.assign(1, c0);
    seen[c0] = 1;
    while (!stack.empty()) {
      const int c = stack.back();
      stack.pop_back();
      comp.cells.push_back(c);
      const int i = c % g.nu, j = c / g.nu;
      for (int dj = -1; dj <= 1; ++dj) {
        for (int di = -1; di <= 1; ++di) {
          if (di == 0 && dj == 0) continue;
          const int ii = i + di, jj = j + dj;
          if (ii < 0 || jj < 0 || ii >= g.nu || jj >= g.nv) {
            comp.edge = true;
            continue;
          }
          const int n = g.index(ii, jj);
          if (!std::isfinite(g.depth[n])) comp.edge = true;  // next to a hole in the scan
          if (seen[n] || !(g.depth[n] > threshold)) continue;
          seen[n] = 1;
          stack.push_back(n);
        }
      }
    }
    out.push_back(std::move(comp));
  }
  return out;
}

// A planned point from its place in R.
WeldPoint MakePoint(const ReferenceSurface& ref, const Eigen::Vector2d& uv, double depth,
                    double height, WeldPointKind kind, bool arc_on, double speed) {
  WeldPoint p;
  p.kind = kind;
  p.uv_R = uv;
  p.depth = depth;
  const Eigen::Vector3d P = ref.Point0(uv.x(), uv.y());
  const Eigen::Vector3d n = ref.Normal0(uv.x(), uv.y());
  p.p_0S = P - depth * n;
  p.p_0T = P + (height - depth) * n;
  p.u_0T = -n;
  p.u_0T_achieved = -n;
  p.stand_off = height;
  p.arc_on = arc_on;
  p.speed = speed;
  return p;
}

void SolveIk(const robots::Weld5Model& model, const TorchIkOptions& o,
             const robots::Vector5d& guess, WeldPoint* p) {
  const TorchIkResult r = SolveTorchIk(model, p->p_0S, p->u_0T, p->stand_off, guess, o);
  p->ik = r.status;
  p->q = r.q;
  p->ik_position_error = r.position_error;
  p->limiting_joint = r.limiting_joint >= 0 ? robots::Weld5JointName(r.limiting_joint) : "";
  if (r.converged()) {
    p->p_0T = r.p_0T;
    p->u_0T_achieved = r.u_0T;
    p->tilt = r.tilt;
  }
}

}  // namespace

WeldPlan PlanWeldRepair(const WeldMap& map, const robots::Weld5Model& model,
                        const WeldPlanOptions& options) {
  if (const std::string bad = options.Validate(); !bad.empty()) {
    throw std::invalid_argument("PlanWeldRepair: bad options: " + bad);
  }
  if (!map.n_0.empty() && map.n_0.size() != map.p_0.size()) {
    throw std::invalid_argument("PlanWeldRepair: map has " + std::to_string(map.n_0.size()) +
                                " normals for " + std::to_string(map.p_0.size()) +
                                " points (give none or one per point)");
  }
  CheckModel(model, options);
  const WeldPlanOptions& o = options;
  WeldPlan plan;
  plan.options = o;
  plan.model = model;
  WeldPlanSummary& sum = plan.summary;
  sum.map_points = map.p_0.size();

  size_t finite = 0;
  for (const auto& p : map.p_0) finite += p.allFinite() ? 1 : 0;
  if (finite == 0) {
    sum.status = WeldPlanStatus::kNothingToRepair;
    sum.message = "the map has no (finite) points: nothing to repair";
    return plan;
  }
  plan.reference = FitReferenceSurface(map.p_0, map.n_0, o.reference);
  for (const auto& w : plan.reference.warnings) sum.warnings.push_back("reference: " + w);
  if (!plan.reference.ok()) {
    sum.status = WeldPlanStatus::kFailed;
    sum.message = std::string("no reference surface: ") + ToString(plan.reference.status) + ": " +
                  plan.reference.message;
    return plan;
  }
  const ReferenceSurface& ref = plan.reference.surface;
  std::string why;
  if (!BuildGrid(map.p_0, ref, o.grid_cell, &plan.grid, &why)) {
    sum.status = WeldPlanStatus::kFailed;
    sum.message = why;
    return plan;
  }
  DepthGrid& g = plan.grid;
  const double cell_area = g.cell * g.cell;

  // Damaged regions.
  for (Component& comp : DamagedComponents(g, o.depth_threshold)) {
    double max_d = 0.0, sum_d = 0.0;
    Eigen::Vector2d c = Eigen::Vector2d::Zero(), deepest = Eigen::Vector2d::Zero();
    for (int k : comp.cells) {
      const double d = g.depth[k];
      const Eigen::Vector2d uv = g.Centre(k % g.nu, k / g.nu);
      c += uv;
      sum_d += d;
      if (d > max_d) max_d = d, deepest = uv;
    }
    c /= static_cast<double>(comp.cells.size());
    const double area = comp.cells.size() * cell_area;
    if (area < o.min_region_area) {
      RejectedRegion r;
      r.cells = static_cast<int>(comp.cells.size());
      r.area = area;
      r.max_depth = max_d;
      r.centroid_0 = ref.Point0(c.x(), c.y());
      std::ostringstream m;
      m << "area " << area * 1e6 << " mm² < min_region_area " << o.min_region_area * 1e6 << " mm²";
      r.reason = m.str();
      plan.rejected.push_back(std::move(r));
      continue;
    }
    WeldRegionPlan rp;
    rp.region.id = static_cast<int>(plan.regions.size());
    rp.region.cells = static_cast<int>(comp.cells.size());
    rp.region.area = area;
    rp.region.max_depth = max_d;
    rp.region.mean_depth = sum_d / comp.cells.size();
    rp.region.volume = sum_d * cell_area;
    rp.region.centroid_0 = ref.Point0(c.x(), c.y());
    rp.region.deepest_uv = deepest;
    rp.region.touches_map_edge = comp.edge;
    for (int k : comp.cells) g.region[k] = rp.region.id;
    if (comp.edge) {
      sum.warnings.push_back("region " + std::to_string(rp.region.id) + " at " +
                             MmPoint(rp.region.centroid_0) +
                             " touches the edge of the scan or a hole in it: the damage may go on "
                             "beyond what was scanned");
    }
    plan.regions.push_back(std::move(rp));
  }
  sum.regions = static_cast<int>(plan.regions.size());
  sum.rejected_regions = static_cast<int>(plan.rejected.size());
  for (const auto& r : plan.regions) sum.damaged_area += r.region.area;
  if (plan.regions.empty()) {
    sum.status = WeldPlanStatus::kNothingToRepair;
    std::ostringstream m;
    m << "no damage deeper than " << Mm(o.depth_threshold) << " mm";
    if (!plan.rejected.empty())
      m << " in a region of at least " << o.min_region_area * 1e6 << " mm² ("
        << plan.rejected.size() << " smaller ones rejected)";
    m << ": nothing to repair";
    sum.message = m.str();
    return plan;
  }

  // Region order: nearest neighbour from the start pose's torch tip.
  robots::Weld5Data fk;
  robots::Weld5ForwardKinematics(model, o.q_start, &fk);
  {
    std::vector<WeldRegionPlan> ordered;
    std::vector<char> used(plan.regions.size(), 0);
    Eigen::Vector3d at = fk.p_0T;
    for (size_t k = 0; k < plan.regions.size(); ++k) {
      size_t best = 0;
      double bd = 1e300;
      for (size_t i = 0; i < plan.regions.size(); ++i) {
        const double d = (plan.regions[i].region.centroid_0 - at).norm();
        if (!used[i] && d < bd) bd = d, best = i;
      }
      used[best] = 1;
      at = plan.regions[best].region.centroid_0;
      ordered.push_back(std::move(plan.regions[best]));
    }
    plan.regions = std::move(ordered);
  }

  // Layers and passes.
  const double step = (1.0 - o.overlap) * o.bead_width;
  const int margin_cells = static_cast<int>(std::ceil(o.margin / g.cell - 1e-9));
  Eigen::Vector3d at = fk.p_0T;
  int bead_id = 0;
  for (WeldRegionPlan& rp : plan.regions) {
    const int id = rp.region.id;
    int imin = g.nu, imax = -1, jmin = g.nv, jmax = -1;
    double max_s = 0.0;
    for (int c = 0; c < static_cast<int>(g.region.size()); ++c) {
      if (g.region[c] != id) continue;
      imin = std::min(imin, c % g.nu), imax = std::max(imax, c % g.nu);
      jmin = std::min(jmin, c / g.nu), jmax = std::max(jmax, c / g.nu);
      if (std::isfinite(g.smoothed[c])) max_s = std::max(max_s, static_cast<double>(g.smoothed[c]));
    }
    const double D = std::max(max_s, o.depth_threshold);
    // A bottom slice thinner than a quarter layer merges into the layer above it.
    const int N = std::max(1, static_cast<int>(std::ceil(D / o.layer_height - 0.25)));
    const int pad = margin_cells + 2;
    const int i_off = imin - pad, j_off = jmin - pad;
    const int w = imax - imin + 1 + 2 * pad, h = jmax - jmin + 1 + 2 * pad;
    for (int k = 0; k < N; ++k) {
      WeldLayer layer;
      layer.index = k;
      layer.depth_top = (N - 1 - k) * o.layer_height;
      layer.depth_bottom = k == 0 ? std::max(D, N * o.layer_height) : (N - k) * o.layer_height;
      cv::Mat mask(h, w, CV_8UC1, cv::Scalar(0));
      for (int jj = 0; jj < h; ++jj) {
        for (int ii = 0; ii < w; ++ii) {
          const int i = ii + i_off, j = jj + j_off;
          if (i < 0 || j < 0 || i >= g.nu || j >= g.nv) continue;
          const int c = g.index(i, j);
          if (g.region[c] != id) continue;
          const bool in = layer.depth_top <= 0.0 ||
                          (std::isfinite(g.smoothed[c]) && g.smoothed[c] > layer.depth_top);
          if (in) mask.at<uint8_t>(jj, ii) = 255;
        }
      }
      if (cv::countNonZero(mask) == 0) continue;
      if (margin_cells > 0) {
        const cv::Mat kern = cv::getStructuringElement(
            cv::MORPH_ELLIPSE, cv::Size(2 * margin_cells + 1, 2 * margin_cells + 1));
        cv::dilate(mask, mask, kern);
      }
      std::vector<Eigen::Vector2d> cells;
      for (int jj = 0; jj < h; ++jj) {
        for (int ii = 0; ii < w; ++ii) {
          if (mask.at<uint8_t>(jj, ii)) cells.push_back(g.Centre(ii + i_off, jj + j_off));
        }
      }
      layer.footprint_area = cells.size() * cell_area;
      double phi = o.raster_angle;
      if (std::isnan(phi)) {
        Eigen::Vector2d m = Eigen::Vector2d::Zero();
        for (const auto& p : cells) m += p;
        m /= static_cast<double>(cells.size());
        Eigen::Matrix2d C = Eigen::Matrix2d::Zero();
        for (const auto& p : cells) C += (p - m) * (p - m).transpose();
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> es(C);
        const Eigen::Vector2d major = es.eigenvectors().col(1);
        phi = std::atan2(major.y(), major.x());
      }
      if (o.alternate_layers && k % 2 == 1) phi += 0.5 * M_PI;
      std::vector<BeadPath> paths;
      if (o.contour_pass) {
        paths = ContourPasses(mask, g, i_off, j_off, 0.5 * o.bead_width, o.point_spacing,
                              3.0 * o.bead_width);
      }
      std::vector<BeadPath> fill =
          RasterPasses(cells, g.cell, phi, step, o.point_spacing, o.pattern);
      paths.insert(paths.end(), fill.begin(), fill.end());

      // Order (contours are closed: start = end, never reversed).
      auto depth_at = [&](const Eigen::Vector2d& uv) {
        return std::min(layer.depth_bottom, std::max(0.0, g.SubstrateDepth(uv.x(), uv.y())));
      };
      std::vector<OrderNode> nodes;
      for (const auto& p : paths) {
        OrderNode nd;
        nd.start = ref.Point0(p.uv.front().x(), p.uv.front().y());
        nd.end = ref.Point0(p.uv.back().x(), p.uv.back().y());
        nd.reversible = !p.closed;
        nodes.push_back(nd);
      }
      std::vector<int> order;
      std::vector<char> reversed;
      OrderPasses(nodes, at, o.allow_reversal, &order, &reversed);

      for (int idx : order) {
        BeadPath p = paths[idx];
        if (reversed[idx]) std::reverse(p.uv.begin(), p.uv.end());
        // Lead-in, pass, lead-out in R: tangential run-up / run-out for open passes; along the
        // loop (ending over its start) for contours.
        std::vector<Eigen::Vector2d> lead_in, lead_out;
        if (p.closed) {
          const double L = PolylineLength(p.uv);
          for (double s = -o.lead_in; s < -1e-9; s += o.point_spacing)
            lead_in.push_back(AlongLoop(p.uv, s));
          for (double s = o.point_spacing; s <= o.lead_out + 1e-9 && s < L; s += o.point_spacing) {
            lead_out.push_back(AlongLoop(p.uv, s));
          }
        } else {
          Eigen::Vector2d t0 = p.uv.size() > 1 ? (p.uv[1] - p.uv[0]).normalized()
                                               : Eigen::Vector2d(std::cos(phi), std::sin(phi));
          Eigen::Vector2d t1 =
              p.uv.size() > 1 ? (p.uv.back() - p.uv[p.uv.size() - 2]).normalized() : t0;
          if (o.lead_in > 0) {
            const int n =
                std::max(1, static_cast<int>(std::ceil(o.lead_in / o.point_spacing - 1e-9)));
            for (int q = n; q >= 1; --q) lead_in.push_back(p.uv.front() - t0 * (o.lead_in * q / n));
          }
          if (o.lead_out > 0) {
            const int n =
                std::max(1, static_cast<int>(std::ceil(o.lead_out / o.point_spacing - 1e-9)));
            for (int q = 1; q <= n; ++q)
              lead_out.push_back(p.uv.back() + t1 * (o.lead_out * q / n));
          }
        }
        WeldBead bead;
        bead.id = bead_id++;
        bead.kind = p.kind;
        const Eigen::Vector2d first = lead_in.empty() ? p.uv.front() : lead_in.front();
        const Eigen::Vector2d last = lead_out.empty() ? p.uv.back() : lead_out.back();
        const double hi = o.stand_off + o.clearance;
        bead.points.push_back(MakePoint(ref, first, depth_at(first), hi, WeldPointKind::kApproach,
                                        false, o.air_speed));
        bool arc = false;  // the arc strikes at the first point at stand-off
        for (const auto& uv : lead_in) {
          bead.points.push_back(MakePoint(ref, uv, depth_at(uv), o.stand_off,
                                          WeldPointKind::kLeadIn, arc,
                                          arc ? o.travel_speed : o.air_speed));
          arc = true;
        }
        for (const auto& uv : p.uv) {
          bead.points.push_back(MakePoint(ref, uv, depth_at(uv), o.stand_off, WeldPointKind::kWeld,
                                          arc, arc ? o.travel_speed : o.air_speed));
          arc = true;
        }
        for (const auto& uv : lead_out) {
          bead.points.push_back(MakePoint(ref, uv, depth_at(uv), o.stand_off,
                                          WeldPointKind::kLeadOut, true, o.travel_speed));
        }
        bead.points.push_back(
            MakePoint(ref, last, depth_at(last), hi, WeldPointKind::kRetract, false, o.air_speed));
        for (size_t q = 1; q < bead.points.size(); ++q) {
          if (bead.points[q].arc_on) {
            bead.weld_length += (bead.points[q].p_0S - bead.points[q - 1].p_0S).norm();
          }
        }
        at = bead.points.back().p_0S;
        layer.beads.push_back(std::move(bead));
      }
      rp.layers.push_back(std::move(layer));
    }
    // Renumber the layers that got a footprint, bottom first.
    for (size_t k = 0; k < rp.layers.size(); ++k) rp.layers[k].index = static_cast<int>(k);
  }

  // Inverse kinematics along the welding order.
  TorchIkOptions quick = o.ik;
  quick.extra_starts = 0;
  quick.max_iterations = std::min(o.ik.max_iterations, 200);
  robots::Vector5d q_prev = o.q_start;
  WeldBead* prev_exec = nullptr;
  int prev_r = -1, prev_l = -1, prev_b = -1;
  std::vector<TrajectorySource> exec_order;  // executable beads in order
  for (size_t r = 0; r < plan.regions.size(); ++r) {
    for (size_t l = 0; l < plan.regions[r].layers.size(); ++l) {
      for (size_t b = 0; b < plan.regions[r].layers[l].beads.size(); ++b) {
        WeldBead& bead = plan.regions[r].layers[l].beads[b];
        robots::Vector5d q = q_prev;
        int failed = 0, first_fail = -1;
        for (size_t k = 0; k < bead.points.size(); ++k) {
          WeldPoint& p = bead.points[k];
          SolveIk(model, failed ? quick : o.ik, q, &p);
          if (p.reachable()) {
            q = p.q;
          } else {
            if (first_fail < 0) first_fail = static_cast<int>(k);
            ++failed;
          }
        }
        sum.points += static_cast<int>(bead.points.size());
        sum.unreachable_points += failed;
        bead.reachable = failed == 0;
        if (!bead.reachable) {
          const WeldPoint& p = bead.points[first_fail];
          std::ostringstream m;
          m << "region " << plan.regions[r].region.id << " layer " << l << " bead " << bead.id
            << " (" << ToString(bead.kind) << ", " << Mm(bead.weld_length, 1) << " mm): " << failed
            << " of " << bead.points.size() << " points not reachable, first the "
            << ToString(p.kind) << " point " << first_fail << " at " << MmPoint(p.p_0T) << ": "
            << (p.ik == robots::Weld5IkStatus::kJointLimit
                    ? "joint " + p.limiting_joint + " would leave its limits"
                    : "outside the workspace with the torch within " +
                          Mm(o.ik.max_tilt * 180.0 / M_PI * 1e-3, 1) +
                          " deg of the normal (wire point " + Mm(p.ik_position_error, 1) +
                          " mm off)")
            << "; the bead is not in the trajectory";
          bead.problem = m.str();
          sum.problems.push_back(bead.problem);
          continue;
        }
        // Air move from the previous executed bead: waypoints at clearance above the reference.
        if (prev_exec != nullptr) {
          const Eigen::Vector2d a = prev_exec->points.back().uv_R, c = bead.points.front().uv_R;
          const int n = static_cast<int>(std::floor((c - a).norm() / o.transit_spacing));
          std::vector<WeldPoint> transit;
          robots::Vector5d qt = prev_exec->points.back().q;
          int dropped = 0;
          for (int t = 1; t <= n; ++t) {
            const Eigen::Vector2d uv = a + (c - a) * (static_cast<double>(t) / (n + 1));
            WeldPoint w = MakePoint(ref, uv, 0.0, o.stand_off + o.clearance,
                                    WeldPointKind::kTransit, false, o.air_speed);
            SolveIk(model, o.ik, qt, &w);
            if (!w.reachable()) {
              ++dropped;
              continue;
            }
            qt = w.q;
            transit.push_back(w);
          }
          if (dropped > 0) {
            sum.warnings.push_back(std::to_string(dropped) + " transit waypoints before bead " +
                                   std::to_string(bead.id) +
                                   " not reachable and left out: that air move is interpolated in "
                                   "joint space");
          }
          bead.points.insert(bead.points.begin(), transit.begin(), transit.end());
          sum.points += static_cast<int>(transit.size());
        }
        bead.executable = true;
        q_prev = bead.points.back().q;
        prev_exec = &bead;
        prev_r = static_cast<int>(r), prev_l = static_cast<int>(l), prev_b = static_cast<int>(b);
        exec_order.push_back({prev_r, prev_l, prev_b, -1});
      }
    }
  }
  for (const auto& rp : plan.regions) {
    sum.layers += static_cast<int>(rp.layers.size());
    for (const auto& layer : rp.layers) {
      sum.beads += static_cast<int>(layer.beads.size());
      for (const auto& b : layer.beads) sum.executable_beads += b.executable ? 1 : 0;
    }
  }

  // The timed joint trajectory.
  robots::Vector5d q_from = o.q_start;
  Eigen::Vector3d p_from = fk.p_0T;
  bool have_p_from = true;
  bool first_segment = true;
  double tilt_sum = 0.0;
  int tilt_count = 0;
  for (const TrajectorySource& s : exec_order) {
    const WeldBead& bead = plan.regions[s.region].layers[s.layer].beads[s.bead];
    bool speed_limited_bead = false;
    for (size_t k = 0; k < bead.points.size(); ++k) {
      const WeldPoint& p = bead.points[k];
      const bool arc = p.arc_on && !first_segment;
      const double f = arc ? 1.0 : o.air_joint_speed_fraction;
      double t_joint = 0.0;
      for (int i = 0; i < robots::kWeld5Joints; ++i) {
        t_joint = std::max(t_joint, std::abs(p.q(i) - q_from(i)) / (model.qd_max(i) * f));
      }
      const double t_cart = have_p_from ? (p.p_0T - p_from).norm() / p.speed : 0.0;
      double dur = std::max({t_cart, t_joint, 1e-3});
      if (arc && t_joint > t_cart * (1.0 + 1e-6) && t_joint > 1e-3) {
        ++sum.speed_limited_segments;
        speed_limited_bead = true;
      }
      dur = std::ceil(dur * 1e3 - 1e-6) * 1e-3;
      const int pieces =
          std::max(1, static_cast<int>(std::ceil(dur / o.max_segment_duration - 1e-9)));
      const double piece = std::ceil(dur / pieces * 1e3 - 1e-6) * 1e-3;
      for (int m = 1; m <= pieces; ++m) {
        const robots::Vector5d qm = q_from + (p.q - q_from) * (static_cast<double>(m) / pieces);
        hal::WeldTrajectoryPoint tp;
        for (int i = 0; i < robots::kWeld5Joints; ++i) tp.joints[i] = qm(i);
        tp.duration = piece;
        tp.arc_on = arc;
        plan.trajectory.push_back(tp);
        plan.trajectory_source.push_back({s.region, s.layer, s.bead, static_cast<int>(k)});
        sum.total_time += piece;
        if (arc) sum.arc_time += piece;
      }
      for (int i = 0; i < robots::kWeld5Joints; ++i) {
        sum.max_joint_speed_ratio = std::max(
            sum.max_joint_speed_ratio, std::abs(p.q(i) - q_from(i)) / (dur * model.qd_max(i)));
      }
      if (arc) {
        // The robot interpolates in joint space: how far does the tip leave the straight path?
        robots::Weld5Data a, b, mid;
        robots::Weld5ForwardKinematics(model, q_from, &a);
        robots::Weld5ForwardKinematics(model, p.q, &b);
        robots::Weld5ForwardKinematics(model, 0.5 * (q_from + p.q), &mid);
        const double err = (mid.p_0T - 0.5 * (a.p_0T + b.p_0T)).norm();
        sum.max_interpolation_error = std::max(sum.max_interpolation_error, err);
      }
      q_from = p.q;
      p_from = p.p_0T;
      first_segment = false;
    }
    if (speed_limited_bead) {
      sum.warnings.push_back("bead " + std::to_string(bead.id) +
                             ": joint speed limits slow some arc-on segments below the travel "
                             "speed (more heat input there)");
    }
    sum.weld_length += bead.weld_length;
    for (const auto& p : bead.points) {
      sum.max_tilt = std::max(sum.max_tilt, p.tilt);
      tilt_sum += p.tilt;
      ++tilt_count;
    }
  }
  sum.mean_tilt = tilt_count > 0 ? tilt_sum / tilt_count : 0.0;
  if (sum.max_interpolation_error > o.max_interpolation_error) {
    sum.warnings.push_back("joint-space interpolation leaves the straight path by up to " +
                           Mm(sum.max_interpolation_error, 3) + " mm on arc-on segments (limit " +
                           Mm(o.max_interpolation_error, 3) + " mm): reduce point_spacing");
  }
  // The process check: deposit per unit length / step-over = the layer it builds.
  {
    const double wire_area = M_PI * 0.25 * o.process.wire_diameter * o.process.wire_diameter;
    const double bead_area =
        o.process.deposition_efficiency * wire_area * o.process.wire_feed_speed / o.travel_speed;
    const double layer = bead_area / step;
    if (std::abs(layer / o.layer_height - 1.0) > 0.3) {
      sum.warnings.push_back(
          "process: " + Mm(bead_area * 1e3, 1) + " mm² of bead cross-section at " +
          Mm(o.travel_speed, 1) + " mm/s and a step-over of " + Mm(step, 1) + " mm build " +
          Mm(layer, 2) + " mm layers, not the planned " + Mm(o.layer_height, 2) + " mm");
    }
  }

  sum.coverage = FillCoverage(plan, false);
  sum.coverage_executable = FillCoverage(plan, true);
  std::ostringstream m;
  if (sum.executable_beads == 0) {
    sum.status = WeldPlanStatus::kFailed;
    m << "no bead is reachable (" << sum.beads << " planned over " << sum.regions << " regions)";
  } else {
    sum.status =
        sum.executable_beads == sum.beads ? WeldPlanStatus::kPlanned : WeldPlanStatus::kPartial;
    m << sum.regions << " regions (" << sum.damaged_area * 1e6 << " mm²), " << sum.layers
      << " layers, " << sum.executable_beads << " of " << sum.beads << " beads executable, "
      << Mm(sum.weld_length, 0) << " mm of weld, coverage " << 100.0 * sum.coverage_executable
      << " %";
  }
  sum.message = m.str();
  return plan;
}

double FillCoverage(const WeldPlan& plan, bool executable_only) {
  const DepthGrid& g = plan.grid;
  std::vector<char> covered(g.region.size(), 0);
  const double r = 0.5 * plan.options.bead_width;
  for (const auto& rp : plan.regions) {
    for (const auto& layer : rp.layers) {
      for (const auto& bead : layer.beads) {
        if (executable_only && !bead.executable) continue;
        for (size_t k = 1; k < bead.points.size(); ++k) {
          if (!bead.points[k].arc_on) continue;
          MarkCapsule(g, bead.points[k - 1].uv_R, bead.points[k].uv_R, r, &covered);
        }
      }
    }
  }
  size_t damaged = 0, hit = 0;
  for (size_t c = 0; c < g.region.size(); ++c) {
    if (g.region[c] < 0) continue;
    ++damaged;
    hit += covered[c] ? 1 : 0;
  }
  return damaged == 0 ? 1.0 : static_cast<double>(hit) / damaged;
}

StandOffComparison CompareStandOff(const WeldPlan& plan,
                                   const std::vector<ExecutedTorchPose>& executed) {
  StandOffComparison out;
  const ReferenceSurface& ref = plan.reference.surface;
  double ss = 0.0, sa = 0.0;
  const WeldPoint* prev = nullptr;
  size_t prev_index = 0;
  for (const ExecutedTorchPose& e : executed) {
    if (e.trajectory_index >= plan.trajectory.size()) {
      throw std::invalid_argument("CompareStandOff: trajectory_index " +
                                  std::to_string(e.trajectory_index) +
                                  " >= " + std::to_string(plan.trajectory.size()) + " segments");
    }
    const TrajectorySource& s = plan.trajectory_source[e.trajectory_index];
    const WeldPoint& p = plan.regions[s.region].layers[s.layer].beads[s.bead].points[s.point];
    if (!plan.trajectory[e.trajectory_index].arc_on) {
      ++out.skipped;
      continue;
    }
    const Eigen::Vector3d u = e.X_0T.linear().col(2);
    double t = 0.0;
    if (!ref.IntersectLine(e.X_0T.translation(), u, &t)) {
      ++out.skipped;
      continue;
    }
    StandOffSample smp;
    smp.trajectory_index = e.trajectory_index;
    if (prev != nullptr && e.trajectory_index == prev_index + 1) {
      out.path_length += (p.p_0S - prev->p_0S).norm();
    }
    smp.path_position = out.path_length;
    smp.stand_off = t + p.depth;
    smp.error = smp.stand_off - plan.options.stand_off;
    smp.axis_error = std::acos(std::clamp(u.normalized().dot(p.u_0T), -1.0, 1.0));
    ss += smp.error * smp.error;
    sa += std::abs(smp.error);
    out.max_abs_error = std::max(out.max_abs_error, std::abs(smp.error));
    out.samples.push_back(smp);
    prev = &p;
    prev_index = e.trajectory_index;
  }
  if (!out.samples.empty()) {
    out.mean_abs_error = sa / out.samples.size();
    out.rms_error = std::sqrt(ss / out.samples.size());
  }
  return out;
}

}  // namespace kinevis::control
