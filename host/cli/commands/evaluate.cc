// rotoscan evaluate: Compare a point cloud or mesh with ground truth (distance, coverage, color error)
#include <ostream>

#include "command.h"

namespace rotoscan::cli {

void RegisterEvaluate(CLI::App& app, const Context& context, int* exit_code) {
  CLI::App* sub = app.add_subcommand(
      "evaluate", "Compare a point cloud or mesh with ground truth (distance, coverage, color error)");
  static std::string cloud, truth;
  sub->add_option("cloud", cloud, "point cloud (PLY)");
  sub->add_option("--truth", truth, "bundle with truth/ or a reference mesh");
  sub->callback([&context, exit_code] {
    *exit_code =
        NotBuilt(context, "evaluate", "evaluation against ground truth (issue: Laser line extraction)");
  });
}

}  // namespace rotoscan::cli
