// Issue 18's scan on the flashed image: `capture::RunScan` through the `usb` board backend (the host's real
// libusb transport and device client) against rotoscan-fw.elf running on the emulated STM32F411
// (firmware/tests/emu, EmuBoard) behind umockdev's emulated usbdevfs (MockUsbBoard, the emulated time
// following the host's CLOCK_MONOTONIC), with the virtual camera, hardware-triggered: each rising edge the
// image raises on its trigger pin (TIM2's output compare) starts an exposure, and the camera renders what
// the image's laser pins and STEP pulses did during it (the emulator's pin-edge log on the host clock:
// EmuRigTruth). The host ties frames to the TRIGGER_EVENTs it receives through its own clock fit, never
// seeing that log. Checked against the truth: every frame written was exposed inside one laser state at its
// step's table angle, the bundle is complete, and the processed cloud lies on the true sphere. The same
// checks as capture_hil_test, which runs the firmware core built for the host instead of the image.
//
// Faults on the mocked endpoint: a lost, a corrupted and a duplicated OUT packet and a 300 ms unplug (the
// kernel re-enumerates the image; the client re-opens, the scan completes); an unplug past the reconnect
// window (a clear error; the image's laser-safety timeout turns its laser pins off; the bundle resumes).
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>
#include <thread>

#include "capture/client_board.h"
#include "capture_hil_rig.h"
#include "emu_board.h"
#include "emu_rig_truth.h"
#include "mock_usb_board.h"
#include "rotoscan/capture/scan.h"

namespace rotoscan::capture {
namespace {

namespace fs = std::filesystem;
using device::testing::EmuBoard;
using device::testing::EmuRigTruth;
using device::testing::MockUsbBoard;
using testing::CheckHilBundleAndCloud;
using testing::HilRig;

constexpr int kSteps = 16;

class CaptureHilEmuTest : public ::testing::Test {
 protected:
  void SetUp() override {
    ROTOSCAN_SKIP_WITHOUT_FW_IMAGE();
    ASSERT_TRUE(MockUsbBoard::InMockEnvironment()) << "run this test under umockdev-wrapper (ctest does)";
    dir_ = fs::temp_directory_path() /
           ("rotoscan_capture_hil_emu_" +
            std::string(::testing::UnitTest::GetInstance()->current_test_info()->name()) + "_" +
            std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    scene_path_ = dir_ / "scene.json";
    testing::WriteHilScene(scene_path_);
    std::string error;
    ASSERT_TRUE(board_.Boot(&error)) << error;
    // The mock's clock starts with the emulated cycle count where Boot left it: device and host time from
    // there on (nothing else runs the emulator before the mock's clock thread).
    const uint64_t zero_cycle = board_.emu().cycles();
    MockUsbBoard::Options options;
    options.real_time = true;
    options.real_us_per_tick = 100;
    usb_ = std::make_unique<MockUsbBoard>(&board_, options);
    truth_ =
        std::make_unique<EmuRigTruth>(usb_.get(), &board_, zero_cycle, 2.0 * M_PI / testing::kHilStepsPerRev);
  }
  void TearDown() override {
    if (replug_.joinable()) replug_.join();
    usb_.reset();
    if (!dir_.empty()) fs::remove_all(dir_);
  }

  ScanOptions Options() {
    return testing::HilScanOptions(
        kSteps, scene_path_, truth_.get(), &frames_checked_,
        [this](const CapturedFrame& c) {
          if (on_frame_) on_frame_(c);
        },
        "capture_hil_emu_test");
  }
  std::string EmuError() {
    std::string e;
    usb_->WithBoardLocked([&] { e = board_.error(); });
    return e;
  }
  // Unplugs now and re-plugs after `ms` of real time, the kernel enumerating the image again first.
  void UnplugFor(int ms) {
    usb_->Unplug();
    replug_ = std::thread([this, ms] {
      std::this_thread::sleep_for(std::chrono::milliseconds(ms));
      std::string error;
      usb_->WithBoardLocked([&] { replug_ok_ = board_.Reenumerate(&error); });
      replug_error_ = error;
      usb_->Replug();
    });
  }
  // The host's clock fit against the emulated board's true clock (printed), within `tolerance_us` at 1 s:
  // device time d (TIM2 less its count at the image's fw_init, core/timebase.c g_tb) is host time
  // zero + d - (TIM2 at zero - boot).
  void CheckClockFit(const HilRig& rig, int64_t tolerance_us) {
    const auto* client_board = dynamic_cast<const internal::ClientBoard*>(rig.board.get());
    ASSERT_NE(client_board, nullptr);
    const double fit_error_us =
        client_board->clock_fit().HostFromDevice(1e6) - static_cast<double>(DeviceToHostUs(1'000'000));
    std::printf("clock fit: %.0f us off the emulated board's true clock at 1 s, drift %.2g\n", fit_error_us,
                client_board->clock_fit().drift);
    EXPECT_LT(std::abs(fit_error_us), static_cast<double>(tolerance_us));
  }
  int64_t DeviceToHostUs(int64_t device_us) {
    int64_t host = 0;
    usb_->WithBoardLocked([&] {
      fw_emu::F411Emu& emu = board_.emu();
      const uint64_t now = emu.cycles();
      const uint32_t device_now = emu.Tim2Now() - emu.Peek(emu.image().Symbol("g_tb"));
      host = truth_->HostUs(now) + (device_us - static_cast<int64_t>(device_now));
    });
    return host;
  }

  fs::path dir_;
  fs::path scene_path_;
  EmuBoard board_;
  std::unique_ptr<MockUsbBoard> usb_;
  std::unique_ptr<EmuRigTruth> truth_;
  std::thread replug_;
  bool replug_ok_ = false;
  std::string replug_error_;
  int frames_checked_ = 0;
  std::function<void(const CapturedFrame&)> on_frame_;
};

TEST_F(CaptureHilEmuTest, TriggeredScanOnTheImageEndsInACloudOnTheSurface) {
  HilRig rig = testing::OpenHilRig(scene_path_, truth_.get());
  ASSERT_NE(rig.camera, nullptr);
  EXPECT_TRUE(rig.board->capabilities().trigger_output);
  auto summary = RunScan(*rig.board, *rig.camera, *rig.context.clock, dir_ / "b", Options(), nullptr);
  ASSERT_TRUE(summary.ok()) << summary.status().ToString() << " / " << EmuError();
  const ScanSummary& s = summary.value();
  std::printf("%s\n", s.Summary().c_str());
  EXPECT_EQ(s.timing, Timing::kTriggered);
  EXPECT_EQ(s.frames_used, kSteps * 4);
  EXPECT_EQ(frames_checked_, kSteps * 4);
  CheckClockFit(rig, Options().match_tolerance_us);
  rig.board.reset();
  // Lasers off at the end (the image's pins, not the host's belief).
  EXPECT_FALSE(truth_->LaserAt(0, MonotonicNowUs()));
  EXPECT_FALSE(truth_->LaserAt(1, MonotonicNowUs()));
  std::printf("the emulator ran at most %.1f ms behind the host\n", truth_->max_wait_us() / 1000.0);
  CheckHilBundleAndCloud(dir_ / "b", scene_path_, kSteps);
  EXPECT_EQ(EmuError(), "");
}

TEST_F(CaptureHilEmuTest, LostCorruptedDuplicatedPacketsAndAShortUnplugStillEndComplete) {
  HilRig rig = testing::OpenHilRig(scene_path_, truth_.get());
  ASSERT_NE(rig.camera, nullptr);
  bool unplugged = false;
  on_frame_ = [&](const CapturedFrame& c) {
    const MockUsbBoard::Counters n = usb_->counters();
    if (c.step >= 3 && n.dropped == 0) usb_->DropNextOut();
    if (c.step >= 5 && n.corrupted == 0) usb_->CorruptNextOut();
    if (c.step >= 7 && n.duplicated == 0) usb_->DuplicateNextOut();
    if (c.step == 10 && !unplugged) {
      unplugged = true;
      UnplugFor(300);  // within reconnect_ms and the image's laser-safety timeout
    }
  };
  auto summary = RunScan(*rig.board, *rig.camera, *rig.context.clock, dir_ / "b", Options(), nullptr);
  ASSERT_TRUE(summary.ok()) << summary.status().ToString() << " / " << EmuError();
  std::printf("%s\n", summary.value().Summary().c_str());
  EXPECT_EQ(summary.value().frames_used, kSteps * 4);
  const MockUsbBoard::Counters counters = usb_->counters();
  EXPECT_EQ(counters.dropped, 1);
  EXPECT_EQ(counters.corrupted, 1);
  EXPECT_EQ(counters.duplicated, 1);
  EXPECT_EQ(counters.unplugs, 1);
  if (replug_.joinable()) replug_.join();
  EXPECT_TRUE(replug_ok_) << replug_error_;
  auto* client_board = dynamic_cast<internal::ClientBoard*>(rig.board.get());
  ASSERT_NE(client_board, nullptr);
  EXPECT_GE(client_board->client().stats().retransmits, 1);  // which frames the faults hit depends on timing
  EXPECT_EQ(client_board->client().stats().reconnects, 1);
  rig.board.reset();
  EXPECT_FALSE(truth_->LaserAt(0, MonotonicNowUs()));
  EXPECT_FALSE(truth_->LaserAt(1, MonotonicNowUs()));
  CheckHilBundleAndCloud(dir_ / "b", scene_path_, kSteps);
  EXPECT_EQ(EmuError(), "");
}

TEST_F(CaptureHilEmuTest, UnplugBeyondTheReconnectWindowFailsClearlyLasersOffAndResumes) {
  // The image is re-enumerated before the re-plug (its USB stack starts over, as after a real re-plug).
  testing::UnplugBeyondRig u;
  u.dir = dir_;
  u.scene_path = scene_path_;
  u.steps = kSteps;
  u.truth = truth_.get();
  u.on_frame = &on_frame_;
  u.open = [this] { return testing::OpenHilRig(scene_path_, truth_.get()); };
  u.options = [this] { return Options(); };
  u.unplug = [this] { usb_->Unplug(); };
  u.replug = [this] {
    std::string error;
    usb_->WithBoardLocked([&] { ASSERT_TRUE(board_.Reenumerate(&error)) << error; });
    usb_->Replug();
  };
  u.context = [this] { return EmuError(); };
  testing::RunUnplugBeyondTheReconnectWindow(u);
}

}  // namespace
}  // namespace rotoscan::capture
