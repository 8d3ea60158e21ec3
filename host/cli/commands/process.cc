// rotoscan process: Turn a scan bundle and a calibration into a colored point cloud (cloud.ply)
#include <cstdio>
#include <ostream>

#include "command.h"
#include "rotoscan/core/file.h"
#include "rotoscan/bundle/truth.h"
#include "rotoscan/cloud/cloud.h"
#include "rotoscan/cloud/filter.h"
#include "rotoscan/geometry/rig.h"
#include "rotoscan/pipeline/process.h"

namespace rotoscan::cli {

struct ProcessCommandOptions {
  std::string bundle, calib, out;
  std::string estimator = "com";
  int threads = 0;
  bool no_merge = false;
  std::string lasers = "both";
  double min_quality = 0.0;
  std::string dark_frame;
  std::string color = "views";
  std::vector<double> lamp;
  bool estimate_lamp = false;
  cloud::FilterOptions filter;
  bool keep_outliers = false;
  bool extend_line_ends = false;
};

int RunProcess(const ProcessCommandOptions& o, const Context& context) {
  auto fail = [&](const Status& s) { return ReportStatus(context, "process", s); };
  if (o.bundle.empty() || o.out.empty()) {
    *context.err << "rotoscan process: a bundle and --out are required\n";
    return kExitUsage;
  }
  const Status paths = CheckOutputPaths({{o.out, "--out"}}, {o.bundle, o.calib});
  if (!paths.ok()) return fail(paths);
  cloud::FilterOptions filter = o.filter;
  filter.remove_outliers = !o.keep_outliers;
  filter.threads = o.threads > 0 ? o.threads : 2;
  if (const Status checked = filter.Check(); !checked.ok()) return fail(checked);
  pipeline::ProcessOptions options;
  auto estimator = laser::ParseEstimator(o.estimator);
  if (!estimator.ok()) return fail(estimator.status());
  options.extract.estimator = *estimator;
  options.extract.extend_line_ends = o.extend_line_ends;
  options.threads = o.threads;
  options.merge = !o.no_merge;
  options.min_quality = static_cast<float>(o.min_quality);
  if (o.color == "step") {
    options.color.enabled = false;
  } else if (o.color == "views-shaded") {
    options.color.remove_shading = false;
  } else if (o.color != "views") {
    return fail(InvalidArgumentError("--color must be views, views-shaded or step"));
  }
  if (!o.lamp.empty()) {
    if (o.lamp.size() != 3) return fail(InvalidArgumentError("--lamp takes 3 numbers: x,y,z"));
    options.color.lamp_in_cam = Eigen::Vector3d(o.lamp[0], o.lamp[1], o.lamp[2]);
  }
  options.color.use_calibrated_lamp = !o.estimate_lamp;
  if (o.lasers == "left") {
    options.use_laser[1] = false;
  } else if (o.lasers == "right") {
    options.use_laser[0] = false;
  } else if (o.lasers != "both") {
    return fail(InvalidArgumentError("--lasers must be left, right or both"));
  }
  if (!o.dark_frame.empty()) {
    auto dark = laser::ReadImage8(o.dark_frame);
    if (!dark.ok()) return fail(dark.status().WithContext("--dark-frame"));
    options.dark_frame = *dark;
  }
  std::filesystem::path calib = o.calib;
  if (calib.empty()) {
    const std::filesystem::path truth = bundle::TruthRigPath(o.bundle);
    std::error_code ec;
    if (!std::filesystem::exists(truth, ec)) {
      return fail(InvalidArgumentError("no --calib given and the bundle has no " + truth.string() +
                                       " (ground truth of the virtual scanner) to fall back on"));
    }
    *context.err << "rotoscan process: no --calib given: using the bundle's ground-truth rig "
                 << truth.string() << " (only a virtual scanner's bundle has one)\n";
    calib = truth;
  }
  auto rig = geometry::ReadRigYaml(calib);
  if (!rig.ok()) return fail(rig.status().WithContext("reading " + calib.string()));
  auto result = pipeline::ProcessBundle(o.bundle, *rig, options, context.progress);
  if (!result.ok()) return fail(result.status().WithContext(o.bundle));
  if (result->cloud.empty()) {
    *context.out << pipeline::FormatSummary(result->summary);
    return fail(NotFoundError("no point survived in " + o.bundle +
                              ": check the calibration and --min-quality; nothing written"));
  }
  cloud::FilterSummary filtered;
  auto clean = cloud::FilterCloud(result->cloud, filter, &filtered);
  if (!clean.ok()) return fail(clean.status());
  *context.out << pipeline::FormatSummary(result->summary);
  char line[300];
  std::snprintf(
      line, sizeof(line),
      "filter: %zu outliers removed (mean distance to %d neighbours > %.3f mm, and over %.3g x their "
      "own: %zu more kept as sparse as around them), %zu thinned\n",
      filtered.outliers, filter.neighbours, filtered.outlier_threshold_mm, filter.local_ratio,
      filtered.kept_sparse, filtered.thinned);
  *context.out << (filter.remove_outliers || filter.thin_voxel_mm > 0 ? line : "filter: off\n");
  if (clean->empty()) return fail(NotFoundError("no point survived the filter: nothing written"));
  const Status written = cloud::WritePly(o.out, *clean);
  if (!written.ok()) return fail(written);
  *context.out << "wrote " << clean->size() << " points to " << o.out << "\n";
  return kExitOk;
}

void RegisterProcess(CLI::App& app, const Context& context, int* exit_code) {
  CLI::App* sub = app.add_subcommand(
      "process", "Turn a scan bundle and a calibration into a colored point cloud (cloud.ply)");
  static ProcessCommandOptions o;
  o = ProcessCommandOptions{};  // Main() may run more than once in a process (tests)
  sub->add_option("bundle", o.bundle, "scan bundle directory");
  sub->add_option("--calib", o.calib,
                  "calibration (calib.yaml); without it the bundle's truth/rig.yaml is used, if it has one");
  sub->add_option("--out", o.out, "output point cloud (PLY)");
  sub->add_option("--estimator", o.estimator, "sub-pixel estimator: com, parabolic, gaussian, zero-crossing")
      ->capture_default_str();
  sub->add_option("--threads", o.threads, "worker threads (0: all cores)")->capture_default_str();
  sub->add_option("--lasers", o.lasers, "left, right or both")->capture_default_str();
  sub->add_option("--min-quality", o.min_quality, "drop points of lower quality (0..1)")
      ->capture_default_str();
  sub->add_flag("--extend-line-ends", o.extend_line_ends,
                "extraction: also look past each stretch's end for a faint continuation (more points on "
                "faint surfaces, and more of them off by over 1 px: README)");
  sub->add_flag("--no-merge", o.no_merge, "keep both lasers' points where they overlap");
  sub->add_flag("--keep-outliers", o.keep_outliers,
                "no statistical outlier removal (by default a point goes when its mean distance to its "
                "nearest neighbours is over mean + ratio x std of the cloud's and local-ratio x its "
                "neighbours')");
  sub->add_option("--outlier-neighbours", o.filter.neighbours, "outlier removal: neighbours per point")
      ->capture_default_str();
  sub->add_option("--outlier-ratio", o.filter.std_ratio, "outlier removal: standard deviations allowed")
      ->capture_default_str();
  sub->add_option("--outlier-radius", o.filter.radius_mm,
                  "outlier removal: neighbour search radius, mm (a missing neighbour counts as this far)")
      ->capture_default_str();
  sub->add_option(
         "--outlier-local-ratio", o.filter.local_ratio,
         "outlier removal: a point over the threshold stays when its mean distance is at most this "
         "x its neighbours' (as sparse as around it: lines crossing the surface at a grazing angle); "
         "0: off")
      ->capture_default_str();
  sub->add_option("--thin", o.filter.thin_voxel_mm,
                  "keep one point (the best) per voxel of this edge, mm (0: no thinning)")
      ->capture_default_str();
  sub->add_option("--dark-frame", o.dark_frame,
                  "8-bit image with the lasers off: the background of steps without a laser-off frame "
                  "(default: zero, when the scan has no laser-off frame at all)");
  sub->add_option("--color", o.color,
                  "views: each point's color from the natural frames where it is seen best, the lamp's shading "
                  "divided out (pipeline/color.h); views-shaded: the same without dividing the shading; step: "
                  "the natural frame of the point's own step")
      ->capture_default_str();
  CLI::Option* lamp =
      sub->add_option(
             "--lamp", o.lamp,
             "a known lamp instead of the calibration's or the estimate: x,y,z in the camera frame, the "
             "direction to the lamp times its diffuse / ambient ratio (pipeline/color.h)")
          ->delimiter(',')
          ->expected(3);
  sub->add_flag("--estimate-lamp", o.estimate_lamp,
                "estimate the lamp from the scan even when the calibration has one (calibrate lamp)")
      ->excludes(lamp);
  sub->callback([&context, exit_code] { *exit_code = RunProcess(o, context); });
}

}  // namespace rotoscan::cli
