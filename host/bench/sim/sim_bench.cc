// Speed of the virtual scanner (issue 3 target: one 1288x964 frame of a ~100k-triangle scene in <= 100 ms
// on one core). Run: build/host/bench/sim/sim_bench
//
// BM_RenderStep renders a whole table step (left, right, off, natural) from one set of camera rays, which
// is how bundles are rendered; its time divided by 4 is the cost per frame (reported as ms_per_frame).
// BM_RenderLaserFrame renders one laser frame alone (rays + shading + sensor of that frame only).
#include <benchmark/benchmark.h>

#include "rotoscan/sim/renderer.h"
#include "rotoscan/sim/scene.h"

namespace {

std::unique_ptr<rotoscan::sim::Renderer> MakeRenderer() {
  // A sphere of 316 segments: 316 * 158 * 2 ~ 100k triangles, filling a good part of the view.
  auto scene = rotoscan::sim::ParseScene(
      R"({"objects": [{"type": "sphere", "radius_mm": 40, "segments": 316}]})", ".", "bench");
  if (!scene.ok()) return nullptr;
  auto renderer = rotoscan::sim::Renderer::Create(*scene);
  return renderer.ok() ? std::move(renderer).value() : nullptr;
}

void BM_RenderStep(benchmark::State& state) {
  auto renderer = MakeRenderer();
  if (!renderer) {
    state.SkipWithError("scene setup failed");
    return;
  }
  uint64_t seed = 1;
  for (auto _ : state) {
    auto step = renderer->RenderStep(0.01 * static_cast<double>(seed), seed);
    benchmark::DoNotOptimize(step.frames[0].data);
    ++seed;
  }
  state.counters["triangles"] = static_cast<double>(renderer->TriangleCount());
  // Frames per second of real time; 1000 / frames_per_s = ms per frame.
  state.counters["frames_per_s"] =
      benchmark::Counter(4.0 * static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_RenderStep)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(2.0);

void BM_RenderLaserFrame(benchmark::State& state) {
  auto renderer = MakeRenderer();
  if (!renderer) {
    state.SkipWithError("scene setup failed");
    return;
  }
  uint64_t seed = 1;
  for (auto _ : state) {
    auto step = renderer->RenderStep(0.01 * static_cast<double>(seed), seed, {true, false, false, false});
    benchmark::DoNotOptimize(step.frames[0].data);
    ++seed;
  }
}
BENCHMARK(BM_RenderLaserFrame)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(2.0);

void BM_LineTruth(benchmark::State& state) {
  auto renderer = MakeRenderer();
  if (!renderer) {
    state.SkipWithError("scene setup failed");
    return;
  }
  for (auto _ : state) {
    auto truth = renderer->LineTruth(rotoscan::geometry::LaserId::kLeft, 0.1);
    benchmark::DoNotOptimize(truth.data());
  }
}
BENCHMARK(BM_LineTruth)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
