// rotoscan device: bench work with the scanner board over USB (list, info, ping, move, laser). The Run
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
int RunDevicePing(const Context& context, const DeviceOptions& options, int count);
// Turns the table by `degrees` (motor steps = degrees / 360 * steps_per_rev) and waits for the move to end.
int RunDeviceMove(const Context& context, const DeviceOptions& options, double degrees, int steps_per_rev);
// Lasers "left", "right", "both" or "off". The board turns them off by itself once the host is silent
// longer than its laser timeout.
int RunDeviceLaser(const Context& context, const DeviceOptions& options, const std::string& which);

}  // namespace rotoscan::cli
