#include <atomic>
#include <cmath>
#include <filesystem>
#include <map>
#include <set>
#include <utility>

#include <gtest/gtest.h>
#include <Eigen/Dense>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "rotoscan/bundle/bundle.h"
#include "rotoscan/bundle/truth.h"
#include "rotoscan/geometry/rigid.h"
#include "rotoscan/sim/renderer.h"
#include "rotoscan/sim/scene.h"
#include "rotoscan/sim/simulate.h"
#include "testing/testing.h"

namespace rotoscan::sim {
namespace {

using bundle::LaserState;
using geometry::LaserId;
using rotoscan::testing::DataPath;
using rotoscan::testing::ScratchDir;

// A small noise-free camera (the default rig scaled down) and the given objects.
Scene SmallScene(const std::string& objects_json, int width = 160, int height = 120, bool noise = false) {
  const std::string text = R"({"camera": {"width": )" + std::to_string(width) + R"(, "height": )" +
                           std::to_string(height) + R"(, "hfov_deg": 20, "noise": )" +
                           (noise ? "true" : "false") +
                           R"(, "blur_sigma_px": 0, "bit_depth": 12},
      "lasers": {"left": {"sigma_mm": 1.0, "speckle_contrast": 0}, "right": {"sigma_mm": 1.0, "speckle_contrast": 0}},
      "objects": )" + objects_json +
                           "}";
  auto scene = ParseScene(text, DataPath("."), "test scene");
  EXPECT_TRUE(scene.ok()) << scene.status().ToString();
  return *scene;
}

TEST(SceneTest, DefaultsMatchThePaperRig) {
  auto scene = SceneDefaults("machine_vision");
  ASSERT_TRUE(scene.ok());
  const geometry::Rig& rig = scene->rig;
  EXPECT_EQ(rig.camera.width, 1288);
  EXPECT_EQ(rig.camera.height, 964);
  EXPECT_NEAR(2 * geometry::RadToDeg(std::atan(644.0 / rig.camera.fx)), 20.0, 1e-9);
  EXPECT_NEAR(geometry::RadToDeg(rig.step_angle_rad), 0.3, 1e-12);
  EXPECT_TRUE(rig.Validate().ok());
  // Both laser planes contain the axis and their origins; 30° from the optical axis at the centre.
  for (int k = 0; k < 2; ++k) {
    EXPECT_NEAR(rig.laser_plane[k].SignedDistance(rig.axis_point_in_cam), 0.0, 1e-9);
    EXPECT_NEAR(rig.laser_plane[k].SignedDistance(scene->laser[k].origin_in_cam), 0.0, 1e-9);
    EXPECT_NEAR(rig.laser_plane[k].normal.dot(rig.axis_direction_in_cam), 0.0, 1e-12);
  }
  EXPECT_LT(scene->laser[0].origin_in_cam.x(), 0);
  EXPECT_GT(scene->laser[1].origin_in_cam.x(), 0);
  EXPECT_TRUE(SceneDefaults("webcam").ok());
  EXPECT_EQ(SceneDefaults("phone").status().code(), StatusCode::kInvalidArgument);
}

TEST(SceneTest, BadSceneFilesNameTheField) {
  const std::pair<std::string, std::string> cases[] = {
      {R"({"camera": {"width": -5}})", "camera.width"},
      {R"({"camra": {}})", "camra"},
      {R"({"camera": {"bit_depth": 10}})", "camera.bit_depth"},
      {R"({"camera": {"distortion": [0, 0, 0]}})", "camera.distortion"},
      {R"({"lasers": {"left": {"sigma_mm": 0}}})", "lasers.left.sigma_mm"},
      {R"({"lasers": {"right": {"power": "high"}}})", "lasers.right.power"},
      {R"({"table": {"axis_direction": [0, 0, 0]}})", "table.axis_direction"},
      {R"({"objects": [{"type": "cube"}]})", "objects[0].type"},
      {R"({"objects": [{"type": "sphere"}, {"radius_mm": 3}]})", "objects[1].type"},
      {R"({"objects": [{"type": "sphere", "color": [1, 2, 0]}]})", "objects[0].color"},
      {R"({"objects": [{"type": "mesh"}]})", "objects[0].file"},
      {R"({"preset": "phone"})", "preset"},
      {R"({"steps": 0})", "steps"},
      {R"({"camera": {"supersampling": 0}})", "camera.supersampling"},
      {R"({"camera": {"noise": 1}})", "camera.noise"},
      {R"({"camera": {"color_matrix": [1, 0, 0]}})", "camera.color_matrix"},
      {R"({"lasers": {"left": {"speckle_contrast": 2}}})", "lasers.left.speckle_contrast"},
      {R"({"lasers": {"right": {"normal": [0, 0, 0]}}})", "lasers.right.normal"},
      {R"({"light": {"direction": [0, 0]}})", "light.direction"},
      {R"({"table": {"step_deg": 0}})", "table.step_deg"},
      {R"({"objects": [{"type": "box", "size_mm": [1, 2]}]})", "objects[0].size_mm"},
      {R"({"objects": [{"type": "sphere", "segments": 2}]})", "objects[0].segments"},
      {R"({"objects": [{"type": "sphere", "radius_mm": 5, "position_mm": [0, 0, "a"]}]})", "objects[0].position_mm"},
      {R"({"camera": )", "JSON"},
  };
  for (const auto& [text, field] : cases) {
    auto scene = ParseScene(text, ".", "bad.json");
    ASSERT_FALSE(scene.ok()) << text;
    EXPECT_EQ(scene.status().code(), StatusCode::kInvalidArgument);
    EXPECT_NE(scene.status().message().find(field), std::string::npos) << scene.status().ToString();
    EXPECT_NE(scene.status().message().find("bad.json"), std::string::npos);
  }
  auto missing = ParseScene(R"({"objects": [{"type": "mesh", "file": "nothing.obj"}]})", ".", "s.json");
  ASSERT_TRUE(missing.ok());
  EXPECT_EQ(Renderer::Create(*missing).status().code(), StatusCode::kNotFound);
  EXPECT_EQ(LoadScene("/nonexistent/scene.json").status().code(), StatusCode::kNotFound);
}

// The line truth lies on the laser plane and on the surface, and projects to its (column, row).
TEST(LineTruthTest, AgreesWithPlaneIntersection) {
  const Scene scene =
      SmallScene(R"([{"type": "plane", "distance_mm": 290, "angle_deg": 20, "size_mm": [120, 100]}])");
  auto renderer = Renderer::Create(scene);
  ASSERT_TRUE(renderer.ok()) << renderer.status().ToString();
  // The object plane in the camera frame: z' = 0 of cam_from_object.
  const Eigen::Isometry3d cam_from_object =
      Eigen::Translation3d(0, 0, 290) * Eigen::AngleAxisd(geometry::DegToRad(20), Eigen::Vector3d::UnitY());
  const Eigen::Vector3d normal = cam_from_object.linear().col(2);
  const double offset = -normal.dot(cam_from_object.translation());
  for (LaserId id : {LaserId::kLeft, LaserId::kRight}) {
    const auto truth = (*renderer)->LineTruth(id, 0.0);
    ASSERT_GT(truth.size(), 60u);
    std::set<int> rows;
    for (const bundle::LinePoint& p : truth) {
      if (p.object != 1) continue;
      rows.insert(p.row);
      EXPECT_NEAR(scene.rig.laser(id).SignedDistance(p.point_in_cam), 0.0, 1e-3);
      EXPECT_NEAR(normal.dot(p.point_in_cam) + offset, 0.0, 1e-3);
      const Eigen::Vector2d pixel = scene.rig.camera.Project(p.point_in_cam);
      EXPECT_NEAR(pixel.x(), p.column, 0.01);
      EXPECT_NEAR(pixel.y(), p.row, 0.01);
      EXPECT_THAT(scene.rig.WorldFromCamAtAngle(0.0) * p.point_in_cam,
                  testing::EigenNear(p.point_in_world, 1e-6));
    }
    EXPECT_GT(rows.size(), 60u);  // the plane spans most rows
  }
}

// The line truth row by row against an independent construction: the 3D line where the laser plane meets
// the object plane, cut to the object's rectangle, and for each image row the point of that line whose
// distorted projection falls on the row (bisection on the line). Every such row is in the truth (nothing
// hides this plane from the camera or the lasers), with the same column (<= 0.01 px) and 3D point
// (<= 0.001 mm), and the truth has no other row on the object.
TEST(LineTruthTest, EveryRowMatchesTheAnalyticIntersection) {
  const Scene scene =
      SmallScene(R"([{"type": "plane", "distance_mm": 290, "angle_deg": 20, "size_mm": [120, 100]}])");
  auto renderer = Renderer::Create(scene);
  ASSERT_TRUE(renderer.ok()) << renderer.status().ToString();
  const geometry::CameraModel& camera = scene.rig.camera;
  const Eigen::Isometry3d cam_from_object =
      Eigen::Translation3d(0, 0, 290) * Eigen::AngleAxisd(geometry::DegToRad(20), Eigen::Vector3d::UnitY());
  const Eigen::Vector3d object_normal = cam_from_object.linear().col(2);
  for (LaserId id : {LaserId::kLeft, LaserId::kRight}) {
    const geometry::Plane& laser = scene.rig.laser(id);
    // The line point + t * direction on both planes (the point nearest the camera centre's projection).
    const Eigen::Vector3d direction = object_normal.cross(laser.normal).normalized();
    Eigen::Matrix3d a;
    a << object_normal.transpose(), laser.normal.transpose(), direction.transpose();
    const Eigen::Vector3d point = a.colPivHouseholderQr().solve(
        Eigen::Vector3d(object_normal.dot(cam_from_object.translation()), -laser.offset, 0.0));
    // The part inside the 120 x 100 mm rectangle: |x| <= 60 and |y| <= 50 in the object frame.
    double t0 = -1e9, t1 = 1e9;
    const Eigen::Vector3d p_obj = cam_from_object.inverse() * point;
    const Eigen::Vector3d d_obj = cam_from_object.linear().transpose() * direction;
    for (int axis = 0; axis < 2; ++axis) {
      const double half = axis == 0 ? 60.0 : 50.0;
      ASSERT_GT(std::abs(d_obj[axis]), 1e-9);
      double lo = (-half - p_obj[axis]) / d_obj[axis], hi = (half - p_obj[axis]) / d_obj[axis];
      if (lo > hi) std::swap(lo, hi);
      t0 = std::max(t0, lo);
      t1 = std::min(t1, hi);
    }
    ASSERT_LT(t0, t1);
    auto row_at = [&](double t) { return camera.Project(point + t * direction).y(); };
    const bool increasing = row_at(t1) > row_at(t0);
    std::map<int, Eigen::Vector3d> expected;  // row -> point in the camera frame
    const int first = std::max(0, static_cast<int>(std::ceil(std::min(row_at(t0), row_at(t1)))));
    const int last =
        std::min(camera.height - 1, static_cast<int>(std::floor(std::max(row_at(t0), row_at(t1)))));
    for (int row = first; row <= last; ++row) {
      double lo = t0, hi = t1;
      for (int it = 0; it < 100; ++it) {
        const double mid = 0.5 * (lo + hi);
        ((row_at(mid) < row) == increasing ? lo : hi) = mid;
      }
      const Eigen::Vector3d x = point + 0.5 * (lo + hi) * direction;
      const double column = camera.Project(x).x();
      if (column >= -0.5 && column <= camera.width - 0.5) expected[row] = x;
    }
    ASSERT_GT(expected.size(), 60u);
    std::map<int, bundle::LinePoint> truth;
    for (const bundle::LinePoint& p : (*renderer)->LineTruth(id, 0.0)) {
      if (p.object != 1) continue;
      EXPECT_TRUE(truth.emplace(p.row, p).second) << "two points on row " << p.row;
    }
    EXPECT_EQ(truth.size(), expected.size());
    for (const auto& [row, x] : expected) {
      const auto it = truth.find(row);
      ASSERT_NE(it, truth.end()) << "row " << row << " missing from the truth";
      EXPECT_NEAR(it->second.column, camera.Project(x).x(), 0.01) << "row " << row;
      EXPECT_LT((it->second.point_in_cam - x).norm(), 1e-3) << "row " << row;
    }
  }
}

// The rendered line (laser-on minus off, red channel) is centred on the true line.
TEST(LineTruthTest, RenderedLineCentreMatchesTruth) {
  const Scene scene =
      SmallScene(R"([{"type": "plane", "distance_mm": 300, "angle_deg": -15, "size_mm": [120, 100]}])");
  auto renderer = Renderer::Create(scene);
  ASSERT_TRUE(renderer.ok());
  const RenderedStep step = (*renderer)->RenderStep(0.0, 1);
  const auto truth = (*renderer)->LineTruth(LaserId::kRight, 0.0);
  cv::Mat on, off, diff;
  cv::extractChannel(step.frames[static_cast<int>(LaserState::kRight)], on, 2);
  cv::extractChannel(step.frames[static_cast<int>(LaserState::kOff)], off, 2);
  cv::subtract(on, off, diff, cv::noArray(), CV_64F);
  int checked = 0;
  double worst = 0;
  for (const bundle::LinePoint& p : truth) {
    if (p.object != 1 || p.column < 10 || p.column > scene.rig.camera.width - 10) continue;
    double sum = 0, moment = 0;
    const int c0 = static_cast<int>(std::round(p.column));
    for (int x = c0 - 6; x <= c0 + 6; ++x) {
      const double v = diff.at<double>(p.row, x);
      sum += v;
      moment += v * x;
    }
    ASSERT_GT(sum, 100.0) << "row " << p.row;
    worst = std::max(worst, std::abs(moment / sum - p.column));
    ++checked;
  }
  EXPECT_GT(checked, 60);
  EXPECT_LT(worst, 0.05);
}

TEST(RendererTest, CheckerboardCornersFoundWhereProjected) {
  Scene scene = SmallScene(R"([{"type": "checkerboard", "cols": 9, "rows": 6, "square_mm": 7}])", 640, 480);
  scene.sensor.supersampling = 1;  // the checker is box-filtered analytically over the pixel
  scene.sensor.bit_depth = 8;
  // cornerSubPix has a sub-pixel-phase bias of up to ~0.07 px on unblurred box-filtered edges (measured
  // here: the rendered edges themselves sit on the truth); a lens-like blur removes it.
  scene.sensor.blur_sigma_px = 1.5;
  const Eigen::Isometry3d cam_from_target = Eigen::Translation3d(-28, -17.5, 330) *
                                            Eigen::AngleAxisd(0.25, Eigen::Vector3d::UnitY()) *
                                            Eigen::AngleAxisd(-0.2, Eigen::Vector3d::UnitX());
  scene.objects[0].has_pose = true;
  scene.objects[0].table_from_object = scene.rig.CamFromTable().inverse() * cam_from_target;
  auto renderer = Renderer::Create(scene);
  ASSERT_TRUE(renderer.ok());
  const RenderedStep step = (*renderer)->RenderStep(0.0, 1, {false, false, false, true});
  cv::Mat gray;
  cv::cvtColor(step.frames[3], gray, cv::COLOR_BGR2GRAY);
  std::vector<cv::Point2f> corners;
  ASSERT_TRUE(cv::findChessboardCorners(gray, cv::Size(9, 6), corners));
  cv::cornerSubPix(gray, corners, cv::Size(5, 5), cv::Size(-1, -1),
                   cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 100, 1e-4));
  double worst = 0;
  for (int j = 0; j < 6; ++j) {
    for (int i = 0; i < 9; ++i) {
      const Eigen::Vector2d truth =
          scene.rig.camera.Project(cam_from_target * Eigen::Vector3d(7.0 * i, 7.0 * j, 0));
      double best = 1e9;  // OpenCV may order the corners either way round
      for (const cv::Point2f& c : corners)
        best = std::min(best, std::hypot(c.x - truth.x(), c.y - truth.y()));
      worst = std::max(worst, best);
    }
  }
  EXPECT_LT(worst, 0.05);
}

// Flat field: mean and variance follow DN = k e, var = k^2 (e + read^2) + 1/12 (quantisation).
TEST(SensorTest, FlatFieldNoiseMatchesShotAndReadNoise) {
  Scene scene = SmallScene("[]", 200, 200, true);
  scene.sensor.read_noise_e = 8.0;
  auto renderer = Renderer::Create(scene);
  ASSERT_TRUE(renderer.ok());
  const double k = scene.sensor.DnPerElectron();
  for (double electrons : {200.0, 3000.0}) {
    const cv::Mat flat(200, 200, CV_32FC3, cv::Scalar::all(electrons));
    const cv::Mat dn = (*renderer)->ApplySensor(flat, 42);
    ASSERT_EQ(dn.type(), CV_16UC3);
    cv::Scalar mean, stddev;
    cv::meanStdDev(dn.reshape(1), mean, stddev);
    const double expected_var = k * k * (electrons + 64.0) + 1.0 / 12.0;
    EXPECT_NEAR(mean[0], k * electrons, 0.02 * k * electrons + 0.1);
    EXPECT_NEAR(stddev[0] * stddev[0], expected_var, 0.04 * expected_var);  // 120k samples: ~0.4 % std error
  }
  // Saturation at the full well.
  const cv::Mat bright(8, 8, CV_32FC3, cv::Scalar::all(10 * scene.sensor.full_well_e));
  double lo = 0, hi = 0;
  cv::minMaxLoc((*renderer)->ApplySensor(bright, 1).reshape(1), &lo, &hi);
  EXPECT_EQ(lo, scene.sensor.MaxDn());
}

// The shape of the noise, not only its variance: the flat field's tail fractions are those of the model
// (DN = round(k e'), e' normal with mean e and variance e + read^2; the rounding is accounted for exactly),
// the standardised residuals have no skew and no excess kurtosis (480k samples: the tolerances are 5 to
// 7 standard errors), and the noise is a function of the seed.
TEST(SensorTest, FlatFieldNoiseIsGaussian) {
  Scene scene = SmallScene("[]", 200, 200, true);
  scene.sensor.read_noise_e = 8.0;
  auto renderer = Renderer::Create(scene);
  ASSERT_TRUE(renderer.ok());
  const double k = scene.sensor.DnPerElectron(), electrons = 3000.0;
  const double mean = k * electrons, sigma_before_rounding = k * std::sqrt(electrons + 64.0);
  const double sigma = std::sqrt(sigma_before_rounding * sigma_before_rounding + 1.0 / 12.0);  // 22.7 DN
  const cv::Mat flat(400, 400, CV_32FC3, cv::Scalar::all(electrons));
  const cv::Mat dn = (*renderer)->ApplySensor(flat, 7);
  cv::Mat d;
  dn.reshape(1).convertTo(d, CV_64F, 1.0, -mean);
  double beyond[4] = {}, m3 = 0, m4 = 0;
  for (auto it = d.begin<double>(); it != d.end<double>(); ++it) {
    for (int s = 1; s <= 3; ++s) beyond[s] += std::abs(*it) > s * sigma;
    const double z = *it / sigma;
    m3 += z * z * z;
    m4 += z * z * z * z;
  }
  const double n = static_cast<double>(d.total());
  auto normal_cdf = [](double x) { return 0.5 * std::erfc(-x / std::sqrt(2.0)); };
  for (int s = 1; s <= 3; ++s) {
    // DN codes beyond +-s sigma: from the highest code below and the lowest code above.
    const double below = std::ceil(mean - s * sigma) - 1, above = std::floor(mean + s * sigma) + 1;
    const double expected = normal_cdf((below + 0.5 - mean) / sigma_before_rounding) + 1.0 -
                            normal_cdf((above - 0.5 - mean) / sigma_before_rounding);
    EXPECT_NEAR(beyond[s] / n, expected, 5 * std::sqrt(expected * (1 - expected) / n) + 1e-4)
        << s << " sigma";
  }
  EXPECT_NEAR(m3 / n, 0.0, 0.025);
  EXPECT_NEAR(m4 / n, 3.0, 0.05);
  EXPECT_EQ(cv::norm((*renderer)->ApplySensor(flat, 7), dn, cv::NORM_INF), 0.0);
  EXPECT_GT(cv::norm((*renderer)->ApplySensor(flat, 8), dn, cv::NORM_INF), 0.0);
}

// Paper Fig. 2: each laser is shadowed by the box in its own region; the other laser lights it.
TEST(RendererTest, LasersShadowDifferentRegions) {
  const Scene with_box = SmallScene(R"([{"type": "box", "size_mm": [30, 30, 60]}])");
  const Scene empty = SmallScene("[]");
  auto boxed = Renderer::Create(with_box);
  auto bare = Renderer::Create(empty);
  ASSERT_TRUE(boxed.ok());
  ASSERT_TRUE(bare.ok());
  std::set<int> lost[2];
  for (int k = 0; k < 2; ++k) {
    std::set<int> table_rows;
    for (const auto& p : (*boxed)->LineTruth(static_cast<LaserId>(k), 0.0)) {
      if (p.object == 0) table_rows.insert(p.row);
    }
    for (const auto& p : (*bare)->LineTruth(static_cast<LaserId>(k), 0.0)) {
      if (!table_rows.count(p.row)) lost[k].insert(p.row);
    }
  }
  EXPECT_FALSE(lost[0].empty());
  EXPECT_FALSE(lost[1].empty());
  // The box's front faces are lit by each laser on a different face: left sees -x face, right +x face.
  const auto left = (*boxed)->LineTruth(LaserId::kLeft, geometry::DegToRad(30));
  const auto right = (*boxed)->LineTruth(LaserId::kRight, geometry::DegToRad(30));
  int left_on_box = 0, right_on_box = 0;
  for (const auto& p : left) left_on_box += p.object == 1;
  for (const auto& p : right) right_on_box += p.object == 1;
  EXPECT_GT(left_on_box, 10);
  EXPECT_GT(right_on_box, 10);
}

// The lamp of the natural image casts shadows: lit from the camera's right, a box darkens the table on
// its left, down to the ambient light alone, and switching "shadows" off removes exactly that.
TEST(RendererTest, LampCastsShadowsInTheNaturalImage) {
  Scene shadowed = SmallScene(R"([{"type": "box", "size_mm": [30, 30, 40]}])");
  shadowed.light_direction_in_cam = Eigen::Vector3d(1.0, -0.4, 0.0).normalized();  // from the right, above
  Scene unshadowed = shadowed;
  unshadowed.lamp_shadows = false;
  auto with = Renderer::Create(shadowed);
  auto without = Renderer::Create(unshadowed);
  ASSERT_TRUE(with.ok() && without.ok());
  const RenderedStep a = (*with)->RenderStep(0.0, 1), b = (*without)->RenderStep(0.0, 1);
  cv::Mat lit, dark, ambient;
  cv::cvtColor(b.frames[3], lit, cv::COLOR_BGR2GRAY);
  cv::cvtColor(a.frames[3], dark, cv::COLOR_BGR2GRAY);
  // The ambient term alone at natural exposure: the off frame (ambient, laser exposure) scaled.
  cv::cvtColor(a.frames[2], ambient, cv::COLOR_BGR2GRAY);
  const double exposure_ratio = shadowed.sensor.natural_exposure_us / shadowed.sensor.laser_exposure_us;
  lit.convertTo(lit, CV_64F);
  dark.convertTo(dark, CV_64F);
  ambient.convertTo(ambient, CV_64F, exposure_ratio);
  int in_shadow = 0, brighter = 0, at_ambient = 0;
  double shadow_x = 0, object_x = 0;
  int object_pixels = 0;
  for (int y = 0; y < lit.rows; ++y) {
    for (int x = 0; x < lit.cols; ++x) {
      const double l = lit.at<double>(y, x), d = dark.at<double>(y, x);
      if (d > l + 1.0) ++brighter;  // a shadow never brightens
      if (l - d > 20.0) {
        ++in_shadow;
        shadow_x += x;
        // 12-bit noise-free frames: within a few DN of the ambient-only level.
        if (std::abs(d - ambient.at<double>(y, x)) < 0.02 * l + 4.0) ++at_ambient;
      }
      if (l > 0.3 * 4095) {  // the bright (light grey) box
        object_x += x;
        ++object_pixels;
      }
    }
  }
  EXPECT_EQ(brighter, 0);
  ASSERT_GT(in_shadow, lit.total() / 100) << "no cast shadow";
  EXPECT_GT(at_ambient, in_shadow * 9 / 10);
  ASSERT_GT(object_pixels, 0);
  EXPECT_LT(shadow_x / in_shadow, object_x / object_pixels) << "the shadow falls away from the lamp";
}

TEST(RendererTest, SpotMeshWithTextureLoads) {
  Scene scene = SmallScene(R"([{"type": "mesh", "file": "meshes/spot/spot.obj",
                                "texture": "meshes/spot/spot_texture.png", "height_mm": 80}])");
  auto renderer = Renderer::Create(scene);
  ASSERT_TRUE(renderer.ok()) << renderer.status().ToString();
  const bundle::TruthMesh mesh = (*renderer)->ObjectMesh();
  EXPECT_EQ(mesh.faces.size(), 5856u);
  float lo = 1e9, hi = -1e9;
  for (const auto& v : mesh.vertices) lo = std::min(lo, v.z()), hi = std::max(hi, v.z());
  EXPECT_NEAR(lo, 0.0, 1e-3);
  EXPECT_NEAR(hi, 80.0, 1e-3);
  const RenderedStep step = (*renderer)->RenderStep(0.0, 3, {false, false, false, true});
  // The texture is not uniform: the natural image varies in color over the cow.
  cv::Scalar mean, stddev;
  cv::meanStdDev(step.frames[3], mean, stddev);
  EXPECT_GT(stddev[0], 50.0);
}

// DESIGN.md "What real laser frames look like": the webcam preset saturates the red line and its color
// matrix makes green drop under it. The sensor's statistic, without MJPEG (at the preset's quality 85 the
// JPEG round trip leaves the top of this narrow line at 255 in only ~1 row in 10: issue 15, open).
TEST(RendererTest, WebcamPresetSaturatesAndDropsGreen) {
  auto scene = ParseScene(R"({"preset": "webcam", "camera": {"width": 160, "height": 120, "hfov_deg": 20,
      "noise": false, "jpeg_quality": 0}, "objects": [{"type": "plane", "distance_mm": 300, "size_mm": [120, 100]}]})",
                          ".", "webcam scene");
  ASSERT_TRUE(scene.ok()) << scene.status().ToString();
  auto renderer = Renderer::Create(*scene);
  ASSERT_TRUE(renderer.ok());
  const RenderedStep step = (*renderer)->RenderStep(0.0, 1, {true, false, true, false});
  const cv::Mat& on = step.frames[0];
  const cv::Mat& off = step.frames[2];
  int saturated = 0, dropped = 0, rows = 0;
  for (int y = 10; y < 110; ++y) {
    int peak = 0;
    for (int x = 1; x < on.cols; ++x) {
      if (on.at<cv::Vec3b>(y, x)[2] > on.at<cv::Vec3b>(y, peak)[2]) peak = x;
    }
    if (on.at<cv::Vec3b>(y, peak)[2] < 100) continue;
    ++rows;
    saturated += on.at<cv::Vec3b>(y, peak)[2] == 255;
    dropped += on.at<cv::Vec3b>(y, peak)[1] + 10 < off.at<cv::Vec3b>(y, peak)[1];
  }
  EXPECT_GT(rows, 50);
  EXPECT_GT(saturated, rows / 2);
  EXPECT_GT(dropped, rows / 2);
}

TEST(SimulateTest, ScanBundleIsDeterministicAndHasTruth) {
  ScratchDir scratch;
  const Scene scene = SmallScene(R"([{"type": "sphere", "radius_mm": 30, "segments": 32}])", 64, 48, true);
  for (int threads : {1, 3}) {
    SimulateOptions options;
    options.out = scratch / ("scan" + std::to_string(threads));
    options.steps = 3;
    options.threads = threads;
    ASSERT_TRUE(Simulate(scene, options, nullptr).ok());
  }
  auto a = bundle::ReadBundle(scratch / "scan1");
  auto b = bundle::ReadBundle(scratch / "scan3");
  ASSERT_TRUE(a.ok()) << a.status().ToString();
  ASSERT_TRUE(b.ok());
  ASSERT_EQ(a->frames.size(), 12u);
  EXPECT_TRUE(a->has_truth);
  for (std::size_t i = 0; i < a->frames.size(); ++i) {
    EXPECT_EQ(cv::norm(*bundle::ReadFrame(*a, i), *bundle::ReadFrame(*b, i), cv::NORM_INF), 0.0);
  }
  auto rig = geometry::ReadRigYaml(bundle::TruthRigPath(a->directory));
  ASSERT_TRUE(rig.ok());
  EXPECT_NEAR(rig->step_angle_rad, scene.rig.step_angle_rad, 1e-12);
  auto mesh = bundle::ReadPlyMesh(bundle::TruthMeshPath(a->directory));
  ASSERT_TRUE(mesh.ok());
  EXPECT_GT(mesh->faces.size(), 500u);
  auto line = bundle::ReadLineTruth(*a, a->frames[a->FindFrame(2, LaserState::kLeft)]);
  ASSERT_TRUE(line.ok()) << line.status().ToString();
  EXPECT_GT(line->size(), 20u);
  EXPECT_NEAR(a->frames[a->FindFrame(2, LaserState::kLeft)].table_angle_rad, 2 * scene.rig.step_angle_rad,
              1e-9);
  // An existing bundle is not overwritten silently.
  SimulateOptions again;
  again.out = scratch / "scan1";
  again.steps = 1;
  EXPECT_EQ(Simulate(scene, again, nullptr).code(), StatusCode::kFailedPrecondition);
}

TEST(SimulateTest, CalibrationBundlesHavePoses) {
  ScratchDir scratch;
  const Scene scene = SmallScene("[]", 96, 72);
  const std::pair<SimulateKind, std::size_t> kinds[] = {{SimulateKind::kCalibrationObject, 8},
                                                        {SimulateKind::kCheckerboard, 2},
                                                        {SimulateKind::kTableCheckerboard, 8}};
  for (const auto& [kind, frames] : kinds) {
    SimulateOptions options;
    options.out = scratch / ("cal" + std::to_string(static_cast<int>(kind)));
    options.kind = kind;
    options.steps = 2;
    ASSERT_TRUE(Simulate(scene, options, nullptr).ok());
    auto b = bundle::ReadBundle(options.out);
    ASSERT_TRUE(b.ok()) << b.status().ToString();
    EXPECT_EQ(b->header.kind, bundle::BundleKind::kCalibration);
    EXPECT_EQ(b->frames.size(), frames);
    auto poses = bundle::ReadTargetPoses(bundle::TruthPosesPath(options.out));
    ASSERT_TRUE(poses.ok());
    EXPECT_EQ(poses->size(), 2u);
  }
  EXPECT_EQ(ParseSimulateKind("board").status().code(), StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace rotoscan::sim

namespace rotoscan::sim {
namespace {

namespace fs = std::filesystem;
using rotoscan::testing::ScratchDir;

// Stops the work after `limit` units, as Ctrl-C would.
class StopAfter : public Progress {
 public:
  explicit StopAfter(uint64_t limit) : limit_(limit) {}
  void Begin(const std::string&, uint64_t) override {}
  void Advance(uint64_t n) override { done_ += n; }
  void End() override {}
  bool Cancelled() const override { return done_.load() >= limit_; }

 private:
  uint64_t limit_;
  std::atomic<uint64_t> done_{0};
};

TEST(SimulateTest, InterruptedScanResumesToTheSameBundle) {
  ScratchDir scratch;
  const Scene scene = SmallScene(R"([{"type": "sphere", "radius_mm": 30, "segments": 32}])", 64, 48, true);
  SimulateOptions whole;
  whole.out = scratch / "whole";
  whole.steps = 6;
  whole.threads = 2;
  ASSERT_TRUE(Simulate(scene, whole, nullptr).ok());

  SimulateOptions options = whole;
  options.out = scratch / "resumed";
  StopAfter stop(2);
  const Status interrupted = Simulate(scene, options, &stop);
  EXPECT_EQ(interrupted.code(), StatusCode::kCancelled);
  EXPECT_NE(interrupted.message().find("--resume"), std::string::npos) << interrupted.message();
  EXPECT_FALSE(fs::exists(options.out));  // no half bundle under the final name
  const fs::path partial = bundle::BundleWriter::PartialDirectory(options.out);
  ASSERT_TRUE(fs::is_directory(partial));
  // Not resumed by accident: a plain run refuses, a different scene refuses to resume.
  EXPECT_EQ(Simulate(scene, options, nullptr).code(), StatusCode::kFailedPrecondition);
  SimulateOptions resume = options;
  resume.resume = true;
  Scene other = scene;
  other.sensor.laser_exposure_us *= 2;
  EXPECT_EQ(Simulate(other, resume, nullptr).code(), StatusCode::kFailedPrecondition);
  // Resume: only the missing steps are rendered (counted by a progress that never stops).
  ASSERT_TRUE(Simulate(scene, resume, nullptr).ok());
  EXPECT_FALSE(fs::exists(partial));
  auto a = bundle::ReadBundle(whole.out);
  auto b = bundle::ReadBundle(options.out);
  ASSERT_TRUE(a.ok() && b.ok()) << b.status().ToString();
  ASSERT_EQ(a->frames.size(), b->frames.size());
  EXPECT_EQ(bundle::BundleJson(a->header, a->frames), bundle::BundleJson(b->header, b->frames));
  for (std::size_t i = 0; i < a->frames.size(); ++i) {
    EXPECT_EQ(cv::norm(*bundle::ReadFrame(*a, i), *bundle::ReadFrame(*b, i), cv::NORM_INF), 0.0) << i;
  }
  for (const char* bookkeeping : {"journal.jsonl", "header.json", ".lock"}) {
    EXPECT_FALSE(fs::exists(options.out / bookkeeping)) << bookkeeping;
  }
}

// Placements: the objects turned as one body, stood on the table, centred on the axis; the true pose is
// what moves the first placement's surface onto the second's, and the bundle records both.
TEST(SimulateTest, PlacementsStandTheObjectOnTheTableAndRecordTheTruth) {
  auto scene = ParseScene(R"({"camera": {"width": 64, "height": 48, "hfov_deg": 20, "noise": false},
      "objects": [{"type": "box", "size_mm": [40, 20, 10]}],
      "placements": [{}, {"rotation_deg": [90, 0, 0], "position_mm": [3, 0, 0]}]})",
                          DataPath("."), "placements");
  ASSERT_TRUE(scene.ok()) << scene.status().ToString();
  Eigen::Isometry3d t0, t1;
  auto p0 = PlaceScene(*scene, 0, &t0);
  auto p1 = PlaceScene(*scene, 1, &t1);
  ASSERT_TRUE(p0.ok() && p1.ok()) << p1.status().ToString();
  EXPECT_EQ(PlaceScene(*scene, 2, nullptr).status().code(), StatusCode::kInvalidArgument);
  const bundle::TruthMesh m0 = (*Renderer::Create(*p0))->ObjectMesh();
  const bundle::TruthMesh m1 = (*Renderer::Create(*p1))->ObjectMesh();
  Eigen::Vector3f lo = m1.vertices[0], hi = m1.vertices[0];
  for (const Eigen::Vector3f& v : m1.vertices) lo = lo.cwiseMin(v), hi = hi.cwiseMax(v);
  EXPECT_NEAR(lo.z(), 0.0, 1e-5);        // on the table
  EXPECT_NEAR(hi.z(), 20.0, 1e-4);       // on its 40 x 10 side: 20 mm tall
  EXPECT_NEAR(lo.x() + hi.x(), 6.0, 1e-4);  // centred on the axis, then moved 3 mm
  ASSERT_EQ(m0.vertices.size(), m1.vertices.size());
  const Eigen::Isometry3d one_from_zero = t1 * t0.inverse();
  for (size_t i = 0; i < m0.vertices.size(); ++i) {
    EXPECT_LT(((one_from_zero * m0.vertices[i].cast<double>()).cast<float>() - m1.vertices[i]).norm(), 1e-4);
  }
  ScratchDir scratch;
  SimulateOptions options;
  options.out = scratch / "side";
  options.steps = 2;
  options.placement = 1;
  ASSERT_TRUE(Simulate(*scene, options, nullptr).ok());
  auto b = bundle::ReadBundle(scratch / "side");
  ASSERT_TRUE(b.ok()) << b.status().ToString();
  EXPECT_EQ(b->header.placement, 1);
  auto truth = bundle::ReadPlacementTruth(bundle::TruthPlacementPath(scratch / "side"));
  ASSERT_TRUE(truth.ok()) << truth.status().ToString();
  EXPECT_THAT(truth->table_from_reference.matrix(), rotoscan::testing::EigenNear(t1.matrix(), 1e-9));
  options.out = scratch / "nope";
  options.placement = 5;
  EXPECT_EQ(Simulate(*scene, options, nullptr).code(), StatusCode::kInvalidArgument);
  EXPECT_FALSE(std::filesystem::exists(scratch / "nope"));
  // Bad lists name the field.
  auto bad = ParseScene(R"({"placements": [{"rotation": [1, 2, 3]}]})", DataPath("."), "bad");
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("placements[0]"), std::string::npos) << bad.status().ToString();
}

}  // namespace
}  // namespace rotoscan::sim
