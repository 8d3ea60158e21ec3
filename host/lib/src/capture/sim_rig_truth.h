// The firmware simulator's pin-edge log (firmware/port/sim, sim_edges()) as the rig's truth (virtual_rig.h):
// laser levels, step pulses and trigger edges on the scan's host clock, device time t being host time
// `host_offset_us + t`. The sim board uses it in virtual time; the hardware-in-the-loop tests use it for the
// simulator behind a mocked USB bus, whose time runs in another thread: `locked` then runs each read of the
// log with that thread held (null: read directly). Another pin log (the emulated board's, in the tests) can
// feed the same timeline: a subclass overrides ReadLog() and hands each new edge to AddEdge().
#pragma once

#include <cstdint>
#include <functional>
#include <utility>
#include <vector>

#include "rotoscan/capture/virtual_rig.h"

namespace rotoscan::capture::internal {

class SimRigTruth : public RigTruth {
 public:
  using Locked = std::function<void(const std::function<void()>&)>;
  SimRigTruth(int64_t host_offset_us, double radians_per_step, Locked locked = nullptr)
      : offset_(host_offset_us), radians_per_step_(radians_per_step), locked_(std::move(locked)) {}

  void LaserFractions(int64_t from_us, int64_t to_us, double* left, double* right) override;
  double TableAngleAt(int64_t us) override;
  std::vector<int64_t> TriggerEdges(int64_t after_us, int64_t until_us) override;
  std::vector<int64_t> LaserSwitches(int64_t from_us, int64_t to_us) override;
  // Whether a laser was lit at `us` (0 left, 1 right).
  bool LaserAt(int laser, int64_t us);

 protected:
  enum class Pin { kLaserLeft, kLaserRight, kDir, kStep, kTrigger };
  // One edge of the log at host time `host_us`, in time order.
  void AddEdge(int64_t host_us, Pin pin, bool level);
  // Takes the log's edges not taken yet (run through `locked` when given).
  virtual void ReadLog();

 private:
  void Update();
  double Fraction(int i, int64_t from, int64_t to) const;

  int64_t offset_;
  double radians_per_step_;
  Locked locked_;
  size_t seen_ = 0;
  int dir_ = 1;
  int32_t position_ = 0;
  std::vector<std::pair<int64_t, bool>> laser_[2];
  std::vector<int64_t> step_times_;
  std::vector<int32_t> step_positions_;
  std::vector<int64_t> triggers_;
};

}  // namespace rotoscan::capture::internal
