#include "vision/render/primitives.h"

#include <gtest/gtest.h>

#include <random>

namespace kinevis::vision::render {
namespace {

Ray MakeRay(const Eigen::Vector3d& o, const Eigen::Vector3d& d) {
  Ray r;
  r.p_C_O = o;
  r.d_C = d.normalized();
  return r;
}

TEST(Primitives, PlaneHitAndNormalFacingTheRay) {
  Eigen::Vector3d n;
  const double t = IntersectPlane(MakeRay({0, 0, 0}, {0, 0, 1}), {0, 0, 2}, {0, 0, 1}, 1e-9, &n);
  EXPECT_DOUBLE_EQ(t, 2.0);
  EXPECT_TRUE(n.isApprox(Eigen::Vector3d(0, 0, -1)));
  EXPECT_EQ(IntersectPlane(MakeRay({0, 0, 0}, {0, 0, -1}), {0, 0, 2}, {0, 0, 1}), kNoHit);
  EXPECT_EQ(IntersectPlane(MakeRay({0, 0, 0}, {1, 0, 0}), {0, 0, 2}, {0, 0, 1}), kNoHit);
}

TEST(Primitives, SphereNearRootAndInsideStart) {
  Eigen::Vector3d n;
  EXPECT_NEAR(IntersectSphere(MakeRay({0, 0, 0}, {0, 0, 1}), {0, 0, 5}, 1.0, 1e-9, &n), 4.0, 1e-12);
  EXPECT_TRUE(n.isApprox(Eigen::Vector3d(0, 0, -1)));
  EXPECT_NEAR(IntersectSphere(MakeRay({0, 0, 5}, {0, 0, 1}), {0, 0, 5}, 1.0), 1.0, 1e-12);
  EXPECT_EQ(IntersectSphere(MakeRay({0, 2, 0}, {0, 0, 1}), {0, 0, 5}, 1.0), kNoHit);
}

TEST(Primitives, RandomHitsLieOnTheSurfaces) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const Eigen::Vector3d a(0.1, -0.2, 1.0), b(-0.1, 0.3, 1.6);
  const double radius = 0.05;
  Eigen::Isometry3d X_CB = Eigen::Isometry3d::Identity();
  X_CB.linear() = Eigen::AngleAxisd(0.4, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  X_CB.translation() = Eigen::Vector3d(0.05, 0.0, 1.2);
  const Eigen::Vector3d half(0.05, 0.025, 0.005);
  int cylinder_hits = 0, box_hits = 0;
  for (int i = 0; i < 20000; ++i) {
    const Ray ray = MakeRay({0, 0, 0}, {0.4 * u(rng), 0.4 * u(rng), 1.0});
    Eigen::Vector3d n;
    const double t = IntersectCylinder(ray, a, b, radius, 1e-9, &n);
    if (t != kNoHit) {
      ++cylinder_hits;
      const Eigen::Vector3d p = ray.p_C_O + t * ray.d_C;
      const Eigen::Vector3d w = (b - a).normalized();
      const Eigen::Vector3d r = (p - a) - (p - a).dot(w) * w;
      EXPECT_NEAR(r.norm(), radius, 1e-12);
      // Radial unit normal (the tube is open: past an end the inside is what a ray meets).
      EXPECT_NEAR(n.norm(), 1.0, 1e-12);
      EXPECT_NEAR(n.dot(w), 0.0, 1e-12);
      EXPECT_LT((n - r / radius).norm(), 1e-9);
    }
    const double tb = IntersectBox(ray, X_CB, half, 1e-9, &n);
    if (tb != kNoHit) {
      ++box_hits;
      const Eigen::Vector3d p_B = X_CB.inverse() * (ray.p_C_O + tb * ray.d_C);
      EXPECT_NEAR((p_B.cwiseAbs() - half).maxCoeff(), 0.0, 1e-12);
      EXPECT_LT(n.dot(ray.d_C), 0.0);
    }
  }
  EXPECT_GT(cylinder_hits, 100);
  EXPECT_GT(box_hits, 100);
}

TEST(Primitives, DiscIsBoundedAndCylinderIsFinite) {
  EXPECT_NEAR(IntersectDisc(MakeRay({0, 0, 0}, {0.05, 0, 1}), {0, 0, 1}, {0, 0, 1}, 0.1),
              std::hypot(0.05, 1.0), 1e-12);
  EXPECT_EQ(IntersectDisc(MakeRay({0, 0, 0}, {0.2, 0, 1}), {0, 0, 1}, {0, 0, 1}, 0.1), kNoHit);
  // Aimed past the end of a short cylinder.
  EXPECT_EQ(IntersectCylinder(MakeRay({0, 0, 0}, {0, 0, 1}), {0.5, -0.1, 1}, {0.5, 0.1, 1}, 0.05),
            kNoHit);
  EXPECT_EQ(IntersectCylinder(MakeRay({0, 0, 0}, {0, 0.5, 1}), {0, -0.1, 1}, {0, 0.1, 1}, 0.05),
            kNoHit);
}

}  // namespace
}  // namespace kinevis::vision::render
