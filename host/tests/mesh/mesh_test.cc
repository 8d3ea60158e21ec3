#include "rotoscan/mesh/mesh.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <random>

#include <open3d/geometry/Image.h>
#include <open3d/geometry/TriangleMesh.h>
#include <open3d/io/TriangleMeshIO.h>
#include <opencv2/core.hpp>

#include "rotoscan/core/file.h"
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

// Every edge shared by exactly two triangles, and the Euler characteristic V - E + F of the used vertices.
struct Topology {
  std::size_t edges_not_two = 0;
  long euler = 0;
};
Topology TopologyOf(const TriangleMesh& mesh) {
  std::map<std::pair<int, int>, int> count;
  std::vector<bool> used(mesh.vertices.size(), false);
  for (const Eigen::Vector3i& t : mesh.triangles) {
    for (int c = 0; c < 3; ++c) {
      ++count[std::minmax(t[c], t[(c + 1) % 3])];
      used[static_cast<std::size_t>(t[c])] = true;
    }
  }
  Topology topology;
  for (const auto& [edge, n] : count) topology.edges_not_two += n == 2 ? 0 : 1;
  const long vertices = std::count(used.begin(), used.end(), true);
  topology.euler = vertices - static_cast<long>(count.size()) + static_cast<long>(mesh.triangles.size());
  return topology;
}

// Median and 95th percentile of |value|.
std::pair<double, double> MedianP95(std::vector<double> values) {
  for (double& v : values) v = std::abs(v);
  std::sort(values.begin(), values.end());
  if (values.empty()) return {0, 0};
  return {values[values.size() / 2], values[std::min(values.size() - 1, values.size() * 95 / 100)]};
}

// Cameras on a circle of 300 mm around the table axis at height `z`, every 10 degrees.
std::vector<Eigen::Vector3d> CameraCircle(double z) {
  std::vector<Eigen::Vector3d> cameras;
  for (int s = 0; s < 36; ++s) {
    const double a = 2 * 3.14159265358979 * s / 36;
    cameras.emplace_back(300 * std::cos(a), 300 * std::sin(a), z);
  }
  return cameras;
}

// Each point seen from the camera of the circle nearest its azimuth (a turntable scan's geometry).
void SeeFromCameras(ColoredPoints* cloud, const std::vector<Eigen::Vector3d>& cameras) {
  cloud->cameras = cameras;
  cloud->views.clear();
  for (const Eigen::Vector3d& p : cloud->points) {
    const double a = std::atan2(p.y(), p.x());
    int s = static_cast<int>(std::lround(a / (2 * 3.14159265358979) * 36.0));
    s = ((s % 36) + 36) % 36;
    cloud->views.push_back((cameras[static_cast<std::size_t>(s)] - p).normalized());
  }
  cloud->step_rad = 2 * 3.14159265358979 / 36;
}

// A sphere floating above the table with a round hole (30 degrees about +x, ~20 mm across) that no laser
// reached: the open mesh has the hole, the watertight one is closed (genus 0) and as close to the true
// sphere where the points are.
TEST(FusionTest, WatertightClosesAHoleAndKeepsTheObservedSurface) {
  ColoredPoints cloud = Sphere(60000, 21);
  ColoredPoints holed;
  for (std::size_t i = 0; i < cloud.points.size(); ++i) {
    const Eigen::Vector3d d = (cloud.points[i] - kCentre).normalized();
    if (d.x() > std::cos(30 * 3.14159265358979 / 180)) continue;
    holed.points.push_back(cloud.points[i]);
    holed.normals.push_back(cloud.normals[i]);
    holed.colors.push_back(cloud.colors[i]);
  }
  SeeFromCameras(&holed, CameraCircle(kCentre.z()));
  FusionOptions options;
  options.voxel_mm = 1.0;
  const Result<TriangleMesh> open = FuseSurface(holed, options);
  options.watertight = true;
  FusionSummary summary;
  const Result<TriangleMesh> closed = FuseSurface(holed, options, &summary);
  ASSERT_TRUE(open.ok() && closed.ok()) << closed.status().ToString();
  EXPECT_GT(BoundaryEdges(*open), 50u);  // the hole
  const Topology topology = TopologyOf(*closed);
  EXPECT_EQ(topology.edges_not_two, 0u);
  EXPECT_EQ(topology.euler, 2);  // one closed surface of genus 0
  EXPECT_EQ(closed->vertex_colors.size(), closed->vertices.size());
  EXPECT_GT(summary.carved_point_rays, 10000u);
  EXPECT_GT(summary.carved_table_rays, 0u);
  EXPECT_GT(summary.observed_vertex_fraction, 0.85);  // the hole is 6.7 % of the sphere
  // On the observed part (more than 40 degrees from the hole's centre: 10 degrees from its rim, where the
  // fill meets the surface): radial error against the truth.
  auto errors = [](const TriangleMesh& mesh, bool observed) {
    std::vector<double> e;
    for (const Eigen::Vector3d& v : mesh.vertices) {
      const Eigen::Vector3d d = v - kCentre;
      const bool in_hole = d.normalized().x() > std::cos((observed ? 40 : 30) * 3.14159265358979 / 180);
      if (in_hole != observed) e.push_back(d.norm() - kRadius);
    }
    return e;
  };
  const auto [open_median, open_p95] = MedianP95(errors(*open, true));
  const auto [closed_median, closed_p95] = MedianP95(errors(*closed, true));
  EXPECT_LT(closed_median, open_median + 0.01);
  EXPECT_LT(closed_p95, open_p95 + 0.02);
  // The filled hole is there, and no farther from the sphere than the cap's height (5.36 mm: how far a
  // flat patch across the rim would be at its centre); nothing invents surface beyond it.
  const std::vector<double> fill = errors(*closed, false);
  EXPECT_GT(fill.size(), 100u);
  const auto [fill_median, fill_p95] = MedianP95(fill);
  const double sagitta = kRadius * (1 - std::cos(30 * 3.14159265358979 / 180));
  EXPECT_LT(fill_median, 1.0);
  EXPECT_LT(fill_p95, 0.75 * sagitta);
  for (double e : fill) EXPECT_LT(std::abs(e), sagitta) << "a fill vertex";
  const double true_volume = 4.0 / 3.0 * 3.14159265358979 * kRadius * kRadius * kRadius;
  EXPECT_NEAR(SignedVolume(*closed) / true_volume, 1.0, 0.02);
}

// A can with no lid standing on the table: the flat bottom closes the bottom, the watertight surface the
// top; closed and of genus 0.
TEST(FusionTest, WatertightCanOnTheTableIsClosed) {
  constexpr double kCanRadius = 20, kHeight = 30;
  ColoredPoints cloud;
  for (int i = 0; i < 400; ++i) {
    const double a = 2 * 3.14159265358979 * i / 400;
    const Eigen::Vector3d radial(std::cos(a), std::sin(a), 0);
    for (double z = 0.1; z < kHeight; z += 0.25) {
      cloud.points.push_back(kCanRadius * radial + Eigen::Vector3d(0, 0, z));
      cloud.normals.push_back(radial);
    }
  }
  SeeFromCameras(&cloud, CameraCircle(60));
  FusionOptions options;
  options.voxel_mm = 1.0;
  options.watertight = true;
  const Result<TriangleMesh> closed = FuseSurface(cloud, options);
  ASSERT_TRUE(closed.ok()) << closed.status().ToString();
  const Topology topology = TopologyOf(*closed);
  EXPECT_EQ(topology.edges_not_two, 0u);
  EXPECT_EQ(topology.euler, 2);
  double lowest = 1e9, highest = -1e9;
  for (const auto& v : closed->vertices) {
    lowest = std::min(lowest, v.z());
    highest = std::max(highest, v.z());
  }
  EXPECT_NEAR(lowest, 0.0, 0.3);
  EXPECT_NEAR(highest, kHeight, 4.0);  // the lid is invented: near the rim, not on it
  const double volume = 3.14159265358979 * kCanRadius * kCanRadius * kHeight;
  EXPECT_NEAR(SignedVolume(*closed) / volume, 1.0, 0.1);
  // Without the cameras there is nothing to carve with: a clear error.
  ColoredPoints blind = cloud;
  blind.views.clear();
  EXPECT_EQ(FuseSurface(blind, options).status().code(), StatusCode::kInvalidArgument);
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

// A thin plate: two sheets 0.6 mm apart (closer than the color radius), the front (+z) red for x < 0 and
// green for x > 0, the back blue; the front's points are missing over 2 < x < 7 (a hole the mesh closes).
TEST(VertexColorTest, FromThePointsOnTheVertexsSideAndHolesFromNeighbours) {
  const Eigen::Vector3d red(0.9, 0.1, 0.1), green(0.1, 0.8, 0.2), blue(0.1, 0.1, 0.9);
  auto front_color = [&](double x) { return x < 0 ? red : green; };
  TriangleMesh mesh;
  const int side = 41;  // vertices every 0.5 mm over 20 x 20 mm
  for (const double z : {0.3, -0.3}) {
    for (int j = 0; j < side; ++j) {
      for (int i = 0; i < side; ++i) mesh.vertices.emplace_back(-10 + 0.5 * i, -10 + 0.5 * j, z);
    }
  }
  for (int sheet = 0; sheet < 2; ++sheet) {
    const int base = sheet * side * side;
    for (int j = 0; j + 1 < side; ++j) {
      for (int i = 0; i + 1 < side; ++i) {
        const int a = base + j * side + i, b = a + 1, c = a + side, d = c + 1;
        if (sheet == 0) {  // counter-clockwise seen from +z
          mesh.triangles.emplace_back(a, b, d);
          mesh.triangles.emplace_back(a, d, c);
        } else {  // seen from -z
          mesh.triangles.emplace_back(a, d, b);
          mesh.triangles.emplace_back(a, c, d);
        }
      }
    }
  }
  mesh.vertex_colors.assign(mesh.vertices.size(), Eigen::Vector3d::Constant(0.5));
  ColoredPoints cloud;
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-10.5, 10.5);
  for (int k = 0; k < 40000; ++k) {
    const double x = u(rng), y = u(rng);
    if (k % 2 == 0) {
      if (x > 2 && x < 7) continue;
      cloud.points.emplace_back(x, y, 0.3 + 0.01 * std::sin(7 * x));
      cloud.normals.emplace_back(0, 0, 1);
      cloud.colors.push_back(front_color(x));
    } else {
      cloud.points.emplace_back(x, y, -0.3);
      cloud.normals.emplace_back(0, 0, -1);
      cloud.colors.push_back(blue);
    }
  }
  VertexColorSummary summary;
  ASSERT_TRUE(ColorVerticesFromPoints(cloud, 1.0, &mesh, &summary).ok());
  size_t front = 0, back = 0, hole = 0;
  for (size_t v = 0; v < mesh.vertices.size(); ++v) {
    const Eigen::Vector3d& p = mesh.vertices[v];
    const Eigen::Vector3d& c = mesh.vertex_colors[v];
    if (p.z() < 0) {  // no bleeding from the front sheet 0.6 mm away
      EXPECT_LT((c - blue).cwiseAbs().maxCoeff(), 1e-9) << p.transpose();
      ++back;
    } else if (std::abs(p.x()) > 1.0 && !(p.x() > 1.5 && p.x() < 7.5)) {  // away from the edge and the hole
      EXPECT_LT((c - front_color(p.x())).cwiseAbs().maxCoeff(), 1e-9) << p.transpose();
      ++front;
    } else if (p.x() > 3.2 && p.x() < 5.8) {  // more than 1 mm into the hole: from the green around it
      EXPECT_LT((c - green).cwiseAbs().maxCoeff(), 1e-9) << p.transpose();
      ++hole;
    }
  }
  EXPECT_EQ(back, size_t{side * side});
  EXPECT_GT(front, 1000u);
  EXPECT_EQ(hole, size_t{5 * side});
  EXPECT_GE(summary.from_neighbours, hole);
  EXPECT_GE(summary.rings, 2);
  EXPECT_EQ(summary.from_points + summary.from_neighbours, mesh.vertices.size());

  ColoredPoints mismatched = cloud;
  mismatched.colors.resize(10);
  EXPECT_EQ(ColorVerticesFromPoints(mismatched, 1.0, &mesh).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(ColorVerticesFromPoints(cloud, 0.0, &mesh).code(), StatusCode::kInvalidArgument);
  TriangleMesh broken = mesh;
  broken.triangles.emplace_back(0, 1, static_cast<int>(broken.vertices.size()));
  EXPECT_EQ(ColorVerticesFromPoints(cloud, 1.0, &broken).code(), StatusCode::kInvalidArgument);
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
      // The OBJ has UVs per corner, so Open3D's reader makes one vertex per (position, UV): 12 here.
      ASSERT_EQ(back->vertices.size(), std::string(ext) == ".obj" ? 12u : 4u);
      ASSERT_EQ(back->vertex_colors.size(), back->vertices.size());
      for (std::size_t v = 0; v < back->vertices.size(); ++v) {  // vertices in order of first use: match by place
        std::size_t same = 0;
        while (same < 3 && (mesh.vertices[same] - back->vertices[v]).norm() > 1e-4) ++same;
        EXPECT_LT((back->vertex_colors[v] - mesh.vertex_colors[same]).norm(), 1e-2) << v;
      }
    }
  }
}

// The OBJ's texture atlas, read back by Open3D (tinyobjloader and its image reader): every corner's UV
// samples its vertex's color, and bilinear sampling inside a triangle gives the linear blend of its three
// vertex colors (what a viewer shows), within a level of 8-bit rounding.
TEST(MeshIoTest, ObjTextureAtlasReadsBackInOpen3d) {
  rotoscan::testing::ScratchDir dir;
  TriangleMesh mesh;  // 300 separate triangles with varied colors
  for (int k = 0; k < 300; ++k) {
    const double a = 0.02 * k;
    const int base = static_cast<int>(mesh.vertices.size());
    mesh.vertices.emplace_back(std::cos(a) * 20, std::sin(a) * 20, k * 0.1);
    mesh.vertices.emplace_back(std::cos(a + 0.3) * 20, std::sin(a + 0.3) * 20, k * 0.1 + 1);
    mesh.vertices.emplace_back(0, 0, k * 0.1 + 2);
    // Chosen so that c1 + c2 - c0 stays in 0..1 (no clamping: the blend is exact up to rounding).
    mesh.vertex_colors.emplace_back(0.3 + 0.2 * std::sin(a), 0.2, 0.5);
    mesh.vertex_colors.emplace_back(0.1, 0.5 + 0.4 * std::cos(a), 0.3);
    mesh.vertex_colors.emplace_back(0.7, 0.3, 0.2 + 0.5 * std::fmod(a, 1.0));
    mesh.triangles.emplace_back(base, base + 1, base + 2);
  }
  ASSERT_TRUE(WriteMesh(dir / "m.obj", mesh).ok());
  // The first triangle sits in the atlas's top-left cell: in the file its v is near 1 (v up).
  const Result<std::string> text = ReadFile(dir / "m.obj");
  ASSERT_TRUE(text.ok());
  const std::size_t vt = text->find("\nvt ");
  ASSERT_NE(vt, std::string::npos);
  double u0 = 0, v0 = 0;
  ASSERT_EQ(std::sscanf(text->c_str() + vt, "\nvt %lf %lf", &u0, &v0), 2);
  EXPECT_LT(u0, 0.5);
  EXPECT_GT(v0, 0.5);
  EXPECT_NE(text->find("mtllib m.mtl"), std::string::npos);
  EXPECT_NE(ReadFile(dir / "m.mtl")->find("map_Kd m_texture.png"), std::string::npos);
  EXPECT_TRUE(std::filesystem::exists(dir / "m.mtl"));
  EXPECT_TRUE(std::filesystem::exists(dir / "m_texture.png"));
  open3d::geometry::TriangleMesh o3d;
  ASSERT_TRUE(open3d::io::ReadTriangleMesh((dir / "m.obj").string(), o3d));
  ASSERT_EQ(o3d.triangles_.size(), mesh.triangles.size());
  ASSERT_EQ(o3d.triangle_uvs_.size(), 3 * mesh.triangles.size());
  ASSERT_FALSE(o3d.textures_.empty());
  // Open3D keeps an empty texture first for "no material"; the triangles name ours.
  ASSERT_EQ(o3d.triangle_material_ids_.size(), mesh.triangles.size());
  const int material = o3d.triangle_material_ids_[0];
  ASSERT_TRUE(material >= 0 && static_cast<std::size_t>(material) < o3d.textures_.size());
  const open3d::geometry::Image& texture = o3d.textures_[static_cast<std::size_t>(material)];
  ASSERT_EQ(texture.num_of_channels_, 3);
  ASSERT_EQ(texture.bytes_per_channel_, 1);
  // Bilinear sample (u, v), RGB 0..255. The file's v runs up from the image's bottom row (OBJ's convention,
  // Blender's and MeshLab's); Open3D's reader turns it into image rows from the top (v' = 1 - v).
  auto sample = [&](const Eigen::Vector2d& uv) {
    const double x = uv.x() * texture.width_ - 0.5, y = uv.y() * texture.height_ - 0.5;
    const int x0 = static_cast<int>(std::floor(x)), y0 = static_cast<int>(std::floor(y));
    const double fx = x - x0, fy = y - y0;
    Eigen::Vector3d rgb = Eigen::Vector3d::Zero();
    for (int dy = 0; dy <= 1; ++dy) {
      for (int dx = 0; dx <= 1; ++dx) {
        const double w = (dx ? fx : 1 - fx) * (dy ? fy : 1 - fy);
        const uint8_t* px = texture.PointerAt<uint8_t>(std::clamp(x0 + dx, 0, texture.width_ - 1),
                                                       std::clamp(y0 + dy, 0, texture.height_ - 1), 0);
        rgb += w * Eigen::Vector3d(px[0], px[1], px[2]);
      }
    }
    return rgb;
  };
  double worst = 0;
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    const Eigen::Vector3i& tri = mesh.triangles[t];
    const Eigen::Vector2d uv[3] = {o3d.triangle_uvs_[3 * t], o3d.triangle_uvs_[3 * t + 1], o3d.triangle_uvs_[3 * t + 2]};
    for (const Eigen::Vector3d& w : {Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(0, 1, 0), Eigen::Vector3d(0, 0, 1),
                                     Eigen::Vector3d(1.0 / 3, 1.0 / 3, 1.0 / 3), Eigen::Vector3d(0.6, 0.3, 0.1)}) {
      const Eigen::Vector2d at = w[0] * uv[0] + w[1] * uv[1] + w[2] * uv[2];
      const Eigen::Vector3d expected = 255.0 * (w[0] * mesh.vertex_colors[static_cast<std::size_t>(tri[0])] +
                                                w[1] * mesh.vertex_colors[static_cast<std::size_t>(tri[1])] +
                                                w[2] * mesh.vertex_colors[static_cast<std::size_t>(tri[2])]);
      worst = std::max(worst, (sample(at) - expected).cwiseAbs().maxCoeff());
    }
  }
  EXPECT_LT(worst, 1.5);  // the 8-bit rounding of the texels
  // A mesh without colors is a plain OBJ: no material, no texture.
  TriangleMesh plain = Tetrahedron();
  plain.vertex_colors.clear();
  ASSERT_TRUE(WriteMesh(dir / "p.obj", plain).ok());
  EXPECT_FALSE(std::filesystem::exists(dir / "p.mtl"));
  EXPECT_FALSE(std::filesystem::exists(dir / "p_texture.png"));
  EXPECT_EQ(MeshFilePaths(dir / "p.obj", &plain).size(), 1u);
  EXPECT_EQ(MeshFilePaths(dir / "m.obj").size(), 3u);
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
