#include "control/weld/weld_planner.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>

#include "tests/control/weld/synthetic_blade.h"

namespace kinevis::control {
namespace {

using ::testing::ContainsRegex;
using ::testing::HasSubstr;

robots::Weld5Model Robot() {
  return robots::Weld5Model::Seed(robots::Weld5TorchTransform(0.025, 0.250, 0.0));
}

// One plan of the default test blade, shared (planning takes a fraction of a second).
const testing::SyntheticBlade& Blade() {
  static const testing::SyntheticBlade blade = testing::DefaultTestBlade();
  return blade;
}
const WeldPlan& DefaultPlan() {
  static const WeldPlan plan = PlanWeldRepair(Blade().Make(), Robot());
  return plan;
}

template <typename F>
void ForEachPoint(const WeldPlan& plan, F f) {
  for (const auto& rp : plan.regions) {
    for (const auto& layer : rp.layers) {
      for (const auto& b : layer.beads) {
        for (const auto& p : b.points) f(layer, b, p);
      }
    }
  }
}

TEST(PlanWeldRepair, DefaultBladeIsPlannedWithFullCoverage) {
  const WeldPlan& plan = DefaultPlan();
  const WeldPlanSummary& s = plan.summary;
  ASSERT_EQ(s.status, WeldPlanStatus::kPlanned) << s.message;
  EXPECT_EQ(s.regions, 3);
  EXPECT_EQ(s.executable_beads, s.beads);
  EXPECT_EQ(s.unreachable_points, 0);
  EXPECT_DOUBLE_EQ(s.coverage, 1.0);
  EXPECT_DOUBLE_EQ(s.coverage_executable, 1.0);
  EXPECT_DOUBLE_EQ(FillCoverage(plan), 1.0);
  EXPECT_GT(s.weld_length, 0.3);
  EXPECT_EQ(plan.trajectory.size(), plan.trajectory_source.size());
}

TEST(PlanWeldRepair, DetectedRegionsMatchTheTruePits) {
  const WeldPlan& plan = DefaultPlan();
  const auto& pits = Blade().scene.pits;
  const double thr = plan.options.depth_threshold;
  for (size_t k = 0; k + 1 < pits.size(); ++k) {  // the last one is the tiny pit
    const auto& pit = pits[k];
    const Eigen::Vector3d c_0 =
        Blade().X_0S * Eigen::Vector3d(pit.centre_S.x(), pit.centre_S.y(), 0.0);
    const DamageRegion* match = nullptr;
    for (const auto& rp : plan.regions) {
      const Eigen::Vector3d d = Blade().X_0S.inverse() * rp.region.centroid_0;
      if ((d.head<2>() - pit.centre_S).norm() < 0.5e-3) match = &rp.region;
    }
    ASSERT_NE(match, nullptr) << "pit " << k << " at " << c_0.transpose();
    EXPECT_NEAR(match->max_depth, pit.depth, 0.1e-3) << "pit " << k;
    // Area deeper than the threshold of a Gaussian pit: π σ² 2 ln(h / thr).
    const double area = M_PI * pit.sigma * pit.sigma * 2.0 * std::log(pit.depth / thr);
    EXPECT_NEAR(match->area, area, 0.15 * area) << "pit " << k;
  }
  // The tiny pit is rejected, with its reason.
  const auto& tiny = pits.back();
  bool rejected = false;
  for (const auto& r : plan.rejected) {
    const Eigen::Vector3d d = Blade().X_0S.inverse() * r.centroid_0;
    if ((d.head<2>() - tiny.centre_S).norm() < 1e-3) {
      rejected = true;
      EXPECT_THAT(r.reason, ContainsRegex("area .* mm² < min_region_area 2 mm²"));
    }
  }
  EXPECT_TRUE(rejected);
}

TEST(PlanWeldRepair, BeadsCoverEveryTrulyDamagedPoint) {
  // Independent of the planner's own grid: every point of the true surface deeper than the
  // threshold (pits big enough to be welded) lies within half a bead of an arc-on segment.
  const WeldPlan& plan = DefaultPlan();
  const ReferenceSurface& ref = plan.reference.surface;
  std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> segments;
  for (const auto& rp : plan.regions) {
    for (const auto& layer : rp.layers) {
      for (const auto& b : layer.beads) {
        for (size_t k = 1; k < b.points.size(); ++k) {
          if (b.points[k].arc_on) segments.push_back({b.points[k - 1].uv_R, b.points[k].uv_R});
        }
      }
    }
  }
  const auto& pits = Blade().scene.pits;
  int checked = 0;
  for (size_t k = 0; k + 1 < pits.size(); ++k) {
    const auto& pit = pits[k];
    for (double x = -4 * pit.sigma; x <= 4 * pit.sigma; x += 0.25e-3) {
      for (double y = -4 * pit.sigma; y <= 4 * pit.sigma; y += 0.25e-3) {
        const double xs = pit.centre_S.x() + x, ys = pit.centre_S.y() + y;
        if (Blade().TrueDepth(xs, ys) <= plan.options.depth_threshold) continue;
        const Eigen::Vector3d q =
            ref.ToR(Blade().X_0S * Eigen::Vector3d(xs, ys, Blade().Height(xs, ys)));
        double best = 1e9;
        for (const auto& [a, b] : segments) {
          const Eigen::Vector2d ab = b - a;
          const double t = ab.squaredNorm() > 0
                               ? std::clamp((q.head<2>() - a).dot(ab) / ab.squaredNorm(), 0.0, 1.0)
                               : 0.0;
          best = std::min(best, (a + t * ab - q.head<2>()).norm());
        }
        ++checked;
        ASSERT_LE(best, 0.5 * plan.options.bead_width)
            << "uncovered at S (" << xs << ", " << ys << ")";
      }
    }
  }
  EXPECT_GT(checked, 1000);
}

TEST(PlanWeldRepair, LayersSliceTheDeepCavity) {
  const WeldPlan& plan = DefaultPlan();
  const WeldRegionPlan* deep = nullptr;
  for (const auto& rp : plan.regions) {
    if (rp.region.max_depth > 3e-3) deep = &rp;
  }
  ASSERT_NE(deep, nullptr);
  ASSERT_EQ(deep->layers.size(), 3u);  // 4 mm at 1.5 mm per layer
  const double h = plan.options.layer_height;
  for (size_t k = 0; k < 3; ++k) {
    const WeldLayer& l = deep->layers[k];
    EXPECT_EQ(l.index, static_cast<int>(k));
    EXPECT_NEAR(l.depth_top, (2 - k) * h, 1e-12);
    if (k > 0) {
      EXPECT_NEAR(l.depth_bottom, deep->layers[k - 1].depth_top, 1e-12);
    }
    if (k > 0) {
      EXPECT_GT(l.footprint_area, deep->layers[k - 1].footprint_area);
    }
    EXPECT_FALSE(l.beads.empty());
    for (const auto& b : l.beads) {
      for (const auto& p : b.points) {
        EXPECT_GE(p.depth, 0.0);
        EXPECT_LE(p.depth, l.depth_bottom + 1e-12);
      }
    }
  }
  // The bottom layer is welded at its slice bottom over the cavity floor.
  double deepest = 0.0;
  for (const auto& b : deep->layers[0].beads) {
    for (const auto& p : b.points) deepest = std::max(deepest, p.depth);
  }
  EXPECT_GT(deepest, 3.0e-3);
}

TEST(PlanWeldRepair, TorchAxisIsTheNormalAndStandOffIsConstant) {
  const WeldPlan& plan = DefaultPlan();
  const ReferenceSurface& ref = plan.reference.surface;
  const double s = plan.options.stand_off;
  int n = 0;
  ForEachPoint(plan, [&](const WeldLayer&, const WeldBead&, const WeldPoint& p) {
    ++n;
    EXPECT_LT((p.u_0T + ref.Normal0(p.uv_R.x(), p.uv_R.y())).norm(), 1e-12);
    // The true sheet's normal (the blade without its pits) at the same place.
    const Eigen::Vector3d q_S = Blade().X_0S.inverse() * p.p_0S;
    EXPECT_GT((-p.u_0T).dot(Blade().ReferenceNormal0(q_S.x(), q_S.y())),
              std::cos(0.2 * M_PI / 180));
    const bool at_work = p.kind == WeldPointKind::kLeadIn || p.kind == WeldPointKind::kWeld ||
                         p.kind == WeldPointKind::kLeadOut;
    if (at_work) {
      EXPECT_DOUBLE_EQ(p.stand_off, s);
    }
    // The wire, stand_off along the torch's actual axis, hits the deposition point.
    EXPECT_NEAR((p.p_0T + p.stand_off * p.u_0T_achieved - p.p_0S).norm(), 0.0, 1e-7);
    EXPECT_LE(p.tilt, plan.options.ik.max_tilt + 1e-9);
    EXPECT_NEAR(std::acos(std::min(1.0, p.u_0T.dot(p.u_0T_achieved))), p.tilt, 1e-6);
    if (p.arc_on) {
      EXPECT_TRUE(at_work);
    }
  });
  EXPECT_GT(n, 500);
  EXPECT_GT(plan.summary.max_tilt, 0.0);  // this blade lies beside the arm's lateral offset
}

TEST(PlanWeldRepair, IkIsConfirmedByForwardKinematicsAndTheTrajectoryIsExecutable) {
  const WeldPlan& plan = DefaultPlan();
  const robots::Weld5Model m = Robot();
  ForEachPoint(plan, [&](const WeldLayer&, const WeldBead& b, const WeldPoint& p) {
    if (!b.executable) return;
    ASSERT_TRUE(p.reachable());
    robots::Weld5Data fk;
    robots::Weld5ForwardKinematics(m, p.q, &fk);
    EXPECT_LT((fk.p_0T - p.p_0T).norm(), 1e-9);
    EXPECT_LT((fk.u_0T - p.u_0T_achieved).norm(), 1e-9);
    EXPECT_LT((fk.p_0T + p.stand_off * fk.u_0T - p.p_0S).norm(), 1e-6);
    for (int i = 0; i < 5; ++i) {
      EXPECT_GE(p.q(i), m.q_min(i));
      EXPECT_LE(p.q(i), m.q_max(i));
    }
  });
  robots::Vector5d q = plan.options.q_start;
  double ratio = 0.0;
  for (size_t k = 0; k < plan.trajectory.size(); ++k) {
    const auto& t = plan.trajectory[k];
    EXPECT_GE(t.duration, 1e-3 - 1e-12);
    EXPECT_LE(t.duration, plan.options.max_segment_duration + 1e-12);
    EXPECT_NEAR(t.duration * 1e3, std::round(t.duration * 1e3), 1e-6);  // whole ms
    robots::Vector5d qn;
    for (int i = 0; i < 5; ++i) qn(i) = t.joints[i];
    for (int i = 0; i < 5; ++i)
      ratio = std::max(ratio, std::abs(qn(i) - q(i)) / t.duration / m.qd_max(i));
    const auto& src = plan.trajectory_source[k];
    const WeldPoint& p =
        plan.regions[src.region].layers[src.layer].beads[src.bead].points[src.point];
    EXPECT_EQ(t.arc_on, p.arc_on);
    if (t.arc_on) {
      robots::Weld5Data a, b;
      robots::Weld5ForwardKinematics(m, q, &a);
      robots::Weld5ForwardKinematics(m, qn, &b);
      EXPECT_LE((b.p_0T - a.p_0T).norm() / t.duration, plan.options.travel_speed * 1.0001);
    }
    q = qn;
  }
  EXPECT_LE(ratio, 1.0 + 1e-9);
  EXPECT_LT(plan.summary.max_interpolation_error, plan.options.max_interpolation_error);
}

TEST(PlanWeldRepair, ExactNormalOnAPlateInFrontOfTheArm) {
  // A flat plate centred on the arm's lateral offset (pz2 ≈ 105 mm): the arm holds the normal.
  testing::SyntheticBlade plate;
  plate.scene.half_extent = Eigen::Vector2d(0.04, 0.02);
  vision::render::CavitationPit pit;
  pit.depth = 2e-3;
  pit.sigma = 2.5e-3;
  plate.scene.pits = {pit};
  plate.X_0S.translation() = Eigen::Vector3d(0.70, 0.105, 0.27);
  plate.spacing = 0.4e-3;
  WeldPlanOptions o;
  o.ik.max_tilt = 0.0;
  const WeldPlan plan = PlanWeldRepair(plate.Make(), Robot(), o);
  ASSERT_EQ(plan.summary.status, WeldPlanStatus::kPlanned) << plan.summary.message;
  EXPECT_LT(plan.summary.max_tilt, 1e-5);
  EXPECT_DOUBLE_EQ(plan.summary.coverage_executable, 1.0);
}

TEST(PlanWeldRepair, UnreachableRegionIsReportedNotDropped) {
  // A tall blade: one pit beside the arm, one 200 mm to the side of it, beyond 10° of tilt.
  testing::SyntheticBlade blade;
  blade.scene.half_extent = Eigen::Vector2d(0.02, 0.16);
  vision::render::CavitationPit near, far;
  near.centre_S = Eigen::Vector2d(0.0, 0.05);
  near.depth = 1.5e-3;
  near.sigma = 2.5e-3;
  far = near;
  far.centre_S = Eigen::Vector2d(0.0, -0.14);
  blade.scene.pits = {near, far};
  blade.spacing = 0.5e-3;
  const WeldPlan plan = PlanWeldRepair(blade.Make(), Robot());
  const WeldPlanSummary& s = plan.summary;
  ASSERT_EQ(s.status, WeldPlanStatus::kPartial) << s.message;
  EXPECT_EQ(s.regions, 2);
  EXPECT_GT(s.executable_beads, 0);
  EXPECT_LT(s.executable_beads, s.beads);
  ASSERT_FALSE(s.problems.empty());
  EXPECT_THAT(s.problems.front(),
              ContainsRegex("region [01] layer 0 bead [0-9]+ .* not reachable"));
  EXPECT_DOUBLE_EQ(s.coverage, 1.0);
  EXPECT_LT(s.coverage_executable, 0.7);
  EXPECT_GT(s.coverage_executable, 0.3);
  // The unreachable beads stay in the plan, flagged, and out of the trajectory.
  int flagged = 0;
  for (size_t r = 0; r < plan.regions.size(); ++r) {
    for (size_t l = 0; l < plan.regions[r].layers.size(); ++l) {
      for (size_t b = 0; b < plan.regions[r].layers[l].beads.size(); ++b) {
        const WeldBead& bead = plan.regions[r].layers[l].beads[b];
        if (bead.executable) continue;
        ++flagged;
        EXPECT_FALSE(bead.problem.empty());
        for (const auto& src : plan.trajectory_source) {
          EXPECT_FALSE(src.region == static_cast<int>(r) && src.layer == static_cast<int>(l) &&
                       src.bead == static_cast<int>(b));
        }
      }
    }
  }
  EXPECT_EQ(flagged, s.beads - s.executable_beads);
}

TEST(PlanWeldRepair, BadParametersAreRefusedByName) {
  WeldPlanOptions o;
  o.bead_width = 0.1e-3;
  o.overlap = 0.95;
  o.stand_off = -1;
  o.pattern = BeadPattern::kRaster;
  const std::string why = o.Validate();
  EXPECT_THAT(why, HasSubstr("bead_width = 0.0001 m (1..30 mm)"));
  EXPECT_THAT(why, HasSubstr("overlap = 0.95"));
  EXPECT_THAT(why, HasSubstr("stand_off = -1 m"));
  const WeldMap map = Blade().Make();
  try {
    PlanWeldRepair(map, Robot(), o);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr("bad options: bead_width"));
  }
  WeldPlanOptions q;
  q.q_start(2) = 0.9;
  EXPECT_THROW(
      {
        try {
          PlanWeldRepair(map, Robot(), q);
        } catch (const std::invalid_argument& e) {
          EXPECT_THAT(e.what(), HasSubstr("q_start pz3 = 0.9 outside [0, 0.5]"));
          throw;
        }
      },
      std::invalid_argument);
  WeldMap bad = map;
  bad.n_0.resize(3);
  EXPECT_THROW(PlanWeldRepair(bad, Robot()), std::invalid_argument);
  robots::Weld5Model broken = Robot();
  broken.qd_max(4) = 0.0;
  EXPECT_THROW(PlanWeldRepair(map, broken), std::invalid_argument);
}

TEST(PlanWeldRepair, EmptyOrFlatMapHasNothingToRepair) {
  const WeldPlan empty = PlanWeldRepair(WeldMap{}, Robot());
  EXPECT_EQ(empty.summary.status, WeldPlanStatus::kNothingToRepair);
  EXPECT_THAT(empty.summary.message, HasSubstr("no (finite) points: nothing to repair"));
  testing::SyntheticBlade flat;
  flat.scene.half_extent = Eigen::Vector2d(0.03, 0.03);
  flat.spacing = 0.5e-3;
  flat.outlier_fraction = 0.0;
  const WeldPlan f = PlanWeldRepair(flat.Make(), Robot());
  EXPECT_EQ(f.summary.status, WeldPlanStatus::kNothingToRepair);
  EXPECT_THAT(f.summary.message, HasSubstr("no damage deeper than 0.50 mm"));
  EXPECT_TRUE(f.trajectory.empty());
  WeldMap line;
  for (int i = 0; i < 200; ++i) line.p_0.emplace_back(0.7, 0.001 * i, 0.3);
  const WeldPlan l = PlanWeldRepair(line, Robot());
  EXPECT_EQ(l.summary.status, WeldPlanStatus::kFailed);
  EXPECT_THAT(l.summary.message, HasSubstr("line or a point"));
}

TEST(PlanWeldRepair, ZigZagJoinsPassesAndKeepsCoverage) {
  WeldPlanOptions o;
  o.pattern = BeadPattern::kZigZag;
  o.contour_pass = false;
  const WeldPlan z = PlanWeldRepair(Blade().Make(), Robot(), o);
  o.pattern = BeadPattern::kRaster;
  const WeldPlan r = PlanWeldRepair(Blade().Make(), Robot(), o);
  ASSERT_EQ(z.summary.status, WeldPlanStatus::kPlanned) << z.summary.message;
  EXPECT_LT(z.summary.beads, r.summary.beads);
  EXPECT_DOUBLE_EQ(z.summary.coverage_executable, 1.0);
  EXPECT_DOUBLE_EQ(r.summary.coverage_executable, 1.0);
  for (const auto& rp : z.regions) {
    for (const auto& l : rp.layers) {
      for (const auto& b : l.beads) EXPECT_EQ(b.kind, BeadKind::kZigZag);
    }
  }
}

TEST(PlanWeldRepair, SlowJointsSlowTheWeldAndAreReported) {
  robots::Weld5Model slow = Robot();
  slow.qd_max *= 0.003;
  const WeldPlan plan = PlanWeldRepair(Blade().Make(), slow);
  ASSERT_NE(plan.summary.status, WeldPlanStatus::kFailed);
  EXPECT_GT(plan.summary.speed_limited_segments, 0);
  EXPECT_LE(plan.summary.max_joint_speed_ratio, 1.0 + 1e-9);
  bool warned = false;
  for (const auto& w : plan.summary.warnings)
    warned |= w.find("joint speed limits") != std::string::npos;
  EXPECT_TRUE(warned);
}

TEST(CompareStandOff, ZeroForThePlanAndTheOffsetForAShiftedTorch) {
  const WeldPlan& plan = DefaultPlan();
  const robots::Weld5Model m = Robot();
  std::vector<ExecutedTorchPose> exact, shifted;
  for (size_t k = 0; k < plan.trajectory.size(); ++k) {
    robots::Vector5d q;
    for (int i = 0; i < 5; ++i) q(i) = plan.trajectory[k].joints[i];
    robots::Weld5Data fk;
    robots::Weld5ForwardKinematics(m, q, &fk);
    exact.push_back({k, fk.X_0T});
    Eigen::Isometry3d back = fk.X_0T;
    back.translation() -= 0.3e-3 * fk.u_0T;  // 0.3 mm farther from the work
    shifted.push_back({k, back});
  }
  const StandOffComparison a = CompareStandOff(plan, exact);
  ASSERT_GT(a.samples.size(), 300u);
  EXPECT_LT(a.max_abs_error, 0.02e-3);  // the deposition surface is the reference offset by δ
  EXPECT_GT(a.path_length, 0.3);
  const StandOffComparison b = CompareStandOff(plan, shifted);
  EXPECT_NEAR(b.mean_abs_error, 0.3e-3, 0.02e-3);
  EXPECT_THROW(CompareStandOff(plan, {{plan.trajectory.size(), Eigen::Isometry3d::Identity()}}),
               std::invalid_argument);
}

}  // namespace
}  // namespace kinevis::control
