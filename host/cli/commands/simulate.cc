// rotoscan simulate: Render scan or calibration bundles on the virtual scanner (with ground truth)
#include <ostream>

#include "command.h"

namespace rotoscan::cli {

void RegisterSimulate(CLI::App& app, const Context& context, int* exit_code) {
  CLI::App* sub = app.add_subcommand(
      "simulate", "Render scan or calibration bundles on the virtual scanner (with ground truth)");
  static std::string scene, out;
  sub->add_option("scene", scene, "scene description (JSON)");
  sub->add_option("--out", out, "output bundle directory");
  sub->callback([&context, exit_code] {
    *exit_code = NotBuilt(context, "simulate", "the virtual scanner (issue: Virtual scanner)");
  });
}

}  // namespace rotoscan::cli
