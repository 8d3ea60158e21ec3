// rotoscan mesh: a colored point cloud (cloud.ply) to a mesh with vertex colors (range-scan fusion by
// default, or Poisson) and a preview PNG.
#include <cstdio>
#include <ostream>

#include "command.h"
#include "rotoscan/core/file.h"
#include "rotoscan/cloud/cloud.h"
#include "rotoscan/mesh/mesh.h"

namespace rotoscan::cli {

struct MeshOptions {
  std::string cloud_path;
  std::string out_path = "mesh.ply";
  std::string preview_path;  // empty: <out without extension>.png
  std::string cloud_preview_path;  // empty: none
  std::string method = "fusion";
  double voxel = 0.5;
  bool open_bottom = false;
  bool watertight = false;
  int depth = 9;
  double trim = 0.02;
  int threads = 0;
};

Status RunMeshCommand(const MeshOptions& options, const Context& context) {
  // Every option is checked before any work, whichever method uses it (NaN passes CLI11's range check).
  if (!(options.trim >= 0.0 && options.trim <= 0.5))
    return InvalidArgumentError("--trim must be in [0, 0.5], got " + std::to_string(options.trim));
  if (options.watertight && options.method != "fusion")
    return InvalidArgumentError("--watertight is an option of --method fusion (Poisson's surface is closed already)");
  std::filesystem::path preview = options.preview_path;
  if (preview.empty()) preview = std::filesystem::path(options.out_path).replace_extension(".png");
  ROTOSCAN_RETURN_IF_ERROR(mesh::CheckMeshPath(options.out_path));
  std::vector<OutputPath> outputs;
  for (const std::filesystem::path& file : mesh::MeshFilePaths(options.out_path)) outputs.push_back({file, "--out"});
  outputs.push_back({preview, "--preview"});
  if (!options.cloud_preview_path.empty()) outputs.push_back({options.cloud_preview_path, "--cloud-preview"});
  ROTOSCAN_RETURN_IF_ERROR(CheckOutputPaths(outputs, {options.cloud_path}));
  ROTOSCAN_ASSIGN_OR_RETURN(cloud::PointCloud cloud, cloud::ReadPly(options.cloud_path));
  const mesh::ColoredPoints points = mesh::ToColoredPoints(cloud);
  mesh::TriangleMesh surface;
  std::string how;
  double seconds = 0;
  if (options.method == "poisson") {
    mesh::PoissonOptions poisson;
    poisson.depth = options.depth;
    poisson.trim_density_quantile = options.trim;
    poisson.threads = options.threads;
    mesh::PoissonSummary summary;
    ROTOSCAN_ASSIGN_OR_RETURN(surface, mesh::PoissonReconstruct(points, poisson, &summary, context.progress));
    how = "Poisson depth " + std::to_string(options.depth);
    seconds = summary.seconds;
  } else {
    mesh::FusionOptions fusion;
    fusion.voxel_mm = options.voxel;
    fusion.flat_bottom = !options.open_bottom;
    fusion.watertight = options.watertight;
    fusion.threads = options.threads > 0 ? options.threads : 2;
    mesh::FusionSummary summary;
    ROTOSCAN_ASSIGN_OR_RETURN(surface, mesh::FuseSurface(points, fusion, &summary, context.progress));
    how = "fusion, " + std::to_string(options.voxel).substr(0, 4) + " mm voxels" +
          (cloud.scan.known ? ", camera path known" : ", camera path unknown");
    if (options.watertight) {
      char closed[160];
      std::snprintf(closed, sizeof(closed), ", watertight: %zu + %zu rays carved, %.1f %% of vertices fill holes",
                    summary.carved_point_rays, summary.carved_table_rays,
                    100.0 * (1.0 - summary.observed_vertex_fraction));
      how += closed;
    }
    if (summary.colored_from_points + summary.colored_from_neighbours > 0) {
      how += "; vertex colors from the points within " +
             std::to_string(options.voxel * fusion.color_radius_voxels).substr(0, 4) + " mm (" +
             std::to_string(summary.colored_from_neighbours) + " vertices with none near: from their neighbours)";
    }
    seconds = summary.seconds;
  }
  // The pictures are drawn before anything is written: a failure leaves no file.
  mesh::PreviewOptions view;
  view.width = 480;
  view.height = 360;
  ROTOSCAN_ASSIGN_OR_RETURN(cv::Mat picture, mesh::RenderPreviewSheet(surface, view));
  cv::Mat cloud_picture;
  if (!options.cloud_preview_path.empty()) {
    ROTOSCAN_ASSIGN_OR_RETURN(cloud_picture, mesh::RenderPointPreviewSheet(points, view));
  }
  // The mesh (with an OBJ's material and texture) and the pictures are committed together: all or none.
  ROTOSCAN_ASSIGN_OR_RETURN(std::vector<PendingFile> files, mesh::MeshFiles(options.out_path, surface));
  ROTOSCAN_ASSIGN_OR_RETURN(PendingFile preview_file, mesh::PngFile(preview, picture));
  files.push_back(std::move(preview_file));
  if (!options.cloud_preview_path.empty()) {
    ROTOSCAN_ASSIGN_OR_RETURN(PendingFile cloud_file, mesh::PngFile(options.cloud_preview_path, cloud_picture));
    files.push_back(std::move(cloud_file));
  }
  ROTOSCAN_RETURN_IF_ERROR(WriteFilesTogether(files));
  *context.out << "mesh: " << cloud.size() << " points -> " << surface.vertices.size() << " vertices, "
               << surface.triangles.size() << " triangles (" << how << ", " << seconds << " s)\n"
               << "wrote";
  for (std::size_t i = 0; i < files.size(); ++i) {
    *context.out << (i == 0 ? " " : i + 1 == files.size() ? " and " : ", ") << files[i].path.string();
  }
  *context.out << "\n";
  return Status::Ok();
}

void RegisterMesh(CLI::App& app, const Context& context, int* exit_code) {
  auto options = std::make_shared<MeshOptions>();
  CLI::App* sub =
      app.add_subcommand("mesh", "Mesh a colored point cloud (fusion or Poisson) and draw a preview picture");
  sub->add_option("cloud", options->cloud_path, "input point cloud (PLY)")->required();
  sub->add_option("--out", options->out_path, "output mesh: .ply (vertex colors), .obj, .stl or .glb")
      ->capture_default_str();
  sub->add_option("--preview", options->preview_path,
                  "preview picture (PNG: front, side, back, top); default: beside the mesh");
  sub->add_option("--cloud-preview", options->cloud_preview_path, "also the cloud's four views (PNG)");
  sub->add_option("--method", options->method,
                  "fusion (range-scan fusion along the sensor rays) or poisson (Open3D's screened Poisson)")
      ->capture_default_str()
      ->check(CLI::IsMember({"fusion", "poisson"}));
  sub->add_option("--voxel", options->voxel, "fusion: voxel edge in mm")
      ->capture_default_str()
      ->check(CLI::Range(0.05, 20.0));
  sub->add_flag("--open-bottom", options->open_bottom,
                "fusion: leave the bottom open instead of closing it with the table plane");
  sub->add_flag("--watertight", options->watertight,
                "fusion: a closed surface: the space the sensor saw empty is carved, holes are filled by "
                "diffusion (needs the camera path that rotoscan process writes into cloud.ply)");
  sub->add_option("--depth", options->depth, "Poisson octree depth")
      ->capture_default_str()
      ->check(CLI::Range(4, 12));
  sub->add_option("--trim", options->trim, "drop vertices below this quantile of sample density")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 0.5));
  sub->add_option("--threads", options->threads, "threads (0: all cores for Poisson, 2 for fusion)")->capture_default_str()->check(
      CLI::Range(0, 256));
  sub->callback([options, &context, exit_code] {
    *exit_code = ReportStatus(context, "mesh", RunMeshCommand(*options, context));
  });
}

}  // namespace rotoscan::cli
