// rotoscan scan: Scan with the real scanner: drive the board, capture frames, write a scan bundle
#include <ostream>

#include "command.h"

namespace rotoscan::cli {

void RegisterScan(CLI::App& app, const Context& context, int* exit_code) {
  CLI::App* sub = app.add_subcommand(
      "scan", "Scan with the real scanner: drive the board, capture frames, write a scan bundle");
  static std::string out;
  sub->add_option("--out", out, "output bundle directory");
  sub->callback(
      [&context, exit_code] { *exit_code = NotBuilt(context, "scan", "acquisition (a later issue)"); });
}

}  // namespace rotoscan::cli
