// `rotoscan calibrate camera` and `rotoscan calibrate BUNDLE...` through the CLI's Main, as a user runs them.
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core/persistence.hpp>

#include "command.h"
#include "rotoscan/core/logging.h"
#include "testing/testing.h"

namespace rotoscan::cli {
namespace {

using rotoscan::testing::DataPath;
using rotoscan::testing::ScratchDir;
using ::testing::HasSubstr;
using ::testing::Not;

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

// A capture where the board is never in view: the command fails saying what to capture, and writes nothing.
TEST(CalibrateCommandTest, TargetNeverFoundSaysWhatToCapture) {
  ScratchDir dir;
  const std::string scene = (dir / "scene.json").string();
  {
    std::ofstream f(scene);
    // A small sensor (the same 20 degree lens) keeps the rendering short.
    f << R"({"camera": {"width": 320, "height": 240, "hfov_deg": 20},
             "objects": [{"type": "checkerboard", "cols": 9, "rows": 6, "square_mm": 7,
                          "position_mm": [300, 0, 0]}]})";
  }
  const std::string bundle = (dir / "bundle").string();
  CliRun r = Call({"simulate", scene, "--kind", "table-checkerboard", "--steps", "3", "--out", bundle});
  ASSERT_EQ(r.code, kExitOk) << r.err;
  std::string warnings;
  SetLogSink([&](LogLevel level, const std::string& message) {
    if (level == LogLevel::kWarning) warnings += message + "\n";
  });
  r = Call({"calibrate", bundle, "--out", (dir / "calib.yaml").string()});
  SetLogSink(nullptr);
  EXPECT_EQ(r.code, kExitFailure);
  EXPECT_THAT(r.err, HasSubstr("target was not found in any view"));
  EXPECT_THAT(r.err, HasSubstr("whole target is in view"));
  // One warning line for the bundle, naming the steps, not one per frame.
  EXPECT_THAT(warnings, HasSubstr("target not found at 3 of 3 views (steps 0 1 2)"));
  EXPECT_THAT(warnings, Not(HasSubstr("natural.png")));
  EXPECT_FALSE(std::filesystem::exists(dir / "calib.yaml"));
}

// The paper's calibration object end to end on the virtual scanner: two rendered placements
// (data/scenes/calibration-object*.json), `rotoscan calibrate` on both, the result against truth/rig.yaml.
// Opt-in (rendering and detection take a minute): ROTOSCAN_CALIB_RENDERED=1.
TEST(CalibrateCommandTest, CalibrationObjectBundlesAgainstTruth) {
  if (std::getenv("ROTOSCAN_CALIB_RENDERED") == nullptr) GTEST_SKIP() << "set ROTOSCAN_CALIB_RENDERED=1";
  ScratchDir dir;
  std::vector<std::string> calibrate = {"calibrate"};
  for (const char* scene : {"calibration-object.json", "calibration-object-2.json"}) {
    const std::string out = (dir / scene).string() + ".bundle";
    const CliRun r = Call({"simulate", std::string(ROTOSCAN_SOURCE_DIR) + "/data/scenes/" + scene, "--kind",
                           "calib-object", "--steps", "9", "--out", out});
    ASSERT_EQ(r.code, kExitOk) << r.err;
    calibrate.push_back(out);
  }
  calibrate.insert(calibrate.end(), {"--out", (dir / "calib.yaml").string()});
  const CliRun r = Call(calibrate);
  std::printf("%s%s", r.out.c_str(), r.err.c_str());
  ASSERT_TRUE(std::filesystem::exists(dir / "calib.yaml")) << r.err;
  EXPECT_THAT(r.out, HasSubstr("2 placements"));
  cv::FileStorage fs((dir / "calib.yaml").string(), cv::FileStorage::READ);
  cv::Mat k;
  fs["K"] >> k;
  cv::FileStorage truth((dir / "calibration-object-2.json.bundle" / "truth" / "rig.yaml").string(),
                        cv::FileStorage::READ);
  cv::Mat k_true;
  truth["K"] >> k_true;
  EXPECT_NEAR(k.at<double>(0, 0), k_true.at<double>(0, 0), 0.001 * k_true.at<double>(0, 0));
  EXPECT_LT(static_cast<double>(fs["rms_px"]), 0.1);
}

}  // namespace
}  // namespace rotoscan::cli
