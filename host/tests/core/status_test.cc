#include "rotoscan/core/status.h"

#include <gtest/gtest.h>

#include "rotoscan/core/check.h"

namespace rotoscan {
namespace {

Result<int> ParsePositive(int v) {
  if (v <= 0) return InvalidArgumentError("value must be > 0, got " + std::to_string(v));
  return v;
}

Result<int> Doubled(int v) {
  ROTOSCAN_ASSIGN_OR_RETURN(int x, ParsePositive(v));
  return 2 * x;
}

Status CheckBoth(int a, int b) {
  ROTOSCAN_RETURN_IF_ERROR(ParsePositive(a).status());
  ROTOSCAN_RETURN_IF_ERROR(ParsePositive(b).status());
  return Status::Ok();
}

TEST(StatusTest, OkAndErrorsFormat) {
  EXPECT_TRUE(Status::Ok().ok());
  EXPECT_EQ(Status::Ok().ToString(), "ok");
  const Status s = NotFoundError("calib.yaml does not exist");
  EXPECT_FALSE(s.ok());
  EXPECT_EQ(s.code(), StatusCode::kNotFound);
  EXPECT_EQ(s.ToString(), "not found: calib.yaml does not exist");
  EXPECT_EQ(s.WithContext("loading rig").ToString(), "not found: loading rig: calib.yaml does not exist");
  EXPECT_TRUE(Status::Ok().WithContext("x").ok());
}

TEST(StatusTest, ResultHoldsValueOrError) {
  EXPECT_EQ(*Doubled(4), 8);
  const Result<int> bad = Doubled(-1);
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(bad.status().message().find("-1"), std::string::npos);
  // Taking the value of an error is a caller bug: it throws rather than returning garbage.
  EXPECT_THROW((void)bad.value(), PreconditionError);
}

TEST(StatusTest, ReturnIfErrorStopsAtFirstError) {
  EXPECT_TRUE(CheckBoth(1, 2).ok());
  const Status s = CheckBoth(1, -7);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("-7"), std::string::npos);
}

TEST(StatusTest, ResultFromOkStatusIsAnInternalError) {
  const Result<int> r{Status::Ok()};
  EXPECT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), StatusCode::kInternal);
}

TEST(CheckTest, FailedCheckThrowsWithFileLineAndMessage) {
  const int width = -3;
  try {
    ROTOSCAN_CHECK_GT(width, 0) << "image width";
    FAIL() << "no throw";
  } catch (const PreconditionError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("status_test.cc:"), std::string::npos) << what;
    EXPECT_NE(what.find("width = -3"), std::string::npos) << what;
    EXPECT_NE(what.find("image width"), std::string::npos) << what;
  }
  EXPECT_NO_THROW(ROTOSCAN_CHECK(width < 0) << "never evaluated");
}

}  // namespace
}  // namespace rotoscan
