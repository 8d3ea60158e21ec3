// rotoscan extract: Find the laser line in a laser-on / laser-off image pair, one sub-pixel point per row
#include <ostream>

#include "command.h"

namespace rotoscan::cli {

void RegisterExtract(CLI::App& app, const Context& context, int* exit_code) {
  CLI::App* sub = app.add_subcommand(
      "extract", "Find the laser line in a laser-on / laser-off image pair, one sub-pixel point per row");
  static std::string on, off, out, channel = "red";
  sub->add_option("--on", on, "laser-on image");
  sub->add_option("--off", off, "laser-off image");
  sub->add_option("--channel", channel, "color channel the laser lives in")->capture_default_str();
  sub->add_option("--out", out, "output CSV: row, column, peak, width, quality");
  sub->callback([&context, exit_code] {
    *exit_code = NotBuilt(context, "extract", "laser line extraction (issue: Laser line extraction)");
  });
}

}  // namespace rotoscan::cli
