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
