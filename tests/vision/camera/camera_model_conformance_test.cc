// The conformance suite every CameraModel passes: what a caller of the interface may rely on,
// whatever the model. Run over every built-in model and a distorted pinhole.
//   - Round trip: a pixel back-projected and a point on its ray projected again gives the pixel.
//   - Project's Jacobian and BackProject's ray Jacobians match central differences.
//   - Out of view: wherever a call returns kOk far outside the image or the field of view, its
//     answer is still consistent (it never returns kOk with a wrong result).

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cctype>
#include <memory>
#include <string>

#include "tests/utilities/jacobian_check.h"
#include "vision/camera/camera_file.h"
#include "vision/camera/camera_model.h"
#include "vision/camera/pinhole_camera.h"

namespace kinevis::vision {
namespace {

std::unique_ptr<CameraModel> MakeModel(const std::string& name) {
  if (name == "pinhole-brown-distorted") {
    PinholeBrownParameters p;
    p.width = 1280;
    p.height = 960;
    p.fx = 1000.0;
    p.fy = 1005.0;
    p.cx = 640.3;
    p.cy = 479.7;
    p.distortion = {-0.28, 0.09, 1e-3, -5e-4, -0.01, 0.0, 0.0, 0.0};
    return std::make_unique<PinholeBrownCamera>(p);
  }
  return BuiltinCameraModel(name);
}

std::vector<std::string> ModelNames() {
  std::vector<std::string> names = BuiltinCameraModelNames();
  names.push_back("pinhole-brown-distorted");
  return names;
}

class CameraModelConformance : public ::testing::TestWithParam<std::string> {
 protected:
  void SetUp() override {
    camera_ = MakeModel(GetParam());
    ASSERT_NE(camera_, nullptr);
    ASSERT_EQ(camera_->Validate(), "");
  }
  // A 15 × 11 grid over the image, 2 % inside its border.
  std::vector<Eigen::Vector2d> Grid() const {
    std::vector<Eigen::Vector2d> out;
    for (int i = 0; i < 15; ++i) {
      for (int k = 0; k < 11; ++k) {
        out.emplace_back((0.02 + 0.96 * i / 14.0) * camera_->width(),
                         (0.02 + 0.96 * k / 10.0) * camera_->height());
      }
    }
    return out;
  }
  std::unique_ptr<CameraModel> camera_;
};

TEST_P(CameraModelConformance, BackProjectThenProjectReturnsThePixel) {
  int ok = 0;
  for (const Eigen::Vector2d& px : Grid()) {
    Ray ray;
    if (camera_->BackProject(px, &ray) != ProjectionStatus::kOk) continue;
    ++ok;
    EXPECT_NEAR(ray.d_C.norm(), 1.0, 1e-12);
    for (double t : {0.5, 3.0}) {
      Eigen::Vector2d back;
      ASSERT_EQ(camera_->Project(ray.p_C_O + t * ray.d_C, &back), ProjectionStatus::kOk)
          << "pixel " << px.transpose() << " at t = " << t;
      EXPECT_LT((back - px).norm(), 1e-6) << "pixel " << px.transpose() << " at t = " << t;
    }
  }
  // Every model sees at least a fifth of its image (the omnidirectional ones lose the corners
  // outside the mirror).
  EXPECT_GE(ok, 165 / 5) << ok << " of 165 grid pixels back-projected";
}

TEST_P(CameraModelConformance, ProjectionJacobianMatchesCentralDifferences) {
  int checked = 0;
  for (const Eigen::Vector2d& px : Grid()) {
    Ray ray;
    if (camera_->BackProject(px, &ray) != ProjectionStatus::kOk) continue;
    const Eigen::Vector3d p = ray.p_C_O + 1.5 * ray.d_C;
    Eigen::Vector2d pixel;
    Matrix23d J;
    ASSERT_EQ(camera_->Project(p, &pixel, &J), ProjectionStatus::kOk);
    const Eigen::MatrixXd numeric = testing::CentralDifferenceJacobian(
        [&](const Eigen::VectorXd& x, Eigen::VectorXd* y) {
          Eigen::Vector2d out;
          if (camera_->Project(x, &out) != ProjectionStatus::kOk) return false;
          *y = out;
          return true;
        },
        p, 1e-6);
    if (numeric.size() == 0) continue;  // at the edge of the domain
    EXPECT_EQ(testing::CompareJacobians(J, numeric, 1e-4), "") << "pixel " << px.transpose();
    ++checked;
  }
  EXPECT_GE(checked, 165 / 5);
}

TEST_P(CameraModelConformance, RayJacobiansMatchCentralDifferences) {
  int checked = 0;
  for (const Eigen::Vector2d& px : Grid()) {
    Ray ray;
    RayJacobian J;
    if (camera_->BackProject(px, &ray, &J) != ProjectionStatus::kOk) continue;
    const auto ray_of = [&](bool origin) {
      return [&, origin](const Eigen::VectorXd& x, Eigen::VectorXd* y) {
        Ray r;
        if (camera_->BackProject(Eigen::Vector2d(x), &r) != ProjectionStatus::kOk) return false;
        *y = origin ? r.p_C_O : r.d_C;
        return true;
      };
    };
    const Eigen::MatrixXd d_direction = testing::CentralDifferenceJacobian(ray_of(false), px, 1e-4);
    const Eigen::MatrixXd d_origin = testing::CentralDifferenceJacobian(ray_of(true), px, 1e-4);
    if (d_direction.size() == 0 || d_origin.size() == 0) continue;
    EXPECT_EQ(testing::CompareJacobians(J.d_direction_d_pixel, d_direction, 1e-5), "")
        << "pixel " << px.transpose();
    EXPECT_EQ(testing::CompareJacobians(J.d_origin_d_pixel, d_origin, 1e-5), "")
        << "pixel " << px.transpose();
    if (camera_->IsCentral()) {
      EXPECT_EQ(J.d_origin_d_pixel, Matrix32d::Zero());
    }
    ++checked;
  }
  EXPECT_GE(checked, 165 / 5);
}

TEST_P(CameraModelConformance, OutOfViewCallsAreRefusedOrStillConsistent) {
  // Pixels far outside the image and points all around the camera: a call may refuse, but an
  // answer it calls kOk must survive the round trip.
  for (const Eigen::Vector2d& px :
       {Eigen::Vector2d(-5.0 * camera_->width(), -5.0 * camera_->height()),
        Eigen::Vector2d(10.0 * camera_->width(), 0.5 * camera_->height()),
        Eigen::Vector2d(0.5 * camera_->width(), -3.0 * camera_->height())}) {
    Ray ray;
    if (camera_->BackProject(px, &ray) != ProjectionStatus::kOk) continue;
    Eigen::Vector2d back;
    ASSERT_EQ(camera_->Project(ray.p_C_O + 2.0 * ray.d_C, &back), ProjectionStatus::kOk);
    EXPECT_LT((back - px).norm(), 1e-6 * std::max(1.0, px.norm()));
  }
  for (const Eigen::Vector3d& p :
       {Eigen::Vector3d(0, 0, -1), Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(0, -1, 0.01),
        Eigen::Vector3d(5, 5, 0.1), Eigen::Vector3d(0.01, 0.01, -1)}) {
    Eigen::Vector2d pixel;
    if (camera_->Project(p, &pixel) != ProjectionStatus::kOk) continue;
    Ray ray;
    if (camera_->BackProject(pixel, &ray) != ProjectionStatus::kOk) continue;
    // The point lies on the ray of its pixel.
    const Eigen::Vector3d v = p - ray.p_C_O;
    EXPECT_LT((v - v.dot(ray.d_C) * ray.d_C).norm(), 1e-6 * v.norm()) << p.transpose();
    EXPECT_GT(v.dot(ray.d_C), 0.0) << p.transpose();
  }
}

INSTANTIATE_TEST_SUITE_P(EveryModel, CameraModelConformance, ::testing::ValuesIn(ModelNames()),
                         [](const ::testing::TestParamInfo<std::string>& info) {
                           std::string name = info.param;
                           for (char& c : name) {
                             if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
                           }
                           return name;
                         });

}  // namespace
}  // namespace kinevis::vision
