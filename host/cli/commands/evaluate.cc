// rotoscan evaluate: Compare a point cloud or mesh with ground truth (distance, coverage, color error)
#include <cstdio>
#include <ostream>

#include "command.h"
#include "rotoscan/pipeline/accuracy.h"

namespace rotoscan::cli {

struct EvaluateCommandOptions {
  std::string cloud, truth, lines;
  std::string estimator = "com";
  size_t max_frames = 0;
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
    return kExitOk;
  }
  return NotBuilt(
      context, "evaluate",
      "cloud against the true mesh (distance, coverage, color error); only --lines BUNDLE is built");
}

void RegisterEvaluate(CLI::App& app, const Context& context, int* exit_code) {
  CLI::App* sub = app.add_subcommand(
      "evaluate", "Compare a point cloud or mesh with ground truth (distance, coverage, color error)");
  static EvaluateCommandOptions o;
  o = EvaluateCommandOptions{};  // Main() may run more than once in a process (tests)
  sub->add_option("cloud", o.cloud, "point cloud (PLY)");
  sub->add_option("--truth", o.truth, "bundle with truth/ or a reference mesh");
  sub->add_option("--lines", o.lines,
                  "a virtual scanner bundle: line centre error of the extraction against truth/lines");
  sub->add_option("--estimator", o.estimator, "sub-pixel estimator for --lines")->capture_default_str();
  sub->add_option("--max-frames", o.max_frames, "at most this many laser frames (0: all)");
  sub->callback([&context, exit_code] { *exit_code = RunEvaluate(o, context); });
}

}  // namespace rotoscan::cli
