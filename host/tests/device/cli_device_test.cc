// `rotoscan device ...` against the firmware core on the mocked USB bus (under umockdev-wrapper), and with
// no board at all.
#include <umockdev.h>

#include <sstream>

#include <gtest/gtest.h>

#include "commands/device.h"
#include "mock_usb_board.h"
#include "sim_board.h"

namespace rotoscan::cli {
namespace {

using device::testing::MockUsbBoard;
using device::testing::SimBoard;

struct Output {
  std::ostringstream out, err;
  Context context{&out, &err, nullptr};
};

class CliDeviceTest : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(MockUsbBoard::InMockEnvironment()) << "run this test under umockdev-wrapper (ctest does)";
  }
};

TEST_F(CliDeviceTest, NoBoardSaysSoAndExitsOne) {
  UMockdevTestbed* empty = umockdev_testbed_new();  // a bus with nothing on it
  Output o;
  EXPECT_EQ(RunDeviceList(o.context), kExitFailure);
  EXPECT_NE(o.err.str().find("no Rotoscan board found"), std::string::npos) << o.err.str();
  Output i;
  EXPECT_EQ(RunDeviceInfo(i.context, DeviceOptions{}), kExitFailure);
  EXPECT_NE(i.err.str().find("no Rotoscan board found"), std::string::npos) << i.err.str();
  g_object_unref(empty);
}

TEST_F(CliDeviceTest, ListInfoPingMoveLaser) {
  SimBoard board;
  MockUsbBoard usb(&board);
  Output list;
  ASSERT_EQ(RunDeviceList(list.context), kExitOk) << list.err.str();
  EXPECT_NE(list.out.str().find("bus 1 address 2"), std::string::npos) << list.out.str();
  Output info;
  ASSERT_EQ(RunDeviceInfo(info.context, DeviceOptions{}), kExitOk) << info.err.str();
  EXPECT_NE(info.out.str().find("protocol:     1."), std::string::npos) << info.out.str();
  EXPECT_NE(info.out.str().find("simulated"), std::string::npos) << info.out.str();
  Output ping;
  ASSERT_EQ(RunDevicePing(ping.context, DeviceOptions{}, 12), kExitOk) << ping.err.str();
  EXPECT_NE(ping.out.str().find("12 pings: round trip min"), std::string::npos) << ping.out.str();
  Output move;
  ASSERT_EQ(RunDeviceMove(move.context, DeviceOptions{}, 90.0, 400), kExitOk) << move.err.str();
  EXPECT_NE(move.out.str().find("table at 100 steps"), std::string::npos) << move.out.str();
  Output laser;
  ASSERT_EQ(RunDeviceLaser(laser.context, DeviceOptions{}, "right"), kExitOk) << laser.err.str();
  int left = -1, right = -1;
  usb.WithBoardLocked([&] {
    left = sim_pin_level(SIM_PIN_LASER_LEFT);
    right = sim_pin_level(SIM_PIN_LASER_RIGHT);
  });
  EXPECT_EQ(left, 0);
  EXPECT_EQ(right, 1);
  Output bad;
  EXPECT_EQ(RunDeviceLaser(bad.context, DeviceOptions{}, "green"), kExitFailure);
  EXPECT_NE(bad.err.str().find("left, right, both or off"), std::string::npos) << bad.err.str();
}

}  // namespace
}  // namespace rotoscan::cli
