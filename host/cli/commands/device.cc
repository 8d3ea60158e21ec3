// rotoscan device: bench work with the scanner board (list, info, ping, move, laser).
#include <ostream>

#include "command.h"

namespace rotoscan::cli {

void RegisterDevice(CLI::App& app, const Context& context, int* exit_code) {
  CLI::App* sub = app.add_subcommand("device", "Talk to the scanner board: list, info, ping, move, laser");
  sub->require_subcommand(1);
  const char* actions[][2] = {
      {"list", "List connected scanner boards"},
      {"info", "Show the board's firmware version and capabilities"},
      {"ping", "Measure the round trip and the clock offset to the board"},
      {"move", "Turn the table by an angle in degrees"},
      {"laser", "Switch the lasers (left, right, both, off)"},
  };
  for (const auto& action : actions) {
    CLI::App* command = sub->add_subcommand(action[0], action[1]);
    const std::string name = std::string("device ") + action[0];
    command->callback([&context, exit_code, name] {
      *exit_code =
          NotBuilt(context, name, "the device client (issue: Wire protocol, firmware core, device client)");
    });
  }
}

}  // namespace rotoscan::cli
