#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <sstream>

#include "command.h"
#include "rotoscan/cloud/cloud.h"
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
