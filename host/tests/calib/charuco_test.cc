// ChArUco boards (calib/charuco.h): parsing, the drawn board, detection on a known image, and camera
// calibration from a virtual-scanner bundle of ChArUco poses, also through `rotoscan calibrate camera`.
#include <cmath>
#include <filesystem>
#include <sstream>
#include <string>
#include <tuple>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core/persistence.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "command.h"
#include "rotoscan/calib/charuco.h"
#include "rotoscan/sim/scene.h"
#include "rotoscan/sim/simulate.h"
#include "testing/testing.h"

namespace rotoscan::calib {
namespace {

using rotoscan::testing::DataPath;
using rotoscan::testing::ScratchDir;
using ::testing::HasSubstr;

const CharucoBoard kBoard{8, 6, 8.0, 6.0, "DICT_5X5_100"};
const CharucoBoard kBigBoard{9, 7, 9.0, 6.75, "DICT_5X5_100"};

TEST(CharucoBoardTest, ParsesBoards) {
  auto board = ParseCharucoBoard("8x6", 8.0, 6.0, "5x5_100");
  ASSERT_TRUE(board.ok()) << board.status().ToString();
  EXPECT_EQ(board->squares_x, 8);
  EXPECT_EQ(board->squares_y, 6);
  EXPECT_EQ(board->dictionary, "DICT_5X5_100");
  EXPECT_EQ(board->CornerCount(), 35);
  EXPECT_EQ(board->MarkerCount(), 24);
  EXPECT_EQ(board->CornerInTarget(0), Eigen::Vector3d(0, 0, 0));
  EXPECT_EQ(board->CornerInTarget(8), Eigen::Vector3d(8, 8, 0));  // id 8: column 1 of row 1
  EXPECT_EQ(board->CornersInTarget().size(), 35u);
  EXPECT_THROW(board->CornerInTarget(35), PreconditionError);
  for (const auto& [squares, square, marker, dictionary, expected] :
       std::vector<std::tuple<std::string, double, double, std::string, std::string>>{
           {"8by6", 8, 6, "DICT_5X5_100", "COLSxROWS"},
           {"2x6", 8, 6, "DICT_5X5_100", "3..100 squares"},
           {"8x6", 0, 6, "DICT_5X5_100", "square size"},
           {"8x6", 8, 8, "DICT_5X5_100", "marker size"},
           {"8x6", 8, 6, "DICT_5X5_7", "unknown ArUco dictionary"},
           {"12x10", 8, 6, "DICT_4X4_50", "needs 60 markers"}}) {
    auto bad = ParseCharucoBoard(squares, square, marker, dictionary);
    ASSERT_FALSE(bad.ok()) << squares;
    EXPECT_EQ(bad.status().code(), StatusCode::kInvalidArgument);
    EXPECT_THAT(bad.status().message(), HasSubstr(expected));
  }
}

TEST(CharucoBoardTest, DrawsTheBoardOnWholeTexels) {
  // 6 mm markers of 7 cells in 8 mm squares: 56 texels per square gives 6-texel cells and 7-texel margins.
  EXPECT_EQ(kBoard.CrispPixelsPerSquare(8, 400), 56);
  const cv::Mat image = kBoard.Draw(56);
  ASSERT_EQ(image.type(), CV_8UC1);
  ASSERT_EQ(image.cols, 8 * 56);
  ASSERT_EQ(image.rows, 6 * 56);
  // Square (0, 0) is black, (1, 0) white around its marker; the edge between them on a texel boundary.
  EXPECT_EQ(image.at<uchar>(28, 55), 0);
  EXPECT_EQ(image.at<uchar>(28, 56), 255);
  EXPECT_EQ(image.at<uchar>(55, 28), 0);
  EXPECT_EQ(image.at<uchar>(56, 28), 255);
  EXPECT_EQ(image.at<uchar>(3, 56 + 6), 255);  // the white margin around marker 0 (7 texels) ...
  EXPECT_EQ(image.at<uchar>(7, 56 + 7), 0);    // ... then its black border
}

// The drawn board, blurred a little, on a white margin: every corner where the drawing puts it.
TEST(CharucoDetectTest, FindsEveryCornerOfTheDrawnBoard) {
  constexpr int kPps = 56, kMargin = 40;
  cv::Mat image;
  cv::copyMakeBorder(kBoard.Draw(kPps), image, kMargin, kMargin, kMargin, kMargin, cv::BORDER_CONSTANT, 255);
  cv::GaussianBlur(image, image, cv::Size(0, 0), 1.5);
  auto found = DetectCharuco(image, kBoard);
  ASSERT_TRUE(found.ok()) << found.status().ToString();
  ASSERT_EQ(found->ids.size(), 35u);
  EXPECT_EQ(found->markers, 24);
  for (std::size_t i = 0; i < found->ids.size(); ++i) {
    const int id = found->ids[i];
    EXPECT_EQ(id, static_cast<int>(i));  // ascending
    // Texel k covers [k - 0.5, k + 0.5] in pixel-centre coordinates: the corner between squares is at
    // (x + 1) * pps - 0.5.
    const Eigen::Vector2d truth((id % 7 + 1) * kPps - 0.5 + kMargin, (id / 7 + 1) * kPps - 0.5 + kMargin);
    EXPECT_LT((found->pixels[i] - truth).norm(), 0.05) << "id " << id;
    EXPECT_EQ(found->corners_in_target[i], kBoard.CornerInTarget(id));
  }
  // The same image in BGR.
  cv::Mat bgr;
  cv::cvtColor(image, bgr, cv::COLOR_GRAY2BGR);
  EXPECT_TRUE(DetectCharuco(bgr, kBoard).ok());
  // Another dictionary's board is not this one.
  EXPECT_FALSE(DetectCharuco(image, {8, 6, 8.0, 6.0, "DICT_6X6_50"}).ok());
}

TEST(CharucoDetectTest, BadInput) {
  EXPECT_EQ(DetectCharuco(cv::Mat(), kBoard).status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(DetectCharuco(cv::Mat(100, 100, CV_16UC1, cv::Scalar(0)), kBoard).status().code(),
            StatusCode::kInvalidArgument);
  EXPECT_EQ(DetectCharuco(cv::Mat(100, 100, CV_8UC1, cv::Scalar(0)), {8, 6, 8.0, 9.0}).status().code(),
            StatusCode::kInvalidArgument);
  const Status blank = DetectCharuco(cv::Mat(200, 300, CV_8UC1, cv::Scalar(255)), kBoard).status();
  EXPECT_EQ(blank.code(), StatusCode::kNotFound);
  EXPECT_THAT(blank.message(), HasSubstr("0 corners found"));
}

// Eight hand-held ChArUco poses rendered by `rotoscan simulate --kind checkerboard` on a 960 x 720 camera
// with the 20° lens. The focal length of so long a lens is weakly determined (std ~0.05 % here; a 640 x 480
// camera or the 8 x 6 board of 8 mm give ~0.09 %): a board of 9 x 7 squares of 9 mm fills more of the view.
class CharucoCalibrationTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new ScratchDir();
    auto scene = sim::ParseScene(R"({"camera": {"width": 960, "height": 720, "hfov_deg": 20},
        "objects": [{"type": "charuco", "cols": 9, "rows": 7, "square_mm": 9, "marker_mm": 6.75}]})",
                                 DataPath("."), "test scene");
    ASSERT_TRUE(scene.ok()) << scene.status().ToString();
    truth_ = scene->rig.camera;
    sim::SimulateOptions options;
    options.out = dir_->path() / "bundle";
    options.kind = sim::SimulateKind::kCheckerboard;
    options.steps = 8;
    options.threads = 2;
    const Status status = sim::Simulate(*scene, options, nullptr);
    ASSERT_TRUE(status.ok()) << status.ToString();
  }
  static void TearDownTestSuite() {
    delete dir_;
    dir_ = nullptr;
  }
  static std::filesystem::path Frames() { return dir_->path() / "bundle" / "frames"; }

  static ScratchDir* dir_;
  static geometry::CameraModel truth_;
};
ScratchDir* CharucoCalibrationTest::dir_ = nullptr;
geometry::CameraModel CharucoCalibrationTest::truth_;

TEST_F(CharucoCalibrationTest, RecoversTheFocalLength) {
  CharucoCalibrationOptions options;
  options.board = kBigBoard;
  auto result = CalibrateCameraFromCharucoDirectory(Frames(), options);
  ASSERT_TRUE(result.ok()) << result.status().ToString();
  EXPECT_EQ(result->views.size(), 8u);
  EXPECT_NEAR(result->camera.fx, truth_.fx, 0.001 * truth_.fx);
  EXPECT_NEAR(result->camera.fy, truth_.fy, 0.001 * truth_.fy);
  EXPECT_NEAR(result->camera.cx, truth_.cx, 2.0);
  EXPECT_NEAR(result->camera.cy, truth_.cy, 2.0);
  EXPECT_LT(result->rms_px, 0.2);
  std::printf("fx %.3f (truth %.3f, %+.4f %%), rms %.3f px\n", result->camera.fx, truth_.fx,
              100.0 * (result->camera.fx / truth_.fx - 1.0), result->rms_px);
  // Too few views is an error saying what to capture.
  options.min_views = 9;
  auto few = CalibrateCameraFromCharucoDirectory(Frames(), options);
  ASSERT_FALSE(few.ok());
  EXPECT_THAT(few.status().message(), HasSubstr("found in only 8 of 8 images"));
}

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
  const int code = cli::Main(static_cast<int>(argv.size()), argv.data(), out, err);
  return {code, out.str(), err.str()};
}

TEST_F(CharucoCalibrationTest, CalibrateCameraCommandWritesCameraYaml) {
  ScratchDir out;
  const CliRun r = Call({"calibrate", "camera", "--images", Frames().string(), "--charuco", "9x7", "--square",
                         "9", "--marker", "6.75", "--out", (out / "camera.yaml").string()});
  ASSERT_EQ(r.code, cli::kExitOk) << r.err;
  EXPECT_THAT(r.out, HasSubstr("from 8 views"));
  cv::FileStorage fs((out / "camera.yaml").string(), cv::FileStorage::READ);
  ASSERT_TRUE(fs.isOpened());
  cv::Mat k;
  fs["K"] >> k;
  EXPECT_NEAR(k.at<double>(0, 0), truth_.fx, 0.001 * truth_.fx);
}

TEST(CharucoCommandTest, BadInputSaysWhatToCapture) {
  ScratchDir dir;
  // Images without the board.
  for (int i = 0; i < 3; ++i) {
    cv::imwrite((dir / ("blank" + std::to_string(i) + ".png")).string(),
                cv::Mat(120, 160, CV_8UC1, cv::Scalar(40 * i)));
  }
  const std::string yaml = (dir / "camera.yaml").string();
  CliRun r = Call({"calibrate", "camera", "--images", dir.path().string(), "--charuco", "8x6", "--square",
                   "8", "--marker", "6", "--out", yaml});
  EXPECT_EQ(r.code, cli::kExitFailure);
  EXPECT_THAT(r.err, HasSubstr("not found in any of the 3 images"));
  EXPECT_THAT(r.err, HasSubstr("capture at least 6 views"));
  EXPECT_FALSE(std::filesystem::exists(yaml));
  // --marker missing, a bad dictionary, no target at all, both targets.
  r = Call({"calibrate", "camera", "--images", dir.path().string(), "--charuco", "8x6", "--square", "8"});
  EXPECT_EQ(r.code, cli::kExitFailure);
  EXPECT_THAT(r.err, HasSubstr("--marker"));
  r = Call({"calibrate", "camera", "--images", dir.path().string(), "--charuco", "8x6", "--square", "8",
            "--marker", "6", "--dictionary", "DICT_3X3_1"});
  EXPECT_EQ(r.code, cli::kExitFailure);
  EXPECT_THAT(r.err, HasSubstr("unknown ArUco dictionary"));
  r = Call({"calibrate", "camera", "--images", dir.path().string(), "--square", "8"});
  EXPECT_EQ(r.code, cli::kExitFailure);
  EXPECT_THAT(r.err, HasSubstr("--pattern"));
  r = Call({"calibrate", "camera", "--images", dir.path().string(), "--pattern", "9x6", "--charuco", "8x6",
            "--square", "8", "--marker", "6"});
  EXPECT_EQ(r.code, cli::kExitUsage);
  EXPECT_FALSE(std::filesystem::exists(yaml));
}

}  // namespace
}  // namespace rotoscan::calib
