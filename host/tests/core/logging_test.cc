#include "rotoscan/core/logging.h"

#include <gtest/gtest.h>

#include <vector>

namespace rotoscan {
namespace {

class LoggingTest : public ::testing::Test {
 protected:
  void SetUp() override {
    saved_ = GetLogLevel();
    SetLogSink([this](LogLevel level, const std::string& text) { lines_.emplace_back(level, text); });
  }
  void TearDown() override {
    SetLogSink(nullptr);
    SetLogLevel(saved_);
  }
  LogLevel saved_;
  std::vector<std::pair<LogLevel, std::string>> lines_;
};

TEST_F(LoggingTest, MessagesBelowTheLevelAreDroppedAndNotEvaluated) {
  SetLogLevel(LogLevel::kWarning);
  int evaluated = 0;
  auto count = [&] { return ++evaluated; };
  ROTOSCAN_LOG(kInfo) << "hidden " << count();
  ROTOSCAN_LOG(kWarning) << "shown " << count();
  ROTOSCAN_LOG(kError) << "also " << 3;
  ASSERT_EQ(lines_.size(), 2u);
  EXPECT_EQ(evaluated, 1);
  EXPECT_EQ(lines_[0].first, LogLevel::kWarning);
  EXPECT_EQ(lines_[0].second, "shown 1");
  EXPECT_EQ(lines_[1].second, "also 3");
}

TEST_F(LoggingTest, OffSilencesEverything) {
  SetLogLevel(LogLevel::kOff);
  ROTOSCAN_LOG(kError) << "x";
  EXPECT_TRUE(lines_.empty());
}

TEST(LogLevelTest, ParsesNames) {
  EXPECT_EQ(ParseLogLevel("debug"), LogLevel::kDebug);
  EXPECT_EQ(ParseLogLevel("warn"), LogLevel::kWarning);
  EXPECT_EQ(ParseLogLevel("off"), LogLevel::kOff);
  EXPECT_FALSE(ParseLogLevel("loud").has_value());
  EXPECT_STREQ(LogLevelName(LogLevel::kError), "error");
}

}  // namespace
}  // namespace rotoscan
