#include <gtest/gtest.h>

#include <sstream>
#include <string>
#include <vector>

#include "command.h"
#include "rotoscan/core/version.h"

namespace rotoscan::cli {
namespace {

struct CliRun {
  int code;
  std::string out, err;
};

CliRun Call(std::vector<const char*> args) {
  args.insert(args.begin(), "rotoscan");
  std::ostringstream out, err;
  const int code = Main(static_cast<int>(args.size()), args.data(), out, err);
  return {code, out.str(), err.str()};
}

TEST(CliTest, HelpListsEveryCommand) {
  const CliRun r = Call({"--help"});
  EXPECT_EQ(r.code, kExitOk);
  for (const char* command : {"demo", "simulate", "calibrate", "extract", "process", "mesh", "evaluate",
                              "scan", "devices", "device", "merge", "bench"}) {
    EXPECT_NE(r.out.find(command), std::string::npos) << command << " missing from:\n" << r.out;
  }
}

TEST(CliTest, EveryCommandHasHelp) {
  for (const char* command : {"demo", "simulate", "calibrate", "extract", "process", "mesh", "evaluate",
                              "scan", "devices", "device", "merge", "bench"}) {
    const CliRun r = Call({command, "--help"});
    EXPECT_EQ(r.code, kExitOk) << command;
    EXPECT_NE(r.out.find(command), std::string::npos) << r.out;
  }
}

TEST(CliTest, Version) {
  const CliRun r = Call({"--version"});
  EXPECT_EQ(r.code, kExitOk);
  EXPECT_NE(r.out.find(ROTOSCAN_VERSION_STRING), std::string::npos) << r.out;
}

TEST(CliTest, UsageErrorsExitWithTwo) {
  EXPECT_EQ(Call({}).code, kExitUsage);  // no command
  const CliRun r = Call({"frobnicate"});
  EXPECT_EQ(r.code, kExitUsage);
  EXPECT_FALSE(r.err.empty());
  EXPECT_EQ(Call({"--log-level", "loud", "demo"}).code, kExitUsage);
}

TEST(CliTest, ReportStatusMapsCodes) {
  std::ostringstream out, err;
  const Context context{&out, &err, nullptr};
  EXPECT_EQ(ReportStatus(context, "x", Status::Ok()), kExitOk);
  EXPECT_EQ(ReportStatus(context, "process", NotFoundError("calib.yaml does not exist")), kExitFailure);
  EXPECT_NE(err.str().find("rotoscan process: not found: calib.yaml does not exist"), std::string::npos);
  EXPECT_EQ(ReportStatus(context, "x", UnimplementedError("later")), kExitNotBuilt);
}

}  // namespace
}  // namespace rotoscan::cli
