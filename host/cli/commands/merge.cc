// rotoscan merge: Align the clouds of several placements of one object and merge them (pipeline/placements.h)
//   rotoscan merge CLOUD0 CLOUD1 [CLOUD2...] --out merged.ply [--hint rx,ry,rz,tx,ty,tz | --hint pose.txt]...
//                  [--voxel MM] [--min-overlap F] [--truth BUNDLE0 --truth BUNDLE1 ...]
#include <optional>
#include <ostream>

#include "command.h"
#include "rotoscan/bundle/truth.h"
#include "rotoscan/cloud/cloud.h"
#include "rotoscan/core/file.h"
#include "rotoscan/pipeline/placements.h"

namespace rotoscan::cli {

struct MergeCommandOptions {
  std::vector<std::string> clouds;
  std::string out;
  std::vector<std::string> hints;
  std::vector<std::string> truth;
  double voxel_mm = 1.0;
  double min_overlap = 0.15;
};

int RunMerge(const MergeCommandOptions& o, const Context& context) {
  auto fail = [&](const Status& s) { return ReportStatus(context, "merge", s); };
  if (o.clouds.size() < 2 || o.out.empty()) {
    *context.err << "rotoscan merge: at least two clouds and --out are required\n";
    return kExitUsage;
  }
  if (!o.hints.empty() && o.hints.size() != o.clouds.size() - 1) {
    return fail(InvalidArgumentError("--hint: give one per cloud after the first (" +
                                     std::to_string(o.clouds.size() - 1) + "), in order, or none"));
  }
  if (!o.truth.empty() && o.truth.size() != o.clouds.size()) {
    return fail(InvalidArgumentError("--truth: give one bundle per cloud, in order, or none"));
  }
  std::vector<std::filesystem::path> inputs(o.clouds.begin(), o.clouds.end());
  const Status paths = CheckOutputPaths({{o.out, "--out"}}, inputs);
  if (!paths.ok()) return fail(paths);
  pipeline::AlignOptions options;
  options.voxel_mm = o.voxel_mm;
  options.fine_voxel_mm = std::min(options.fine_voxel_mm, o.voxel_mm);
  options.min_overlap = o.min_overlap;
  std::vector<std::optional<Eigen::Isometry3d>> hints;
  if (!o.hints.empty()) {
    hints.emplace_back();
    for (const std::string& h : o.hints) {
      auto pose = pipeline::ParsePoseHint(h);
      if (!pose.ok()) return fail(pose.status());
      hints.emplace_back(*pose);
    }
  }
  std::vector<cloud::PointCloud> clouds;
  for (const std::string& path : o.clouds) {
    auto read = cloud::ReadPly(path);
    if (!read.ok()) return fail(read.status());
    clouds.push_back(std::move(*read));
  }
  auto merged = pipeline::MergePlacements(clouds, options, hints, 2.0, context.progress);
  if (!merged.ok()) return fail(merged.status());
  *context.out << pipeline::FormatPlacementReport(*merged);
  if (!o.truth.empty()) {
    // Against the virtual scanner's truth: the alignment's error over the true surface.
    auto reference = bundle::ReadPlacementTruth(bundle::TruthPlacementPath(o.truth[0]));
    if (!reference.ok()) return fail(reference.status().WithContext("--truth"));
    for (size_t k = 1; k < o.truth.size(); ++k) {
      auto placement = bundle::ReadPlacementTruth(bundle::TruthPlacementPath(o.truth[k]));
      if (!placement.ok()) return fail(placement.status().WithContext("--truth"));
      auto mesh = bundle::ReadPlyMesh(bundle::TruthMeshPath(o.truth[k]));
      if (!mesh.ok()) return fail(mesh.status().WithContext("--truth"));
      const Eigen::Isometry3d truth =
          reference->table_from_reference * placement->table_from_reference.inverse();
      const pipeline::AlignmentError e = pipeline::MeasureAlignmentError(
          merged->placements[k].alignment.target_from_source, truth, mesh->vertices, mesh->faces);
      *context.out << "placement " << k << " against the truth: alignment error " << e.rms_mm
                   << " mm RMS over the true surface, " << e.angle_deg << " deg, " << e.translation_mm
                   << " mm at its centroid\n";
    }
  }
  const Status written = cloud::WritePly(o.out, merged->cloud);
  if (!written.ok()) return fail(written);
  *context.out << "wrote " << merged->cloud.size() << " points (property 'placement' per point) to " << o.out
               << "\n";
  return kExitOk;
}

void RegisterMerge(CLI::App& app, const Context& context, int* exit_code) {
  CLI::App* sub = app.add_subcommand(
      "merge", "Align the clouds of several placements of one object (automatically) and merge them");
  static MergeCommandOptions o;
  o = MergeCommandOptions{};  // Main() may run more than once in a process (tests)
  sub->add_option("clouds", o.clouds, "clouds (PLY) of the placements; the first is the reference frame");
  sub->add_option("--out", o.out, "merged cloud (PLY, with a 'placement' property per point)");
  sub->add_option("--hint", o.hints,
                  "a rough pose of cloud k (k = 1, 2, ... in order) in the first's frame: rx,ry,rz,tx,ty,tz "
                  "(degrees about x, y, z applied in that order; mm) or a file with those 6 numbers or a 4x4 "
                  "matrix; decides an ambiguous alignment (a symmetric object)");
  sub->add_option("--voxel", o.voxel_mm, "thinning for features and the global registration, mm")
      ->capture_default_str()
      ->check(CLI::Range(0.05, 100.0));
  sub->add_option("--min-overlap", o.min_overlap, "refuse an alignment sharing less of the cloud (0..1)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 1.0));
  sub->add_option("--truth", o.truth,
                  "virtual scanner: the bundle of each cloud, in order (truth/placement.csv): report the "
                  "alignment error against the true poses");
  sub->callback([&context, exit_code] { *exit_code = RunMerge(o, context); });
}

}  // namespace rotoscan::cli
