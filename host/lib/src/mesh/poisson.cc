#include <algorithm>
#include <chrono>
#include <limits>
#include <memory>
#include <string>
#include <thread>

#include <open3d/geometry/KDTreeSearchParam.h>
#include <open3d/geometry/PointCloud.h>
#include <open3d/geometry/TriangleMesh.h>
#include <open3d/io/TriangleMeshIO.h>
#include <open3d/utility/Logging.h>

#include "rotoscan/core/file.h"
#include "rotoscan/core/logging.h"
#include "rotoscan/mesh/mesh.h"

namespace rotoscan::mesh {
namespace fs = std::filesystem;

Status PoissonOptions::Check() const {
  if (depth < 4 || depth > 12)
    return InvalidArgumentError("Poisson depth must be in 4..12, got " + std::to_string(depth));
  if (!(trim_density_quantile >= 0 && trim_density_quantile < 1)) {  // NaN too
    return InvalidArgumentError("trim_density_quantile must be in [0, 1)");
  }
  if (normal_neighbours < 3) return InvalidArgumentError("normal_neighbours must be >= 3");
  if (threads < 0) return InvalidArgumentError("threads must be >= 0");
  return Status::Ok();
}

ColoredPoints ToColoredPoints(const cloud::PointCloud& cloud) {
  ColoredPoints out;
  out.points.reserve(cloud.size());
  out.normals.reserve(cloud.size());
  out.colors.reserve(cloud.size());
  for (const cloud::CloudPoint& p : cloud.points) {
    out.points.push_back(p.position_in_table.cast<double>());
    out.normals.push_back(p.normal.cast<double>());
    out.colors.emplace_back(p.color[0] / 255.0, p.color[1] / 255.0, p.color[2] / 255.0);
    out.quality.push_back(p.quality);
  }
  if (cloud.scan.known) {
    out.step_rad = cloud.scan.step_rad;
    out.views.reserve(cloud.size());
    std::vector<int32_t> steps;
    for (const cloud::CloudPoint& p : cloud.points) {
      const Eigen::Vector3d to_camera =
          cloud.scan.CameraAt(p.placement, p.step) - p.position_in_table.cast<double>();
      out.views.push_back(to_camera.norm() > 0 ? to_camera.normalized() : Eigen::Vector3d::Zero());
      // The cameras over the table top: the first placement's (a merged cloud's frame is its table).
      if (p.placement == 0 && (steps.empty() || steps.back() != p.step)) steps.push_back(p.step);
    }
    std::sort(steps.begin(), steps.end());
    steps.erase(std::unique(steps.begin(), steps.end()), steps.end());
    for (int32_t step : steps) out.cameras.push_back(cloud.scan.CameraAtStep(step));
  }
  return out;
}

namespace {

TriangleMesh FromOpen3d(const open3d::geometry::TriangleMesh& in) {
  TriangleMesh out;
  out.vertices = in.vertices_;
  out.vertex_colors = in.vertex_colors_;
  out.triangles.reserve(in.triangles_.size());
  for (const auto& t : in.triangles_) out.triangles.emplace_back(t.x(), t.y(), t.z());
  return out;
}

open3d::geometry::TriangleMesh ToOpen3d(const TriangleMesh& in) {
  open3d::geometry::TriangleMesh out;
  out.vertices_ = in.vertices;
  out.vertex_colors_ = in.vertex_colors;
  out.triangles_.reserve(in.triangles.size());
  for (const auto& t : in.triangles) out.triangles_.emplace_back(t.x(), t.y(), t.z());
  return out;
}

struct QuietOpen3d {
  QuietOpen3d() { open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error); }
};

}  // namespace

Status CheckCloudExtent(const ColoredPoints& cloud) {
  const std::size_t n = cloud.points.size();
  Eigen::Vector3d low = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d high = -low;
  for (const auto& p : cloud.points) {
    if (!p.allFinite()) return InvalidArgumentError("point cloud holds a non-finite point");
    low = low.cwiseMin(p);
    high = high.cwiseMax(p);
  }
  // Open3D's Poisson divides by the cloud's extent (and fusion's volume is sized from it): a cloud without one (identical points, or points apart
  // only at denormal scale) crashes it, and a cloud flat along an axis gives a surface of absurd size.
  const Eigen::Vector3d extent = high - low;
  const double largest = extent.maxCoeff();
  const double magnitude = std::max({1.0, low.cwiseAbs().maxCoeff(), high.cwiseAbs().maxCoeff()});
  if (!(largest > 1e-9 * magnitude) || !(largest > 1e-6)) {
    return InvalidArgumentError("the cloud has no extent: its " + std::to_string(n) +
                                " points lie within " + std::to_string(largest) + " mm of each other");
  }
  Eigen::Index flat_axis = 0;
  if (!(extent.minCoeff(&flat_axis) > 1e-6 * largest)) {
    return InvalidArgumentError(std::string("the cloud is flat: its points all lie in one plane along ") +
                                "xyz"[flat_axis] + " (meshing needs a surface around a volume)");
  }
  return Status::Ok();
}

Result<TriangleMesh> PoissonReconstruct(const ColoredPoints& cloud, const PoissonOptions& options,
                                        PoissonSummary* summary, Progress* progress) {
  static QuietOpen3d quiet;
  ROTOSCAN_RETURN_IF_ERROR(options.Check());
  const std::size_t n = cloud.points.size();
  if (n < 100)
    return InvalidArgumentError("Poisson meshing needs at least 100 points, got " + std::to_string(n));
  if ((!cloud.normals.empty() && cloud.normals.size() != n) ||
      (!cloud.colors.empty() && cloud.colors.size() != n)) {
    return InvalidArgumentError("point cloud arrays differ in length (points, normals, colors)");
  }
  ROTOSCAN_RETURN_IF_ERROR(CheckCloudExtent(cloud));
  Eigen::Vector3d low = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d high = -low;
  for (const auto& p : cloud.points) {
    low = low.cwiseMin(p);
    high = high.cwiseMax(p);
  }
  const double largest = (high - low).maxCoeff();
  ProgressScope scope(progress, "mesh", 3);
  const auto start = std::chrono::steady_clock::now();

  open3d::geometry::PointCloud pcd;
  pcd.points_ = cloud.points;
  pcd.colors_ = cloud.colors;
  bool need_normals = cloud.normals.empty();
  if (!need_normals) {
    pcd.normals_ = cloud.normals;
    for (const auto& normal : cloud.normals) {
      if (!(normal.squaredNorm() > 0.25)) {
        need_normals = true;
        break;
      }
    }
  }
  if (need_normals) {
    // Orient estimated normals away from the cloud's centroid axis: right for a turntable object.
    pcd.EstimateNormals(open3d::geometry::KDTreeSearchParamKNN(options.normal_neighbours));
    Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
    for (const auto& p : pcd.points_) centroid += p;
    centroid /= static_cast<double>(n);
    for (std::size_t i = 0; i < n; ++i) {
      Eigen::Vector3d outward = pcd.points_[i] - centroid;
      outward.z() = 0;  // away from the vertical axis
      if (pcd.normals_[i].dot(outward) < 0) pcd.normals_[i] = -pcd.normals_[i];
    }
  }
  scope.Advance();

  const int threads = options.threads > 0
                          ? options.threads
                          : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  auto [o3d_mesh, densities] = open3d::geometry::TriangleMesh::CreateFromPointCloudPoisson(
      pcd, static_cast<size_t>(options.depth), 0.0f, 1.1f, false, threads);
  scope.Advance();
  if (!o3d_mesh || o3d_mesh->triangles_.empty())
    return NotConvergedError("Poisson reconstruction produced no surface");
  // The surface lies within the cloud's box grown by Open3D's scale (1.1): anything beyond is a failed solve.
  for (const auto& v : o3d_mesh->vertices_) {
    if (!v.allFinite() || ((v - low).array() < -largest).any() || ((v - high).array() > largest).any()) {
      return NotConvergedError("Poisson reconstruction produced a surface outside the cloud's extent");
    }
  }
  const std::size_t before = o3d_mesh->vertices_.size();
  if (options.trim_density_quantile > 0 && !densities.empty()) {
    std::vector<double> sorted = densities;
    const auto k =
        static_cast<std::ptrdiff_t>(options.trim_density_quantile * static_cast<double>(sorted.size()));
    std::nth_element(sorted.begin(), sorted.begin() + k, sorted.end());
    const double threshold = sorted[static_cast<std::size_t>(k)];
    std::vector<bool> remove(densities.size());
    for (std::size_t i = 0; i < densities.size(); ++i) remove[i] = densities[i] < threshold;
    o3d_mesh->RemoveVerticesByMask(remove);
  }
  scope.Advance();
  if (summary != nullptr) {
    summary->input_points = n;
    summary->vertices_before_trim = before;
    summary->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  }
  ROTOSCAN_LOG(kDebug) << "Poisson depth " << options.depth << ": " << n << " points -> "
                       << o3d_mesh->vertices_.size() << " vertices, " << o3d_mesh->triangles_.size()
                       << " triangles";
  return FromOpen3d(*o3d_mesh);
}

Status CheckMeshPath(const fs::path& path) {
  const std::string ext = path.extension().string();
  if (ext != ".ply" && ext != ".obj" && ext != ".stl" && ext != ".glb") {
    return InvalidArgumentError("mesh file " + path.string() + ": extension must be .ply, .obj, .stl or .glb");
  }
  return Status::Ok();
}

std::vector<fs::path> MeshFilePaths(const fs::path& path, const TriangleMesh* mesh) {
  std::vector<fs::path> paths = {path};
  if (path.extension() == ".obj" && (mesh == nullptr || !mesh->vertex_colors.empty())) {
    const fs::path stem = path.parent_path() / path.stem();
    paths.push_back(fs::path(stem.string() + ".mtl"));
    paths.push_back(fs::path(stem.string() + "_texture.png"));
  }
  return paths;
}

Result<std::vector<PendingFile>> MeshFiles(const fs::path& path, const TriangleMesh& mesh) {
  static QuietOpen3d quiet;
  ROTOSCAN_RETURN_IF_ERROR(CheckMeshPath(path));
  const std::string ext = path.extension().string();
  if (mesh.vertices.empty() || mesh.triangles.empty())
    return InvalidArgumentError("refusing to write an empty mesh");
  if (ext == ".glb") {
    ROTOSCAN_ASSIGN_OR_RETURN(std::string bytes, EncodeGlb(mesh));
    return std::vector<PendingFile>{FileWithContent(path, std::move(bytes))};
  }
  if (ext == ".obj") {
    const std::vector<fs::path> paths = MeshFilePaths(path, &mesh);
    const std::string mtl = paths.size() > 1 ? paths[1].filename().string() : "";
    const std::string texture = paths.size() > 2 ? paths[2].filename().string() : "";
    ROTOSCAN_ASSIGN_OR_RETURN(ObjWithAtlas obj, EncodeObjWithAtlas(mesh, mtl, texture));
    std::vector<PendingFile> files = {FileWithContent(path, std::move(obj.obj))};
    if (paths.size() > 2) {
      files.push_back(FileWithContent(paths[1], std::move(obj.mtl)));
      ROTOSCAN_ASSIGN_OR_RETURN(PendingFile png, PngFile(paths[2], obj.texture));
      files.push_back(std::move(png));
    }
    return files;
  }
  auto o3d = std::make_shared<open3d::geometry::TriangleMesh>(ToOpen3d(mesh));
  if (ext == ".stl") o3d->ComputeTriangleNormals();
  const bool colors = !mesh.vertex_colors.empty();
  PendingFile file{path, [path, ext, o3d, colors](const fs::path& tmp) -> Status {
    // Open3D picks the format by extension: write beside with the real extension, then move into place.
    const fs::path with_ext = fs::path(tmp.string() + ext);
    const bool ok = open3d::io::WriteTriangleMesh(with_ext.string(), *o3d, /*write_ascii=*/false,
                                                  /*compressed=*/false, /*write_vertex_normals=*/false,
                                                  /*write_vertex_colors=*/colors,
                                                  /*write_triangle_uvs=*/false, /*print_progress=*/false);
    std::error_code ec;
    if (!ok) {
      fs::remove(with_ext, ec);
      return IoError("cannot write mesh " + path.string());
    }
    // Open3D does not report every failed write (a full disk truncates the file and it still says yes):
    // read the file back and compare before it may replace the target.
    open3d::geometry::TriangleMesh back;
    const bool read_back = open3d::io::ReadTriangleMesh(with_ext.string(), back);
    if (!read_back || back.triangles_.size() != o3d->triangles_.size() ||
        (ext != ".stl" && back.vertices_.size() != o3d->vertices_.size())) {
      fs::remove(with_ext, ec);
      return IoError("cannot write mesh " + path.string() + ": the file written is incomplete (disk full?)");
    }
    fs::rename(with_ext, tmp, ec);
    if (ec) return IoError("cannot move " + with_ext.string() + ": " + ec.message());
    return Status::Ok();
  }};
  return std::vector<PendingFile>{std::move(file)};
}

Status WriteMesh(const fs::path& path, const TriangleMesh& mesh) {
  ROTOSCAN_ASSIGN_OR_RETURN(std::vector<PendingFile> files, MeshFiles(path, mesh));
  return WriteFilesTogether(files);
}

Result<TriangleMesh> ReadMesh(const fs::path& path) {
  static QuietOpen3d quiet;
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) return NotFoundError("mesh file " + path.string() + " does not exist");
  open3d::geometry::TriangleMesh o3d;
  if (!open3d::io::ReadTriangleMesh(path.string(), o3d) || o3d.vertices_.empty()) {
    return CorruptDataError("cannot read a mesh from " + path.string());
  }
  if (path.extension() == ".glb" || path.extension() == ".gltf") {
    for (Eigen::Vector3d& v : o3d.vertices_) v = Eigen::Vector3d(v.x(), -v.z(), v.y()) * 1000.0;  // metres, +Y up
  }
  for (const auto& t : o3d.triangles_) {
    if ((t.array() < 0).any() || (t.array() >= static_cast<int>(o3d.vertices_.size())).any()) {
      return CorruptDataError(path.string() + ": a triangle indexes a vertex that does not exist");
    }
  }
  return FromOpen3d(o3d);
}

}  // namespace rotoscan::mesh
