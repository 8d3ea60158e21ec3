// pipeline::ProcessSteps per table step on a small rendered bundle (Spot, both lasers, 1288x964): the
// per-step cost behind `rotoscan process` (DESIGN.md: a 1,200-step two-laser scan faster than the camera
// captures it, 160 s, i.e. <= 133 ms per step on the whole machine).
//
//   BM_ProcessBundle/<threads>   from disk: PNG decoding of the 4 frames of each step included
//   BM_ProcessMemory/<threads>   frames already decoded: extraction, triangulation, color, normals, merge
//   BM_TriangulatorSetup         the fixed cost of each run: the camera's undistortion table
//                                (laser/triangulate.h), paid once per process, not per step
//
// Items are table steps. The bundle is rendered once per run into a temporary folder (a few seconds).
// Run: build/host/bench/pipeline/pipeline_bench --benchmark_counters_tabular=true
#include <benchmark/benchmark.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "rotoscan/bundle/bundle.h"
#include "rotoscan/bundle/truth.h"
#include "rotoscan/geometry/rig.h"
#include "rotoscan/laser/triangulate.h"
#include "rotoscan/pipeline/process.h"
#include "rotoscan/sim/scene.h"
#include "rotoscan/sim/simulate.h"

namespace {

constexpr int kSteps = 8;

struct Fixture {
  std::filesystem::path bundle_dir;
  rotoscan::geometry::Rig rig;
  std::vector<rotoscan::pipeline::StepFrames> frames;
  bool ok = false;
};

const Fixture& Data() {
  static const Fixture fixture = [] {
    Fixture f;
    f.bundle_dir = std::filesystem::temp_directory_path() / "rotoscan-pipeline-bench";
    auto scene =
        rotoscan::sim::LoadScene(std::filesystem::path(ROTOSCAN_SOURCE_DIR) / "data/scenes/spot.json");
    if (!scene.ok()) {
      std::fprintf(stderr, "%s\n", scene.status().ToString().c_str());
      return f;
    }
    rotoscan::sim::SimulateOptions options;
    options.out = f.bundle_dir;
    options.steps = kSteps;
    options.overwrite = true;
    if (const rotoscan::Status s = rotoscan::sim::Simulate(*scene, options, nullptr); !s.ok()) {
      std::fprintf(stderr, "%s\n", s.ToString().c_str());
      return f;
    }
    auto rig = rotoscan::geometry::ReadRigYaml(rotoscan::bundle::TruthRigPath(f.bundle_dir));
    auto bundle = rotoscan::bundle::ReadBundle(f.bundle_dir);
    if (!rig.ok() || !bundle.ok()) return f;
    f.rig = *rig;
    const rotoscan::pipeline::BundleStepSource source(std::move(*bundle));
    for (int i = 0; i < source.StepCount(); ++i) {
      auto step = source.Load(i);
      if (!step.ok()) return f;
      f.frames.push_back(std::move(*step));
    }
    f.ok = true;
    return f;
  }();
  return fixture;
}

class MemorySource : public rotoscan::pipeline::StepSource {
 public:
  explicit MemorySource(const std::vector<rotoscan::pipeline::StepFrames>& frames) : frames_(frames) {}
  int StepCount() const override { return static_cast<int>(frames_.size()); }
  rotoscan::Result<rotoscan::pipeline::StepFrames> Load(int index) const override {
    return frames_[static_cast<size_t>(index)];  // cv::Mat copies share the pixels
  }

 private:
  const std::vector<rotoscan::pipeline::StepFrames>& frames_;
};

void Report(benchmark::State& state, size_t points) {
  state.SetItemsProcessed(state.iterations() * kSteps);
  state.counters["s_per_step"] =
      benchmark::Counter(kSteps, benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
  state.counters["points"] = static_cast<double>(points);
}

void BM_ProcessBundle(benchmark::State& state) {
  const Fixture& f = Data();
  if (!f.ok) {
    state.SkipWithError("could not render the bundle");
    return;
  }
  rotoscan::pipeline::ProcessOptions options;
  options.threads = static_cast<int>(state.range(0));
  size_t points = 0;
  for (auto _ : state) {
    auto result = rotoscan::pipeline::ProcessBundle(f.bundle_dir, f.rig, options);
    if (!result.ok()) {
      state.SkipWithError(result.status().ToString().c_str());
      return;
    }
    points = result->cloud.size();
  }
  Report(state, points);
}
BENCHMARK(BM_ProcessBundle)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_ProcessMemory(benchmark::State& state) {
  const Fixture& f = Data();
  if (!f.ok) {
    state.SkipWithError("could not render the bundle");
    return;
  }
  const MemorySource source(f.frames);
  rotoscan::pipeline::ProcessOptions options;
  options.threads = static_cast<int>(state.range(0));
  size_t points = 0;
  for (auto _ : state) {
    auto result = rotoscan::pipeline::ProcessSteps(f.rig, source, options);
    if (!result.ok()) {
      state.SkipWithError(result.status().ToString().c_str());
      return;
    }
    points = result->cloud.size();
  }
  Report(state, points);
}
BENCHMARK(BM_ProcessMemory)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_TriangulatorSetup(benchmark::State& state) {
  const Fixture& f = Data();
  if (!f.ok) {
    state.SkipWithError("could not render the bundle");
    return;
  }
  for (auto _ : state) {
    const rotoscan::laser::Triangulator triangulator(f.rig.camera);
    benchmark::DoNotOptimize(&triangulator);
  }
}
BENCHMARK(BM_TriangulatorSetup)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
