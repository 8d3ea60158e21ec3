// Frame-to-trigger matching by sequence number; see frame_matcher.h.
#include "rotoscan/device/frame_matcher.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <sstream>

namespace rotoscan::device {

Status FrameMatchOptions::Check() const {
  if (!(max_time_error_us > 0.0)) return InvalidArgumentError("frame match: max_time_error_us must be > 0");
  if (!std::isfinite(expected_latency_us))
    return InvalidArgumentError("frame match: expected_latency_us not finite");
  return Status::Ok();
}

namespace {
template <typename T>
void AppendList(std::ostringstream& s, const char* name, const std::vector<T>& v) {
  s << "; " << name << ": ";
  if (v.empty()) {
    s << "none";
    return;
  }
  for (size_t i = 0; i < v.size() && i < 10; ++i) s << (i ? "," : "") << v[i];
  if (v.size() > 10) s << ",... (" << v.size() << ")";
}
}  // namespace

std::string FrameMatchReport::Summary() const {
  std::ostringstream s;
  s << matches.size() << " matched";
  AppendList(s, "missing triggers", missing_triggers);
  AppendList(s, "missing frames", missing_frames);
  AppendList(s, "unmatched frames", unmatched_frames);
  AppendList(s, "time mismatches", time_mismatches);
  return s.str();
}

Result<FrameMatchReport> MatchFrames(std::vector<TriggerRecord> triggers, std::vector<FrameRecord> frames,
                                     const std::optional<ClockFit>& clock, const FrameMatchOptions& options) {
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  FrameMatchReport report;
  std::sort(triggers.begin(), triggers.end(),
            [](const TriggerRecord& a, const TriggerRecord& b) { return a.trigger_seq < b.trigger_seq; });
  std::sort(frames.begin(), frames.end(),
            [](const FrameRecord& a, const FrameRecord& b) { return a.frame_id < b.frame_id; });
  for (size_t i = 1; i < triggers.size(); ++i) {
    if (triggers[i].trigger_seq == triggers[i - 1].trigger_seq) {
      return InvalidArgumentError("frame match: trigger seq " + std::to_string(triggers[i].trigger_seq) +
                                  " appears twice");
    }
  }
  for (size_t i = 1; i < frames.size(); ++i) {
    if (frames[i].frame_id == frames[i - 1].frame_id) {
      return InvalidArgumentError("frame match: frame id " + std::to_string(frames[i].frame_id) +
                                  " appears twice");
    }
  }
  if (triggers.empty() || frames.empty()) {
    for (const FrameRecord& f : frames) report.unmatched_frames.push_back(f.frame_id);
    return report;
  }
  const uint32_t first_seq = triggers.front().trigger_seq;
  const uint32_t last_seq = triggers.back().trigger_seq;
  const uint64_t first_frame = frames.front().frame_id;
  std::map<uint32_t, const TriggerRecord*> by_seq;
  for (const TriggerRecord& t : triggers) by_seq[t.trigger_seq] = &t;
  for (uint32_t seq = first_seq; seq != last_seq; ++seq) {
    if (!by_seq.count(seq)) report.missing_triggers.push_back(seq);
  }
  std::map<uint32_t, const FrameRecord*> frame_by_seq;
  for (const FrameRecord& f : frames) {
    const uint64_t k = f.frame_id - first_frame;
    if (k > static_cast<uint64_t>(last_seq - first_seq)) {
      report.unmatched_frames.push_back(f.frame_id);
      continue;
    }
    const uint32_t seq = first_seq + static_cast<uint32_t>(k);
    frame_by_seq[seq] = &f;
    auto it = by_seq.find(seq);
    if (it == by_seq.end()) {
      report.unmatched_frames.push_back(f.frame_id);
      continue;
    }
    FrameMatch match;
    match.frame_id = f.frame_id;
    match.trigger = *it->second;
    if (clock) {
      const double expected =
          clock->HostFromDevice(static_cast<double>(it->second->device_us)) + options.expected_latency_us;
      match.time_error_us = static_cast<double>(f.host_us) - expected;
      if (std::abs(*match.time_error_us) > options.max_time_error_us)
        report.time_mismatches.push_back(f.frame_id);
    }
    report.matches.push_back(match);
  }
  for (const TriggerRecord& t : triggers) {
    if (!frame_by_seq.count(t.trigger_seq)) report.missing_frames.push_back(t.trigger_seq);
  }
  return report;
}

}  // namespace rotoscan::device
