#include "rotoscan/pipeline/evaluate.h"

#include <cmath>
#include <sstream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "command.h"
#include "rotoscan/bundle/bundle.h"
#include "rotoscan/bundle/truth.h"
#include "rotoscan/cloud/cloud.h"
#include "rotoscan/core/file.h"
#include "rotoscan/geometry/rig.h"
#include "rotoscan/geometry/rigid.h"
#include "testing/testing.h"

namespace rotoscan::pipeline {
namespace {

constexpr float kHalf = 10.0f;    // the box: 20 x 20 mm, centred on the table axis
constexpr float kHeight = 20.0f;  // standing on the table top

// A 160x120 camera, 20 degree field of view, 300 mm from the table axis and 25 mm above the table top
// (it sees the box's top face), table steps of 10 degrees.
geometry::Rig SmallRig() {
  geometry::Rig rig;
  rig.camera = geometry::CameraModel::FromFieldOfView(160, 120, 20.0);
  rig.axis_point_in_cam = Eigen::Vector3d(0, 25, 300);
  rig.axis_direction_in_cam = Eigen::Vector3d(0, -1, 0);
  for (int l = 0; l < 2; ++l) {
    const Eigen::Vector3d origin(l == 0 ? -173.2 : 173.2, 0, 0);
    const Eigen::Vector3d normal = rig.axis_direction_in_cam.cross(rig.axis_point_in_cam - origin);
    rig.laser_plane[l] = geometry::Plane::FromPointNormal(origin, normal);
  }
  rig.step_angle_rad = geometry::DegToRad(10.0);
  return rig;
}

EvaluationViews Views(const geometry::Rig& rig, int count) {
  EvaluationViews views;
  views.camera = rig.camera;
  for (int i = 0; i < count; ++i) {
    views.cam_from_table.push_back(rig.WorldFromCamAtAngle(i * rig.step_angle_rad).inverse());
  }
  views.step_rad = count > 1 ? rig.step_angle_rad : 0.0;
  return views;
}

bundle::TruthMesh Box() {
  bundle::TruthMesh mesh;
  for (int i = 0; i < 8; ++i) {
    mesh.vertices.emplace_back((i & 1) ? kHalf : -kHalf, (i & 2) ? kHalf : -kHalf, (i & 4) ? kHeight : 0.f);
    mesh.colors.push_back({static_cast<uint8_t>(i * 30), 100, 200});
  }
  const int quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4},
                           {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  for (const auto& q : quads) {
    mesh.faces.emplace_back(q[0], q[1], q[2]);
    mesh.faces.emplace_back(q[0], q[2], q[3]);
  }
  return mesh;
}

// Points on a grid of `pitch` over the box's five faces that are not on the table (the sides and the
// top), each with its outward normal.
struct SurfacePoint {
  Eigen::Vector3f position, normal;
};
std::vector<SurfacePoint> BoxSurface(float pitch) {
  std::vector<SurfacePoint> out;
  const int n = static_cast<int>(std::lround(2 * kHalf / pitch));
  for (int i = 0; i <= n; ++i) {
    for (int j = 0; j <= n; ++j) {
      const float a = -kHalf + i * pitch, b = j * pitch, c = -kHalf + j * pitch;
      out.push_back({{a, c, kHeight}, Eigen::Vector3f::UnitZ()});
      out.push_back({{kHalf, a, b}, Eigen::Vector3f::UnitX()});
      out.push_back({{-kHalf, a, b}, -Eigen::Vector3f::UnitX()});
      out.push_back({{a, kHalf, b}, Eigen::Vector3f::UnitY()});
      out.push_back({{a, -kHalf, b}, -Eigen::Vector3f::UnitY()});
    }
  }
  return out;
}

cloud::PointCloud CloudOf(const std::vector<SurfacePoint>& surface, float offset_mm = 0.f) {
  cloud::PointCloud cloud;
  for (const SurfacePoint& s : surface) {
    cloud::CloudPoint p;
    p.position_in_table = s.position + offset_mm * s.normal;
    p.laser = s.position.x() > 0 ? 0 : 1;
    cloud.points.push_back(p);
  }
  return cloud;
}

EvaluateOptions TestOptions() {
  EvaluateOptions o;
  o.sample_spacing_mm = 0.3;
  o.coverage_radius_mm = 0.5;
  return o;
}

// The visible area of the box from all around: four sides and the top, less the 0.5 mm strip of the
// sides next to the table (table_clearance_mm).
constexpr double kVisibleArea = 4 * 20.0 * 19.5 + 400.0;

TEST(EvaluateTest, CloudOnTheSurfaceHasZeroDistanceAndFullCoverage) {
  const geometry::Rig rig = SmallRig();
  TruthSurface truth{Box(), {}, "vertex colors"};
  const cloud::PointCloud cloud = CloudOf(BoxSurface(0.2f));
  auto r = EvaluateCloud(cloud, truth, Views(rig, 36), TestOptions());
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_EQ(r->points, cloud.size());
  EXPECT_LT(r->distance.rms_mm, 1e-4);
  EXPECT_LT(r->distance.max_mm, 1e-3);
  // Sampling noise of the area estimate: ~1 / sqrt(20,000 samples) < 1 %.
  EXPECT_NEAR(r->coverage.visible_area_mm2, kVisibleArea, 0.03 * kVisibleArea);
  EXPECT_GT(r->coverage.both, 0.995);
  // Left = the x > 0 half of the points, right = the other half: each covers about half.
  EXPECT_NEAR(r->coverage.left, 0.5, 0.04);
  EXPECT_NEAR(r->coverage.right, 0.5, 0.04);
  EXPECT_NEAR(r->coverage.left + r->coverage.right, 1.0, 0.05);
}

TEST(EvaluateTest, CloudDisplacedAlongTheNormalGivesThatDistance) {
  const geometry::Rig rig = SmallRig();
  TruthSurface truth{Box(), {}, "vertex colors"};
  auto r = EvaluateCloud(CloudOf(BoxSurface(0.5f), 0.5f), truth, Views(rig, 4), TestOptions());
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_NEAR(r->distance.rms_mm, 0.5, 1e-4);
  EXPECT_NEAR(r->distance.mean_mm, 0.5, 1e-4);
  EXPECT_NEAR(r->distance.p95_mm, 0.5, 1e-4);
  EXPECT_NEAR(r->distance.max_mm, 0.5, 1e-4);
  EXPECT_NEAR(r->distance_left.rms_mm, 0.5, 1e-4);
  EXPECT_NEAR(r->distance_right.rms_mm, 0.5, 1e-4);
}

TEST(EvaluateTest, DistanceStatisticsOfAMixedCloud) {
  // 19 points on the surface and one 2 mm off: rms = 2 / sqrt(20), mean = 0.1, max = 2, p95 = 0.
  const geometry::Rig rig = SmallRig();
  TruthSurface truth{Box(), {}, "vertex colors"};
  cloud::PointCloud cloud;
  for (int i = 0; i < 20; ++i) {
    cloud::CloudPoint p;
    p.position_in_table = Eigen::Vector3f(-9.5f + i, 0.f, kHeight + (i == 7 ? 2.f : 0.f));
    cloud.points.push_back(p);
  }
  auto r = EvaluateCloud(cloud, truth, Views(rig, 1), TestOptions());
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_NEAR(r->distance.rms_mm, 2.0 / std::sqrt(20.0), 1e-5);
  EXPECT_NEAR(r->distance.mean_mm, 0.1, 1e-5);
  EXPECT_NEAR(r->distance.max_mm, 2.0, 1e-5);
  EXPECT_NEAR(r->distance.p95_mm, 0.0, 1e-5);
}

TEST(EvaluateTest, HalfTheObjectCoversHalfTheVisibleSurface) {
  const geometry::Rig rig = SmallRig();
  TruthSurface truth{Box(), {}, "vertex colors"};
  std::vector<SurfacePoint> half;
  for (const SurfacePoint& s : BoxSurface(0.2f)) {
    if (s.position.y() > 0) half.push_back(s);
  }
  auto r = EvaluateCloud(CloudOf(half), truth, Views(rig, 36), TestOptions());
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_NEAR(r->coverage.both, 0.5, 0.03);
}

TEST(EvaluateTest, OneViewSeesOnlyTheFrontAndTheTop) {
  // From one table angle the camera sees the face towards it and the top; the sides and the back are
  // hidden by the box itself (occlusion rays).
  const geometry::Rig rig = SmallRig();
  TruthSurface truth{Box(), {}, "vertex colors"};
  auto r = EvaluateCloud(CloudOf(BoxSurface(0.2f)), truth, Views(rig, 1), TestOptions());
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  const double expected = 20.0 * 19.5 + 400.0;
  EXPECT_NEAR(r->coverage.visible_area_mm2, expected, 0.04 * expected);
  EXPECT_GT(r->coverage.both, 0.995);
}

TEST(EvaluateTest, AutomaticRadiusBridgesTheGapBetweenSteps) {
  const geometry::Rig rig = SmallRig();
  TruthSurface truth{Box(), {}, "vertex colors"};
  EvaluateOptions o = TestOptions();
  o.coverage_radius_mm = 0;
  auto r = EvaluateCloud(CloudOf(BoxSurface(1.0f)), truth, Views(rig, 36), o);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  // r_max = the box's corner, 10 sqrt(2) mm; step 10 degrees.
  EXPECT_NEAR(r->coverage.radius_mm, 0.6 * 10 * std::sqrt(2.0) * geometry::DegToRad(10.0), 1e-4);
}

// The truth of the color tests: an albedo that varies over the box.
Eigen::Vector3f Pattern(const Eigen::Vector3d& p) {
  return Eigen::Vector3f(static_cast<float>(0.2 + 0.6 * (p.x() + kHalf) / (2 * kHalf)), 0.5f,
                         static_cast<float>(0.3 + 0.02 * p.z()));
}

TEST(EvaluateTest, ColorsScaledByTheExposureHaveNoErrorAfterTheGain) {
  const geometry::Rig rig = SmallRig();
  TruthSurface truth{Box(), [](int, float, float, const Eigen::Vector3d& p) { return Pattern(p); },
                     "pattern"};
  cloud::PointCloud cloud = CloudOf(BoxSurface(0.5f));
  for (cloud::CloudPoint& p : cloud.points) {
    const Eigen::Vector3f c = 0.5f * 255.f * Pattern(p.position_in_table.cast<double>());
    for (int k = 0; k < 3; ++k) p.color[k] = static_cast<uint8_t>(std::lround(c[k]));
  }
  auto r = EvaluateCloud(cloud, truth, Views(rig, 4), TestOptions());
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  ASSERT_TRUE(r->has_color);
  EXPECT_EQ(r->color.points, cloud.size());
  EXPECT_EQ(r->color.truth_source, "pattern");
  EXPECT_THAT(r->color.gain, rotoscan::testing::EigenNear(Eigen::Vector3d(2, 2, 2), 0.01));
  EXPECT_LT(r->color.mean_abs_error_all, 0.75);  // rounding to 8 bits (mean 0.25), times the gain 2
  EXPECT_DOUBLE_EQ(r->color.within_tolerance, 1.0);
  EXPECT_LT(r->color.mean_abs_error_per_point_gain, 0.75);
}

TEST(EvaluateTest, WrongColorsGiveTheExpectedError) {
  // True albedo 0.5 everywhere (127.5 levels); half the points read 100, half 140. The gain is
  // g = 127.5 (100 + 140) / (100^2 + 140^2) and the errors |100 g - 127.5|, |140 g - 127.5|.
  const geometry::Rig rig = SmallRig();
  TruthSurface truth{
      Box(), [](int, float, float, const Eigen::Vector3d&) { return Eigen::Vector3f(0.5f, 0.5f, 0.5f); },
      "grey"};
  cloud::PointCloud cloud = CloudOf(BoxSurface(0.5f));
  for (size_t i = 0; i < cloud.size(); ++i) cloud.points[i].color.fill(i % 2 == 0 ? 100 : 140);
  if (cloud.size() % 2 == 1) cloud.points.pop_back();
  auto r = EvaluateCloud(cloud, truth, Views(rig, 4), TestOptions());
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  const double g = 127.5 * 240.0 / (100.0 * 100.0 + 140.0 * 140.0);
  const double expected = 0.5 * (std::abs(100 * g - 127.5) + std::abs(140 * g - 127.5));
  EXPECT_NEAR(r->color.gain[1], g, 1e-9);
  EXPECT_NEAR(r->color.mean_abs_error_all, expected, 1e-6);
  EXPECT_GT(r->color.mean_abs_error_all, 20.0);
  EXPECT_DOUBLE_EQ(r->color.within_tolerance, 0.0);
  // Grey measured as grey: one gain per point removes the whole error.
  EXPECT_LT(r->color.mean_abs_error_per_point_gain, 1e-9);
  EXPECT_DOUBLE_EQ(r->color.within_tolerance_per_point_gain, 1.0);
}

TEST(EvaluateTest, VertexColorsAreInterpolatedAtTheClosestPoint) {
  // One triangle, red, green and blue at its corners: a point above barycentric (0.6, 0.3, 0.1) has the
  // true color (0.6, 0.3, 0.1) * 255. Checks the (u, v) convention of the closest-point query too.
  bundle::TruthMesh mesh;
  mesh.vertices = {{-10, 0, 1}, {10, 0, 1}, {0, 0, 21}};
  mesh.colors = {{255, 0, 0}, {0, 255, 0}, {0, 0, 255}};
  mesh.faces = {{0, 1, 2}};
  TruthSurface truth{mesh, {}, "vertex colors"};
  cloud::PointCloud cloud;
  const double w[4][3] = {{0.6, 0.3, 0.1}, {0.2, 0.2, 0.6}, {0.1, 0.8, 0.1}, {0.4, 0.4, 0.2}};
  for (const auto& b : w) {
    cloud::CloudPoint p;
    p.position_in_table = static_cast<float>(b[0]) * mesh.vertices[0] +
                          static_cast<float>(b[1]) * mesh.vertices[1] +
                          static_cast<float>(b[2]) * mesh.vertices[2] + Eigen::Vector3f(0, -0.1f, 0);
    for (int k = 0; k < 3; ++k) p.color[k] = static_cast<uint8_t>(std::lround(255 * b[k]));
    cloud.points.push_back(p);
  }
  auto r = EvaluateCloud(cloud, truth, Views(SmallRig(), 1), TestOptions());
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_NEAR(r->distance.max_mm, 0.1, 1e-5);
  EXPECT_EQ(r->color.points, 4u);
  EXPECT_LT(r->color.mean_abs_error_all, 0.5);
}

TEST(EvaluateTest, BadInputIsAnError) {
  const geometry::Rig rig = SmallRig();
  TruthSurface truth{Box(), {}, "vertex colors"};
  const cloud::PointCloud cloud = CloudOf(BoxSurface(2.0f));
  EXPECT_EQ(EvaluateCloud(cloud::PointCloud{}, truth, Views(rig, 4)).status().code(),
            StatusCode::kInvalidArgument);
  EXPECT_EQ(EvaluateCloud(cloud, TruthSurface{}, Views(rig, 4)).status().code(),
            StatusCode::kInvalidArgument);
  EXPECT_EQ(EvaluateCloud(cloud, truth, EvaluationViews{rig.camera, {}, 0.0}).status().code(),
            StatusCode::kInvalidArgument);
  TruthSurface broken = truth;
  broken.mesh.faces.emplace_back(0, 1, 8);
  EXPECT_EQ(EvaluateCloud(cloud, broken, Views(rig, 4)).status().code(), StatusCode::kInvalidArgument);
  EvaluateOptions o;
  o.sample_spacing_mm = 0;
  auto r = EvaluateCloud(cloud, truth, Views(rig, 4), o);
  EXPECT_EQ(r.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(r.status().message().find("sample_spacing_mm"), std::string::npos);
  o = EvaluateOptions{};
  o.max_samples = 100;  // the box (2,400 mm^2) needs 38,400 at 0.25 mm
  EXPECT_EQ(EvaluateCloud(cloud, truth, Views(rig, 4), o).status().code(), StatusCode::kInvalidArgument);

  rotoscan::testing::ScratchDir dir;
  EXPECT_EQ(LoadTruthSurface(dir.path()).status().code(), StatusCode::kNotFound);
  EXPECT_EQ(LoadEvaluationViews(dir.path()).status().code(), StatusCode::kNotFound);
}

// Reach: a 20 x 20 x 40 mm box standing on the table, taller than the camera (25 mm above the table top),
// so its top is hidden from the camera at every table angle; laid on a side, the top is a side and is
// scanned like the others. A cloud of every face but the top leaves the top uncovered: one region, not
// scannable upright, scannable in another pose, and the best second pose lays the box down.
TEST(EvaluateTest, ReachFindsTheHiddenTopAndThePoseThatScansIt) {
  constexpr float kTall = 40.0f;
  bundle::TruthMesh tall = Box();
  for (Eigen::Vector3f& v : tall.vertices) v.z() *= kTall / kHeight;
  cloud::PointCloud cloud;
  for (float a = -kHalf; a <= kHalf + 1e-3f; a += 0.2f) {
    for (float b = 0; b <= kTall + 1e-3f; b += 0.2f) {
      for (const Eigen::Vector3f& q : {Eigen::Vector3f(kHalf, a, b), Eigen::Vector3f(-kHalf, a, b),
                                       Eigen::Vector3f(a, kHalf, b), Eigen::Vector3f(a, -kHalf, b)}) {
        cloud::CloudPoint p;
        p.position_in_table = q;
        cloud.points.push_back(p);
      }
    }
  }
  const geometry::Rig rig = SmallRig();
  ScanRig scan_rig;
  scan_rig.rig = rig;
  scan_rig.laser_origin_in_cam[0] = Eigen::Vector3d(-173.2, 0, 0);
  scan_rig.laser_origin_in_cam[1] = Eigen::Vector3d(173.2, 0, 0);
  scan_rig.placement_rotation = {Eigen::Matrix3d::Identity()};
  ReachOptions reach;
  reach.orientations = 50;
  EvaluateOptions o = TestOptions();
  auto r = EvaluateReach(cloud, TruthSurface{tall, {}, "vertex colors"}, Views(rig, 36), scan_rig, o, reach);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  // The surface above the 0.5 mm clearance: 4 sides of 20 x 39.5 and the top (400 mm^2); ~1 % sampling noise.
  const double area = 4 * 20.0 * 39.5 + 400.0;
  EXPECT_NEAR(r->area_mm2, area, 0.03 * area);
  // Covered: all but the top, less the 0.5 mm radius's strip along its edges (4 x 20 x 0.5 mm^2).
  EXPECT_NEAR(r->covered, (area - 400.0 + 40.0) / area, 0.015);
  // Upright, the sides are scannable and the top is not: every covered sample of the sides is.
  EXPECT_NEAR(r->scannable_given, (area - 400.0) / area, 0.015);
  EXPECT_GT(r->covered_of_scannable_given, 0.99);
  EXPECT_LT(r->covered_not_scannable, 0.015);  // the top's strip within the radius
  EXPECT_GT(r->scannable_any, 0.99);
  ASSERT_FALSE(r->regions.empty());
  EXPECT_NEAR(r->regions[0].area_mm2, 400.0 - 40.0, 40.0);
  EXPECT_NEAR(r->regions[0].centroid.z(), kTall, 0.05);
  EXPECT_LT(r->regions[0].scannable_given, 0.02);
  EXPECT_GT(r->regions[0].scannable_any, 0.98);
  // A second pose that tilts the top towards the camera (not upright, not upside down: then the top is on
  // the table) scans the rest.
  EXPECT_GT(r->best_second, 0.99);
  EXPECT_LT(r->best_second_up.z(), 0.95) << r->best_second_up.transpose();
  EXPECT_GT(r->best_second_up.z(), -0.95) << r->best_second_up.transpose();
  ASSERT_EQ(r->uncovered.size(), r->uncovered_class.size());
  size_t other_pose = 0;
  for (uint8_t c : r->uncovered_class) other_pose += c == 1;
  EXPECT_GT(other_pose, r->uncovered.size() * 9 / 10);
  // With a limit on the incidence: where a laser's plane (through the axis) crosses a side near a corner,
  // the laser meets it at up to 45 degrees from its normal whichever laser it is, so 40 degrees leaves the
  // sides' outer parts out.
  reach.max_incidence_deg = 40;
  auto strict =
      EvaluateReach(cloud, TruthSurface{tall, {}, "vertex colors"}, Views(rig, 36), scan_rig, o, reach);
  ASSERT_TRUE(strict.ok()) << strict.status().ToString();
  EXPECT_LT(strict->scannable_given, r->scannable_given - 0.05);
  // Bad input.
  reach.max_incidence_deg = 0;
  EXPECT_EQ(EvaluateReach(cloud, TruthSurface{tall, {}, "vertex colors"}, Views(rig, 36), scan_rig, o, reach)
                .status()
                .code(),
            StatusCode::kInvalidArgument);
  cloud.points[0].placement = 3;  // a placement the rig does not have
  EXPECT_EQ(EvaluateReach(cloud, TruthSurface{tall, {}, "vertex colors"}, Views(rig, 36), scan_rig, o, {})
                .status()
                .code(),
            StatusCode::kInvalidArgument);
}

// A bundle directory with bundle.json (4 table steps, no frame files), truth/rig.yaml and truth/object.ply.
void WriteBoxBundle(const std::filesystem::path& dir, const geometry::Rig& rig) {
  bundle::BundleHeader header;
  header.kind = bundle::BundleKind::kScan;
  header.camera.model = rig.camera;
  header.table_step_rad = geometry::DegToRad(90.0);
  std::vector<bundle::FrameRecord> frames;
  for (int s = 0; s < 4; ++s) {
    bundle::FrameRecord f;
    f.step = s;
    f.table_angle_rad = s * header.table_step_rad;
    f.laser = bundle::LaserState::kNatural;
    f.file = bundle::FrameFileName(s, f.laser);
    frames.push_back(f);
  }
  std::filesystem::create_directories(dir / "truth");
  ASSERT_TRUE(WriteFileAtomically(dir / "bundle.json", bundle::BundleJson(header, frames)).ok());
  ASSERT_TRUE(geometry::WriteRigYaml(bundle::TruthRigPath(dir), rig).ok());
  ASSERT_TRUE(bundle::WritePlyMesh(bundle::TruthMeshPath(dir), Box()).ok());
}

int RunCli(std::vector<std::string> args, std::string* out_text, std::string* err_text) {
  std::vector<const char*> argv{"rotoscan", "--no-progress"};
  for (const std::string& a : args) argv.push_back(a.c_str());
  std::ostringstream out, err;
  const int code = cli::Main(static_cast<int>(argv.size()), argv.data(), out, err);
  *out_text = out.str();
  *err_text = err.str();
  return code;
}

TEST(EvaluateCommandTest, ReportsEveryMetricAndWritesJson) {
  rotoscan::testing::ScratchDir dir;
  WriteBoxBundle(dir.path() / "scan", SmallRig());
  auto views = LoadEvaluationViews(dir.path() / "scan");
  ASSERT_TRUE(views.ok()) << views.status().ToString();
  EXPECT_EQ(views->cam_from_table.size(), 4u);
  EXPECT_NEAR(views->step_rad, geometry::DegToRad(90.0), 1e-12);

  cloud::PointCloud cloud = CloudOf(BoxSurface(0.25f), 0.1f);
  ASSERT_TRUE(cloud::WritePly(dir.path() / "cloud.ply", cloud).ok());
  const std::string report = (dir.path() / "report.json").string();
  std::string out, err;
  ASSERT_EQ(
      RunCli({"evaluate", (dir.path() / "cloud.ply").string(), "--truth", (dir.path() / "scan").string(),
              "--report", report, "--radius", "0.5", "--spacing", "0.4"},
             &out, &err),
      0)
      << err;
  EXPECT_NE(out.find("distance: "), std::string::npos) << out;
  EXPECT_NE(out.find("coverage: "), std::string::npos) << out;
  EXPECT_NE(out.find("color: "), std::string::npos) << out;
  auto text = ReadFile(report);
  ASSERT_TRUE(text.ok());
  const nlohmann::json j = nlohmann::json::parse(*text);
  EXPECT_NEAR(j["distance"]["rms_mm"].get<double>(), 0.1, 1e-4);
  EXPECT_GT(j["coverage"]["both"].get<double>(), 0.99);
  EXPECT_EQ(j["color"]["truth"], "vertex colors");

  // Missing truth, an empty cloud, an unreadable cloud: exit 1 with the reason, and no report.
  const std::string report2 = (dir.path() / "report2.json").string();
  EXPECT_EQ(RunCli({"evaluate", (dir.path() / "cloud.ply").string(), "--truth", dir.path().string(),
                    "--report", report2},
                   &out, &err),
            1);
  EXPECT_NE(err.find("object.ply"), std::string::npos) << err;
  ASSERT_TRUE(cloud::WritePly(dir.path() / "empty.ply", cloud::PointCloud{}).ok());
  EXPECT_EQ(RunCli({"evaluate", (dir.path() / "empty.ply").string(), "--truth",
                    (dir.path() / "scan").string(), "--report", report2},
                   &out, &err),
            1);
  EXPECT_NE(err.find("no points"), std::string::npos) << err;
  ASSERT_TRUE(WriteFileAtomically(dir.path() / "bad.ply", "ply\nformat nonsense\n").ok());
  EXPECT_EQ(RunCli({"evaluate", (dir.path() / "bad.ply").string(), "--truth", (dir.path() / "scan").string()},
                   &out, &err),
            1);
  EXPECT_NE(err.find("bad.ply"), std::string::npos) << err;
  EXPECT_FALSE(std::filesystem::exists(report2));
  // Neither a cloud nor --lines: usage.
  EXPECT_EQ(RunCli({"evaluate"}, &out, &err), 2);
  // --reach and --uncovered need the scene (the lasers' origins, the placements): usage, nothing written.
  const std::string uncovered = (dir.path() / "uncovered.ply").string();
  EXPECT_EQ(RunCli({"evaluate", (dir.path() / "cloud.ply").string(), "--truth", (dir.path() / "scan").string(),
                    "--uncovered", uncovered},
                   &out, &err),
            2);
  EXPECT_NE(err.find("--scene"), std::string::npos) << err;
  EXPECT_FALSE(std::filesystem::exists(uncovered));
}

}  // namespace
}  // namespace rotoscan::pipeline
