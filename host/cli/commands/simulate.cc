// rotoscan simulate: Render scan or calibration bundles on the virtual scanner (with ground truth).
//   rotoscan simulate SCENE.json --out DIR [--kind scan|calib-object|checkerboard|table-checkerboard]
//                    [--steps N] [--threads N] [--overwrite | --resume] [--no-truth] [--table-slip DEG]
//                    [--table-slip-mode independent|cumulative]
//                    [--placement N] [--step-deg DEG]
#include <memory>
#include <ostream>

#include "command.h"
#include "rotoscan/core/file.h"
#include "rotoscan/sim/scene.h"
#include "rotoscan/sim/simulate.h"

namespace rotoscan::cli {

struct SimulateCommandOptions {
  std::string scene;
  std::string out;
  std::string kind = "scan";
  int steps = 0;
  int threads = 0;
  bool overwrite = false;
  bool resume = false;
  bool no_truth = false;
  double table_slip_deg = 0.0;
  std::string table_slip_mode = "independent";
  int placement = 0;
  double step_deg = 0.0;
};

int RunSimulate(const SimulateCommandOptions& options, const Context& context) {
  auto kind = sim::ParseSimulateKind(options.kind);
  if (!kind.ok()) return ReportStatus(context, "simulate", kind.status());
  const Status paths = CheckOutputPaths({{options.out, "--out", OutputKind::kDirectory}}, {options.scene});
  if (!paths.ok()) return ReportStatus(context, "simulate", paths);
  auto slip_mode = sim::ParseSlipMode(options.table_slip_mode);
  if (!slip_mode.ok()) return ReportStatus(context, "simulate", slip_mode.status());
  auto scene = sim::LoadScene(options.scene);
  if (!scene.ok()) return ReportStatus(context, "simulate", scene.status());
  sim::SimulateOptions sim_options;
  sim_options.out = options.out;
  sim_options.kind = *kind;
  sim_options.steps = options.steps;
  sim_options.threads = options.threads;
  sim_options.overwrite = options.overwrite;
  sim_options.resume = options.resume;
  sim_options.truth = !options.no_truth;
  sim_options.table_slip_deg = options.table_slip_deg;
  sim_options.table_slip_mode = *slip_mode;
  sim_options.placement = options.placement;
  sim_options.step_deg = options.step_deg;
  const Status status = sim::Simulate(*scene, sim_options, context.progress);
  if (!status.ok()) return ReportStatus(context, "simulate", status);
  *context.out << "rotoscan simulate: wrote " << options.kind << " bundle " << options.out << "\n";
  return kExitOk;
}

void RegisterSimulate(CLI::App& app, const Context& context, int* exit_code) {
  auto options = std::make_shared<SimulateCommandOptions>();
  CLI::App* sub = app.add_subcommand(
      "simulate", "Render scan or calibration bundles on the virtual scanner (with ground truth)");
  sub->add_option("scene", options->scene, "scene description (JSON, see sim/scene.h)")->required();
  sub->add_option("--out", options->out, "output bundle directory")->required();
  sub->add_option("--kind", options->kind, "scan, calib-object, checkerboard or table-checkerboard")
      ->capture_default_str()
      ->check(CLI::IsMember({"scan", "calib-object", "checkerboard", "table-checkerboard"}));
  sub->add_option("--steps", options->steps, "table steps (scan) or poses/angles (calibration); 0: default")
      ->check(CLI::Range(0, 1000000));
  sub->add_option("--threads", options->threads, "render threads (0: all cores)")->check(CLI::Range(0, 1024));
  auto* overwrite =
      sub->add_flag("--overwrite", options->overwrite, "replace an existing (or an interrupted) bundle");
  sub->add_flag("--resume", options->resume,
                "finish an interrupted bundle (same scene and options): only missing frames are rendered")
      ->excludes(overwrite);
  sub->add_flag("--no-truth", options->no_truth, "do not write truth/");
  sub->add_option("--step-deg", options->step_deg,
                  "scan: the table's step in degrees instead of the scene's (e.g. 360 / steps for a whole turn)")
      ->check(CLI::Range(0.0, 360.0));
  sub->add_option("--table-slip", options->table_slip_deg,
                  "a table that slips: each true angle off the commanded one by up to this many degrees "
                  "(uniform; bundle.json keeps the commanded angle, truth/table_angles.csv the true one)")
      ->check(CLI::Range(0.0, 45.0));
  sub->add_option("--table-slip-mode", options->table_slip_mode,
                  "independent: each position off on its own; cumulative: the deviations add up from position "
                  "to position (a table that loses steps drifts and does not come back)")
      ->capture_default_str()
      ->check(CLI::IsMember({"independent", "cumulative"}));
  sub->add_option("--placement", options->placement,
                  "scans: the object's placement on the table (the scene's 'placements', e.g. 1 = on its "
                  "side); recorded in the bundle, its true pose in truth/placement.csv")
      ->check(CLI::Range(0, 255));
  sub->callback([options, &context, exit_code] { *exit_code = RunSimulate(*options, context); });
}

}  // namespace rotoscan::cli
