// Matches camera frames to the board's trigger events by sequence number, and reports what is missing.
//
// The board fires the camera in hardware and reports every edge as a TRIGGER event with its own counter
// (trigger seq). The camera numbers its frames too. Once the first frame is tied to the first trigger of a
// capture, frame (first_frame + k) belongs to trigger (first_trigger + k): a camera that drops a frame
// skips a number, a lost event leaves a hole in the trigger seqs, and both are reported rather than
// silently shifted. With a clock fit the frame's host timestamp is also checked against the trigger time
// converted to the host clock: a frame further away than `max_time_error_us` is reported as a mismatch
// (a wrong pairing would be off by a whole frame period).
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "rotoscan/core/status.h"
#include "rotoscan/device/clock_sync.h"

namespace rotoscan::device {

struct TriggerRecord {
  uint32_t trigger_seq = 0;
  uint64_t device_us = 0;  // trigger edge on the board's clock
  uint8_t laser_mask = 0;
  int32_t table_position = 0;  // motor steps
};

struct FrameRecord {
  uint64_t frame_id = 0;  // the camera's own counter
  int64_t host_us = 0;    // when the host received or timestamped the frame
};

struct FrameMatchOptions {
  // Frame k is expected at trigger time + latency (exposure + readout + transfer).
  double expected_latency_us = 0.0;
  double max_time_error_us = 5000.0;
  Status Check() const;
};

struct FrameMatch {
  uint64_t frame_id = 0;
  TriggerRecord trigger;
  std::optional<double> time_error_us;  // frame time - (trigger time on host + latency), with a clock fit
};

struct FrameMatchReport {
  std::vector<FrameMatch> matches;
  std::vector<uint32_t> missing_triggers;  // trigger seqs with no event (lost events)
  std::vector<uint32_t> missing_frames;    // trigger seqs whose frame the camera never delivered
  std::vector<uint64_t> unmatched_frames;  // frame ids beyond the last trigger, or whose trigger is missing
  std::vector<uint64_t> time_mismatches;   // frame ids whose time is off by more than max_time_error_us
  bool complete() const {
    return missing_triggers.empty() && missing_frames.empty() && unmatched_frames.empty() &&
           time_mismatches.empty();
  }
  std::string Summary() const;  // "200 matched; missing triggers: 17; missing frames: none; ..."
};

// `triggers` and `frames` in any order; duplicates (same seq or same frame id) are InvalidArgument.
// The first frame (lowest id) is tied to the first trigger (lowest seq). Empty inputs give an empty report.
Result<FrameMatchReport> MatchFrames(std::vector<TriggerRecord> triggers, std::vector<FrameRecord> frames,
                                     const std::optional<ClockFit>& clock,
                                     const FrameMatchOptions& options = {});

}  // namespace rotoscan::device
