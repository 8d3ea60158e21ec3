// rotoscan device: bench work with the scanner board over USB (list, info, ping, move, laser, flash). The Run
// functions are what the CLI calls; tests call them too (with a board on a mocked USB bus).
#pragma once

#include <cstdint>
#include <string>

#include "command.h"

namespace rotoscan::cli {

struct DeviceOptions {
  int bus = 0;  // pick one board by bus and address when several are attached; 0 = the first
  int address = 0;
  double ack_timeout_ms = 200;
};

// Prints one line per attached board; says "no Rotoscan board found" and returns 1 when there is none.
int RunDeviceList(const Context& context);
// Protocol and firmware versions, capabilities, serial number.
int RunDeviceInfo(const Context& context, const DeviceOptions& options);
// `count` round trips: fastest and median round trip, clock offset and drift.
// `rotoscan device status`: the board's STATUS and, from protocol 1.1 boards, its DIAG (the step interrupt's
// measured cycles, the fault recorded before the last reset).
int RunDeviceStatus(const Context& context, const DeviceOptions& options);
int RunDevicePing(const Context& context, const DeviceOptions& options, int count);
// Turns the table by `degrees` (motor steps = degrees / 360 * steps_per_rev) and waits for the move to end.
int RunDeviceMove(const Context& context, const DeviceOptions& options, double degrees, int steps_per_rev);
// Lasers "left", "right", "both" or "off". The board turns them off by itself once the host is silent
// longer than its laser timeout.
int RunDeviceLaser(const Context& context, const DeviceOptions& options, const std::string& which);

struct FlashOptions {
  std::string dfu_util = "dfu-util";  // found on PATH unless it holds a '/'
  double wait_s = 15;                 // for the board to come back on USB after dfu-util's :leave
};

// Flashes a firmware image (rotoscan-fw.bin) through the STM32's ROM DFU bootloader (0483:df11; BOOT0 held
// high at reset) by running `dfu-util -a 0 -d 0483:df11 -s 0x08000000:leave -D FILE`, then waits for the
// board to come back and checks that its firmware version is the one in the image's USB device descriptor.
// Refuses a file that is not an STM32F411 image (an .elf, a truncated or oversized file) before touching
// the board.
int RunDeviceFlash(const Context& context, const DeviceOptions& options, const std::string& file,
                   const FlashOptions& flash);

// The firmware version ("1.2.3") an image's USB device descriptor declares (bcdDevice of the Rotoscan
// VID:PID), or an error when `image` is not a Rotoscan STM32F411 image.
Result<std::string> FirmwareImageVersion(const std::string& image);

}  // namespace rotoscan::cli
