// rotoscan demo: the main job of the README. A full scan on the virtual scanner: render calibration
// bundles, calibrate, render a scan of the bundled Spot mesh, process it into a colored point cloud, mesh
// it and draw a preview picture. Until every stage exists it runs what exists and says what is missing.
#include <ostream>

#include "command.h"

namespace rotoscan::cli {

struct DemoOptions {
  std::string out_dir = "rotoscan-demo";
  int steps = 200;
};

int RunDemo(const DemoOptions& options, const Context& context) {
  *context.out << "rotoscan demo: output directory " << options.out_dir << ", " << options.steps
               << " table steps\n";
  const char* missing[] = {
      "virtual scanner (rotoscan simulate): renders the calibration and scan bundles",
      "calibration (rotoscan calibrate): camera, laser planes and table axis from the calibration bundles",
      "processing (rotoscan process): laser lines to a colored point cloud",
      "meshing and preview (rotoscan mesh): Poisson mesh and preview PNG",
  };
  *context.err << "rotoscan demo: the full scan cannot run yet; stages not built:\n";
  for (const char* stage : missing) *context.err << "  - " << stage << "\n";
  return kExitNotBuilt;
}

void RegisterDemo(CLI::App& app, const Context& context, int* exit_code) {
  auto options = std::make_shared<DemoOptions>();
  CLI::App* sub = app.add_subcommand(
      "demo",
      "Full virtual scan: calibrate, scan the Spot model, process, mesh, preview (the README's main job)");
  sub->add_option("--out", options->out_dir, "output directory")->capture_default_str();
  sub->add_option("--steps", options->steps, "table steps over 360 degrees")
      ->capture_default_str()
      ->check(CLI::Range(4, 100000));
  sub->callback([options, &context, exit_code] { *exit_code = RunDemo(*options, context); });
}

}  // namespace rotoscan::cli
