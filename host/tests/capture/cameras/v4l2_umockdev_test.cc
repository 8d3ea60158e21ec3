// The v4l2 camera backend against a UVC webcam emulated by umockdev (fake_uvc_camera.h): the backend's
// real open/ioctl/mmap/poll path, through the kernel interface as umockdev intercepts it. Run under
// umockdev-wrapper (CTest does it, through host/tests/device/run_hil.sh).
#include <linux/videodev2.h>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>

#include <opencv2/core.hpp>

#include "capture/v4l2_camera.h"
#include "fake_uvc_camera.h"
#include "rotoscan/capture/factory.h"

namespace rotoscan::capture {
namespace {

using testing::FakeUvcCamera;
using ::testing::HasSubstr;

class V4l2Umockdev : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!FakeUvcCamera::InMockEnvironment()) GTEST_SKIP() << "needs umockdev-wrapper (run through ctest)";
  }

  static std::unique_ptr<V4l2Camera> Open(const std::vector<std::string>& options) {
    OpenContext context;
    context.options = options;
    auto camera = V4l2Camera::Open("/dev/video0", context);
    EXPECT_TRUE(camera.ok()) << camera.status().ToString();
    return camera.ok() ? std::move(camera).value() : nullptr;
  }

  static CameraSettings Small(PixelFormat format) {
    CameraSettings s;
    s.width = 64;
    s.height = 48;
    s.format = format;
    s.exposure_us = 10'000;
    return s;
  }

  // Reads frames until `n` arrived (each within a second).
  static std::vector<Frame> Read(Camera* camera, int n) {
    std::vector<Frame> frames;
    for (int i = 0; i < n; ++i) {
      auto f = camera->NextFrame(1'000'000);
      EXPECT_TRUE(f.ok()) << f.status().ToString();
      if (!f.ok() || !f.value()) break;
      frames.push_back(std::move(*std::move(f).value()));
    }
    return frames;
  }
};

// MJPEG through mmap'ed buffers, like the C270 at 1280x960: controls manual and read back, frames decoded,
// ids and start-of-exposure stamps as sent.
TEST_F(V4l2Umockdev, MjpegMmapFramesWithStartOfExposureStamps) {
  FakeUvcCamera fake(FakeUvcCamera::Options{});
  auto camera = Open({"format=mjpeg", "io=mmap", "readout_us=20000"});
  ASSERT_NE(camera, nullptr);
  auto got = camera->Configure(Small(PixelFormat::kBgr8));
  ASSERT_TRUE(got.ok()) << got.status().ToString();
  EXPECT_EQ(camera->pixel_format(), V4L2_PIX_FMT_MJPEG);
  EXPECT_EQ(got->exposure_us, 10'000);
  EXPECT_NEAR(got->frame_rate_hz, 30.0, 0.01);
  EXPECT_EQ(fake.control(V4L2_CID_EXPOSURE_AUTO), V4L2_EXPOSURE_MANUAL);
  EXPECT_EQ(fake.control(V4L2_CID_EXPOSURE_ABSOLUTE), 100);  // 100 us units
  EXPECT_EQ(fake.control(V4L2_CID_EXPOSURE_AUTO_PRIORITY), 0);
  EXPECT_EQ(fake.control(V4L2_CID_AUTO_WHITE_BALANCE), 0);
  EXPECT_EQ(fake.control(V4L2_CID_WHITE_BALANCE_TEMPERATURE), 4000);  // the camera's default
  EXPECT_EQ(camera->capabilities().readout_us, 20'000);
  ASSERT_TRUE(camera->Start().ok());
  const auto frames = Read(camera.get(), 5);
  ASSERT_EQ(frames.size(), 5u);
  EXPECT_EQ(fake.memory(), "mmap");
  const auto sent = fake.sent();
  ASSERT_GE(sent.size(), 5u);
  for (size_t i = 0; i < frames.size(); ++i) {
    const Frame& f = frames[i];
    EXPECT_EQ(f.frame_id, sent[i].sequence);
    EXPECT_EQ(f.exposure_start_us, sent[i].stamp_us);  // SOE: the stamp is the first row's start
    EXPECT_EQ(f.exposure_us, 10'000);
    EXPECT_EQ(f.readout_us, 20'000);
    EXPECT_EQ(f.ExposureEndUs(), sent[i].stamp_us + 30'000);
    ASSERT_EQ(f.image.type(), CV_8UC3);
    ASSERT_EQ(f.image.size(), sent[i].image.size());
    // JPEG at quality 95: within a few levels of what was encoded.
    cv::Mat diff;
    cv::absdiff(f.image, sent[i].image, diff);
    EXPECT_LT(cv::mean(diff)[0], 3.0) << "frame " << i;
    EXPECT_LT(cv::mean(diff)[2], 3.0) << "frame " << i;
  }
  EXPECT_EQ(camera->capabilities().timestamp, TimestampSource::kExposureStart);
  EXPECT_EQ(camera->counters().dropped, 0u);
  EXPECT_TRUE(camera->Stop().ok());
}

// YUYV through user-pointer buffers, gray: the Y bytes exactly; an end-of-frame stamp converted back to
// the start of exposure.
TEST_F(V4l2Umockdev, YuyvUserptrGrayWithEndOfFrameStamps) {
  FakeUvcCamera::Options options;
  options.start_of_exposure = false;
  FakeUvcCamera fake(options);
  auto camera = Open({"format=yuyv", "io=userptr", "readout_us=15000", "gain=100", "wb_temperature=5000"});
  ASSERT_NE(camera, nullptr);
  auto got = camera->Configure(Small(PixelFormat::kGray8));
  ASSERT_TRUE(got.ok()) << got.status().ToString();
  EXPECT_EQ(camera->pixel_format(), V4L2_PIX_FMT_YUYV);
  EXPECT_EQ(fake.control(V4L2_CID_GAIN), 100);
  EXPECT_EQ(fake.control(V4L2_CID_WHITE_BALANCE_TEMPERATURE), 5000);
  ASSERT_TRUE(camera->Start().ok());
  const auto frames = Read(camera.get(), 4);
  ASSERT_EQ(frames.size(), 4u);
  EXPECT_EQ(fake.memory(), "userptr");
  const auto sent = fake.sent();
  for (size_t i = 0; i < frames.size(); ++i) {
    const Frame& f = frames[i];
    EXPECT_EQ(f.frame_id, sent[i].sequence);
    EXPECT_EQ(f.exposure_start_us, sent[i].stamp_us - 15'000 - 10'000);  // EOF: end - readout - exposure
    EXPECT_EQ(f.ExposureEndUs(), sent[i].stamp_us);
    ASSERT_EQ(f.image.type(), CV_8UC1);
    int mismatches = 0;
    for (int y = 0; y < 48; ++y) {
      for (int x = 0; x < 64; ++x) {
        mismatches += f.image.at<uint8_t>(y, x) != sent[i].bytes[static_cast<size_t>(y * 64 + x) * 2];
      }
    }
    EXPECT_EQ(mismatches, 0) << "frame " << i;
  }
  EXPECT_EQ(camera->capabilities().timestamp, TimestampSource::kFrameEnd);
}

// A frame the camera dropped and a truncated JPEG: both are gaps in the frame ids, counted, no crash.
TEST_F(V4l2Umockdev, DroppedFrameAndCorruptJpegAreGaps) {
  FakeUvcCamera fake(FakeUvcCamera::Options{});
  auto camera = Open({"format=mjpeg"});
  ASSERT_NE(camera, nullptr);
  ASSERT_TRUE(camera->Configure(Small(PixelFormat::kBgr8)).ok());
  ASSERT_TRUE(camera->Start().ok());
  auto frames = Read(camera.get(), 2);  // 0, 1
  fake.DropNextFrame();                  // 2 never arrives
  auto more = Read(camera.get(), 1);     // 3
  fake.CorruptNextFrame();               // 4 is truncated
  auto last = Read(camera.get(), 1);     // 5
  frames.insert(frames.end(), more.begin(), more.end());
  frames.insert(frames.end(), last.begin(), last.end());
  ASSERT_EQ(frames.size(), 4u);
  EXPECT_EQ(frames[0].frame_id, 0u);
  EXPECT_EQ(frames[1].frame_id, 1u);
  EXPECT_EQ(frames[2].frame_id, 3u);
  EXPECT_EQ(frames[3].frame_id, 5u);
  const auto c = camera->counters();
  EXPECT_EQ(c.frames, 4u);
  EXPECT_EQ(c.dropped, 2u);
  EXPECT_EQ(c.corrupt_jpeg, 1u);
  // The frame after the corrupt one is whole.
  cv::Mat diff;
  cv::absdiff(frames[3].image, FakeUvcCamera::MakeImage(64, 48, 5), diff);
  EXPECT_LT(cv::mean(diff)[0], 3.0);
}

TEST_F(V4l2Umockdev, UnplugMidStreamIsADeviceError) {
  FakeUvcCamera fake(FakeUvcCamera::Options{});
  auto camera = Open({});
  ASSERT_NE(camera, nullptr);
  ASSERT_TRUE(camera->Configure(Small(PixelFormat::kBgr8)).ok());
  ASSERT_TRUE(camera->Start().ok());
  ASSERT_EQ(Read(camera.get(), 2).size(), 2u);
  fake.Unplug();
  auto f = camera->NextFrame(1'000'000);
  ASSERT_FALSE(f.ok());
  EXPECT_EQ(f.status().code(), StatusCode::kDeviceError);
  EXPECT_THAT(f.status().message(), HasSubstr("unplugged"));
  EXPECT_FALSE(camera->Stop().ok());  // STREAMOFF fails too; the camera is closed cleanly anyway
}

TEST_F(V4l2Umockdev, ControlNotHeldIsAnErrorNamingIt) {
  FakeUvcCamera::Options options;
  options.ignored_control = V4L2_CID_WHITE_BALANCE_TEMPERATURE;
  FakeUvcCamera fake(options);
  auto camera = Open({"wb_temperature=5000"});
  ASSERT_NE(camera, nullptr);
  auto got = camera->Configure(Small(PixelFormat::kBgr8));
  ASSERT_FALSE(got.ok());
  EXPECT_EQ(got.status().code(), StatusCode::kDeviceError);
  EXPECT_THAT(got.status().message(), HasSubstr("V4L2_CID_WHITE_BALANCE_TEMPERATURE"));
  EXPECT_THAT(got.status().message(), HasSubstr("does not hold"));
}

TEST_F(V4l2Umockdev, MissingControlIsAnErrorNamingIt) {
  FakeUvcCamera::Options options;
  options.missing_control = V4L2_CID_EXPOSURE_ABSOLUTE;
  FakeUvcCamera fake(options);
  auto camera = Open({});
  ASSERT_NE(camera, nullptr);
  EXPECT_FALSE(camera->capabilities().manual_exposure);
  auto got = camera->Configure(Small(PixelFormat::kBgr8));
  ASSERT_FALSE(got.ok());
  EXPECT_EQ(got.status().code(), StatusCode::kDeviceError);
  EXPECT_THAT(got.status().message(), HasSubstr("V4L2_CID_EXPOSURE_ABSOLUTE"));
}

TEST_F(V4l2Umockdev, FactoryOpensAndListsIt) {
  FakeUvcCamera fake(FakeUvcCamera::Options{});
  auto camera = OpenCamera("v4l2:/dev/video0", OpenContext{});
  ASSERT_TRUE(camera.ok()) << camera.status().ToString();
  EXPECT_THAT((*camera)->Description(), HasSubstr("Fake UVC Camera"));
  auto list = ListV4l2Cameras();
  ASSERT_TRUE(list.ok()) << list.status().ToString();
  ASSERT_EQ(list->size(), 1u);
  EXPECT_EQ((*list)[0].spec, "v4l2:/dev/video0");
  EXPECT_THAT((*list)[0].description, HasSubstr("MJPG 64x48 32x24"));
  EXPECT_THAT((*list)[0].description, HasSubstr("YUYV 64x48"));
  auto missing = OpenCamera("v4l2:/dev/video7", OpenContext{});
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.status().code(), StatusCode::kNotFound);
}

TEST_F(V4l2Umockdev, BadOptionsAndRequests) {
  FakeUvcCamera fake(FakeUvcCamera::Options{});
  OpenContext context;
  context.options = {"io=dma"};
  EXPECT_EQ(V4l2Camera::Open("/dev/video0", context).status().code(), StatusCode::kInvalidArgument);
  auto camera = Open({});
  ASSERT_NE(camera, nullptr);
  CameraSettings triggered = Small(PixelFormat::kBgr8);
  triggered.triggered = true;
  EXPECT_EQ(camera->Configure(triggered).status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(camera->Start().code(), StatusCode::kFailedPrecondition);
  EXPECT_EQ(camera->NextFrame(1000).status().code(), StatusCode::kFailedPrecondition);
}

}  // namespace
}  // namespace rotoscan::capture
