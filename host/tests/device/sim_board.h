// The firmware core built for the host (firmware/port/sim) as a VirtualBoard. The simulator is one global
// board: create one SimBoard at a time.
#pragma once

#include "rotoscan/device/transport.h"
#include "sim_port.h"

namespace rotoscan::device::testing {

class SimBoard : public VirtualBoard {
 public:
  SimBoard() { sim_reset(); }
  void Receive(const uint8_t* data, size_t size) override { sim_usb_receive(data, size); }
  size_t Transmit(uint8_t* out, size_t max) override { return sim_usb_transmit(out, max); }
  void Advance(int64_t us) override { sim_advance_us(static_cast<uint64_t>(us)); }
};

}  // namespace rotoscan::device::testing
