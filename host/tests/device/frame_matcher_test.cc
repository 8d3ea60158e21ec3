#include "rotoscan/device/frame_matcher.h"

#include <gtest/gtest.h>

namespace rotoscan::device {
namespace {

// 10 triggers 33 ms apart from trigger seq 100, frames from camera id 7 arriving 12 ms after each trigger.
// The board clock is 1 s ahead of the host clock and 0 ppm.
constexpr double kPeriodUs = 33'000, kLatencyUs = 12'000;

std::vector<TriggerRecord> Triggers() {
  std::vector<TriggerRecord> t;
  for (uint32_t k = 0; k < 10; ++k) t.push_back({100 + k, static_cast<uint64_t>(1e6 + k * kPeriodUs), 1, 0});
  return t;
}
std::vector<FrameRecord> Frames() {
  std::vector<FrameRecord> f;
  for (uint64_t k = 0; k < 10; ++k) f.push_back({7 + k, static_cast<int64_t>(k * kPeriodUs + kLatencyUs)});
  return f;
}
ClockFit Clock() {
  ClockFit c;
  c.offset_us = 1e6;
  return c;
}
FrameMatchOptions Options() {
  FrameMatchOptions o;
  o.expected_latency_us = kLatencyUs;
  o.max_time_error_us = 5000;
  return o;
}

TEST(FrameMatcherTest, CompleteCaptureMatchesOneToOne) {
  auto report = MatchFrames(Triggers(), Frames(), Clock(), Options());
  ASSERT_TRUE(report.ok());
  EXPECT_TRUE(report->complete()) << report->Summary();
  ASSERT_EQ(report->matches.size(), 10u);
  EXPECT_EQ(report->matches[3].frame_id, 10u);
  EXPECT_EQ(report->matches[3].trigger.trigger_seq, 103u);
  EXPECT_NEAR(*report->matches[3].time_error_us, 0.0, 1e-6);
}

TEST(FrameMatcherTest, LostEventAndDroppedFrameAreReportedNotShifted) {
  auto triggers = Triggers();
  triggers.erase(triggers.begin() + 4);  // event 104 lost
  auto frames = Frames();
  frames.erase(frames.begin() + 6);  // camera dropped frame 13 (trigger 106)
  auto report = MatchFrames(triggers, frames, Clock(), Options());
  ASSERT_TRUE(report.ok());
  EXPECT_FALSE(report->complete());
  EXPECT_EQ(report->missing_triggers, std::vector<uint32_t>{104});
  EXPECT_EQ(report->missing_frames, std::vector<uint32_t>{106});
  EXPECT_EQ(report->unmatched_frames, std::vector<uint64_t>{11});  // its trigger is the lost one
  EXPECT_TRUE(report->time_mismatches.empty());
  EXPECT_EQ(report->matches.size(), 8u);
  for (const FrameMatch& m : report->matches) EXPECT_EQ(m.trigger.trigger_seq - 100, m.frame_id - 7);
  EXPECT_NE(report->Summary().find("missing triggers: 104"), std::string::npos) << report->Summary();
}

TEST(FrameMatcherTest, FrameAtTheWrongTimeIsAMismatch) {
  auto frames = Frames();
  frames[5].host_us += static_cast<int64_t>(kPeriodUs);  // looks like the next trigger's frame
  auto report = MatchFrames(Triggers(), frames, Clock(), Options());
  ASSERT_TRUE(report.ok());
  EXPECT_EQ(report->time_mismatches, std::vector<uint64_t>{12});
  // Without a clock nothing can be said about time.
  auto untimed = MatchFrames(Triggers(), frames, std::nullopt, Options());
  ASSERT_TRUE(untimed.ok());
  EXPECT_TRUE(untimed->complete());
}

TEST(FrameMatcherTest, ExtraFramesAndBadInput) {
  auto frames = Frames();
  frames.push_back({17, static_cast<int64_t>(10 * kPeriodUs + kLatencyUs)});
  auto report = MatchFrames(Triggers(), frames, Clock(), Options());
  ASSERT_TRUE(report.ok());
  EXPECT_EQ(report->unmatched_frames, std::vector<uint64_t>{17});
  auto duplicate = Triggers();
  duplicate.push_back(duplicate[2]);
  EXPECT_EQ(MatchFrames(duplicate, Frames(), Clock(), Options()).status().code(),
            StatusCode::kInvalidArgument);
  FrameMatchOptions bad;
  bad.max_time_error_us = 0;
  EXPECT_EQ(MatchFrames(Triggers(), Frames(), Clock(), bad).status().code(), StatusCode::kInvalidArgument);
  auto empty = MatchFrames({}, {}, std::nullopt, Options());
  ASSERT_TRUE(empty.ok());
  EXPECT_TRUE(empty->matches.empty());
}

}  // namespace
}  // namespace rotoscan::device
