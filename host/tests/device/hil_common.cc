#include "hil_common.h"

#include <gtest/gtest.h>

#include <map>

namespace rotoscan::device::testing {

ScanProgram HilProgram(uint32_t steps) {
  ScanProgram p;
  p.step_count = steps;
  p.steps_per_move = kHilStepsPerMove;
  p.settle_us = 500;
  p.laser_lead_us = 200;
  p.shots = {{kLaserLeft, 1000}, {kLaserRight, 1000}, {0, 1000}, {0, 4000}};  // left, right, off, natural
  return p;
}

MotionConfig HilConfig(uint32_t laser_timeout_ms) {
  MotionConfig c;
  c.start_rate_hz = 1000;
  c.max_rate_hz = 20000;
  c.accel_hz_per_s = 2'000'000;
  c.trigger_pulse_us = 50;
  c.laser_timeout_ms = laser_timeout_ms;
  return c;
}

void PinLogDecoder::Add(uint64_t time, RigPin pin, bool level) {
  switch (pin) {
    case RigPin::kLaserLeft: lasers_ = static_cast<uint8_t>((lasers_ & ~1u) | (level ? 1u : 0u)); break;
    case RigPin::kLaserRight: lasers_ = static_cast<uint8_t>((lasers_ & ~2u) | (level ? 2u : 0u)); break;
    case RigPin::kDir: dir_ = level ? 1 : -1; break;
    case RigPin::kStep:
      if (level) {
        position_ += dir_;
        ++step_pulses_;
      }
      break;
    case RigPin::kTrigger:
      if (level) triggers_.push_back({time, lasers_, position_});
      break;
    case RigPin::kOther: break;
  }
}

void CheckHilShots(const HilScanResult& scan, const ScanProgram& program, const std::vector<EdgeTruth>& edges,
                   int step_pulses) {
  ASSERT_EQ(scan.shots.size(), program.step_count * program.shots.size()) << "a (step, shot) lost";
  // Every motor step pulse was needed: the table went from the first step to the last exactly once.
  EXPECT_EQ(step_pulses, static_cast<int>((program.step_count - 1) * program.steps_per_move))
      << "a step lost or taken twice";
  EXPECT_LE(edges.size(), static_cast<size_t>(scan.triggers_seen) + (scan.safety_seen ? 2u : 0u))
      << "trigger edges without events";
  std::map<uint64_t, size_t> edge_at;
  for (size_t i = 0; i < edges.size(); ++i) edge_at[edges[i].time] = i;
  for (const auto& [key, t] : scan.shots) {
    const auto [step, shot] = key;
    const auto found = edge_at.find(t.time_us);
    ASSERT_NE(found, edge_at.end()) << "step " << step << " shot " << int(shot) << ": no trigger edge at "
                                    << t.time_us;
    const EdgeTruth& truth = edges[found->second];
    if (!scan.safety_seen) {
      EXPECT_EQ(found->second, t.trigger_seq) << "step " << step << " shot " << int(shot);
    }
    EXPECT_EQ(t.laser_mask, program.shots[shot].laser_mask) << "step " << step << " shot " << int(shot);
    EXPECT_EQ(truth.lasers, program.shots[shot].laser_mask) << "step " << step << " shot " << int(shot);
    EXPECT_EQ(t.position, static_cast<int32_t>(step) * program.steps_per_move);
    EXPECT_EQ(truth.position, t.position);
  }
}

}  // namespace rotoscan::device::testing
