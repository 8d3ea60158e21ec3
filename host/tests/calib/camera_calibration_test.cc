#include "rotoscan/calib/camera_calibration.h"

#include <fstream>

#include <gtest/gtest.h>
#include <opencv2/core/persistence.hpp>
#include <opencv2/imgcodecs.hpp>

#include "rotoscan/core/file.h"
#include "testing/testing.h"

namespace rotoscan::calib {
namespace {

using rotoscan::testing::DataPath;
using rotoscan::testing::ScratchDir;
using ::testing::HasSubstr;

CameraCalibrationOptions OpenCvLeftOptions() {
  CameraCalibrationOptions options;
  options.pattern = {9, 6, 25.0};
  return options;
}

TEST(CameraCalibrationTest, MatchesPublishedOpenCvLeftIntrinsics) {
  // data/calib/opencv-left: OpenCV's 13 sample views of a 9x6 board with 25 mm squares, and the intrinsics
  // published with them. Required: focal lengths within 0.5 %, principal point within 2 px.
  cv::FileStorage published(DataPath("calib/opencv-left/left_intrinsics.yml").string(),
                            cv::FileStorage::READ);
  ASSERT_TRUE(published.isOpened());
  cv::Mat k;
  published["camera_matrix"] >> k;
  const auto result = CalibrateCameraFromDirectory(DataPath("calib/opencv-left"), OpenCvLeftOptions());
  ASSERT_TRUE(result.ok()) << result.status().ToString();
  const auto& camera = result->camera;
  EXPECT_EQ(camera.width, 640);
  EXPECT_EQ(camera.height, 480);
  EXPECT_EQ(result->views.size(), 13u);
  EXPECT_NEAR(camera.fx, k.at<double>(0, 0), 0.005 * k.at<double>(0, 0));
  EXPECT_NEAR(camera.fy, k.at<double>(1, 1), 0.005 * k.at<double>(1, 1));
  EXPECT_NEAR(camera.cx, k.at<double>(0, 2), 2.0);
  EXPECT_NEAR(camera.cy, k.at<double>(1, 2), 2.0);
  EXPECT_LT(result->rms_px, 0.5);
  EXPECT_EQ(result->per_view_rms_px.size(), 13u);
  EXPECT_GT(result->intrinsics_std[0], 0.0);

  ScratchDir dir;
  ASSERT_TRUE(WriteCameraYaml(dir / "camera.yaml", *result).ok());
  cv::FileStorage back((dir / "camera.yaml").string(), cv::FileStorage::READ);
  ASSERT_TRUE(back.isOpened());
  EXPECT_EQ(static_cast<int>(back["image_width"]), 640);
  cv::Mat k_back;
  back["K"] >> k_back;
  EXPECT_DOUBLE_EQ(k_back.at<double>(0, 0), camera.fx);
  // camera.yaml's own reader gives the model back.
  const Result<geometry::CameraModel> read = ReadCameraYaml(dir / "camera.yaml");
  ASSERT_TRUE(read.ok()) << read.status().ToString();
  EXPECT_EQ(read->width, 640);
  EXPECT_DOUBLE_EQ(read->fx, camera.fx);
  EXPECT_DOUBLE_EQ(read->cy, camera.cy);
  EXPECT_EQ(read->distortion, camera.distortion);
}

// The 31 bytes that made OpenCV 4.6's YAML parser loop forever (geometry/yaml.h): camera.yaml's reader
// refuses them at once, from text and from a file, as calib.yaml's does; a missing file is kNotFound.
TEST(CameraCalibrationTest, CameraYamlReaderRefusesTheBytesThatHangOpenCv) {
  const std::string hang("%YAML:1.0\n---AML:1.\n-\xec\n\n-\xec\n 21\n", 31);
  const Result<geometry::CameraModel> text = ParseCameraYaml(hang, "hang.yaml");
  EXPECT_EQ(text.status().code(), StatusCode::kCorruptData) << text.status().ToString();
  ScratchDir dir;
  ASSERT_TRUE(WriteFileAtomically(dir / "camera.yaml", hang).ok());
  const Result<geometry::CameraModel> file = ReadCameraYaml(dir / "camera.yaml");
  EXPECT_EQ(file.status().code(), StatusCode::kCorruptData) << file.status().ToString();
  EXPECT_NE(file.status().message().find("camera.yaml"), std::string::npos);
  EXPECT_EQ(ReadCameraYaml(dir / "none.yaml").status().code(), StatusCode::kNotFound);
  // Keys missing: a clear error naming them.
  const Result<geometry::CameraModel> empty = ParseCameraYaml("%YAML:1.0\nrms_px: 0.3\n", "empty.yaml");
  EXPECT_EQ(empty.status().code(), StatusCode::kInvalidArgument) << empty.status().ToString();
}

TEST(CameraCalibrationTest, ParsesPattern) {
  const auto p = ParsePattern("9x6", 25);
  ASSERT_TRUE(p.ok());
  EXPECT_EQ(p->cols, 9);
  EXPECT_EQ(p->rows, 6);
  EXPECT_EQ(p->CornersInTarget().size(), 54u);
  EXPECT_DOUBLE_EQ(p->CornersInTarget()[10].x(), 25.0);
  EXPECT_DOUBLE_EQ(p->CornersInTarget()[10].y(), 25.0);
  EXPECT_FALSE(ParsePattern("9by6", 25).ok());
  EXPECT_FALSE(ParsePattern("9x6x", 25).ok());
  EXPECT_FALSE(ParsePattern("6x6", 25).ok());
  EXPECT_FALSE(ParsePattern("9x6", 0).ok());
}

TEST(CameraCalibrationTest, EmptyOrMissingDirectory) {
  ScratchDir dir;
  auto result = CalibrateCameraFromDirectory(dir.path(), OpenCvLeftOptions());
  EXPECT_EQ(result.status().code(), StatusCode::kNotFound);
  EXPECT_THAT(result.status().message(), HasSubstr("no images"));
  result = CalibrateCameraFromDirectory(dir / "missing", OpenCvLeftOptions());
  EXPECT_THAT(result.status().message(), HasSubstr("does not exist"));
}

TEST(CameraCalibrationTest, UnreadableImages) {
  ScratchDir dir;
  for (const char* name : {"a.png", "b.jpg"}) std::ofstream(dir / name) << "not an image";
  const auto result = CalibrateCameraFromDirectory(dir.path(), OpenCvLeftOptions());
  EXPECT_EQ(result.status().code(), StatusCode::kCorruptData);
  EXPECT_THAT(result.status().message(), HasSubstr("could be read"));
}

TEST(CameraCalibrationTest, PatternNeverFoundOrTooFewViews) {
  ScratchDir dir;
  const cv::Mat blank(120, 160, CV_8UC1, cv::Scalar(128));
  for (int i = 0; i < 4; ++i) cv::imwrite((dir / ("blank" + std::to_string(i) + ".png")).string(), blank);
  auto result = CalibrateCameraFromDirectory(dir.path(), OpenCvLeftOptions());
  EXPECT_THAT(result.status().message(), HasSubstr("target found in only 0 of 4 images"));

  ScratchDir few;
  for (const char* name : {"left01.jpg", "left02.jpg", "left03.jpg"}) {
    std::filesystem::copy_file(DataPath("calib/opencv-left") / name, few / name);
  }
  result = CalibrateCameraFromDirectory(few.path(), OpenCvLeftOptions());
  EXPECT_EQ(result.status().code(), StatusCode::kInvalidArgument);
  EXPECT_THAT(result.status().message(), HasSubstr("target found in only 3 of 3 images"));
  EXPECT_THAT(result.status().message(), HasSubstr("need >= 6"));
}

}  // namespace
}  // namespace rotoscan::calib
