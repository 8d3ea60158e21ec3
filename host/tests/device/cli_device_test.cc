// `rotoscan device ...` against the firmware core on the mocked USB bus (under umockdev-wrapper), and with
// no board at all.
#include <umockdev.h>

#include <sys/stat.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

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
  EXPECT_NE(info.out.str().find(" diag "), std::string::npos) << info.out.str();
  Output status;
  ASSERT_EQ(RunDeviceStatus(status.context, DeviceOptions{}), kExitOk) << status.err.str();
  EXPECT_NE(status.out.str().find("state:        idle"), std::string::npos) << status.out.str();
  EXPECT_NE(status.out.str().find("step irq:     not measured on this board"), std::string::npos)
      << status.out.str();
  EXPECT_NE(status.out.str().find("last fault:   none recorded"), std::string::npos) << status.out.str();
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

// A firmware image as the cross build makes it, reduced to what `device flash` reads: the vector table and the
// USB device descriptor (bcdDevice = the firmware version).
std::string FakeImage(uint16_t bcd_device) {
  std::string b(512, '\0');
  const uint8_t vectors[8] = {0x00, 0x00, 0x02, 0x20, 0x71, 0x02, 0x00, 0x08};  // sp 0x20020000, reset 0x08000271
  b.replace(0, 8, reinterpret_cast<const char*>(vectors), 8);
  const uint8_t desc[18] = {18, 1, 0x00, 0x02, 0, 0, 0, 64, 0x09, 0x12, 0x01, 0x00, uint8_t(bcd_device & 0xFF),
                            uint8_t(bcd_device >> 8), 1, 2, 3, 1};
  b.replace(300, 18, reinterpret_cast<const char*>(desc), 18);
  return b;
}

// A fake dfu-util first on PATH: records its arguments, exits with $FAKE_DFU_RC.
class FlashTest : public CliDeviceTest {
 protected:
  void SetUp() override {
    CliDeviceTest::SetUp();
    char tmpl[] = "/tmp/rotoscan-flash-XXXXXX";
    ASSERT_NE(mkdtemp(tmpl), nullptr);
    dir_ = tmpl;
    const std::string script = dir_ + "/dfu-util";
    std::ofstream(script) << "#!/bin/sh\necho \"$@\" > \"$(dirname \"$0\")/args\"\nexit ${FAKE_DFU_RC:-0}\n";
    ASSERT_EQ(chmod(script.c_str(), 0755), 0);
    old_path_ = std::getenv("PATH") ? std::getenv("PATH") : "";
    setenv("PATH", (dir_ + ":" + old_path_).c_str(), 1);
    unsetenv("FAKE_DFU_RC");
  }
  void TearDown() override {
    setenv("PATH", old_path_.c_str(), 1);
    unsetenv("FAKE_DFU_RC");
    std::filesystem::remove_all(dir_);
  }
  std::string Write(const std::string& name, const std::string& bytes) {
    const std::string path = dir_ + "/" + name;
    std::ofstream(path, std::ios::binary) << bytes;
    return path;
  }
  std::string Args() {
    std::ifstream in(dir_ + "/args");
    std::string line;
    std::getline(in, line);
    return line;
  }
  std::string dir_, old_path_;
};

TEST_F(FlashTest, RunsDfuUtilThenChecksTheVersionTheBoardReports) {
  SimBoard board;  // the firmware core, version 0.1.0, back on the (mocked) bus after the flash
  MockUsbBoard usb(&board);
  const std::string image = Write("rotoscan-fw.bin", FakeImage(0x0010));
  ASSERT_EQ(FirmwareImageVersion(image).value(), "0.1.0");
  Output o;
  FlashOptions flash;
  flash.wait_s = 2;
  ASSERT_EQ(RunDeviceFlash(o.context, DeviceOptions{}, image, flash), kExitOk) << o.err.str();
  EXPECT_EQ(Args(), "-a 0 -d 0483:df11 -s 0x08000000:leave -D " + image);
  EXPECT_NE(o.out.str().find("board back: firmware 0.1.0"), std::string::npos) << o.out.str();

  // The board comes back with another version than the image's: the flash did not take.
  Output other;
  EXPECT_EQ(RunDeviceFlash(other.context, DeviceOptions{}, Write("v020.bin", FakeImage(0x0020)), flash),
            kExitFailure);
  EXPECT_NE(other.err.str().find("runs firmware 0.1.0 but the image is 0.2.0"), std::string::npos)
      << other.err.str();
}

TEST_F(FlashTest, DfuUtilFailureAndNoBoardAfterwardsAreErrors) {
  const std::string image = Write("rotoscan-fw.bin", FakeImage(0x0010));
  FlashOptions flash;
  flash.wait_s = 0.5;
  setenv("FAKE_DFU_RC", "74", 1);
  Output failed;
  EXPECT_EQ(RunDeviceFlash(failed.context, DeviceOptions{}, image, flash), kExitFailure);
  EXPECT_NE(failed.err.str().find("failed (exit 74): is the board in its bootloader?"), std::string::npos)
      << failed.err.str();
  unsetenv("FAKE_DFU_RC");
  UMockdevTestbed* empty = umockdev_testbed_new();  // dfu-util succeeds but no board comes back
  Output gone;
  EXPECT_EQ(RunDeviceFlash(gone.context, DeviceOptions{}, image, flash), kExitFailure);
  EXPECT_NE(gone.err.str().find("did not come back"), std::string::npos) << gone.err.str();
  g_object_unref(empty);
  Output missing;
  flash.dfu_util = dir_ + "/no-such-dfu-util";
  EXPECT_EQ(RunDeviceFlash(missing.context, DeviceOptions{}, image, flash), kExitFailure);
  EXPECT_NE(missing.err.str().find("no-such-dfu-util"), std::string::npos) << missing.err.str();
}

TEST_F(FlashTest, RefusesWhatIsNotAnImageBeforeRunningDfuUtil) {
  const std::vector<std::pair<std::string, std::string>> bad = {
      {"elf", std::string("\x7f" "ELF\x01\x01\x01", 7) + std::string(100, '\0')},
      {"empty", ""},
      {"too-big", FakeImage(0x0010) + std::string(40 * 1024, '\0')},
      {"no-descriptor", FakeImage(0x0010).substr(0, 200)},
  };
  for (const auto& [name, bytes] : bad) {
    Output o;
    EXPECT_EQ(RunDeviceFlash(o.context, DeviceOptions{}, Write(name, bytes), FlashOptions{}), kExitFailure) << name;
    EXPECT_FALSE(o.err.str().empty()) << name;
  }
  Output none;
  EXPECT_EQ(RunDeviceFlash(none.context, DeviceOptions{}, dir_ + "/absent.bin", FlashOptions{}), kExitFailure);
  EXPECT_EQ(Args(), "") << "dfu-util ran on a bad image";
}

}  // namespace
}  // namespace rotoscan::cli
