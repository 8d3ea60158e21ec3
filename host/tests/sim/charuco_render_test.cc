// The virtual scanner's ChArUco board (sim/scene.h "charuco"), rendered and detected (calib/charuco.h)
// against its truth: the projected corners of BoardCornersInTarget, by ChArUco id.
#include <algorithm>
#include <cmath>
#include <string>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "rotoscan/calib/camera_calibration.h"
#include "rotoscan/calib/charuco.h"
#include "rotoscan/sim/renderer.h"
#include "rotoscan/sim/scene.h"
#include "testing/testing.h"

namespace rotoscan::sim {
namespace {

using rotoscan::testing::DataPath;

// 640 x 480, 20° field of view (fx = 1815 px: a square of the board is ~44 px at 330 mm), noise free, a
// lens-like blur (unblurred box-filtered edges give cornerSubPix a phase bias, see sim_test.cc).
Scene BoardScene(const std::string& board_json, double ambient = 0.3) {
  const std::string text = R"({"camera": {"width": 640, "height": 480, "hfov_deg": 20, "noise": false,
      "blur_sigma_px": 1.5, "bit_depth": 8}, "light": {"ambient": )" +
                           std::to_string(ambient) + R"(}, "objects": [)" + board_json + "]}";
  auto scene = ParseScene(text, DataPath("."), "test scene");
  EXPECT_TRUE(scene.ok()) << scene.status().ToString();
  return *scene;
}

constexpr const char* kCharuco =
    R"({"type": "charuco", "cols": 8, "rows": 6, "square_mm": 8, "marker_mm": 6, "dictionary": "DICT_5X5_100"})";
// A plain checkerboard with the same inner corners.
constexpr const char* kChecker = R"({"type": "checkerboard", "cols": 7, "rows": 5, "square_mm": 8})";

const calib::CharucoBoard kBoard{8, 6, 8.0, 6.0, "DICT_5X5_100"};

const Eigen::Isometry3d kCamFromTarget = Eigen::Translation3d(-24, -16, 330) *
                                         Eigen::AngleAxisd(0.25, Eigen::Vector3d::UnitY()) *
                                         Eigen::AngleAxisd(-0.2, Eigen::Vector3d::UnitX());

// Places object 0 (the board) at kCamFromTarget, adds `extra` (objects placed in the camera frame).
cv::Mat Render(Scene scene, const std::vector<std::pair<ObjectSpec, Eigen::Isometry3d>>& extra = {}) {
  scene.sensor.supersampling = 1;  // the patterns are box-filtered analytically over the pixel
  const Eigen::Isometry3d table_from_cam = scene.rig.CamFromTable().inverse();
  scene.objects[0].has_pose = true;
  scene.objects[0].table_from_object = table_from_cam * kCamFromTarget;
  for (const auto& [spec, cam_from_object] : extra) {
    scene.objects.push_back(spec);
    scene.objects.back().has_pose = true;
    scene.objects.back().table_from_object = table_from_cam * cam_from_object;
  }
  auto renderer = Renderer::Create(scene);
  EXPECT_TRUE(renderer.ok()) << renderer.status().ToString();
  if (!renderer.ok()) return cv::Mat();
  return (*renderer)->RenderStep(0.0, 1, {false, false, false, true}).frames[3];
}

ObjectSpec Occluder(double width_mm, double height_mm) {
  ObjectSpec o;
  o.type = ObjectType::kPlane;
  o.size_mm = Eigen::Vector3d(width_mm, height_mm, 0.0);
  o.color = Eigen::Vector3d(0.5, 0.5, 0.5);
  return o;
}

// Largest distance of a detected corner from its id's projected truth.
double WorstError(const Scene& scene, const calib::CharucoDetection& d) {
  const std::vector<Eigen::Vector3d> truth = BoardCornersInTarget(scene.objects[0]);
  double worst = 0.0;
  for (std::size_t i = 0; i < d.ids.size(); ++i) {
    const Eigen::Vector2d p = scene.rig.camera.Project(kCamFromTarget * truth.at(d.ids[i]));
    worst = std::max(worst, (d.pixels[i] - p).norm());
  }
  return worst;
}

TEST(CharucoSceneTest, ReadsSquaresAsACheckerboardWithMarkers) {
  const Scene scene = BoardScene(kCharuco);
  const ObjectSpec& o = scene.objects[0];
  EXPECT_EQ(o.type, ObjectType::kCheckerboard);
  EXPECT_EQ(o.cols, 7);  // inner corners
  EXPECT_EQ(o.rows, 5);
  EXPECT_DOUBLE_EQ(o.marker_mm, 6.0);
  EXPECT_EQ(o.dictionary, "DICT_5X5_100");
  // The truth is the detector's board frame, id by id.
  const std::vector<Eigen::Vector3d> truth = BoardCornersInTarget(o);
  ASSERT_EQ(static_cast<int>(truth.size()), kBoard.CornerCount());
  for (int id = 0; id < kBoard.CornerCount(); ++id) EXPECT_EQ(truth[id], kBoard.CornerInTarget(id)) << id;
}

TEST(CharucoSceneTest, BadBoardsNameTheField) {
  const std::string head = R"({"objects": [{"type": "charuco", )";
  for (const auto& [body, expected] : std::vector<std::pair<std::string, std::string>>{
           {R"("square_mm": 8, "marker_mm": 8})", "marker size"},
           {R"("dictionary": "DICT_9X9_1"})", "unknown ArUco dictionary"},
           {R"("cols": 12, "rows": 10, "dictionary": "4x4_50"})", "needs 60 markers"},
           {R"("cols": 2})", "objects[0]"}}) {
    auto scene = ParseScene(head + body + "]}", DataPath("."), "s.json");
    ASSERT_FALSE(scene.ok()) << body;
    EXPECT_NE(scene.status().message().find(expected), std::string::npos) << scene.status().message();
    EXPECT_NE(scene.status().message().find("objects[0]"), std::string::npos) << scene.status().message();
  }
  auto plain = ParseScene(R"({"objects": [{"type": "checkerboard", "marker_mm": 5}]})", DataPath("."), "s");
  EXPECT_FALSE(plain.ok());
}

TEST(CharucoRenderTest, CornersFoundWhereProjected) {
  const Scene scene = BoardScene(kCharuco);
  const cv::Mat image = Render(scene);
  ASSERT_FALSE(image.empty());
  auto found = calib::DetectCharuco(image, kBoard);
  ASSERT_TRUE(found.ok()) << found.status().ToString();
  EXPECT_EQ(static_cast<int>(found->ids.size()), kBoard.CornerCount());
  EXPECT_EQ(found->markers, kBoard.MarkerCount());
  EXPECT_LT(WorstError(scene, *found), 0.05);
  std::printf("noise-free: %zu corners, worst %.4f px\n", found->ids.size(), WorstError(scene, *found));
}

// A third of the board hidden by an object in front of it, or in the shadow of one (the lamp blocked,
// ambient light only): the checkerboard detector needs the whole board and fails; the ChArUco corners
// that are seen are still found, each with its id.
enum class Obstruction { kHidden, kShadowed };

class CharucoObstructedTest : public ::testing::TestWithParam<Obstruction> {};

TEST_P(CharucoObstructedTest, VisibleCornersKeepTheirIds) {
  const bool hidden = GetParam() == Obstruction::kHidden;
  const double ambient = hidden ? 0.3 : 0.03;
  const Scene charuco = BoardScene(kCharuco, ambient);
  const Scene checker = BoardScene(kChecker, ambient);
  // The left third of the board (target x in [-8, 13.3] mm of its [-8, 56]).
  const Eigen::Vector3d left_third = kCamFromTarget * Eigen::Vector3d(2.7, 16, 0);
  Eigen::Isometry3d cam_from_occluder = Eigen::Isometry3d::Identity();
  ObjectSpec occluder = Occluder(22.0, 80.0);
  if (hidden) {
    // 100 mm in front of the board on the camera's line of sight, scaled by perspective.
    occluder = Occluder(22.0 * 230.0 / left_third.z(), 80.0);
    cam_from_occluder.translation() = left_third * (230.0 / left_third.z());
  } else {
    // 100 mm from the board towards the lamp, above the board (its lower edge shows at the top of the
    // image), its shadow on the board.
    cam_from_occluder.translation() = left_third + 100.0 * charuco.light_direction_in_cam;
  }
  // Unobstructed, both boards are found (so that the failure below is the obstruction's).
  ASSERT_TRUE(calib::DetectCheckerboard(Render(checker), {7, 5, 8.0}).ok());
  const cv::Mat checker_image = Render(checker, {{occluder, cam_from_occluder}});
  EXPECT_FALSE(calib::DetectCheckerboard(checker_image, {7, 5, 8.0}).ok());

  const cv::Mat image = Render(charuco, {{occluder, cam_from_occluder}});
  auto found = calib::DetectCharuco(image, kBoard);
  ASSERT_TRUE(found.ok()) << found.status().ToString();
  const int n = static_cast<int>(found->ids.size());
  std::printf("%s: %d corners, %d markers, worst %.4f px\n", hidden ? "hidden" : "shadowed", n,
              found->markers, WorstError(charuco, *found));
  EXPECT_GE(n, kBoard.CornerCount() / 2);       // the right two thirds: 20 of 35 corners
  EXPECT_LT(n, kBoard.CornerCount());           // and not the hidden ones
  EXPECT_LT(WorstError(charuco, *found), 0.1);  // every id where its corner is
}

INSTANTIATE_TEST_SUITE_P(HiddenOrShadowed, CharucoObstructedTest,
                         ::testing::Values(Obstruction::kHidden, Obstruction::kShadowed));

}  // namespace
}  // namespace rotoscan::sim
