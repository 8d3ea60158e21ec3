// Issue 18, hardware in the loop with the flashed image: the host's real libusb transport and client, through
// umockdev's emulated usbdevfs (mock_usb_board), talk to rotoscan-fw.elf running on the emulated STM32F411
// (firmware/tests/emu, EmuBoard): each bulk URB becomes OUT or IN transactions on the emulated OTG_FS core.
// A 16-step scan program (short, to keep the test near a second) with the
// faults of hil_sim_test injected on the mocked endpoint -- a lost packet, a corrupted byte, a duplicated
// command, an unplug long enough for the image's laser-safety timeout to stop the program, a re-plug (the
// harness re-enumerates the board as the kernel would) and a resume. Every TRIGGER_EVENT is checked against
// the emulator's pin edges: the TIM2 count of the trigger's rising edge exact to the tick, the laser pins and
// the table position at it, no (step, shot) lost or taken twice.
#include <gtest/gtest.h>

#include <chrono>
#include <thread>
#include <utility>

#include "emu_board.h"
#include "hil_common.h"
#include "mock_usb_board.h"
#include "rotoscan/device/client.h"
#include "rotoscan_protocol.h"

namespace rotoscan::device {
namespace {

using testing::CheckHilShots;
using testing::DecodeEmuLog;
using testing::EmuBoard;
using testing::HilConfig;
using testing::HilFaults;
using testing::HilProgram;
using testing::HilScanResult;
using testing::MockUsbBoard;
using testing::PinLogDecoder;
using testing::RunHilScan;

constexpr uint32_t kSteps = 16;
constexpr uint32_t kLaserTimeoutMs = 100;  // the least SET_CONFIG takes

class HilEmuTest : public ::testing::Test {
 protected:
  void SetUp() override {
    ROTOSCAN_SKIP_WITHOUT_FW_IMAGE();
    ASSERT_TRUE(MockUsbBoard::InMockEnvironment()) << "run this test under umockdev-wrapper (ctest does)";
    std::string error;
    ASSERT_TRUE(board_.Boot(&error)) << error;
    MockUsbBoard::Options o;
    // The image sleeps (WFI) most of a scan and the emulator skips that time, so board time could outrun the
    // host's 20 ms keep-alive: at most 200 us of board time per 100 us of real time.
    o.virtual_us_per_tick = 200;
    o.real_us_per_tick = 100;
    usb_ = std::make_unique<MockUsbBoard>(&board_, o);
    ClientOptions options;
    options.ack_timeout_us = 150'000;
    auto transport = MakeLibusbTransport();
    ASSERT_TRUE(transport.ok()) << transport.status().ToString();
    auto client = Client::Connect(std::move(transport).value(), options);
    ASSERT_TRUE(client.ok()) << client.status().ToString() << " / " << board_.error();
    client_ = std::move(client).value();
  }
  void TearDown() override {
    if (replug_.joinable()) replug_.join();
    client_.reset();
    usb_.reset();
  }

  uint64_t BoardCycles() {
    uint64_t c = 0;
    usb_->WithBoardLocked([&] { c = board_.emu().cycles(); });
    return c;
  }

  // The scan (RunHilScan) with the faults at 2, 4, 6 and 10 triggers: the unplug lasts until the board has
  // run twice its laser timeout on its own; the kernel enumerates it again before libusb sees it.
  HilScanResult RunScan(bool with_faults) {
    HilFaults faults;
    if (with_faults) {
      faults = {2, 4, 6, 10, [this] {
                  usb_->Unplug();
                  const uint64_t from = BoardCycles();
                  replug_ = std::thread([this, from] {
                    while (BoardCycles() - from < 2ull * kLaserTimeoutMs * 96'000) {
                      std::this_thread::sleep_for(std::chrono::milliseconds(5));
                    }
                    std::string error;
                    usb_->WithBoardLocked([&] { replug_ok_ = board_.Reenumerate(&error); });
                    replug_error_ = error;
                    usb_->Replug();
                  });
                }};
    }
    HilScanResult scan = RunHilScan(*client_, *usb_, HilConfig(kLaserTimeoutMs), HilProgram(kSteps), faults,
                                    std::chrono::seconds(90), [this] { return board_.error(); });
    if (replug_.joinable()) replug_.join();
    return scan;
  }

  void CheckAgainstEdges(const HilScanResult& scan) {
    PinLogDecoder log;
    usb_->WithBoardLocked([&] { log = DecodeEmuLog(board_.emu()); });
    CheckHilShots(scan, HilProgram(kSteps), log.triggers(), log.step_pulses());
  }

  EmuBoard board_;
  std::unique_ptr<MockUsbBoard> usb_;
  std::unique_ptr<Client> client_;
  std::thread replug_;
  bool replug_ok_ = false;
  std::string replug_error_;
};

TEST_F(HilEmuTest, EnumerateClaimAndGetInfo) {
  const DeviceInfo& info = client_->info();
  EXPECT_EQ(info.protocol_major, PROTO_VERSION_MAJOR);
  EXPECT_FALSE(info.simulated);
  auto fit = client_->SyncClock(5);
  ASSERT_TRUE(fit.ok()) << fit.status().ToString();
  EXPECT_EQ(board_.error(), "");
}

TEST_F(HilEmuTest, ScanOf16StepsEveryTriggerArrivesRight) {
  const HilScanResult scan = RunScan(/*with_faults=*/false);
  if (!scan.safety_seen) {
    EXPECT_EQ(scan.triggers_seen, static_cast<int>(kSteps * 4));
  }
  EXPECT_EQ(client_->stats().lost_events, 0);
  CheckAgainstEdges(scan);
  EXPECT_EQ(board_.error(), "");
}

TEST_F(HilEmuTest, ScanSurvivesLostCorruptedDuplicatedPacketsAndAnUnplug) {
  const HilScanResult scan = RunScan(/*with_faults=*/true);
  const MockUsbBoard::Counters faults = usb_->counters();
  EXPECT_EQ(faults.dropped, 1);
  EXPECT_EQ(faults.corrupted, 1);
  EXPECT_EQ(faults.duplicated, 1);
  EXPECT_EQ(faults.unplugs, 1);
  EXPECT_TRUE(replug_ok_) << replug_error_;
  EXPECT_GE(client_->stats().retransmits, 1);  // which frames the faults hit depends on timing
  EXPECT_EQ(client_->stats().reconnects, 1);
  EXPECT_EQ(client_->stats().lost_events, 0);
  EXPECT_TRUE(scan.safety_seen);
  ASSERT_TRUE(scan.resumed_at.has_value()) << "the program should have been stopped by the laser timeout";
  CheckAgainstEdges(scan);
  EXPECT_EQ(board_.error(), "");
}

}  // namespace
}  // namespace rotoscan::device
