// rotoscan bench: Measure accuracy and speed (e.g. rotoscan bench accuracy --distance 300)
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <ostream>
#include <tuple>
#include <utility>
#include <vector>

#include "command.h"
#include "rotoscan/cloud/cloud.h"
#include "rotoscan/mesh/mesh.h"
#include "rotoscan/pipeline/accuracy.h"
#include "rotoscan/pipeline/calibrate.h"
#include "rotoscan/sim/scene.h"
#include "rotoscan/sim/simulate.h"
#include "rotoscan/pipeline/evaluate.h"

namespace rotoscan::cli {

struct BenchCommandOptions {
  std::string what;
  std::vector<double> distances;
  int steps = 4;
  bool calib = false;   // accuracy with a rig calibrated from rendered bundles (pipeline/calibrate.h)
  double k1 = -0.2;     // lens distortion of the virtual camera in that mode
  int board_poses = 0;  // in that mode: add a hand-held checkerboard bundle of that many poses
  std::string target = "object";  // in that mode: object (the paper's) | board (the demo's table board)
  int calibration_steps = 0;      // in that mode: table angles per placement (0: 9 object, 16 board)
  std::vector<std::string> scenes;  // accuracy --scene: line centres on these scenes instead of the plane
  double f_number = 0.0;          // accuracy --scene: the lasers' speckle f-number (0: the scene's)
  std::string cloud, truth;       // mesh: the scan's cloud.ply and its bundle (with truth/)
  int depth = 9;                  // mesh: Poisson depth
  double voxel = 0.5;             // mesh: fusion voxel, mm
  int threads = 2;                // mesh: threads for both
  bool watertight = false;        // mesh: also the watertight fusion
  bool extend_line_ends = false;  // accuracy --scene: ExtractOptions::extend_line_ends
};

// bench accuracy --scene FILE...: each scene rendered (--steps table steps over the whole turn) and its
// line centres compared with the truth (issue 15's figures on the webcam scenes): lit rows found, rows
// more than 1 px from the true centre, RMS of the others; measured across the line (pipeline/accuracy.h: the
// distance to the true line, which the targets are judged on) and per row (which a steep line's slope
// multiplies); for all lit rows (the target's figure: the cloud keeps the table's points) and for the
// object's rows and the table's apart.
int RunBenchSceneAccuracy(const BenchCommandOptions& o, const Context& context) {
  const std::filesystem::path work =
      std::filesystem::temp_directory_path() / ("rotoscan-bench-scene-" + std::to_string(::getpid()));
  int code = kExitOk;
  for (const std::string& file : o.scenes) {
    auto scene = sim::LoadScene(file);
    if (!scene.ok()) {
      code = ReportStatus(context, "bench", scene.status());
      break;
    }
    if (o.f_number > 0) {
      for (sim::LaserModel& laser : scene->laser) laser.f_number = o.f_number;
    }
    sim::SimulateOptions options;
    options.out = work / "scene";
    options.steps = o.steps;
    options.overwrite = true;
    scene->rig.step_angle_rad = 2.0 * 3.14159265358979323846 / o.steps;  // spread over the whole turn
    Status status = sim::Simulate(*scene, options, context.progress);
    if (!status.ok()) {
      code = ReportStatus(context, "bench", status);
      break;
    }
    laser::ExtractOptions extract;
    extract.extend_line_ends = o.extend_line_ends;
    auto a = pipeline::MeasureLineAccuracyByPart(options.out, extract, 0, 1.0, context.progress);
    if (!a.ok()) {
      code = ReportStatus(context, "bench", a.status());
      break;
    }
    char buffer[256];
    std::snprintf(buffer, sizeof(buffer), "scene=%s speckle=f/%.1f frames=%zu\n", file.c_str(),
                  scene->laser[0].f_number, a->all.frames);
    *context.out << buffer;
    const std::pair<const char*, const pipeline::LineAccuracy*> parts[] = {
        {"all", &a->all}, {"object", &a->object}, {"table", &a->table}};
    for (const auto& [name, part] : parts) {
      const double lit = static_cast<double>(std::max<size_t>(1, part->truth_rows));
      std::snprintf(buffer, sizeof(buffer),
                    "  %-6s lit rows=%zu found=%.2f %% | across the line: over 1 px=%.3f %% rms=%.3f px | per row: "
                    "over 1 px=%.3f %% rms=%.3f px mean=%+.3f px\n",
                    name, part->truth_rows, 100.0 * (lit - part->missed) / lit, 100.0 * part->across_outliers / lit,
                    part->across_rms_px(), 100.0 * part->outliers / lit, part->rms_px(), part->mean_px());
      *context.out << buffer;
    }
  }
  std::error_code ec;
  std::filesystem::remove_all(work, ec);
  return code;
}


// bench mesh: fusion and Open3D's Poisson on the same cloud in the same run (Poisson's OpenMP threads
// passive: main.cc), each mesh's vertices against the true surface, and the machine's load.
int RunBenchMesh(const BenchCommandOptions& o, const Context& context) {
  if (o.cloud.empty() || o.truth.empty()) {
    *context.err << "rotoscan bench mesh: give --cloud CLOUD.ply --truth BUNDLE\n";
    return kExitUsage;
  }
  auto fail = [&](const Status& s) { return ReportStatus(context, "bench", s); };
  auto cloud = cloud::ReadPly(o.cloud);
  if (!cloud.ok()) return fail(cloud.status());
  auto truth = pipeline::LoadTruthSurface(o.truth);
  if (!truth.ok()) return fail(truth.status());
  auto views = pipeline::LoadEvaluationViews(o.truth);
  if (!views.ok()) return fail(views.status());
  const mesh::ColoredPoints points = mesh::ToColoredPoints(*cloud);
  double load[3] = {0, 0, 0};
  if (getloadavg(load, 3) < 0) load[0] = -1;
  char line[512];
  std::snprintf(line, sizeof(line), "cloud: %zu points, camera path %s; load average %.2f before\n", cloud->size(),
                cloud->scan.known ? "known" : "unknown", load[0]);
  *context.out << line;
  mesh::FusionOptions fusion;
  fusion.voxel_mm = o.voxel;
  fusion.threads = o.threads;
  mesh::FusionSummary fused_summary;
  auto fused = mesh::FuseSurface(points, fusion, &fused_summary, context.progress);
  if (!fused.ok()) return fail(fused.status());
  mesh::PoissonOptions poisson;
  poisson.depth = o.depth;
  poisson.threads = o.threads;
  mesh::PoissonSummary poisson_summary;
  auto solved = mesh::PoissonReconstruct(points, poisson, &poisson_summary, context.progress);
  if (!solved.ok()) return fail(solved.status());
  if (getloadavg(load, 3) < 0) load[0] = -1;
  std::snprintf(line, sizeof(line), "fusion %.2f s (splat %.2f, extract %.2f), Poisson %.2f s: %.1fx\n",
                fused_summary.seconds, fused_summary.splat_seconds, fused_summary.extract_seconds,
                poisson_summary.seconds, poisson_summary.seconds / fused_summary.seconds);
  *context.out << line << std::flush;
  pipeline::EvaluateOptions evaluate;
  evaluate.threads = o.threads;
  // Holes: the visible surface as seen from at most 100 of the table angles (all of them costs minutes).
  pipeline::EvaluationViews some = *views;
  if (some.cam_from_table.size() > 100) {
    some.cam_from_table.clear();
    const std::size_t every = (views->cam_from_table.size() + 99) / 100;
    for (std::size_t i = 0; i < views->cam_from_table.size(); i += every) some.cam_from_table.push_back(views->cam_from_table[i]);
  }
  std::vector<std::tuple<const char*, const mesh::TriangleMesh*, double>> rows = {
      {"fusion", &*fused, fused_summary.seconds}, {"poisson", &*solved, poisson_summary.seconds}};
  Result<mesh::TriangleMesh> closed = mesh::TriangleMesh{};
  mesh::FusionSummary closed_summary;
  if (o.watertight) {
    fusion.watertight = true;
    closed = mesh::FuseSurface(points, fusion, &closed_summary, context.progress);
    if (!closed.ok()) return fail(closed.status());
    rows.emplace_back("fusion-wt", &*closed, closed_summary.seconds);
  }
  for (const auto& [name, surface, seconds] : rows) {
    auto report = pipeline::EvaluateCloud(mesh::VerticesAsCloud(*surface), *truth, some, evaluate, nullptr);
    if (!report.ok()) return fail(report.status());
    std::vector<Eigen::Vector3f> vertices;
    for (const Eigen::Vector3d& v : surface->vertices) vertices.push_back(v.cast<float>());
    auto to_mesh = pipeline::EvaluateTruthToMesh(vertices, surface->triangles, *truth, some, evaluate, nullptr);
    if (!to_mesh.ok()) return fail(to_mesh.status());
    std::snprintf(line, sizeof(line),
                  "%-9s %7.2f s  %8zu vertices %8zu triangles  vertices to truth: median %.4f mean %.4f p95 %.4f "
                  "max %.3f mm; truth to mesh: median %.4f p95 %.4f mm, holes %.4f of the visible area "
                  "(radius %.2f mm)\n",
                  name, seconds, surface->vertices.size(), surface->triangles.size(), report->distance.median_mm,
                  report->distance.mean_mm, report->distance.p95_mm, report->distance.max_mm,
                  to_mesh->distance.median_mm, to_mesh->distance.p95_mm, to_mesh->hole_fraction, to_mesh->radius_mm);
    *context.out << line << std::flush;
  }
  std::snprintf(line, sizeof(line),
                "fusion (voxel %.2f mm, %d threads) is %.1fx Poisson (depth %d, %d threads); fusion splat %.2f s, "
                "extract %.2f s; load average %.2f after\n",
                o.voxel, o.threads, poisson_summary.seconds / fused_summary.seconds, o.depth, o.threads,
                fused_summary.splat_seconds, fused_summary.extract_seconds, load[0]);
  *context.out << line;
  return kExitOk;
}

// bench accuracy --calib: the plane test with rigs calibrated from rendered calibration bundles (--target
// object | board) with distortion on: the three steps against the joint refinement (and the true rig).
int RunBenchCalibratedAccuracy(const BenchCommandOptions& o, const Context& context) {
  const std::vector<double> distances = o.distances.empty() ? std::vector<double>{300} : o.distances;
  const std::filesystem::path work =
      std::filesystem::temp_directory_path() / ("rotoscan-bench-calib-" + std::to_string(::getpid()));
  int code = kExitOk;
  for (double d : distances) {
    if (!(d > 50 && d < 2000)) {
      *context.err << "rotoscan bench: --distance must be in (50, 2000) mm\n";
      code = kExitUsage;
      break;
    }
    pipeline::CalibratedAccuracyOptions options;
    if (o.target == "board") {
      options.target = pipeline::CalibrationTarget::kTableBoard;
      options.calibration_steps = 16;
    } else if (o.target != "object") {
      *context.err << "rotoscan bench: --target must be object or board\n";
      code = kExitUsage;
      break;
    }
    if (o.calibration_steps > 0) options.calibration_steps = o.calibration_steps;
    options.distance_mm = d;
    options.k1 = o.k1;
    options.scan_steps = o.steps;
    options.board_poses = o.board_poses;
    options.work_dir = work;
    auto a = pipeline::RunCalibratedPlaneAccuracy(options, context.progress);
    if (!a.ok()) {
      code = ReportStatus(context, "bench", a.status());
      break;
    }
    char buffer[512];
    std::snprintf(buffer, sizeof(buffer),
                  "target=%s distance=%.0f mm k1=%.3f board poses=%d points=%zu three-step: rms=%.4f "
                  "mean=%+.4f mm "
                  "(corner rms %.3f px) "
                  "joint: rms=%.4f mean=%+.4f mm (corner rms %.3f px) true rig: rms=%.4f mean=%+.4f mm\n",
                  o.target.c_str(), d, o.k1, o.board_poses, a->points, a->three_step_rms_mm, a->three_step_mean_mm,
                  a->three_step.rms_px, a->joint_rms_mm, a->joint_mean_mm, a->joint.rms_px,
                  a->true_rig_rms_mm, a->true_rig_mean_mm);
    *context.out << buffer;
  }
  std::error_code ec;
  std::filesystem::remove_all(work, ec);
  return code;
}

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
      // Its work directory goes away below: nothing to resume (bench has no --resume).
      code = ReportStatus(context, "bench",
                          a.status().code() == StatusCode::kCancelled ? CancelledError("interrupted") : a.status());
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
  sub->add_option("what", o.what, "accuracy | mesh");
  sub->add_option("--distance", o.distances, "plane distance(s) in mm for accuracy (default 270..310)");
  sub->add_option("--steps", o.steps, "table steps rendered per distance")
      ->capture_default_str()
      ->check(CLI::Range(1, 1200));
  sub->add_flag(
      "--calib", o.calib,
      "accuracy: calibrate from rendered calibration-object bundles (three-step and joint) with lens "
      "distortion on, then scan the plane with each rig (default distance 300 mm)");
  sub->add_option("--k1", o.k1, "accuracy --calib: radial distortion k1 of the virtual camera")
      ->capture_default_str();
  sub->add_option("--target", o.target,
                  "accuracy --calib: calibration target, object (the paper's two-plane object; its three steps "
                  "are the paper's DLT without distortion) or board (the demo's checkerboard on the table in "
                  "three placements)")
      ->capture_default_str();
  sub->add_option("--calib-steps", o.calibration_steps,
                  "accuracy --calib: table angles per calibration placement (default 9 object, 16 board)");
  sub->add_option("--scene", o.scenes,
                  "accuracy: line centres against the truth on these scene files (e.g. data/scenes/"
                  "glossy-webcam.json), --steps table steps over the whole turn, instead of the plane test");
  sub->add_option("--f-number", o.f_number,
                  "accuracy --scene: render the lasers' speckle through this f-number instead of the scene's "
                  "(the webcam preset's is 4; a webcam's own lens is nearer 2-2.4: README)")
      ->check(CLI::Range(0.5, 64.0));
  sub->add_flag("--extend-line-ends", o.extend_line_ends,
                "accuracy --scene: also look past each stretch's end for a faint continuation (opt-in "
                "extraction step: more rows found, more rows over 1 px; README)");
  sub->add_option("--board-poses", o.board_poses,
                  "accuracy --calib: also calibrate from a hand-held checkerboard bundle of this many poses "
                  "(joint refinement only: it fixes the distortion)")
      ->capture_default_str();
  sub->add_option("--cloud", o.cloud, "mesh: the scan's cloud.ply");
  sub->add_option("--truth", o.truth, "mesh: the scan's bundle (with truth/)");
  sub->add_option("--depth", o.depth, "mesh: Poisson depth")->capture_default_str()->check(CLI::Range(4, 12));
  sub->add_option("--voxel", o.voxel, "mesh: fusion voxel, mm")->capture_default_str()->check(CLI::Range(0.05, 20.0));
  sub->add_flag("--watertight", o.watertight, "mesh: also the watertight fusion (a third row)");
  sub->add_option("--threads", o.threads, "mesh: threads for both methods")
      ->capture_default_str()
      ->check(CLI::Range(1, 256));
  sub->callback([&context, exit_code] {
    if (o.what == "mesh") {
      *exit_code = RunBenchMesh(o, context);
      return;
    }
    if (o.what == "accuracy") {
      if (!o.scenes.empty() && o.steps < 1) {
        *context.err << "rotoscan bench: --steps must be >= 1\n";
        *exit_code = kExitUsage;
        return;
      }
      *exit_code = o.calib              ? RunBenchCalibratedAccuracy(o, context)
                   : !o.scenes.empty() ? RunBenchSceneAccuracy(o, context)
                                       : RunBenchAccuracy(o, context);
      return;
    }
    if (o.what == "extract" || o.what == "render") {
      *exit_code = NotBuilt(context, "bench",
                            "'" + o.what + "' (built: accuracy; speed: the Google Benchmark programs in host/bench/)");
      return;
    }
    *context.err << "rotoscan bench: unknown benchmark '" << o.what << "' (accuracy, mesh, extract or render)\n";
    *exit_code = kExitUsage;
  });
}

}  // namespace rotoscan::cli
