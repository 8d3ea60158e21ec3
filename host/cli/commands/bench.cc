// rotoscan bench: Measure accuracy and speed (e.g. rotoscan bench accuracy --distance 300)
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <ostream>
#include <vector>

#include "command.h"
#include "rotoscan/pipeline/accuracy.h"

namespace rotoscan::cli {

struct BenchCommandOptions {
  std::string what;
  std::vector<double> distances;
  int steps = 4;
};

// The paper's Table 1 on the virtual scanner: a plane at each distance, RMS distance to the true plane.
int RunBenchAccuracy(const BenchCommandOptions& o, const Context& context) {
  const std::vector<double> distances =
      o.distances.empty() ? std::vector<double>{270, 280, 290, 300, 310} : o.distances;
  // The paper's figures (Table 1, mm) for the line printed beside ours.
  auto paper = [](double d) -> double {
    const double table[][2] = {{270, 0.1122}, {280, 0.1318}, {290, 0.1411}, {300, 0.1787}, {310, 0.1870}};
    for (const auto& row : table) {
      if (std::abs(row[0] - d) < 0.5) return row[1];
    }
    return -1;
  };
  const std::filesystem::path work =
      std::filesystem::temp_directory_path() / ("rotoscan-bench-accuracy-" + std::to_string(::getpid()));
  int code = kExitOk;
  for (double d : distances) {
    if (!(d > 50 && d < 2000)) {
      *context.err << "rotoscan bench: --distance must be in (50, 2000) mm\n";
      code = kExitUsage;
      break;
    }
    auto a = pipeline::RunPlaneAccuracy(d, work, o.steps, "", context.progress);
    if (!a.ok()) {
      code = ReportStatus(context, "bench", a.status());
      break;
    }
    char buffer[200];
    const double p = paper(d);
    std::snprintf(buffer, sizeof(buffer), "distance=%.0f mm points=%zu mean=%.4f mm paper=%s rms=%.4f\n", d,
                  a->points, a->mean_mm, p > 0 ? (std::to_string(p).substr(0, 6) + " mm").c_str() : "-",
                  a->rms_mm);
    *context.out << buffer;
  }
  std::error_code ec;
  std::filesystem::remove_all(work, ec);
  return code;
}

void RegisterBench(CLI::App& app, const Context& context, int* exit_code) {
  CLI::App* sub =
      app.add_subcommand("bench", "Measure accuracy and speed (e.g. rotoscan bench accuracy --distance 300)");
  static BenchCommandOptions o;
  o = BenchCommandOptions{};  // Main() may run more than once in a process (tests)
  sub->add_option("what", o.what, "accuracy | extract | render");
  sub->add_option("--distance", o.distances, "plane distance(s) in mm for accuracy (default 270..310)");
  sub->add_option("--steps", o.steps, "table steps rendered per distance")->capture_default_str();
  sub->callback([&context, exit_code] {
    if (o.what == "accuracy") {
      *exit_code = RunBenchAccuracy(o, context);
      return;
    }
    *exit_code =
        NotBuilt(context, "bench",
                 "'" + o.what + "' (built: accuracy; speed: the Google Benchmark programs in host/bench/)");
  });
}

}  // namespace rotoscan::cli
