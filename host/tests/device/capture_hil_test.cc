// Issue 13's hardware-in-the-loop scan: `capture::RunScan` through the `usb` board backend (the host's real
// libusb transport and device client) against the firmware core behind umockdev's emulated usbdevfs
// (MockUsbBoard, its time following the host's CLOCK_MONOTONIC), with the virtual camera, hardware-
// triggered: each trigger edge the firmware raises on its pin starts an exposure, and the camera renders
// what the simulated lasers and table did during it (the simulator's pin-edge log on the host clock:
// SimRigTruth). The host ties frames to the TRIGGER_EVENTs it receives through its own clock fit, never
// seeing that log. Checked against the truth: every frame written was exposed inside one laser state at its
// step's table angle, and the processed cloud lies on the true sphere.
//
// The usb backend's error paths: a lost OUT packet and a short unplug mid-scan (the client re-sends and
// re-opens, the scan completes); an unplug longer than the reconnect window (a clear error, the board's
// laser safety turns the lasers off, the partial bundle resumes to a complete one with no step lost or
// taken twice).
//
// The same scan with Aravis's fake GenICam camera (the `aravis` backend through the real Aravis stack), its
// fill pattern rendering the virtual scanner at each frame. Aravis 0.8.26's `Fake` interface streams at its
// own rate whatever TriggerMode and TriggerSource say (its stream thread never looks at TriggerSoftware:
// tried, frames keep coming at the frame period with none sent), so that scan is free-running, judged by
// the frames' own timestamps, not hardware-triggered.
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <thread>

#ifdef ROTOSCAN_TEST_ARAVIS
#include <arv.h>

#include <mutex>
#include <optional>

#include <opencv2/imgproc.hpp>

#include "capture/aravis_camera.h"
#include "capture/virtual_render.h"
#include "rotoscan/sim/renderer.h"
#endif
#include "capture/client_board.h"
#include "capture/sim_rig_truth.h"
#include "capture_hil_rig.h"
#include "mock_usb_board.h"
#include "rotoscan/bundle/bundle.h"
#include "rotoscan/capture/factory.h"
#include "rotoscan/capture/scan.h"
#include "rotoscan/sim/scene.h"
#include "fake_board.h"
#include "sim_board.h"

namespace rotoscan::capture {
namespace {

namespace fs = std::filesystem;
using device::testing::MockUsbBoard;
using device::testing::SimBoard;
using testing::HilRig;

constexpr int kSteps = 16;
// The firmware core's unique id ("ROTOSCANSIM1", firmware/port/sim) in hex: its USB serial number string.
const char* const kSimSerial = "524F544F5343414E53494D31";

// The scene, the rig's opening, the scan's options with the check of every frame against the truth, and the
// check of the bundle and its cloud: capture_hil_rig (shared with capture_hil_emu_test).
class CaptureHilTest : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(MockUsbBoard::InMockEnvironment()) << "run this test under umockdev-wrapper (ctest does)";
    dir_ = fs::temp_directory_path() /
           ("rotoscan_capture_hil_" + std::string(::testing::UnitTest::GetInstance()->current_test_info()->name()) +
            "_" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    scene_path_ = dir_ / "scene.json";
    testing::WriteHilScene(scene_path_);
    MockUsbBoard::Options options;
    options.real_time = true;
    options.real_us_per_tick = 100;
    options.serial = kSimSerial;
    usb_ = std::make_unique<MockUsbBoard>(&sim_, options);
    MockUsbBoard* usb = usb_.get();
    truth_ = std::make_unique<internal::SimRigTruth>(usb->device_zero_host_us(), 2.0 * M_PI / testing::kHilStepsPerRev,
                                                     [usb](const std::function<void()>& f) { usb->WithBoardAtNow(f); });
  }
  void TearDown() override {
    if (replug_.joinable()) replug_.join();
    usb_.reset();
    fs::remove_all(dir_);
  }

  HilRig Open(const std::string& spec = "usb", const std::vector<std::string>& camera_options = {}) {
    return testing::OpenHilRig(scene_path_, truth_.get(), kReconnectMs, spec, camera_options);
  }
  // Every frame against the simulator's pin log (one laser state over its whole exposure, the table standing
  // at the step's angle), then the test's own on_frame_ (fault injection).
  ScanOptions Options() {
    return testing::HilScanOptions(
        kSteps, scene_path_, truth_.get(), &frames_checked_,
        [this](const CapturedFrame& c) {
          if (on_frame_) on_frame_(c);
        },
        "capture_hil_test");
  }
  // The bundle holds every (step, laser) once; the cloud lies on the true sphere.
  void CheckBundleAndCloud(const fs::path& bundle_dir, int steps = kSteps) {
    testing::CheckHilBundleAndCloud(bundle_dir, scene_path_, steps);
  }

  // The board unplugged now and plugged in again 300 ms later (within reconnect_ms and the laser safety).
  void UnplugForAWhile() {
    usb_->Unplug();
    replug_ = std::thread([this] {
      std::this_thread::sleep_for(std::chrono::milliseconds(300));
      usb_->Replug();
    });
  }

  static constexpr int kReconnectMs = 1000;
  fs::path dir_;
  fs::path scene_path_;
  SimBoard sim_;
  std::unique_ptr<MockUsbBoard> usb_;
  std::unique_ptr<internal::SimRigTruth> truth_;
  std::thread replug_;
  int frames_checked_ = 0;
  std::function<void(const CapturedFrame&)> on_frame_;
};

TEST_F(CaptureHilTest, TriggeredScanOverTheMockedBusEndsInACloudOnTheSurface) {
  HilRig rig = Open();
  ASSERT_NE(rig.camera, nullptr);
  EXPECT_TRUE(rig.board->capabilities().trigger_output);
  auto summary = RunScan(*rig.board, *rig.camera, *rig.context.clock, dir_ / "b", Options(), nullptr);
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  const ScanSummary& s = summary.value();
  std::printf("%s\n", s.Summary().c_str());
  EXPECT_EQ(s.timing, Timing::kTriggered);
  EXPECT_EQ(s.frames_used, kSteps * 4);
  EXPECT_EQ(frames_checked_, kSteps * 4);
  // The host's clock fit against the board's true clock (device time 0 = device_zero_host_us).
  const auto* client_board = dynamic_cast<internal::ClientBoard*>(rig.board.get());
  ASSERT_NE(client_board, nullptr);
  const double fit_error_us =
      client_board->clock_fit().HostFromDevice(1e6) - static_cast<double>(usb_->device_zero_host_us() + 1'000'000);
  std::printf("clock fit: %.0f us off the board's true clock at 1 s, drift %.2g\n", fit_error_us,
              client_board->clock_fit().drift);
  EXPECT_LT(std::abs(fit_error_us), static_cast<double>(Options().match_tolerance_us));
  rig.board.reset();
  // Lasers off at the end (the pins, not the host's belief).
  EXPECT_FALSE(truth_->LaserAt(0, MonotonicNowUs()));
  EXPECT_FALSE(truth_->LaserAt(1, MonotonicNowUs()));
  CheckBundleAndCloud(dir_ / "b");
}

// The host stalls for longer than the board's laser timeout (a loaded machine): the board stops the program
// and turns the lasers off; the scan resumes it and ends complete, no frame tied to the wrong step.
TEST_F(CaptureHilTest, HostStallTripsLaserSafetyAndTheScanResumes) {
  HilRig rig = Open();
  ASSERT_NE(rig.camera, nullptr);
  bool stalled = false;
  on_frame_ = [&](const CapturedFrame& c) {
    if (c.step == 4 && !stalled) {
      stalled = true;
      std::this_thread::sleep_for(std::chrono::milliseconds(2500));  // > MotionConfig::laser_timeout_ms
    }
  };
  auto summary = RunScan(*rig.board, *rig.camera, *rig.context.clock, dir_ / "b", Options(), nullptr);
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  std::printf("%s\n", summary.value().Summary().c_str());
  EXPECT_EQ(summary.value().frames_used, kSteps * 4);
  rig.board.reset();
  CheckBundleAndCloud(dir_ / "b");
}

TEST_F(CaptureHilTest, DroppedFrameLostPacketAndShortUnplugMidScanStillEndComplete) {
  // And a frame the camera loses (its 23rd exposure, step 5: the id is used, no frame comes): the shot is
  // re-taken.
  HilRig rig = Open("usb", {"drop=22"});
  ASSERT_NE(rig.camera, nullptr);
  bool dropped = false, unplugged = false;
  on_frame_ = [&](const CapturedFrame& c) {
    if (c.step == 4 && !dropped) {
      dropped = true;
      usb_->DropNextOut();
    }
    if (c.step == 9 && !unplugged) {
      unplugged = true;
      UnplugForAWhile();
    }
  };
  auto summary = RunScan(*rig.board, *rig.camera, *rig.context.clock, dir_ / "b", Options(), nullptr);
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  std::printf("%s\n", summary.value().Summary().c_str());
  EXPECT_EQ(summary.value().frames_used, kSteps * 4);
  const auto counters = usb_->counters();
  EXPECT_EQ(counters.dropped, 1);
  EXPECT_EQ(counters.unplugs, 1);
  auto* client_board = dynamic_cast<internal::ClientBoard*>(rig.board.get());
  ASSERT_NE(client_board, nullptr);
  EXPECT_GE(client_board->client().stats().retransmits, 1);
  EXPECT_EQ(client_board->client().stats().reconnects, 1);
  EXPECT_EQ(summary.value().frames_dropped, 1);
  EXPECT_GE(summary.value().shots_retaken, 1);
  rig.board.reset();
  EXPECT_FALSE(truth_->LaserAt(0, MonotonicNowUs()));
  EXPECT_FALSE(truth_->LaserAt(1, MonotonicNowUs()));
  CheckBundleAndCloud(dir_ / "b");
}

TEST_F(CaptureHilTest, UnplugBeyondTheReconnectWindowFailsClearlyLasersOffAndResumes) {
  static_assert(kReconnectMs == 1000, "RunUnplugBeyondTheReconnectWindow expects a 1000 ms window");
  testing::UnplugBeyondRig u;
  u.dir = dir_;
  u.scene_path = scene_path_;
  u.steps = kSteps;
  u.truth = truth_.get();
  u.on_frame = &on_frame_;
  u.open = [this] { return Open(); };
  u.options = [this] { return Options(); };
  u.unplug = [this] { usb_->Unplug(); };
  u.replug = [this] { usb_->Replug(); };
  testing::RunUnplugBeyondTheReconnectWindow(u);
}


// Two boards on the bus: the one scanning (the firmware core, opened as usb:SERIAL) is unplugged mid-scan
// and re-plugged at a new address; the scan finds it again by its serial number, not at its old address,
// and completes. The other board (a FakeBoard with the default description's serial) is never talked to.
TEST_F(CaptureHilTest, TwoBoardsTheReplugedOneIsFoundAgainBySerial) {
  device::testing::FakeBoard other;
  MockUsbBoard::Options other_options;
  other_options.port = 2;
  other_options.address = 3;  // the address the scanning board's re-plug would take next: it must skip it
  MockUsbBoard other_usb(&other, other_options);
  HilRig rig = Open(std::string("usb:") + kSimSerial);
  ASSERT_NE(rig.camera, nullptr);
  EXPECT_EQ(rig.board->info().serial, "524f544f5343414e53494d31");
  const int address_before = usb_->address();
  bool unplugged = false;
  on_frame_ = [&](const CapturedFrame& c) {
    if (c.step == 6 && !unplugged) {
      unplugged = true;
      UnplugForAWhile();
    }
  };
  auto summary = RunScan(*rig.board, *rig.camera, *rig.context.clock, dir_ / "b", Options(), nullptr);
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  std::printf("%s\n", summary.value().Summary().c_str());
  EXPECT_EQ(summary.value().frames_used, kSteps * 4);
  EXPECT_NE(usb_->address(), address_before);
  EXPECT_NE(usb_->address(), other_usb.address());
  auto* client_board = dynamic_cast<internal::ClientBoard*>(rig.board.get());
  ASSERT_NE(client_board, nullptr);
  EXPECT_EQ(client_board->client().stats().reconnects, 1);
  size_t other_commands = 0;
  other_usb.WithBoardLocked([&] { other_commands = other.received.size(); });
  EXPECT_EQ(other_commands, 0u) << "the other board was talked to";
  rig.board.reset();
  EXPECT_FALSE(truth_->LaserAt(0, MonotonicNowUs()));
  EXPECT_FALSE(truth_->LaserAt(1, MonotonicNowUs()));
  CheckBundleAndCloud(dir_ / "b");
}

#ifdef ROTOSCAN_TEST_ARAVIS
// Aravis's fake camera, fed with the virtual scanner's renders of what the simulated rig did during each
// frame. The fake stamps a frame when it fills it (Aravis's system timestamp, which the backend takes as
// the frame's end): the exposure that frame shows is [fill - exposure, fill], exposure being the fake's
// own ExposureTime register as Aravis passes it to the fill pattern.
struct FakeFeed {
  struct Fill {
    int64_t end_us;
    int64_t exposure_us;
  };
  sim::Renderer* renderer = nullptr;
  RigTruth* truth = nullptr;
  double natural_threshold_us = 0;
  std::mutex mutex;
  std::vector<Fill> fills;
  uint64_t count = 0;
  int bad_fills = 0;  // buffers of another format or size than asked for
  ArvBuffer* ignore = nullptr;  // a buffer the test fills itself (a frame never delivered): not recorded

  static void Callback(ArvBuffer* buffer, void* data, guint32 exposure_time_us, guint32, ArvPixelFormat format) {
    auto* feed = static_cast<FakeFeed*>(data);
    const int64_t end = MonotonicNowUs();
    // The truth runs the simulated board up to the present before reading its pin log (WithBoardAtNow):
    // complete up to `end` however late the mock's clock thread is.
    std::lock_guard<std::mutex> lock(feed->mutex);
    const auto& camera = feed->renderer->scene().rig.camera;
    size_t size = 0;
    auto* bytes = static_cast<uint8_t*>(const_cast<void*>(arv_buffer_get_data(buffer, &size)));
    const size_t need = static_cast<size_t>(camera.width) * static_cast<size_t>(camera.height) * 3;
    // The buffer's received size is not set yet when the fake fills it (0): it holds the payload the
    // backend allocated for the configured size and format, checked here by the format.
    (void)size;
    if (format != ARV_PIXEL_FORMAT_RGB_8_PACKED || bytes == nullptr) {
      if (feed->bad_fills++ == 0) {
        std::fprintf(stderr, "fake fill: pixel format 0x%x, %zu bytes, wanted RGB8 and %zu\n", format, size, need);
      }
      return;
    }
    const int64_t exposure = exposure_time_us;
    const cv::Mat bgr = internal::RenderExposure(*feed->renderer, *feed->truth, end - exposure, exposure, 0, feed->count++,
                                                 static_cast<double>(exposure) >= feed->natural_threshold_us,
                                                 PixelFormat::kBgr8);
    cv::Mat rgb(camera.height, camera.width, CV_8UC3, bytes);
    cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
    if (buffer != feed->ignore) feed->fills.push_back({end, exposure});
  }
  // The fill nearest a frame's end as the backend saw it (within `within_us`).
  std::optional<Fill> Nearest(int64_t end_us, int64_t within_us) {
    std::lock_guard<std::mutex> lock(mutex);
    std::optional<Fill> best;
    for (const Fill& f : fills) {
      if (std::llabs(f.end_us - end_us) <= within_us && (!best || std::llabs(f.end_us - end_us) < std::llabs(best->end_us - end_us))) best = f;
    }
    return best;
  }
};

// The Aravis scan: the `usb` board and Aravis's fake camera fed by FakeFeed, free-running. `fault` (may be
// null) runs after each frame written, with the fake camera at hand (fault injection). Every frame written is
// checked against the fill it came from (its true window inside one laser state, at the step's angle); the
// bundle holds every (step, laser) once and its cloud lies on the true sphere.
class CaptureHilAravisTest : public CaptureHilTest {
 protected:
  static constexpr int kAravisSteps = 8;
  struct Outcome {
    ScanSummary summary;
    AravisCounters counters;
  };
  using Fault = std::function<void(const CapturedFrame&, ArvFakeCamera*)>;

  void Scan(const Fault& fault, Outcome* outcome) {
    // Only Aravis's fake interface: discovery elsewhere waits for the network and could find real cameras.
    for (unsigned i = 0; i < arv_get_n_interfaces(); ++i) {
      const std::string id = arv_get_interface_id(i);
      if (id != "Fake") arv_disable_interface(id.c_str());
    }
    arv_enable_interface("Fake");
    HilRig rig;
    rig.context.options = {"steps_per_rev=" + std::to_string(testing::kHilStepsPerRev),
                           "reconnect_ms=" + std::to_string(kReconnectMs)};
    auto board = OpenBoard("usb", &rig.context);
    ASSERT_TRUE(board.ok()) << board.status().ToString();
    rig.board = std::move(board).value();
    rig.context.options.clear();
    auto opened = OpenCamera("aravis:Fake_1", rig.context);
    ASSERT_TRUE(opened.ok()) << opened.status().ToString();
    rig.camera = std::move(opened).value();
    auto* aravis = dynamic_cast<AravisCamera*>(rig.camera.get());
    ASSERT_NE(aravis, nullptr);

    auto scene = sim::LoadScene(scene_path_);
    ASSERT_TRUE(scene.ok());
    auto renderer = sim::Renderer::Create(scene.value());
    ASSERT_TRUE(renderer.ok()) << renderer.status().ToString();
    FakeFeed feed;
    feed.renderer = renderer.value().get();
    feed.truth = truth_.get();
    feed.natural_threshold_us = internal::NaturalThresholdUs(scene.value());
    CameraSettings settings;
    settings.width = scene.value().rig.camera.width;
    settings.height = scene.value().rig.camera.height;
    settings.format = PixelFormat::kBgr8;
    auto configured = rig.camera->Configure(settings);
    ASSERT_TRUE(configured.ok()) << configured.status().ToString();
    ArvFakeCamera* fake =
        arv_fake_device_get_fake_camera(ARV_FAKE_DEVICE(arv_camera_get_device(aravis->arv_camera())));
    arv_fake_camera_set_fill_pattern(fake, &FakeFeed::Callback, &feed);
    fake_feed_ = &feed;

    ScanOptions o = Options();
    o.steps = kAravisSteps;
    o.timing = Timing::kFreeRunning;
    // Check each frame written against the fill it came from: its true window inside one laser state.
    int checked = 0;
    o.on_frame = [&](const CapturedFrame& c) {
      const auto fill = feed.Nearest(c.frame->ExposureEndUs(), 15'000);
      EXPECT_TRUE(fill.has_value()) << "step " << c.step << ": no fill of the fake camera near this frame";
      if (fill) {
        const int64_t start = fill->end_us - fill->exposure_us;
        EXPECT_EQ(fill->exposure_us, c.laser == bundle::LaserState::kNatural ? 20000 : 2000) << "step " << c.step;
        EXPECT_TRUE(truth_->LaserSwitches(start, fill->end_us).empty())
            << "step " << c.step << " " << bundle::LaserStateName(c.laser) << " exposed across a laser switch";
        double left = 0, right = 0;
        truth_->LaserFractions(start, fill->end_us, &left, &right);
        EXPECT_EQ(left, c.laser == bundle::LaserState::kLeft ? 1.0 : 0.0) << "step " << c.step;
        EXPECT_EQ(right, c.laser == bundle::LaserState::kRight ? 1.0 : 0.0) << "step " << c.step;
        EXPECT_NEAR(truth_->TableAngleAt(start), c.table_angle_rad, 1e-9) << "step " << c.step;
        EXPECT_NEAR(truth_->TableAngleAt(fill->end_us), c.table_angle_rad, 1e-9) << "step " << c.step;
        ++checked;
      }
      if (fault) fault(c, fake);
      return Status::Ok();
    };
    auto summary = RunScan(*rig.board, *rig.camera, *rig.context.clock, dir_ / "b", o, nullptr);
    if (fault_thread_.joinable()) fault_thread_.join();
    arv_fake_camera_set_fill_pattern(fake, nullptr, nullptr);
    fake_feed_ = nullptr;
    ASSERT_TRUE(summary.ok()) << summary.status().ToString();
    std::printf("aravis fake: %s\n", summary.value().Summary().c_str());
    EXPECT_EQ(summary.value().timing, Timing::kFreeRunning);
    EXPECT_EQ(summary.value().frames_used, kAravisSteps * 4);
    EXPECT_EQ(checked, kAravisSteps * 4);
    EXPECT_EQ(feed.bad_fills, 0);
    outcome->summary = summary.value();
    outcome->counters = aravis->counters();
    rig.camera.reset();
    rig.board.reset();
    CheckBundleAndCloud(dir_ / "b", kAravisSteps);
  }

  FakeFeed* fake_feed_ = nullptr;
  std::thread fault_thread_;
};

TEST_F(CaptureHilAravisTest, FreeRunningOverTheMockedBusEndsInACloudOnTheSurface) {
  Outcome outcome;
  Scan(nullptr, &outcome);
  EXPECT_EQ(outcome.counters.dropped, 0u);
}

// Faults in the Aravis scan, each ending in a complete bundle with every frame checked against the truth:
//  * a dropped frame: the fake camera fills one frame that never reaches the host (a frame id gap, as a frame
//    lost on the link); the state it would have served is taken from a later frame;
//  * a lost buffer: for 50 ms the fake's Width register says more than the buffers hold, so Aravis completes
//    buffers with an error status (as with missing packets): the backend drops them;
//  * a stall: the host takes no frame for 500 ms, the stream's buffers run out (frames lost) and those
//    waiting are stale: judged by their timestamps, none is used for a state it did not see;
//  * a lost USB packet to the board (the client re-sends).
TEST_F(CaptureHilAravisTest, DroppedFrameLostBufferStallAndLostPacketEndComplete) {
  bool dropped = false, lost = false, stalled = false, packet = false;
  ArvBuffer* never_delivered = nullptr;
  Outcome outcome;
  Scan(
      [&](const CapturedFrame& c, ArvFakeCamera* fake) {
        if (c.step == 1 && !packet) {
          packet = true;
          usb_->DropNextOut();
        }
        if (c.step == 2 && c.laser == bundle::LaserState::kRight && !dropped) {
          dropped = true;
          // The camera exposes and sends a frame the host never gets: the next frame's id skips one.
          never_delivered = arv_buffer_new(arv_fake_camera_get_payload(fake), nullptr);
          fake_feed_->ignore = never_delivered;
          arv_fake_camera_fill_buffer(fake, never_delivered, nullptr);
        }
        if (c.step == 4 && c.laser == bundle::LaserState::kLeft && !lost) {
          lost = true;
          guint32 width = 0;
          arv_fake_camera_read_register(fake, ARV_FAKE_CAMERA_REGISTER_WIDTH, &width);
          arv_fake_camera_write_register(fake, ARV_FAKE_CAMERA_REGISTER_WIDTH, width + 64);
          fault_thread_ = std::thread([fake, width] {
            std::this_thread::sleep_for(std::chrono::milliseconds(50));
            arv_fake_camera_write_register(fake, ARV_FAKE_CAMERA_REGISTER_WIDTH, width);
          });
        }
        if (c.step == 6 && c.laser == bundle::LaserState::kOff && !stalled) {
          stalled = true;
          std::this_thread::sleep_for(std::chrono::milliseconds(500));  // < the board's 2 s laser timeout
        }
      },
      &outcome);
  if (never_delivered != nullptr) g_object_unref(never_delivered);
  EXPECT_TRUE(dropped && lost && stalled && packet);
  std::printf("aravis counters: %llu frames, %llu dropped, %llu failed buffers\n",
              static_cast<unsigned long long>(outcome.counters.frames),
              static_cast<unsigned long long>(outcome.counters.dropped),
              static_cast<unsigned long long>(outcome.counters.failed));
  EXPECT_GE(outcome.summary.frames_dropped, 1) << "the frame id gap was not seen";
  EXPECT_GE(outcome.counters.failed, 1u) << "no buffer completed with an error status";
  EXPECT_GE(outcome.counters.dropped, 2u);
  EXPECT_EQ(usb_->counters().dropped, 1);
}
#endif  // ROTOSCAN_TEST_ARAVIS

}  // namespace
}  // namespace rotoscan::capture
