// rotoscan bench: Measure accuracy and speed (e.g. rotoscan bench accuracy --distance 300)
#include <ostream>

#include "command.h"

namespace rotoscan::cli {

void RegisterBench(CLI::App& app, const Context& context, int* exit_code) {
  CLI::App* sub =
      app.add_subcommand("bench", "Measure accuracy and speed (e.g. rotoscan bench accuracy --distance 300)");
  static std::string what;
  sub->add_option("what", what, "accuracy | extract | render");
  sub->callback([&context, exit_code] {
    *exit_code = NotBuilt(context, "bench", "benchmarks (issues: Virtual scanner, Laser line extraction)");
  });
}

}  // namespace rotoscan::cli
