#include "rotoscan/mesh/mesh.h"

#include <gtest/gtest.h>

#include <cmath>
#include <map>
#include <random>

#include <opencv2/core.hpp>

#include "rotoscan/mesh/report.h"
#include "testing/testing.h"

namespace rotoscan::mesh {
namespace {

constexpr double kRadius = 40.0;  // mm
const Eigen::Vector3d kCentre(5, -3, 50);

// Points on a sphere with outward normals; red on top (z > centre), blue below.
ColoredPoints Sphere(int n, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  ColoredPoints cloud;
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3d d = Eigen::Vector3d(normal(rng), normal(rng), normal(rng)).normalized();
    cloud.points.push_back(kCentre + kRadius * d);
    cloud.normals.push_back(d);
    cloud.colors.push_back(d.z() > 0 ? Eigen::Vector3d(0.9, 0.1, 0.1) : Eigen::Vector3d(0.1, 0.1, 0.9));
  }
  return cloud;
}

// Signed volume of a closed, outward-oriented mesh (divergence theorem); negative if it faces inward.
double SignedVolume(const TriangleMesh& mesh) {
  double volume = 0;
  for (const Eigen::Vector3i& t : mesh.triangles) {
    volume += mesh.vertices[t[0]].dot(mesh.vertices[t[1]].cross(mesh.vertices[t[2]])) / 6.0;
  }
  return volume;
}

// Edges used by exactly one triangle: a closed surface has none.
std::size_t BoundaryEdges(const TriangleMesh& mesh) {
  std::map<std::pair<int, int>, int> count;
  for (const Eigen::Vector3i& t : mesh.triangles) {
    for (int c = 0; c < 3; ++c) ++count[std::minmax(t[c], t[(c + 1) % 3])];
  }
  std::size_t boundary = 0;
  for (const auto& [edge, n] : count) boundary += n == 1 ? 1 : 0;
  return boundary;
}

TEST(FusionTest, SphereIsClosedOutwardAndOnTheSurface) {
  ColoredPoints cloud = Sphere(60000, 11);
  cloud.views = cloud.normals;  // seen straight on
  FusionOptions options;
  options.voxel_mm = 1.0;
  options.flat_bottom = false;
  FusionSummary summary;
  const Result<TriangleMesh> mesh = FuseSurface(cloud, options, &summary);
  ASSERT_TRUE(mesh.ok()) << mesh.status().ToString();
  ASSERT_EQ(mesh->vertex_colors.size(), mesh->vertices.size());
  double sum_sq = 0, worst = 0;
  for (std::size_t i = 0; i < mesh->vertices.size(); ++i) {
    const Eigen::Vector3d d = mesh->vertices[i] - kCentre;
    const double err = d.norm() - kRadius;
    sum_sq += err * err;
    worst = std::max(worst, std::abs(err));
    if (d.z() > 5) {
      EXPECT_GT(mesh->vertex_colors[i].x(), mesh->vertex_colors[i].z());
    } else if (d.z() < -5) {
      EXPECT_LT(mesh->vertex_colors[i].x(), mesh->vertex_colors[i].z());
    }
  }
  // The sphere's curvature biases a 1 mm-voxel distance field by ~h^2 / 2R; noise-free samples.
  EXPECT_LT(std::sqrt(sum_sq / static_cast<double>(mesh->vertices.size())), 0.05);
  EXPECT_LT(worst, 0.2);
  const double true_volume = 4.0 / 3.0 * 3.14159265358979 * kRadius * kRadius * kRadius;
  EXPECT_NEAR(SignedVolume(*mesh) / true_volume, 1.0, 0.01);  // outward, closed
  EXPECT_EQ(BoundaryEdges(*mesh), 0u);
  EXPECT_EQ(summary.input_points, 60000u);
  EXPECT_GT(summary.blocks, 0u);
}

TEST(FusionTest, SmallComponentsAreRemovedAndThreadsAgree) {
  ColoredPoints cloud = Sphere(60000, 12);
  // A speck of 300 points 30 mm beside the sphere.
  for (int i = 0; i < 300; ++i) {
    const Eigen::Vector3d d = Eigen::Vector3d(std::cos(i * 0.7), std::sin(i * 0.7), std::cos(i * 1.3)).normalized();
    cloud.points.push_back(kCentre + Eigen::Vector3d(kRadius + 30, 0, 0) + 1.5 * d);
    cloud.normals.push_back(d);
    cloud.colors.emplace_back(0, 1, 0);
  }
  FusionOptions options;
  options.voxel_mm = 1.0;
  options.flat_bottom = false;
  options.threads = 1;
  const Result<TriangleMesh> one = FuseSurface(cloud, options);
  options.threads = 2;
  FusionSummary summary;
  const Result<TriangleMesh> two = FuseSurface(cloud, options, &summary);
  ASSERT_TRUE(one.ok() && two.ok());
  EXPECT_EQ(one->triangles.size(), two->triangles.size());
  EXPECT_GE(summary.removed_components, 1u);
  for (const auto& v : two->vertices) EXPECT_LT((v - kCentre).norm(), kRadius + 1.0);
  options.min_component_fraction = 0;
  const Result<TriangleMesh> all = FuseSurface(cloud, options);
  ASSERT_TRUE(all.ok());
  EXPECT_GT(all->triangles.size(), two->triangles.size());
}

// An open can standing on the table (wall and lid sampled, no bottom): the flat bottom closes it.
TEST(FusionTest, FlatBottomClosesTheCanOnTheTable) {
  constexpr double kCanRadius = 20, kHeight = 30;
  ColoredPoints cloud;
  for (int i = 0; i < 400; ++i) {
    const double a = 2 * 3.14159265358979 * i / 400;
    const Eigen::Vector3d radial(std::cos(a), std::sin(a), 0);
    for (double z = 0.1; z < kHeight; z += 0.25) {
      cloud.points.push_back(kCanRadius * radial + Eigen::Vector3d(0, 0, z));
      cloud.normals.push_back(radial);
    }
    for (double r = 0.25; r < kCanRadius; r += 0.25) {
      cloud.points.push_back(r * radial + Eigen::Vector3d(0, 0, kHeight));
      cloud.normals.push_back(Eigen::Vector3d::UnitZ());
    }
  }
  FusionOptions options;
  options.voxel_mm = 1.0;
  const Result<TriangleMesh> closed = FuseSurface(cloud, options);
  ASSERT_TRUE(closed.ok()) << closed.status().ToString();
  const double volume = 3.14159265358979 * kCanRadius * kCanRadius * kHeight;
  EXPECT_NEAR(SignedVolume(*closed) / volume, 1.0, 0.03);
  double lowest = 1e9;
  for (const auto& v : closed->vertices) lowest = std::min(lowest, v.z());
  EXPECT_NEAR(lowest, 0.0, 0.3) << BoundaryEdges(*closed) << " " << SignedVolume(*closed) / volume;
  options.flat_bottom = false;
  const Result<TriangleMesh> open = FuseSurface(cloud, options);
  ASSERT_TRUE(open.ok());
  EXPECT_GT(BoundaryEdges(*open), 100u);
}

TEST(FusionTest, BadInput) {
  FusionOptions options;
  EXPECT_EQ(FuseSurface(Sphere(50, 3), options).status().code(), StatusCode::kInvalidArgument);
  ColoredPoints mismatched = Sphere(500, 3);
  mismatched.views.resize(10);
  EXPECT_EQ(FuseSurface(mismatched, options).status().code(), StatusCode::kInvalidArgument);
  ColoredPoints nan = Sphere(500, 3);
  nan.points[7].x() = std::nan("");
  EXPECT_EQ(FuseSurface(nan, options).status().code(), StatusCode::kInvalidArgument);
  ColoredPoints far = Sphere(500, 3);
  far.points[3].x() = 5e6;  // 5 km away: the volume would not fit
  EXPECT_EQ(FuseSurface(far, options).status().code(), StatusCode::kInvalidArgument);
  ColoredPoints bare = Sphere(500, 3);
  bare.normals.clear();
  EXPECT_EQ(FuseSurface(bare, options).status().code(), StatusCode::kInvalidArgument);
  options.voxel_mm = 0;
  EXPECT_EQ(FuseSurface(Sphere(500, 3), options).status().code(), StatusCode::kInvalidArgument);
}

TEST(PoissonTest, SphereIsRecoveredWithColors) {
  PoissonOptions options;
  options.depth = 6;
  options.trim_density_quantile = 0.0;
  options.threads = 1;  // tests run two at a time on two cores  // a closed sphere: nothing to trim
  PoissonSummary summary;
  const Result<TriangleMesh> mesh = PoissonReconstruct(Sphere(6000, 1), options, &summary);
  ASSERT_TRUE(mesh.ok()) << mesh.status().ToString();
  ASSERT_GT(mesh->triangles.size(), 500u);
  ASSERT_EQ(mesh->vertex_colors.size(), mesh->vertices.size());
  double sum_sq = 0;
  for (std::size_t i = 0; i < mesh->vertices.size(); ++i) {
    const Eigen::Vector3d d = mesh->vertices[i] - kCentre;
    const double err = d.norm() - kRadius;
    sum_sq += err * err;
    // Colors follow the hemisphere (away from the equator, where they blend).
    if (d.z() > 10) {
      EXPECT_GT(mesh->vertex_colors[i].x(), mesh->vertex_colors[i].z());
    } else if (d.z() < -10) {
      EXPECT_LT(mesh->vertex_colors[i].x(), mesh->vertex_colors[i].z());
    }
  }
  // Octree cell at depth 6 over ~1.1 x 80 mm: ~1.4 mm; the surface is found well inside a cell.
  EXPECT_LT(std::sqrt(sum_sq / mesh->vertices.size()), 0.4);
  EXPECT_EQ(summary.input_points, 6000u);
}

TEST(PoissonTest, NormalsAreEstimatedWhenMissing) {
  ColoredPoints cloud = Sphere(4000, 2);
  cloud.normals.clear();
  PoissonOptions options;
  options.depth = 5;
  options.trim_density_quantile = 0.0;
  options.threads = 1;  // tests run two at a time on two cores
  const Result<TriangleMesh> mesh = PoissonReconstruct(cloud, options);
  ASSERT_TRUE(mesh.ok()) << mesh.status().ToString();
  double worst = 0;
  for (const auto& v : mesh->vertices) worst = std::max(worst, std::abs((v - kCentre).norm() - kRadius));
  EXPECT_LT(worst, 2.0);  // inward-flipped normals would give a garbage surface, far off the sphere
}

TEST(PoissonTest, BadInput) {
  PoissonOptions options;
  EXPECT_EQ(PoissonReconstruct(Sphere(50, 3), options).status().code(), StatusCode::kInvalidArgument);
  ColoredPoints mismatched = Sphere(500, 3);
  mismatched.colors.pop_back();
  EXPECT_EQ(PoissonReconstruct(mismatched, options).status().code(), StatusCode::kInvalidArgument);
  ColoredPoints nan = Sphere(500, 3);
  nan.points[7].x() = std::nan("");
  EXPECT_EQ(PoissonReconstruct(nan, options).status().code(), StatusCode::kInvalidArgument);
  options.depth = 20;
  EXPECT_EQ(PoissonReconstruct(Sphere(500, 3), options).status().code(), StatusCode::kInvalidArgument);
}

TriangleMesh Tetrahedron() {
  TriangleMesh mesh;
  mesh.vertices = {{0, 0, 0}, {10, 0, 0}, {0, 10, 0}, {0, 0, 10}};
  mesh.vertex_colors = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {1, 1, 1}};
  mesh.triangles = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
  return mesh;
}

TEST(MeshIoTest, PlyRoundTripAndFormats) {
  rotoscan::testing::ScratchDir dir;
  const TriangleMesh mesh = Tetrahedron();
  ASSERT_TRUE(WriteMesh(dir / "t.ply", mesh).ok());
  const Result<TriangleMesh> back = ReadMesh(dir / "t.ply");
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ASSERT_EQ(back->vertices.size(), 4u);
  ASSERT_EQ(back->triangles.size(), 4u);
  EXPECT_NEAR(back->vertices[3].z(), 10.0, 1e-5);
  ASSERT_EQ(back->vertex_colors.size(), 4u);
  EXPECT_NEAR(back->vertex_colors[1].y(), 1.0, 1e-2);
  EXPECT_TRUE(WriteMesh(dir / "t.obj", mesh).ok());
  EXPECT_TRUE(WriteMesh(dir / "t.stl", mesh).ok());
  EXPECT_GT(std::filesystem::file_size(dir / "t.stl"), 84u);  // binary STL: header + count + 4 x 50 bytes
  EXPECT_EQ(WriteMesh(dir / "t.xyz", mesh).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(WriteMesh(dir / "e.ply", TriangleMesh{}).code(), StatusCode::kInvalidArgument);
  EXPECT_FALSE(std::filesystem::exists(dir / "e.ply"));
  EXPECT_EQ(ReadMesh(dir / "none.ply").status().code(), StatusCode::kNotFound);
}

// Every format written by us and read back by Open3D (tinygltf for .glb, its own PLY/OBJ/STL readers).
TEST(MeshIoTest, EveryFormatRoundTripsThroughOpen3d) {
  rotoscan::testing::ScratchDir dir;
  const TriangleMesh mesh = Tetrahedron();
  for (const char* ext : {".ply", ".obj", ".stl", ".glb"}) {
    SCOPED_TRACE(ext);
    const std::filesystem::path path = dir / (std::string("t") + ext);
    ASSERT_TRUE(WriteMesh(path, mesh).ok());
    const Result<TriangleMesh> back = ReadMesh(path);
    ASSERT_TRUE(back.ok()) << back.status().ToString();
    ASSERT_EQ(back->triangles.size(), 4u);
    // Every triangle comes back with its corners in order (STL repeats the vertices per face).
    for (std::size_t t = 0; t < 4; ++t) {
      for (int c = 0; c < 3; ++c) {
        EXPECT_LT((back->vertices[back->triangles[t][c]] - mesh.vertices[mesh.triangles[t][c]]).norm(), 1e-4);
      }
    }
    if (std::string(ext) != ".stl") {
      ASSERT_EQ(back->vertices.size(), 4u);
      ASSERT_EQ(back->vertex_colors.size(), 4u);
      for (std::size_t v = 0; v < 4; ++v) {  // the OBJ reader orders vertices by first use: match by place
        std::size_t same = 0;
        while (same < 3 && (mesh.vertices[same] - back->vertices[v]).norm() > 1e-4) ++same;
        EXPECT_LT((back->vertex_colors[v] - mesh.vertex_colors[same]).norm(), 1e-2) << v;
      }
    }
  }
}

TEST(MeshIoTest, GlbFollowsTheContainerLayout) {
  const Result<std::string> glb = EncodeGlb(Tetrahedron());
  ASSERT_TRUE(glb.ok());
  auto u32 = [&](std::size_t at) {
    uint32_t v = 0;
    for (int i = 0; i < 4; ++i) v |= static_cast<uint32_t>(static_cast<unsigned char>((*glb)[at + i])) << (8 * i);
    return v;
  };
  EXPECT_EQ(glb->substr(0, 4), "glTF");
  EXPECT_EQ(u32(4), 2u);
  EXPECT_EQ(u32(8), glb->size());
  const uint32_t json_length = u32(12);
  EXPECT_EQ(json_length % 4, 0u);
  EXPECT_EQ(u32(16), 0x4E4F534Au);
  const std::string json = glb->substr(20, json_length);
  EXPECT_NE(json.find("\"COLOR_0\":2"), std::string::npos);
  EXPECT_NE(json.find("\"max\":[0.00999999978,0.00999999978,0]"), std::string::npos) << json;  // x, z, -y in m
  const uint32_t bin_length = u32(20 + json_length);
  EXPECT_EQ(u32(24 + json_length), 0x004E4942u);
  // Positions, normals, colors (4 x 12 bytes each) and 4 x 3 indices of 4 bytes.
  EXPECT_EQ(bin_length, 3u * 48 + 48);
  EXPECT_EQ(28 + json_length + bin_length, glb->size());
  EXPECT_EQ(EncodeGlb(TriangleMesh{}).status().code(), StatusCode::kInvalidArgument);
  TriangleMesh bad = Tetrahedron();
  bad.triangles[0][1] = 9;
  EXPECT_EQ(EncodeGlb(bad).status().code(), StatusCode::kInvalidArgument);
}

TEST(PreviewTest, SheetHasFourViews) {
  ColoredPoints cloud = Sphere(20000, 6);
  cloud.views = cloud.normals;
  FusionOptions options;
  options.voxel_mm = 2.0;
  options.flat_bottom = false;
  const Result<TriangleMesh> mesh = FuseSurface(cloud, options);
  ASSERT_TRUE(mesh.ok());
  PreviewOptions view;
  view.width = 80;
  view.height = 60;
  for (const Result<cv::Mat>& sheet : {RenderPreviewSheet(*mesh, view), RenderPointPreviewSheet(cloud, view)}) {
    ASSERT_TRUE(sheet.ok()) << sheet.status().ToString();
    ASSERT_EQ(sheet->cols, 160);
    ASSERT_EQ(sheet->rows, 120);
    for (int i = 0; i < 4; ++i) {  // the object in the middle of every view
      EXPECT_FALSE(sheet->at<cv::Vec3b>(30 + 60 * (i / 2), 40 + 80 * (i % 2)) == cv::Vec3b(38, 32, 30)) << i;
    }
  }
}

TEST(ReportTest, Base64MatchesRfc4648AndTheReportEmbedsPictures) {
  // RFC 4648 section 10 test vectors.
  EXPECT_EQ(Base64(""), "");
  EXPECT_EQ(Base64("f"), "Zg==");
  EXPECT_EQ(Base64("fo"), "Zm8=");
  EXPECT_EQ(Base64("foo"), "Zm9v");
  EXPECT_EQ(Base64("foob"), "Zm9vYg==");
  EXPECT_EQ(Base64("fooba"), "Zm9vYmE=");
  EXPECT_EQ(Base64("foobar"), "Zm9vYmFy");
  ScanReport report;
  report.figures.emplace_back("points <left>", "12");
  report.pictures.push_back({"a picture", cv::Mat(8, 8, CV_8UC3, cv::Scalar(1, 2, 3)), {}});
  report.sections.push_back({"stage", "a & b"});
  const Result<std::string> html = ReportHtml(report);
  ASSERT_TRUE(html.ok());
  EXPECT_NE(html->find("points &lt;left&gt;"), std::string::npos);
  EXPECT_NE(html->find("a &amp; b"), std::string::npos);
  EXPECT_NE(html->find("src=\"data:image/png;base64,iVBORw0KGgo"), std::string::npos);  // the PNG signature
  report.pictures.push_back({"empty", cv::Mat(), {}});
  EXPECT_EQ(ReportHtml(report).status().code(), StatusCode::kInvalidArgument);
}

TEST(PreviewTest, MeshFillsTheMiddleAndLeavesTheCorners) {
  PoissonOptions options;
  options.depth = 5;
  options.trim_density_quantile = 0.0;
  options.threads = 1;  // tests run two at a time on two cores
  const Result<TriangleMesh> mesh = PoissonReconstruct(Sphere(3000, 4), options);
  ASSERT_TRUE(mesh.ok());
  PreviewOptions view;
  view.width = 160;
  view.height = 120;
  view.elevation_deg = 60;  // looking down: the red top dominates the middle
  const Result<cv::Mat> image = RenderPreview(*mesh, view);
  ASSERT_TRUE(image.ok()) << image.status().ToString();
  ASSERT_EQ(image->cols, 160);
  const cv::Vec3b centre = image->at<cv::Vec3b>(60, 80);
  EXPECT_GT(centre[2], 2 * centre[0]) << "expected red in BGR, got " << cv::Mat(centre).t();
  EXPECT_TRUE(image->at<cv::Vec3b>(0, 0) == cv::Vec3b(38, 32, 30));
  // Framing fits the bounding box's sphere (radius sqrt(3) R) in the frame's height: the sphere's disc has
  // a radius of about 60 px / sqrt(3) * 0.95 = 33 px, so ~3,400 pixels.
  cv::Mat channels[3];
  cv::split(*image, channels);
  const int covered = cv::countNonZero(channels[2] != 30);
  EXPECT_GT(covered, 2800);
  EXPECT_LT(covered, 4200);
  rotoscan::testing::ScratchDir dir;
  ASSERT_TRUE(WritePng(dir / "p.png", *image).ok());
  EXPECT_GT(std::filesystem::file_size(dir / "p.png"), 100u);
}

TEST(PreviewTest, PointsAndBadOptions) {
  PreviewOptions view;
  view.width = 100;
  view.height = 100;
  const Result<cv::Mat> image = RenderPointPreview(Sphere(20000, 5), view);
  ASSERT_TRUE(image.ok());
  EXPECT_FALSE(image->at<cv::Vec3b>(50, 50) == cv::Vec3b(38, 32, 30));
  view.width = 2;
  EXPECT_EQ(RenderPointPreview(Sphere(10, 5), view).status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(RenderPreview(TriangleMesh{}, PreviewOptions{}).status().code(), StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace rotoscan::mesh
