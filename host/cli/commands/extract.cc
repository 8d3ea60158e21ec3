// rotoscan extract: Find the laser line in a laser-on / laser-off image pair, one sub-pixel point per row
#include <cstdio>
#include <ostream>
#include <sstream>

#include "command.h"
#include "rotoscan/core/file.h"
#include "rotoscan/laser/extract.h"

namespace rotoscan::cli {

struct ExtractCommandOptions {
  std::string on, off, out;
  std::string channel = "red";
  std::string layout = "auto";
  std::string estimator = "com";
};

namespace {

Result<cv::Mat> ReadImage(const std::string& path, const char* what) {
  auto image = laser::ReadImage8(path);
  if (!image.ok()) return image.status().WithContext(std::string(what) + " image");
  return image;
}

}  // namespace

// The CSV (header line, then row,column,peak,width,quality per found row) on success.
int RunExtract(const ExtractCommandOptions& o, const Context& context) {
  auto fail = [&](const Status& s) { return ReportStatus(context, "extract", s); };
  if (o.on.empty() || o.off.empty() || o.out.empty()) {
    *context.err << "rotoscan extract: --on, --off and --out are required\n";
    return kExitUsage;
  }
  const Status paths = CheckOutputPaths({{o.out, "--out"}}, {o.on, o.off});
  if (!paths.ok()) return fail(paths);
  laser::ExtractOptions options;
  auto channel = laser::ParseChannel(o.channel);
  if (!channel.ok()) return fail(channel.status());
  options.channel = *channel;
  auto layout = laser::ParsePixelLayout(o.layout);
  if (!layout.ok()) return fail(layout.status());
  options.layout = *layout;
  auto estimator = laser::ParseEstimator(o.estimator);
  if (!estimator.ok()) return fail(estimator.status());
  options.estimator = *estimator;
  auto on = ReadImage(o.on, "laser-on");
  if (!on.ok()) return fail(on.status());
  auto off = ReadImage(o.off, "laser-off");
  if (!off.ok()) return fail(off.status());
  auto line = laser::ExtractLine(*on, *off, options);
  if (!line.ok()) return fail(line.status().WithContext(o.on + " / " + o.off));
  std::string csv = "row,column,peak,width,quality\n";
  char buffer[128];
  for (const laser::LinePoint& p : line->points) {
    std::snprintf(buffer, sizeof(buffer), "%d,%.4f,%.1f,%.3f,%.3f\n", p.row, p.column, p.peak, p.width,
                  p.quality);
    csv += buffer;
  }
  const Status written = WriteFileAtomically(o.out, csv);
  if (!written.ok()) return fail(written.WithContext("writing " + o.out));
  const laser::LineStats& s = line->stats;
  *context.out << "found " << s.found << " of " << s.rows << " rows (no contrast " << s.low_contrast
               << ", bad width " << s.bad_width << ", laser-off saturated " << s.off_saturated
               << ", multiple peaks " << s.multiple_peaks << "), noise " << s.noise_dn << " DN, threshold "
               << s.threshold_dn << " DN -> " << o.out << "\n";
  return kExitOk;
}

void RegisterExtract(CLI::App& app, const Context& context, int* exit_code) {
  CLI::App* sub = app.add_subcommand(
      "extract", "Find the laser line in a laser-on / laser-off image pair, one sub-pixel point per row");
  static ExtractCommandOptions o;
  o = ExtractCommandOptions{};  // Main() may run more than once in a process (tests)
  sub->add_option("--on", o.on, "laser-on image (8-bit, gray or color, any size)");
  sub->add_option("--off", o.off, "laser-off image of the same size");
  sub->add_option("--channel", o.channel, "color channel the laser lives in: red, green, blue")
      ->capture_default_str();
  sub->add_option("--layout", o.layout, "pixel layout: auto, gray, bgr, rgb, bayer-rggb|grbg|bggr|gbrg")
      ->capture_default_str();
  sub->add_option("--estimator", o.estimator, "sub-pixel estimator: com, parabolic, gaussian, zero-crossing")
      ->capture_default_str();
  sub->add_option("--out", o.out, "output CSV: row, column, peak, width, quality");
  sub->callback([&context, exit_code] { *exit_code = RunExtract(o, context); });
}

}  // namespace rotoscan::cli
