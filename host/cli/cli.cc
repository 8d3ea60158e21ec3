#include <cstdlib>
#include <exception>
#include <ostream>

#include "command.h"
#include "rotoscan/core/logging.h"
#include "rotoscan/core/version.h"

namespace rotoscan::cli {

int ReportStatus(const Context& context, const std::string& command, const Status& status) {
  if (status.ok()) return kExitOk;
  *context.err << "rotoscan " << command << ": " << status.ToString() << "\n";
  return status.code() == StatusCode::kUnimplemented ? kExitNotBuilt : kExitFailure;
}

int NotBuilt(const Context& context, const std::string& command, const std::string& what) {
  *context.err << "rotoscan " << command << ": not built yet: " << what << "\n";
  return kExitNotBuilt;
}

int Main(int argc, const char* const* argv, std::ostream& out, std::ostream& err) {
  CLI::App app{"rotoscan " ROTOSCAN_VERSION_STRING
               ": color 3D laser turntable scanner (calibrate, scan, process, mesh)",
               "rotoscan"};
  app.set_version_flag("--version", "rotoscan " ROTOSCAN_VERSION_STRING);
  app.require_subcommand(1);
  app.fallthrough();
  std::string log_level = "info";
  bool no_progress = false;
  app.add_option("--log-level", log_level, "trace, debug, info, warning, error or off")
      ->check(CLI::IsMember({"trace", "debug", "info", "warning", "warn", "error", "off"}));
  app.add_flag("--no-progress", no_progress,
               "never draw progress bars (they are off in pipes and CI anyway)");

  ProgressBar bar(ProgressBar::Mode::kAuto);
  ProgressBar quiet(ProgressBar::Mode::kNever);
  Context context{&out, &err, &bar};
  int exit_code = kExitOk;
  for (Registrar registrar :
       {RegisterDemo, RegisterSimulate, RegisterCalibrate, RegisterExtract, RegisterProcess, RegisterMesh,
        RegisterEvaluate, RegisterScan, RegisterDevice, RegisterBench, RegisterMerge}) {
    registrar(app, context, &exit_code);
  }
  // Global options must be applied before a command's callback runs.
  app.parse_complete_callback([&] {
    if (auto level = ParseLogLevel(log_level)) SetLogLevel(*level);
    if (no_progress) context.progress = &quiet;
  });

  if (const char* env = std::getenv("ROTOSCAN_LOG_LEVEL"); env != nullptr && !ParseLogLevel(env)) {
    err << "rotoscan: ROTOSCAN_LOG_LEVEL='" << env << "' is not trace, debug, info, warning, error or off\n";
    return kExitUsage;
  }
  // The command word: the first argument that is not a global option (CLI11 would say "A subcommand is
  // required" for a misspelt one).
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--log-level") {
      ++i;
      continue;
    }
    if (arg.empty() || arg[0] == '-') continue;
    bool known = false;
    const CLI::App& commands = app;
    for (const CLI::App* command : commands.get_subcommands([](const CLI::App*) { return true; })) {
      known = known || command->check_name(arg);
    }
    if (!known) {
      err << "rotoscan: unknown command '" << arg << "' (rotoscan --help lists them)\n";
      return kExitUsage;
    }
    break;
  }
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // --help (on any command) and --version arrive here with exit code 0; CLI11 prints them.
    const int code = app.exit(e, out, err);
    return code == 0 ? kExitOk : kExitUsage;
  } catch (const std::exception& e) {
    // A library precondition failure is a bug; report it without crashing.
    err << "rotoscan: internal error: " << e.what() << "\n";
    return kExitFailure;
  }
  return exit_code;
}

}  // namespace rotoscan::cli
