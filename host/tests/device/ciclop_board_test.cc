// The `ciclop` capture Board (capture/board.h), opened through the capture factory, against FakeCiclop on
// a pseudo-terminal. What free-running capture relies on is checked against the fake's ground truth: every
// real laser switch and every real table motion lies inside the interval of a BoardChange the board
// reported, unplug included.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "fake_ciclop.h"
#include "rotoscan/capture/factory.h"
#include "rotoscan/device/serial_port.h"

namespace rotoscan::capture {
namespace {

using device::testing::FakeCiclop;
using device::testing::FakeCiclopOptions;

constexpr double kRadPerDeg = M_PI / 180.0;

class CiclopBoardTest : public ::testing::Test {
 protected:
  void SetUp() override {
    char dir_template[] = "/tmp/rotoscan-ciclop-board-XXXXXX";
    ASSERT_NE(mkdtemp(dir_template), nullptr);
    dir_ = dir_template;
    FakeCiclopOptions options;
    options.link_path = dir_ + "/ttyUSB0";
    fake_ = std::make_unique<FakeCiclop>(options);
    ASSERT_TRUE(fake_->Start()) << fake_->error();
    context_.options = {"ok_timeout_ms=1000", "reconnect_ms=3000"};  // bounds on failures only (no lost ok here)
  }
  void TearDown() override {
    board_.reset();
    fake_.reset();
    ::unlink((dir_ + "/ttyUSB0").c_str());
    ::rmdir(dir_.c_str());
  }
  void Open() {
    auto board = OpenBoard("ciclop:" + dir_ + "/ttyUSB0", &context_);
    ASSERT_TRUE(board.ok()) << board.status().ToString();
    board_ = std::move(board).value();
  }
  // Every true laser switch lies inside one of the reported changes.
  void ExpectEverySwitchCovered() {
    for (const auto& e : fake_->laser_events()) {
      bool covered = false;
      for (const BoardChange& c : changes_) covered |= e.time_us >= c.earliest_us && e.time_us <= c.latest_us;
      if (e.time_us < connected_us_) continue;  // switched off by the reset at connection
      EXPECT_TRUE(covered) << "laser " << e.laser << (e.on ? " on" : " off") << " at " << e.time_us
                           << " is in no change interval";
    }
  }

  std::string dir_;
  std::unique_ptr<FakeCiclop> fake_;
  OpenContext context_;
  std::unique_ptr<Board> board_;
  std::vector<BoardChange> changes_;
  int64_t connected_us_ = 0;
};

TEST_F(CiclopBoardTest, OpensThroughTheFactory) {
  Open();
  EXPECT_EQ(board_->info().name, "bq Ciclop (horus-fw)");
  EXPECT_EQ(board_->info().firmware_version, "Horus 0.1 ['$' for help]");
  EXPECT_NEAR(board_->capabilities().degrees_per_step, 1.0 / 176.0, 1e-12);
  EXPECT_FALSE(board_->capabilities().trigger_output);
  EXPECT_EQ(board_->LoadProgram(device::ScanProgram{}).code(), StatusCode::kUnimplemented);
  ASSERT_NE(context_.clock, nullptr);
  EXPECT_FALSE(context_.clock->is_virtual());
}

TEST_F(CiclopBoardTest, LaserAndMoveChangesContainTheTruth) {
  Open();
  connected_us_ = device::MonotonicNowUs();
  ASSERT_TRUE(board_->EnableMotor(true).ok());
  for (uint8_t mask : {kLaserLeft, kLaserRight, uint8_t(kLaserLeft | kLaserRight), uint8_t(0)}) {
    auto change = board_->SetLasers(mask);
    ASSERT_TRUE(change.ok()) << change.status().ToString();
    EXPECT_EQ(change->lasers, mask);
    EXPECT_EQ(board_->lasers(), mask);
    changes_.push_back(*change);
  }
  ExpectEverySwitchCovered();
  auto move = board_->MoveTo(4.0 * kRadPerDeg);
  ASSERT_TRUE(move.ok()) << move.status().ToString();
  const auto moves = fake_->moves();
  ASSERT_EQ(moves.size(), 1u);
  EXPECT_TRUE(move->moved);
  EXPECT_LE(move->earliest_us, moves[0].start_us);
  EXPECT_GE(move->latest_us, moves[0].end_us);
  EXPECT_NEAR(fake_->TableAngleAt(move->latest_us), 4.0, 0.5 / 176.0);
  EXPECT_NEAR(board_->table_angle_rad(), 4.0 * kRadPerDeg, 1e-12);
  auto by = board_->MoveBy(-1.0 * kRadPerDeg);
  ASSERT_TRUE(by.ok()) << by.status().ToString();
  EXPECT_NEAR(fake_->TableAngleAt(by->latest_us), 3.0, 0.5 / 176.0);
  ASSERT_TRUE(board_->Shutdown().ok());
  EXPECT_FALSE(fake_->motor());
}

TEST_F(CiclopBoardTest, UnplugMidScanIsInsideAChangeInterval) {
  Open();
  connected_us_ = device::MonotonicNowUs();
  for (int step = 1; step <= 4; ++step) {
    auto move = board_->MoveTo(step * 1.0 * kRadPerDeg);
    ASSERT_TRUE(move.ok()) << "step " << step << ": " << move.status().ToString();
    EXPECT_NEAR(fake_->TableAngleAt(move->latest_us), step * 1.0, 0.5 / 176.0);
    for (uint8_t mask : {kLaserLeft, kLaserRight, uint8_t(0)}) {
      auto change = board_->SetLasers(mask);
      ASSERT_TRUE(change.ok()) << "step " << step << ": " << change.status().ToString();
      changes_.push_back(*change);
      // The cable is pulled while the right laser's frame is exposed, and plugged back.
      if (step == 2 && mask == kLaserRight) {
        fake_->Unplug();
        fake_->Replug();
      }
    }
  }
  // The reboot switched the right laser off between two commands: the next change's interval starts at
  // the last contact before the unplug, so it covers that switch too.
  ExpectEverySwitchCovered();
  EXPECT_EQ(fake_->moves().size(), 4u);
  EXPECT_EQ(fake_->boots(), 2);
}

TEST_F(CiclopBoardTest, BadSpecsAndOptionsAreClearErrors) {
  OpenContext context;
  auto none = OpenBoard("ciclop", &context);
  ASSERT_FALSE(none.ok());
  EXPECT_EQ(none.status().code(), StatusCode::kInvalidArgument);
  auto missing = OpenBoard("ciclop:/nonexistent/ttyUSB7", &context);
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.status().code(), StatusCode::kNotFound);
  OpenContext bad_option;
  bad_option.options = {"feed=fast"};
  auto bad = OpenBoard("ciclop:" + dir_ + "/ttyUSB0", &bad_option);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("feed"), std::string::npos);
  OpenContext virtual_clock;
  virtual_clock.clock = std::make_shared<VirtualClock>();
  auto wrong_clock = OpenBoard("ciclop:" + dir_ + "/ttyUSB0", &virtual_clock);
  ASSERT_FALSE(wrong_clock.ok());
  EXPECT_EQ(wrong_clock.status().code(), StatusCode::kInvalidArgument);
}

TEST(CiclopBackend, IsBuiltAndListsWithoutOpening) {
  const auto built = BuiltBoardBackends();
  EXPECT_NE(std::find(built.begin(), built.end(), "ciclop"), built.end());
  const DeviceList list = ListDevices();
  for (const auto& board : list.boards) {
    if (board.spec.rfind("ciclop:", 0) == 0) {
      EXPECT_NE(board.description.find("serial port"), std::string::npos);
    }
  }
}

}  // namespace
}  // namespace rotoscan::capture
