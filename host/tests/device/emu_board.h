// The flashed firmware image (rotoscan-fw.elf) on the emulated STM32F411 (firmware/tests/emu) as a
// VirtualBoard: what the host writes to the bulk OUT endpoint goes into the emulated OTG_FS core as OUT
// transactions (retried while the image NAKs), what it reads comes out as IN transactions, and Advance runs
// the emulated CPU. Boot() powers it on and enumerates it as the kernel would before libusb sees it;
// Reenumerate() does it again after a re-plug (a self-powered board: the image keeps running).
// Advance() runs the emulated CPU up to the caller's time counted in cycles since Boot(), not for a number of
// cycles: a transfer runs the CPU itself while the image NAKs (usb_host's retries), an enumeration runs it
// through the control transfers, and a run overshoots its end by the instruction or exception entry under
// way; all of that is taken off the next Advance() calls, so the emulated time stays the caller's time (at
// most one transfer ahead of it) instead of drifting ahead.
#pragma once

#include <algorithm>
#include <cstdint>
#include <memory>
#include <string>
#include <utility>

#include "elf_image.h"
#include "emu_image.h"
#include "f411_emu.h"
#include "hil_common.h"
#include "rotoscan/device/transport.h"
#include "usb_host.h"

namespace rotoscan::device::testing {

// The image's pins (firmware/port/stm32f411/board.h): STEP PB4, DIR PB5, LASER_L PB13, LASER_R PB14, TRIGGER
// PA15.
inline RigPin EmuRigPin(const fw_emu::PinEdge& e) {
  if (e.port == fw_emu::kPortB && e.pin == 4) return RigPin::kStep;
  if (e.port == fw_emu::kPortB && e.pin == 5) return RigPin::kDir;
  if (e.port == fw_emu::kPortB && e.pin == 13) return RigPin::kLaserLeft;
  if (e.port == fw_emu::kPortB && e.pin == 14) return RigPin::kLaserRight;
  if (e.port == fw_emu::kPortA && e.pin == 15) return RigPin::kTrigger;
  return RigPin::kOther;
}

// Skips the test when there is no image to run (in a test body or SetUp()).
#define ROTOSCAN_SKIP_WITHOUT_FW_IMAGE()                                     \
  if (!::rotoscan::fw_emu::ImageExists(::rotoscan::fw_emu::ImagePath()))     \
  GTEST_SKIP() << "no firmware image at " << ::rotoscan::fw_emu::ImagePath() \
               << " (the cross build, firmware.cross_build, needs arm-none-eabi-gcc)"

class EmuBoard : public VirtualBoard {
 public:
  explicit EmuBoard(fw_emu::EmuOptions options = {}) : options_(std::move(options)) {}

  // Loads the image, powers the chip on and enumerates it. false and *error when any of it fails.
  bool Boot(std::string* error) {
    fw_emu::ElfImage image;
    if (!fw_emu::ReadElf(fw_emu::ImagePath(), &image, error)) return false;
    emu_ = std::make_unique<fw_emu::F411Emu>(image, options_);
    if (!emu_->ok()) return *error = emu_->error(), false;
    emu_->PowerOn();
    host_ = std::make_unique<fw_emu::UsbHost>(emu_.get());
    const bool ok = Reenumerate(error);
    target_cycle_ = emu_->cycles();  // the caller's time starts here
    return ok;
  }
  bool Reenumerate(std::string* error) {
    const fw_emu::UsbHost::Enumeration e = host_->Enumerate(address_++);
    if (!e.ok) *error = e.error;
    return e.ok;
  }

  void Receive(const uint8_t* data, size_t size) override {
    if (!host_->BulkOut(kEpOut, data, size)) Note("bulk OUT: " + host_->error());
    last_out_cycle_ = emu_->cycles();
  }
  size_t Transmit(uint8_t* out, size_t max) override {
    fw_emu::UsbHost::Bytes bytes;
    if (!host_->BulkIn(kEpIn, max, &bytes)) Note("bulk IN: " + host_->error());
    std::copy(bytes.begin(), bytes.end(), out);
    return bytes.size();
  }
  // In slices of 100 us, each at the SYSCLK of its start (it changes at boot and after a reset).
  void Advance(int64_t us) override {
    for (int64_t done = 0; done < us;) {
      const int64_t slice = std::min<int64_t>(us - done, 100);
      target_cycle_ += static_cast<uint64_t>(slice) * (emu_->sysclk_hz() / 1'000'000u);
      done += slice;
      if (emu_->cycles() < target_cycle_ && !emu_->Run(target_cycle_ - emu_->cycles())) {
        Note(emu_->error());
        return;
      }
    }
  }

  fw_emu::F411Emu& emu() { return *emu_; }
  // The first thing that went wrong on the emulated side (empty when nothing did).
  const std::string& error() const { return error_; }
  // The cycle at which the last OUT transfer from the host had been taken by the image.
  uint64_t last_out_cycle() const { return last_out_cycle_; }

 private:
  static constexpr uint8_t kEpOut = 0x01, kEpIn = 0x01;
  void Note(const std::string& what) {
    if (error_.empty()) error_ = what;
  }
  fw_emu::EmuOptions options_;
  std::unique_ptr<fw_emu::F411Emu> emu_;
  std::unique_ptr<fw_emu::UsbHost> host_;
  uint8_t address_ = 5;
  std::string error_;
  uint64_t last_out_cycle_ = 0;
  uint64_t target_cycle_ = 0;
};

// The image's pin log decoded (hil_common.h), edge times in device microseconds: the TIM2 count less the
// count at fw_init (core/timebase.c g_tb.boot_counter, the first word of the image's g_tb).
inline PinLogDecoder DecodeEmuLog(fw_emu::F411Emu& emu) {
  const uint32_t boot_counter = emu.Peek(emu.image().Symbol("g_tb"));
  PinLogDecoder log;
  for (const fw_emu::PinEdge& e : emu.edges()) log.Add(e.tim2 - boot_counter, EmuRigPin(e), e.level);
  return log;
}

}  // namespace rotoscan::device::testing
