// rotoscan mesh: a colored point cloud (cloud.ply) to a Poisson mesh with vertex colors and a preview PNG.
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
  int depth = 9;
  double trim = 0.02;
  int threads = 0;
};

Status RunMeshCommand(const MeshOptions& options, const Context& context) {
  std::filesystem::path preview = options.preview_path;
  if (preview.empty()) preview = std::filesystem::path(options.out_path).replace_extension(".png");
  ROTOSCAN_RETURN_IF_ERROR(mesh::CheckMeshPath(options.out_path));
  ROTOSCAN_RETURN_IF_ERROR(
      CheckOutputPaths({{options.out_path, "--out"}, {preview, "--preview"}}, {options.cloud_path}));
  ROTOSCAN_ASSIGN_OR_RETURN(cloud::PointCloud cloud, cloud::ReadPly(options.cloud_path));
  mesh::PoissonOptions poisson;
  poisson.depth = options.depth;
  poisson.trim_density_quantile = options.trim;
  poisson.threads = options.threads;
  mesh::PoissonSummary summary;
  ROTOSCAN_ASSIGN_OR_RETURN(
      mesh::TriangleMesh surface,
      mesh::PoissonReconstruct(mesh::ToColoredPoints(cloud), poisson, &summary, context.progress));
  // The preview is drawn before anything is written: a failure leaves neither file.
  ROTOSCAN_ASSIGN_OR_RETURN(cv::Mat picture, mesh::RenderPreview(surface, mesh::PreviewOptions{}));
  ROTOSCAN_RETURN_IF_ERROR(mesh::WriteMesh(options.out_path, surface));
  ROTOSCAN_RETURN_IF_ERROR(mesh::WritePng(preview, picture));
  *context.out << "mesh: " << summary.input_points << " points -> " << surface.vertices.size()
               << " vertices, " << surface.triangles.size() << " triangles (depth " << options.depth << ", "
               << summary.seconds << " s)\n"
               << "wrote " << options.out_path << " and " << preview.string() << "\n";
  return Status::Ok();
}

void RegisterMesh(CLI::App& app, const Context& context, int* exit_code) {
  auto options = std::make_shared<MeshOptions>();
  CLI::App* sub =
      app.add_subcommand("mesh", "Mesh a colored point cloud (Poisson) and draw a preview picture");
  sub->add_option("cloud", options->cloud_path, "input point cloud (PLY)")->required();
  sub->add_option("--out", options->out_path, "output mesh: .ply (vertex colors), .obj or .stl")
      ->capture_default_str();
  sub->add_option("--preview", options->preview_path, "preview picture (PNG); default: beside the mesh");
  sub->add_option("--depth", options->depth, "Poisson octree depth")
      ->capture_default_str()
      ->check(CLI::Range(4, 12));
  sub->add_option("--trim", options->trim, "drop vertices below this quantile of sample density")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 0.5));
  sub->add_option("--threads", options->threads, "threads (0: all cores)")->capture_default_str()->check(
      CLI::Range(0, 256));
  sub->callback([options, &context, exit_code] {
    *exit_code = ReportStatus(context, "mesh", RunMeshCommand(*options, context));
  });
}

}  // namespace rotoscan::cli
