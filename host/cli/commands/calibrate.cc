// rotoscan calibrate: camera intrinsics from checkerboard or ChArUco images (calibrate camera), the whole
// rig (camera, both laser planes, table axis) from calibration bundles (pipeline/calibrate.h), or the lamp
// of the natural frames from a scan of a white sphere (calibrate lamp, pipeline/lamp.h). This file
// parses the options, calls the library and prints.
#include <filesystem>
#include <iomanip>
#include <memory>
#include <ostream>
#include <string>
#include <system_error>
#include <vector>

#include "command.h"
#include "rotoscan/calib/camera_calibration.h"
#include "rotoscan/calib/charuco.h"
#include "rotoscan/core/file.h"
#include "rotoscan/geometry/rig.h"
#include "rotoscan/pipeline/calibrate.h"
#include "rotoscan/pipeline/lamp.h"

namespace rotoscan::cli {

struct CalibrateRigOptions {
  std::vector<std::string> bundles;
  std::string out = "calib.yaml";
  std::string report;
  std::string table_slip = "independent";  // the table angles' prior: each position, or each move
};

int RunCalibrateRig(const CalibrateRigOptions& options, const Context& context) {
  const std::string command = "calibrate";
  if (options.bundles.empty()) {
    return ReportStatus(context, command, InvalidArgumentError("no calibration bundle given"));
  }
  std::vector<OutputPath> outputs{{options.out, "--out"}};
  if (!options.report.empty()) outputs.push_back({options.report, "--report"});
  const std::vector<std::filesystem::path> bundles(options.bundles.begin(), options.bundles.end());
  const Status paths = CheckOutputPaths(outputs, bundles);
  if (!paths.ok()) return ReportStatus(context, command, paths);
  pipeline::CalibrateOptions calibrate_options;
  if (options.table_slip == "cumulative") {
    calibrate_options.calibration.table_angle_prior = calib::RigCalibrationOptions::TableAnglePrior::kIncrements;
  }
  Result<pipeline::BundleCalibration> result =
      pipeline::CalibrateFromBundles(bundles, calibrate_options, context.progress);
  if (!result.ok()) return ReportStatus(context, command, result.status());
  const Status written = pipeline::WriteBundleCalibration(*result, options.out, options.report);
  if (!written.ok()) return ReportStatus(context, command, written);

  std::ostream& out = *context.out;
  out << pipeline::FormatCalibrationSummary(*result);
  out << "wrote " << options.out << (options.report.empty() ? "" : " and " + options.report) << "\n";
  const calib::RigCalibrationSummary& s = result->calibration.summary;
  if (!s.passed) {
    *context.err << "rotoscan calibrate: the calibration did not pass its checks:\n";
    for (const auto& f : s.failures) *context.err << "  - " << f << "\n";
    return kExitFailure;
  }
  out << "calibration passed its checks\n";
  return kExitOk;
}

struct CalibrateCameraOptions {
  std::string images;
  std::string pattern;
  std::string charuco;  // ChArUco board squares, COLSxROWS (instead of `pattern`)
  double marker_mm = 0.0;
  std::string dictionary = "DICT_5X5_100";
  double square_mm = 0.0;
  std::string out = "camera.yaml";
  bool fix_aspect_ratio = false;
  int min_views = 6;
};

int RunCalibrateCamera(const CalibrateCameraOptions& options, const Context& context) {
  const std::string command = "calibrate camera";
  const Status paths = CheckOutputPaths({{options.out, "--out"}}, {options.images});
  if (!paths.ok()) return ReportStatus(context, command, paths);
  Result<calib::CameraCalibration> result = InvalidArgumentError(
      "give the target: --pattern COLSxROWS (checkerboard inner corners) or --charuco COLSxROWS (ChArUco "
      "squares) with --marker MM");
  if (!options.charuco.empty()) {
    if (!(options.marker_mm > 0)) {
      return ReportStatus(context, command,
                          InvalidArgumentError("--charuco needs --marker MM (the side of one marker)"));
    }
    Result<calib::CharucoBoard> board =
        calib::ParseCharucoBoard(options.charuco, options.square_mm, options.marker_mm, options.dictionary);
    if (!board.ok()) return ReportStatus(context, command, board.status());
    calib::CharucoCalibrationOptions charuco_options;
    charuco_options.board = *board;
    charuco_options.fix_aspect_ratio = options.fix_aspect_ratio;
    charuco_options.min_views = options.min_views;
    result = calib::CalibrateCameraFromCharucoDirectory(options.images, charuco_options, context.progress);
  } else if (!options.pattern.empty()) {
    Result<calib::CheckerboardPattern> pattern = calib::ParsePattern(options.pattern, options.square_mm);
    if (!pattern.ok()) return ReportStatus(context, command, pattern.status());
    calib::CameraCalibrationOptions calibration_options;
    calibration_options.pattern = *pattern;
    calibration_options.fix_aspect_ratio = options.fix_aspect_ratio;
    calibration_options.min_views = options.min_views;
    result = calib::CalibrateCameraFromDirectory(options.images, calibration_options, context.progress);
  }
  if (!result.ok()) return ReportStatus(context, command, result.status());
  const Status written = calib::WriteCameraYaml(options.out, *result);
  if (!written.ok()) return ReportStatus(context, command, written);

  const geometry::CameraModel& c = result->camera;
  std::ostream& out = *context.out;
  out << std::fixed << std::setprecision(3);
  out << "camera " << c.width << "x" << c.height << " from " << result->views.size() << " views\n";
  out << "  fx " << c.fx << " +- " << result->intrinsics_std[0] << "  fy " << c.fy << " +- "
      << result->intrinsics_std[1] << " px\n";
  out << "  cx " << c.cx << " +- " << result->intrinsics_std[2] << "  cy " << c.cy << " +- "
      << result->intrinsics_std[3] << " px\n";
  out << std::setprecision(5) << "  distortion k1 k2 p1 p2 k3:";
  for (double k : c.distortion) out << " " << k;
  out << "\n" << std::setprecision(3) << "  reprojection RMS " << result->rms_px << " px\n";
  for (std::size_t i = 0; i < result->views.size(); ++i) {
    out << "    " << result->views[i] << ": " << result->per_view_rms_px[i] << " px\n";
  }
  for (const auto& r : result->rejected) out << "  skipped " << r << "\n";
  out << "wrote " << options.out << "\n";
  return kExitOk;
}

struct CalibrateLampOptions {
  std::string bundle;
  std::string calib = "calib.yaml";
  std::string out;  // empty: --calib itself
};

int RunCalibrateLamp(const CalibrateLampOptions& options, const Context& context) {
  const std::string command = "calibrate lamp";
  const std::string out = options.out.empty() ? options.calib : options.out;
  // The calibration written must not land in the sphere's bundle (it would replace one of its files).
  std::error_code error;
  const std::filesystem::path bundle_dir = std::filesystem::weakly_canonical(options.bundle, error);
  const std::filesystem::path written_at = std::filesystem::weakly_canonical(out, error);
  const std::string inside = bundle_dir.string() + "/";
  if (!bundle_dir.empty() && written_at.string().compare(0, inside.size(), inside) == 0) {
    return ReportStatus(context, command,
                        InvalidArgumentError("the calibration (" + out +
                                             ") must not be written inside the bundle " + options.bundle));
  }
  if (!options.out.empty()) {
    const Status paths =
        CheckOutputPaths({{options.out, "--out"}},
                         {std::filesystem::path(options.bundle), std::filesystem::path(options.calib)});
    if (!paths.ok()) return ReportStatus(context, command, paths);
  }
  Result<geometry::Rig> rig = geometry::ReadRigYaml(options.calib);
  if (!rig.ok()) return ReportStatus(context, command, rig.status());
  Result<pipeline::LampCalibration> lamp =
      pipeline::CalibrateLamp(options.bundle, *rig, {}, context.progress);
  if (!lamp.ok()) return ReportStatus(context, command, lamp.status());
  if (out != options.calib) {
    Result<std::string> text = ReadFile(options.calib);
    if (!text.ok()) return ReportStatus(context, command, text.status());
    const Status copied = WriteFileAtomically(out, *text);
    if (!copied.ok()) return ReportStatus(context, command, copied);
  }
  const Status written = pipeline::WriteLampIntoCalibration(out, lamp->lamp_in_cam);
  if (!written.ok()) return ReportStatus(context, command, written);
  *context.out << pipeline::FormatLampCalibration(*lamp) << "wrote the lamp into " << out << "\n";
  return kExitOk;
}

void RegisterCalibrate(CLI::App& app, const Context& context, int* exit_code) {
  CLI::App* sub = app.add_subcommand(
      "calibrate", "Calibrate the rig from calibration bundles, or the camera alone (calibrate camera)");
  auto rig_options = std::make_shared<CalibrateRigOptions>();
  sub->add_option("bundles", rig_options->bundles, "calibration bundle directories");
  sub->add_option("--out", rig_options->out, "output calibration (calib.yaml)")->capture_default_str();
  sub->add_option("--report", rig_options->report, "calibration report (JSON)");
  sub->add_option("--table-slip", rig_options->table_slip,
                  "how the table slips: independent (each position's angle has the commanded one as its prior) "
                  "or cumulative (lost steps add up: the prior is on each move between positions)")
      ->capture_default_str()
      ->check(CLI::IsMember({"independent", "cumulative"}));
  sub->callback([rig_options, &context, exit_code, sub] {
    if (sub->got_subcommand("camera") || sub->got_subcommand("lamp")) return;
    *exit_code = RunCalibrateRig(*rig_options, context);
  });

  auto camera_options = std::make_shared<CalibrateCameraOptions>();
  CLI::App* camera =
      sub->add_subcommand("camera", "Camera intrinsics and distortion from checkerboard or ChArUco images");
  camera->add_option("--images", camera_options->images, "directory of board images")->required();
  CLI::Option* pattern = camera->add_option("--pattern", camera_options->pattern,
                                            "checkerboard inner corners, COLSxROWS (e.g. 9x6)");
  camera->add_option("--charuco", camera_options->charuco, "ChArUco board squares, COLSxROWS (e.g. 8x6)")
      ->excludes(pattern);
  camera->add_option("--marker", camera_options->marker_mm, "ChArUco marker side in mm");
  camera->add_option("--dictionary", camera_options->dictionary, "ChArUco marker dictionary")
      ->capture_default_str();
  camera->add_option("--square", camera_options->square_mm, "square size in mm")->required();
  camera->add_option("--out", camera_options->out, "output (camera.yaml)")->capture_default_str();
  camera->add_flag("--fix-aspect-ratio", camera_options->fix_aspect_ratio,
                   "estimate one focal length (fx = fy)");
  camera->add_option("--min-views", camera_options->min_views, "fewest views with the board found")
      ->capture_default_str()
      ->check(CLI::Range(3, 10000));
  camera->callback(
      [camera_options, &context, exit_code] { *exit_code = RunCalibrateCamera(*camera_options, context); });

  auto lamp_options = std::make_shared<CalibrateLampOptions>();
  CLI::App* lamp = sub->add_subcommand(
      "lamp",
      "The natural frames' lamp (direction and diffuse/ambient, camera frame) from a scan of a matte white "
      "sphere; written into the calibration, where process uses it");
  lamp->add_option("bundle", lamp_options->bundle, "scan bundle of the sphere (data/scenes/lamp-sphere.json)")
      ->required();
  lamp->add_option("--calib", lamp_options->calib, "the rig's calibration (read, and updated unless --out)")
      ->capture_default_str();
  lamp->add_option("--out", lamp_options->out, "write the calibration with the lamp here instead");
  lamp->callback(
      [lamp_options, &context, exit_code] { *exit_code = RunCalibrateLamp(*lamp_options, context); });
}

}  // namespace rotoscan::cli
