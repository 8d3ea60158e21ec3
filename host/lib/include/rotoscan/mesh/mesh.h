// Meshing of a colored point cloud and a preview picture of the result.
//
// Surface reconstruction is screened Poisson (Kazhdan, Bolitho & Hoppe; the paper's Fig. 10c/11c used
// MeshLab's), through Open3D, which also interpolates the vertex colors. Poisson closes every surface, so the
// parts it invents far from any sample (the "balloon" under an open bottom) are trimmed by dropping the
// vertices of lowest sample density. Open3D stays inside this module's .cc files: the API uses Eigen only.
#pragma once

#include <cstdint>
#include <filesystem>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core/mat.hpp>

#include "rotoscan/cloud/cloud.h"
#include "rotoscan/core/progress.h"
#include "rotoscan/core/status.h"

namespace rotoscan::mesh {

// Points in mm with unit normals (zero normals are estimated) and colors in [0, 1].
struct ColoredPoints {
  std::vector<Eigen::Vector3d> points;
  std::vector<Eigen::Vector3d> normals;  // empty, or one per point
  std::vector<Eigen::Vector3d> colors;   // empty, or one per point (RGB)
};

// A scan's cloud as meshing input: positions, normals (zero ones are estimated) and colors.
ColoredPoints ToColoredPoints(const cloud::PointCloud& cloud);

struct TriangleMesh {
  std::vector<Eigen::Vector3d> vertices;       // mm
  std::vector<Eigen::Vector3d> vertex_colors;  // RGB in [0, 1]; empty if none
  std::vector<Eigen::Vector3i> triangles;      // counter-clockwise seen from outside
};

struct PoissonOptions {
  int depth = 9;                        // octree depth (9: ~0.3 mm cells on a 150 mm object)
  double trim_density_quantile = 0.02;  // drop vertices below this quantile of sample density
  int normal_neighbours = 30;           // for normal estimation when the input has none
  int threads = 0;                      // 0: all cores
  Status Check() const;
};

struct PoissonSummary {
  std::size_t input_points = 0;
  std::size_t vertices_before_trim = 0;
  double seconds = 0.0;
};

// Poisson surface of `cloud`. kInvalidArgument for fewer than 100 points or inconsistent arrays.
Result<TriangleMesh> PoissonReconstruct(const ColoredPoints& cloud, const PoissonOptions& options,
                                        PoissonSummary* summary = nullptr, Progress* progress = nullptr);

// Writes .ply (binary, vertex colors), .obj or .stl by the extension of `path`, atomically.
// kInvalidArgument unless `path` ends in .ply, .obj or .stl (checked before any work).
Status CheckMeshPath(const std::filesystem::path& path);
Status WriteMesh(const std::filesystem::path& path, const TriangleMesh& mesh);
Result<TriangleMesh> ReadMesh(const std::filesystem::path& path);

struct PreviewOptions {
  int width = 960;
  int height = 720;
  double azimuth_deg = 30.0;    // view direction about the z (up) axis
  double elevation_deg = 20.0;  // above the horizontal
  double fov_deg = 30.0;
  Eigen::Vector3d up = Eigen::Vector3d::UnitZ();  // the model's up axis (table frame: z)
  Status Check() const;
};

// A shaded, colored picture of `mesh` (BGR, 8-bit) framed to fit, on a dark background: the quick look a
// person wants after a scan. A headlight Lambert term times the vertex color.
Result<cv::Mat> RenderPreview(const TriangleMesh& mesh, const PreviewOptions& options);

// The same for a point cloud (splats of one pixel, nearest wins).
Result<cv::Mat> RenderPointPreview(const ColoredPoints& cloud, const PreviewOptions& options);

// Encodes `image` as PNG and writes it atomically.
Status WritePng(const std::filesystem::path& path, const cv::Mat& image);

}  // namespace rotoscan::mesh
