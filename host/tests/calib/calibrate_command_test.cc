// `rotoscan calibrate camera` and `rotoscan calibrate BUNDLE...` through the CLI's Main, as a user runs them.
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core/persistence.hpp>

#include "command.h"
#include "testing/testing.h"

namespace rotoscan::cli {
namespace {

using rotoscan::testing::DataPath;
using rotoscan::testing::ScratchDir;
using ::testing::HasSubstr;

struct CliRun {
  int code;
  std::string out, err;
};

CliRun Call(std::vector<std::string> args) {
  args.insert(args.begin(), "rotoscan");
  args.insert(args.begin() + 1, "--no-progress");
  std::vector<const char*> argv;
  for (const auto& a : args) argv.push_back(a.c_str());
  std::ostringstream out, err;
  const int code = Main(static_cast<int>(argv.size()), argv.data(), out, err);
  return {code, out.str(), err.str()};
}

TEST(CalibrateCommandTest, CameraOnOpenCvSampleWritesCameraYaml) {
  ScratchDir dir;
  const CliRun r = Call({"calibrate", "camera", "--images", DataPath("calib/opencv-left").string(),
                         "--pattern", "9x6", "--square", "25", "--out", (dir / "camera.yaml").string()});
  ASSERT_EQ(r.code, kExitOk) << r.err;
  EXPECT_THAT(r.out, HasSubstr("from 13 views"));
  cv::FileStorage fs((dir / "camera.yaml").string(), cv::FileStorage::READ);
  ASSERT_TRUE(fs.isOpened());
  cv::Mat k;
  fs["K"] >> k;
  EXPECT_NEAR(k.at<double>(0, 0), 535.9, 0.005 * 535.9);
}

TEST(CalibrateCommandTest, CameraBadInputSaysWhatToDo) {
  ScratchDir dir;
  CliRun r = Call({"calibrate", "camera", "--images", dir.path().string(), "--pattern", "9x6", "--square",
                   "25", "--out", (dir / "camera.yaml").string()});
  EXPECT_EQ(r.code, kExitFailure);
  EXPECT_THAT(r.err, HasSubstr("no images"));
  r = Call({"calibrate", "camera", "--images", DataPath("calib/opencv-left").string(), "--pattern", "9by6",
            "--square", "25", "--out", (dir / "camera.yaml").string()});
  EXPECT_EQ(r.code, kExitFailure);
  EXPECT_THAT(r.err, HasSubstr("COLSxROWS"));
  EXPECT_FALSE(std::filesystem::exists(dir / "camera.yaml"));
  r = Call({"calibrate", "camera", "--pattern", "9x6"});
  EXPECT_EQ(r.code, kExitUsage);
}

TEST(CalibrateCommandTest, RigNeedsReadableCalibrationBundles) {
  ScratchDir dir;
  CliRun r = Call({"calibrate", "--out", (dir / "calib.yaml").string()});
  EXPECT_EQ(r.code, kExitFailure);
  EXPECT_THAT(r.err, HasSubstr("no calibration bundle"));
  r = Call({"calibrate", (dir / "missing").string(), "--out", (dir / "calib.yaml").string()});
  EXPECT_EQ(r.code, kExitFailure);
  EXPECT_FALSE(std::filesystem::exists(dir / "calib.yaml"));
}

}  // namespace
}  // namespace rotoscan::cli
