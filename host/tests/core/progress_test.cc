#include "rotoscan/core/progress.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <cstdlib>
#include <string>
#include <thread>
#include <vector>

namespace rotoscan {
namespace {

std::string ReadAll(std::FILE* f) {
  std::fflush(f);
  std::rewind(f);
  std::string s;
  char buffer[256];
  size_t n;
  while ((n = std::fread(buffer, 1, sizeof(buffer), f)) > 0) s.append(buffer, n);
  return s;
}

TEST(ProgressBarTest, QuietWhenNotATerminal) {
  std::FILE* f = std::tmpfile();
  ASSERT_NE(f, nullptr);
  EXPECT_FALSE(ShouldDrawProgress(f));  // a file, as in a pipe or a CI log
  {
    ProgressBar bar(ProgressBar::Mode::kAuto, f);
    EXPECT_FALSE(bar.enabled());
    bar.Begin("render", 10);
    for (int i = 0; i < 10; ++i) bar.Advance();
    bar.End();
    EXPECT_EQ(bar.done(), 10u);
  }
  EXPECT_EQ(ReadAll(f), "");
  std::fclose(f);
}

TEST(ProgressBarTest, DrawsWhenForcedAndEndsWithANewline) {
  std::FILE* f = std::tmpfile();
  ASSERT_NE(f, nullptr);
  {
    ProgressBar bar(ProgressBar::Mode::kAlways, f);
    bar.Begin("process", 4);
    bar.Advance(4);
    bar.End();
  }
  const std::string text = ReadAll(f);
  std::fclose(f);
  EXPECT_NE(text.find("process"), std::string::npos) << text;
  EXPECT_NE(text.find("100% 4/4"), std::string::npos) << text;
  EXPECT_EQ(text.back(), '\n');
}

TEST(ProgressBarTest, FormatsFractionRateAndEta) {
  ProgressBar bar(ProgressBar::Mode::kNever);
  bar.Begin("render", 200);
  bar.Advance(50);
  const std::string line = bar.FormatLine(10.0);  // 50 units in 10 s: 5/s, 150 left -> 30 s
  EXPECT_NE(line.find(" 25% 50/200"), std::string::npos) << line;
  EXPECT_NE(line.find("5.0/s"), std::string::npos) << line;
  EXPECT_NE(line.find("eta 30s"), std::string::npos) << line;
  EXPECT_NE(line.find("[########"), std::string::npos) << line;
}

// A scan: steps are the units, frames (several a step) the second count, both rates shown, the time left
// from the steps.
TEST(ProgressBarTest, FormatsASecondCountWithItsOwnRate) {
  ProgressBar bar(ProgressBar::Mode::kNever);
  bar.Begin("scan", 1200);
  bar.SetUnits("steps", "frames");
  bar.Advance(300);
  bar.AdvanceSecondary(1230);  // 4 a step and 30 more (re-takes, frames rejected)
  const std::string line = bar.FormatLine(41.0);  // 300 steps in 41 s: 7.3/s, 900 left -> 123 s
  EXPECT_NE(line.find(" 25% 300/1200 steps"), std::string::npos) << line;
  EXPECT_NE(line.find("  7.3 steps/s"), std::string::npos) << line;
  EXPECT_NE(line.find("  30.0 frames/s"), std::string::npos) << line;
  EXPECT_NE(line.find("eta 123s"), std::string::npos) << line;
  EXPECT_EQ(bar.secondary_done(), 1230u);
  bar.Advance(900);
  bar.AdvanceSecondary(3600);
  const std::string last = bar.FormatLine(164.0);  // done: the frames taken and the time, no rate
  EXPECT_NE(last.find("100% 1200/1200 steps  4830 frames  164.0s"), std::string::npos) << last;
  // Units and the second count belong to one phase.
  bar.Begin("process", 10);
  bar.Advance(5);
  const std::string next = bar.FormatLine(1.0);
  EXPECT_EQ(next.find("frames"), std::string::npos) << next;
  EXPECT_NE(next.find(" 50% 5/10  5.0/s  eta 1s"), std::string::npos) << next;
  EXPECT_EQ(bar.secondary_done(), 0u);
}

TEST(ProgressBarTest, CountsFromManyThreads) {
  ProgressBar bar(ProgressBar::Mode::kNever);
  bar.Begin("x", 4000);
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t)
    threads.emplace_back([&] {
      for (int i = 0; i < 1000; ++i) bar.Advance();
    });
  for (auto& t : threads) t.join();
  EXPECT_EQ(bar.done(), 4000u);
}

TEST(ProgressScopeTest, ToleratesNull) {
  ProgressScope scope(nullptr, "nothing", 3);
  scope.Advance();
  EXPECT_FALSE(scope.Cancelled());
}

}  // namespace
}  // namespace rotoscan
