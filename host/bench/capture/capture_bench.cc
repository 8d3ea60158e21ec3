// Scan timing in virtual time (DESIGN.md "Targets": a scan takes no longer than the camera's frame rate
// allows). The sim board (the firmware core) and the virtual camera at 30 frames/s run a whole scan; the
// figures are on the scan's virtual clock, so they do not depend on the machine:
//   virtual_s / frames_s   the scan's duration over the time of the frames it used (frames_used / 30)
//   captured / used        frames the camera delivered vs frames written
//   frames_per_step        4 (left, right, off, natural), or 3 with a shared off frame (*_shared_off)
// Targets: hardware-triggered <= 1.05x, free-running <= 1.5x, for a 1,200-step scan (4 frames per step).
// The *_shared_off runs take 3 frames per step (the off frame is also the color frame); compare their
// virtual_s with the 4-frame run of the same mode.
// Frames are rendered small (64x48): the renderer's speed is sim_bench's business.
//   build/host/bench/capture/capture_bench                       (1,200 steps; ~1 min of wall time)
//   build/host/bench/capture/capture_bench --benchmark_filter=/120   (a quicker look)
//
// BM_LiveKeepsUp: does `scan --live` keep up with the camera on 2 cores (one for the capture, one for the
// processing, as `scan --live` runs it: pipeline::ProcessSteps with 1 thread)? The frames of a 24-step
// scan at the full 1288 x 964 of the machine-vision preset (a 40 mm sphere filling the view) are captured
// once (sim board, virtual camera, untimed) and kept in memory as the live source holds them; then their
// processing (extraction and triangulation of both lasers per step, then the merge and the normals at the
// end) is timed in wall time on this machine. Baseline, in the same run: the frames' own time at
// 30 frames/s (4 frames per step: 133.3 ms). ratio = processing / frames time < 1 keeps up (the end-of-scan
// merge and normals are counted in, so the per-step figure is an upper bound).
//   build/host/bench/capture/capture_bench --benchmark_filter=Live
#include <chrono>
#include <filesystem>
#include <fstream>
#include <map>

#include <unistd.h>

#include <benchmark/benchmark.h>

#include "rotoscan/capture/factory.h"
#include "rotoscan/capture/scan.h"
#include "rotoscan/pipeline/process.h"
#include "rotoscan/sim/scene.h"

namespace rotoscan::capture {
namespace {

namespace fs = std::filesystem;

void BM_Scan(benchmark::State& state, Timing timing, bool rolling, bool shared_off = false) {
  const int steps = static_cast<int>(state.range(0));
  const fs::path dir = fs::temp_directory_path() / ("rotoscan_capture_bench_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const fs::path scene_path = dir / "scene.json";
  std::ofstream(scene_path) << R"({"camera": {"width": 64, "height": 48, "hfov_deg": 20},
    "objects": [{"type": "sphere", "radius_mm": 30, "position_mm": [0, 0, 30]}]})";
  for (auto _ : state) {
    OpenContext context;
    context.scene_path = scene_path.string();
    if (rolling) context.options = {"rolling=1"};
    auto board = OpenBoard("sim", &context).value();
    context.board = board.get();
    auto camera = OpenCamera("virtual", context).value();
    ScanOptions o;
    o.steps = steps;
    o.step_deg = 0.3;
    o.timing = timing;
    o.shared_off = shared_off;
    o.header.created_by = "capture_bench";
    o.header.camera.model = sim::LoadScene(scene_path).value().rig.camera;
    fs::remove_all(dir / "b");
    auto summary = RunScan(*board, *camera, *context.clock, dir / "b", o, nullptr);
    if (!summary.ok()) {
      state.SkipWithError(summary.status().ToString().c_str());
      break;
    }
    const auto& s = summary.value();
    state.counters["virtual_s"] = static_cast<double>(s.elapsed_us) / 1e6;
    state.counters["frames_s"] = static_cast<double>(s.frames_time_us) / 1e6;
    state.counters["ratio"] = static_cast<double>(s.elapsed_us) / static_cast<double>(s.frames_time_us);
    state.counters["captured"] = s.frames_captured;
    state.counters["used"] = s.frames_used;
    state.counters["frames_per_step"] = static_cast<double>(s.frames_used) / steps;
  }
  fs::remove_all(dir);
}

BENCHMARK_CAPTURE(BM_Scan, triggered, Timing::kTriggered, false)->Arg(120)->Arg(1200)->Iterations(1)->Unit(benchmark::kSecond);
BENCHMARK_CAPTURE(BM_Scan, free_running_rolling, Timing::kFreeRunning, true)->Arg(120)->Arg(1200)->Iterations(1)->Unit(benchmark::kSecond);
BENCHMARK_CAPTURE(BM_Scan, free_running_global, Timing::kFreeRunning, false)->Arg(120)->Arg(1200)->Iterations(1)->Unit(benchmark::kSecond);
BENCHMARK_CAPTURE(BM_Scan, triggered_shared_off, Timing::kTriggered, false, true)->Arg(120)->Arg(1200)->Iterations(1)->Unit(benchmark::kSecond);
BENCHMARK_CAPTURE(BM_Scan, free_running_rolling_shared_off, Timing::kFreeRunning, true, true)->Arg(120)->Arg(1200)->Iterations(1)->Unit(benchmark::kSecond);

// The captured steps in memory, as `scan --live` hands them to the processing.
class MemorySteps : public pipeline::StepSource {
 public:
  int StepCount() const override { return static_cast<int>(steps_.size()); }
  Result<pipeline::StepFrames> Load(int index) const override { return steps_.at(index); }
  void Add(const CapturedFrame& c) {
    pipeline::StepFrames& s = steps_[c.step];
    s.step = c.step;
    s.table_angle_rad = c.table_angle_rad;
    s.name = "step " + std::to_string(c.step);
    s.Set(c.laser, c.frame->image.clone());
  }

 private:
  std::map<int, pipeline::StepFrames> steps_;
};

void BM_LiveKeepsUp(benchmark::State& state) {
  const int steps = static_cast<int>(state.range(0));
  constexpr double kFps = 30.0;
  const fs::path dir = fs::temp_directory_path() / ("rotoscan_capture_bench_live_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const fs::path scene_path = dir / "scene.json";
  std::ofstream(scene_path) << R"({"objects": [{"type": "sphere", "radius_mm": 40, "position_mm": [0, 0, 0]}]})";
  const auto scene = sim::LoadScene(scene_path).value();
  MemorySteps source;
  {
    OpenContext context;
    context.scene_path = scene_path.string();
    auto board = OpenBoard("sim", &context).value();
    context.board = board.get();
    auto camera = OpenCamera("virtual", context).value();
    ScanOptions o;
    o.steps = steps;
    o.step_deg = 360.0 / 192;  // 100 motor steps of the sim board
    o.frame_rate_hz = kFps;
    o.header.created_by = "capture_bench";
    o.header.camera.model = scene.rig.camera;
    o.on_frame = [&source](const CapturedFrame& c) {
      source.Add(c);
      return Status::Ok();
    };
    auto summary = RunScan(*board, *camera, *context.clock, dir / "b", o, nullptr);
    if (!summary.ok()) {
      state.SkipWithError(summary.status().ToString().c_str());
      fs::remove_all(dir);
      return;
    }
  }
  pipeline::ProcessOptions options;
  options.threads = 1;  // as `scan --live`: the other core captures
  size_t points = 0;
  double seconds = 0.0;
  for (auto _ : state) {
    const auto start = std::chrono::steady_clock::now();
    auto processed = pipeline::ProcessSteps(scene.rig, source, options, nullptr);
    seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    if (!processed.ok()) {
      state.SkipWithError(processed.status().ToString().c_str());
      break;
    }
    points = processed.value().cloud.size();
  }
  const double frames_s = steps * 4 / kFps;  // the baseline: the camera's time for those frames
  state.counters["width"] = scene.rig.camera.width;
  state.counters["height"] = scene.rig.camera.height;
  state.counters["points"] = static_cast<double>(points);
  state.counters["process_ms_per_step"] = 1000.0 * seconds / steps;
  state.counters["frames_ms_per_step"] = 1000.0 * frames_s / steps;
  state.counters["ratio"] = seconds / frames_s;
  fs::remove_all(dir);
}
BENCHMARK(BM_LiveKeepsUp)->Arg(24)->Iterations(3)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
}  // namespace rotoscan::capture
