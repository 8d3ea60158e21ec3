// The fake Ciclop board's ground truth (fake_ciclop.h) as the rig's truth (capture/virtual_rig.h), so that
// the virtual camera films what the fake board did: its lasers as they really switched and its table as it
// really turned, on the host's CLOCK_MONOTONIC. Header only: the users link rotoscan::capture.
#pragma once

#include <cmath>
#include <cstdint>
#include <vector>

#include "fake_ciclop.h"
#include "rotoscan/capture/virtual_rig.h"

namespace rotoscan::device::testing {

// The fake board's truth as the virtual camera reads it (laser 1 = left, 2 = right, as horus-fw counts).
class FakeCiclopTruth : public capture::RigTruth {
 public:
  explicit FakeCiclopTruth(const FakeCiclop* fake) : fake_(fake) {}
  void LaserFractions(int64_t from_us, int64_t to_us, double* left, double* right) override {
    const auto events = fake_->laser_events();
    double* out[2] = {left, right};
    for (int laser = 1; laser <= 2; ++laser) {
      bool on = false;
      int64_t lit = 0;
      int64_t t = from_us;
      for (const auto& e : events) {
        if (e.laser != laser) continue;
        if (e.time_us <= from_us) {
          on = e.on;
          continue;
        }
        if (e.time_us >= to_us) break;
        if (on) lit += e.time_us - t;
        t = e.time_us;
        on = e.on;
      }
      if (on) lit += to_us - t;
      *out[laser - 1] = to_us > from_us ? static_cast<double>(lit) / static_cast<double>(to_us - from_us) : 0.0;
    }
  }
  double TableAngleAt(int64_t us) override { return fake_->TableAngleAt(us) * M_PI / 180.0; }
  std::vector<int64_t> TriggerEdges(int64_t, int64_t) override { return {}; }  // no trigger line
  std::vector<int64_t> LaserSwitches(int64_t from_us, int64_t to_us) override {
    std::vector<int64_t> times;
    for (const auto& e : fake_->laser_events()) {
      if (e.time_us >= from_us && e.time_us <= to_us) times.push_back(e.time_us);
    }
    return times;
  }

 private:
  const FakeCiclop* fake_;
};

}  // namespace rotoscan::device::testing
