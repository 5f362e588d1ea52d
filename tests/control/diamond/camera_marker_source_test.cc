// The DIAMOND marker from a hal::Camera (control/diamond/camera_marker_source.h), in both modes,
// on a SimCamera rendering the marker scene: the detected pixel against the projection of the
// scene's true marker centre, and camera faults named.

#include "control/diamond/camera_marker_source.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <chrono>
#include <memory>
#include <string>
#include <thread>

#include "common/units.h"
#include "hal/camera/camera_factory.h"
#include "hal/camera/sim_camera.h"
#include "robots/diamond/diamond_model.h"
#include "tests/utilities/diamond_seed_camera.h"
#include "vision/camera/pinhole_camera.h"
#include "vision/render/renderer.h"
#include "vision/render/scenes/diamond_marker_scene.h"

namespace kinevis::control {
namespace {

using namespace std::chrono_literals;
using ::testing::HasSubstr;

std::string TestName() { return ::testing::UnitTest::GetInstance()->current_test_info()->name(); }

// The seed's camera (1280×640, f = 1000 px) at its 45° placement, a marker 0.2 m from the RCM.
class MarkerCamera {
 public:
  explicit MarkerCamera(hal::PixelFormat format = hal::PixelFormat::kMono8,
                        std::chrono::milliseconds render_time = 0ms)
      : name_("marker-" + TestName()) {
    const vision::PinholeBrownParameters p = kinevis::testing::DiamondSeedCamera();
    model_ = std::make_unique<vision::PinholeBrownCamera>(p);
    vision::render::RenderOptions o;
    o.supersampling = 4;
    o.noise_sigma = 1.0;
    renderer_ = std::make_unique<vision::render::Renderer>(*model_, o);
    scene_parameters_.X_CO = vision::render::DiamondCameraPose(0.4462);
    // On the a-priori sphere at (φ, γ) = (100°, 52°), near the working region's centre.
    scene_parameters_.p_O_T = robots::DiamondToolPoint(robots::DiamondModel::APriori().radius,
                                                       100 * common::kDeg, 52 * common::kDeg);
    scene_ = std::make_unique<vision::render::DiamondMarkerScene>(scene_parameters_);
    hal::CameraFormat f;
    f.width = p.width;
    f.height = p.height;
    f.pixel_format = format;
    f.fps = 30;
    hal::RegisterRenderSource(
        name_, f, [this, render_time](uint64_t id, common::Duration, hal::Image* image) {
          if (render_time > 0ms) std::this_thread::sleep_for(render_time);
          if (image->format != hal::PixelFormat::kMono8) return std::error_code();  // left blank
          renderer_->Render(*scene_, id,
                            {image->data.data(), image->width, image->height, image->stride});
          return std::error_code();
        });
    camera_ = hal::OpenCamera("sim:" + name_);
    camera_->Open();
    EXPECT_FALSE(camera_->Start());
  }
  ~MarkerCamera() {
    camera_.reset();
    hal::UnregisterRenderSource(name_);
  }
  hal::Camera* camera() { return camera_.get(); }
  Eigen::Vector2d TruePixel() const {
    Eigen::Vector2d px;
    model_->Project(scene_->p_C_T(), &px);
    return px;
  }

 private:
  std::string name_;
  std::unique_ptr<vision::CameraModel> model_;
  std::unique_ptr<vision::render::Renderer> renderer_;
  vision::render::DiamondMarkerSceneParameters scene_parameters_;
  std::unique_ptr<vision::render::DiamondMarkerScene> scene_;
  std::unique_ptr<hal::Camera> camera_;
};

// Polls like a control loop (every 1 ms of steady time) until a frame comes, for at most 5 s.
bool PollUntilFrame(CameraMarkerSource* source, MarkerFrame* frame) {
  const auto end = std::chrono::steady_clock::now() + 5s;
  while (std::chrono::steady_clock::now() < end) {
    if (source->Poll(common::SteadyClock::Instance().Now(), frame)) return true;
    std::this_thread::sleep_for(1ms);
  }
  return false;
}

TEST(CameraMarkerSourceTest, SynchronousModeDetectsTheMarkerWhereTheSceneHasIt) {
  MarkerCamera cam;
  CameraMarkerSource source(cam.camera());
  MarkerFrame frame;
  const Eigen::Vector2d truth = cam.TruePixel();
  ASSERT_TRUE(truth.x() > 50 && truth.x() < 1230 && truth.y() > 50 && truth.y() < 590) << truth;
  ASSERT_TRUE(PollUntilFrame(&source, &frame)) << source.error();
  ASSERT_TRUE(frame.found) << vision::ToString(frame.status);
  EXPECT_LT((frame.pixel - cam.TruePixel()).norm(), 0.5);
  EXPECT_EQ(frame.sequence, 1u);
  EXPECT_EQ(source.frames(), 1u);
  EXPECT_EQ(source.error(), "");
}

TEST(CameraMarkerSourceTest, AsynchronousModeDetectsInTheWorkerAndHandsOverTheNewest) {
  MarkerCamera cam(hal::PixelFormat::kMono8, 40ms);  // a slow camera
  CameraMarkerSourceOptions o;
  o.asynchronous = true;
  CameraMarkerSource source(cam.camera(), o);
  MarkerFrame first, second;
  ASSERT_TRUE(PollUntilFrame(&source, &first)) << source.error();
  ASSERT_TRUE(PollUntilFrame(&source, &second)) << source.error();
  ASSERT_TRUE(first.found && second.found);
  EXPECT_GT(second.sequence, first.sequence);
  EXPECT_GT(second.timestamp, first.timestamp);
  EXPECT_LT((second.pixel - cam.TruePixel()).norm(), 0.5);
  EXPECT_EQ(source.error(), "");
}

TEST(CameraMarkerSourceTest, FramesThatAreNotGreyAreAnErrorNamingTheCamera) {
  for (const bool asynchronous : {false, true}) {
    SCOPED_TRACE(asynchronous ? "asynchronous" : "synchronous");
    MarkerCamera cam(hal::PixelFormat::kBgr8);
    CameraMarkerSourceOptions o;
    o.asynchronous = asynchronous;
    CameraMarkerSource source(cam.camera(), o);
    MarkerFrame frame;
    const auto end = std::chrono::steady_clock::now() + 5s;
    while (source.error().empty() && std::chrono::steady_clock::now() < end) {
      EXPECT_FALSE(source.Poll(common::SteadyClock::Instance().Now(), &frame));
      std::this_thread::sleep_for(1ms);
    }
    EXPECT_THAT(source.error(), HasSubstr("camera "));
    EXPECT_THAT(source.error(), HasSubstr("frames are not mono8"));
    EXPECT_FALSE(source.Poll(common::SteadyClock::Instance().Now(), &frame));
  }
}

TEST(CameraMarkerSourceTest, BadArgumentsAreNamed) {
  CameraMarkerSourceOptions o;
  o.grab_timeout_ms = 0;
  try {
    CameraMarkerSource source(nullptr, o);
    FAIL() << "constructed without a camera";
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr("camera: null"));
    EXPECT_THAT(e.what(), HasSubstr("grab_timeout_ms"));
  }
}

}  // namespace
}  // namespace kinevis::control
