// Hardware in the loop, the promised test: the host's real libusb transport and client, through umockdev's
// emulated usbdevfs, talk to the real firmware core built for the host (port/sim, virtual time). A 200-step
// scan program runs on the board; every TRIGGER_EVENT is checked against the simulator's own log of pin
// edges (the trigger edge's time, the laser pins' levels at it, the STEP pulses before it), and faults are
// injected on the mocked endpoint: a lost packet, a corrupted byte, a duplicated command, an unplug and
// re-plug in the middle of the scan (the laser-safety timeout stops the program meanwhile; the host resumes
// it, and the shots of the interrupted step are replaced, so no step is lost or taken twice).
#include <chrono>
#include <thread>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "hil_common.h"
#include "mock_usb_board.h"
#include "rotoscan/device/client.h"
#include "rotoscan_protocol.h"
#include "sim_board.h"

namespace rotoscan::device {
namespace {

using testing::CheckHilShots;
using testing::DecodeSimLog;
using testing::HilConfig;
using testing::HilFaults;
using testing::HilProgram;
using testing::HilScanResult;
using testing::MockUsbBoard;
using testing::PinLogDecoder;
using testing::RunHilScan;
using testing::SimBoard;

constexpr uint32_t kSteps = 200;

class HilSimTest : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(MockUsbBoard::InMockEnvironment()) << "run this test under umockdev-wrapper (ctest does)";
    usb_ = std::make_unique<MockUsbBoard>(&board_);
    ClientOptions options;
    options.ack_timeout_us = 200'000;
    auto transport = MakeLibusbTransport();
    ASSERT_TRUE(transport.ok()) << transport.status().ToString();
    auto client = Client::Connect(std::move(transport).value(), options);
    ASSERT_TRUE(client.ok()) << client.status().ToString();
    client_ = std::move(client).value();
  }

  // Runs the program to the end (RunHilScan), the faults at 100, 200, 300 and 450 triggers: the unplug is
  // re-plugged after 400 ms (2 s of board time), longer than the board's laser timeout.
  HilScanResult RunScan(bool with_faults) {
    HilFaults faults;
    if (with_faults) {
      faults = {100, 200, 300, 450, [this] {
                  usb_->Unplug();
                  replug_ = std::thread([this] {
                    std::this_thread::sleep_for(std::chrono::milliseconds(400));
                    usb_->Replug();
                  });
                }};
    }
    // Wall-clock limit only against a hang; the scan takes about a second.
    HilScanResult scan = RunHilScan(*client_, *usb_, HilConfig(/*laser_timeout_ms=*/1000), HilProgram(kSteps),
                                    faults, std::chrono::seconds(60));
    if (replug_.joinable()) replug_.join();
    return scan;
  }

  void CheckAgainstEdges(const HilScanResult& scan) {
    PinLogDecoder log;
    usb_->WithBoardLocked([&] { log = DecodeSimLog(); });
    CheckHilShots(scan, HilProgram(kSteps), log.triggers(), log.step_pulses());
  }

  void TearDown() override {
    if (replug_.joinable()) replug_.join();
    client_.reset();
    usb_.reset();
  }

  SimBoard board_;
  std::unique_ptr<MockUsbBoard> usb_;
  std::unique_ptr<Client> client_;
  std::thread replug_;
};

TEST_F(HilSimTest, EnumerateClaimAndGetInfo) {
  const DeviceInfo& info = client_->info();
  EXPECT_EQ(info.protocol_major, PROTO_VERSION_MAJOR);
  EXPECT_TRUE(info.simulated);
  EXPECT_EQ(info.max_shots, PROTO_MAX_SHOTS);
  auto fit = client_->SyncClock(10);
  ASSERT_TRUE(fit.ok()) << fit.status().ToString();
}

TEST_F(HilSimTest, ScanOf200StepsEveryTriggerArrivesRight) {
  const HilScanResult scan = RunScan(/*with_faults=*/false);
  // A machine loaded enough to starve the keep-alive makes the board stop and the host resume (retaking
  // the interrupted step's shots); without that, exactly one trigger per shot.
  if (!scan.safety_seen) {
    EXPECT_EQ(scan.triggers_seen, static_cast<int>(kSteps * 4));
  }
  EXPECT_EQ(client_->stats().lost_events, 0);
  CheckAgainstEdges(scan);
}

TEST_F(HilSimTest, ScanSurvivesLostCorruptedDuplicatedPacketsAndAnUnplug) {
  const HilScanResult scan = RunScan(/*with_faults=*/true);
  const MockUsbBoard::Counters faults = usb_->counters();
  EXPECT_EQ(faults.dropped, 1);
  EXPECT_EQ(faults.corrupted, 1);
  EXPECT_EQ(faults.duplicated, 1);
  EXPECT_EQ(faults.unplugs, 1);
  EXPECT_GE(client_->stats().retransmits, 2);  // the lost and the corrupted command
  EXPECT_EQ(client_->stats().reconnects, 1);
  EXPECT_EQ(client_->stats().lost_events, 0);
  EXPECT_TRUE(scan.safety_seen);
  ASSERT_TRUE(scan.resumed_at.has_value()) << "the program should have been stopped by the laser timeout";
  CheckAgainstEdges(scan);
}

}  // namespace
}  // namespace rotoscan::device
