// The firmware core built for the host (firmware/port/sim) as a VirtualBoard. The simulator is one global
// board: create one SimBoard at a time.
#pragma once

#include "hil_common.h"
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

// The simulator's pin log decoded (hil_common.h), edge times in device microseconds.
inline PinLogDecoder DecodeSimLog() {
  PinLogDecoder log;
  const sim_edge_t* edges = sim_edges();
  for (size_t i = 0; i < sim_edge_count(); ++i) {
    const sim_edge_t& e = edges[i];
    RigPin pin = RigPin::kOther;
    switch (e.pin) {
      case SIM_PIN_LASER_LEFT: pin = RigPin::kLaserLeft; break;
      case SIM_PIN_LASER_RIGHT: pin = RigPin::kLaserRight; break;
      case SIM_PIN_DIR: pin = RigPin::kDir; break;
      case SIM_PIN_STEP: pin = RigPin::kStep; break;
      case SIM_PIN_TRIGGER: pin = RigPin::kTrigger; break;
      default: break;
    }
    log.Add(e.time_us, pin, e.level != 0);
  }
  return log;
}

}  // namespace rotoscan::device::testing
