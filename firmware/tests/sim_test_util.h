// Reading the simulated board's pin-edge log in the firmware tests.
#pragma once

#include <cstdint>
#include <vector>

#include "sim_port.h"

namespace rotoscan::firmware_test {

// Times of the edges of `pin` to `level`, oldest first.
inline std::vector<uint64_t> EdgeTimes(sim_pin_t pin, int level) {
  std::vector<uint64_t> out;
  const sim_edge_t* e = sim_edges();
  for (size_t i = 0; i < sim_edge_count(); ++i) {
    if (e[i].pin == pin && e[i].level == level) out.push_back(e[i].time_us);
  }
  return out;
}

// Replays the log: the level of `pin` just after every edge at or before time t was applied, starting from
// `initial`.
inline int LevelAt(sim_pin_t pin, uint64_t t, int initial = 0) {
  int level = initial;
  const sim_edge_t* e = sim_edges();
  for (size_t i = 0; i < sim_edge_count() && e[i].time_us <= t; ++i) {
    if (e[i].pin == pin) level = e[i].level;
  }
  return level;
}

// The laser mask at time t from the log (bit 0 left, bit 1 right).
inline int LaserMaskAt(uint64_t t) {
  return LevelAt(SIM_PIN_LASER_LEFT, t) | (LevelAt(SIM_PIN_LASER_RIGHT, t) << 1);
}

}  // namespace rotoscan::firmware_test
