// Speed of the virtual scanner (issue 3 target: one 1288x964 frame of a ~100k-triangle scene in <= 100 ms
// on one core). Run: build/host/bench/sim/sim_bench
//
// BM_RenderStep renders a whole table step (left, right, off, natural) from one set of camera rays, which
// is how bundles are rendered; frames_per_s counts its 4 frames. BM_RenderLaserFrame and
// BM_RenderNaturalFrame render one frame alone (camera rays + shading + sensor; the natural frame also
// casts the lamp's shadow rays).
//
// Timings on a loaded machine are noisy; instruction counts are not. One RenderStep call of a benchmark:
//   valgrind --tool=callgrind --toggle-collect='rotoscan::sim::Renderer::RenderStep*'
//       build/host/bench/sim/sim_bench --benchmark_filter=BM_RenderNaturalFrame   (one command line)
// (callgrind runs a single iteration; the first also builds the normal-deviate table, ~50 M instructions
// once per process).
#include <benchmark/benchmark.h>

#include "rotoscan/sim/renderer.h"
#include "rotoscan/sim/scene.h"

namespace {

// A sphere of 316 segments: 316 * 158 * 2 ~ 100k triangles, filling a good part of the view. Built once
// for all benchmarks (the ray grid and the BVH take about a second).
const rotoscan::sim::Renderer* SharedRenderer(benchmark::State& state) {
  static const std::unique_ptr<rotoscan::sim::Renderer> renderer = [] {
    auto scene = rotoscan::sim::ParseScene(
        R"({"objects": [{"type": "sphere", "radius_mm": 40, "segments": 316}]})", ".", "bench");
    if (!scene.ok()) return std::unique_ptr<rotoscan::sim::Renderer>();
    auto created = rotoscan::sim::Renderer::Create(*scene);
    return created.ok() ? std::move(created).value() : nullptr;
  }();
  if (!renderer) state.SkipWithError("scene setup failed");
  return renderer.get();
}

// Renders steps with the frames of `mask`; counts frames per second of real time (1000 / that = ms per
// frame).
void RenderSteps(benchmark::State& state, const rotoscan::sim::FrameMask& mask) {
  const rotoscan::sim::Renderer* renderer = SharedRenderer(state);
  if (renderer == nullptr) return;
  uint64_t seed = 1;
  for (auto _ : state) {
    auto step = renderer->RenderStep(0.01 * static_cast<double>(seed), seed, mask);
    benchmark::DoNotOptimize(step.frames[0].data);
    ++seed;
  }
  int frames = 0;
  for (bool wanted : mask) frames += wanted ? 1 : 0;
  state.counters["triangles"] = static_cast<double>(renderer->TriangleCount());
  state.counters["frames_per_s"] = benchmark::Counter(static_cast<double>(frames * state.iterations()),
                                                      benchmark::Counter::kIsRate);
}

void BM_RenderStep(benchmark::State& state) { RenderSteps(state, rotoscan::sim::kAllFrames); }
BENCHMARK(BM_RenderStep)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(2.0);

void BM_RenderLaserFrame(benchmark::State& state) { RenderSteps(state, {true, false, false, false}); }
BENCHMARK(BM_RenderLaserFrame)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(2.0);

void BM_RenderNaturalFrame(benchmark::State& state) { RenderSteps(state, {false, false, false, true}); }
BENCHMARK(BM_RenderNaturalFrame)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(2.0);

void BM_LineTruth(benchmark::State& state) {
  const rotoscan::sim::Renderer* renderer = SharedRenderer(state);
  if (renderer == nullptr) return;
  for (auto _ : state) {
    auto truth = renderer->LineTruth(rotoscan::geometry::LaserId::kLeft, 0.1);
    benchmark::DoNotOptimize(truth.data());
  }
}
BENCHMARK(BM_LineTruth)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
