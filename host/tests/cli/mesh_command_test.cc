#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <random>
#include <sstream>

#include "command.h"
#include "rotoscan/bundle/bundle.h"
#include "rotoscan/bundle/truth.h"
#include "rotoscan/cloud/cloud.h"
#include "rotoscan/core/file.h"
#include "rotoscan/mesh/mesh.h"
#include "testing/testing.h"

namespace rotoscan::cli {
namespace {

int Call(std::vector<std::string> args, std::string* err_text = nullptr) {
  std::vector<const char*> argv{"rotoscan"};
  for (const auto& a : args) argv.push_back(a.c_str());
  std::ostringstream out, err;
  const int code = Main(static_cast<int>(argv.size()), argv.data(), out, err);
  if (err_text != nullptr) *err_text = err.str();
  return code;
}

TEST(MeshCommandTest, CloudToMeshAndPreview) {
  rotoscan::testing::ScratchDir dir;
  cloud::PointCloud sphere;
  std::mt19937 rng(7);
  std::normal_distribution<float> normal(0.f, 1.f);
  for (int i = 0; i < 4000; ++i) {
    cloud::CloudPoint p;
    p.normal = Eigen::Vector3f(normal(rng), normal(rng), normal(rng)).normalized();
    p.position_in_table = 30.f * p.normal + Eigen::Vector3f(0, 0, 40);
    p.color = {200, 180, 40};
    sphere.points.push_back(p);
  }
  ASSERT_TRUE(cloud::WritePly(dir / "cloud.ply", sphere).ok());
  ASSERT_EQ(
      Call({"mesh", (dir / "cloud.ply").string(), "--out", (dir / "mesh.ply").string(), "--method", "poisson",
            "--depth", "5", "--threads", "1"}),
      kExitOk);
  const Result<mesh::TriangleMesh> surface = mesh::ReadMesh(dir / "mesh.ply");
  ASSERT_TRUE(surface.ok()) << surface.status().ToString();
  double worst = 0;
  for (const auto& v : surface->vertices)
    worst = std::max(worst, std::abs((v - Eigen::Vector3d(0, 0, 40)).norm() - 30));
  EXPECT_LT(worst, 1.5);  // depth 5 over 66 mm: 2 mm cells
  EXPECT_TRUE(std::filesystem::exists(dir / "mesh.png"));
}

// The default method (fusion) on a cloud that knows its camera path, written as glTF binary.
TEST(MeshCommandTest, FusionToGlbWithPreviews) {
  rotoscan::testing::ScratchDir dir;
  cloud::PointCloud sphere;
  sphere.scan.known = true;
  sphere.scan.camera_at_step0 = Eigen::Vector3d(300, 0, 40);
  sphere.scan.step_rad = 2 * 3.14159265358979 / 360;
  std::mt19937 rng(8);
  std::normal_distribution<float> normal(0.f, 1.f);
  for (int i = 0; i < 40000; ++i) {
    cloud::CloudPoint p;
    p.normal = Eigen::Vector3f(normal(rng), normal(rng), normal(rng)).normalized();
    p.position_in_table = 30.f * p.normal + Eigen::Vector3f(0, 0, 40);
    p.color = {200, 180, 40};
    p.quality = 1;
    // The step that faced the point: the camera's azimuth equals the point's.
    p.step = static_cast<int32_t>(std::lround(std::atan2(p.normal.y(), p.normal.x()) / sphere.scan.step_rad));
    sphere.points.push_back(p);
  }
  ASSERT_TRUE(cloud::WritePly(dir / "cloud.ply", sphere).ok());
  ASSERT_EQ(Call({"mesh", (dir / "cloud.ply").string(), "--out", (dir / "mesh.glb").string(), "--voxel", "1",
                  "--open-bottom", "--cloud-preview", (dir / "cloud.png").string()}),
            kExitOk);
  const Result<mesh::TriangleMesh> surface = mesh::ReadMesh(dir / "mesh.glb");  // Open3D's glTF reader
  ASSERT_TRUE(surface.ok()) << surface.status().ToString();
  ASSERT_GT(surface->triangles.size(), 1000u);
  double worst = 0;
  for (const auto& v : surface->vertices)
    worst = std::max(worst, std::abs((v - Eigen::Vector3d(0, 0, 40)).norm() - 30));
  EXPECT_LT(worst, 0.3);  // 1 mm voxels, noise-free points
  EXPECT_TRUE(std::filesystem::exists(dir / "mesh.png"));
  EXPECT_TRUE(std::filesystem::exists(dir / "cloud.png"));
}

// Runs the program's Main; stdout in *out_text.
int CallOut(std::vector<std::string> args, std::string* out_text, std::string* err_text = nullptr) {
  std::vector<const char*> argv{"rotoscan", "--no-progress"};
  for (const auto& a : args) argv.push_back(a.c_str());
  std::ostringstream out, err;
  const int code = Main(static_cast<int>(argv.size()), argv.data(), out, err);
  *out_text = out.str();
  if (err_text != nullptr) *err_text = err.str();
  return code;
}

// The number after `key` in `text` (NaN if absent).
double NumberAfter(const std::string& text, const std::string& key) {
  const std::size_t at = text.find(key);
  if (at == std::string::npos) return std::nan("");
  return std::strtod(text.c_str() + at + key.size(), nullptr);
}

// Issue 19: `evaluate` on a mesh measures truth -> mesh against its triangles, so a hole counts by its area;
// and `bench mesh` on a small scan prints its figures. A rendered sphere (90 steps of 4°, 320 x 240) is the
// truth.
TEST(MeshCommandTest, EvaluateMeasuresHolesByAreaAndBenchMeshReports) {
  rotoscan::testing::ScratchDir dir;
  ASSERT_TRUE(WriteFileAtomically(dir / "scene.json",
                                  R"({"seed": 5, "steps": 90,
                                      "camera": {"width": 320, "height": 240, "hfov_deg": 20, "supersampling": 1},
                                      "objects": [{"type": "sphere", "radius_mm": 20}]})")
                  .ok());
  const std::string bundle = (dir / "bundle").string(), cloud = (dir / "cloud.ply").string(),
                    mesh = (dir / "mesh.ply").string();
  std::string out, err;
  // A whole turn in 90 steps: --step-deg overrides the scene's 0.3° (which would turn the table 27° only).
  ASSERT_EQ(CallOut({"simulate", (dir / "scene.json").string(), "--out", bundle, "--threads", "2", "--step-deg", "4"},
                    &out, &err),
            kExitOk)
      << err;
  const Result<bundle::Bundle> rendered = bundle::ReadBundle(bundle);
  ASSERT_TRUE(rendered.ok()) << rendered.status().ToString();
  double last_deg = 0;
  for (const auto& f : rendered->frames) last_deg = std::max(last_deg, f.table_angle_rad * 180 / 3.14159265358979);
  EXPECT_NEAR(last_deg, 356.0, 1e-6);
  ASSERT_EQ(CallOut({"process", bundle, "--out", cloud, "--threads", "2"}, &out, &err), kExitOk) << err;
  EXPECT_NE(out.find("filter: "), std::string::npos) << out;
  ASSERT_EQ(CallOut({"mesh", cloud, "--out", mesh, "--voxel", "1", "--watertight"}, &out, &err), kExitOk) << err;
  EXPECT_NE(out.find("watertight"), std::string::npos) << out;
  ASSERT_EQ(CallOut({"evaluate", mesh, "--truth", bundle}, &out, &err), kExitOk) << err;
  const double holes = NumberAfter(out, "holes: ");
  const double median = NumberAfter(out, "truth to mesh: ");
  // Measured: vertices to truth p95 0.84 mm (the filled gaps between laser lines 4° apart), holes 0.024.
  EXPECT_LT(NumberAfter(out, "p95="), 1.5) << out;
  EXPECT_LT(holes, 0.06) << out;
  EXPECT_FALSE(std::isnan(median)) << out;

  // Cut a cap of 6 mm off the top: its area is 2 pi R h = 754 mm^2, all of it visible (the camera looks
  // down); the hole's area as measured must account for it (less a rim of the coverage radius).
  Result<mesh::TriangleMesh> surface = mesh::ReadMesh(mesh);
  ASSERT_TRUE(surface.ok());
  double top = -1e9;
  for (const auto& v : surface->vertices) top = std::max(top, v.z());
  mesh::TriangleMesh holed = *surface;
  holed.triangles.clear();
  for (const auto& t : surface->triangles) {
    if (surface->vertices[t[0]].z() < top - 6 || surface->vertices[t[1]].z() < top - 6 ||
        surface->vertices[t[2]].z() < top - 6) {
      holed.triangles.push_back(t);
    }
  }
  ASSERT_TRUE(mesh::WriteMesh(dir / "holed.ply", holed).ok());
  const std::string report = (dir / "holed.json").string();
  ASSERT_EQ(CallOut({"evaluate", (dir / "holed.ply").string(), "--truth", bundle, "--report", report}, &out, &err),
            kExitOk)
      << err;
  const double hole_area = NumberAfter(out, "of the visible area (");
  const double radius = NumberAfter(out, "farther than ");
  const double cap = 2 * 3.14159265358979 * 20 * 6;
  const double rim = 2 * 3.14159265358979 * 20 * radius;  // the band within the radius of the cut's edge
  EXPECT_GT(hole_area, 0.85 * (cap - rim)) << out;
  EXPECT_LT(hole_area, 1.1 * cap) << out;
  const Result<std::string> json = ReadFile(report);
  ASSERT_TRUE(json.ok());
  EXPECT_NE(json->find("\"truth_to_mesh\""), std::string::npos);
  EXPECT_NE(json->find("\"hole_area_mm2\""), std::string::npos);

  // bench mesh on the same small scan: every figure it promises, no timing checked.
  ASSERT_EQ(CallOut({"bench", "mesh", "--cloud", cloud, "--truth", bundle, "--voxel", "1", "--depth", "6",
                     "--threads", "1", "--watertight"},
                    &out, &err),
            kExitOk)
      << err;
  for (const char* field : {"load average", "fusion ", "poisson ", "fusion-wt", "vertices to truth: median",
                            "truth to mesh: median", "holes ", "x Poisson"}) {
    EXPECT_NE(out.find(field), std::string::npos) << field << "\n" << out;
  }
}

TEST(MeshCommandTest, MissingCloudIsAClearError) {
  rotoscan::testing::ScratchDir dir;
  std::string err;
  EXPECT_EQ(Call({"mesh", (dir / "none.ply").string(), "--out", (dir / "m.ply").string()}, &err),
            kExitFailure);
  EXPECT_NE(err.find("none.ply"), std::string::npos) << err;
  EXPECT_FALSE(std::filesystem::exists(dir / "m.ply"));
  EXPECT_EQ(Call({"mesh"}), kExitUsage);
}

}  // namespace
}  // namespace rotoscan::cli
