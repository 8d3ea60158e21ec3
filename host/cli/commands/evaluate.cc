// rotoscan evaluate: Compare a point cloud with ground truth (distance, coverage, color error), or with
// --lines the line extraction of a bundle against truth/lines.
#include <array>
#include <cstdio>
#include <ostream>

#include "command.h"
#include "rotoscan/cloud/cloud.h"
#include "rotoscan/core/file.h"
#include "rotoscan/mesh/mesh.h"
#include "rotoscan/pipeline/accuracy.h"
#include "rotoscan/pipeline/evaluate.h"

namespace rotoscan::cli {

struct EvaluateCommandOptions {
  std::string cloud, truth, lines, scene, report, uncovered;
  bool reach = false;
  pipeline::ReachOptions reach_options;
  std::string estimator = "com";
  size_t max_frames = 0;
  pipeline::EvaluateOptions evaluate;
};

int RunEvaluate(const EvaluateCommandOptions& o, const Context& context) {
  auto fail = [&](const Status& s) { return ReportStatus(context, "evaluate", s); };
  if (!o.lines.empty()) {
    laser::ExtractOptions options;
    auto estimator = laser::ParseEstimator(o.estimator);
    if (!estimator.ok()) return fail(estimator.status());
    options.estimator = *estimator;
    auto a = pipeline::MeasureLineAccuracy(o.lines, options, o.max_frames, 2.0, context.progress);
    if (!a.ok()) return fail(a.status());
    char buffer[400];
    std::snprintf(
        buffer, sizeof(buffer),
        "line centre (%s): %zu frames, %zu true rows, %zu extracted, %zu matched, %zu outliers (>2 px), "
        "%zu spurious, %zu missed; mean=%.4f px max=%.4f px rms=%.4f px\n",
        laser::EstimatorName(options.estimator), a->frames, a->truth_rows, a->extracted, a->matched,
        a->outliers, a->spurious, a->missed, a->mean_px(), a->max_abs, a->rms_px());
    *context.out << buffer;
    // Across the line (pipeline/accuracy.h: the distance to the true line, which a steep line's row error
    // overstates by its slope).
    std::snprintf(buffer, sizeof(buffer), "across the line: %zu within 2 px, %zu further; rms=%.4f px\n",
                  a->across_matched, a->across_outliers, a->across_rms_px());
    *context.out << buffer;
    return kExitOk;
  }
  if (o.cloud.empty() || o.truth.empty()) {
    *context.err << "rotoscan evaluate: give CLOUD.ply --truth BUNDLE (or --lines BUNDLE)\n";
    return kExitUsage;
  }
  Status checked = o.evaluate.Check();
  if (!checked.ok()) return fail(checked);
  if (!o.report.empty()) {
    checked = CheckOutputPaths({{o.report, "--report"}}, {o.cloud, o.truth, o.scene});
    if (!checked.ok()) return fail(checked);
  }
  const bool reach = o.reach || !o.uncovered.empty();
  if (reach && mesh::IsMeshFile(o.cloud)) {
    *context.err << "rotoscan evaluate: --reach and --uncovered take a point cloud, not a mesh\n";
    return kExitUsage;
  }
  if (reach && o.scene.empty()) {
    *context.err
        << "rotoscan evaluate: --reach and --uncovered need --scene (the rig's lasers and the placements)\n";
    return kExitUsage;
  }
  if (!o.uncovered.empty()) {
    checked = CheckOutputPaths({{o.uncovered, "--uncovered"}}, {o.cloud, o.truth, o.scene, o.report});
    if (!checked.ok()) return fail(checked);
  }
  // A mesh is compared through its vertices: distance mesh -> truth, and coverage (truth -> mesh: the visible
  // true surface with a vertex within the radius; the rest are the mesh's holes).
  const bool is_mesh = mesh::IsMeshFile(o.cloud);
  Result<cloud::PointCloud> cloud = cloud::PointCloud{};
  std::vector<Eigen::Vector3f> mesh_vertices;
  std::vector<Eigen::Vector3i> mesh_triangles;
  if (is_mesh) {
    auto surface = mesh::ReadMesh(o.cloud);
    if (!surface.ok()) return fail(surface.status());
    cloud = mesh::VerticesAsCloud(*surface);
    for (const Eigen::Vector3d& v : surface->vertices) mesh_vertices.push_back(v.cast<float>());
    mesh_triangles = surface->triangles;
    if (mesh_triangles.empty()) return fail(InvalidArgumentError(o.cloud + ": the mesh has no triangles"));
  } else {
    cloud = cloud::ReadPly(o.cloud);
  }
  if (!cloud.ok()) return fail(cloud.status());
  if (cloud->empty()) return fail(InvalidArgumentError(o.cloud + ": the cloud has no points"));
  auto truth = pipeline::LoadTruthSurface(o.truth, o.scene);
  if (!truth.ok()) return fail(truth.status());
  auto views = pipeline::LoadEvaluationViews(o.truth);
  if (!views.ok()) return fail(views.status());
  auto report = pipeline::EvaluateCloud(*cloud, *truth, *views, o.evaluate, context.progress);
  if (!report.ok()) return fail(report.status());
  if (is_mesh) {
    // Truth -> mesh: the true surface's samples against the mesh's triangles (holes by area).
    auto to_mesh = pipeline::EvaluateTruthToMesh(mesh_vertices, mesh_triangles, *truth, *views, o.evaluate,
                                                 context.progress);
    if (!to_mesh.ok()) return fail(to_mesh.status());
    report->has_truth_to_mesh = true;
    report->truth_to_mesh = *to_mesh;
  }
  if (!o.report.empty()) {
    Status written = WriteFileAtomically(o.report, pipeline::EvaluationJson(*report));
    if (!written.ok()) return fail(written);
  }
  *context.out << pipeline::EvaluationSummary(*report);
  if (reach) {
    auto rig = pipeline::LoadScanRig(o.truth, o.scene);
    if (!rig.ok()) return fail(rig.status());
    auto where =
        pipeline::EvaluateReach(*cloud, *truth, *views, *rig, o.evaluate, o.reach_options, context.progress);
    if (!where.ok()) return fail(where.status());
    *context.out << pipeline::ReachSummary(*where);
    if (!o.uncovered.empty()) {
      // Yellow: scannable in the cloud's placements (missed by the scan); blue: only in another pose; red:
      // in no pose tried.
      static constexpr std::array<std::array<uint8_t, 3>, 3> kClassColor = {
          {{255, 210, 0}, {40, 110, 255}, {230, 20, 20}}};
      cloud::PointCloud lost;
      for (size_t i = 0; i < where->uncovered.size(); ++i) {
        cloud::CloudPoint p;
        p.position_in_table = where->uncovered[i];
        p.normal = where->uncovered_normal[i];
        p.color = kClassColor[where->uncovered_class[i]];
        lost.points.push_back(p);
      }
      Status written = cloud::WritePly(o.uncovered, lost);
      if (!written.ok()) return fail(written);
      *context.out
          << "uncovered: " << lost.size() << " samples written to " << o.uncovered
          << " (yellow: scannable in the cloud's placements, blue: only in another pose, red: in none)\n";
    }
  }
  if (is_mesh) {
    char line[200];
    std::snprintf(line, sizeof(line),
                  "mesh: %zu vertices, %zu triangles (distance and coverage above: of its vertices; holes by "
                  "area: the truth-to-mesh line)\n",
                  cloud->size(), mesh_triangles.size());
    *context.out << line;
  }
  return kExitOk;
}

void RegisterEvaluate(CLI::App& app, const Context& context, int* exit_code) {
  CLI::App* sub = app.add_subcommand(
      "evaluate", "Compare a point cloud with ground truth (distance, coverage, color error)");
  static EvaluateCommandOptions o;
  o = EvaluateCommandOptions{};  // Main() may run more than once in a process (tests)
  sub->add_option("cloud", o.cloud, "point cloud (PLY) or mesh (PLY with faces, OBJ, STL, GLB) in the table frame");
  sub->add_option("--truth", o.truth, "virtual scanner bundle with truth/ (object.ply, rig.yaml)");
  sub->add_option("--scene", o.scene,
                  "the scene JSON the bundle was rendered from: true colors from its textures (exact) "
                  "instead of truth/object.ply's vertex colors");
  sub->add_option("--report", o.report, "write the figures as JSON to this file");
  sub->add_option("--radius", o.evaluate.coverage_radius_mm,
                  "coverage radius, mm (0: max(0.5, 0.6 x largest radius x table step))")
      ->capture_default_str();
  sub->add_option("--spacing", o.evaluate.sample_spacing_mm, "surface sample spacing for coverage, mm")
      ->capture_default_str();
  sub->add_option("--threads", o.evaluate.threads, "worker threads (0: all cores)");
  sub->add_flag(
      "--reach", o.reach,
      "split the whole surface's coverage by what the rig can scan in the cloud's placements and in any "
      "pose, with the uncovered regions and the best second pose (needs --scene; a cloud, not a mesh)");
  sub->add_option("--uncovered", o.uncovered,
                  "write the uncovered true-surface samples to this PLY, colored by reach (implies --reach)");
  sub->add_option("--reach-poses", o.reach_options.orientations,
                  "object orientations (up directions) tried for the best poses")
      ->capture_default_str();
  sub->add_option(
         "--reach-incidence", o.reach_options.max_incidence_deg,
         "largest incidence (degrees from the normal) at which the camera sees and a laser lights a point")
      ->capture_default_str();
  sub->add_option("--lines", o.lines,
                  "a virtual scanner bundle: line centre error of the extraction against truth/lines");
  sub->add_option("--estimator", o.estimator, "sub-pixel estimator for --lines")->capture_default_str();
  sub->add_option("--max-frames", o.max_frames, "at most this many laser frames (0: all)");
  sub->callback([&context, exit_code] { *exit_code = RunEvaluate(o, context); });
}

}  // namespace rotoscan::cli
