// The serial port and the Ciclop (horus-fw) client against FakeCiclop over a real pseudo-terminal. Every
// timing check compares the client's windows with the fake's ground truth (when a laser really switched,
// where the table really was), so no test depends on how fast the machine is.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>

#include "fake_ciclop.h"
#include "rotoscan/device/ciclop_client.h"
#include "rotoscan/device/serial_port.h"

namespace rotoscan::device {
namespace {

using testing::FakeCiclop;
using testing::FakeCiclopOptions;

class CiclopTest : public ::testing::Test {
 protected:
  void SetUp() override {
    char dir_template[] = "/tmp/rotoscan-ciclop-XXXXXX";
    ASSERT_NE(mkdtemp(dir_template), nullptr);
    dir_ = dir_template;
    fake_options_.link_path = dir_ + "/ttyUSB0";
  }
  void TearDown() override {
    client_.reset();
    fake_.reset();
    ::unlink((dir_ + "/ttyUSB0").c_str());
    ::rmdir(dir_.c_str());
  }
  void StartFake() {
    fake_ = std::make_unique<FakeCiclop>(fake_options_);
    ASSERT_TRUE(fake_->Start()) << fake_->error();
  }
  CiclopOptions ClientOptions() const {
    CiclopOptions o;
    o.port = fake_options_.link_path;
    o.banner_timeout_us = 200'000;
    o.reset_attempts = 2;
    o.ok_timeout_us = 100'000;
    o.reconnect_timeout_us = 300'000;
    return o;
  }
  void Connect() {
    StartFake();
    client_ = std::make_unique<CiclopClient>(ClientOptions());
    Status s = client_->Connect();
    ASSERT_TRUE(s.ok()) << s.ToString();
  }
  int Count(const std::string& line) const {
    const auto lines = fake_->lines();
    return static_cast<int>(std::count(lines.begin(), lines.end(), line));
  }
  // The truth event of laser n switching to `on` lies inside the ack's window.
  void ExpectSwitchInside(int laser, bool on, const Ack& ack) {
    bool found = false;
    for (const auto& e : fake_->laser_events()) {
      if (e.laser == laser && e.on == on && e.time_us >= ack.sent_us && e.time_us <= ack.ok_us) found = true;
    }
    EXPECT_TRUE(found) << "laser " << laser << (on ? " on" : " off") << " not inside [" << ack.sent_us << ", "
                       << ack.ok_us << "]";
  }

  std::string dir_;
  FakeCiclopOptions fake_options_;
  std::unique_ptr<FakeCiclop> fake_;
  std::unique_ptr<CiclopClient> client_;
};

const double kStep = 1.0 / 176.0;  // horus-fw's default resolution, degrees

TEST(SerialPort, MissingPathIsNotFound) {
  auto port = SerialPort::Open("/nonexistent/ttyUSB9");
  ASSERT_FALSE(port.ok());
  EXPECT_EQ(port.status().code(), StatusCode::kNotFound);
}

TEST(SerialPort, NotATtyIsRefused) {
  auto port = SerialPort::Open("/dev/null");
  ASSERT_FALSE(port.ok());
  EXPECT_EQ(port.status().code(), StatusCode::kDeviceError);
  EXPECT_NE(port.status().message().find("not a tty"), std::string::npos);
}

TEST(SerialPort, BadBaudIsInvalid) {
  auto port = SerialPort::Open("/dev/null", 12345);
  ASSERT_FALSE(port.ok());
  EXPECT_EQ(port.status().code(), StatusCode::kInvalidArgument);
}

TEST_F(CiclopTest, SecondOpenOfOnePortIsRefused) {
  StartFake();
  auto first = SerialPort::Open(fake_options_.link_path);
  ASSERT_TRUE(first.ok()) << first.status().ToString();
  auto second = SerialPort::Open(fake_options_.link_path);
  ASSERT_FALSE(second.ok());
  EXPECT_NE(second.status().message().find("in use"), std::string::npos);
}

TEST_F(CiclopTest, ConnectReadsBannerAndSettingsAndSwitchesLasersOff) {
  fake_options_.acceleration_deg_per_s2 = 250.0;  // not the default: read back through "$$"
  Connect();
  EXPECT_EQ(client_->banner(), "Horus 0.1 ['$' for help]");
  EXPECT_DOUBLE_EQ(client_->acceleration_deg_per_s2(), 250.0);
  EXPECT_DOUBLE_EQ(client_->max_rate_deg_per_s(), 180.0);
  EXPECT_EQ(Count("G1F180"), 1);
  EXPECT_EQ(Count("M70T1"), 1);
  EXPECT_EQ(Count("M70T2"), 1);
  EXPECT_FALSE(client_->laser(1));
  EXPECT_FALSE(client_->laser(2));
}

TEST_F(CiclopTest, LaserSwitchesHappenInsideTheirAckWindows) {
  Connect();
  for (int laser = 1; laser <= 2; ++laser) {
    auto on = client_->SetLaser(laser, true);
    ASSERT_TRUE(on.ok()) << on.status().ToString();
    ExpectSwitchInside(laser, true, *on);
    EXPECT_TRUE(fake_->LaserAt(laser, on->ok_us));
    auto off = client_->SetLaser(laser, false);
    ASSERT_TRUE(off.ok()) << off.status().ToString();
    ExpectSwitchInside(laser, false, *off);
    EXPECT_FALSE(fake_->LaserAt(laser, off->ok_us));
  }
  const LatencyStats stats = client_->latency();
  std::printf("ack windows over %d lines: min %lld, mean %lld, max %lld us\n", stats.count,
              static_cast<long long>(stats.min_us), static_cast<long long>(stats.mean_us),
              static_cast<long long>(stats.max_us));
  EXPECT_GE(stats.count, 4);
  EXPECT_GE(stats.min_us, fake_options_.reply_latency_min_us);  // the window cannot be shorter than the board's
}

TEST_F(CiclopTest, MotorOnAndOff) {
  Connect();
  ASSERT_TRUE(client_->SetMotor(true).ok());
  EXPECT_TRUE(fake_->motor());
  ASSERT_TRUE(client_->SetMotor(false).ok());
  EXPECT_FALSE(fake_->motor());
}

TEST_F(CiclopTest, MoveOkComesBeforeTheMoveEndsAndWaitIdleBoundsTheEnd) {
  Connect();
  auto move = client_->MoveTo(20.0);  // 20 deg at 180 deg/s^2, 180 deg/s: 0.67 s
  ASSERT_TRUE(move.ok()) << move.status().ToString();
  ASSERT_TRUE(move->idle_us.has_value());
  const auto moves = fake_->moves();
  ASSERT_EQ(moves.size(), 1u);
  // Started inside the ack window; the ok came long before the end (GRBL answers when queued).
  EXPECT_GE(moves[0].start_us, move->ack.sent_us);
  EXPECT_LE(moves[0].start_us, move->ack.ok_us);
  EXPECT_LT(move->ack.ok_us, moves[0].end_us - 500'000);
  // The first Idle report comes after the true end, and the table is at the target by then.
  EXPECT_GE(*move->idle_us, moves[0].end_us);
  EXPECT_NEAR(fake_->TableAngleAt(*move->idle_us), 20.0, 0.5 * kStep);
  // The predicted end is the true end within the ack window (the start is only known that well).
  EXPECT_NEAR(static_cast<double>(move->predicted_end_us), static_cast<double>(moves[0].end_us),
              static_cast<double>(move->ack.latency_us()) + 1000.0);
  // Half-way through, the table was between the two angles.
  const double mid = fake_->TableAngleAt((moves[0].start_us + moves[0].end_us) / 2);
  EXPECT_NEAR(mid, 10.0, 0.5);
  EXPECT_NEAR(client_->angle_deg(), 20.0, 1e-9);
}

TEST_F(CiclopTest, ErrorLineIsReportedWithTheBoardsMessage) {
  Connect();
  auto bad = client_->Command("M99");
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.status().code(), StatusCode::kDeviceError);
  EXPECT_NE(bad.status().message().find("'M99'"), std::string::npos) << bad.status().message();
  EXPECT_NE(bad.status().message().find("error: Unsupported command"), std::string::npos);
  // The client is still in step: the next command works.
  EXPECT_TRUE(client_->SetLaser(1, true).ok());
}

TEST_F(CiclopTest, LostOkOfALaserLineIsRecoveredWithTheSwitchInsideTheWindow) {
  Connect();
  fake_->LoseOks(1);
  auto on = client_->SetLaser(2, true);
  ASSERT_TRUE(on.ok()) << on.status().ToString();
  EXPECT_EQ(client_->lost_oks(), 1);
  EXPECT_EQ(on->tries, 2);  // idempotent: sent again after the fence
  ExpectSwitchInside(2, true, *on);
  // Still in step afterwards: every later ok belongs to its own line.
  auto off = client_->SetLaser(2, false);
  ASSERT_TRUE(off.ok());
  EXPECT_EQ(off->tries, 1);
  ExpectSwitchInside(2, false, *off);
}

TEST_F(CiclopTest, LostOkOfAMoveNeverSendsTheMoveTwice) {
  Connect();
  fake_->LoseOks(1);
  auto move = client_->MoveTo(10.0);
  ASSERT_TRUE(move.ok()) << move.status().ToString();
  EXPECT_EQ(client_->lost_oks(), 1);
  EXPECT_EQ(Count("G1X10"), 1);
  ASSERT_EQ(fake_->moves().size(), 1u);
  EXPECT_NEAR(fake_->TableAngleAt(*move->idle_us), 10.0, 0.5 * kStep);
  auto next = client_->MoveTo(11.0);
  ASSERT_TRUE(next.ok()) << next.status().ToString();
  EXPECT_NEAR(fake_->TableAngleAt(*next->idle_us), 11.0, 0.5 * kStep);
}

TEST_F(CiclopTest, GarbageIsSkipped) {
  Connect();
  fake_->SendGarbage(std::string("\x80\xfe#%\r\nZ\x01q\r\n", 11));
  auto on = client_->SetLaser(1, true);
  ASSERT_TRUE(on.ok()) << on.status().ToString();
  ExpectSwitchInside(1, true, *on);
  EXPECT_EQ(client_->garbage_lines(), 2);
  EXPECT_EQ(client_->lost_oks(), 0);
}

TEST_F(CiclopTest, GarbageGluedToAnOkIsALostOkRecovered) {
  Connect();
  fake_->SendGarbage("\xffZq");  // no line end: the next "ok" arrives as "\xffZqok"
  auto on = client_->SetLaser(1, true);
  ASSERT_TRUE(on.ok()) << on.status().ToString();
  ExpectSwitchInside(1, true, *on);
  EXPECT_EQ(client_->garbage_lines(), 1);
  EXPECT_EQ(client_->lost_oks(), 1);
}

TEST_F(CiclopTest, UnplugMidScanRestoresStateAndLosesNoStep) {
  Connect();
  ASSERT_TRUE(client_->SetMotor(true).ok());
  const double step = 1.5;
  for (int k = 1; k <= 6; ++k) {
    auto move = client_->MoveTo(k * step);
    ASSERT_TRUE(move.ok()) << "step " << k << ": " << move.status().ToString();
    EXPECT_NEAR(fake_->TableAngleAt(*move->idle_us), k * step, 0.5 * kStep) << "step " << k;
    auto on = client_->SetLaser(1, true);
    ASSERT_TRUE(on.ok()) << "step " << k << ": " << on.status().ToString();
    if (k == 3) {
      // The cable is pulled while the laser frames are taken, and put back: the adapter comes back at the
      // same path, the board reboots (position 0, lasers off, motor off, no feed rate).
      fake_->Unplug();
      fake_->Replug();
    }
    auto off = client_->SetLaser(1, false);
    ASSERT_TRUE(off.ok()) << "step " << k << ": " << off.status().ToString();
    if (k != 3) ExpectSwitchInside(1, false, *off);
  }
  ASSERT_EQ(client_->reconnections().size(), 1u);
  // The reboot switched the laser off while the client could not know: inside the reconnection's
  // unknown range, which frames must avoid.
  const Reconnection r = client_->reconnections()[0];
  int offs_inside = 0;
  for (const auto& e : fake_->laser_events()) {
    if (e.laser == 1 && !e.on && e.time_us >= r.last_contact_us && e.time_us <= r.restored_us) ++offs_inside;
  }
  EXPECT_EQ(offs_inside, 1);
  EXPECT_EQ(fake_->boots(), 2);
  EXPECT_TRUE(fake_->motor());  // restored
  // Six steps, each one move, none repeated, and the table where the client thinks it is.
  EXPECT_EQ(fake_->moves().size(), 6u);
  EXPECT_NEAR(fake_->TableAngleAt(MonotonicNowUs()), 6 * step, 0.5 * kStep);
  EXPECT_NEAR(client_->angle_deg(), 6 * step, 1e-9);
  // After the reboot the board counts from 0 at 4.5 deg: the client sent the 6 deg move as X1.5.
  EXPECT_EQ(Count("G1X6"), 0);
  EXPECT_EQ(Count("G1X1.5"), 2);  // step 1 before the unplug, step 4 after it
}

TEST_F(CiclopTest, UnplugDuringAMoveLeavesTheAngleUnknownUntilSetAngle) {
  Connect();
  auto move = client_->MoveTo(90.0, /*wait=*/false);  // 1.4 s
  ASSERT_TRUE(move.ok()) << move.status().ToString();
  fake_->Unplug();
  fake_->Replug();
  auto idle = client_->WaitIdle(2'000'000);
  ASSERT_FALSE(idle.ok());
  EXPECT_NE(idle.status().message().find("unknown"), std::string::npos) << idle.status().message();
  EXPECT_FALSE(client_->angle_known());
  auto refused = client_->MoveTo(0.0);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.status().code(), StatusCode::kFailedPrecondition);
  // The user says where the table is (as read on the table's scale): moves work again, from there.
  const double truth = fake_->TableAngleAt(MonotonicNowUs());
  ASSERT_TRUE(client_->SetAngle(truth).ok());
  auto back = client_->MoveTo(truth + 2.0);
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  EXPECT_NEAR(fake_->TableAngleAt(*back->idle_us), truth + 2.0, 0.5 * kStep);
}

TEST_F(CiclopTest, BoardThatStaysUnpluggedFailsClearly) {
  Connect();
  fake_->Unplug();
  auto on = client_->SetLaser(1, true);
  ASSERT_FALSE(on.ok());
  EXPECT_EQ(on.status().code(), StatusCode::kDeviceError);
  EXPECT_NE(on.status().message().find("did not come back"), std::string::npos) << on.status().message();
}

TEST_F(CiclopTest, BoardThatNeverAnswersFailsWithTimeoutNotAHang) {
  StartFake();
  fake_->SetSilent(true);
  CiclopClient client(ClientOptions());
  Status s = client.Connect();
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.code(), StatusCode::kTimeout);
  // The boot banner may be read before the board stops answering: then the "$G" fence times out.
  EXPECT_TRUE(s.message().find("no banner") != std::string::npos ||
              s.message().find("does not answer") != std::string::npos)
      << s.message();
}

TEST_F(CiclopTest, BoardThatGoesSilentFailsWithTimeoutNamingTheLine) {
  Connect();
  fake_->SetSilent(true);
  auto on = client_->SetLaser(1, true);
  ASSERT_FALSE(on.ok());
  EXPECT_EQ(on.status().code(), StatusCode::kTimeout);
  EXPECT_NE(on.status().message().find("'M71T1'"), std::string::npos) << on.status().message();
  EXPECT_NE(on.status().message().find("$G"), std::string::npos);
}

TEST_F(CiclopTest, PlainGrblIsRefused) {
  fake_options_.banner = "Grbl 0.9j ['$' for help]";
  StartFake();
  CiclopClient client(ClientOptions());
  Status s = client.Connect();
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("not running horus-fw"), std::string::npos) << s.message();
}

TEST_F(CiclopTest, ReplugAfterAMoveKeepsTheAngle) {
  Connect();
  ASSERT_TRUE(client_->MoveTo(5.0).ok());
  {
    // The client holds the port's lock: a second program cannot open it meanwhile.
    auto other = SerialPort::Open(fake_options_.link_path);
    EXPECT_FALSE(other.ok());
  }
  fake_->Unplug();
  fake_->Replug();
  auto move = client_->MoveTo(6.0);
  ASSERT_TRUE(move.ok()) << move.status().ToString();
  EXPECT_NEAR(fake_->TableAngleAt(*move->idle_us), 6.0, 0.5 * kStep);
  EXPECT_EQ(client_->reconnections().size(), 1u);
}

TEST_F(CiclopTest, BoardResetByItselfIsRecovered) {
  Connect();
  ASSERT_TRUE(client_->MoveTo(5.0).ok());
  fake_->Reboot();  // its banner is waiting when the client sends the next line
  auto on = client_->SetLaser(1, true);
  ASSERT_TRUE(on.ok()) << on.status().ToString();
  EXPECT_EQ(client_->reconnections().size(), 1u);
  EXPECT_TRUE(fake_->LaserAt(1, on->ok_us));
  auto move = client_->MoveTo(6.0);
  ASSERT_TRUE(move.ok()) << move.status().ToString();
  EXPECT_NEAR(fake_->TableAngleAt(*move->idle_us), 6.0, 0.5 * kStep);
  EXPECT_EQ(Count("G1X1"), 1);  // the board counts from 0 at 5 deg since its reset
}

TEST(CiclopOptions, Checked) {
  CiclopOptions o;
  o.ok_timeout_us = 0;
  EXPECT_FALSE(o.Check().ok());
  CiclopClient client(o);
  EXPECT_EQ(client.Connect().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(client.SetLaser(1, true).status().code(), StatusCode::kFailedPrecondition);
}

}  // namespace
}  // namespace rotoscan::device
