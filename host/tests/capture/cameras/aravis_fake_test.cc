// The aravis camera backend through the real Aravis stack, against Aravis's own fake GenICam camera (its
// "Fake" interface: the GenICam XML, feature nodes, register map and stream thread are Aravis's). The
// fake's fill pattern is ours: a synthetic image that carries a serial number in its first pixels, so each
// frame that comes through can be compared byte for byte with what the camera "exposed".
#include <arv.h>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cstring>
#include <mutex>
#include <vector>

#include <opencv2/core.hpp>

#include "capture/aravis_camera.h"
#include "rotoscan/capture/factory.h"

namespace rotoscan::capture {
namespace {

using ::testing::HasSubstr;

// Only Aravis's fake interface: discovery on the GigE Vision and USB3 Vision interfaces would wait for
// answers from the network (a second per search) and could find real cameras.
class OnlyFakeInterface : public ::testing::Environment {
 public:
  void SetUp() override {
    for (unsigned i = 0; i < arv_get_n_interfaces(); ++i) {
      const std::string id = arv_get_interface_id(i);
      if (id != "Fake") arv_disable_interface(id.c_str());
    }
    arv_enable_interface("Fake");
  }
};
const auto* const kEnvironment = ::testing::AddGlobalTestEnvironment(new OnlyFakeInterface);

constexpr int kWidth = 64;
constexpr int kHeight = 48;

// What the fake camera was given to expose, keyed by serial.
struct Pattern {
  std::mutex mutex;
  uint32_t next = 1;
  std::vector<cv::Mat> images;  // images[serial - 1]

  static cv::Mat Make(uint32_t serial) {
    cv::Mat m(kHeight, kWidth, CV_8UC1);
    for (int y = 0; y < kHeight; ++y) {
      for (int x = 0; x < kWidth; ++x) m.at<uint8_t>(y, x) = static_cast<uint8_t>((x * 3 + y * 5 + serial * 7) & 0xff);
    }
    std::memcpy(m.data, &serial, sizeof(serial));  // the serial in the first 4 pixels
    return m;
  }
};

void Fill(ArvBuffer* buffer, void* data, guint32, guint32, ArvPixelFormat) {
  auto* pattern = static_cast<Pattern*>(data);
  size_t size = 0;
  auto* bytes = static_cast<uint8_t*>(const_cast<void*>(arv_buffer_get_data(buffer, &size)));
  std::lock_guard<std::mutex> lock(pattern->mutex);
  const cv::Mat image = Pattern::Make(pattern->next++);
  pattern->images.push_back(image);
  // The received size is not set yet (0); the buffer holds the payload, at least width x height bytes.
  (void)size;
  std::memcpy(bytes, image.data, image.total());
}

uint32_t SerialOf(const cv::Mat& image) {
  uint32_t serial = 0;
  std::memcpy(&serial, image.data, sizeof(serial));
  return serial;
}

ArvFakeCamera* FakeOf(AravisCamera* camera) {
  return arv_fake_device_get_fake_camera(ARV_FAKE_DEVICE(arv_camera_get_device(camera->arv_camera())));
}

std::unique_ptr<AravisCamera> OpenFake(const std::vector<std::string>& options = {}) {
  OpenContext context;
  context.options = options;
  auto camera = AravisCamera::Open("Fake_1", context);
  EXPECT_TRUE(camera.ok()) << camera.status().ToString();
  return camera.ok() ? std::move(camera).value() : nullptr;
}

CameraSettings Small() {
  CameraSettings s;
  s.width = kWidth;
  s.height = kHeight;
  s.format = PixelFormat::kGray8;
  s.frame_rate_hz = 200.0;
  s.exposure_us = 2'000;
  s.gain_db = 3.0;  // the fake's GainRaw: 0..10
  return s;
}

std::string Feature(AravisCamera* camera, const char* name) {
  GError* error = nullptr;
  const char* v = arv_camera_get_string(camera->arv_camera(), name, &error);
  g_clear_error(&error);
  return v != nullptr ? v : "";
}

TEST(AravisFake, FreeRunningFramesAreWhatTheCameraExposed) {
  auto camera = OpenFake();
  ASSERT_NE(camera, nullptr);
  EXPECT_TRUE(camera->capabilities().trigger_input);
  EXPECT_TRUE(camera->capabilities().device_timestamps);
  EXPECT_FALSE(camera->capabilities().exposure_active_output);  // the fake has no LineSelector
  auto got = camera->Configure(Small());
  ASSERT_TRUE(got.ok()) << got.status().ToString();
  EXPECT_EQ(got->width, kWidth);
  EXPECT_EQ(got->exposure_us, 2'000);
  GError* error = nullptr;
  EXPECT_DOUBLE_EQ(arv_camera_get_exposure_time(camera->arv_camera(), &error), 2'000.0);
  EXPECT_DOUBLE_EQ(arv_camera_get_gain(camera->arv_camera(), &error), 3.0);
  EXPECT_EQ(Feature(camera.get(), "TriggerMode"), "Off");
  EXPECT_EQ(Feature(camera.get(), "PixelFormat"), "Mono8");
  ASSERT_EQ(error, nullptr);

  Pattern pattern;
  arv_fake_camera_set_fill_pattern(FakeOf(camera.get()), &Fill, &pattern);
  const int64_t before = MonotonicNowUs();
  ASSERT_TRUE(camera->Start().ok());
  std::vector<Frame> frames;
  for (int i = 0; i < 6; ++i) {
    auto f = camera->NextFrame(2'000'000);
    ASSERT_TRUE(f.ok()) << f.status().ToString();
    ASSERT_TRUE(f.value().has_value()) << "no frame within 2 s";
    frames.push_back(std::move(*std::move(f).value()));
  }
  ASSERT_TRUE(camera->Stop().ok());
  const int64_t after = MonotonicNowUs();

  std::lock_guard<std::mutex> lock(pattern.mutex);
  for (size_t i = 0; i < frames.size(); ++i) {
    const Frame& f = frames[i];
    ASSERT_EQ(f.image.type(), CV_8UC1);
    const uint32_t serial = SerialOf(f.image);
    ASSERT_GE(serial, 1u);
    ASSERT_LE(serial, pattern.images.size());
    EXPECT_EQ(cv::norm(f.image, pattern.images[serial - 1], cv::NORM_INF), 0.0) << "frame " << i;
    EXPECT_EQ(f.exposure_us, 2'000);
    ASSERT_TRUE(f.device_time_us.has_value());
    // Exposure windows on the host clock, inside the acquisition.
    EXPECT_GE(f.exposure_start_us, before - 2'000 - 1'000);
    EXPECT_LE(f.ExposureEndUs(), after);
    if (i > 0) {
      const Frame& p = frames[i - 1];
      EXPECT_GT(serial, SerialOf(p.image));
      EXPECT_GT(f.frame_id, p.frame_id);
      // A gap in frame ids is exactly a frame that was filled and not delivered.
      EXPECT_EQ(f.frame_id - p.frame_id, serial - SerialOf(p.image));
      EXPECT_GT(*f.device_time_us, *p.device_time_us);
      EXPECT_GT(f.exposure_start_us, p.exposure_start_us);
    }
  }
  EXPECT_EQ(camera->counters().frames, 6u);
}

TEST(AravisFake, TriggeredOnALineInput) {
  auto camera = OpenFake({"trigger_line=Line0"});
  ASSERT_NE(camera, nullptr);
  CameraSettings s = Small();
  s.triggered = true;
  auto got = camera->Configure(s);
  ASSERT_TRUE(got.ok()) << got.status().ToString();
  EXPECT_EQ(Feature(camera.get(), "TriggerMode"), "On");
  EXPECT_EQ(Feature(camera.get(), "TriggerSource"), "Line0");
  EXPECT_EQ(camera->trigger_source(), "Line0");
  EXPECT_THAT(camera->Description(), HasSubstr("triggered on Line0"));
  // The fake raises its line input at a set frequency: the board's trigger output.
  arv_fake_camera_set_trigger_frequency(FakeOf(camera.get()), 100.0);
  ASSERT_TRUE(camera->Start().ok());
  uint64_t last_id = 0;
  uint64_t last_time = 0;
  for (int i = 0; i < 4; ++i) {
    auto f = camera->NextFrame(2'000'000);
    ASSERT_TRUE(f.ok()) << f.status().ToString();
    ASSERT_TRUE(f.value().has_value());
    if (i > 0) {
      EXPECT_GT((*f)->frame_id, last_id);
      EXPECT_GT(*(*f)->device_time_us, last_time);
    }
    last_id = (*f)->frame_id;
    last_time = *(*f)->device_time_us;
  }
  ASSERT_TRUE(camera->Stop().ok());
}

TEST(AravisFake, SettingsTheCameraDoesNotHoldAreErrorsNamingTheFeature) {
  auto camera = OpenFake();
  ASSERT_NE(camera, nullptr);
  CameraSettings s = Small();
  s.gain_db = 20.0;  // beyond the fake's GainRaw range
  auto got = camera->Configure(s);
  ASSERT_FALSE(got.ok());
  EXPECT_EQ(got.status().code(), StatusCode::kInvalidArgument);
  EXPECT_THAT(got.status().message(), HasSubstr("GainRaw"));

  auto wired = OpenFake({"exposure_line=Line1"});
  ASSERT_NE(wired, nullptr);
  got = wired->Configure(Small());
  ASSERT_FALSE(got.ok());
  EXPECT_THAT(got.status().message(), HasSubstr("LineSelector"));

  auto bad_line = OpenFake({"trigger_line=Line7"});
  ASSERT_NE(bad_line, nullptr);
  CameraSettings t = Small();
  t.triggered = true;
  got = bad_line->Configure(t);
  ASSERT_FALSE(got.ok());
  EXPECT_THAT(got.status().message(), HasSubstr("TriggerSource"));
  EXPECT_THAT(got.status().message(), HasSubstr("Line0"));  // the values it has
}

TEST(AravisFake, MissingCameraIsAClearError) {
  OpenContext context;
  auto camera = OpenCamera("aravis:Fake_9", context);
  ASSERT_FALSE(camera.ok());
  EXPECT_EQ(camera.status().code(), StatusCode::kNotFound);
  EXPECT_THAT(camera.status().message(), HasSubstr("Fake_9"));
  EXPECT_THAT(camera.status().message(), HasSubstr("Fake_1"));  // what was found
  auto opened = OpenCamera("aravis:Fake_1", context);
  ASSERT_TRUE(opened.ok()) << opened.status().ToString();
  auto list = ListAravisCameras();
  ASSERT_TRUE(list.ok());
  bool found = false;
  for (const auto& d : *list) found |= d.spec == "aravis:Fake_1";
  EXPECT_TRUE(found);
}

TEST(AravisFrameIds, SixteenBitBlockIdsWrapWithoutZero) {
  FrameIdExtender ids;
  EXPECT_EQ(ids.Extend(65534), 65534u);
  EXPECT_EQ(ids.Extend(65535), 65535u);
  EXPECT_EQ(ids.Extend(1), 65536u);  // 0 is skipped on the wire
  EXPECT_EQ(ids.Extend(3), 65538u);  // a dropped frame stays a gap
  FrameIdExtender wide;
  EXPECT_EQ(wide.Extend(100000), 100000u);
  EXPECT_EQ(wide.Extend(100001), 100001u);
}

}  // namespace
}  // namespace rotoscan::capture
