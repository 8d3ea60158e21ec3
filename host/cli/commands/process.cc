// rotoscan process: Turn a scan bundle and a calibration into a colored point cloud (cloud.ply)
#include <ostream>

#include "command.h"

namespace rotoscan::cli {

void RegisterProcess(CLI::App& app, const Context& context, int* exit_code) {
  CLI::App* sub = app.add_subcommand(
      "process", "Turn a scan bundle and a calibration into a colored point cloud (cloud.ply)");
  static std::string bundle, calib, out;
  sub->add_option("bundle", bundle, "scan bundle directory");
  sub->add_option("--calib", calib, "calibration (calib.yaml)");
  sub->add_option("--out", out, "output point cloud (PLY)");
  sub->callback([&context, exit_code] {
    *exit_code =
        NotBuilt(context, "process", "processing (issue: Laser line extraction, triangulation, color)");
  });
}

}  // namespace rotoscan::cli
