// The CLI's commands. Each command lives in commands/<name>.cc and has an options struct, a Run function
// that tests call directly, and a Register function that adds it to the CLI11 app. main.cc only
// dispatches.
//
// Exit codes: 0 done; 1 the work failed (the message says why); 2 bad usage; 3 not built yet.
#pragma once

#include <functional>
#include <iosfwd>
#include <string>

#include <CLI/CLI.hpp>

#include "rotoscan/core/progress.h"
#include "rotoscan/core/status.h"

namespace rotoscan::cli {

enum ExitCode : int { kExitOk = 0, kExitFailure = 1, kExitUsage = 2, kExitNotBuilt = 3 };

// What a command writes to and reports progress on. Results go to `out`, messages to `err`.
struct Context {
  std::ostream* out;
  std::ostream* err;
  Progress* progress = nullptr;  // may be null
};

// Prints "rotoscan <command>: <status>" on err and returns the exit code for it.
int ReportStatus(const Context& context, const std::string& command, const Status& status);

// For a command whose implementation has not landed: says so and returns kExitNotBuilt.
int NotBuilt(const Context& context, const std::string& command, const std::string& what);

// Registration: each adds one subcommand to `app`; its callback stores the exit code in `*exit_code`.
using Registrar = void (*)(CLI::App& app, const Context& context, int* exit_code);
void RegisterDemo(CLI::App& app, const Context& context, int* exit_code);
void RegisterSimulate(CLI::App& app, const Context& context, int* exit_code);
void RegisterCalibrate(CLI::App& app, const Context& context, int* exit_code);
void RegisterExtract(CLI::App& app, const Context& context, int* exit_code);
void RegisterProcess(CLI::App& app, const Context& context, int* exit_code);
void RegisterMesh(CLI::App& app, const Context& context, int* exit_code);
void RegisterMerge(CLI::App& app, const Context& context, int* exit_code);
void RegisterEvaluate(CLI::App& app, const Context& context, int* exit_code);
void RegisterScan(CLI::App& app, const Context& context, int* exit_code);
void RegisterDevice(CLI::App& app, const Context& context, int* exit_code);
void RegisterBench(CLI::App& app, const Context& context, int* exit_code);

// The whole program: parses argv, runs one command, returns the exit code. Never throws.
int Main(int argc, const char* const* argv, std::ostream& out, std::ostream& err);

}  // namespace rotoscan::cli
