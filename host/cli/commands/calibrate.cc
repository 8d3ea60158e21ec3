// rotoscan calibrate: camera intrinsics from checkerboard images, or the whole rig (camera, both laser
// planes, table axis) from calibration bundles.
#include <ostream>

#include "command.h"

namespace rotoscan::cli {

void RegisterCalibrate(CLI::App& app, const Context& context, int* exit_code) {
  CLI::App* sub = app.add_subcommand(
      "calibrate", "Calibrate the rig from calibration bundles, or the camera alone (calibrate camera)");
  static std::vector<std::string> bundles;
  static std::string out, report;
  sub->add_option("bundles", bundles, "calibration bundle directories");
  sub->add_option("--out", out, "output calibration (calib.yaml)");
  sub->add_option("--report", report, "calibration report (JSON)");
  sub->callback([&context, exit_code, sub] {
    if (sub->got_subcommand("camera")) return;
    *exit_code = NotBuilt(context, "calibrate", "rig calibration (issue: Calibration)");
  });

  CLI::App* camera =
      sub->add_subcommand("camera", "Camera intrinsics and distortion from checkerboard images");
  static std::string images, pattern, camera_out;
  static double square_mm = 0;
  camera->add_option("--images", images, "directory of checkerboard images");
  camera->add_option("--pattern", pattern, "inner corners, COLSxROWS (e.g. 9x6)");
  camera->add_option("--square", square_mm, "square size in mm");
  camera->add_option("--out", camera_out, "output (camera.yaml)");
  camera->callback([&context, exit_code] {
    *exit_code = NotBuilt(context, "calibrate camera", "camera calibration (issue: Calibration)");
  });
}

}  // namespace rotoscan::cli
