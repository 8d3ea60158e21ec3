// Issue 18: the flashed image (rotoscan-fw.elf of the cross build) run from reset on the emulated
// STM32F411: the clock tree it programs, read back from the emulator's RCC / flash / PWR models, its pins
// after boot, and its enumeration over the DWC2 model as Linux does it. Also the harness's own stops:
// an unmapped address, an unmodelled register and an interrupt without a handler stop the run with the
// address and the instruction.
#include <gtest/gtest.h>

#include <cstdio>
#include <string>
#include <vector>

#include "elf_image.h"
#include "emu_image.h"
#include "f411_emu.h"
#include "usb_host.h"
#include "version.h"

namespace rotoscan::fw_emu {
namespace {

constexpr uint32_t kRccPllcfgr = 0x40023804, kRccCfgr = 0x40023808, kFlashAcr = 0x40023C00,
                   kPwrCr = 0x40007000;

class EmuBoot : public ::testing::Test {
 protected:
  void SetUp() override {
    const std::string path = ImagePath();
    if (!ImageExists(path)) {
      GTEST_SKIP() << "no firmware image at " << path
                   << " (the cross build, firmware.cross_build, needs arm-none-eabi-gcc)";
    }
    std::string error;
    ASSERT_TRUE(ReadElf(path, &image_, &error)) << error;
    emu_ = std::make_unique<F411Emu>(image_, options_);
    ASSERT_TRUE(emu_->ok()) << emu_->error();
    emu_->PowerOn();
  }

  ElfImage image_;
  EmuOptions options_;
  std::unique_ptr<F411Emu> emu_;
};

TEST_F(EmuBoot, ProgramsTheClockTreeOfTheIssue) {
  ASSERT_TRUE(emu_->RunUs(2000)) << emu_->error();
  const uint32_t pll = emu_->Peek(kRccPllcfgr);
  EXPECT_EQ(pll & 0x3Fu, 25u) << "PLLM";
  EXPECT_EQ((pll >> 6) & 0x1FFu, 192u) << "PLLN";
  EXPECT_EQ(2 * (((pll >> 16) & 3u) + 1), 2u) << "PLLP";
  EXPECT_EQ((pll >> 24) & 0xFu, 4u) << "PLLQ";
  EXPECT_TRUE(pll & (1u << 22)) << "PLL source HSE";
  const uint32_t cfgr = emu_->Peek(kRccCfgr);
  EXPECT_EQ(cfgr & 3u, 2u) << "SW = PLL";
  EXPECT_EQ((cfgr >> 2) & 3u, 2u) << "SWS = PLL";
  EXPECT_EQ((cfgr >> 4) & 0xFu, 0u) << "AHB /1";
  EXPECT_EQ((cfgr >> 10) & 7u, 4u) << "APB1 /2";
  EXPECT_EQ((cfgr >> 13) & 7u, 0u) << "APB2 /1";
  const uint32_t acr = emu_->Peek(kFlashAcr);
  EXPECT_EQ(acr & 0xFu, 3u) << "flash latency";
  EXPECT_EQ(acr & 0x700u, 0x700u) << "prefetch, instruction and data caches on";
  EXPECT_EQ((emu_->Peek(kPwrCr) >> 14) & 3u, 3u) << "voltage scale 1";
  EXPECT_EQ(emu_->sysclk_hz(), 96000000u);
  EXPECT_EQ(emu_->usb_clock_hz(), 48000000u);
  EXPECT_EQ(emu_->apb1_hz(), 48000000u);
  std::printf("boot: %llu instructions, %llu cycles in the first 2 ms (16 MHz until the PLL, then 96 MHz)\n",
              static_cast<unsigned long long>(emu_->instructions()),
              static_cast<unsigned long long>(emu_->cycles()));
}

TEST_F(EmuBoot, PinsAreSafeAndTheLedComesOn) {
  ASSERT_TRUE(emu_->RunUs(2000)) << emu_->error();
  EXPECT_FALSE(emu_->PinLevel(kPortB, 13)) << "left laser off";
  EXPECT_FALSE(emu_->PinLevel(kPortB, 14)) << "right laser off";
  EXPECT_TRUE(emu_->PinLevel(kPortB, 12)) << "stepper driver disabled (/EN high)";
  EXPECT_FALSE(emu_->PinLevel(kPortC, 13)) << "LED on (active low)";
  EXPECT_FALSE(emu_->PinLevel(kPortA, 15)) << "trigger low";
  // The lasers never went high on the way.
  for (const PinEdge& e : emu_->edges()) {
    EXPECT_FALSE(e.port == kPortB && (e.pin == 13 || e.pin == 14) && e.level) << "laser pin high at boot";
  }
}

TEST_F(EmuBoot, EnumeratesLikeLinuxDoes) {
  UsbHost host(emu_.get());
  const UsbHost::Enumeration e = host.Enumerate(9);
  ASSERT_TRUE(e.ok) << e.error;
  ASSERT_EQ(e.device.size(), 18u);
  EXPECT_EQ(e.device[1], 1);                          // DEVICE
  EXPECT_EQ(e.device[2] | e.device[3] << 8, 0x0200);  // USB 2.00
  EXPECT_EQ(e.device[7], 64);                         // bMaxPacketSize0
  EXPECT_EQ(e.device[8] | e.device[9] << 8, 0x1209);  // pid.codes
  EXPECT_EQ(e.device[10] | e.device[11] << 8, 0x0001);
  EXPECT_EQ(e.device[13], FW_VERSION_MAJOR);
  // Configuration: one vendor-specific interface with bulk OUT 0x01 and bulk IN 0x81, 64 bytes each.
  ASSERT_EQ(e.configuration.size(), 32u);
  EXPECT_EQ(e.configuration[4], 1);         // bNumInterfaces
  EXPECT_EQ(e.configuration[9 + 4], 2);     // bNumEndpoints
  EXPECT_EQ(e.configuration[9 + 5], 0xFF);  // vendor specific
  EXPECT_EQ(e.configuration[18 + 2], 0x01);
  EXPECT_EQ(e.configuration[18 + 3], 2);
  EXPECT_EQ(e.configuration[18 + 4], 64);
  EXPECT_EQ(e.configuration[25 + 2], 0x81);
  EXPECT_EQ(e.configuration[25 + 3], 2);
  EXPECT_EQ(e.configuration[25 + 4], 64);
  ASSERT_EQ(e.strings.size(), 3u);
  EXPECT_EQ(e.strings[0], "Rotoscan");
  std::string serial;
  for (uint8_t b : options_.uid) {
    char hex[3];
    std::snprintf(hex, sizeof(hex), "%02X", b);
    serial += hex;
  }
  EXPECT_EQ(e.strings[2], serial) << "the serial number is the chip's unique id";
  // The vendor request the host's flasher uses to read the version.
  const UsbHost::Control v = host.ControlTransfer(0xC0, 1, 0, 0, 3);
  ASSERT_TRUE(v.ok) << v.error;
  ASSERT_EQ(v.data.size(), 3u);
  EXPECT_EQ(v.data[0], FW_VERSION_MAJOR);
  EXPECT_EQ(v.data[1], FW_VERSION_MINOR);
  EXPECT_EQ(v.data[2], FW_VERSION_PATCH);
  // A malformed request is stalled, and the device still answers afterwards.
  EXPECT_TRUE(host.ControlTransfer(0x80, 6, 0x0700, 0, 64).stalled);
  EXPECT_TRUE(host.GetDescriptor(1, 0, 18).ok);
  EXPECT_EQ(dwc2_model_error(emu_->usb()), nullptr) << dwc2_model_error(emu_->usb());
  std::printf("enumerated and configured after %llu cycles from reset: %llu instructions\n",
              static_cast<unsigned long long>(emu_->cycles()),
              static_cast<unsigned long long>(emu_->instructions()));
}

// ---- the harness's own stops, on hand-assembled images ----

ElfImage TinyImage(const std::vector<uint16_t>& code, const std::vector<uint32_t>& literals,
                   uint32_t extra_vector = 0) {
  std::vector<uint8_t> bytes(0x200, 0);
  auto put32 = [&](size_t at, uint32_t v) {
    for (int i = 0; i < 4; ++i) bytes[at + i] = uint8_t(v >> (8 * i));
  };
  put32(0, 0x20020000);   // initial SP
  put32(4, 0x08000101);   // reset: 0x100
  put32(12, 0x08000141);  // HardFault: 0x140
  if (extra_vector != 0) put32(4 * extra_vector, 0x08000141);
  size_t at = 0x100;
  for (uint16_t hw : code) {
    bytes[at++] = uint8_t(hw);
    bytes[at++] = uint8_t(hw >> 8);
  }
  at = 0x110;
  for (uint32_t w : literals) put32((at += 4) - 4, w);
  bytes[0x140] = 0xFE;  // HardFault_Handler: b .
  bytes[0x141] = 0xE7;
  ElfImage image;
  ElfSegment s;
  s.load_address = s.address = 0x08000000;
  s.mem_size = uint32_t(bytes.size());
  s.bytes = bytes;
  image.segments.push_back(s);
  image.symbols["HardFault_Handler"] = 0x08000141;
  return image;
}

TEST(EmuHarness, UnmappedPeripheralStopsWithAddressAndInstruction) {
  // ldr r0, [pc, #12] (0x40005400, I2C1: not modelled); ldr r1, [r0]; b .
  F411Emu emu(TinyImage({0x4803, 0x6801, 0xE7FE}, {0x40005400}), EmuOptions{});
  emu.PowerOn();
  EXPECT_FALSE(emu.Run(1000));
  EXPECT_NE(emu.error().find("read of unmapped address 0x40005400"), std::string::npos) << emu.error();
  EXPECT_NE(emu.error().find("pc 0x08000102 (instruction 6801)"), std::string::npos) << emu.error();
}

TEST(EmuHarness, UnmodelledRegisterStopsWithAddressAndInstruction) {
  // RCC_AHB1RSTR (0x40023810) lies in a modelled window but is not modelled: str r1, [r0].
  F411Emu emu(TinyImage({0x4803, 0x2101, 0x6001, 0xE7FE}, {0x40023810}), EmuOptions{});
  emu.PowerOn();
  EXPECT_FALSE(emu.Run(1000));
  EXPECT_NE(emu.error().find("write to unmodelled register 0x40023810"), std::string::npos) << emu.error();
  EXPECT_NE(emu.error().find("pc 0x08000104 (instruction 6001)"), std::string::npos) << emu.error();
}

TEST(EmuHarness, InterruptWithoutItsOwnHandlerStops) {
  // Enables and pends IRQ 5, whose vector is the default handler (HardFault_Handler).
  F411Emu emu(TinyImage({0x4803, 0x2120, 0x6001, 0x4803, 0x6001, 0xE7FE}, {0xE000E100, 0xE000E200}, 16 + 5),
              EmuOptions{});
  emu.PowerOn();
  EXPECT_FALSE(emu.Run(1000));
  EXPECT_NE(emu.error().find("unhandled interrupt: exception 21 (IRQ 5)"), std::string::npos) << emu.error();
}

TEST(EmuHarness, PeripheralWithItsClockOffStops) {
  // TIM2_CR1 written before RCC_APB1ENR.TIM2EN.
  F411Emu emu(TinyImage({0x4803, 0x2101, 0x6001, 0xE7FE}, {0x40000000}), EmuOptions{});
  emu.PowerOn();
  EXPECT_FALSE(emu.Run(1000));
  EXPECT_NE(emu.error().find("TIM2 accessed with its clock off"), std::string::npos) << emu.error();
}

}  // namespace
}  // namespace rotoscan::fw_emu
